"""Benchmark of the analyzer's output set (prints figures): two back-EMF runs (×1.2) of the
truth simulator, analysed with two candidate effects, then the outputs written without and with
the PNG plots: the time of writing, the size of report.html and of the series CSVs.

``python -m host_tools.analyzer.report.bench_outputs [--duration S] [--work DIR]``"""
from __future__ import annotations

import argparse
import os
import tempfile
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=1.5, help="seconds per run (default 1.5)")
    ap.add_argument("--work", default=None, help="folder for the runs and outputs (default: "
                    "a temporary one)")
    a = ap.parse_args()
    from host_tools import runfmt
    from host_tools.analyzer.pipeline import analyze
    from host_tools.analyzer.report.writers import write_outputs
    from host_tools.truth.run import simulate_run

    d = a.work or tempfile.mkdtemp(prefix="bench-outputs-")
    line = {"kind": "line", "accel": 1.0}
    paths = []
    for k, cruise in enumerate((0.6, 0.4)):
        p = os.path.join(d, f"r{k}")
        if not os.path.exists(p):
            simulate_run(p, {**line, "cruise": cruise},
                         {"motor_back_emf": {"ke_ratio": 1.2}}, duration_s=a.duration,
                         seed=3 + k)
        paths.append(p)
    runs = [runfmt.load_run(p) for p in paths]
    runfmt.label_runs(runs)
    an = analyze(runs, jobs=2, effects=["motor_back_emf", "axle_coulomb"], log=lambda m: None)
    for plots in (False, True):
        out = os.path.join(d, f"out-{'png' if plots else 'noplots'}")
        t0 = time.perf_counter()
        rep = write_outputs(an, out, plots=plots)
        dt = time.perf_counter() - t0
        size = {o: os.path.getsize(os.path.join(out, o)) for o in rep["outputs"]}
        ser = sum(v for k, v in size.items() if k.startswith("series/"))
        print(f"2 runs x {a.duration:g} s, plots {'on' if plots else 'off'}: outputs written in "
              f"{dt:.2f} s; report.html {size['report.html'] / 1e6:.2f} MB; series "
              f"{ser / 1e6:.2f} MB; {sum(1 for k in size if k.endswith('.png'))} PNGs; "
              f"verdict {an.verdict}")


if __name__ == "__main__":
    main()
