"""What the parts of a recording session read from each other, for the type checker only.

:class:`~host_tools.logger.session.Logger` joins three mixins (:mod:`.link`, :mod:`.frames`,
:mod:`.runfolder`); each uses state and methods that the session or another part defines.
:class:`SessionParts` declares them once: each mixin derives from it while type checking
(``if TYPE_CHECKING``) and from ``object`` at run time, so none of it is used at run time.
"""
from __future__ import annotations

import contextlib
from typing import IO, Any, Callable

from host_tools import protocol as P
from host_tools import runfmt
from host_tools.logger.frames import TelemetryColumns
from host_tools.logger.reference import ReferenceTracker


class SessionParts:
    # the session's settings (session.Logger.__init__)
    d: P.Definition
    out: str
    open_port: Callable[[], Any]
    port_name: str
    baud: int
    experiment: dict[str, Any] | None
    clamp: bool | None
    mu: tuple[float, float] | None
    controller: str | None
    drive_limits: dict[str, Any] | None
    description: str | None
    reconnect_timeout_s: float
    clock: Callable[[], float]
    reftrack: ReferenceTracker
    on_row: Callable[[dict[str, Any]], None] | None
    # the session's state (session.Logger)
    commands: list[dict[str, Any]]
    end_reason: str
    _config_sent: bool
    _params_before_config: int
    _write_error: OSError | None
    _t0: float
    _last_rx: float
    _last_hb: float
    _last_flush: float
    # the link's (link.LinkMixin), the frames' (frames.FramesMixin), the files' (runfolder)
    dec: P.StreamDecoder
    cols: TelemetryColumns
    stats: dict[str, int]
    params: dict[str, Any] | None
    _params_count: int
    _queue: list[P.Frame]
    _handling: int
    _interrupt_due: bool
    writer: runfmt.RunWriter
    raw: IO[bytes]
    events: IO[str]

    def event(self, kind: str, **kw: Any) -> None:
        raise NotImplementedError  # runfolder.RunFolderMixin

    def write_meta(self) -> None:
        raise NotImplementedError  # runfolder.RunFolderMixin

    def _uninterrupted(self) -> contextlib.AbstractContextManager[None]:
        raise NotImplementedError  # link.LinkMixin

    def _meta(self) -> dict[str, Any]:
        raise NotImplementedError  # runfolder.RunFolderMixin

    def _flush(self) -> None:
        raise NotImplementedError  # runfolder.RunFolderMixin

    def _drain(self) -> None:
        raise NotImplementedError  # frames.FramesMixin

    def _should_stop(self) -> bool:
        raise NotImplementedError  # session.Logger

    def _status(self, force: bool = False, note: str = "") -> None:
        raise NotImplementedError  # session.Logger
