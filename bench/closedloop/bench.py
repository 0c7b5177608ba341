#!/usr/bin/env python3
"""Benchmark: the closed loop (lib/control against the lib/slipmodel plant) run by
lib/closedloop's driver through the C ABI, against the reference it must match: the plant
re-simulated from rest at every tick (host_tools.control.resimulate_from_rest, O(ticks^2)).
Prints figures; asserts nothing.

    python3 bench/closedloop/bench.py [--minutes 10] [--short 3] [--no-replay]

1. a closed-loop run of --minutes (fixed-point cascade, clamp on, figure eight R = 0.6 m,
   25 ms ticks: 10 min = 24,000 ticks) through host_tools.control.ClosedLoop;
2. the same settings for --short seconds both ways, in this process: time of each, the ratio,
   and the largest difference of their outputs;
3. (unless --no-replay) the analyzer's ClosedLoopReplay.simulate on a 100 s recording written
   by the truth simulator (its longest: its command history holds 4,096 ticks; the writing
   is not timed).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools import _native  # noqa: E402
from host_tools.control import ClosedLoop, resimulate_from_rest  # noqa: E402

REF = ("figure_eight", 0.5, 0.4, 0.6)
T = 0.025
REPLAY_S = 100.0


def best_of(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--short", type=float, default=3.0, help="seconds for the comparison")
    ap.add_argument("--no-replay", action="store_true")
    a = ap.parse_args(argv)
    _native.build()
    n_long = int(round(a.minutes * 60 / T))
    n_short = int(round(a.short / T))

    def driver(n):
        return ClosedLoop(*REF, fixed_point=True, clamp=True).run(n)

    t_long, out = best_of(lambda: driver(n_long), 3)
    e = np.hypot(out["x_m"] - out["x_odo_m"], out["y_m"] - out["y_odo_m"])
    print(f"closed loop, {a.minutes:g} min = {n_long} ticks (figure eight, fixed point, clamp on, "
          f"plant dt 0.5 ms): {t_long:.3f} s (best of 3), {n_long / t_long:,.0f} ticks/s, "
          f"{a.minutes * 60 / t_long:,.0f} simulated s per s; odometry vs true pose at the end "
          f"{e[-1] * 1e3:.2f} mm")

    t_new, new = best_of(lambda: driver(n_short), 5)
    t_old, (old, _) = best_of(lambda: resimulate_from_rest(*REF, fixed_point=True, clamp=True,
                                                             t0=0.0, n=n_short), 1)
    diff = max(float(np.abs(new[c] - old[c]).max()) for c in old)
    print(f"{a.short:g} s = {n_short} ticks: driver {t_new * 1e3:.2f} ms (best of 5), "
          f"re-simulation from rest {t_old * 1e3:.0f} ms: ratio {t_old / t_new:,.0f}x; "
          f"largest output difference {diff:g}")
    print(f"  (the re-simulation grows with ticks^2: {a.minutes:g} min would take about "
          f"{t_old * (n_long / n_short) ** 2 / 3600:,.1f} h at this rate, extrapolated)")

    if not a.no_replay:
        from host_tools import truth
        from host_tools.analyzer.prepare.inputs import prepare
        from host_tools.analyzer.replay.closedloop import ClosedLoopReplay
        from host_tools.runfmt import load_run
        with tempfile.TemporaryDirectory() as d:
            path = truth.simulate_run(os.path.join(d, "run"),
                                      {"kind": REF[0], "accel": REF[1], "cruise": REF[2],
                                       "radius": REF[3]}, None, duration_s=REPLAY_S, seed=1)
            prep = prepare(load_run(path))
            rp = ClosedLoopReplay()
            setup, problems, _ = rp.setup(prep)
            if setup is None:
                print(f"replay not run: {problems}")
                return 0
            t_rep, sim = best_of(lambda: rp.simulate(prep, {}, setup), 3)
            print(f"analyzer ClosedLoopReplay.simulate on a {REPLAY_S:g} s recording of the truth "
                  f"simulator ({sim['t_s'].size} ticks): {t_rep:.3f} s (best of 3)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
