"""The telemetry logger over pyserial loop://, a pty pair and socket:// with a simulated robot:
corruption, drops, duplication, a robot reset, a pulled cable, Ctrl-C, commands and acks, and
attaching external ground truth."""
from __future__ import annotations

import json
import math
import os
import pty
import socket
import threading
import time
import tty

import numpy as np
import pytest
import serial

from host_tools import logger as L
from host_tools import protocol as P
from host_tools import runfmt

D = P.definition()
TEL = D.by_name["Telemetry"]
NAMES = TEL.field_names()
RUNNING = 1 << D.flags["status"]["running"]


def telemetry(seq: int, t_us: int, omega: float = 10.0, running: bool = False, x: float = 0.0,
              failsafe: int = 0, boot: int = 7) -> bytes:
    vals = dict.fromkeys(NAMES, 0)
    vals.update(t_us=t_us, enc_r=seq * 3, enc_l=seq * 3, omega_r=int(omega * 100), omega_l=int(omega * 100),
                x_odo=int(x * 1e6), status=RUNNING if running else 0, inner_max=150, stack_hwm=700, failsafe=failsafe,
                boot_count=boot)
    return D.encode_raw("Telemetry", seq, [vals[n] for n in NAMES])


def params_frame(seq: int, mu=(0.3, D.robot_defaults["robot"]["mu_k"]), clamp=1,
                 controller=0) -> bytes:
    p = dict(D.robot_defaults["robot"], **D.robot_defaults["motor"])
    p.update(encoder_ppr=D.robot_defaults["encoder_ppr"], inner_period_us=25000, outer_period_us=50000, telemetry_period_us=20000,
             baud=115200, clamp_on=clamp, controller=controller, firmware_id=0xDEADBEEF, ke_ratio=1.0, drop_v=0.0)
    p["mu_s"], p["mu_k"] = mu
    return D.encode_raw("Params", seq, [p[f.name] for f in D.by_name["Params"].fields])


def rows(run_dir):
    return runfmt.load_run(run_dir, check_units=False)


def events(run_dir):
    with open(os.path.join(run_dir, "events.jsonl")) as fh:
        return [json.loads(line) for line in fh]


# --------------------------------------------------------------------- loop://


def test_loop_corruption_drops_and_duplicates(tmp_path):
    port = serial.serial_for_url("loop://", timeout=0.02)
    frames = [telemetry(i, 1_000_000 + 20_000 * i) for i in range(40)]
    stream = bytearray()
    for i, fr in enumerate(frames):
        if i == 5:
            stream += b"\x12\x34\x56garbage"            # garbage between frames
        if i == 10:
            bad = bytearray(fr)
            bad[30] ^= 0x04                            # CRC error
            stream += bad
            continue
        if i in (15, 16, 17):                          # dropped frames: a gap of 3
            continue
        if i == 20:
            stream += fr[:37]                          # cut short (robot lost power mid-frame)
            continue
        stream += fr
        if i == 25:
            stream += fr                               # duplicated by the radio
    port.write(bytes(stream))
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "loop://", 115200, record_s=0.6, params_timeout_s=0.05,
                  status=False)
    assert lg.run() == 0
    run = rows(out)
    expect = [i for i in range(40) if i not in (10, 15, 16, 17, 20)]
    assert run.telemetry["seq"].astype(int).tolist() == expect
    assert np.allclose(run.telemetry["t_s"], [1.0 + 0.02 * i for i in expect])
    assert np.allclose(run.telemetry["omega_r"], 10.0)
    meta = json.load(open(out / "meta.json"))
    lg_stats = meta["logger"]
    # garbage, the flipped bit and the truncated frame: three rejected blocks, >= 1 by CRC
    assert sum(lg_stats["rejected_blocks"].values()) == 3
    assert lg_stats["crc_errors"] >= 1
    assert lg_stats["duplicates"] == 1
    assert lg_stats["lost_frames"] == 5 and lg_stats["gaps"] == 3  # 10, 15-17, 20
    assert meta["logger"]["params_source"].startswith("defaults")
    assert "controller_variant" not in meta  # neither reported nor commanded: unknown
    ev = events(out)
    kinds = [e["kind"] for e in ev]
    assert "duplicate" in kinds and kinds.count("gap") == 3
    # raw.bin holds every byte received: the robot's stream (plus our own looped-back frames)
    raw = (out / "raw.bin").read_bytes()
    assert raw.startswith(bytes(stream))
    rej = [e for e in ev if e["kind"] == "rejected_block"]
    assert {e["reason"] for e in rej} >= {"crc"}
    for e in rej:  # offsets point into raw.bin
        assert 0 <= e["raw_offset"] < len(raw)


# ----------------------------------------------------------------- a fake robot


STALL_S = 0.1  # a gap between the fake robot's steps this much longer than its period: a stall


class FakeRobot(threading.Thread):
    """Robot side of the protocol: answers commands with Acks, sends Params on request and
    telemetry every ``period`` s (board time in 20 ms steps), runs experiments, brakes when no
    host frame arrived for 500 ms of wall time.  ``tamper(seq, frame) -> bytes`` can corrupt/drop/duplicate."""

    def __init__(self, write, read, period=0.004, reject=None, tamper=None, ignore_config=False):
        super().__init__(daemon=True)
        self.mu, self.clamp, self.ignore_config = (0.3, D.robot_defaults["robot"]["mu_k"]), 0, ignore_config
        self.controller = D.enums["controller"]["improved"]  # the firmware's default
        self.write, self.read = write, read
        self.period = period
        self.reject = reject or {}
        self.tamper = tamper
        self.seq = 0
        self.t_us = 0
        self.running_until = None
        self.last_host = None
        self.received: list[str] = []
        self.dec = P.StreamDecoder()
        self.stop_flag = threading.Event()
        self.failsafe = 0
        self.lock = threading.Lock()

    def next_seq(self):
        s = self.seq
        self.seq = (self.seq + 1) & 0xFFFF
        return s

    def send(self, data):
        try:
            self.write(data)
        except OSError:
            pass

    def handle(self, data):
        for f in self.dec.feed(data):
            msg = D.by_type.get(f.type)
            self.last_host = time.monotonic()
            name = msg.name if msg else f"type{f.type}"
            self.received.append(name)
            result = self.reject.get(name, "ok")
            if result == "ok" and msg is not None:
                if name == "Start":
                    _, raws = D.unpack(f)
                    self.running_until = self.t_us + raws[3] * 1000  # duration ms -> us
                    self.failsafe = 0
                elif name == "Stop":
                    self.running_until = None
                elif name == "SetMu" and not self.ignore_config:
                    _, raws = D.unpack(f)
                    self.mu = (raws[0] * 1e-4, raws[1] * 1e-4)
                elif name == "SetClamp" and not self.ignore_config:
                    self.clamp = D.unpack(f)[1][0]
                elif name == "SetController" and not self.ignore_config:
                    self.controller = D.unpack(f)[1][0]
            self.send(D.encode_raw("Ack", self.next_seq(), (f.seq, f.type, D.enums["result"][result], 255)))
            if name == "RequestParams" and result == "ok":
                self.send(params_frame(self.next_seq(), self.mu, self.clamp, self.controller))

    def step(self):
        running = self.running_until is not None and self.t_us < self.running_until
        # failsafe on host (wall) time: this robot's board clock runs faster than real time
        if running and self.last_host is not None and time.monotonic() - self.last_host > 0.5:
            self.running_until, running, self.failsafe = None, False, 1
        if self.running_until is not None and not running:
            self.running_until = None
        seq = self.next_seq()
        fr = telemetry(seq, self.t_us, omega=20.0 if running else 0.0, running=running,
                       failsafe=self.failsafe)
        if self.tamper:
            fr = self.tamper(seq, fr)
        self.send(fr)
        self.t_us += 20_000

    def run(self):
        last = time.monotonic()
        while not self.stop_flag.is_set():
            # this robot runs in the host's process (the in-process tests): a stall of the whole
            # process (a loaded machine) stops both, and is not the host falling silent, which a
            # real robot, running on, would judge on its own clock
            now = time.monotonic()
            stalled = now - last - self.period
            last = now
            if stalled > STALL_S and self.last_host is not None:
                with self.lock:
                    self.last_host += stalled
            data = self.read()
            if data:
                self.handle(data)
            with self.lock:
                self.step()
            time.sleep(self.period)


def pty_pair():
    master, slave = pty.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, os.ttyname(slave), slave


def robot_on_pty(start=True, **kw):
    master, path, slave = pty_pair()

    def read():
        try:
            return os.read(master, 4096)
        except BlockingIOError:
            return b""
        except OSError:
            return b""
    robot = FakeRobot(lambda b: os.write(master, b), read, **kw)
    if start:
        robot.start()
    return robot, path, (master, slave)


def _wait_until(cond, timeout_s=30.0):
    """Wait for ``cond()`` (a wall-clock guard only: a loaded machine may be slow to get there)."""
    deadline = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_pty_experiment_with_params_commands_and_heartbeats(tmp_path):
    robot, path, fds = robot_on_pty(period=0.004)
    out = tmp_path / "run"
    try:
        rc = L.main(_args(["--port", path, "--out", str(out), "--experiment", "straight", "--accel", "48",
                           "--accel-time", "0.5", "--duration", "1.0", "--clamp", "on", "--mu-s", "0.3",
                           "--mu-k", "0.25", "--quiet", "--record-s", "20"]))
    finally:
        robot.stop_flag.set()
        robot.join(2)
    assert rc == 0
    meta = json.load(open(out / "meta.json"))
    assert meta["experiment"].startswith("straight line, 48 rad/s^2 wheel acceleration for 0.5 s")
    assert meta["robot"]["mu_s"] == pytest.approx(0.3)          # the robot's Params after SetMu
    assert meta["robot"]["mu_k"] == pytest.approx(0.25)
    assert meta["torque_clamp"] is True
    assert not [e for e in events(out) if e["kind"] == "params_mismatch"]
    assert meta["logger"]["params_source"] == "robot"
    assert meta["logger"]["firmware_id"] == "deadbeef"
    assert meta["logger"]["end_reason"] == "experiment finished"
    assert [c["command"] for c in meta["commands"]] == ["SetClamp", "SetMu", "Start"]
    assert all(c["result"] == "ok" for c in meta["commands"])
    assert robot.received[:5] == ["RequestParams", "SetClamp", "SetMu", "RequestParams", "Start"]
    # 1 s of board time at 20 ms per frame took ~0.2 s of host time; heartbeats kept it alive
    assert robot.failsafe == 0
    run = rows(out)
    st = run.telemetry["status"].astype(int)
    assert (st & RUNNING).sum() >= 45
    assert run.telemetry["t_s"].size > 50
    for fd in fds:
        os.close(fd)


def _record_with_robot(tmp_path, argv, **robot_kw):
    robot, path, fds = robot_on_pty(period=0.004, **robot_kw)
    out = tmp_path / "run"
    try:
        rc = L.main(_args(["--port", path, "--out", str(out), "--quiet", "--record-s", "20"] + argv))
    finally:
        robot.stop_flag.set()
        robot.join(2)
        for fd in fds:
            os.close(fd)
    return rc, robot, json.load(open(out / "meta.json")), events(out)


START = ["--experiment", "straight", "--accel", "48", "--accel-time", "0.2", "--duration", "0.4"]


def test_controller_is_set_before_start_and_reported_in_meta(tmp_path):
    rc, robot, meta, ev = _record_with_robot(tmp_path, START + ["--controller", "thesis"])
    assert rc == 0
    # SetController, then the robot's own report of it, then the Start
    assert robot.received[:4] == ["RequestParams", "SetController", "RequestParams", "Start"]
    assert robot.controller == D.enums["controller"]["thesis"]
    assert meta["controller_variant"] == "thesis"
    assert meta["commands"][0] == {"command": "SetController", "values": {"variant": "thesis"}, "result": "ok"}
    # the robot's Params after the command carried it (the event shows the raw field)
    assert [e["controller"] for e in ev if e["kind"] == "params"] == [0, 1]
    assert not [e for e in ev if e["kind"] == "params_mismatch"]
    assert meta["logger"]["end_reason"] == "experiment finished"


def test_without_controller_option_meta_has_the_robots_report(tmp_path):
    rc, robot, meta, _ = _record_with_robot(tmp_path, START)
    assert rc == 0 and "SetController" not in robot.received
    assert meta["controller_variant"] == "improved"


def test_controller_the_robot_did_not_adopt_is_reported_as_it_runs(tmp_path, capsys):
    # a robot that acknowledges but keeps its loop: meta.json says what it reports, and the
    # difference from the command is an event and a warning
    rc, _, meta, ev = _record_with_robot(tmp_path, START + ["--controller", "thesis"], ignore_config=True)
    assert rc == 0
    assert meta["controller_variant"] == "improved"
    (mm,) = [e for e in ev if e["kind"] == "params_mismatch"]
    assert mm["detail"] == ["controller 0 (commanded thesis)"]
    assert "controller 0 (commanded thesis)" in capsys.readouterr().err


def test_controller_refused_by_the_robot_stops_before_start(tmp_path):
    rc, robot, meta, _ = _record_with_robot(tmp_path, START + ["--controller", "thesis"],
                                            reject={"SetController": "busy"})
    assert rc == 1 and "Start" not in robot.received
    assert meta["logger"]["end_reason"] == "robot rejected SetController: busy"
    assert meta["commands"][-1]["result"] == "busy"
    assert meta["controller_variant"] == "improved"  # what the robot reported, not the command


def test_bad_controller_value_is_refused_before_anything_is_sent(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        _args(["--port", "loop://", "--out", str(tmp_path / "x"), "--controller", "pid"])
    assert e.value.code == 2 and "invalid choice: 'pid'" in capsys.readouterr().err
    with pytest.raises(L.LoggerError) as e:
        L.Logger(str(tmp_path / "y"), lambda: None, "loop://", 115200, controller="pid")
    assert e.value.code == 2 and not (tmp_path / "y").exists()
    with pytest.raises(P.ProtocolError):  # the codec refuses the raw value past the enum too
        D.encode("SetController", 0, {"variant": 2})


def test_failsafe_without_heartbeats_is_recorded(tmp_path):
    """A robot running an experiment that stops hearing the host brakes (failsafe
    host_timeout); the logger, recording freely (so sending no heartbeats), records why."""
    robot, path, fds = robot_on_pty(period=0.004, start=False)
    # an experiment under way from the robot's first frame, its host heard until the logger
    # connects (however late a loaded machine lets it)
    robot.running_until, robot.last_host = 10**9, math.inf
    robot.start()

    def open_port():
        port = serial.serial_for_url(path, timeout=0.02)
        with robot.lock:
            robot.last_host = time.monotonic()
        return port
    out = tmp_path / "run"
    lg = L.Logger(str(out), open_port, path, 115200, record_s=60, params_timeout_s=0.2, status=False)

    def stop_after_the_brake():  # the robot brakes 0.5 s after the host's last frame (its
        _wait_until(lambda: robot.failsafe)  # RequestParams): recorded until 20 rows after
        n = lg.stats["telemetry_rows"]
        _wait_until(lambda: lg.stats["telemetry_rows"] >= n + 20)
        lg.stop()
    th = threading.Thread(target=stop_after_the_brake, daemon=True)
    th.start()
    try:
        assert lg.run() == 0
    finally:
        th.join()
        robot.stop_flag.set()
        robot.join(2)
    fs = [e for e in events(out) if e["kind"] == "failsafe"]
    assert fs and fs[0]["reason"] == "host_timeout"
    st = rows(out).telemetry["status"].astype(int)
    assert st[0] & RUNNING and not st[-1] & RUNNING
    for fd in fds:
        os.close(fd)


def test_rejected_command_exits_1_and_keeps_the_run(tmp_path, capsys):
    robot, path, fds = robot_on_pty(reject={"Start": "busy"})
    out = tmp_path / "run"
    try:
        rc = L.main(_args(["--port", path, "--out", str(out), "--experiment", "arc", "--radius", "0.5",
                           "--quiet"]))
    finally:
        robot.stop_flag.set()
        robot.join(2)
    assert rc == 1
    assert "robot rejected Start: busy" in capsys.readouterr().err
    meta = json.load(open(out / "meta.json"))
    assert meta["commands"][-1]["result"] == "busy"
    assert meta["logger"]["end_reason"] == "robot rejected Start: busy"
    runfmt.load_meta(out)
    for fd in fds:
        os.close(fd)


def test_bad_input_exit_2(tmp_path, capsys):
    rc = L.main(_args(["--port", "loop://", "--out", str(tmp_path / "r"), "--experiment", "straight",
                       "--accel", "500"]))
    assert rc == 2
    assert "Start.wheel_accel: 500.0 rad/s^2 is out of range [0.01, 200]" in capsys.readouterr().err
    rc = L.main(_args(["--port", str(tmp_path / "no-such-tty"), "--out", str(tmp_path / "r2")]))
    assert rc == 2
    assert "cannot open port" in capsys.readouterr().err
    rc = L.main(_args(["--port", "loop://", "--out", str(tmp_path / "r3"), "--mu-s", "0.3"]))
    assert rc == 2


# ---------------------------------------------------------- socket: pulled cable


class SocketRobot:
    """TCP server carrying the fake robot; ``pull()`` closes the connection and the listening
    socket (the port disappears), ``plug()`` brings it back."""

    def __init__(self, **kw):
        self.srv = None
        self.conn = None
        self.port = None
        self.lock = threading.Lock()
        self.plug()
        self.robot = FakeRobot(self._write, self._read, **kw)
        self.robot.start()

    def plug(self):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", self.port or 0))
        s.listen(1)
        s.setblocking(False)
        self.port = s.getsockname()[1]
        self.srv = s

    def pull(self):
        with self.lock:
            for s in (self.conn, self.srv):
                if s is not None:
                    s.close()
            self.conn = self.srv = None

    def _accept(self):
        if self.conn is None and self.srv is not None:
            try:
                self.conn, _ = self.srv.accept()
                self.conn.setblocking(False)
            except (BlockingIOError, OSError):
                pass

    def _write(self, b):
        with self.lock:
            self._accept()
            if self.conn is not None:
                try:
                    self.conn.sendall(b)
                except OSError:
                    pass
            # while unplugged the robot's frames go nowhere (they are lost, as on a real cable)

    def _read(self):
        with self.lock:
            self._accept()
            if self.conn is None:
                return b""
            try:
                return self.conn.recv(4096)
            except (BlockingIOError, OSError):
                return b""

    def close(self):
        self.robot.stop_flag.set()
        self.robot.join(2)
        self.pull()


def _cable_timeline(lg, robot, pull, plug, rows_before=100, frames_lost=60, rows_after=50):
    """Pull the cable once the logger has ``rows_before`` rows, plug it back once it noticed
    and the robot sent ``frames_lost`` frames into nothing, stop the logger once it has
    ``rows_after`` rows more: the steps follow the recording, not the wall clock, which a
    loaded machine stretches (fewer frames per second)."""
    _wait_until(lambda: lg.stats["telemetry_rows"] >= rows_before)
    pull()
    t_us = robot.t_us
    _wait_until(lambda: lg.stats["disconnects"] >= 1 and robot.t_us - t_us >= frames_lost * 20_000)
    n = lg.stats["telemetry_rows"]
    plug()
    _wait_until(lambda: lg.stats["telemetry_rows"] >= n + rows_after)
    lg.stop()


def test_pulled_cable_reconnects_and_resumes(tmp_path):
    sr = SocketRobot(period=0.004)
    out = tmp_path / "run"
    url = f"socket://127.0.0.1:{sr.port}"
    lg = L.Logger(str(out), lambda: serial.serial_for_url(url, timeout=0.02), url, 115200,
                  record_s=120, params_timeout_s=0.3, reconnect_timeout_s=30, status=False)
    th = threading.Thread(target=_cable_timeline, args=(lg, sr.robot, sr.pull, sr.plug), daemon=True)
    th.start()
    try:
        assert lg.run() == 0
    finally:
        th.join()
        sr.close()
    ev = events(out)
    kinds = [e["kind"] for e in ev]
    assert "disconnect" in kinds and "reconnect" in kinds
    i_dis, i_re = kinds.index("disconnect"), kinds.index("reconnect")
    assert i_dis < i_re
    run = rows(out)
    t = run.telemetry["t_s"]
    assert np.all(np.diff(t) > 0)
    seq = run.telemetry["seq"].astype(int)
    # frames before and after the outage; the outage itself shows as one gap
    gap = [e for e in ev if e["kind"] == "gap"]
    assert len(gap) >= 1 and max(g["missing"] for g in gap) > 50
    assert seq.size > 100
    meta = json.load(open(out / "meta.json"))
    assert meta["logger"]["disconnects"] >= 1


def test_port_never_returns_gives_complete_run(tmp_path):
    sr = SocketRobot(period=0.004)
    url = f"socket://127.0.0.1:{sr.port}"
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: serial.serial_for_url(url, timeout=0.02), url, 115200,
                  record_s=30, params_timeout_s=0.3, reconnect_timeout_s=0.8, status=False)

    def cable():  # pulled for good once rows were recorded (however slowly they come)
        _wait_until(lambda: lg.stats["telemetry_rows"] > 20)
        sr.pull()
    th = threading.Thread(target=cable, daemon=True)
    th.start()
    try:
        assert lg.run() == 1
    finally:
        th.join()
        sr.close()
    meta = json.load(open(out / "meta.json"))
    assert "did not return within 0.8 s" in meta["logger"]["end_reason"]
    assert rows(out).telemetry["t_s"].size > 20


def test_robot_power_loss_and_reset(tmp_path):
    """The robot dies mid-frame and reboots: its seq and clock restart; the logger records a
    reset and keeps t_s increasing."""
    port = serial.serial_for_url("loop://", timeout=0.02)
    # (pyserial's loop:// queue holds 4096 bytes: stay below it)
    a = [telemetry(i, 5_000_000 + 20_000 * i) for i in range(18)]
    b = [telemetry(i, 3000 + 20_000 * i, boot=8) for i in range(18)]
    port.write(b"".join(a) + a[0][:25] + b"".join(b))
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "loop://", 115200, record_s=0.5, params_timeout_s=0.05,
                  status=False)
    assert lg.run() == 0
    run = rows(out)
    assert run.telemetry["t_s"].size == 36
    assert np.all(np.diff(run.telemetry["t_s"]) > 0)
    assert lg.stats["robot_resets"] == 1
    assert [e for e in events(out) if e["kind"] == "robot_reset"]


def _record(tmp_path, stream: bytes):
    port = serial.serial_for_url("loop://", timeout=0.02)
    port.write(stream)
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "loop://", 115200, record_s=0.4, params_timeout_s=0.05,
                  status=False)
    assert lg.run() == 0
    return lg, rows(out)


def test_a_stale_frame_early_in_a_boot_is_not_a_reset(tmp_path):
    """One older frame within the first 5 s of board time (seq < 1000) is not a reset: taken
    for one, it would give a row with a made-up time, '1 gap (2 frames lost)', later t_s
    shifted."""
    fr = [telemetry(i, 20_000 * (i + 1)) for i in range(30)]
    lg, run = _record(tmp_path, b"".join(fr[:20] + [fr[12]] + fr[20:]))
    assert lg.stats["robot_resets"] == 0
    assert lg.stats["stale"] == 1 and lg.stats["lost_frames"] == 0 and lg.stats["gaps"] == 0
    assert run.telemetry["seq"].astype(int).tolist() == list(range(30))
    assert np.allclose(run.telemetry["t_s"], 0.02 * np.arange(1, 31))


def test_reordered_pairs_early_in_a_boot_are_not_resets(tmp_path):
    n = 38  # (pyserial's loop:// queue holds 4096 bytes: 38 frames of 104 bytes stay below it)
    fr = [telemetry(i, 20_000 * (i + 1)) for i in range(n)]
    stream = b"".join(fr[i + 1] + fr[i] for i in range(0, n, 2))
    lg, run = _record(tmp_path, stream)
    assert lg.stats["robot_resets"] == 0
    assert lg.stats["stale"] == n // 2
    # the later frame of each pair is written; the one before it arrives late: stale, not lost
    assert run.telemetry["seq"].astype(int).tolist() == list(range(1, n, 2))
    assert lg.stats["lost_frames"] == n // 2 - 1  # every second frame never became a row...
    assert lg.stats["lost_frames"] + run.telemetry["t_s"].size == n - 1  # ...and none twice


def test_a_reset_is_recognised_by_the_boot_counter_alone(tmp_path):
    """A reset whose frames look like a continuation by time and seq (a board clock that
    happens to be later) is still a reset; a late frame of the old boot after it is stale."""
    a = [telemetry(i, 20_000 * (i + 1), boot=3) for i in range(10)]
    b = [telemetry(i + 10, 20_000 * (i + 11), boot=4) for i in range(10)]
    lg, run = _record(tmp_path, b"".join(a + b[:5] + [a[9]] + b[5:]))
    assert lg.stats["robot_resets"] == 1 and lg.stats["stale"] == 1
    assert run.telemetry["t_s"].size == 20 and np.all(np.diff(run.telemetry["t_s"]) > 0)
    ev = [e for e in events(tmp_path / "run") if e["kind"] == "robot_reset"]
    assert ev[0]["boot"] == 4 and ev[0]["last_boot"] == 3


def test_clock_wrap_is_unwrapped(tmp_path):
    port = serial.serial_for_url("loop://", timeout=0.02)
    t0 = 2**32 - 60_000
    port.write(b"".join(telemetry(i, (t0 + 20_000 * i) % 2**32) for i in range(8)))
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "loop://", 115200, record_s=0.3, params_timeout_s=0.05,
                  status=False)
    assert lg.run() == 0
    t = rows(out).telemetry["t_s"]
    assert np.allclose(np.diff(t), 0.02)
    assert lg.stats["robot_resets"] == 0


def test_ctrl_c_leaves_a_complete_run(tmp_path):
    port = serial.serial_for_url("loop://", timeout=0.02)
    port.write(b"".join(telemetry(i, 20_000 * (i + 1)) for i in range(20)))
    calls = {"n": 0}

    class Interrupting:
        def __init__(self, p):
            self.p = p

        @property
        def in_waiting(self):
            return self.p.in_waiting

        def read(self, n):
            calls["n"] += 1
            if calls["n"] > 5:
                raise KeyboardInterrupt
            return self.p.read(min(n, 200))

        def write(self, b):
            return self.p.write(b)

        def close(self):
            self.p.close()
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: Interrupting(port), "loop://", 115200, params_timeout_s=5,
                  status=False)
    assert lg.run() == 0
    meta = json.load(open(out / "meta.json"))
    assert meta["logger"]["end_reason"] == "interrupted (Ctrl-C)"
    assert rows(out).telemetry["t_s"].size >= 5
    assert events(out)[-1]["kind"] == "end"


def test_refuses_to_overwrite(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "telemetry.csv").write_text("x\n")
    rc = L.main(_args(["--port", "loop://", "--out", str(out), "--quiet"]))
    assert rc == 2


# ---------------------------------------------------------------- ground truth


def _make_run(path, offset, noise=0.002, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 6, 0.02)
    # accelerate for 0.5 s, hold, brake at 4 s
    v = np.clip(np.minimum(t / 0.5, 1.0) * 0.6 - np.clip((t - 4) / 0.5, 0, 1) * 0.6, 0, None)
    v[t < 1.0] = 0
    v[(t >= 1.0) & (t < 1.5)] = (t[(t >= 1.0) & (t < 1.5)] - 1.0) / 0.5 * 0.6
    x = np.cumsum(v) * 0.02
    with runfmt.RunWriter(path, {"experiment": "test"}) as w:
        for i in range(t.size):
            w.write_row({"t_s": t[i], "enc_r": 0, "enc_l": 0, "omega_r": 0, "omega_l": 0, "tau_cmd_r": 0,
                         "tau_cmd_l": 0, "pwm_r": 0, "pwm_l": 0, "x_odo_m": x[i], "y_odo_m": 0.0,
                         "phi_odo_rad": 0.0})
    # tracker at 30 Hz on its own clock: t_tracker = t_board - offset, with noise and a dropout
    tt = np.arange(0, 6, 1 / 30)
    xt = np.interp(tt, t, x) * 1.05 + rng.normal(0, noise, tt.size)  # slip: 5 % further
    keep = ~((tt > 3.0) & (tt < 3.4))
    return tt[keep] - offset, xt[keep], rng.normal(0, noise, keep.sum())


def _write_tracker(path, t, x, y, phi=None):
    """A tracker's CSV (t_s, x_m, y_m, phi_rad; phi empty when None); returns ``path``."""
    with open(path, "w") as fh:
        fh.write("t_s,x_m,y_m,phi_rad\n")
        for a, b, c in zip(t, x, y):
            fh.write(f"{a:.4f},{b:.5f},{c:.5f},{'' if phi is None else phi}\n")
    return path


def test_groundtruth_offset_is_estimated(tmp_path):
    run = tmp_path / "run"
    tt, xt, yt = _make_run(str(run), offset=2.37)
    csv = _write_tracker(tmp_path / "tracker.csv", tt, xt, yt)
    rc = L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv)]))
    assert rc == 0
    meta = json.load(open(run / "meta.json"))
    assert meta["groundtruth"]["offset_s"] == pytest.approx(2.37, abs=0.02)
    r = runfmt.load_run(run, check_units=False)
    assert r.groundtruth["t_s"][0] == pytest.approx(tt[0] + 2.37, abs=0.02)


def test_groundtruth_given_offset_and_bad_csv(tmp_path, capsys):
    run = tmp_path / "run"
    tt, xt, yt = _make_run(str(run), offset=0.0)
    csv = tmp_path / "tracker.csv"
    csv.write_text("t_s,x_m\n0,1\n")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv)])) == 2
    assert "column 'y_m'" in capsys.readouterr().err
    csv.write_text("t_s,x_m,y_m\n0,0,0\n0.1,nan,0\n")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv), "--gt-offset", "1"])) == 2
    assert "row 2" in capsys.readouterr().err
    csv.write_text("t_s,x_m,y_m\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(tt, xt, yt)))
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv), "--gt-offset", "0.5"])) == 0
    assert json.load(open(run / "meta.json"))["groundtruth"]["method"] == "given"


def _args(argv):
    import argparse
    p = argparse.ArgumentParser()
    L.add_arguments(p)
    return p.parse_args(argv)


def test_long_outage_with_seq_wrap_is_a_gap_not_stale(tmp_path):
    """40 000 frames (13 min) lost: the 16-bit seq is ambiguous, the board time decides."""
    port = serial.serial_for_url("loop://", timeout=0.02)
    a = [telemetry(i, 1_000_000 + 20_000 * i) for i in range(10)]
    b = [telemetry((i + 40_010) & 0xFFFF, 1_000_000 + 20_000 * (i + 40_010)) for i in range(10)]
    port.write(b"".join(a + b))
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "loop://", 115200, record_s=0.4, params_timeout_s=0.05,
                  status=False)
    assert lg.run() == 0
    assert rows(out).telemetry["t_s"].size == 20
    assert lg.stats["lost_frames"] == 40_000 and lg.stats["gaps"] == 1
    assert lg.stats["stale"] == 0 and lg.stats["robot_resets"] == 0


def test_robot_ignoring_set_mu_is_reported(tmp_path, capsys):
    robot, path, fds = robot_on_pty(ignore_config=True)
    out = tmp_path / "run"
    try:
        rc = L.main(_args(["--port", path, "--out", str(out), "--mu-s", "0.5", "--mu-k", "0.4", "--clamp", "off",
                           "--quiet", "--record-s", "0.5"]))
    finally:
        robot.stop_flag.set()
        robot.join(2)
    assert rc == 0
    assert "warning: the robot reports mu_s 0.3000 (commanded 0.5)" in capsys.readouterr().err
    meta = json.load(open(out / "meta.json"))
    assert meta["robot"]["mu_s"] == pytest.approx(0.3)  # what the robot says it uses
    assert meta["torque_clamp"] is False
    (ev,) = [e for e in events(out) if e["kind"] == "params_mismatch"]
    assert len(ev["detail"]) == 2
    for fd in fds:
        os.close(fd)


class ScriptedPort:
    """Serves a byte stream in given chunk sizes, then ends the session like Ctrl-C."""

    def __init__(self, data: bytes, chunks: list[int]):
        self.data, self.chunks, self.pos, self.k = data, chunks, 0, 0
        self.written = bytearray()

    @property
    def in_waiting(self):
        return len(self.data) - self.pos

    def read(self, n):
        if self.pos >= len(self.data):
            raise KeyboardInterrupt
        c = self.chunks[self.k % len(self.chunks)]
        self.k += 1
        out = self.data[self.pos:self.pos + c]
        self.pos += len(out)
        return out

    def write(self, b):
        self.written += b

    def close(self):
        pass


from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402


@st.composite
def robot_streams(draw):
    """Telemetry with random drops, duplicates, reorders, garbage, truncation and resets (a
    reset restarts seq and clock and increments the boot counter)."""
    seq, t_us, out, sent = 0, draw(st.integers(0, 2**32 - 1)), bytearray(), set()
    boot = draw(st.integers(0, 0xFFFF))
    for _ in range(draw(st.integers(1, 40))):
        op = draw(st.sampled_from(["ok"] * 6 + ["drop", "dup", "swap", "junk", "cut", "reset"]))
        fr = telemetry(seq, t_us, boot=boot)
        if op == "reset":
            seq, t_us, boot = 0, draw(st.integers(0, 100_000)), (boot + 1) & 0xFFFF
            fr = telemetry(seq, t_us, boot=boot)
        if op == "drop":
            pass
        elif op == "dup":
            out += fr + fr
        elif op == "swap":
            nxt = telemetry((seq + 1) & 0xFFFF, (t_us + 20_000) % 2**32, boot=boot)
            out += nxt + fr
        elif op == "junk":
            out += draw(st.binary(max_size=30)) + fr
        elif op == "cut":
            out += fr[:draw(st.integers(1, len(fr) - 1))]
        else:
            out += fr
        sent.add((seq, t_us))
        if op == "swap":
            sent.add(((seq + 1) & 0xFFFF, (t_us + 20_000) % 2**32))
            seq, t_us = (seq + 1) & 0xFFFF, (t_us + 20_000) % 2**32
        seq, t_us = (seq + 1) & 0xFFFF, (t_us + 20_000) % 2**32
    return bytes(out), sent, draw(st.lists(st.integers(1, 200), min_size=1, max_size=5))


@given(robot_streams())
@settings(max_examples=60, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
def test_fuzz_logger_sequence_logic(tmp_path_factory, case):
    """Whatever arrives: no crash, t_s strictly increasing, every row is a frame that was sent,
    and the run folder loads."""
    data, sent, chunks = case
    out = tmp_path_factory.mktemp("fz") / "run"
    port = ScriptedPort(data, chunks)
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=0.0, status=False)
    assert lg.run() == 0
    rows_written = lg.stats["telemetry_rows"]
    if rows_written == 0:
        return
    run = rows(out)
    t = run.telemetry["t_s"]
    assert np.all(np.diff(t) > 0)
    seqs = run.telemetry["seq"].astype(int)
    assert all(any(s == q for q, _ in sent) for s in seqs)


def test_groundtruth_start_pose_from_tracker(tmp_path, capsys):
    run = tmp_path / "run"
    tt, xt, yt = _make_run(str(run), offset=0.0)
    # room coordinates: the robot starts at (1.0, 2.0) heading 0.5 rad
    csv = _write_tracker(tmp_path / "tracker.csv", tt, 1.0 + xt * math.cos(0.5),
                         2.0 + xt * math.sin(0.5) + yt, phi=0.5)
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv), "--gt-offset", "0",
                         "--gt-start-pose"])) == 0
    sp = json.load(open(run / "meta.json"))["start_pose"]
    assert sp == pytest.approx([1.0, 2.0, 0.5], abs=0.01)
    assert runfmt.load_run(run, check_units=False).start_pose == pytest.approx(tuple(sp))
    # without a heading column it is refused, with the reason
    run2 = tmp_path / "run2"
    _make_run(str(run2), offset=0.0)
    csv.write_text("t_s,x_m,y_m\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(tt, xt, yt)))
    assert L.main(_args(["--out", str(run2), "--attach-groundtruth", str(csv), "--gt-offset", "0",
                         "--gt-start-pose"])) == 2
    assert "needs the phi_rad column" in capsys.readouterr().err


def log_until_rows_then_signal(out, sig, min_rows=20, extra=(), period=0.01):
    """``python -m host_tools log`` in a subprocess against a fake robot on a pty, stopped
    with signal ``sig`` once ``min_rows`` rows are on disk.  Returns (returncode, stderr)."""
    import subprocess
    import sys
    from pathlib import Path

    robot, path, fds = robot_on_pty(period=period)
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.Popen([sys.executable, "-m", "host_tools", "log", "--port", path, "--out",
                             str(out), *extra], cwd=root, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60  # a guard: a loaded machine starts Python slowly
        tpath = out / "telemetry.csv"
        while time.monotonic() < deadline:  # wait until rows are on disk (flushed as it goes)
            if tpath.exists() and len(tpath.read_text().splitlines()) > min_rows:
                break
            time.sleep(0.05)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
        robot.stop_flag.set()
        robot.join(2)
        for fd in fds:
            os.close(fd)
    return proc.returncode, err


def test_cli_sigint_end_to_end(tmp_path):
    """python -m host_tools log in a subprocess, stopped with a real SIGINT (Ctrl-C)."""
    import signal

    out = tmp_path / "run"
    rc, err = log_until_rows_then_signal(out, signal.SIGINT)
    assert rc == 0, err
    assert "frames/s" in err  # the live status line
    meta = json.load(open(out / "meta.json"))
    assert meta["logger"]["end_reason"] == "interrupted (Ctrl-C)"
    assert meta["logger"]["params_source"] == "robot"
    assert rows(out).telemetry["t_s"].size >= 20


def test_nan_params_are_refused_not_fatal(tmp_path, capsys):
    p = dict(D.robot_defaults["robot"], **D.robot_defaults["motor"])
    p.update(encoder_ppr=D.robot_defaults["encoder_ppr"], inner_period_us=25000, outer_period_us=50000, telemetry_period_us=20000,
             baud=115200, clamp_on=0, controller=0, firmware_id=1, ke_ratio=1.0, drop_v=0.0, mu_s=float("nan"))
    bad = D.encode_raw("Params", 0, [p[f.name] for f in D.by_name["Params"].fields])
    port = serial.serial_for_url("loop://", timeout=0.02)
    port.write(bad + b"".join(telemetry(i + 1, 20_000 * (i + 1)) for i in range(10)))
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: port, "loop://", 115200, record_s=0.4, params_timeout_s=0.05, status=False)
    assert lg.run() == 0
    assert "ignoring the robot's Params (seq 0)" in capsys.readouterr().err
    (ev,) = [e for e in events(out) if e["kind"] == "bad_params"]
    assert "robot.mu_s" in ev["reason"] and ev["mu_s"] == "nan"
    meta = json.load(open(out / "meta.json"))
    assert meta["robot"]["mu_s"] == D.robot_defaults["robot"]["mu_s"] and meta["logger"]["params_source"].startswith("defaults")
    assert rows(out).telemetry["t_s"].size == 10


def test_pulled_usb_cable_on_a_tty_device(tmp_path):
    """A real tty (pty) behind a stable device path, as /dev/ttyUSB0 for a USB-serial XBee:
    the device vanishes (reads fail with EIO, the path is gone), then comes back as a new tty
    under the same path. The logger must notice, wait, reopen and keep recording."""
    dev = tmp_path / "ttyXBEE"
    state = {"master": None, "slave": None}
    lock = threading.Lock()

    def plug():
        master, slave = pty.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        with lock:
            state["master"], state["slave"] = master, slave
        os.symlink(os.ttyname(slave), dev)

    def unplug():
        os.unlink(dev)
        with lock:
            m, s = state["master"], state["slave"]
            state["master"] = state["slave"] = None
        os.close(s)
        os.close(m)

    def write(b):
        with lock:
            if state["master"] is not None:
                try:
                    os.write(state["master"], b)
                except OSError:
                    pass

    def read():
        with lock:
            if state["master"] is None:
                return b""
            try:
                return os.read(state["master"], 4096)
            except (BlockingIOError, OSError):
                return b""

    plug()
    robot = FakeRobot(write, read, period=0.004)
    robot.start()
    out = tmp_path / "run"
    lg = L.Logger(str(out), lambda: serial.serial_for_url(str(dev), timeout=0.02), str(dev), 115200,
                  record_s=120, params_timeout_s=0.3, reconnect_timeout_s=30, status=False)
    th = threading.Thread(target=_cable_timeline, args=(lg, robot, unplug, plug), daemon=True)
    th.start()
    try:
        assert lg.run() == 0
    finally:
        th.join()
        robot.stop_flag.set()
        robot.join(2)
        if state["master"] is not None:
            unplug()
    ev = events(out)
    kinds = [e["kind"] for e in ev]
    assert "disconnect" in kinds and "reconnect" in kinds
    i_dis, i_re = kinds.index("disconnect"), kinds.index("reconnect")
    assert i_dis < i_re
    run = rows(out)
    t = run.telemetry["t_s"]
    assert np.all(np.diff(t) > 0)
    host_t = run.telemetry["host_t_s"]
    # rows before and after
    assert (host_t < ev[i_dis]["host_t_s"]).sum() > 20 and (host_t > ev[i_re]["host_t_s"]).sum() > 20


def test_groundtruth_with_unix_timestamps(tmp_path):
    """A tracker stamped with a PC's Unix time is aligned through the logger's host clock."""
    run = tmp_path / "run"
    t0_unix, board_minus_host = 1_700_000_000.25, 12.5  # robot booted 12.5 s before the logger
    rng = np.random.default_rng(3)
    wire_s = D.wire_size("Telemetry") * D.bits_per_byte / D.baud  # a frame's last byte arrives after this
    with runfmt.RunWriter(str(run), {"experiment": "t", "logger": {"host_t0_unix_s": t0_unix}}) as w:
        for i in range(200):
            host_t = 0.5 + 0.02 * i
            w.write_row({**{c: 0 for c in runfmt.TELEMETRY_COLUMNS}, "t_s": host_t + board_minus_host,
                         "host_t_s": host_t + wire_s + abs(rng.normal(0, 0.004))})  # radio/USB latency
    csv = tmp_path / "tracker.csv"
    csv.write_text("t_s,x_m,y_m\n" + "".join(f"{t0_unix + 0.5 + k / 30:.4f},0,0\n" for k in range(100)))
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv), "--gt-unix-time"])) == 0
    info = json.load(open(run / "meta.json"))["groundtruth"]
    assert info["offset_s"] == pytest.approx(board_minus_host - t0_unix, abs=0.005)
    gt = runfmt.load_run(run, check_units=False).groundtruth
    assert gt["t_s"][0] == pytest.approx(0.5 + board_minus_host, abs=0.005)


def test_status_line_in_a_log_is_whole_lines(tmp_path, capsys, monkeypatch):
    """On a terminal the status line is redrawn in place every 0.5 s ("\\r"); into a pipe or a
    log file (CI) it is a whole line every 2 s, with no carriage returns."""
    from host_tools.logger import session as S
    now = [0.0]
    lg = L.Logger(str(tmp_path / "r"), lambda: None, "loop://", 115200, clock=lambda: now[0])
    lg._last_status = lg._last_rx = 0.0  # as run() starts them
    for k in range(1, 51):  # 25 s of status calls every 0.5 s
        now[0] = 0.5 * k
        lg._status()
    err = capsys.readouterr().err
    assert "\r" not in err and err.count("frames/s") == 12, err
    monkeypatch.setattr(S, "_stderr_is_terminal", lambda: True)
    for k in range(51, 61):
        now[0] = 0.5 * k
        lg._status()
    err = capsys.readouterr().err
    assert err.count("\r") == 10 and "\n" not in err
