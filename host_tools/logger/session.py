"""One recording session: the experiment's command sequence from start to end.

:class:`Logger` joins the link (:mod:`.link`), the frame handling and statistics
(:mod:`.frames`) and the run folder (:mod:`.runfolder`), and runs the session: ask for the
robot's parameters, send the configuration commands (SetClamp, SetMu, SetController, each
acknowledged, retried), ask again for what the robot now uses, start the experiment (with
heartbeats) and record until it ends, ``record_s`` passes or a signal stops it.  It also
shows the live status line.
"""
from __future__ import annotations

import logging
import signal
import threading
import sys
import time
from types import FrameType
from typing import Any, Callable

from host_tools import protocol as P
from host_tools import runfmt
from host_tools._stdio import say
from host_tools.logger.errors import LoggerError, Stopped
from host_tools.logger.frames import FramesMixin
from host_tools.logger.link import LinkMixin
from host_tools.logger.reference import ReferenceTracker
from host_tools.logger.runfolder import RunFolderMixin

ACK_TIMEOUT_S = 0.4
ACK_RETRIES = 3
STATUS_EVERY_S = 0.5
STATUS_EVERY_PIPE_S = 2.0  # stderr not a terminal (a log file, CI): one whole line this often
STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

log = logging.getLogger(__name__)


class Logger(LinkMixin, FramesMixin, RunFolderMixin):
    """One recording session.  ``open_port`` returns a pyserial-like object (read, write,
    in_waiting, close) or raises; it is called again to reconnect."""

    def __init__(self, out_dir: str, open_port: Callable[[], Any], port_name: str, baud: int,
                 experiment: dict[str, Any] | None = None, clamp: bool | None = None,
                 mu: tuple[float, float] | None = None, record_s: float | None = None,
                 controller: str | None = None, reconnect_timeout_s: float = 30.0, params_timeout_s: float = 1.0,
                 status: bool = True, description: str | None = None,
                 d: P.Definition | None = None, clock: Callable[[], float] = time.monotonic,
                 model: dict[str, Any] | None = None, drive_limits: dict[str, Any] | None = None,
                 on_row: Callable[[dict[str, Any]], None] | None = None):
        self.d = d or P.definition()
        self.out = out_dir
        self.open_port = open_port
        self.port_name = port_name
        self.baud = baud
        self.experiment = experiment
        self.clamp = clamp
        self.mu = mu
        if controller is not None and controller not in self.d.enums["controller"]:
            raise LoggerError(f"controller '{controller}' is not one of "
                              f"{', '.join(sorted(self.d.enums['controller']))}", 2)
        self.controller = controller
        # SetModel values (host_tools.model.firmware_model) and SetDriveLimits values: sent with
        # the configuration; the drive limits in force go into meta.json's drive reference
        self.model = model
        self.drive_limits = drive_limits
        self.reftrack = ReferenceTracker(self.d)
        self.drives = False  # a drive session (host_tools.robot) is an experiment too
        self.record_s = record_s
        self.reconnect_timeout_s = reconnect_timeout_s
        self.params_timeout_s = params_timeout_s
        self.show_status = status
        self.description = description
        self.clock = clock
        self._init_link()
        self._init_frames()
        self.on_row = on_row  # called with each telemetry row written (the live view)
        self._stop = False
        self._signals = 0
        self._interruptible = False
        self._handling = 0  # > 0 while input is handled: a second signal waits for its end
        self._interrupt_due = False
        self._write_error: OSError | None = None
        self.commands: list[dict[str, Any]] = []
        self._params_before_config = 0
        self._config_sent = False
        self.end_reason = ""
        self._t0 = 0.0
        self._rate_mark = (0.0, 0)
        self._fps = 0.0

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
            except LoggerError:
                self._remove_if_created()  # one clear message, nothing left behind
                raise
            try:
                self._open_files()
            except LoggerError:
                self._free_reserve()
                raise
            except OSError as exc:
                self._free_reserve()
                self._close_port()
                raise LoggerError(f"--out {runfmt.display(self.out)} cannot be written: "
                                  f"{exc.strerror or exc}", 2) from None
            except runfmt.RunFormatError as exc:  # the folder changed since prepare_out
                self._free_reserve()
                self._close_port()
                raise LoggerError(str(exc), 2) from None
            try:
                self._interruptible = True  # the second signal may interrupt from here on
                try:
                    self._session()
                except (KeyboardInterrupt, Stopped):
                    self.end_reason = self.end_reason or "interrupted (Ctrl-C)"
                    self._send_stop()
                except LoggerError as exc:
                    self.end_reason = str(exc)
                    code = exc.code
                    self._send_stop()
                except OSError as exc:  # a write failed: disk full, file system gone read-only
                    self._write_error = exc
                    self.end_reason = f"write failed: {exc.strerror or exc}"
                    code = 1
                    self._send_stop()
            except KeyboardInterrupt:  # the one interruption landed in a handler above
                self.end_reason = self.end_reason or "interrupted (Ctrl-C)"
            finally:
                try:
                    self._interruptible = False
                except KeyboardInterrupt:  # raised just before the line above: the only one
                    self.end_reason = self.end_reason or "interrupted (Ctrl-C)"
                self._interrupt_due = False  # left due by a step that raised: the session is over
                if self.end_reason == "" and self._stop:
                    self.end_reason = "stopped"
                # failed before the experiment ran (nothing of it recorded): marked so; a free
                # recording's data is never marked (a retry would replace it)
                if (code != 0 and self._write_error is None and self._run_frames == 0
                        and (self.experiment is not None or self.drives or self.stats["telemetry_rows"] == 0)):
                    self.mark_failed(self.end_reason or f"exit code {code}")
                if self.close() and code == 0:
                    code = 1
        finally:
            for sig, h in old_handlers.items():
                signal.signal(sig, h)
        return code

    def _session(self) -> None:
        self._configure()
        if self.experiment is not None:
            self._heartbeat = True  # from the Start on, so the failsafe never fires early
            self.command("Start", self.experiment)
            if self.pump(lambda: self._run_frames > 0 and not self.running):
                self._heartbeat = False
                self.end_reason = "experiment finished"
                self.pump(None, 0.3)  # the last frames after the end
            elif self._stop and self.end_reason.startswith(("interrupted", "stopped")):
                raise Stopped()
        else:
            self.pump()

    def _send_stop(self) -> None:
        """Stop the robot's experiment or drive when the recording ends before it did."""
        if self.experiment is None and not self.drives:
            return
        self._heartbeat = False
        try:
            self.send("Stop")
        except BaseException:  # a further signal or a dead port: the failsafe stops the robot
            pass

    def _configure(self) -> None:
        """Ask for the robot's parameters, send the configuration commands, ask again."""
        self.event("start", port=self.port_name, baud=self.baud)
        self.write_meta()
        self.send("RequestParams")
        if not self.pump(lambda: self.params is not None, self.params_timeout_s):
            if self._stop:
                raise Stopped()
            self.event("no_params", waited_s=self.params_timeout_s)
        if self.clamp is not None:
            self.command("SetClamp", {"on": int(self.clamp)})
        if self.mu is not None:
            self.command("SetMu", {"mu_s": self.mu[0], "mu_k": self.mu[1]})
        if self.model is not None:
            self.command("SetModel", self.model)
        if self.drive_limits is not None:
            self.command("SetDriveLimits", self.drive_limits)
        if self.controller is not None:
            self.command("SetController", {"variant": self.controller})
        if (self.clamp is not None or self.mu is not None or self.controller is not None
                or self.model is not None):
            # meta.json records what the robot reports it now uses, not what we asked for
            self._config_sent = True
            n = self._params_before_config = self._params_count
            self.send("RequestParams")
            if not self.pump(lambda: self._params_count > n, self.params_timeout_s):
                if self._stop:
                    raise Stopped()
                self.event("no_params_after_config", waited_s=self.params_timeout_s)

    def command(self, name: str, values: dict[str, Any] | None = None) -> None:
        """Send a command and wait for its Ack (retrying); LoggerError if rejected/unanswered."""
        rec = {"command": name, "values": values or {}, "result": None}
        self.commands.append(rec)
        for attempt in range(ACK_RETRIES):
            if self._stop:
                rec["result"] = "not sent: stopping" if attempt == 0 else "no ack: stopping"
                raise Stopped()
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

    def _should_stop(self) -> bool:
        if self._stop:
            return True
        if self.record_s is not None and self.clock() - self._t0 >= self.record_s:
            self.end_reason = self.end_reason or f"recorded {self.record_s:g} s"
            return True
        return False

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        """The first signal asks the session to stop; a later one interrupts it at once, but
        only once and only while the session runs: closing the folder (the queued frames, the
        end event, meta.json, the reserve file) is never interrupted, however many follow.
        Nor is the handling of a chunk of input or of one frame: a row written but not yet
        counted, or bytes in raw.bin not yet decoded, would be a row written twice or frames
        lost; the interruption waits for the end of that step (microseconds)."""
        if not self._signals:  # named before counting: a signal landing in this handler
            name = signal.Signals(signum).name  # finds the reason already set
            self.end_reason = self.end_reason or ("interrupted (Ctrl-C)" if name == "SIGINT"
                                                  else f"stopped by {name}")
            self._stop = True
        self._signals += 1
        if self._signals > 1 and self._interruptible:
            self._interruptible = False
            if self._handling:  # never inside the handling of input: at its end (link.py)
                self._interrupt_due = True
                return
            raise KeyboardInterrupt  # a second signal: stop at once (close() still runs)

    def _install_signals(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        old = {}
        for name in STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                old[sig] = signal.signal(sig, self._on_signal)
        return old

    def _status(self, force: bool = False, note: str = "") -> None:
        if not self.show_status:
            return
        now = self.clock()
        tty = _stderr_is_terminal()
        if not force and now - self._last_status < (STATUS_EVERY_S if tty else STATUS_EVERY_PIPE_S):
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
                f" (lost {self.stats['lost_frames']})  dup {self.stats['duplicates']}"
                f"  flagged {self.stats['implausible']}  | {live}")
        if note:
            line += f"  [{note}]"
        if tty:  # one line redrawn in place
            say("\r" + line[:160].ljust(160), end="\n" if note else "")
        else:  # a log keeps whole lines, no carriage returns
            say(line)

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
                    self._end_frames()
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
        if self._close_files():
            failed = True
        if failed:
            self._trim_after_failure()
        try:
            self.write_meta()
        except Exception as exc:  # never lose the data over a meta problem
            failed = True
            log.warning(f"could not rewrite meta.json: {exc}")
        self._free_reserve()
        self._close_port()
        self._status(force=True, note=self.end_reason or "stopped")
        return failed

    def stop(self) -> None:
        self._stop = True


def _stderr_is_terminal() -> bool:
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError, OSError):
        return False
