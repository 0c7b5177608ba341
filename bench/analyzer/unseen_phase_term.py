"""Benchmark: the analysis of a case with and without the phase term of the replay's
uncertainty from unreported commands (``replay.unseen.phase_term``, docs/analyzer.md "The
replay's uncertainty from unreported commands"): a cascade whose outer period spans several
inner ticks (meta.json ``periods_s.outer`` / ``periods_s.inner`` >= 2) seen by frames that
report one phase of that period for a block of frames (a 29 ms loop seen every 55 ms).

Usage (nice it; one process):

  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_phase_term.py [--off] CASE_DIR ...

Prints per case: verdict, the three largest windows of the duty replay in noise floors (the
strong-window threshold for comparison) and the selected effects with their fitted values.
``--off``: the same analysis with the phase term left out (every other draw unchanged).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools.analyzer import pipeline  # noqa: E402
from host_tools.analyzer.locate.mismatch import strong_threshold  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", help="case folders (a suite runs/<case>)")
    ap.add_argument("--off", action="store_true", help="without the phase term")
    a = ap.parse_args(argv)
    if a.off:
        UN.phase_term = lambda prep: None  # input_uncertainty calls this name
    for case in a.cases:
        runs = sorted(str(p) for p in Path(case).iterdir() if (p / "meta.json").exists())
        with contextlib.redirect_stderr(io.StringIO()):
            an = pipeline.analyze(runs, jobs=1, log=lambda m: None)
        total = sum(float(r.telemetry["t_s"][-1] - r.telemetry["t_s"][0]) for r in an.runs)
        duty = [e for e in an.mismatch if e.get("replay") == "duty"]
        top = sorted(duty, key=lambda e: -e["rms"] / e["noise_floor"])[:3]
        print(f"{Path(case).name} [{'without the phase term' if a.off else 'phase term'}]: {an.verdict}; "
              f"{len(duty)} windows, strong at {strong_threshold(total):.2f} floors; largest: "
              + ", ".join(f"{e['run']} {e['channel']} {e['t_start_s']:.2f}-{e['t_end_s']:.2f} s "
                          f"{e['rms'] / e['noise_floor']:.2f}" for e in top)
              + "; selected: " + (", ".join(f"{s['effect']} {s['params']}" for s in an.selected)
                                  or "-"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
