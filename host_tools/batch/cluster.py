"""A Dask cluster of separate processes on this machine (``dask scheduler`` and ``dask worker``,
as on a real cluster, all on 127.0.0.1): for the distributed test and the benchmark."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class ProcessCluster:
    """``with ProcessCluster(2) as c: c.address``; ``c.kill_worker(i)`` kills worker ``i``
    and its nanny at once (SIGKILL to its process group)."""

    def __init__(self, workers: int = 2, memory_limit: str = "1GiB", log: str | None = None,
                 timeout_s: float = 120.0):
        self.n, self.memory_limit, self.timeout_s = workers, memory_limit, timeout_s
        self._dir = tempfile.mkdtemp(prefix="ddbatch-cluster-")
        self._log = open(log or os.path.join(self._dir, "cluster.log"), "w")
        self.scheduler: subprocess.Popen | None = None
        self.workers: list[subprocess.Popen] = []
        self.address = ""

    def _start(self, *args: str) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT,
                                stdout=self._log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True,
                                env=dict(os.environ, PYTHONPATH=ROOT))

    def __enter__(self) -> "ProcessCluster":
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        sched_file = os.path.join(self._dir, "scheduler.json")
        self.scheduler = self._start("scheduler", "--host", "127.0.0.1", "--port", "0",
                                     "--no-dashboard", "--scheduler-file", sched_file)
        t0 = time.monotonic()
        while not os.path.isfile(sched_file):
            if self.scheduler.poll() is not None or time.monotonic() - t0 > self.timeout_s:
                raise RuntimeError(f"the dask scheduler did not start (log: {self._log.name})")
            time.sleep(0.2)
        time.sleep(0.2)  # the file is written whole, but give it a moment
        with open(sched_file) as fh:
            self.address = json.load(fh)["address"]
        for k in range(self.n):
            self.workers.append(self._start(
                "worker", self.address, "--host", "127.0.0.1", "--nthreads", "1",
                "--nworkers", "1", "--memory-limit", self.memory_limit, "--no-dashboard",
                "--name", f"w{k}", "--death-timeout", "60"))
        from dask.distributed import Client
        with Client(self.address, timeout=f"{self.timeout_s:g}s") as c:
            c.wait_for_workers(self.n, timeout=self.timeout_s)

    @staticmethod
    def _kill(proc: subprocess.Popen) -> None:
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.wait(timeout=30)

    def kill_worker(self, i: int) -> None:
        self._kill(self.workers[i])

    def stop(self) -> None:
        for p in reversed(self.workers + ([self.scheduler] if self.scheduler else [])):
            self._kill(p)
        self._log.close()
