"""The exit-code convention of the interop commands, in one place: 0 done, 2 bad input (the
message names the file and place), 1 the output could not be written."""
from __future__ import annotations

import logging
from typing import Callable

from host_tools import runfmt

log = logging.getLogger("host_tools.interop")


def run(action: Callable[[], str], bad: tuple[type[BaseException], ...], out: str) -> int:
    """Run ``action`` (which returns the line to print when done) with the exit codes."""
    try:
        line = action()
    except bad as exc:
        log.error("bad input: %s", exc)
        return 2
    except OSError as exc:
        log.error("cannot write %s: %s", runfmt.display(out), exc.strerror or exc)
        return 1
    print(line)
    return 0


def read_text(path: str, error: type[Exception]) -> str:
    """The text of an input file; ``error`` (bad input) naming the file when it cannot be read."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or exc
        raise error(f"{runfmt.display(path)}: cannot be read: {why}") from None
