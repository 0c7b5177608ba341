"""Verified frames -> telemetry rows, events and link statistics.

:class:`TelemetryColumns` is the layout of telemetry.csv, derived from the protocol definition.
:class:`FramesMixin` is the part of :class:`~host_tools.logger.session.Logger` that handles
each verified frame: it keeps the robot's frame counter, boot number and board time (gaps,
duplicates, stale frames, resets, a wrapped microsecond clock), turns Telemetry into rows,
records Acks and Params, and counts everything in ``stats``.  It uses the session's
``d``, ``clock``, ``event``, ``writer``, ``write_meta`` and ``_meta``.
"""
from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np

from host_tools import protocol as P
from host_tools import runfmt
from host_tools.logger.errors import LoggerError


def shortest_f32(v: float) -> float:
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


class FramesMixin:
    """Frame handling and statistics of one recording session."""

    def _init_frames(self) -> None:
        self.cols = TelemetryColumns(self.d)
        self._queue: list[P.Frame] = []  # verified frames not yet handled
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
        self.running = False
        self._run_frames = 0
        self._last_failsafe = 0
        self._params_count = 0
        self._errors_logged = 0

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
            shown = {k: (v if not isinstance(v, float) or not math.isfinite(v) else shortest_f32(v)) for k, v in new.items()}
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
        self.reftrack.row(row)  # the reference the firmware tracks (meta.json "reference")
        self.stats["telemetry_rows"] += 1
        if getattr(self, "on_row", None) is not None:
            self.on_row(row)
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
