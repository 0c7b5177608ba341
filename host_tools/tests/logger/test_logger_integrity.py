"""The logger keeps every frame that passed the CRC (implausible ones flagged, resets only when
confirmed), survives a closed status pipe, and closes the run folder completely after a
volley of signals."""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from host_tools import logger as L
from host_tools import protocol as P
from test_logger import ScriptedPort, _args, events, robot_on_pty, rows, telemetry
from test_logger_reliability import _check_complete

ROOT = Path(__file__).resolve().parents[3]
D = P.definition()


def _stream(n=200, boot=7, t0=1_000_000, tamper=None):
    out = []
    for i in range(n):
        seq, t_us, b = i, t0 + 20_000 * i, boot
        if tamper:
            seq, t_us, b = tamper(i, seq, t_us, b)
        out.append(telemetry(seq, t_us, boot=b))
    return b"".join(out)


def _log(tmp_path, data, monkeypatch, capsys):
    """``log --port X --out RUN`` through the CLI, the port serving ``data`` then Ctrl-C."""
    port = ScriptedPort(data, [997])
    monkeypatch.setattr(serial, "serial_for_url", lambda *a, **k: port)
    out = tmp_path / "run"
    rc = L.main(_args(["--port", "scripted", "--out", str(out), "--quiet", "--params-timeout", "0"]))
    return rc, out, capsys.readouterr().err


@pytest.mark.parametrize("what", ["boot_count 9 instead of 7", "t_us 1000 s ahead"])
def test_one_implausible_frame_loses_no_good_frame(tmp_path, monkeypatch, capsys, what):
    def tamper(i, seq, t_us, b):
        if i == 50:
            return (seq, t_us, 9) if what.startswith("boot") else (seq, t_us + 1_000_000_000, b)
        return seq, t_us, b
    rc, out, err = _log(tmp_path, _stream(tamper=tamper), monkeypatch, capsys)
    assert rc == 0, err
    tel = rows(out).telemetry
    assert tel["seq"].astype(int).tolist() == [i for i in range(200) if i != 50]
    meta = json.loads((out / "meta.json").read_text())["logger"]
    assert meta["implausible"] == 1 and meta["robot_resets"] == 0 and meta["stale"] == 0
    assert meta["lost_frames"] == 0
    (ev,) = [e for e in events(out) if e["kind"] == "implausible"]
    assert ev["seq"] == 50 and ev["values"]["seq"] == 50  # kept, with every value
    assert ev["boot"] == (9 if what.startswith("boot") else 7)
    assert "1 implausible" in err  # the end summary counts them


def test_a_reset_is_recognised_once_following_frames_confirm_it(tmp_path, monkeypatch, capsys):
    def tamper(i, seq, t_us, b):
        return (seq, t_us, b) if i < 100 else (i - 100, 5_000 + 20_000 * (i - 100), 8)
    rc, out, err = _log(tmp_path, _stream(tamper=tamper), monkeypatch, capsys)
    assert rc == 0, err
    assert json.loads((out / "meta.json").read_text())["logger"]["robot_resets"] == 1
    assert rows(out).telemetry["t_s"].size == 200
    assert [e["boot"] for e in events(out) if e["kind"] == "robot_reset"] == [8]


def test_an_unconfirmed_reset_at_the_end_is_flagged_not_a_reset(tmp_path, monkeypatch, capsys):
    data = _stream(n=100) + telemetry(0, 5_000, boot=8)
    rc, out, err = _log(tmp_path, data, monkeypatch, capsys)
    assert rc == 0, err
    meta = json.loads((out / "meta.json").read_text())["logger"]
    assert meta["robot_resets"] == 0 and meta["implausible"] == 1
    assert rows(out).telemetry["t_s"].size == 100
    (ev,) = [e for e in events(out) if e["kind"] == "implausible"]
    assert ev["reason"] == "unconfirmed reset"


def test_an_absurd_first_frame_does_not_discard_the_recording(tmp_path, monkeypatch, capsys):
    def tamper(i, seq, t_us, b):
        return (seq, t_us + 3_000_000_000, b) if i == 0 else (seq, t_us, b)
    rc, out, err = _log(tmp_path, _stream(n=50, tamper=tamper), monkeypatch, capsys)
    assert rc == 0, err
    assert rows(out).telemetry["seq"].astype(int).tolist() == list(range(1, 50))
    assert json.loads((out / "meta.json").read_text())["logger"]["implausible"] == 1


# ------------------------------------------------------------- a closed status pipe


@contextlib.contextmanager
def _logging(out, extra=(), period=0.005):
    """``python -m host_tools log`` in a subprocess against a fake robot on a pty; yields
    (process, robot) and ends both."""
    robot, path, fds = robot_on_pty(period=period)
    proc = subprocess.Popen([sys.executable, "-m", "host_tools", "log", "--port", path, "--out", str(out),
                             *extra], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        yield proc, robot
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        robot.stop_flag.set()
        robot.join(2)
        for fd in fds:
            os.close(fd)


def _wait_rows(out, n, timeout=60):  # a guard: a loaded machine starts Python slowly
    tpath = out / "telemetry.csv"
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if tpath.exists() and len(tpath.read_bytes().splitlines()) > n:
            return True
        time.sleep(0.05)
    return False


def test_a_closed_status_pipe_never_ends_the_recording(tmp_path):
    """``ddrobot log ... 2>&1 | head -c 200``: the status line's reader goes away; the
    recording goes on until it is stopped, exit 0, and the robot still gets its Stop."""
    out = tmp_path / "run"
    with _logging(out, ["--experiment", "straight", "--duration", "60", "--record-s", "60"]) as (proc, robot):
        proc.stderr.read(200)
        proc.stderr.close()  # like head -c 200 exiting
        proc.stdout.close()
        assert _wait_rows(out, 400), "the recording ended after the status pipe closed"
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=20)
    assert rc == 0
    meta = _check_complete(out, "interrupted (Ctrl-C)")
    assert meta["logger"]["telemetry_rows"] >= 400
    assert "Stop" in robot.received


# ------------------------------------------------------------- a volley of signals


@pytest.mark.parametrize("sig, gap_s, reason", [
    (signal.SIGINT, 0.001, "interrupted (Ctrl-C)"), (signal.SIGINT, 0.0, "interrupted (Ctrl-C)"),
    (signal.SIGINT, 0.01, "interrupted (Ctrl-C)"), (signal.SIGTERM, 0.001, "stopped by SIGTERM"),
    (signal.SIGTERM, 0.0, "stopped by SIGTERM")])
def test_three_quick_signals_leave_a_complete_folder(tmp_path, sig, gap_s, reason):
    out = tmp_path / "run"
    with _logging(out, period=0.002) as (proc, _robot):
        assert _wait_rows(out, 100)
        for _ in range(3):
            proc.send_signal(sig)
            time.sleep(gap_s)
        _, err = proc.communicate(timeout=20)
    err = err.decode(errors="replace")
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    _check_complete(out, reason)


# ------------------------------------------------------------- never through a stale link


def test_stale_temp_links_in_the_run_folder_are_never_written_through(tmp_path, monkeypatch, capsys):
    """A ``meta.json.tmp`` left as a link to another file (another run's meta.json): the
    logger and --attach-groundtruth write their own temporary files, never through it."""
    victim = tmp_path / "victim.json"
    victim.write_text('{"keep": true}\n')
    out = tmp_path / "run"
    out.mkdir()
    (out / "meta.json.tmp").symlink_to(victim)
    port = ScriptedPort(_stream(n=30), [997])
    monkeypatch.setattr(serial, "serial_for_url", lambda *a, **k: port)
    assert L.main(_args(["--port", "scripted", "--out", str(out), "--quiet", "--params-timeout", "0"])) == 0
    assert victim.read_text() == '{"keep": true}\n'
    assert json.loads((out / "meta.json").read_text())["logger"]["telemetry_rows"] == 30
    run = rows(out)
    trk = tmp_path / "trk.csv"
    trk.write_text("t_s,x_m,y_m\n" + "".join(f"{t:.3f},0,0\n" for t in run.telemetry["t_s"]))
    assert L.main(_args(["--out", str(out), "--attach-groundtruth", str(trk), "--gt-offset", "0"])) == 0
    assert victim.read_text() == '{"keep": true}\n'
    assert "groundtruth" in json.loads((out / "meta.json").read_text())
