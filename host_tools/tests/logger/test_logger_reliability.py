"""The logger on signals, full disks, bursts interrupted by Ctrl-C and an unusable --out."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
from pathlib import Path

import pytest

from host_tools import logger as L
from host_tools import protocol as P
from host_tools import runfmt
from host_tools.logger import link as logger_link
from host_tools.logger import runfolder as logger_files
from host_tools.logger.reference import ReferenceTracker
from host_tools.runfmt import write as runfmt_write
from test_logger import (ScriptedPort, _args, events, log_until_rows_then_signal, rows,
                         telemetry)

ROOT = Path(__file__).resolve().parents[3]
D = P.definition()


def _frames_in(raw: bytes) -> list:
    dec = P.StreamDecoder(D.version, D.max_payload)
    return dec.feed(raw)


def _check_complete(out: Path, end_reason: str, raw_complete: bool = True):
    """The folder after a stop: meta.json final and consistent with the files.  After a
    write failure raw.bin may lack the tail that did not fit (its frames were decoded and
    counted from memory)."""
    meta = json.loads((out / "meta.json").read_text())
    lg = meta["logger"]
    assert lg["end_reason"] == end_reason
    run = rows(out)
    assert lg["telemetry_rows"] == run.telemetry["t_s"].size > 0
    ev = events(out)
    assert ev[-1]["kind"] == "end" and ev[-1]["reason"] == end_reason
    # raw.bin complete: the frames meta.json counts are all in it (the robot's frames)
    frames = _frames_in((out / "raw.bin").read_bytes())
    tel = [f for f in frames if f.type == D.by_name["Telemetry"].type]
    if raw_complete:
        assert len(tel) >= lg["telemetry_rows"] and lg["frames"] == len(frames)
    else:
        assert lg["frames"] >= len(frames)
    assert not (out / "meta.json.tmp").exists() and not list(out.glob(".*.tmp"))
    assert not (out / L.RESERVE_NAME).exists()
    return meta


@pytest.mark.parametrize("sig, reason", [(signal.SIGTERM, "stopped by SIGTERM"),
                                         (signal.SIGHUP, "stopped by SIGHUP"),
                                         (signal.SIGINT, "interrupted (Ctrl-C)")])
def test_signals_stop_like_ctrl_c_end_to_end(tmp_path, sig, reason):
    out = tmp_path / "run"
    rc, err = log_until_rows_then_signal(out, sig, min_rows=30, extra=["--quiet"], period=0.005)
    assert rc == 0, err
    assert "Traceback" not in err
    _check_complete(out, reason)


def _burst(n=60, t0=1_000_000):
    return b"".join(telemetry(i, t0 + 20_000 * i) for i in range(n))


def _sigint_at_rows(monkeypatch, at: set[int]) -> None:
    """A real SIGINT to this process while the n-th row (n in ``at``) is being written."""
    real = runfmt.RunWriter.write_row
    state = {"n": 0}

    def write_row(self, row):
        state["n"] += 1
        if state["n"] in at:
            os.kill(os.getpid(), signal.SIGINT)
        return real(self, row)
    monkeypatch.setattr(runfmt.RunWriter, "write_row", write_row)


def test_ctrl_c_during_a_burst_writes_every_verified_frame(tmp_path, monkeypatch):
    """SIGINT arrives while the 10th of 60 frames read in one chunk is being written."""
    port = ScriptedPort(_burst(60), [60 * 200])
    _sigint_at_rows(monkeypatch, {10})
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=5, status=False)
    assert lg.run() == 0
    assert lg.dec.frames == 60
    assert rows(out).telemetry["seq"].astype(int).tolist() == list(range(60))
    _check_complete(out, "interrupted (Ctrl-C)")


def test_second_ctrl_c_during_a_burst_still_counts_every_frame(tmp_path, monkeypatch):
    """Two signals: the second interrupts the handling of a frame at once; close() handles the
    rest.  Each of the 60 verified frames is a row or counted (as a duplicate)."""
    port = ScriptedPort(_burst(60), [60 * 200])
    _sigint_at_rows(monkeypatch, {10, 20})
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=5, status=False)
    assert lg.run() == 0
    s = lg.stats
    assert s["telemetry_rows"] + s["duplicates"] + s["stale"] >= 60
    assert rows(out).telemetry["seq"].astype(int).tolist() == list(range(60))


def _two_sigints_in(monkeypatch, owner, name: str, at: int) -> None:
    """Two real SIGINTs to this process inside the ``at``-th call of ``owner.name``: the
    first asks the session to stop, the second lands in the middle of the work."""
    real = getattr(owner, name)
    state = {"n": 0}

    def hooked(self, *args):
        state["n"] += 1
        if state["n"] == at:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
        return real(self, *args)
    monkeypatch.setattr(owner, name, hooked)


@pytest.mark.parametrize("owner, name", [
    (ReferenceTracker, "row"),  # a row written, the frame's handling not finished
    (P.StreamDecoder, "feed"),  # the bytes in raw.bin, not yet decoded
    (runfmt.RunWriter, "write_row")])  # before the row is written
def test_a_second_signal_never_tears_a_frame(tmp_path, monkeypatch, owner, name):
    """However a second signal cuts into the handling of the input, every verified frame is
    a row exactly once, the recording ends as interrupted and the exit code is 0."""
    n = len(telemetry(0, 0))
    port = ScriptedPort(_burst(60), [60 * n])  # one read: 60 frames
    _two_sigints_in(monkeypatch, owner, name, 1 if name == "feed" else 10)
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=5, status=False)
    assert lg.run() == 0
    assert lg.dec.frames == 60
    assert rows(out).telemetry["seq"].astype(int).tolist() == list(range(60))
    assert lg.stats["gaps"] == lg.stats["duplicates"] == lg.stats["stale"] == 0
    _check_complete(out, "interrupted (Ctrl-C)")


class FullDisk:
    """A file system with ``free`` bytes: a write that does not fit writes what fits and
    raises ENOSPC, like a real full disk; removing a file frees what was written to it."""

    def __init__(self, monkeypatch, free: int):
        self.free = free
        self.sizes: dict[str, int] = {}
        real_open, real_remove = open, os.remove
        disk = self

        class F:
            def __init__(self, path, mode, **kw):
                self.path = os.path.abspath(path) if not isinstance(path, int) else f"fd {path}"
                self.fh = real_open(path, mode, **kw)
                self.text = "b" not in mode
                disk.sizes.setdefault(self.path, 0)

            def write(self, data):
                b = data.encode() if self.text else bytes(data)
                if len(b) > disk.free:
                    part = b[:disk.free]
                    self.fh.write(part.decode(errors="ignore") if self.text else part)
                    self.fh.flush()
                    disk.sizes[self.path] += len(part)
                    disk.free = 0
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                disk.free -= len(b)
                disk.sizes[self.path] += len(b)
                return self.fh.write(data)

            def __getattr__(self, name):
                return getattr(self.fh, name)

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.fh.close()

        def fake_open(path, mode="r", **kw):
            if any(c in mode for c in "wa"):
                return F(path, mode, **kw)
            return real_open(path, mode, **kw)

        def fake_remove(path):
            real_remove(path)
            disk.free += disk.sizes.pop(os.path.abspath(path), 0)

        for mod in (logger_files, runfmt_write):  # every module that opens a file to write
            monkeypatch.setattr(mod, "open", fake_open, raising=False)
        monkeypatch.setattr(os, "remove", fake_remove)


def test_disk_full_stops_with_exit_1_and_a_readable_run(tmp_path, monkeypatch, capsys):
    FullDisk(monkeypatch, free=L.RESERVE_BYTES + 20_000)
    port = ScriptedPort(_burst(2000), [900])
    out = tmp_path / "run"
    monkeypatch.setattr(logger_link, "FLUSH_EVERY_S", 0.0)
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=0.05,
                  status=False)
    assert lg.run() == 1
    meta = _check_complete(out, "write failed: No space left on device", raw_complete=False)
    # every line of the text files is whole
    assert (out / "telemetry.csv").read_bytes().endswith(b"\n")
    for line in (out / "events.jsonl").read_text().splitlines():
        json.loads(line)
    n = rows(out).telemetry["t_s"].size
    assert 0 < n < 2000 and meta["logger"]["telemetry_rows"] == n


def test_disk_full_through_the_cli(tmp_path, monkeypatch, capsys):
    FullDisk(monkeypatch, free=L.RESERVE_BYTES + 20_000)
    port = ScriptedPort(_burst(2000), [900])
    import serial
    monkeypatch.setattr(serial, "serial_for_url", lambda *a, **k: port)
    monkeypatch.setattr(logger_link, "FLUSH_EVERY_S", 0.0)
    rc = L.main(_args(["--port", "scripted", "--out", str(tmp_path / "run"), "--quiet"]))
    err = capsys.readouterr().err
    assert rc == 1
    assert "error: write failed: No space left on device" in err and "Traceback" not in err


def _can_mount_tmpfs(where: Path) -> bool:
    where.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=640k", "tmpfs", str(where)],
                       capture_output=True)
    return r.returncode == 0


def test_disk_full_on_a_real_small_tmpfs(tmp_path):
    mnt = tmp_path / "small"
    if not _can_mount_tmpfs(mnt):
        pytest.skip("cannot mount a tmpfs here (needs root); the injected ENOSPC tests cover it")
    try:
        port = ScriptedPort(_burst(6000, t0=0), [4000])
        out = mnt / "run"
        lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=0.05,
                      status=False)
        assert lg.run() == 1
        meta = _check_complete(out, "write failed: No space left on device", raw_complete=False)
        assert meta["logger"]["telemetry_rows"] > 100
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.parametrize("how", ["existing file", "below a file", "recorded run"])
def test_unusable_out_exit_2_before_the_port_is_opened(tmp_path, capsys, monkeypatch, how):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out = {"existing file": blocker, "below a file": blocker / "run",
           "recorded run": tmp_path / "old"}[how]
    if how == "recorded run":
        out.mkdir()
        (out / "raw.bin").write_bytes(b"")
    import serial
    monkeypatch.setattr(serial, "serial_for_url",
                        lambda *a, **k: pytest.fail("the port was opened"))
    rc = L.main(_args(["--port", "loop://", "--out", str(out), "--quiet"]))
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert ("--out" in err) or ("already exists" in err), err
    assert not (blocker.is_dir())


def test_a_row_write_failing_once_is_not_retried_into_a_repeated_time(tmp_path, monkeypatch):
    """The disk fills while the 30th row is written (and has room again at once, as after the
    reserve is freed): the queued frames are counted as not written, never retried (a retried
    row made 'time does not increase' escape from close())."""
    real = runfmt.RunWriter.write_row
    state = {"n": 0}

    class FailOnce:
        def __init__(self, fh):
            self.fh, self.failed = fh, False

        def write(self, data):
            if not self.failed:
                self.failed = True
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return self.fh.write(data)

        def __getattr__(self, name):
            return getattr(self.fh, name)

    def write_row(self, row):
        state["n"] += 1
        if state["n"] == 30:
            self._fh = FailOnce(self._fh)
        return real(self, row)
    monkeypatch.setattr(runfmt.RunWriter, "write_row", write_row)
    port = ScriptedPort(_burst(60), [60 * 200])
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=5, status=False)
    assert lg.run() == 1
    meta = _check_complete(out, "write failed: No space left on device")
    s = meta["logger"]
    assert s["telemetry_rows"] == 29 and s["frames_not_written"] == 31
    assert s["telemetry_rows"] + s["frames_not_written"] == lg.dec.frames == 60
