"""One batch task: analyze one run set in a subprocess and write its result atomically.

:func:`analyze_set` runs on a Dask worker (or anywhere).  It calls the analyzer only through
its public entry, ``python -m host_tools analyze RUN... --out DIR``, in a subprocess that

* has its own memory limit (``RLIMIT_AS``, ``mem_mb``): a runaway analysis fails alone;
* has a wall-time limit (``timeout_s``): past it its process group is killed;
* dies with the worker (``PR_SET_PDEATHSIG``, set by :mod:`host_tools.batch._launch`): a
  killed worker leaves no analysis running that would race the task's redo.

The outputs go to ``OUT/.partial/<id>.<random>/`` and the finished folder (the analyzer's
report.json, report.md, model.json, plots, plus ``result.json``, the batch's record) is
renamed into ``OUT/<set_id>/`` in one step, so ``OUT/<set_id>/result.json`` exists only
for a set whose outputs are complete.  A failure (analyzer exit 1 or 2, timeout, killed by
the memory limit) is recorded the same way, with its error.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RESULT = "result.json"
RESULT_FORMAT = "ddbatch-result/1"
#: statuses a re-run does not redo (a bad input stays bad until its files change)
FINAL = ("ok", "bad_input")


def _tree_peak(proc: subprocess.Popen, timeout_s: float | None) -> tuple[float, bool]:
    """Wait for ``proc``, sampling the resident memory of its process tree every 0.2 s;
    returns (peak MB, timed out).  Past ``timeout_s`` its process group is killed."""
    import psutil  # a dependency of distributed
    t0 = time.monotonic()
    peak = 0
    try:
        ps = psutil.Process(proc.pid)
    except psutil.Error:
        ps = None
    while proc.poll() is None:
        if ps is not None:
            try:
                rss = ps.memory_info().rss + sum(c.memory_info().rss
                                                 for c in ps.children(recursive=True))
                peak = max(peak, rss)
            except psutil.Error:
                pass
        if timeout_s is not None and time.monotonic() - t0 > timeout_s:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
            return peak / 2 ** 20, True
        try:
            proc.wait(timeout=0.2)
        except subprocess.TimeoutExpired:
            pass
    return peak / 2 ** 20, False


def read_result(out_root: str, set_id: str) -> dict | None:
    """The stored record of a set, or None (missing or unreadable: not done)."""
    try:
        with open(os.path.join(out_root, set_id, RESULT)) as fh:
            rec = json.load(fh)
        return rec if rec.get("format") == RESULT_FORMAT else None
    except (OSError, ValueError):
        return None


def is_done(out_root: str, runset) -> bool:
    """Analyzed before (ok, or bad input) from the same recordings."""
    rec = read_result(out_root, runset.set_id)
    return bool(rec and rec.get("status") in FINAL and
                rec.get("fingerprint") == runset.fingerprint())


def _summary(report: dict) -> dict:
    """What the fleet table takes from a report.json."""
    return {"verdict": report.get("verdict"),
            "selected": report.get("selected") or [],
            "candidates": [{"effect": c.get("effect"), "params": c.get("params") or {},
                            "param_std": c.get("param_std") or {}}
                           for c in report.get("candidates") or []],
            "fit": {k: (report.get("fit") or {}).get(k) for k in
                    ("normalized_rms_before", "normalized_rms_after", "rmse_before",
                     "rmse_after", "noise_floor")},
            "elapsed_s": report.get("elapsed_s")}


def analyze_set(runset, out_root: str, timeout_s: float | None = 600.0,
                mem_mb: float | None = 4096.0, jobs: int = 1,
                analyzer_args: list[str] | None = None) -> dict:
    """Analyze ``runset`` (a :class:`host_tools.batch.sets.RunSet`) into
    ``out_root/<set_id>/``; returns the record written to its result.json:
    ``status`` ok | failed (analyzer exit 1 or a signal) | timeout | bad_input (exit 2),
    ``rc``, ``error`` (the end of the analyzer's stderr), ``wall_s``, ``peak_rss_mb``,
    ``worker``, and the report's summary.  Never raises for a failed analysis."""
    set_id = runset.set_id
    partial = os.path.join(out_root, ".partial")
    os.makedirs(partial, exist_ok=True)
    tmp = os.path.join(partial, f"{set_id.replace('/', '~')}.{uuid.uuid4().hex[:12]}")
    os.makedirs(tmp)
    cmd = [sys.executable, "-m", "host_tools", "analyze", *runset.runs, "--out", tmp,
           "--jobs", str(jobs), *(analyzer_args or [])]
    launch = [sys.executable, "-m", "host_tools.batch._launch", str(os.getpid()),
              str(mem_mb or 0), "--", *cmd]
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env["PYTHONPATH"] = ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    rec = {"format": RESULT_FORMAT, **runset.to_dict(), "fingerprint": runset.fingerprint(),
           "worker": f"{socket.gethostname()}:{os.getpid()}",
           "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    t0 = time.monotonic()
    err_path = os.path.join(tmp, "analyzer.log")
    with open(err_path, "w+b") as log:
        try:
            proc = subprocess.Popen(launch, cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True)
            peak_mb, timed_out = _tree_peak(proc, timeout_s)
            rc = proc.returncode
        except OSError as exc:
            peak_mb, timed_out, rc = 0.0, False, None
            log.write(f"error: cannot start the analyzer: {exc}\n".encode())
        log.seek(0)
        tail = log.read()[-4000:].decode("utf-8", "replace")
    rec.update(rc=rc, wall_s=round(time.monotonic() - t0, 3), peak_rss_mb=round(peak_mb, 1))
    report = None
    if timed_out:
        rec.update(status="timeout", error=f"stopped after {timeout_s:g} s (--timeout)")
    elif rc == 0:
        try:
            with open(os.path.join(tmp, "report.json")) as fh:
                report = json.load(fh)
            rec.update(status="ok", error=None)
        except (OSError, ValueError) as exc:
            rec.update(status="failed", error=f"exit 0 but no readable report.json: {exc}")
    elif rc == 2:
        rec.update(status="bad_input", error=_last_error(tail))
    else:
        why = (f"killed by signal {signal.Signals(-rc).name}" if rc is not None and rc < 0
               else f"exit {rc}")
        if mem_mb and rc is not None and ("MemoryError" in tail or "Cannot allocate" in tail):
            why += f" (out of memory at the {mem_mb:g} MB limit)"
        rec.update(status="failed", error=f"{why}: {_last_error(tail)}")
    if report is not None:
        rec["report"] = _summary(report)
    with open(os.path.join(tmp, RESULT), "w") as fh:
        json.dump(rec, fh, indent=1)
    _publish(tmp, os.path.join(out_root, set_id), partial)
    return rec


def _last_error(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    errs = [ln for ln in lines if ln.startswith("error") or "Error" in ln]
    return (errs[-1] if errs else lines[-1] if lines else "no output")[-500:]


def _publish(tmp: str, dest: str, partial: str) -> None:
    """Move the finished folder ``tmp`` to ``dest`` (replacing an older result)."""
    os.makedirs(os.path.dirname(dest), exist_ok=True)
    old = None
    if os.path.exists(dest):
        old = f"{tmp}.old"
        os.rename(dest, old)
    try:
        os.rename(tmp, dest)
    except OSError:  # a concurrent copy of this task published first: keep it
        shutil.rmtree(tmp, ignore_errors=True)
    if old:
        shutil.rmtree(old, ignore_errors=True)


def clean_partial(out_root: str, older_than_s: float) -> int:
    """Remove leftovers of attempts that died (workers killed) older than ``older_than_s``."""
    partial = os.path.join(out_root, ".partial")
    n = 0
    if os.path.isdir(partial):
        now = time.time()
        for d in os.listdir(partial):
            p = os.path.join(partial, d)
            try:
                if now - os.stat(p).st_mtime > older_than_s:
                    shutil.rmtree(p, ignore_errors=True)
                    n += 1
            except OSError:
                pass
    return n
