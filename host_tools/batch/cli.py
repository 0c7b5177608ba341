"""``ddrobot batch SOURCE --out OUT [--scheduler ADDRESS] [--workers N] ...``

Analyze many run sets on Dask: one task per run set (SOURCE: a folder tree
ROBOT/YYYY-MM-DD/RUN/ or a manifest, see host_tools/batch/sets.py), on a local cluster
started here (default) or on an existing one (--scheduler tcp://HOST:PORT).  Each analysis
runs ``python -m host_tools analyze`` in a subprocess with a time and memory limit; a failed,
timed-out or lost analysis is recorded with its error and the batch goes on.  A re-run skips
the sets already done from the same recordings.  Then writes the fleet table and report.

Exit codes: 0 every set analyzed, 1 some set failed (see the table's status and error
columns), 2 bad input (a manifest's file, row and column, or a bad option)."""
from __future__ import annotations

import argparse
import logging
import math

log = logging.getLogger(__name__)

EPILOG = """\
outputs (in OUT):
  <robot>/<date>[/<set>]/  per run set: result.json (the batch's record: status, error,
                           time, worker), the analyzer's report.json, report.md, model.json
  fleet.parquet, fleet.csv one row per run set: robot, date, verdict, selected effects with
                           values and 1-sigma uncertainties, mismatch RMS (noise floors)
  fleet.md, plots/         each robot's fitted parameters over time, drift flags

on a cluster, OUT and the run folders must be on storage every worker sees at the same path.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n")[1]
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("source", metavar="SOURCE",
                        help="folder tree ROBOT/YYYY-MM-DD/[SET/]RUN/ or a manifest (.csv with "
                             "columns robot,date,run[,set], or .json {\"sets\": [...]})")
    parser.add_argument("--out", required=True, metavar="OUT", help="output folder")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: "
                             "a local cluster)")
    parser.add_argument("--workers", type=int, default=2,
                        help="local cluster: worker processes, one task each (default 2)")
    parser.add_argument("--worker-memory", default="1GiB",
                        help="local cluster: Dask memory limit per worker (default 1GiB)")
    parser.add_argument("--memory", type=float, default=4096.0, metavar="MB",
                        help="address-space limit of each analysis subprocess, MB (default "
                             "4096; 0: none)")
    parser.add_argument("--timeout", type=float, default=600.0, metavar="SECONDS",
                        help="wall-time limit of each analysis (default 600)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="the analyzer's own processes per set (default 1: Dask provides "
                             "the parallelism)")
    parser.add_argument("--effects", default=None, metavar="NAME[,NAME...]",
                        help="passed to the analyzer: fit only these effects")
    parser.add_argument("--redo", action="store_true", help="analyze every set again")
    parser.add_argument("--alpha", type=float, default=None,
                        help="drift test: chance of any false flag in the fleet (default 0.01)")
    parser.add_argument("--no-plots", action="store_true",
                        help="no analyzer plots and no fleet plots")


def _bad(msg: str) -> int:
    log.error("bad input: %s", msg)
    return 2


def main(args: argparse.Namespace) -> int:
    from host_tools.batch import fleet
    from host_tools.batch.run import run_batch
    from host_tools.batch.sets import BadInput, discover

    if not 1 <= args.workers <= 256:
        return _bad(f"--workers {args.workers} must be in 1..256")
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        return _bad(f"--timeout {args.timeout:g} must be > 0")
    if not (math.isfinite(args.memory) and (args.memory == 0 or args.memory >= 256)):
        return _bad(f"--memory {args.memory:g} must be 0 (no limit) or >= 256 MB")
    if not 1 <= args.jobs <= 64:
        return _bad(f"--jobs {args.jobs} must be in 1..64")
    alpha = fleet.ALPHA if args.alpha is None else args.alpha
    if not 0 < alpha < 1:
        return _bad(f"--alpha {alpha:g} must be in (0, 1)")
    try:
        sets = discover(args.source)
    except BadInput as exc:
        return _bad(str(exc))
    extra = (["--effects", args.effects] if args.effects else []) + \
        (["--no-plots"] if args.no_plots else [])
    try:
        records, stats = run_batch(sets, args.out, scheduler=args.scheduler,
                                   workers=args.workers, worker_memory=args.worker_memory,
                                   timeout_s=args.timeout, mem_mb=args.memory or None,
                                   jobs=args.jobs, analyzer_args=extra, redo=args.redo)
    except OSError as exc:
        log.error("%s", exc)
        return 1
    pq, csv = fleet.write_table(records, args.out)
    md, series = fleet.write_report(records, args.out, alpha=alpha, plots=not args.no_plots)
    rate = 60.0 * stats["run"] / stats["wall_s"] if stats["run"] and stats["wall_s"] else 0.0
    print(f"batch: {stats['sets']} run sets: {stats['run']} analyzed now ({rate:.1f} per "
          f"minute on {stats['workers']} worker(s)), {stats['skipped']} skipped as done, "
          f"{stats['failed']} failed")
    for s in series:
        if s["flag"]:
            t = s["test"]
            print(f"drift: {s['robot']} {s['param']}: {t['slope']:+.3g}/day "
                  f"(p = {t['p']:.2g}; {s['value'][0]:.5g} -> {s['value'][-1]:.5g})")
    print(f"fleet: {pq}, {csv}, {md}")
    return 1 if stats["failed"] else 0
