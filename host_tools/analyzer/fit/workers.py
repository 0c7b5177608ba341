"""The fits of the candidate effects, run in a pool of worker processes that each hold the fit
problem."""
from __future__ import annotations

import multiprocessing as mp
import os
import sys
import time

from host_tools.analyzer.fit.judge import Candidate, evaluate_candidate
from host_tools.analyzer.fit.problem import Problem


def log_stderr(msg: str) -> None:
    print(f"[analyze {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


_PROBLEM: Problem | None = None

_MAIN_PID = os.getpid()


def _init_worker(problem: Problem) -> None:
    global _PROBLEM
    _PROBLEM = problem
    if os.getpid() != _MAIN_PID:
        # A worker ends at once on the pool's SIGTERM, whatever C code it is in: a Python-level
        # handler inherited from the command line (which turns signals into a clean exit of the
        # main process) runs only between bytecodes, and a worker that never gets there would
        # keep Pool.terminate() waiting for ever.  Ctrl-C is the main process's to handle.
        import signal
        for name in ("SIGTERM", "SIGHUP"):
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _eval_task(args):
    names, x0, ref_effects = args
    t0 = time.time()
    cand = evaluate_candidate(_PROBLEM, names, x0=x0, ref_effects=ref_effects)
    return cand, time.time() - t0


def run_tasks(problem: Problem, tasks: list, jobs: int, label: str) -> list[Candidate]:
    out: list[Candidate] = []
    if jobs <= 1 or len(tasks) <= 1:
        _init_worker(problem)
        for i, task in enumerate(tasks, 1):
            cand, dt = _eval_task(task)
            out.append(cand)
            log_stderr(f"{label} {i}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s")
        return out
    ctx = mp.get_context("fork")
    with ctx.Pool(jobs, initializer=_init_worker, initargs=(problem,)) as pool:
        for i, (cand, dt) in enumerate(pool.imap_unordered(_eval_task, tasks), 1):
            out.append(cand)
            log_stderr(f"{label} {i}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s")
    order = {tuple(t[0]): i for i, t in enumerate(tasks)}
    out.sort(key=lambda c: order[tuple(c.effects)])
    return out
