"""bench/analyzer/walk_call_path.py: the walk of analyze's call path through the analyzer's
files (stays, returns, visits), on a tiny synthetic case."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from _native_skip import needs_native

ROOT = Path(__file__).resolve().parents[3]


def _tool():
    spec = importlib.util.spec_from_file_location(
        "walk_call_path", ROOT / "bench" / "analyzer" / "walk_call_path.py")
    assert spec is not None and spec.loader is not None
    mod = sys.modules.get(spec.name)
    if mod is None:
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod  # its dataclass looks its module up there
        spec.loader.exec_module(mod)
    return mod


def test_stays_and_returns_are_counted_from_the_sequence():
    w = _tool().Walk([("a.py", 2), ("b.py", 1), ("a.py", 3), ("c.py", 1), ("b.py", 1)])
    assert w.files == ["a.py", "b.py", "c.py"]
    assert w.returns == 2
    assert dict(w.visits) == {"a.py": 2, "b.py": 2, "c.py": 1}
    assert dict(w.calls) == {"a.py": 5, "b.py": 2, "c.py": 1}


@needs_native()
def test_analyze_visits_each_stage_file_once_and_in_order(tmp_path):
    """analyze calls each stage once with all runs: its own calls (depth 1) visit the stage
    files in the pipeline's order and never return to one."""
    from host_tools.analyzer import synth
    paths = synth.make_case(tmp_path / "null", None, profiles=("ramp", "turn"), duration_s=1.0)
    w = _tool().walk(paths, depth=1, jobs=1)
    stages = ["pipeline.py", "prepare/inputs.py", "replay/nominal.py", "locate/mismatch.py",
              "select.py", "prepare/command_lag.py", "report/sections.py", "report/model.py"]
    assert [f for f in w.files if f in stages] == stages, w.stays
    assert w.returns == 0, w.stays
    deeper = _tool().walk(paths, depth=2, jobs=1, ignore=["signals.py"])
    assert "signals.py" not in deeper.files
    assert {"replay/closedloop.py", "replay/openloop.py", "locate/floors.py"} <= set(deeper.files)
    assert len(deeper.stays) > len(w.stays)

