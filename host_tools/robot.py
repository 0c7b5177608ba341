"""Drive the robot from Python, recording as it drives.

    from host_tools.robot import Robot
    with Robot(port="/dev/ttyUSB0", out="runs/drive-01") as bot:     # or Robot(fil=True, out=...)
        bot.drive(0.3, 0.0)          # v m/s, omega rad/s (ROS cmd_vel), kept alive until changed
        bot.sleep(2.0)               # board time
        bot.drive(0.3, 1.0)
        bot.sleep(3.0)
        bot.stop()
    # runs/drive-01 is a ddrun/1 run folder whose meta.json "reference" holds the Drive targets
    # the firmware tracked, with their board times (the analyzer replays it in closed loop)

:class:`Robot` opens the XBee port (any pyserial URL) or the firmware in the loop
(``fil=True``: ``.build/fil/fil`` running firmware.elf against the plant, ``sim_args`` its
options), records through the telemetry logger (:mod:`host_tools.logger`) into ``out`` and
keeps the link alive (heartbeats).  ``drive(v, w)`` sends a Drive command and repeats it every
``repeat_s`` (the firmware's command timeout, protocol.json ``drive.cmd_timeout``, would
otherwise ramp the robot to rest); ``stop()`` sends Stop (brake, drive mode ends);
``set_model(model)`` sends an analyzer model.json to the firmware (SetMu + SetModel; only while
stopped); ``drive_path(rows)`` drives a scripted path of (t, v, w) rows on the board clock.
In the firmware in the loop the host holds the simulator's board clock (``--lockstep``) from
the start: the start-up, ``set_model``, ``stop``/``wait_stopped`` and ``drive_path`` grant board
time as they wait for the robot, and the clock stands in between, so a script of these lands
on the same board times whatever the host's speed; ``drive``, ``sleep`` and the keys let it run
free on the wall clock (docs/fil.md, "Lockstep with the host").
``close()`` (or leaving the ``with`` block) stops the robot, ends the recording and returns the
logger's exit code.

``ddrobot drive`` is the command line: ``--path FILE`` (CSV rows t, v, w) or keys at a terminal.
"""
from __future__ import annotations

import argparse
import csv
import logging
import math
import queue
import sys
import threading
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

from host_tools import logger as L
from host_tools import model as M
from host_tools import protocol as P
from host_tools._stdio import STATUS
from host_tools.logger.reference import _U32_S

log = logging.getLogger(__name__)

REPEAT_S = 0.05  # Drive commands per second: 20, as a ROS teleop node publishes cmd_vel
LOCKSTEP_PROBE_S = 0.02  # lockstep: board time granted per step of a wait for the robot (a reply, a frame)
CATCH_UP_WALL_S = 30.0  # lockstep: wall time the robot's bytes of one hold may take to reach the host
QUIET_GRIDS = 3  # lockstep: grid periods without host bytes before a drive starts
STOP_SETTLE_S = 0.5  # lockstep: board time after a drive's Stop (the robot at rest) before the hold


class RobotError(Exception):
    """The robot could not be opened, configured or driven; ``code`` is the exit code."""

    def __init__(self, msg: str, code: int = 1):
        super().__init__(msg)
        self.code = code


class DriveSession(L.Logger):
    """The logger's session for driving: configure, then keep the link alive and send what the
    caller queues (Drive and Stop at once, other commands acknowledged) until stopped."""

    def __init__(self, *a, fil_meta: dict | None = None, sim: Any = None, **kw):
        super().__init__(*a, **kw)
        self.fil_meta = fil_meta
        self.sim = sim  # host_tools.fil.Sim with --lockstep: held from the start, pump grants board time
        self.drives = True
        self.ready = threading.Event()
        self.queue: "queue.Queue[tuple]" = queue.Queue()
        self.drive_sent = 0
        self.drive_rejected: dict[str, int] = {}
        self._drive_seqs: set[int] = set()

    def _meta(self) -> dict:
        meta = super()._meta()
        if self.fil_meta is not None:
            meta["source"] = "fil"
            meta["fil"] = self.fil_meta
        meta.setdefault("logger", {})["drive_commands_sent"] = self.drive_sent
        if self.drive_rejected:
            meta["logger"]["drive_commands_rejected"] = dict(self.drive_rejected)
        return meta

    def _session(self) -> None:
        self._configure()
        self._heartbeat = not self._held()  # while held the clock stands: no timeout to keep off
        self.ready.set()
        while not self._should_stop():
            self._serve_queue()
            self.pump(None, 0.01)
            self._collect_drive_acks()
        self._heartbeat = False

    def _held(self) -> bool:
        return self.sim is not None and self.sim.stepping

    def pump(self, until=None, timeout=None) -> bool:
        """The logger's receive loop; while the simulator holds (lockstep) a wait for the robot
        (``until``: the start-up's Params, a command's Ack) grants board time: once the host has
        read all the robot sent before the hold, the clock runs LOCKSTEP_PROBE_S to the next
        multiple of it, and ``timeout`` is board time.  So each reply is seen, and the next
        command sent, at the same board time in every run.  Without ``until`` (idle) the clock
        stands."""
        sim = self.sim
        if until is None or not self._held():
            return super().pump(until, timeout)
        from host_tools import fil as F
        sim.start_hold()
        t_end = None if timeout is None else sim.held_at + timeout
        while True:
            if not super().pump(lambda: until() or sim.caught_up(), CATCH_UP_WALL_S):
                if until():
                    return True
                if not self._should_stop():
                    raise L.LoggerError("firmware in the loop: the robot's bytes of a hold did not arrive", 1)
                return False
            if until():
                return True
            if t_end is not None and sim.held_at >= t_end - 1e-9:
                return False
            try:
                sim.run_to((math.floor(sim.held_at / LOCKSTEP_PROBE_S + 1e-6) + 1) * LOCKSTEP_PROBE_S)
            except F.FilError as exc:
                raise L.LoggerError(f"firmware in the loop: {exc}", 1) from None

    def _serve_queue(self) -> None:
        while True:
            try:
                item = self.queue.get_nowait()
            except queue.Empty:
                return
            kind, name, values, done = item
            try:
                if kind == "heartbeat":  # here, in the one thread that writes to the port
                    self._heartbeat = bool(values["on"])
                    done["ok"] = True
                elif kind == "params":
                    self._request_params()
                    done["ok"] = True
                elif kind == "send":
                    seq = self.send(name, values)
                    if name == "Drive":
                        self.drive_sent += 1
                        self._drive_seqs.add(seq)
                    elif name == "Stop":
                        self.commands.append({"command": "Stop", "values": {}, "result": "sent"})
                    done["ok"] = True
                else:
                    self.command(name, values)
                    done["ok"] = True
            except (L.LoggerError, P.ProtocolError) as exc:
                done["error"] = str(exc)
            finally:
                done["event"].set()

    def _request_params(self) -> None:
        """RequestParams until a Params frame arrives, at most ACK_RETRIES times. The firmware
        answers the first (a reply waits for room in its transmit queue, before telemetry); the
        re-ask guards against a frame lost on the link."""
        n = self._params_count
        for _ in range(L.ACK_RETRIES):
            self.send("RequestParams")
            if self.pump(lambda: self._params_count > n, self.params_timeout_s):
                return
            if self._should_stop():
                return
        self.event("no_params_after_config", waited_s=self.params_timeout_s)

    def _collect_drive_acks(self) -> None:
        for seq in [s for s in self._drive_seqs if s in self.acks]:
            result, _ = self.acks.pop(seq)
            self._drive_seqs.discard(seq)
            name = self.d.result_names.get(result, str(result))
            if name != "ok":
                self.drive_rejected[name] = self.drive_rejected.get(name, 0) + 1
        if len(self._drive_seqs) > 200:  # never answered (a lossy link): forget the oldest
            for s in sorted(self._drive_seqs)[:100]:
                self._drive_seqs.discard(s)


def _model_commands(model: Any) -> tuple[tuple[float, float], dict]:
    if isinstance(model, (str, Path)):
        return M.firmware_commands(M.load_model(model), model)
    return M.firmware_commands(dict(model), "model")


class Robot:
    """One robot (a serial port or the firmware in the loop), recording into ``out`` while open.

    ``clamp``/``controller``/``mu``: the configuration commands of ``log``; ``model``: a
    model.json path or dict sent at open (SetMu + SetModel); ``drive_limits``: {"accel" m/s^2,
    "alpha" rad/s^2, "cmd_timeout" s} (SetDriveLimits; default protocol.json ``drive``, always
    sent so that meta.json states the limits in force).  ``fil=True``: the firmware in the loop
    (``elf``: default builds it; ``sim_args``: options of .build/fil/fil)."""

    def __init__(self, port: str | None = None, *, out: str | Path, fil: bool = False,
                 elf: str | Path | None = None, sim_args: Sequence[str] | None = None,
                 baud: int | None = None, clamp: bool | None = None, controller: str | None = None,
                 mu: tuple[float, float] | None = None, model: Any = None,
                 drive_limits: dict | None = None, description: str | None = None,
                 repeat_s: float = REPEAT_S, status: bool = False, open_timeout_s: float = 20.0):
        if (port is None) == (not fil):
            raise RobotError("give a port or fil=True (not both)", 2)
        self.d = P.definition()
        self.out = Path(out)
        self.repeat_s = float(repeat_s)
        self._sim = None
        self._target: tuple[float, float] | None = None
        self._last_send = 0.0
        self._closed = False
        self.code: int | None = None
        limits = dict(drive_limits or {k: self.d.spec["drive"][k] for k in ("accel", "alpha", "cmd_timeout")})
        self.d.raw_values("SetDriveLimits", limits)  # ProtocolError (a ValueError) when out of range
        fw_model = None
        if model is not None:
            if mu is not None:
                raise RobotError("model and mu exclude each other (the model carries mu)", 2)
            mu, fw_model = _model_commands(model)
        fil_meta = None
        if fil:
            from host_tools import fil as F
            F.build_sim()
            elf = Path(elf) if elf else F.build_firmware()
            args = list(sim_args or [])
            if "--t-end" not in args:
                args += ["--t-end", "3600"]
            if "--lockstep" not in args:  # drive_path holds the board clock (free running otherwise)
                args += ["--lockstep"]
            self._sim = F.Sim(elf, self.out, args)
            port = self._sim.pty
            fil_meta = {"command": self._sim.cmd[1:], "elf": str(elf)}
        baud = baud or self.d.baud

        sim = self._sim

        def open_port():
            import serial
            if sim is None:
                return serial.serial_for_url(port, baudrate=baud, timeout=0.05, write_timeout=0.5)
            # a held simulator sends nothing: a short read timeout lets the session thread
            # serve the drive's commands at once rather than after a blocked read
            return sim.wrap_port(serial.serial_for_url(port, baudrate=baud, timeout=0.002, write_timeout=0.5))

        self.session = DriveSession(str(self.out), open_port, str(port), baud, clamp=clamp, mu=mu,
                                    controller=controller, model=fw_model, drive_limits=limits,
                                    status=status, description=description or "drive (velocity commands)",
                                    d=self.d, fil_meta=fil_meta, sim=sim)
        self._thread = threading.Thread(target=self._run, name="ddrobot-session", daemon=True)
        self._thread.start()
        t_end = time.monotonic() + open_timeout_s
        while not self.session.ready.is_set():
            if not self._thread.is_alive() or time.monotonic() > t_end:
                why = self.session.end_reason or "the robot did not answer"
                self.close()
                raise RobotError(f"cannot drive: {why}", self.code if self.code else 1)
            time.sleep(0.01)

    def _run(self) -> None:
        try:
            self.code = self.session.run()
        except L.LoggerError as exc:
            self.session.end_reason = self.session.end_reason or str(exc)
            self.code = exc.code
        except Exception as exc:  # never leave the caller waiting on a dead thread
            self.session.end_reason = self.session.end_reason or f"{type(exc).__name__}: {exc}"
            self.code = 1

    # ---- context manager
    def __enter__(self) -> "Robot":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- state
    @property
    def run_dir(self) -> Path:
        return self.out

    @property
    def board_time_s(self) -> float | None:
        """Board time of the latest telemetry frame."""
        r = self.session.last_row
        return None if r is None else float(r["t_s"])

    @property
    def telemetry(self) -> dict | None:
        """The latest telemetry row (logger columns)."""
        return self.session.last_row

    @property
    def running(self) -> bool:
        return bool(self.session.running)

    def _alive(self) -> None:
        if self._closed or not self._thread.is_alive():
            raise RobotError(f"the session has ended: {self.session.end_reason or 'closed'}")

    def _queue(self, kind: str, name: str, values: dict | None = None, wait: bool = True) -> None:
        self._alive()
        done: dict = {"event": threading.Event()}
        self.session.queue.put((kind, name, values, done))
        if not wait:
            return
        while not done["event"].wait(0.05):
            self._alive()
        if "error" in done:
            raise RobotError(done["error"])

    # ---- commands
    def drive(self, v: float, w: float) -> None:
        """Velocity command: v (m/s, forward) and w (rad/s, + = left). Repeated every
        ``repeat_s`` by :meth:`sleep`/:meth:`drive_path` until changed; the first one starts
        drive mode."""
        values = {"linear": float(v), "angular": float(w)}
        self.d.raw_values("Drive", values)  # ProtocolError (ValueError) when out of range
        self._free_clock()
        self._target = (float(v), float(w))
        self._queue("send", "Drive", values, wait=False)
        self._last_send = time.monotonic()

    def _keep_alive(self) -> None:
        if self._target is not None and time.monotonic() - self._last_send >= self.repeat_s:
            self.drive(*self._target)

    def sleep(self, seconds: float, board: bool = True) -> None:
        """Wait ``seconds`` of board time (``board=False``: wall-clock time), repeating the
        current Drive command."""
        if board:
            self._free_clock()
        t0 = self.board_time_s if board else None
        w_end = time.monotonic() + seconds
        while True:
            self._alive()
            if board and t0 is not None:
                now = self.board_time_s
                if now is not None and now - t0 >= seconds:
                    return
            elif time.monotonic() >= w_end:
                return
            self._keep_alive()
            time.sleep(0.005)

    def drive_path(self, rows: Iterable[Sequence[float]]) -> None:
        """A scripted path: rows (t, v, w), t in seconds of board time, sorted; each (v, w) is
        commanded from its t until the next row's (the last one is held for one repeat period,
        then the robot is stopped: give a last row with v = w = 0 and a later t to let it ramp
        down before the stop).

        On a port, t counts from now and each command is sent when telemetry shows the board
        clock there (it lands where the link and the host's timing put it). In the firmware in
        the loop the board clock is held by the host (lockstep, :meth:`_drive_path_lockstep`):
        the first row starts the drive at the firmware's next inner tick, t0, and every later
        row is the target of the first outer tick at or after t0 + (t - the first row's t), sent
        half an outer period before that tick, so the run is the same whatever the host's speed
        (and, held since the start, starts at the same board time)."""
        rows = [tuple(float(x) for x in r) for r in rows]
        for i, r in enumerate(rows):
            if len(r) != 3 or not all(math.isfinite(x) for x in r):
                raise ValueError(f"path row {i + 1}: expected three finite numbers t, v, w, got {r}")
            if i and r[0] < rows[i - 1][0]:
                raise ValueError(f"path row {i + 1}: t = {r[0]} is before the previous row's {rows[i - 1][0]}")
            self.d.raw_values("Drive", {"linear": r[1], "angular": r[2]})
        self._wait_telemetry()
        if self._sim is not None and self._sim.lockstep and rows:
            self._drive_path_lockstep(rows)
            return
        t0 = self.board_time_s
        for i, (t, v, w) in enumerate(rows):
            while self.board_time_s - t0 < t:
                self._alive()
                self._keep_alive()
                time.sleep(0.002)
            self.drive(v, w)
        self.sleep(self.repeat_s)
        self.stop()

    def _drive_path_lockstep(self, rows: list[tuple[float, ...]]) -> None:
        """drive_path in the firmware in the loop: the simulator's board clock stops at holds the
        host grants (sim/fil/lockstep.cpp), and every host byte of the drive is written while it
        stands, so it reaches the robot at the board time of the hold, however late the host is.
        The session's wall-clock heartbeats pause meanwhile (a Drive every outer period keeps
        the link alive, on the board clock). The drive starts on a board-time grid of the least
        common multiple of the firmware's task periods (100 ms), after QUIET_GRIDS of them
        without host bytes. Held since the simulator's start (or the previous drive_path), that
        grid point is the same in every run; after a free-running stretch (sleep, drive) it is
        the next one after wherever the host let the clock run, and the drive is the same only
        relative to its t0 (hardware periods that do not divide 100 ms can move a frame by tens
        of microseconds)."""
        from host_tools import fil as F
        sim = self._sim
        assert sim is not None
        periods = {t["name"]: int(t["period_us"]) for t in self.d.tasks()}
        outer = periods["outer"] / 1e6
        grid = math.lcm(*periods.values()) / 1e6
        self._target = None  # no wall-clock repeats (_keep_alive) in between
        self._queue("heartbeat", "", {"on": False})  # done by the session thread: no heartbeat after it
        try:
            if sim.stepping:  # held since the start or the previous drive_path
                now = sim.run_to(math.ceil(sim.start_hold() / grid - 1e-9) * grid)
            else:
                now = sim.hold(grid)
            # every byte the host wrote before (configuration, heartbeats) delivered now, then a
            # quiet interval on the grid: the firmware idles into the same state in every run
            now = sim.run_to(now + QUIET_GRIDS * grid)
            t_first = rows[0][0]
            if t_first > 0:
                now = sim.run_to(now + t_first)
            self._send_written("Drive", rows[0][1:])
            t_sent = now
            t0 = None
            while t0 is None:  # the drive's first tick, from the first frame that reports it
                now = sim.run_to(now + LOCKSTEP_PROBE_S)
                t0 = self._drive_t0(t_sent)
                if t0 is None and now - t_sent > 1.0:
                    raise RobotError("the drive did not start within 1 s of board time: "
                                     f"{self.session.end_reason or 'no running frame'}")
            # each row's tick index on the drive's grid (row 0: tick 0)
            ticks = [0] + [max(1, math.ceil((t - t_first) / outer - 1e-9)) for t, _, _ in rows[1:]]
            n_hold = max(1, round(self.repeat_s / outer))
            last: tuple[float, ...] | None = tuple(rows[0][1:])
            last_t = t_sent
            k = 0
            for j in range(1, ticks[-1] + n_hold + 1):
                while k + 1 < len(rows) and ticks[k + 1] <= j:
                    k += 1
                mid = t0 + (j - 0.5) * outer  # half an outer period before tick j
                if mid > now:
                    now = sim.run_to(mid)
                target = tuple(rows[k][1:])
                if target != last or now - last_t >= self.repeat_s - 1e-9:
                    self._send_written("Drive", target)
                    last, last_t = target, now
            stop_at = t0 + (ticks[-1] + n_hold + 0.5) * outer
            now = sim.run_to(max(stop_at, now))
            self._send_written("Stop", None)
            # the robot comes to rest; the clock stays held there until the caller goes on
            # (_free_clock), so that a recording closed now ends at the same board time in
            # every run
            sim.run_to(now + STOP_SETTLE_S)
        except F.FilError as exc:
            self._free_clock()
            raise RobotError(f"firmware in the loop: {exc}") from None
        except BaseException:
            self._free_clock()
            raise

    def _free_clock(self) -> None:
        """Let a held simulator run on (after drive_path), its heartbeats on the wall clock."""
        if self._sim is None or not self._sim.stepping:
            return
        if self._thread.is_alive():
            self._queue("heartbeat", "", {"on": True})
        self._sim.release()

    def _send_written(self, name: str, vw: Sequence[float] | None) -> None:
        """Send a command and return once it is written to the port (before the next grant)."""
        if name == "Drive":
            assert vw is not None
            self._queue("send", "Drive", {"linear": float(vw[0]), "angular": float(vw[1])})
        else:
            self._queue("send", name, None)

    def _drive_t0(self, t_sent: float, timeout_s: float = 5.0) -> float | None:
        """While the simulator holds: the drive's first tick (board time, from the telemetry's
        ref_t0) once the logger has decoded the last telemetry frame the robot sent before the
        hold, if that frame was made after the Drive was sent and reports drive mode running;
        else None."""
        r = self._decoded_at_hold(timeout_s)
        running = 1 << self.d.flags["status"]["running"]
        drive = 1 << self.d.flags["status"]["drive_mode"]
        t = float(r["t_s"])
        st = int(r["status"])
        if t < t_sent or (st & running) == 0 or (st & drive) == 0:
            return None
        return round(t - (t - float(r["ref_t0_s"])) % _U32_S, 6)

    def _decoded_at_hold(self, timeout_s: float = 5.0) -> dict:
        """While the simulator holds: once the host has read every byte the robot sent before
        the hold (a frame in transmission too: a recording closed then ends with the same bytes
        in every run) and the logger has decoded the last telemetry frame among them, that row."""
        assert self._sim is not None
        last = self._sim.last_frame_t
        t_end = time.monotonic() + timeout_s
        while True:
            self._alive()
            r = self.session.last_row
            if r is not None and float(r["t_s"]) >= last - 5e-7 and self._sim.caught_up():
                return r
            if time.monotonic() > t_end:
                raise RobotError("the logger did not decode the robot's frames while the simulator held")
            time.sleep(0.002)

    def _held(self) -> bool:
        return self._sim is not None and self._sim.stepping

    def _grant_until(self, done, timeout_s: float, what: str) -> None:
        """While the simulator holds: grant board time in steps of LOCKSTEP_PROBE_S until
        ``done()`` (looked at once the logger has decoded what the robot sent before each hold);
        RobotError after ``timeout_s`` of board time."""
        from host_tools import fil as F
        sim = self._sim
        assert sim is not None
        try:
            t_end = sim.start_hold() + timeout_s
            while True:
                self._decoded_at_hold()
                if done():
                    return
                if sim.held_at >= t_end - 1e-9:
                    raise RobotError(what)
                sim.run_to((math.floor(sim.held_at / LOCKSTEP_PROBE_S + 1e-6) + 1) * LOCKSTEP_PROBE_S)
        except F.FilError as exc:
            raise RobotError(f"firmware in the loop: {exc}") from None

    def _wait_telemetry(self, timeout_s: float = 5.0) -> None:
        if self._held():
            self._grant_until(lambda: self.board_time_s is not None, timeout_s, "no telemetry from the robot")
            return
        t_end = time.monotonic() + timeout_s
        while self.board_time_s is None:
            self._alive()
            if time.monotonic() > t_end:
                raise RobotError("no telemetry from the robot")
            time.sleep(0.01)

    def stop(self) -> None:
        """Brake; drive mode ends (the next drive() starts it again, from the origin). A held
        simulator stays held (the Stop reaches the robot at the next grant)."""
        if not self._held():
            self._free_clock()
        self._target = None
        self._queue("send", "Stop", None)

    def wait_stopped(self, timeout_s: float = 5.0) -> None:
        """Wait until telemetry reports the robot not running (``timeout_s``: board time while
        the simulator holds, which grants it in steps; else wall time)."""
        if self._held():
            self._grant_until(lambda: not self.running, timeout_s, "the robot still reports running")
            return
        t_end = time.monotonic() + timeout_s
        while self.running:
            self._alive()
            if time.monotonic() > t_end:
                raise RobotError("the robot still reports running")
            time.sleep(0.01)

    def set_model(self, model: Any) -> None:
        """Send an analyzer model.json (path or dict) to the firmware: SetMu and SetModel, each
        acknowledged; then the robot's Params are asked for and waited for (meta.json records
        them). Only while
        stopped (the firmware answers busy while running). A held simulator stays held: the
        waits for the Acks grant board time (DriveSession.pump)."""
        mu, values = _model_commands(model)
        self._queue("command", "SetMu", {"mu_s": mu[0], "mu_k": mu[1]})
        self._queue("command", "SetModel", values)
        self.session.mu, self.session.model = mu, values
        self._queue("params", "RequestParams", None)

    def close(self) -> int:
        """Stop the robot, end the recording (the run folder is complete) and the simulator;
        returns the logger's exit code."""
        if self._closed:
            return self.code or 0
        held = self._sim is not None and self._sim.stepping  # after drive_path: stopped, at rest
        if held:
            try:  # the recording ends with the last frame before the hold
                self._decoded_at_hold()
            except RobotError:
                pass
        if self._thread.is_alive() and self.session.ready.is_set() and not held:
            try:
                self.stop()
                self.wait_stopped(2.0)
                self.sleep(0.2, board=False)  # the last frames after the stop
            except RobotError:
                pass
        self._closed = True
        self.session.stop()
        self._thread.join(30.0)
        if self._sim is not None:
            from host_tools import fil as F
            try:
                self._sim.release()  # the recording has ended: the simulator sees the hang-up
            except F.FilError:
                pass
            try:
                self._sim.wait(30.0)
            except F.FilError:
                self._sim.kill()
            try:
                self.session.fil_meta["summary"] = {
                    k: v for k, v in self._sim.summary().items()
                    if k in ("sim_s_per_wall_s", "encoder_isr", "tasks", "slip", "link")}
                self.session.write_meta()
            except (OSError, ValueError):
                pass
        return self.code or 0


# ================================================================================ CLI


def read_path(path: str) -> list[tuple[float, float, float]]:
    """A path file: CSV rows t, v, w (a header row with non-numbers is skipped, # comments);
    ValueError naming the row and column of a bad cell."""
    rows: list[tuple[float, float, float]] = []
    try:
        fh = open(path, newline="")
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    with fh:
        for n, rec in enumerate(csv.reader(fh), 1):
            if not rec or rec[0].strip().startswith("#"):
                continue
            if n == 1 and not _is_float(rec[0]):
                continue  # header
            if len(rec) != 3:
                raise ValueError(f"{path}: row {n}: expected 3 columns t, v, w, got {len(rec)}")
            vals = []
            for c, cell in enumerate(rec, 1):
                if not _is_float(cell) or not math.isfinite(float(cell)):
                    raise ValueError(f"{path}: row {n}, column {c}: {cell.strip()!r} is not a finite number")
                vals.append(float(cell))
            if rows and vals[0] < rows[-1][0]:
                raise ValueError(f"{path}: row {n}, column 1: t = {vals[0]:g} is before the previous row's")
            try:
                P.definition().raw_values("Drive", {"linear": vals[1], "angular": vals[2]})
            except P.ProtocolError as exc:
                col = 2 if "linear" in str(exc) else 3
                raise ValueError(f"{path}: row {n}, column {col}: {exc}") from None
            rows.append((vals[0], vals[1], vals[2]))
    if not rows:
        raise ValueError(f"{path}: no rows t, v, w")
    return rows


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


KEYS_HELP = ("keys: w/s faster/slower (+-0.05 m/s), a/d turn left/right (+-0.2 rad/s), "
             "space stop, q quit")


def _keys(bot: Robot, v_step: float = 0.05, w_step: float = 0.2) -> None:
    """Drive from a terminal's keys (raw mode), until q."""
    import select
    import termios
    import tty
    fd = sys.stdin.fileno()
    old = termios.tcgetattr(fd)
    v = w = 0.0
    print(KEYS_HELP, file=sys.stderr)
    try:
        tty.setcbreak(fd)
        while True:
            if select.select([sys.stdin], [], [], 0.02)[0]:
                k = sys.stdin.read(1)
                if k == "q":
                    break
                if k == " ":
                    v = w = 0.0
                    bot.stop()
                    continue
                v += {"w": v_step, "s": -v_step}.get(k, 0.0)
                w += {"a": w_step, "d": -w_step}.get(k, 0.0)
                v = max(-1.0, min(1.0, round(v, 3)))
                w = max(-6.0, min(6.0, round(w, 3)))
                bot.drive(v, w)
                r = bot.telemetry or {}
                sys.stderr.write(f"\rv {v:+.2f} m/s  w {w:+.2f} rad/s  board t {r.get('t_s', 0):.1f} s   ")
                sys.stderr.flush()
            else:
                bot.sleep(0.0)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)


def add_arguments(p: argparse.ArgumentParser) -> None:
    d = P.definition()
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run folder to record into")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--port", help="serial device, pty path or pyserial URL")
    src.add_argument("--fil", action="store_true", help="the firmware in the loop (simavr + plant)")
    p.add_argument("--path", metavar="FILE", help="scripted path: CSV rows t (s, board clock), v (m/s), "
                   "w (rad/s); without it, keys at the terminal (" + KEYS_HELP + ")")
    p.add_argument("--model", metavar="MODEL_JSON", help="send an analyzer model.json first (SetMu + SetModel)")
    p.add_argument("--accel", type=float, default=d.spec["drive"]["accel"], help="|dv/dt| limit, m/s^2")
    p.add_argument("--alpha", type=float, default=d.spec["drive"]["alpha"], help="|dw/dt| limit, rad/s^2")
    p.add_argument("--cmd-timeout", type=float, default=d.spec["drive"]["cmd_timeout"],
                   help="without a Drive for this long the robot ramps to rest, s")
    p.add_argument("--clamp", choices=["on", "off"],
                   help="the torque clamp at tau_max on or off (default: as the robot has it)")
    p.add_argument("--controller", choices=sorted(d.enums["controller"]),
                   help="the velocity loop the robot runs (default: as the robot has it)")
    p.add_argument("--elf", help="with --fil: firmware ELF (default: build it)")
    p.add_argument("sim_options", nargs=argparse.REMAINDER, help="with --fil, after '--': options of .build/fil/fil")


def main(a: argparse.Namespace) -> int:
    try:
        rows = read_path(a.path) if a.path else None
        if rows is None and not sys.stdin.isatty():
            raise ValueError("no --path and stdin is not a terminal: give --path FILE")
        sim_args = [o for o in a.sim_options if o != "--"]
        if sim_args and not a.fil:
            raise ValueError("simulator options need --fil")
        bot = Robot(a.port, out=a.out, fil=a.fil, elf=a.elf, sim_args=sim_args,
                    clamp=None if a.clamp is None else a.clamp == "on", controller=a.controller,
                    model=a.model, drive_limits={"accel": a.accel, "alpha": a.alpha,
                                                 "cmd_timeout": a.cmd_timeout})
    except (ValueError, M.ModelError) as exc:  # ProtocolError is a ValueError
        log.error("%s", exc)
        return 2
    except RobotError as exc:
        log.error("%s", exc)
        return exc.code
    except Exception as exc:  # the simulator or firmware build (FilError)
        log.error("%s", exc)
        return 2
    try:
        if rows is not None:
            bot.drive_path(rows)
        else:
            _keys(bot)
    except KeyboardInterrupt:
        pass
    except RobotError as exc:
        log.error("%s", exc)
    finally:
        code = bot.close()
    s = bot.session.stats
    log.log(STATUS, "%s: %s rows, %s Drive commands; end: %s", a.out, s["telemetry_rows"],
            bot.session.drive_sent, bot.session.end_reason)
    return code
