#!/usr/bin/env python3
"""Benchmark: how fast runs go out to MCAP and ROS bags come in.  Prints figures; asserts
nothing.

    python3 bench/interop/bench_interop.py [--duration 60]

A tour of ``--duration`` s from the truth simulator (telemetry every 20 ms, camera at its
default rate) is exported to MCAP (host_tools.interop.mcap_export), written as a ROS 2 MCAP
bag and a ROS 1 bag (the tests' writer, host_tools/tests/interop/_bags.py) and imported back
(host_tools.interop.rosbag_import).  Wall-clock seconds per stage, messages per second and the
file sizes; the largest column difference after the round trip.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "host_tools", "tests", "interop"))

import numpy as np  # noqa: E402

import _bags  # noqa: E402
from host_tools import runfmt, truth  # noqa: E402
from host_tools.interop import mcap_export, rosbag_import  # noqa: E402


def size(path: str) -> int:
    if os.path.isfile(path):
        return os.path.getsize(path)
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="run length, s (default 60)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = truth.simulate_run(os.path.join(tmp, "run"), {"kind": "tour"}, None,
                                 duration_s=a.duration, seed=1)
        r = runfmt.load_run(run)
        n = r.telemetry["t_s"].size
        print(f"run: {a.duration:g} s, {n} telemetry rows, {r.groundtruth['t_s'].size} "
              f"ground-truth rows")
        t0 = time.perf_counter()
        counts = mcap_export.export(run, os.path.join(tmp, "run.mcap"))
        dt = time.perf_counter() - t0
        m = sum(counts.values())
        print(f"export: {m} messages in {dt:.2f} s ({m / dt:,.0f} messages/s, "
              f"{n / dt:,.0f} rows/s), {size(os.path.join(tmp, 'run.mcap')) / 1e6:.2f} MB")
        mp = _bags.write_map(run, os.path.join(tmp, "map.json"))
        for fmt, name in (("mcap", "bag_mcap"), ("ros1", "run.bag")):
            bag = os.path.join(tmp, name)
            t0 = time.perf_counter()
            _bags.write_bag(run, bag, fmt)
            tw = time.perf_counter() - t0
            t0 = time.perf_counter()
            out = os.path.join(tmp, f"imported_{fmt}")
            rosbag_import.import_bag(bag, str(mp), out)
            ti = time.perf_counter() - t0
            b = runfmt.load_run(out)
            worst = max(float(np.max(np.abs(b.telemetry[c] - r.telemetry[c])))
                        for c in r.telemetry)
            print(f"{fmt} bag: written in {tw:.2f} s ({size(bag) / 1e6:.2f} MB), imported in "
                  f"{ti:.2f} s ({n / ti:,.0f} frames/s); largest column difference {worst:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
