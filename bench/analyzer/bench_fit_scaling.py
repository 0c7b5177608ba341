"""Benchmark of the fit's cost against the number of runs: ``python bench/analyzer/bench_fit_scaling.py``.

Records mismatching runs with the independent truth simulator (``host_tools.truth``: 1.5 s
lines and arcs of this project's firmware recorder with a back-EMF constant 15 % above nominal,
this benchmark's own seeds), prepares the first 8, 32 and 128 of them as the analyzer does
(nominal replay, noise floors, fit problem) and fits one candidate effect with its held-out
folds (``fit.judge.evaluate_candidate``, the work each candidate of an analysis does).  Prints
per run count: the fit's wall and CPU time, the CPU time per run and its ratio to the smallest
count's (1.0 when the cost grows linearly with the runs) and the runs replayed per run (a
count that the machine's load does not change), and the CPU per run of the stages before the
fit (loading, preparing, replaying and locating, for comparison); then the peak memory.  On a
shared machine compare the CPU columns and the replay counts; wall times vary with the other
jobs."""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
sys.path.insert(0, ROOT)

# (reference, clamp) cycled over the runs: a straight line and arcs both ways
REFERENCES = [({"kind": "line", "accel": 1.0, "cruise": 0.6}, True),
              ({"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.5}, True),
              ({"kind": "arc", "accel": 1.2, "cruise": 0.6, "radius": -0.7}, True)]
EFFECTS = {"motor_back_emf": {"ke_ratio": 1.15}}
DURATION_S = 1.5
SEED = 7300


def _problem(paths: list[str]):
    """The fit problem of ``paths`` as :func:`host_tools.analyzer.pipeline.analyze` builds it."""
    from host_tools.analyzer import pipeline as pl

    return pl.front(paths).det


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/bench_fit_scaling.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", default="8,32,128", help="comma-separated run counts")
    ap.add_argument("--effect", default="motor_back_emf", help="the candidate effect fitted")
    ap.add_argument("--keep", default=None, help="keep (and reuse) the generated runs here")
    args = ap.parse_args(argv)
    from host_tools import truth
    from host_tools.analyzer.fit.judge import evaluate_candidate, heldout_method
    from host_tools.analyzer.fit.problem import CACHE_BYTES

    counts = sorted(int(n) for n in args.runs.split(","))
    root = args.keep or tempfile.mkdtemp(prefix="analyzer-bench-fit-")
    paths = []
    for i in range(counts[-1]):
        p = os.path.join(root, f"run-{i:03d}")
        if not os.path.exists(os.path.join(p, "meta.json")):
            ref, clamp = REFERENCES[i % len(REFERENCES)]
            truth.simulate_run(p, ref, EFFECTS, clamp=clamp, duration_s=DURATION_S,
                               seed=SEED + i, overwrite=True)
        paths.append(p)
    print(f"one candidate ({args.effect}) fitted with its held-out folds on N mismatching "
          f"{DURATION_S:g} s runs ({os.cpu_count()} cores)")
    print(f"{'runs':>5s} {'wall':>8s} {'CPU':>8s} {'CPU/run':>8s} {'ratio/run':>9s} "
          f"{'replays/run':>11s} {'prep/run':>8s}  held out")
    base = None
    for n in counts:
        c_prep = time.process_time()
        det = _problem(paths[:n])
        prep = (time.process_time() - c_prep) / n
        pb = det.problem
        n0 = pb.n_simulated
        t0, c0 = time.perf_counter(), time.process_time()
        cand = evaluate_candidate(pb, [args.effect])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        per = cpu / n
        base = base or per
        print(f"{n:5d} {wall:7.1f}s {cpu:7.1f}s {per:7.3f}s {per / base:9.2f} "
              f"{(pb.n_simulated - n0) / n:11.1f} {prep:7.3f}s  {heldout_method(n, pb.split_frac)}; "
              + ", ".join(f"{k} {v:.5g}" for k, v in cand.fit.params[args.effect].items()),
              flush=True)
    import resource
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"\npeak resident memory of this process {peak:.0f} MB (the replay cache holds at most "
          f"{CACHE_BYTES / 2 ** 20:.0f} MB); runs under {root}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
