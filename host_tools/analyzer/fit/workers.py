"""The fits of the candidate effects, run in a pool of worker processes that each hold the fit
problem."""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from typing import TYPE_CHECKING, Mapping

from host_tools import _progress
from host_tools.analyzer import lines, log
from host_tools.analyzer.fit.judge import Candidate, evaluate_candidate
from host_tools.analyzer.fit.problem import Problem

if TYPE_CHECKING:
    from concurrent.futures import Executor

    import numpy as np

    # (effects to fit, start coordinates or None, effects the candidate is compared with)
    FitTask = tuple[list[str], np.ndarray | None, Mapping[str, Mapping[str, float]]]


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


def _eval_task(args: FitTask) -> tuple[Candidate, float]:
    names, x0, ref_effects = args
    assert _PROBLEM is not None  # _init_worker set it in this process
    t0 = time.time()
    cand = evaluate_candidate(_PROBLEM, names, x0=x0, ref_effects=ref_effects)
    return cand, time.time() - t0


def _stop_workers(ex: Executor) -> None:
    """End the pool's worker processes at once (an interrupted analysis must not wait for
    their fits).  ProcessPoolExecutor has no public way to do so before Python 3.14
    (``terminate_workers``): its process table is used when that method is missing."""
    stop = getattr(ex, "terminate_workers", None)
    if stop is not None:
        stop()
        return
    for p in list((getattr(ex, "_processes", None) or {}).values()):
        try:
            p.terminate()
        except (OSError, ValueError, AttributeError):
            pass


def _end_pool(ex: Executor) -> None:
    """Stop the pool's workers and wait (bounded) for its manager thread to end.  Without the
    wait, the interpreter's exit hook of concurrent.futures may wake the manager thread while it
    closes its pipe, and the analysis that a signal ended cleanly would end in a traceback
    ("Bad file descriptor") after its message."""
    manager = getattr(ex, "_executor_manager_thread", None)  # shutdown() forgets it
    _stop_workers(ex)
    ex.shutdown(wait=False, cancel_futures=True)
    if manager is not None:
        manager.join(10.0)


def run_tasks(problem: Problem, tasks: list[FitTask], jobs: int, label: str) -> list[Candidate]:
    """Fit ``tasks`` (candidate effects) with ``jobs`` worker processes; the candidates in the
    order of ``tasks``.  A worker that dies (the out-of-memory killer's SIGKILL, a SIGTERM sent
    to it alone) breaks the pool: every fit of a task the pool had not returned is then done
    here, in this process, one after the other, and the analysis goes on (a message on stderr
    says so) instead of waiting for ever for the dead worker's result."""
    with _progress.Progress(len(tasks), f"fitting {label}s", unit=label, logger=log,
                            emit=lines, leave=False) as bar:
        return _run_tasks(problem, tasks, jobs, label, bar)


def _run_tasks(problem: Problem, tasks: list[FitTask], jobs: int, label: str,
               bar: _progress.Progress) -> list[Candidate]:
    out: list[Candidate] = []
    if jobs <= 1 or len(tasks) <= 1:
        _init_worker(problem)
        for i, task in enumerate(tasks, 1):
            cand, dt = _eval_task(task)
            out.append(cand)
            bar.step(f"{label} {i}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s")
        return out
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("fork")
    ex = ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_init_worker,
                             initargs=(problem,))
    done: dict[int, Candidate] = {}
    broken = None
    try:
        futures = {ex.submit(_eval_task, t): k for k, t in enumerate(tasks)}
        pending = set(futures)
        while pending and broken is None:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in finished:
                try:
                    cand, dt = f.result()
                except BrokenProcessPool as exc:
                    broken = exc
                    continue
                done[futures[f]] = cand
                bar.step(f"{label} {len(done)}/{len(tasks)}: {cand.name} fitted in "
                         f"{dt:.1f} s")
    except BaseException:
        _end_pool(ex)
        raise
    if broken is not None:
        _end_pool(ex)
        left = [k for k in range(len(tasks)) if k not in done]
        log.warning(f"a fitting worker process died ({broken}); fitting the {len(left)} "
                    f"{label}(s) it left here, in this process, one after the other")
        _init_worker(problem)
        for k in left:
            cand, dt = _eval_task(tasks[k])
            done[k] = cand
            bar.step(f"{label} {len(done)}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s "
                     "(in-process, after the worker died)")
    else:
        ex.shutdown(wait=True)
    return [done[k] for k in range(len(tasks))]
