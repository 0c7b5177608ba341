"""Telemetry logger: ``python -m host_tools log --port PORT --out RUN_DIR [...]``.

Opens the XBee serial port (any pyserial URL: a device or pty path, ``socket://host:port``,
``loop://``), asks the robot for its parameters, optionally sets the clamp / friction
coefficients / velocity loop (``--controller improved|thesis``, command SetController) and
starts an experiment (keeping it alive with heartbeats), decodes every frame and writes a
``ddrun/1`` run folder (shared/spec/run-format.md) through host_tools.runfmt:

    meta.json      parameters the robot reported (or the defaults, said so), the velocity loop
                   it reported ("controller_variant": "improved" or "thesis"; absent when the
                   robot reported none and none was commanded), the commands sent, and a
                   "logger" section with the link statistics and the end reason
    telemetry.csv  the spec columns + seq, host_t_s and every other telemetry field
    raw.bin        every byte received, unmodified (nothing is lost, even undecodable bytes)
    events.jsonl   one JSON object per line, {"host_t_s", "kind", ...}; kinds: start, end,
                   command, ack, params, bad_params, params_mismatch, no_params, no_params_after_config,
                   rejected_block (raw_offset
                   into raw.bin, length, reason cobs/short/long/crc/version), gap (missing),
                   duplicate, stale, time_not_increasing, robot_reset, failsafe (reason),
                   unknown_type, bad_length, disconnect, reconnect

Files are flushed as they are written; the folder is complete and readable after Ctrl-C, a
pulled cable (the logger waits for the port to come back and carries on) or a robot power loss
(a board reset is recognised from the boot counter in telemetry, ``boot_count``, and the board
time is kept increasing; an old frame arriving late is stale, never a reset).

Guarantees:
* SIGINT (Ctrl-C), SIGTERM and SIGHUP stop the recording the same way, exit 0: the bytes
  already read are decoded to the end, every frame that passed the CRC is written as a row or
  counted (duplicate, stale, unknown type, ...), events.jsonl gets its "end" line, meta.json
  its row count and end_reason ("interrupted (Ctrl-C)", "stopped by SIGTERM", ...).  A second
  signal interrupts at once (the folder is still closed the same way).
* A full disk (or any other write error) stops the recording with exit 1 and a message: a
  256 KB reserve file kept in the run folder while recording is deleted so that meta.json
  (end_reason "write failed: ...", the rows on disk, frames_not_written for the verified frames
  still queued, never retried) and the end of events.jsonl can still be written; a row or event
  line torn by the failure is cut off, so every file holds whole lines; raw.bin holds what was
  written before the failure.
* --out that is an existing file, cannot be created or written, or holds a recorded run:
  exit 2 before the port is opened.

``--attach-groundtruth TRACKER.csv`` (without ``--port``) adds an external tracker's CSV
(columns t_s, x_m, y_m, optional phi_rad, on the tracker's own clock) to a recorded run as
groundtruth.csv, shifting its time by ``--gt-offset``, by an offset estimated by
cross-correlating the speed from odometry with the speed from the tracker, or (``--gt-unix-time``,
a tracker stamped by a PC clock) through the logger's own host clock recorded in meta.json.
"""
from __future__ import annotations

import argparse
import errno
import json
import math
import os
import signal
import sys
import threading
import time
from typing import Any, Callable

import numpy as np

from host_tools import protocol as P
from host_tools import runfmt

HEARTBEAT_S = 0.2
ACK_TIMEOUT_S = 0.4
ACK_RETRIES = 3
RECONNECT_POLL_S = 0.5
STATUS_EVERY_S = 0.5
FLUSH_EVERY_S = 0.2
RESERVE_BYTES = 256 * 1024  # kept free in the run folder for the final meta.json and events
RESERVE_NAME = ".logger-reserve"
RUN_FILES = ("meta.json", "telemetry.csv", "raw.bin", "events.jsonl")
STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


class _Stopped(Exception):
    """Raised where a stop request (signal) must end a wait that would otherwise fail."""


class LoggerError(Exception):
    """A problem that ends the recording; ``code`` is the exit code (1 failed, 2 bad input)."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


def _f32(v: float) -> float:
    """A float32 from the robot as the shortest decimal that reads back as the same float32."""
    return float(f"{v:.7g}") if float(np.float32(f"{v:.7g}")) == float(np.float32(v)) else float(f"{v:.9g}")


def _decimals(scale: float) -> int:
    return max(0, int(math.ceil(-math.log10(scale))) + 1) if scale < 1 else 0


class TelemetryColumns:
    """Column layout of telemetry.csv derived from the protocol definition."""

    def __init__(self, d: P.Definition):
        self.msg = d.by_name["Telemetry"]
        self.fields = [f for f in self.msg.fields if f.name != "t_us"]
        required = list(runfmt.TELEMETRY_COLUMNS)
        have = {f.column for f in self.msg.fields}
        missing = [c for c in required if c not in have]
        if missing:  # the definition must carry every spec column
            raise LoggerError(f"{d.path}: Telemetry lacks spec column(s) {missing}", 2)
        rest = [f.column for f in self.fields if f.column not in required]
        self.columns = required + ["seq", "host_t_s"] + rest
        self.index = {f.name: i for i, f in enumerate(self.msg.fields)}
        self._conv = []
        for i, f in enumerate(self.msg.fields):
            if f.name == "t_us":
                continue
            if f.scale is None:
                self._conv.append((f.column, i, None, 0))
            else:
                self._conv.append((f.column, i, f.scale, _decimals(f.scale)))

    def row(self, raws: tuple, t_s: float, seq: int, host_t: float) -> dict[str, Any]:
        out: dict[str, Any] = {"t_s": round(t_s, 6), "seq": seq, "host_t_s": round(host_t, 4)}
        for col, i, scale, nd in self._conv:
            r = raws[i]
            out[col] = r if scale is None else (r * scale if scale >= 1 else round(r * scale, nd))
        return out


def describe_experiment(cmd: dict) -> str:
    p, a, ta, T = cmd["profile"], cmd["wheel_accel"], cmd["accel_time"], cmd["duration"]
    base = f"{a:g} rad/s^2 wheel acceleration for {ta:g} s, then hold; {T:g} s in all"
    if p == "straight":
        return "straight line, " + base
    if p == "arc":
        return f"arc of radius {cmd['radius']:g} m, " + base
    return f"figure eight of loop radius {cmd['radius']:g} m, " + base


class Logger:
    """One recording session.  ``open_port`` returns a pyserial-like object (read, write,
    in_waiting, close) or raises; it is called again to reconnect."""

    def __init__(self, out_dir: str, open_port: Callable[[], Any], port_name: str, baud: int,
                 experiment: dict | None = None, clamp: bool | None = None,
                 mu: tuple[float, float] | None = None, record_s: float | None = None,
                 controller: str | None = None, reconnect_timeout_s: float = 30.0, params_timeout_s: float = 1.0,
                 status: bool = True, description: str | None = None,
                 d: P.Definition | None = None, clock: Callable[[], float] = time.monotonic):
        self.d = d or P.definition()
        self.out = out_dir
        self.open_port = open_port
        self.port_name = port_name
        self.baud = baud
        self.experiment = experiment
        self.clamp = clamp
        self.mu = mu
        if controller is not None and controller not in self.d.enums["controller"]:
            raise LoggerError(f"controller {controller!r} is not one of "
                              f"{sorted(self.d.enums['controller'])}", 2)
        self.controller = controller
        self.record_s = record_s
        self.reconnect_timeout_s = reconnect_timeout_s
        self.params_timeout_s = params_timeout_s
        self.show_status = status
        self.description = description
        self.clock = clock
        self.cols = TelemetryColumns(self.d)
        self.dec = P.StreamDecoder(self.d.version, self.d.max_payload)
        self.port = None
        self.tx_seq = 0
        # statistics
        self._queue: list[P.Frame] = []  # verified frames not yet handled
        self._stop = False
        self._signals = 0
        self._write_error: OSError | None = None
        self.stats = {"frames": 0, "telemetry_rows": 0, "gaps": 0, "lost_frames": 0,
                      "duplicates": 0, "stale": 0, "robot_resets": 0, "disconnects": 0,
                      "unknown_type": 0, "bad_length": 0, "bytes": 0}
        self.last_seq: int | None = None
        self.boot: int | None = None  # boot_count of the current boot
        self.boots_seen: set[int] = set()
        self.last_t_us: int | None = None
        self.t_epoch = 0.0  # seconds added to the unwrapped board time (after resets)
        self.t_wraps = 0
        self.last_t_s: float | None = None
        self.last_host_t: float | None = None
        self.last_row: dict | None = None
        self.params: dict | None = None
        self.acks: dict[int, tuple[int, int]] = {}
        self.commands: list[dict] = []
        self.running = False
        self._run_frames = 0
        self._heartbeat = False
        self._last_failsafe = 0
        self._params_count = 0
        self._params_before_config = 0
        self._config_sent = False
        self.end_reason = ""
        self._errors_logged = 0
        self._t0 = 0.0
        self._rate_mark = (0.0, 0)
        self._fps = 0.0

    # ------------------------------------------------------------------ files
    def _meta(self) -> dict:
        dflt = self.d.robot_defaults
        meta: dict[str, Any] = {
            "format": runfmt.FORMAT,
            "experiment": self.description or (describe_experiment(self.experiment) if self.experiment
                                               else "free recording (no experiment command sent)"),
            "source": "robot",
            "robot": dict(dflt["robot"]),
            "motor": dict(dflt["motor"]),
            "encoder_ppr": dflt["encoder_ppr"],
            "periods_s": {t["name"]: round(t["period_us"] * 1e-6, 9) for t in self.d.tasks()},
            # this project's firmware ramps a clamped wheel's duty every millisecond and
            # reports the duty of the frame's moment (docs/firmware.md)
            "duty_ramp": True,
        }
        mu_ok = self.mu is not None and self._acked("SetMu")
        clamp_ok = self.clamp is not None and self._acked("SetClamp")
        if mu_ok:
            meta["robot"]["mu_s"], meta["robot"]["mu_k"] = self.mu
        meta["torque_clamp"] = bool(self.clamp) if clamp_ok else False
        p = self.params
        # Params received after the configuration commands: what the robot now uses
        fresh = p is not None and self._config_sent and self._params_count > self._params_before_config
        if p is not None:
            for k in meta["robot"]:
                if k in ("mu_s", "mu_k") and mu_ok and not fresh:
                    continue  # Params predate SetMu: the commanded (acknowledged) values apply
                meta["robot"][k] = _f32(p[k])
            for k in meta["motor"]:
                meta["motor"][k] = _f32(p[k])
            meta["encoder_ppr"] = int(p["encoder_ppr"])
            meta["periods_s"] = {k: round(p[f"{k}_period_us"] * 1e-6, 9) for k in ("inner", "outer", "telemetry")}
            if fresh or not clamp_ok:
                meta["torque_clamp"] = bool(p["clamp_on"])
        variant = self._variant_reported(fresh)
        if variant is not None:
            meta["controller_variant"] = variant
        meta["commands"] = self.commands
        self.stats["frames"] = self.dec.frames
        meta["logger"] = dict(
            self.stats, port=self.port_name, baud=self.baud, protocol_version=self.d.version,
            host_t0_unix_s=round(getattr(self, "_t0_unix", 0.0), 6),
            crc_errors=self.dec.crc_errors, rejected_blocks=dict(self.dec.rejected),
            params_source="robot" if p is not None else "defaults (the robot never reported Params)",
            firmware_id=(f"{p['firmware_id']:08x}" if p is not None else None),
            robot_baud=(p["baud"] if p is not None else None),
            end_reason=self.end_reason or "recording")
        return meta

    def _variant_reported(self, fresh: bool) -> str | None:
        """The velocity loop for meta.json: the robot's Params when they follow the
        configuration (or none was sent), else the acknowledged SetController, else None."""
        ctl_ok = self.controller is not None and self._acked("SetController")
        p = self.params
        if p is not None and (fresh or not ctl_ok):
            names = {v: k for k, v in self.d.enums["controller"].items()}
            return names.get(int(p["controller"]), f"unknown (code {int(p['controller'])})")
        return self.controller if ctl_ok else None

    def _acked(self, name: str) -> bool:
        return any(c["command"] == name and c["result"] == "ok" for c in self.commands)

    def write_meta(self) -> None:
        path = os.path.join(self.out, "meta.json")
        meta = runfmt.validate_meta(self._meta(), path)
        tmp = path + ".tmp"
        try:
            with open(tmp, "w") as fh:
                fh.write(json.dumps(meta, indent=2) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            try:  # never leave a half-written meta.json.tmp next to the last good meta.json
                os.remove(tmp)
            except OSError:
                pass
            raise

    def event(self, kind: str, **kw) -> None:
        kw = {"host_t_s": round(self.clock() - self._t0, 4), "kind": kind, **kw}
        self.events.write(json.dumps(kw) + "\n")

    # ------------------------------------------------------------------ port
    def _connect(self, first: bool) -> bool:
        try:
            self.port = self.open_port()
            return True
        except Exception as exc:  # pyserial raises SerialException / OSError / ValueError
            self.port = None
            if first:
                raise LoggerError(f"cannot open port {self.port_name}: {exc}", 2) from None
            return False

    def _lost(self, exc: Exception) -> None:
        self.stats["disconnects"] += 1
        self.event("disconnect", error=str(exc), pending_bytes=self.dec.pending())
        self._status(force=True, note=f"port lost ({exc}); waiting for it to return")
        try:
            self.port.close()
        except Exception:
            pass
        self.port = None
        self.write_meta()

    def _reconnect(self) -> None:
        t_lost = self.clock()
        while True:
            if self._connect(first=False):
                self.event("reconnect", after_s=round(self.clock() - t_lost, 3))
                self._status(force=True, note="port back")
                return
            if self.clock() - t_lost > self.reconnect_timeout_s:
                raise LoggerError(f"port {self.port_name} did not return within "
                                  f"{self.reconnect_timeout_s:g} s", 1)
            if self._should_stop():
                return
            time.sleep(RECONNECT_POLL_S)

    def send(self, name: str, values: dict | None = None) -> int:
        """Send one command (validated against the definition). Returns its seq."""
        seq = self.tx_seq
        frame = self.d.encode(name, seq, values)  # ProtocolError on a bad value
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        if self.port is not None:
            try:
                self.port.write(frame)
            except Exception as exc:
                self._lost(exc)
        return seq

    def command(self, name: str, values: dict | None = None) -> None:
        """Send a command and wait for its Ack (retrying); LoggerError if rejected/unanswered."""
        rec = {"command": name, "values": values or {}, "result": None}
        self.commands.append(rec)
        for attempt in range(ACK_RETRIES):
            if self._stop:
                rec["result"] = "not sent: stopping" if attempt == 0 else "no ack: stopping"
                raise _Stopped()
            seq = self.send(name, values)
            self.event("command", command=name, seq=seq, values=values or {}, attempt=attempt + 1)
            if self.pump(lambda: seq in self.acks, ACK_TIMEOUT_S) or seq in self.acks:
                result, detail = self.acks.pop(seq)
                rname = self.d.result_names.get(result, f"code {result}")
                rec["result"] = rname
                if rname != "ok":
                    msg = self.d.by_name[name]
                    where = (f" (field {msg.fields[detail].name})"
                             if rname == "out_of_range" and detail < len(msg.fields) else "")
                    self.write_meta()
                    raise LoggerError(f"robot rejected {name}: {rname}{where}", 1)
                self.write_meta()
                return
        rec["result"] = "no ack"
        self.write_meta()
        raise LoggerError(f"robot did not acknowledge {name} after {ACK_RETRIES} tries", 1)

    # ------------------------------------------------------------------ receive
    def pump(self, until: Callable[[], bool] | None = None, timeout: float | None = None) -> bool:
        """Read and handle input until ``until()`` is true (returns True) or ``timeout`` passes
        or the session should stop (returns False).  Handles disconnects and heartbeats."""
        t_end = None if timeout is None else self.clock() + timeout
        while True:
            if until is not None and until():
                return True
            if self._should_stop() or (t_end is not None and self.clock() >= t_end):
                return False
            if self.port is None:
                self._reconnect()
                continue
            try:
                n = self.port.in_waiting
                data = self.port.read(n if n > 0 else 1)
            except Exception as exc:
                self._lost(exc)
                continue
            if data:
                self._last_rx = self.clock()
                self._receive(data)
            now = self.clock()
            if self._heartbeat and now - self._last_hb >= HEARTBEAT_S:
                self._last_hb = now
                self.send("Heartbeat")
            if now - self._last_flush >= FLUSH_EVERY_S:
                self._flush()
            self._status()

    def _receive(self, data: bytes) -> None:
        try:
            self.raw.write(data)
        finally:  # decoded even when raw.bin could not take it (a full disk): counted
            self.stats["bytes"] += len(data)
            self._queue.extend(self.dec.feed(data))
        self._drain()

    def _drain(self) -> None:
        """Handle the verified frames in the queue.  A frame leaves the queue only after it
        was handled, so an interruption (a second Ctrl-C) leaves it for close() to handle: a
        frame handled twice is then counted as a duplicate, never lost."""
        if len(self.dec.errors) > self._errors_logged:
            for off, n, reason in self.dec.errors[self._errors_logged:]:
                self.event("rejected_block", raw_offset=off, length=n, reason=reason)
            self._errors_logged = len(self.dec.errors)
        while self._queue:
            self._frame(self._queue[0])
            self._queue.pop(0)

    def _frame(self, f: P.Frame) -> None:
        msg = self.d.by_type.get(f.type)
        if msg is None or msg.dir != "robot_to_host":
            self.stats["unknown_type"] += 1
            self.event("unknown_type", type=f.type, seq=f.seq, raw_offset=f.offset)
            return
        if len(f.payload) != msg.size:
            self.stats["bad_length"] += 1
            self.event("bad_length", type=f.type, seq=f.seq, length=len(f.payload), raw_offset=f.offset)
            return
        raws = msg.struct.unpack(f.payload)
        host_t = self.clock() - self._t0
        if msg.name == "Telemetry":
            self._telemetry(f, raws, host_t)
            return
        if self._sequence(f, host_t, t_us=None) == "drop":
            return
        if msg.name == "Ack":
            cmd_seq, _cmd_type, result, detail = raws
            self.acks[cmd_seq] = (result, detail)
            self.event("ack", cmd_seq=cmd_seq, result=self.d.result_names.get(result, result), detail=detail)
        elif msg.name == "Params":
            new = dict(zip(msg.field_names(), raws))
            shown = {k: (v if not isinstance(v, float) or not math.isfinite(v) else _f32(v)) for k, v in new.items()}
            old, self.params = self.params, new
            try:  # a robot reporting NaN or nonsense must not stop the recording
                runfmt.validate_meta(self._meta(), "Params")
            except runfmt.RunFormatError as exc:
                self.params = old
                self.event("bad_params", reason=str(exc), seq=f.seq,
                           **{k: (v if not isinstance(v, float) or math.isfinite(v) else str(v)) for k, v in shown.items()})
                sys.stderr.write(f"\nwarning: ignoring the robot's Params (seq {f.seq}): {exc}\n")
                return
            self._params_count += 1
            self.event("params", **shown)
            self._check_params_vs_commands()
            self.write_meta()

    def _check_params_vs_commands(self) -> None:
        """After SetMu / SetClamp, the robot's own report must show the commanded values."""
        if not self._config_sent:
            return
        p, bad = self.params, []
        if self.mu is not None:
            for k, v in zip(("mu_s", "mu_k"), self.mu):
                if abs(p[k] - v) > 1e-4:
                    bad.append(f"{k} {p[k]:.4f} (commanded {v})")
        if self.clamp is not None and bool(p["clamp_on"]) != self.clamp:
            bad.append(f"clamp_on {p['clamp_on']} (commanded {int(self.clamp)})")
        if self.controller is not None and p["controller"] != self.d.enums["controller"][self.controller]:
            bad.append(f"controller {p['controller']} (commanded {self.controller})")
        if bad:
            self.event("params_mismatch", detail=bad)
            sys.stderr.write("\nwarning: the robot reports " + ", ".join(bad) + "\n")

    def _sequence(self, f: P.Frame, host_t: float, t_us: int | None,
                  boot: int | None = None) -> str:
        """Track the robot's frame counter.  Returns "ok", "reset" (the board restarted: seq
        and clock start again) or "drop" (a duplicate or stale frame, recorded as an event).

        A reset is recognised only from what a reset changes: the boot counter in telemetry
        (``boot_count``, EEPROM, +1 per boot).  A boot number never seen before is a reset; a
        frame of an earlier boot is stale.  Within one boot the board time decides: later than
        the last frame means new (a seq jump is a gap, however long the outage), not later
        means a duplicate or a stale frame.  Other frames only drop exact repeats."""
        if boot is not None:
            if self.boot is None:
                self.boot = boot
                self.boots_seen.add(boot)
            elif boot != self.boot:
                if boot in self.boots_seen:  # a late frame from before the last reset
                    self.stats["stale"] += 1
                    self.event("stale", seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset,
                               boot=boot, current_boot=self.boot)
                    return "drop"
                self._reset(f, host_t, t_us, boot)
                self.boot = boot
                self.boots_seen.add(boot)
                self.last_seq = f.seq
                return "reset"
        if self.last_seq is None:
            self.last_seq = f.seq
            return "ok"
        ahead = (f.seq - self.last_seq) & 0xFFFF
        if t_us is None:  # Ack / Params
            if ahead == 0:
                self.stats["duplicates"] += 1
                self.event("duplicate", seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset)
                return "drop"
            if ahead < 0x8000:
                self._count_gap(f, ahead - 1)
                self.last_seq = f.seq
            return "ok"
        if self.last_t_us is None:  # first telemetry frame (or the first after a reset)
            if 0 < ahead < 0x8000:
                self._count_gap(f, ahead - 1)
            self.last_seq = f.seq
            return "ok"
        dt = (t_us - self.last_t_us) & 0xFFFFFFFF
        if 0 < dt < 0x80000000:
            if ahead >= 0x8000 or ahead == 0:
                # the 16-bit counter is ambiguous after a long outage: count from the board time
                period = self.d.by_name["Telemetry"].spec.get("rate_hz", 50)
                missing = max(0, int(round(dt * 1e-6 * period)) - 1)
            else:
                missing = ahead - 1
            self._count_gap(f, missing)
            self.last_seq = f.seq
            return "ok"
        kind = "duplicate" if ahead == 0 else "stale"
        self.stats["duplicates" if ahead == 0 else "stale"] += 1
        self.event(kind, seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset)
        return "drop"

    def _count_gap(self, f: P.Frame, missing: int) -> None:
        if missing > 0:
            self.stats["gaps"] += 1
            self.stats["lost_frames"] += missing
            self.event("gap", after_seq=self.last_seq, seq=f.seq, missing=missing, raw_offset=f.offset)

    def _reset(self, f: P.Frame, host_t: float, t_us: int | None, boot: int) -> None:
        self.stats["robot_resets"] += 1
        if t_us is not None and self.last_t_s is not None:
            # keep board time increasing: continue from the last frame + the host time elapsed
            elapsed = max(host_t - (self.last_host_t or host_t), 1e-6)
            self.t_epoch = self.last_t_s + elapsed - t_us * 1e-6
            self.t_wraps = 0
            self.last_t_us = None
        self.event("robot_reset", seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset,
                   t_epoch_s=round(self.t_epoch, 6), boot=boot, last_boot=self.boot)

    def _telemetry(self, f: P.Frame, raws: tuple, host_t: float) -> None:
        t_us = raws[0]
        if self._sequence(f, host_t, t_us, raws[self.cols.index["boot_count"]]) == "drop":
            return
        if self.last_t_us is not None and t_us < self.last_t_us:
            self.t_wraps += 1  # accepted as forward in time: the u32 microsecond clock wrapped
        t_s = self.t_epoch + (self.t_wraps * 2**32 + t_us) * 1e-6
        if self.last_t_s is not None and not t_s > self.last_t_s:
            self.stats["stale"] += 1
            self.event("time_not_increasing", seq=f.seq, t_s=t_s, last_t_s=self.last_t_s)
            return
        row = self.cols.row(raws, t_s, f.seq, host_t)
        self.writer.write_row(row)
        self.stats["telemetry_rows"] += 1
        self.last_t_us, self.last_t_s, self.last_host_t, self.last_row = t_us, t_s, host_t, row
        status = raws[self.cols.index["status"]]
        flags = self.d.flags["status"]
        self.running = bool(status & (1 << flags["running"]))
        if self.running:
            self._run_frames += 1
        failsafe = raws[self.cols.index["failsafe"]]
        if failsafe != self._last_failsafe:
            names = {v: k for k, v in self.d.enums["failsafe"].items()}
            self.event("failsafe", seq=f.seq, reason=names.get(failsafe, failsafe))
            self._last_failsafe = failsafe

    # ------------------------------------------------------------------ status
    def _flush(self) -> None:
        self._last_flush = self.clock()
        self.writer.flush()
        self.raw.flush()
        self.events.flush()

    def _status(self, force: bool = False, note: str = "") -> None:
        if not self.show_status:
            return
        now = self.clock()
        if not force and now - self._last_status < STATUS_EVERY_S:
            return
        t_mark, n_mark = self._rate_mark
        if now - t_mark >= 1.0:
            self._fps = (self.stats["telemetry_rows"] - n_mark) / (now - t_mark)
            self._rate_mark = (now, self.stats["telemetry_rows"])
        self._last_status = now
        r = self.last_row
        quiet = now - self._last_rx
        if quiet > 1.0:
            live = f"NO DATA for {quiet:.0f} s (robot off? out of range?)"
        elif r is not None:
            radius = (self.params or self.d.robot_defaults["robot"])["r"]
            v = radius * (r["omega_r"] + r["omega_l"]) / 2
            live = (f"t {r['t_s']:.2f} s  v {v:+.3f} m/s  w_r {r['omega_r']:+.2f} w_l {r['omega_l']:+.2f} rad/s"
                    f"  {'RUN' if self.running else 'idle'}")
        else:
            live = "no telemetry yet"
        line = (f"{self._fps:5.1f} frames/s  rows {self.stats['telemetry_rows']}  crc {self.dec.crc_errors}"
                f"  bad {self.dec.bad_blocks - self.dec.crc_errors}  gaps {self.stats['gaps']}"
                f" (lost {self.stats['lost_frames']})  dup {self.stats['duplicates']}  | {live}")
        if note:
            line += f"  [{note}]"
        sys.stderr.write("\r" + line[:160].ljust(160) + ("\n" if note else ""))
        sys.stderr.flush()

    # ------------------------------------------------------------------ session
    def _should_stop(self) -> bool:
        if self._stop:
            return True
        if self.record_s is not None and self.clock() - self._t0 >= self.record_s:
            self.end_reason = self.end_reason or f"recorded {self.record_s:g} s"
            return True
        return False

    def prepare_out(self) -> None:
        """Create the run folder and check that it can be written, before the port is
        opened; LoggerError (exit 2) when --out is unusable."""
        shown = runfmt.display(self.out)
        if os.path.exists(self.out) and not os.path.isdir(self.out):
            raise LoggerError(f"--out {shown} exists and is not a folder", 2)
        for f in RUN_FILES[1:]:
            if os.path.exists(os.path.join(self.out, f)):
                raise LoggerError(f"{runfmt.display(os.path.join(self.out, f))} already exists; "
                                  "refusing to overwrite a recorded run", 2)
        reserve = os.path.join(self.out, RESERVE_NAME)
        try:
            os.makedirs(self.out, exist_ok=True)
            with open(reserve, "wb") as fh:
                fh.write(bytes(RESERVE_BYTES))
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            self._free_reserve()
            raise LoggerError(f"--out {shown} cannot be written: {exc.strerror or exc}", 2) from None

    def _free_reserve(self) -> None:
        try:
            os.remove(os.path.join(self.out, RESERVE_NAME))
        except OSError:
            pass

    def _on_signal(self, signum, _frame) -> None:
        self._signals += 1
        if self._signals > 1:
            raise KeyboardInterrupt  # a second signal: stop at once (close() still runs)
        name = signal.Signals(signum).name
        self.end_reason = self.end_reason or ("interrupted (Ctrl-C)" if name == "SIGINT"
                                              else f"stopped by {name}")
        self._stop = True

    def _install_signals(self) -> dict:
        if threading.current_thread() is not threading.main_thread():
            return {}
        old = {}
        for name in STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                old[sig] = signal.signal(sig, self._on_signal)
        return old

    def run(self) -> int:
        self.prepare_out()
        self._stop = False
        self._t0 = self.clock()
        self._t0_unix = time.time()  # host_t_s = 0 in Unix time, for trackers stamped by a PC clock
        self._last_hb = self._last_flush = self._last_status = self._last_rx = self._t0
        self._rate_mark = (self._t0, 0)
        old_handlers = self._install_signals()
        code = 0
        try:
            try:
                self._connect(first=True)
                self.writer = runfmt.RunWriter(self.out, self._meta_for_writer(),
                                               columns=self.cols.columns)
                self.raw = open(os.path.join(self.out, "raw.bin"), "wb")
                self.events = open(os.path.join(self.out, "events.jsonl"), "w")
            except LoggerError:
                self._free_reserve()
                raise
            except OSError as exc:
                self._free_reserve()
                raise LoggerError(f"--out {runfmt.display(self.out)} cannot be written: "
                                  f"{exc.strerror or exc}", 2) from None
            try:
                self._session()
            except (KeyboardInterrupt, _Stopped):
                self.end_reason = self.end_reason or "interrupted (Ctrl-C)"
                if self.experiment is not None:
                    try:
                        self.send("Stop")
                    except Exception:
                        pass
            except LoggerError as exc:
                self.end_reason = str(exc)
                code = exc.code
            except OSError as exc:  # a write failed: disk full, file system gone read-only
                self._write_error = exc
                self.end_reason = f"write failed: {exc.strerror or exc}"
                code = 1
            finally:
                if self.end_reason == "" and self._stop:
                    self.end_reason = "stopped"
                if self.close() and code == 0:
                    code = 1
        finally:
            for sig, h in old_handlers.items():
                signal.signal(sig, h)
        return code

    def _session(self) -> None:
        self.event("start", port=self.port_name, baud=self.baud)
        self.write_meta()
        self.send("RequestParams")
        if not self.pump(lambda: self.params is not None, self.params_timeout_s):
            if self._stop:
                raise _Stopped()
            self.event("no_params", waited_s=self.params_timeout_s)
        if self.clamp is not None:
            self.command("SetClamp", {"on": int(self.clamp)})
        if self.mu is not None:
            self.command("SetMu", {"mu_s": self.mu[0], "mu_k": self.mu[1]})
        if self.controller is not None:
            self.command("SetController", {"variant": self.controller})
        if self.clamp is not None or self.mu is not None or self.controller is not None:
            # meta.json records what the robot reports it now uses, not what we asked for
            self._config_sent = True
            n = self._params_before_config = self._params_count
            self.send("RequestParams")
            if not self.pump(lambda: self._params_count > n, self.params_timeout_s):
                if self._stop:
                    raise _Stopped()
                self.event("no_params_after_config", waited_s=self.params_timeout_s)
        if self.experiment is not None:
            self._heartbeat = True  # from the Start on, so the failsafe never fires early
            self.command("Start", self.experiment)
            if self.pump(lambda: self._run_frames > 0 and not self.running):
                self._heartbeat = False
                self.end_reason = "experiment finished"
                self.pump(None, 0.3)  # the last frames after the end
            elif self._stop and self.end_reason.startswith(("interrupted", "stopped")):
                raise _Stopped()
        else:
            self.pump()

    def _meta_for_writer(self) -> dict:
        return self._meta()

    def _cut_torn_line(self, path: str) -> None:
        """After a failed write: cut a text file back to its last complete line."""
        try:
            with open(path, "rb+") as fh:
                data = fh.read()
                keep = data.rfind(b"\n") + 1
                if keep < len(data):
                    fh.truncate(keep)
        except OSError:
            pass

    def close(self) -> bool:
        """Handle the frames still queued, close the files, finalize meta.json.  Returns True
        when a write failed (during the recording or here)."""
        # every verified frame already read is written or counted before the files close; after
        # a write failure none is retried (a half-buffered row written twice would repeat a
        # time): the queued frames are counted as not written
        if self._write_error is None:
            for _ in range(2):  # a second try after a second Ctrl-C
                try:
                    self._drain()
                    break
                except KeyboardInterrupt:
                    continue
                except Exception as exc:  # OSError: the disk filled up just now
                    self._write_error = exc if isinstance(exc, OSError) else OSError(str(exc))
                    break
        failed = self._write_error is not None
        if failed:
            # free the reserve for the buffered rows, meta.json and the end of events.jsonl
            self._free_reserve()
            self.end_reason = self.end_reason or f"write failed: {self._write_error}"
            self.stats["frames_not_written"] = len(self._queue)
        for name in ("writer", "raw", "events"):
            obj = getattr(self, name, None)
            if obj is None:
                continue
            try:
                if name == "events":
                    self.event("end", reason=self.end_reason or "stopped",
                               pending_bytes=self.dec.pending())
                obj.flush()
            except OSError as exc:
                failed = True
                self._write_error = self._write_error or exc
            try:
                obj.close()
            except Exception:
                failed = True
        if failed:
            for f in ("telemetry.csv", "events.jsonl"):
                self._cut_torn_line(os.path.join(self.out, f))
            try:  # meta.json states the rows that reached the disk
                with open(os.path.join(self.out, "telemetry.csv"), "rb") as fh:
                    on_disk = max(0, fh.read().count(b"\n") - 1)
                self.stats["rows_lost_at_write_failure"] = self.stats["telemetry_rows"] - on_disk
                self.stats["telemetry_rows"] = on_disk
            except OSError:
                pass
        try:
            self.write_meta()
        except Exception as exc:  # never lose the data over a meta problem
            failed = True
            sys.stderr.write(f"\nwarning: could not rewrite meta.json: {exc}\n")
        self._free_reserve()
        if self.port is not None:
            try:
                self.port.close()
            except Exception:
                pass
        self._status(force=True, note=self.end_reason or "stopped")
        return failed

    def stop(self) -> None:
        self._stop = True


# ======================================================================= ground truth


def estimate_offset(t_tel: np.ndarray, x_odo: np.ndarray, y_odo: np.ndarray,
                    t_trk: np.ndarray, x_trk: np.ndarray, y_trk: np.ndarray,
                    max_offset_s: float = 10.0, dt: float = 0.01) -> tuple[float, float]:
    """Offset (s) such that t_board = t_tracker + offset, by cross-correlating the speed along
    the path from odometry with that from the tracker.  Returns (offset, peak correlation)."""
    def speed(t, x, y):
        g = np.arange(t[0], t[-1], dt)
        if g.size < 4:
            raise LoggerError("too few samples to estimate the clock offset; pass --gt-offset", 2)
        xi, yi = np.interp(g, t, x), np.interp(g, t, y)
        s = np.hypot(np.gradient(xi, dt), np.gradient(yi, dt))
        k = max(1, int(round(0.05 / dt)))  # 50 ms moving average against tracker noise
        s = np.convolve(s, np.ones(k) / k, mode="same")
        # tracker dropouts: no speed where the original samples are further apart than 0.25 s
        idx = np.searchsorted(t, g)
        idx = np.clip(idx, 1, len(t) - 1)
        gap = (t[idx] - t[idx - 1]) > 0.25
        s[gap] = np.nan
        return g, s

    g_a, s_a = speed(t_tel, x_odo, y_odo)
    g_b, s_b = speed(t_trk, x_trk, y_trk)
    lags = np.arange(-max_offset_s, max_offset_s + dt / 2, dt)
    best = (-2.0, 0.0)
    scores = np.full(lags.size, np.nan)
    for i, lag in enumerate(lags):
        # tracker sample at tracker time tt is board time tt + lag
        b = np.interp(g_a - lag, g_b, s_b, left=np.nan, right=np.nan)
        ok = np.isfinite(b) & np.isfinite(s_a)
        if ok.sum() < max(20, 0.2 * s_a.size):
            continue
        a_, b_ = s_a[ok] - s_a[ok].mean(), b[ok] - b[ok].mean()
        den = math.sqrt(float(a_ @ a_) * float(b_ @ b_))
        if den <= 0:
            continue
        scores[i] = float(a_ @ b_) / den
        if scores[i] > best[0]:
            best = (scores[i], lag)
    peak, lag = best
    if peak <= -2.0:
        raise LoggerError("the tracker and the telemetry do not overlap in time within "
                          f"+-{max_offset_s:g} s; pass --gt-offset", 1)
    i = int(np.nanargmax(scores))
    if 0 < i < lags.size - 1 and np.isfinite(scores[i - 1]) and np.isfinite(scores[i + 1]):
        y0, y1, y2 = scores[i - 1], scores[i], scores[i + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            lag = lags[i] + 0.5 * (y0 - y2) / den * dt
    return float(lag), float(peak)


def attach_groundtruth(run_dir: str, csv_path: str, offset_s: float | None = None,
                       max_offset_s: float = 10.0, min_correlation: float = 0.5,
                       overwrite: bool = False, set_start_pose: bool = False, unix_time: bool = False) -> dict:
    try:
        run = runfmt.load_run(run_dir, check_units=False)
        trk = runfmt._read_csv(csv_path, runfmt.GROUNDTRUTH_REQUIRED, may_be_empty=("phi_rad",))
        runfmt._check_time(trk["t_s"], csv_path)
    except runfmt.RunFormatError as exc:
        raise LoggerError(str(exc), 2) from None
    info: dict[str, Any] = {"file": os.path.basename(csv_path), "rows": int(trk["t_s"].size)}
    if unix_time:
        # tracker stamped by a PC clock (Unix seconds): map through the logger's host clock
        t0 = (run.meta.get("logger") or {}).get("host_t0_unix_s")
        if not t0 or "host_t_s" not in run.telemetry:
            raise LoggerError(f"{run_dir}: --gt-unix-time needs a run recorded by this logger "
                              "(meta.json logger.host_t0_unix_s and the host_t_s column)", 2)
        tel = run.telemetry
        # board time - host reception time: reception latency only lowers it, so take a high
        # percentile (the least delayed frames) rather than the maximum (robust to outliers)
        lag = tel["t_s"] - (t0 + tel["host_t_s"])
        offset_s = float(np.percentile(lag, 95))
        info.update(method="unix time via the logger's host clock (host_t0_unix_s + host_t_s)",
                    offset_s=round(offset_s, 4), host_board_spread_s=round(float(lag.max() - lag.min()), 4))
    elif offset_s is None:
        tel = run.telemetry
        lag, peak = estimate_offset(tel["t_s"], tel["x_odo_m"], tel["y_odo_m"],
                                    trk["t_s"], trk["x_m"], trk["y_m"], max_offset_s)
        info.update(method="speed cross-correlation (odometry vs tracker)",
                    offset_s=round(lag, 4), peak_correlation=round(peak, 4))
        if peak < min_correlation:
            raise LoggerError(f"clock offset estimate is unreliable (peak correlation {peak:.2f} < "
                              f"{min_correlation}); pass --gt-offset", 1)
        offset_s = lag
    else:
        info.update(method="given", offset_s=offset_s)
    phi = trk.get("phi_rad")
    start_pose = None
    if set_start_pose:
        # the tracker's pose at the first telemetry frame, on the board clock
        t0 = float(run.telemetry["t_s"][0])
        tb = trk["t_s"] + offset_s
        if not tb[0] <= t0 <= tb[-1]:
            raise LoggerError(f"{csv_path}: the tracker does not cover the run start (board time {t0:.3f} s)", 1)
        ok = np.isfinite(phi) if phi is not None else np.zeros(tb.shape, bool)
        if ok.sum() < 2:
            raise LoggerError(f"{csv_path}: --gt-start-pose needs the phi_rad column", 2)
        ph = np.unwrap(phi[ok])
        start_pose = [float(np.interp(t0, tb, trk["x_m"])), float(np.interp(t0, tb, trk["y_m"])),
                      float(np.interp(t0, tb[ok], ph))]
        info["start_pose_from"] = "tracker pose at the first telemetry frame"
    try:
        runfmt.write_groundtruth(run_dir, trk["t_s"] + offset_s, trk["x_m"], trk["y_m"], phi,
                                 overwrite=overwrite)
    except runfmt.RunFormatError as exc:
        raise LoggerError(str(exc), 2) from None
    mpath = os.path.join(run_dir, "meta.json")
    with open(mpath) as fh:
        meta = json.load(fh)
    meta["groundtruth"] = info
    if start_pose is not None:
        meta["start_pose"] = [round(v, 6) for v in start_pose]
    tmp = mpath + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(meta, fh, indent=2)
        fh.write("\n")
    os.replace(tmp, mpath)
    return info


# ================================================================================ CLI


def add_arguments(p: argparse.ArgumentParser) -> None:
    d = P.definition()
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run folder to write (or to attach to)")
    p.add_argument("--port", help="serial device, pty path or pyserial URL (socket://h:p, loop://)")
    p.add_argument("--baud", type=int, default=d.baud, help=f"default {d.baud} (protocol.json link.baud)")
    p.add_argument("--experiment", choices=sorted(d.enums["profile"]), help="send Start with this profile")
    p.add_argument("--accel", type=float, default=48.0, help="wheel acceleration, rad/s^2 (default 48)")
    p.add_argument("--accel-time", type=float, default=0.5, help="acceleration phase, s (default 0.5)")
    p.add_argument("--duration", type=float, default=3.0, help="experiment length, s (default 3)")
    p.add_argument("--radius", type=float, default=0.0, help="arc / figure-eight radius, m (+ = left)")
    p.add_argument("--clamp", choices=["on", "off"], help="send SetClamp before starting")
    p.add_argument("--mu-s", type=float, help="send SetMu (with --mu-k)")
    p.add_argument("--mu-k", type=float)
    p.add_argument("--controller", choices=sorted(d.enums["controller"]),
                   help="send SetController before starting: the cascade's velocity loop "
                   "(the firmware's default: improved); meta.json controller_variant says which ran")
    p.add_argument("--model", metavar="MODEL_JSON", help="send SetMu with the mu_s/mu_k of an analyzer "
                   "model.json (ddmodel/1): the firmware's tau_max follows (instead of --mu-s/--mu-k)")
    p.add_argument("--description", help="meta.json 'experiment' text (default: from the command)")
    p.add_argument("--record-s", type=float, help="stop after this many seconds (default: until the "
                   "experiment ends, or Ctrl-C)")
    p.add_argument("--reconnect-timeout", type=float, default=30.0,
                   help="give up when a lost port has not returned after this many s (default 30)")
    p.add_argument("--params-timeout", type=float, default=1.0, help="wait for Params, s (default 1)")
    p.add_argument("--quiet", action="store_true", help="no live status line")
    p.add_argument("--attach-groundtruth", metavar="TRACKER_CSV",
                   help="add an external tracker CSV (t_s,x_m,y_m[,phi_rad]) to the run in --out")
    p.add_argument("--gt-offset", type=float, help="tracker clock offset, s (t_board = t_tracker + offset); "
                   "estimated by speed cross-correlation when omitted")
    p.add_argument("--gt-max-offset", type=float, default=10.0, help="search window, s (default 10)")
    p.add_argument("--gt-unix-time", action="store_true", help="the tracker's t_s is Unix time from a PC clock: "
                   "align through the logger's host clock instead of estimating")
    p.add_argument("--gt-start-pose", action="store_true", help="set meta.json start_pose to the tracker's "
                   "pose at the first telemetry frame (tracker in room coordinates; needs phi_rad)")


def main(args: argparse.Namespace) -> int:
    if args.attach_groundtruth:
        try:
            info = attach_groundtruth(args.out, args.attach_groundtruth, args.gt_offset, args.gt_max_offset,
                                      set_start_pose=args.gt_start_pose, unix_time=args.gt_unix_time)
        except LoggerError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return exc.code
        print(f"groundtruth.csv written: offset {info['offset_s']} s ({info['method']}"
              + (f", peak correlation {info['peak_correlation']}" if "peak_correlation" in info else "") + ")")
        return 0
    if not args.port:
        print("error: --port is required (or --attach-groundtruth)", file=sys.stderr)
        return 2
    d = P.definition()
    experiment = None
    try:
        if args.experiment:
            experiment = {"profile": args.experiment, "wheel_accel": args.accel,
                          "accel_time": args.accel_time, "duration": args.duration, "radius": args.radius}
            d.raw_values("Start", experiment)
        mu = None
        if (args.mu_s is None) != (args.mu_k is None):
            raise P.ProtocolError("--mu-s and --mu-k go together")
        if args.mu_s is not None:
            mu = (args.mu_s, args.mu_k)
        if getattr(args, "model", None):
            if mu is not None:
                raise P.ProtocolError("--model and --mu-s/--mu-k exclude each other")
            from host_tools import model as M
            mu = M.firmware_mu(M.load_model(args.model), args.model)
        if mu is not None:
            d.raw_values("SetMu", {"mu_s": mu[0], "mu_k": mu[1]})
    except (P.ProtocolError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    record_s = args.record_s
    if record_s is None and experiment is not None:
        record_s = args.duration + 5.0  # safety net if the end of the run is never reported

    def open_port():
        import serial
        return serial.serial_for_url(args.port, baudrate=args.baud, timeout=0.05, write_timeout=0.5)

    lg = Logger(args.out, open_port, args.port, args.baud, experiment=experiment,
                clamp=None if args.clamp is None else args.clamp == "on", mu=mu, record_s=record_s,
                controller=getattr(args, "controller", None),
                reconnect_timeout_s=args.reconnect_timeout, params_timeout_s=args.params_timeout,
                status=not args.quiet, description=args.description, d=d)
    try:
        code = lg.run()
    except LoggerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.code
    s = lg.stats
    print(f"\n{args.out}: {s['telemetry_rows']} rows, {lg.dec.crc_errors} CRC errors, "
          f"{lg.dec.bad_blocks - lg.dec.crc_errors} other bad blocks, {s['gaps']} gaps "
          f"({s['lost_frames']} frames lost), {s['duplicates']} duplicates, {s['robot_resets']} resets, "
          f"{s['disconnects']} disconnects; end: {lg.end_reason}", file=sys.stderr)
    if code:
        print(f"error: {lg.end_reason}", file=sys.stderr)
    return code
