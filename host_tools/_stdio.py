"""Status output that never ends the work it reports on.

A tool's stdout or stderr may be a pipe whose reader has gone (``ddrobot log ... 2>&1 | head``).
Python ignores SIGPIPE, so a write then raises BrokenPipeError (EPIPE); a closed or detached
stream raises ValueError.  What a tool prints is a report about its work, never the work: these
helpers swallow such failures, and :func:`settle` points a dead stream at /dev/null before the
interpreter's final flush, so that no "Exception ignored ... BrokenPipeError" is printed and the
exit code stays the tool's own.

The tools' messages for people go through :mod:`logging` (module loggers under
``host_tools``): :class:`StatusHandler` writes them to stderr with :func:`say`, so a message is
as harmless as a ``say``.  Level :data:`STATUS` (between INFO and WARNING) is the progress and
the notes a tool has always shown by default: written as the bare message, hidden by ``-q``.
"""
from __future__ import annotations

import logging
import os
import sys

STATUS = 25
logging.addLevelName(STATUS, "STATUS")

_open_line = False  # stderr's last write left a line open (a "\r" status line)


def say(text: str = "", stream=None, end: str = "\n") -> bool:
    """Write ``text + end`` to ``stream`` (default stderr) and flush; False when it failed."""
    global _open_line
    stream = sys.stderr if stream is None else stream
    try:
        stream.write(text + end)
        stream.flush()
        if stream is sys.stderr:
            _open_line = not end.endswith("\n")
        return True
    except (OSError, ValueError):
        return False


def out(text: str = "", end: str = "\n") -> bool:
    """:func:`say` to stdout."""
    return say(text, sys.stdout, end)


def settle() -> None:
    """Flush stdout and stderr; a stream that cannot take it is pointed at /dev/null."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        try:
            stream.flush()
        except (OSError, ValueError):
            try:
                fd = os.open(os.devnull, os.O_WRONLY)
                os.dup2(fd, stream.fileno())
                os.close(fd)
            except (OSError, ValueError):
                pass


class StatusHandler(logging.Handler):
    """The tools' messages to the current ``sys.stderr``: STATUS records as the bare message,
    the others as ``level: message`` (``error: ...``, ``warning: ...``).  A closed or dead
    stream never ends the work (:func:`say`); a progress bar being drawn is cleared and redrawn
    around the message (``host_tools._progress``); an open status line is ended first."""

    _ddrobot = True

    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        if record.exc_info and record.levelno >= logging.ERROR:
            msg += "\n" + logging.Formatter().formatException(record.exc_info)
        return msg if record.levelno == STATUS else f"{record.levelname.lower()}: {msg}"

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = self.format(record)
        except Exception:  # a message that cannot be formatted is not worth a traceback
            return
        if _open_line:
            text = "\n" + text
        from host_tools import _progress
        if not _progress.write_above(text):
            say(text)


def install(level: int = STATUS) -> StatusHandler:
    """The ``host_tools`` loggers' one handler (replacing an earlier one) at ``level``."""
    root = logging.getLogger("host_tools")
    for h in list(root.handlers):
        if getattr(h, "_ddrobot", False):
            root.removeHandler(h)
    h = StatusHandler()
    root.addHandler(h)
    root.setLevel(level)
    root.propagate = False
    return h


if not any(getattr(h, "_ddrobot", False) for h in logging.getLogger("host_tools").handlers):
    install()  # a tool used as a library shows what its command line shows by default
