"""meta.json values inside their unit ranges that no robot can have: refused with the
physical reason, the file and the key (exit 2 in the tools)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools import runfmt
from host_tools.runfmt import RunFormatError, validate_meta
from host_tools.runfmt.validate import PLANT_DT_MIN_S, max_stable_plant_dt_s

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("robot, key, why", [
    ({"e": 0, "d": 0}, "robot.e", "0/0"),
    ({"e": 0}, "robot.e", "cannot drive"),
    ({"I_wy": 1e-9}, "robot.I_wy", "time constant"),
    ({"I_wy": 1e-6}, "robot.I_wy", "time constant"),
])
def test_impossible_robots_are_refused_with_the_reason(robot, key, why):
    with pytest.raises(RunFormatError) as e:
        validate_meta({"robot": robot}, "x/meta.json")
    msg = str(e.value)
    assert "x/meta.json" in msg and f"'{key}'" in msg and why in msg


def test_the_bound_is_the_plants_step_not_a_narrowed_range():
    meta = validate_meta({})
    # the default robot is stable at every step the analyzer takes (up to 10 ms)
    assert max_stable_plant_dt_s(meta) > 1e-2
    # a light wheel just stable at the smallest step passes; just below it is refused
    m = meta["motor"]
    i_edge = PLANT_DT_MIN_S / 2 * m["stall_nm"] / m["no_load_rad_s"]
    validate_meta({"robot": {"I_wy": i_edge * 1.01}})
    with pytest.raises(RunFormatError):
        validate_meta({"robot": {"I_wy": i_edge * 0.99}})
    validate_meta({"robot": {"d": 0}})  # no caster load is possible (centre of mass on the axle)


def test_timing_refuses_such_a_run_with_exit_2(tmp_path):
    run = tmp_path / "run"
    with runfmt.RunWriter(str(run), {"experiment": "t"}) as w:
        w.write_row({c: 0 for c in runfmt.TELEMETRY_COLUMNS} | {"t_s": 0.02})
    meta = json.loads((run / "meta.json").read_text())
    meta["robot"].update(e=0, d=0)
    (run / "meta.json").write_text(json.dumps(meta))
    r = subprocess.run([sys.executable, "-m", "host_tools", "timing", "--run", str(run)], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 2 and "meta.json" in r.stderr and "'robot.e'" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_analyze_refuses_a_dt_unstable_for_the_robot(tmp_path, capsys):
    """A light wheel (I_wy 1e-5 kg m^2: stable up to about 1 ms steps) with --dt 0.01: exit 2
    before the analysis, naming the file and the longest stable step."""
    from host_tools.__main__ import main as cli
    from test_badinput import _base

    run = _base(tmp_path / "run", meta={"experiment": "light wheel", "robot": {"I_wy": 1e-5}})
    assert cli(["analyze", str(run), "--out", str(tmp_path / "out"), "--dt", "0.01"]) == 2
    err = capsys.readouterr().err
    assert "longest stable plant step" in err and "meta.json" in err
