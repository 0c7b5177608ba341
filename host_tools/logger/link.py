"""The serial (XBee) link of a recording session.

:class:`LinkMixin` is the part of :class:`~host_tools.logger.session.Logger` that owns the
port: opening it (``open_port`` returns a pyserial-like object: read, write, in_waiting,
close), noticing a lost port and waiting for it to return, sending frames, and the receive
loop :meth:`LinkMixin.pump`, which also sends the heartbeats and flushes the run files on
time.  Every byte read goes to raw.bin and to the stream decoder; the verified frames go to
:meth:`~host_tools.logger.frames.FramesMixin._drain`.
"""
from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Any, Callable, Iterator

from host_tools import protocol as P
from host_tools.logger.errors import LoggerError

if TYPE_CHECKING:  # the state and methods the other parts provide (parts.py)
    from host_tools.logger.parts import SessionParts
else:
    SessionParts = object

HEARTBEAT_S = 0.2
RECONNECT_POLL_S = 0.5
FLUSH_EVERY_S = 0.2


class LinkMixin(SessionParts):
    """Port, send and receive of one recording session."""

    def _init_link(self) -> None:
        self.dec = P.StreamDecoder(self.d.version, self.d.max_payload)
        self.port: Any = None  # a pyserial-like object (read, write, in_waiting, close)
        self.tx_seq = 0
        self._heartbeat = False

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

    def _close_port(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except Exception:
                pass

    def send(self, name: str, values: dict[str, Any] | None = None) -> int:
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
        with self._uninterrupted():  # in raw.bin and decoded, or neither
            try:
                self.raw.write(data)
            finally:  # decoded even when raw.bin could not take it (a full disk): counted
                self.stats["bytes"] += len(data)
                self._queue.extend(self.dec.feed(data))
        self._drain()

    @contextlib.contextmanager
    def _uninterrupted(self) -> Iterator[None]:
        """A step of input handling that a second signal must not cut: the signal handler
        (session.Logger._on_signal) leaves the interruption due, raised here at the step's
        end (the outermost step's, when steps nest)."""
        self._handling += 1
        try:
            yield
        finally:
            self._handling -= 1
        if self._interrupt_due and not self._handling:
            self._interrupt_due = False
            raise KeyboardInterrupt
