"""Benchmark of the analyzer on long recordings: ``python bench/analyzer/bench_long.py``.

Records long runs with the independent truth simulator (``host_tools.truth``, tour references
of speed ramps, cruises, arcs, stops and turns on the spot; this project's firmware pipeline as
the recorder unless ``--recorder`` says otherwise), then runs ``python -m host_tools analyze``
on each case in a process of its own and prints, per case: the recording's length, the
verdict, the back-EMF ratio found, the wall time, the CPU time of the analyzer and its worker
processes (on a machine shared with other jobs the wall time varies; with 2 workers on 2 cores
CPU/2 is what an idle machine's wall time approaches) and the peak resident memory of any one
analyzer process, against the targets (10 minutes of recording analyzed in at most 60 s with at most
1 GB).  The seeds are this benchmark's own (not the suite's held-back set's)."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
sys.path.insert(0, ROOT)

TIME_TARGET_S = 60.0
MEMORY_TARGET_MB = 1024.0
# (name, runs, seconds per run, effects)
CASES = [
    ("null_20s", 2, 20.0, {}),
    ("emf_20s", 2, 20.0, {"motor_back_emf": {"ke_ratio": 1.15}}),
    ("null_2min", 2, 60.0, {}),
    ("emf_2min", 2, 60.0, {"motor_back_emf": {"ke_ratio": 1.15}}),
    ("null_10min", 2, 300.0, {}),
    ("emf_10min", 2, 300.0, {"motor_back_emf": {"ke_ratio": 1.15}}),
]
SEED = 7100


def _analyze(paths: list[str], out: str, jobs: int) -> tuple[dict, float, float, float]:
    """Run the analyzer in a child process: (report, wall time, CPU time of the analyzer and
    its workers, peak RSS of any one of those processes in MB)."""
    cmd = [sys.executable, "-m", "host_tools", "analyze", *paths, "--out", out, "--no-plots",
           "--jobs", str(jobs)]
    # peak RSS over this child and its worker processes: measured in a wrapper process so that
    # earlier cases do not count (RUSAGE_CHILDREN keeps the maximum of every waited child)
    wrapper = ("import resource, subprocess, sys; rc = subprocess.call(sys.argv[1:], "
               "stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL); "
               "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
               "print(u.ru_utime + u.ru_stime, u.ru_maxrss); sys.exit(rc)")
    t0 = time.time()
    res = subprocess.run([sys.executable, "-c", wrapper, *cmd], capture_output=True, text=True,
                         cwd=ROOT)
    dt = time.time() - t0
    try:
        cpu_s, rss_kb = (float(v) for v in res.stdout.strip().splitlines()[-1].split())
    except (ValueError, IndexError):
        cpu_s, rss_kb = float("nan"), float("nan")
    rss_mb = rss_kb / 1024.0
    try:
        with open(os.path.join(out, "report.json")) as fh:
            rep = json.load(fh)
    except (OSError, ValueError):
        rep = {"verdict": f"failed (exit {res.returncode})"}
    return rep, dt, cpu_s, rss_mb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/bench_long.py",
                                 description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=",".join(c[0] for c in CASES),
                    help="comma-separated case names")
    ap.add_argument("--recorder", default=None, help="a recorder profile of the truth simulator")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--keep", default=None, help="keep the generated runs and reports here")
    ap.add_argument("--seed", type=int, default=SEED,
                    help=f"first seed of the recordings (default {SEED}; other seeds are other "
                         "tuning draws, never the suite's held-back seeds)")
    args = ap.parse_args(argv)
    from host_tools import truth
    from host_tools.suite.cases import RECORDERS

    rec = RECORDERS[args.recorder] if args.recorder else None
    root = args.keep or tempfile.mkdtemp(prefix="analyzer-bench-long-")
    want = args.cases.split(",")
    ok_all = True
    print(f"{'case':12s} {'recorded':>9s} {'verdict':12s} {'ke_ratio':>8s} {'wall':>7s} "
          f"{'CPU':>7s} {'peak RSS':>9s}  targets (wall time on a shared machine: see CPU/2)")
    for name, n_runs, dur, eff in CASES:
        if name not in want:
            continue
        paths = []
        for k in range(n_runs):
            p = os.path.join(root, name, f"run-{k}")
            truth.simulate_run(p, {"kind": "tour"}, eff, clamp=True, duration_s=dur,
                               seed=args.seed + 17 * k + len(name), overwrite=True, recorder=rec)
            paths.append(p)
        rep, dt, cpu, rss = _analyze(paths, os.path.join(root, name, "report"), args.jobs)
        expect = "explained" if eff else "no_mismatch"
        ke = next((s["params"].get("ke_ratio") for s in rep.get("selected", [])
                   if s["effect"] == "motor_back_emf"), None)
        if ke is None and eff:
            ke = next((c["params"].get("ke_ratio") for c in rep.get("candidates", [])
                       if c["effect"] == "motor_back_emf"), None)
        named = (not eff) or any(s["effect"] == "motor_back_emf" or "motor_back_emf" in
                                 s.get("equivalent", []) for s in rep.get("selected", []))
        total_min = n_runs * dur / 60.0
        limit = TIME_TARGET_S * max(total_min / 10.0, 1.0) if total_min >= 10 else TIME_TARGET_S
        ok = rep.get("verdict") == expect and named and dt <= limit and rss <= MEMORY_TARGET_MB
        ok_all &= ok
        print(f"{name:12s} {total_min:7.2f} m {rep.get('verdict', '?'):12s} "
              f"{'-' if ke is None else f'{ke:.3f}':>8s} {dt:6.1f}s {cpu:6.1f}s {rss:7.0f}MB  "
              f"{'ok' if ok else 'MISSED'} (verdict {expect}, <= {limit:.0f} s, "
              f"<= {MEMORY_TARGET_MB:.0f} MB)", flush=True)
    print(f"\nruns and reports under {root}; {os.cpu_count()} cores, --jobs {args.jobs}")
    return 0 if ok_all else 1


if __name__ == "__main__":
    sys.exit(main())
