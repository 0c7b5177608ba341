"""Status output that never ends the work it reports on.

A tool's stdout or stderr may be a pipe whose reader has gone (``ddrobot log ... 2>&1 | head``).
Python ignores SIGPIPE, so a write then raises BrokenPipeError (EPIPE); a closed or detached
stream raises ValueError.  What a tool prints is a report about its work, never the work: these
helpers swallow such failures, and :func:`settle` points a dead stream at /dev/null before the
interpreter's final flush, so that no "Exception ignored ... BrokenPipeError" is printed and the
exit code stays the tool's own.
"""
from __future__ import annotations

import os
import sys


def say(text: str = "", stream=None, end: str = "\n") -> bool:
    """Write ``text + end`` to ``stream`` (default stderr) and flush; False when it failed."""
    stream = sys.stderr if stream is None else stream
    try:
        stream.write(text + end)
        stream.flush()
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
