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
                   into raw.bin, length, reason cobs/short/long/crc/version), gap (after_seq, seq,
                   missing: frames of any kind skipped in the robot's one seq counter, counted
                   in the order the frames came, an Ack or Params after telemetry still held
                   for confirmation after it),
                   duplicate, stale, time_not_increasing, robot_reset, failsafe (reason),
                   implausible (a verified frame no following frame confirmed: all its
                   values and the reason; counted in meta.json logger.implausible),
                   unknown_type, bad_length, disconnect, reconnect

Files are flushed as they are written; the folder is complete and readable after Ctrl-C, a
pulled cable (the logger waits for the port to come back and carries on) or a robot power loss
(a board reset is recognised from the boot counter in telemetry, ``boot_count``, once the 2
following frames confirm it, and the board time is kept increasing; an old frame arriving late
is stale, never a reset).  Every frame that passed the CRC is a row, counted, or flagged.

Guarantees:
* SIGINT (Ctrl-C), SIGTERM and SIGHUP stop the recording the same way, exit 0: the bytes
  already read are decoded to the end, every frame that passed the CRC is written as a row or
  counted (duplicate, stale, unknown type, ...), events.jsonl gets its "end" line, meta.json
  its row count and end_reason ("interrupted (Ctrl-C)", "stopped by SIGTERM", ...).  A second
  signal interrupts at once, though never inside the handling of one chunk of input or one
  frame (a row written twice or bytes never decoded): it waits for that step's end, which
  takes microseconds; the folder is still closed the same way; later signals are ignored.
  A closed status pipe (stderr to ``head``) never ends the recording.
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
groundtruth.csv, shifting its time by an offset estimated from the start from rest and printed
with its standard error (refused, exit 2 and nothing written, when the data cannot pin it
within one tracker frame), by ``--gt-offset``, or (``--gt-unix-time``, a tracker stamped by the
logging PC's clock: no estimate, within the link's latency) through the logger's own host clock
recorded in meta.json
(:mod:`host_tools.gt_align`).

Modules, by concern: ``link`` (the serial port: connect, reconnect, send, the receive loop),
``frames`` (verified frames -> rows and events; sequence, resets, statistics), ``runfolder``
(--out checks, meta.json, the files, closing them after a failure), ``session`` (the
:class:`Logger`: the command sequence of an experiment, signals, the status line), ``cli``
(``add_arguments``, ``main``), ``errors``.  Everything a caller uses is re-exported here.
"""
from __future__ import annotations

from host_tools.logger.cli import add_arguments, main
from host_tools.logger.errors import LoggerError
from host_tools.logger.frames import TelemetryColumns
from host_tools.logger.link import FLUSH_EVERY_S, HEARTBEAT_S, RECONNECT_POLL_S
from host_tools.logger.runfolder import RESERVE_BYTES, RESERVE_NAME, RUN_FILES, describe_experiment
from host_tools.logger.session import (ACK_RETRIES, ACK_TIMEOUT_S, STATUS_EVERY_S, STOP_SIGNALS,
                                       Logger)

__all__ = [
    "ACK_RETRIES", "ACK_TIMEOUT_S", "FLUSH_EVERY_S", "HEARTBEAT_S", "RECONNECT_POLL_S",
    "RESERVE_BYTES", "RESERVE_NAME", "RUN_FILES", "STATUS_EVERY_S", "STOP_SIGNALS", "Logger",
    "LoggerError", "TelemetryColumns", "add_arguments", "describe_experiment", "main",
]
