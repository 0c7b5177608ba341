#!/usr/bin/env python3
"""Benchmark: ``ddrobot batch`` throughput on a generated fleet, and its drift report.
Prints figures; asserts nothing.

    nice .venv/bin/python bench/batch/bench.py [--out out/bench-batch] [--robots 5] [--days 10]
        [--configs local1,local2,cluster] [--sets N] [--report-out DIR]

1. the fleet (host_tools.batch.fleetgen: one robot's wheels wear, one's battery sags, one has
   constant large wheels, the rest nominal) is generated under OUT/fleet unless there;
2. for each configuration the same run sets are analyzed from scratch into OUT/<config>:
   ``local1``/``local2``: a local cluster of 1/2 worker processes; ``cluster``: a
   ``dask scheduler`` and 2 ``dask worker`` processes on 127.0.0.1 reached by its address;
   prints run sets per minute (wall time of the batch, cluster start excluded);
3. the fleet report: of the last configuration when it analyzed every set, else of a batch
   of every set into --report-out (resumable: sets done there are skipped); prints the
   flagged robots and the generated truth (which robots drift in what).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools.batch import fleet, fleetgen  # noqa: E402
from host_tools.batch.cluster import ProcessCluster  # noqa: E402
from host_tools.batch.run import run_batch  # noqa: E402
from host_tools.batch.sets import from_tree  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/bench-batch")
    ap.add_argument("--robots", type=int, default=5)
    ap.add_argument("--days", type=int, default=10)
    ap.add_argument("--configs", default="local1,local2,cluster")
    ap.add_argument("--sets", type=int, default=0,
                    help="time only N sets, spread over the robots (default: all)")
    ap.add_argument("--report-out", default=None,
                    help="folder of the full fleet's batch for the report (default "
                         "OUT/report)")
    a = ap.parse_args()
    fleet_dir = os.path.join(a.out, "fleet")
    if not os.path.isdir(fleet_dir):
        t0 = time.time()
        fleetgen.generate(fleet_dir, robots=a.robots, days=a.days)
        print(f"generated {a.robots} robots x {a.days} days in {time.time() - t0:.0f} s")
    with open(os.path.abspath(fleet_dir) + ".labels.json") as fh:
        labels = json.load(fh)
    sets = from_tree(fleet_dir)
    timed = sets
    if a.sets and a.sets < len(sets):  # every k-th set: each robot, several days
        k = len(sets) / a.sets
        timed = [sets[int(i * k)] for i in range(a.sets)]
    print(f"fleet: {len(sets)} run sets ({len(sets[0].runs)} runs each); timing "
          f"{len(timed)} of them per configuration; {os.cpu_count()} CPUs, load "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{'configuration':<44} {'sets':>5} {'wall s':>8} {'sets/min':>9} {'failed':>7} "
          f"{'mean analysis s':>16}")
    last = None
    quiet = lambda s: None  # noqa: E731
    for cfg in [c for c in a.configs.split(",") if c]:
        out = os.path.join(a.out, cfg)
        shutil.rmtree(out, ignore_errors=True)
        if cfg.startswith("local"):
            n = int(cfg[5:] or 1)
            recs, st = run_batch(timed, out, workers=n, progress=quiet)
            what = f"local cluster, {n} worker(s)"
        elif cfg == "cluster":
            with ProcessCluster(2) as cl:
                recs, st = run_batch(timed, out, scheduler=cl.address, progress=quiet)
            what = "dask scheduler + 2 dask worker processes"
        else:
            print(f"unknown configuration {cfg!r}", file=sys.stderr)
            return 2
        mean = sum(r.get("wall_s") or 0 for r in recs) / max(1, len(recs))
        print(f"{what:<44} {len(recs):>5} {st['wall_s']:>8.1f} "
              f"{60 * len(recs) / st['wall_s']:>9.2f} {st['failed']:>7} {mean:>16.1f}",
              flush=True)
        last = (out, recs)
    if last is not None and len(timed) == len(sets):
        out, recs = last
    else:
        out = a.report_out or os.path.join(a.out, "report")
        recs, _ = run_batch(sets, out, workers=2, progress=quiet)
    fleet.write_table(recs, out)
    md, series = fleet.write_report(recs, out)
    flagged = sorted({(s["robot"], s["param"]) for s in series if s["flag"]})
    truth = sorted((r, v["drift"]) for r, v in labels["robots"].items() if v["drift"])
    print(f"fleet report: {md}")
    print("flagged: " + (", ".join(f"{r} {p}" for r, p in flagged) or "none"))
    print("truth:   " + ", ".join(f"{r} {p}" for r, p in truth))
    print("flags match the truth" if flagged == truth else "flags DIFFER from the truth")
    return 0


if __name__ == "__main__":
    sys.exit(main())
