"""The fits of the candidate effects, run in a pool of worker processes that each hold the fit
problem."""
from __future__ import annotations

import multiprocessing as mp
import os
import time

from host_tools._stdio import say
from host_tools.analyzer.fit.judge import Candidate, evaluate_candidate
from host_tools.analyzer.fit.problem import Problem


class WorkerDied(RuntimeError):
    """A fitting worker process ended without a result (SIGKILL from the out-of-memory
    killer, a signal to that one process): the analysis cannot be completed."""


def log_stderr(msg: str) -> None:
    say(f"[analyze {time.strftime('%H:%M:%S')}] {msg}")  # a closed pipe never ends the analysis


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
    # concurrent.futures notices a worker that died without a result (BrokenProcessPool);
    # multiprocessing.Pool would wait for its result for ever
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ex = ProcessPoolExecutor(jobs, mp_context=mp.get_context("fork"), initializer=_init_worker,
                             initargs=(problem,))
    try:
        pending = {ex.submit(_eval_task, t) for t in tasks}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                try:
                    cand, dt = fut.result()
                except BrokenProcessPool:
                    raise WorkerDied("a fitting worker process ended without its result (killed: "
                                     "by the out-of-memory killer or a signal to that process); "
                                     "nothing was written. Run again, with fewer --jobs if memory "
                                     "is short") from None
                out.append(cand)
                log_stderr(f"{label} {len(out)}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s")
    finally:
        procs = list(getattr(ex, "_processes", {}).values())  # end the workers at once, as
        ex.shutdown(wait=False, cancel_futures=True)          # Pool.terminate() did
        for proc in procs:
            if proc.is_alive():
                proc.terminate()
        for proc in procs:
            proc.join(5)
    order = {tuple(t[0]): i for i, t in enumerate(tasks)}
    out.sort(key=lambda c: order[tuple(c.effects)])
    return out
