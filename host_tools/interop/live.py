"""Live view: a Foxglove WebSocket server (``foxglove-sdk``, protocol foxglove.websocket.v1)
that publishes each decoded telemetry row while ``log --live`` or ``fil record --live``
records.

Topics (:data:`host_tools.interop.messages.LIVE_TOPICS`): ``/telemetry`` (the row, JSON, the
columns of telemetry.csv), ``/odometry/pose`` and ``/odometry/tf`` (the robot's odometry in
the world frame).  Open Foxglove, "Open connection", "Foxglove WebSocket", ``ws://HOST:PORT``.

Publishing never stops a recording: a failure is logged once and publishing stops; the
recording goes on.  Messages carry the host's receive time as log time (Foxglove's live clock)
and the board time in their ``timestamp`` / ``t_s`` fields.
"""
from __future__ import annotations

import logging
import time
from typing import Any, Mapping, Sequence

from host_tools.interop import messages as M

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765


def parse_address(text: str | int | None) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` -> (host, port); None -> the defaults (127.0.0.1, 8765).
    ValueError with the reason."""
    if text is None:
        return "127.0.0.1", DEFAULT_PORT
    host, _, port = str(text).rpartition(":")
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"--live {text}: expected PORT or HOST:PORT") from None
    if not 0 <= p <= 65535:
        raise ValueError(f"--live {text}: port must be in 0..65535 (0: any free port)")
    return host or "127.0.0.1", p


class LivePublisher:
    """A running Foxglove WebSocket server.  ``columns``: the telemetry columns, so that the
    channels are advertised at once (a client can subscribe before the first frame); without
    them the channels appear with the first row.  ``publish(row)`` for each decoded row;
    ``close()`` stops the server."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 columns: Sequence[str] | None = None, name: str = "ddrobot"):
        import foxglove
        self._fg = foxglove
        self.ctx = foxglove.Context()
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.ctx)
        self.host = host
        self.port = int(self.server.port)
        self.channels: dict[str, Any] = {}
        self.published = 0
        self._failed = False
        if columns is not None:
            self._open({c: "number" for c in columns})
        log.info("live view: ws://%s:%d (Foxglove: Open connection > Foxglove WebSocket)",
                 host, self.port)

    def _open(self, fields: Mapping[str, str]) -> None:
        for topic in M.LIVE_TOPICS:
            name, enc, data = M.schema_for(topic, fields)
            schema = self._fg.Schema(name=name, encoding=enc, data=data)
            self.channels[topic] = self._fg.Channel(topic, schema=schema,
                                                    message_encoding=M.message_encoding(enc),
                                                    context=self.ctx)

    def subscribed(self, topics: Sequence[str] | None = None) -> bool:
        """True when a viewer is subscribed to every one of ``topics`` (default: all)."""
        want = list(self.channels) if topics is None else list(topics)
        return bool(want) and all(t in self.channels and self.channels[t].has_sinks()
                                  for t in want)

    def wait_subscribed(self, topics: Sequence[str] | None = None,
                        timeout_s: float = 10.0) -> bool:
        """Wait until :meth:`subscribed` (a recording started by a script that must not lose
        its first frames to a viewer still connecting); False after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while not self.subscribed(topics):
            if time.monotonic() >= end:
                return False
            time.sleep(0.005)
        return True

    def publish(self, row: Mapping[str, Any]) -> None:
        if self._failed:
            return
        try:
            if not self.channels:
                self._open(M.row_fields(row))
            now = time.time_ns()
            t = float(row["t_s"])
            x, y, phi = (float(row[k]) for k in ("x_odo_m", "y_odo_m", "phi_odo_rad"))
            self.channels["/telemetry"].log(M.json_message(row), log_time=now)
            self.channels["/odometry/pose"].log(M.pose_in_frame(t, x, y, phi), log_time=now)
            self.channels["/odometry/tf"].log(M.frame_transform(t, M.BASE_ODO, x, y, phi),
                                              log_time=now)
            self.published += 1
        except Exception as exc:  # the recording matters more than the live view
            self._failed = True
            log.warning("live view stopped (the recording goes on): %s", exc)

    def close(self) -> None:
        try:
            self.server.stop()
        except Exception as exc:
            log.debug("live view: stopping the server: %s", exc)


def start(address: str | int | None, columns: Sequence[str] | None = None) -> LivePublisher:
    """The server of a ``--live [HOST:]PORT`` option."""
    host, port = parse_address(address)
    try:
        return LivePublisher(host, port, columns)
    except RuntimeError as exc:  # foxglove-sdk: the port is taken, the host is unknown
        raise ValueError(f"--live {address}: cannot serve on {host}:{port}: {exc}") from None


def add_option(p) -> None:
    """The ``--live [[HOST:]PORT]`` option of ``log`` and ``fil record``."""
    p.add_argument("--live", nargs="?", const=str(DEFAULT_PORT), default=None,
                   metavar="[HOST:]PORT",
                   help="serve the telemetry live to Foxglove over its WebSocket protocol "
                   f"(default 127.0.0.1:{DEFAULT_PORT}; 0.0.0.0:PORT for other machines): "
                   "topics " + ", ".join(M.LIVE_TOPICS))
