"""The batch on Dask: one task per run set, on a LocalCluster started here (default) or on
an existing cluster (``scheduler`` address).

A task that raises (it should not: :func:`host_tools.batch.task.analyze_set` records every
analysis failure) or whose worker died more often than the scheduler allows
(``distributed.scheduler.allowed-failures``) is recorded as ``lost`` with the error; the
batch goes on.  A worker that dies mid-task has its tasks redone on another worker by the
scheduler.  Sets already done (``task.is_done``) are skipped unless ``redo``.
"""
from __future__ import annotations

import logging
import os
import time
from typing import Callable, Sequence

from host_tools import _progress
from host_tools.batch import task as T
from host_tools.batch.sets import RunSet

log = logging.getLogger(__name__)

#: default Dask worker memory limit of the local cluster (the analysis itself runs in a
#: subprocess bounded by ``mem_mb``)
WORKER_MEMORY = "1GiB"


def _client(scheduler: str | None, workers: int, worker_memory: str):
    from dask.distributed import Client, LocalCluster
    if scheduler:
        return Client(scheduler, timeout="30s"), None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           memory_limit=worker_memory, host="127.0.0.1",
                           dashboard_address=None, silence_logs=40,
                           # no dashboard; the scheduler's HTTP endpoints on a free local port
                           scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    return Client(cluster), cluster


def run_batch(sets: Sequence[RunSet], out_root: str, scheduler: str | None = None,
              workers: int = 2, worker_memory: str = WORKER_MEMORY,
              timeout_s: float | None = 600.0, mem_mb: float | None = 4096.0, jobs: int = 1,
              analyzer_args: list[str] | None = None, redo: bool = False,
              progress: Callable[[str], None] | None = None) -> tuple[list[dict], dict]:
    """Analyze ``sets`` into ``out_root``; returns (one record per set, in the order of
    ``sets``; stats: done, skipped, failed, wall_s, workers)."""
    from dask.distributed import as_completed

    say = progress or (lambda s: log.log(_progress.STATUS, "%s", s))
    out_root = os.path.abspath(out_root)
    os.makedirs(out_root, exist_ok=True)
    if timeout_s:
        T.clean_partial(out_root, older_than_s=2 * timeout_s + 60)
    todo = [s for s in sets if redo or not T.is_done(out_root, s)]
    skipped = len(sets) - len(todo)
    if skipped:
        say(f"batch: {skipped} of {len(sets)} run set(s) already done, skipped")
    records: dict[str, dict] = {}
    t0 = time.monotonic()
    n_workers = 0
    if todo:
        client, cluster = _client(scheduler, workers, worker_memory)
        try:
            n_workers = len(client.scheduler_info().get("workers", {}))
            say(f"batch: {len(todo)} run set(s) on {n_workers} worker(s) at "
                f"{client.scheduler.address}")
            futs = {}
            for s in todo:
                f = client.submit(T.analyze_set, s, out_root, timeout_s, mem_mb, jobs,
                                  analyzer_args, key=f"analyze-{s.set_id}-{os.urandom(4).hex()}",
                                  pure=False)
                futs[f] = s
            n_ok = n_bad = 0
            bar = _progress.Progress(len(todo), "batch", unit="set", logger=log, emit=say)
            for k, f in enumerate(as_completed(futs), start=1):
                s = futs[f]
                try:
                    rec = f.result()
                except Exception as exc:  # noqa: BLE001  (KilledWorker, a crash in the task)
                    rec = {"format": T.RESULT_FORMAT, **s.to_dict(), "status": "lost",
                           "rc": None, "error": f"{type(exc).__name__}: {exc}"[:500]}
                records[s.set_id] = rec
                if rec["status"] == "ok":
                    n_ok += 1
                else:
                    n_bad += 1
                el = time.monotonic() - t0
                eta = el / k * (len(todo) - k)
                what = (rec.get("report") or {}).get("verdict") if rec["status"] == "ok" \
                    else f"{rec['status'].upper()}: {rec.get('error')}"
                bar.step(f"[{k}/{len(todo)}] {s.set_id}: {what} ({rec.get('wall_s', 0):.1f} s) "
                         f"- {n_ok} ok, {n_bad} failed, {el:.0f} s elapsed, ~{eta:.0f} s left")
            bar.close()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    wall = time.monotonic() - t0
    out = []
    for s in sets:
        rec = records.get(s.set_id) or T.read_result(out_root, s.set_id) or \
            {"format": T.RESULT_FORMAT, **s.to_dict(), "status": "lost", "rc": None,
             "error": "no result"}
        out.append(rec)
    stats = {"sets": len(sets), "run": len(todo), "skipped": skipped,
             "failed": sum(1 for r in out if r.get("status") != "ok"), "wall_s": wall,
             "workers": n_workers}
    return out, stats
