"""``python -m host_tools log`` (``ddrobot log``): the command line of the logger.

Records a run (:class:`~host_tools.logger.session.Logger`), or with ``--attach-groundtruth``
adds an external tracker's CSV to a recorded run (:mod:`host_tools.gt_align`).
"""
from __future__ import annotations

import argparse
import logging
import signal
import threading
from typing import TYPE_CHECKING, Any

from host_tools import gt_align
from host_tools import protocol as P
from host_tools._stdio import STATUS, out
from host_tools.logger.errors import LoggerError
from host_tools.logger.session import STOP_SIGNALS, Logger

if TYPE_CHECKING:
    from host_tools.interop.live import LivePublisher

log = logging.getLogger(__name__)


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
    p.add_argument("--mu-k", type=float, help="kinetic friction coefficient sent with SetMu (with --mu-s)")
    p.add_argument("--controller", choices=sorted(d.enums["controller"]),
                   help="send SetController before starting: the cascade's velocity loop "
                   "(the firmware's default: improved); meta.json controller_variant says which ran")
    p.add_argument("--model", metavar="MODEL_JSON", help="send an analyzer model.json (ddmodel/1) to the "
                   "firmware: SetMu (mu_s/mu_k: its tau_max follows; instead of --mu-s/--mu-k) and SetModel "
                   "(wheel radius, half track, back-EMF ratio, voltage drop)")
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
                   "forces this offset; when omitted it is estimated with its uncertainty from the start from "
                   "rest, and refused (exit 2) when the data cannot pin it within one tracker frame")
    p.add_argument("--gt-max-offset", type=float, default=10.0, help="search window, s (default 10)")
    p.add_argument("--gt-unix-time", action="store_true", help="the tracker's t_s is Unix time from a PC clock: "
                   "align through the logger's host clock instead of estimating")
    p.add_argument("--gt-start-pose", action="store_true", help="set meta.json start_pose to the tracker's "
                   "pose at the first telemetry frame (tracker in room coordinates; needs phi_rad)")
    from host_tools.interop import live
    live.add_option(p)


def main(args: argparse.Namespace) -> int:
    if args.attach_groundtruth:
        try:
            info = gt_align.attach_groundtruth(args.out, args.attach_groundtruth, args.gt_offset,
                                               args.gt_max_offset, set_start_pose=args.gt_start_pose,
                                               unix_time=args.gt_unix_time)
        except gt_align.GroundTruthError as exc:
            log.error("%s", exc)
            return exc.code
        out(gt_align.describe(info))
        return 0
    if not args.port:
        log.error("--port is required (or --attach-groundtruth)")
        return 2
    d = P.definition()
    experiment = None
    try:
        if args.experiment:
            experiment = {"profile": args.experiment, "wheel_accel": args.accel,
                          "accel_time": args.accel_time, "duration": args.duration, "radius": args.radius}
            d.raw_values("Start", experiment)
        mu = None
        model = None
        if (args.mu_s is None) != (args.mu_k is None):
            raise P.ProtocolError("--mu-s and --mu-k go together")
        if args.mu_s is not None:
            mu = (args.mu_s, args.mu_k)
        if getattr(args, "model", None):
            if mu is not None:
                raise P.ProtocolError("--model and --mu-s/--mu-k exclude each other")
            from host_tools import model as M
            mu, model = M.firmware_commands(M.load_model(args.model), args.model)
        if mu is not None:
            d.raw_values("SetMu", {"mu_s": mu[0], "mu_k": mu[1]})
    except (P.ProtocolError, ValueError, OverflowError) as exc:  # ModelError is a ValueError
        log.error("%s", exc)
        return 2
    record_s = args.record_s
    if record_s is None and experiment is not None:
        record_s = args.duration + 5.0  # safety net if the end of the run is never reported

    def open_port() -> Any:
        import serial
        return serial.serial_for_url(args.port, baudrate=args.baud, timeout=0.05, write_timeout=0.5)

    try:
        pub = _live(args, d)
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    lg = Logger(args.out, open_port, args.port, args.baud, experiment=experiment,
                clamp=None if args.clamp is None else args.clamp == "on", mu=mu, record_s=record_s,
                controller=getattr(args, "controller", None), model=model,
                reconnect_timeout_s=args.reconnect_timeout, params_timeout_s=args.params_timeout,
                status=not args.quiet and log.isEnabledFor(STATUS), description=args.description, d=d,
                on_row=pub.publish if pub else None)
    # signals before and after the recording (a third quick Ctrl-C arriving while the summary
    # is printed or the process exits) are ignored: the recording owns them while it runs.
    # Run as the process's command, they stay ignored until the process has exited.
    held = _hold_signals()
    try:
        return _record(args, lg, pub)
    finally:
        if not getattr(args, "_owns_process", False):
            for sig, handler in held.items():
                signal.signal(sig, handler)


def _hold_signals() -> dict[int, Any]:
    held = {}
    if threading.current_thread() is threading.main_thread():
        for name in STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                held[sig] = signal.signal(sig, signal.SIG_IGN)
    return held


def _record(args: argparse.Namespace, lg: Logger, pub: LivePublisher | None) -> int:
    try:
        code = lg.run()
    except LoggerError as exc:
        log.error("%s", exc)
        return exc.code
    finally:
        if pub:
            pub.close()
    s = lg.stats
    log.log(STATUS, f"{args.out}: {s['telemetry_rows']} rows, {lg.dec.crc_errors} CRC errors, "
          f"{lg.dec.bad_blocks - lg.dec.crc_errors} other bad blocks, {s['gaps']} gaps "
          f"({s['lost_frames']} frames lost), {s['duplicates']} duplicates, {s['stale']} stale, "
          f"{s['implausible']} implausible (flagged in events.jsonl), {s['robot_resets']} resets, "
          f"{s['disconnects']} disconnects; end: {lg.end_reason}")
    if code:
        log.error("%s", lg.end_reason)
    return code


def _live(args: argparse.Namespace, d: P.Definition) -> LivePublisher | None:
    """The live view's server of --live, or None."""
    if getattr(args, "live", None) is None:
        return None
    from host_tools.interop import live
    from host_tools.logger.frames import TelemetryColumns
    return live.start(args.live, TelemetryColumns(d).columns)
