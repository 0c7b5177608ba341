"""Verified frames -> telemetry rows, events and link statistics.

:class:`TelemetryColumns` is the layout of telemetry.csv, derived from the protocol definition.
:class:`FramesMixin` is the part of :class:`~host_tools.logger.session.Logger` that handles
each verified frame: it keeps the robot's frame counter, boot number and board time (gaps,
duplicates, stale frames, resets, a wrapped microsecond clock), turns Telemetry into rows,
records Acks and Params, and counts everything in ``stats``.  It uses the session's
``d``, ``clock``, ``event``, ``writer``, ``write_meta`` and ``_meta``.
"""
from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from host_tools import protocol as P
from host_tools import runfmt
from host_tools.logger.errors import LoggerError

if TYPE_CHECKING:  # the state and methods the other parts provide (parts.py)
    from host_tools.logger.parts import SessionParts
else:
    SessionParts = object

CONFIRM_FRAMES = 2   # following frames that must continue a reset, a jump or the first frame
MAX_AHEAD_S = 2.0    # board time may run ahead of the host time elapsed by this much

log = logging.getLogger(__name__)


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
        self._conv: list[tuple[str, int, float | None, int]] = []
        for i, f in enumerate(self.msg.fields):
            if f.name == "t_us":
                continue
            if f.scale is None:
                self._conv.append((f.column, i, None, 0))
            else:
                self._conv.append((f.column, i, f.scale, _decimals(f.scale)))

    def row(self, raws: tuple[Any, ...], t_s: float, seq: int, host_t: float) -> dict[str, Any]:
        out: dict[str, Any] = {"t_s": round(t_s, 6), "seq": seq, "host_t_s": round(host_t, 4)}
        for col, i, scale, nd in self._conv:
            r = raws[i]
            out[col] = r if scale is None else (r * scale if scale >= 1 else round(r * scale, nd))
        return out


class FramesMixin(SessionParts):
    """Frame handling and statistics of one recording session."""

    def _init_frames(self) -> None:
        self.cols = TelemetryColumns(self.d)
        self._queue: list[P.Frame] = []  # verified frames not yet handled
        self.stats = {"frames": 0, "telemetry_rows": 0, "gaps": 0, "lost_frames": 0,
                      "duplicates": 0, "stale": 0, "robot_resets": 0, "disconnects": 0,
                      "unknown_type": 0, "bad_length": 0, "bytes": 0, "implausible": 0}
        self.last_seq: int | None = None
        self.boot: int | None = None  # boot_count of the current boot
        self.boots_seen: set[int] = set()
        self.last_t_us: int | None = None
        self.t_epoch = 0.0  # seconds added to the unwrapped board time (after resets)
        self.t_wraps = 0
        self.last_t_s: float | None = None
        self.last_host_t: float | None = None
        self.last_row: dict[str, Any] | None = None
        self.params: dict[str, Any] | None = None
        self.acks: dict[int, tuple[int, int]] = {}
        self.running = False
        self._run_frames = 0
        self._last_failsafe = 0
        self._params_count = 0
        self._errors_logged = 0
        self._chain: _Chain | None = None  # telemetry held until following frames confirm it
        self._flagged_seqs: list[int] = []  # flagged since the last row: received, not lost

    def _drain(self) -> None:
        """Handle the verified frames in the queue.  A frame is handled and leaves the queue
        as one step that a second Ctrl-C waits for (``_uninterrupted``); a write error in it
        leaves the frame queued (counted as not written by close(), never retried)."""
        if len(self.dec.errors) > self._errors_logged:
            for off, n, reason in self.dec.errors[self._errors_logged:]:
                self.event("rejected_block", raw_offset=off, length=n, reason=reason)
            self._errors_logged = len(self.dec.errors)
        while self._queue:
            with self._uninterrupted():  # handled and off the queue, or neither
                self._frame(self._queue[0])
                self._queue.pop(0)

    def _end_frames(self) -> None:
        """At the end of the recording: telemetry still held for confirmation.  The first
        frames of a recording stand on their own; a reset or a jump that no following frame
        confirmed is not recognised: its frames are flagged (kept in events.jsonl)."""
        ch, self._chain = self._chain, None
        if ch is None:
            return
        if ch.kind == "first":
            self._commit(ch)
        else:
            self._flag(ch, "unconfirmed " + ch.kind)

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
        if self._sequence(f) == "drop":
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
                log.warning(f"ignoring the robot's Params (seq {f.seq}): {exc}")
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
        assert p is not None  # called on a Params frame, after it is stored
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
            log.warning("the robot reports " + ", ".join(bad))

    def _sequence(self, f: P.Frame) -> str:
        """Track the robot's frame counter for Ack and Params frames (they carry neither board
        time nor boot number): "drop" for an exact repeat of the frame received before it,
        else "ok".  Gaps are counted in the order the frames arrived: while Telemetry is held
        for confirmation (:meth:`_telemetry`), the frame's seq waits in the chain with it and
        is counted when the chain is committed or flagged; else at once (a seq jump is a gap)."""
        ch = self._chain
        if ch is not None:
            before = ch.replies[-1][1] if ch.replies and ch.replies[-1][0] == len(ch.frames) else ch.frames[-1][0]
            if f.seq == before.seq:
                self._count_duplicate(f, before.seq)
                return "drop"
            ch.replies.append((len(ch.frames), f))
            return "ok"
        if self.last_seq is not None and f.seq == self.last_seq:
            self._count_duplicate(f, self.last_seq)
            return "drop"
        self._count_reply_seq(f)
        return "ok"

    def _count_duplicate(self, f: P.Frame, last_seq: int) -> None:
        self.stats["duplicates"] += 1
        self.event("duplicate", seq=f.seq, last_seq=last_seq, raw_offset=f.offset)

    def _count_reply_seq(self, f: P.Frame) -> None:
        """Gaps before an Ack or Params frame (a seq behind the last is ignored: it cannot be
        placed without a board time).  Flagged telemetry in between was received: not lost."""
        if self.last_seq is None:
            self.last_seq = f.seq
            return
        ahead = (f.seq - self.last_seq) & 0xFFFF
        if 0 < ahead < 0x8000:
            self._count_gap(f, ahead - 1 - self._flagged_between(ahead))
            self.last_seq = f.seq

    def _flagged_between(self, ahead: int) -> int:
        """Frames flagged since the last row with a seq between the last seq and ``ahead``
        after it: received, not lost."""
        assert self.last_seq is not None
        last = self.last_seq
        return sum(1 for s in self._flagged_seqs if 0 < (s - last) & 0xFFFF < ahead)

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

    def _telemetry(self, f: P.Frame, raws: tuple[Any, ...], host_t: float) -> None:
        """A verified Telemetry frame.  A frame that continues the current boot in time is a
        row at once.  One that would change what the rows mean -- a boot number never seen
        (a reset), a board time far ahead of the host time elapsed (a jump), or the first
        frame of the recording -- is held until CONFIRM_FRAMES following frames continue it;
        a frame that continues the old state instead shows it was implausible (a bit error
        the CRC missed, a robot bug): it is flagged and kept in events.jsonl with all its
        values, and the recording carries on without losing a row."""
        item = (f, raws, host_t)
        t_us, boot = raws[0], raws[self.cols.index["boot_count"]]
        ch = self._chain
        if ch is not None:
            tail_f, tail_raws, tail_host = ch.frames[-1]
            rel = self._relation(tail_raws[0], tail_raws[self.cols.index["boot_count"]], tail_host,
                                 t_us, boot, host_t)
            if rel == "next":
                ch.frames.append(item)
                if len(ch.frames) > CONFIRM_FRAMES:
                    self._chain = None
                    self._commit(ch)
                return
            if rel == "same" or any(c[0].seq == f.seq and c[1][0] == t_us for c in ch.frames):
                self.stats["duplicates"] += 1
                self.event("duplicate", seq=f.seq, last_seq=tail_f.seq, raw_offset=f.offset)
                return
            if rel == "earlier":  # a reordered frame of the chain's own boot
                self._drop(f, "stale", boot)
                return
            old = self._classify(t_us, boot, host_t)
            if old in ("duplicate", "stale", "stale_boot") and ch.kind != "first":
                self._drop(f, old, boot)  # a late frame of the old state: the chain stands
                return
            self._chain = None
            self._flag(ch, f"not confirmed: seq {f.seq} continues the recording instead"
                       if old == "ok" else f"not confirmed: seq {f.seq} does not continue it")
        kind = self._classify(t_us, boot, host_t)
        if kind == "ok":
            self._accept(f, raws, host_t)
        elif kind in ("first", "reset", "jump"):
            self._chain = _Chain(kind, [item])
        else:
            self._drop(f, kind, boot)

    def _relation(self, t0_us: int, boot0: int, host0: float, t_us: int, boot: int,
                  host_t: float) -> str:
        """How a frame stands to one before it: "next" (same boot, later by a plausible
        step), "same" (same boot and time), "earlier" (same boot, earlier by at most
        MAX_AHEAD_S: arrived late), else "other"."""
        if boot != boot0:
            return "other"
        dt = (t_us - t0_us) & 0xFFFFFFFF
        if dt == 0:
            return "same"
        if dt < 0x80000000:
            return "next" if dt * 1e-6 <= max(host_t - host0, 0.0) + MAX_AHEAD_S else "other"
        return "earlier" if (2**32 - dt) * 1e-6 <= MAX_AHEAD_S else "other"

    def _classify(self, t_us: int, boot: int, host_t: float) -> str:
        """A Telemetry frame against the rows written so far: "first", "ok", "reset" (a boot
        number never seen), "jump" (same boot, board time far ahead of the host time
        elapsed), "duplicate", "stale" (not later), "stale_boot" (a boot before the current)."""
        if self.boot is None:
            return "first"
        if boot != self.boot:
            return "stale_boot" if boot in self.boots_seen else "reset"
        if self.last_t_us is None:
            return "ok"  # the first frame after a confirmed reset
        dt = (t_us - self.last_t_us) & 0xFFFFFFFF
        if dt == 0:
            return "duplicate"
        if dt >= 0x80000000:
            return "stale"
        elapsed = max(host_t - (self.last_host_t if self.last_host_t is not None else host_t), 0.0)
        return "ok" if dt * 1e-6 <= elapsed + MAX_AHEAD_S else "jump"

    def _drop(self, f: P.Frame, kind: str, boot: int) -> None:
        if kind == "duplicate":
            self.stats["duplicates"] += 1
            self.event("duplicate", seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset)
        elif kind == "stale_boot":
            self.stats["stale"] += 1
            self.event("stale", seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset,
                       boot=boot, current_boot=self.boot)
        else:
            self.stats["stale"] += 1
            self.event("stale", seq=f.seq, last_seq=self.last_seq, raw_offset=f.offset)

    def _commit(self, ch: "_Chain") -> None:
        """A confirmed chain: its first frame starts the boot (a reset), continues after a
        jump or starts the recording; every frame of it becomes a row."""
        f, raws, host_t = ch.frames[0]
        boot = raws[self.cols.index["boot_count"]]
        if ch.kind == "reset":
            self._reset(f, host_t, raws[0], boot)
            self.last_seq = None
        if ch.kind in ("reset", "first"):
            self.boot = boot
            self.boots_seen.add(boot)
        for i, (f, raws, host_t) in enumerate(ch.frames, 1):
            self._accept(f, raws, host_t)
            for _, reply in (r for r in ch.replies if r[0] == i):  # the replies that came after it
                self._count_reply_seq(reply)

    def _flag(self, ch: "_Chain", reason: str) -> None:
        """Frames that no following frame confirmed: kept (events.jsonl, all values) and
        counted, never written as rows (their time cannot be placed among the rows)."""
        for f, raws, host_t in ch.frames:
            self.stats["implausible"] += 1
            self._flagged_seqs.append(f.seq)
            values = self.cols.row(raws, 0.0, f.seq, host_t)
            del values["t_s"]
            self.event("implausible", seq=f.seq, raw_offset=f.offset, t_us=raws[0],
                       boot=raws[self.cols.index["boot_count"]], current_boot=self.boot,
                       reason=reason, values=values)
        for _, reply in ch.replies:  # the Acks and Params that came in between, in order
            self._count_reply_seq(reply)

    def _accept(self, f: P.Frame, raws: tuple[Any, ...], host_t: float) -> None:
        t_us = raws[0]
        self._count_seq(f, t_us)
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
        on_row = getattr(self, "on_row", None)
        if on_row is not None:
            on_row(row)
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

    def _count_seq(self, f: P.Frame, t_us: int) -> None:
        """Gaps before an accepted telemetry frame, from seq (or the board time when the
        16-bit counter is ambiguous after a long outage)."""
        if self.last_seq is None:
            self._flagged_seqs = []
            self.last_seq = f.seq
            return
        ahead = (f.seq - self.last_seq) & 0xFFFF
        between = self._flagged_between(ahead)  # frames flagged in between: not lost
        self._flagged_seqs = []
        if self.last_t_us is None:  # the first frame after a reset
            if 0 < ahead < 0x8000:
                self._count_gap(f, ahead - 1 - between)
        elif ahead >= 0x8000 or ahead == 0:
            dt = (t_us - self.last_t_us) & 0xFFFFFFFF
            period = self.d.by_name["Telemetry"].spec.get("rate_hz", 50)
            self._count_gap(f, max(0, int(round(dt * 1e-6 * period)) - 1))
        else:
            self._count_gap(f, ahead - 1 - between)
        self.last_seq = f.seq


class _Chain:
    """Telemetry frames held until confirmed: ``kind`` "first", "reset" or "jump";
    ``replies``, the Ack and Params frames that came while it was held, each with the number
    of its frames before it (their seqs are counted in that order when it is settled)."""

    def __init__(self, kind: str, frames: list[tuple[P.Frame, tuple[Any, ...], float]]):
        self.kind = kind
        self.frames = frames
        self.replies: list[tuple[int, P.Frame]] = []
