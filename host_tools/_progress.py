"""Progress bars (tqdm) for long work, drawn only for a person at a terminal.

A bar is drawn when stderr is a terminal and the ``host_tools`` loggers show STATUS messages
(not ``-q``).  Anywhere else (a pipe, a file, a CI log, a test reading stderr) the work reports
the one-line messages it always has, through ``emit`` (by default a STATUS message).  With a
bar, each of those lines is an INFO message instead: ``-v`` shows them above the bar.

:class:`Progress` is one counted bar (cases, candidates, simulated seconds: count, elapsed,
rate and ETA); :func:`stage` keeps one line per tool naming its last finished stage, with the
elapsed time, for work whose stages have no count known in advance (the analyzer's).  Writing
to a terminal that has gone never ends the work: the bar is then dropped.
"""
from __future__ import annotations

import logging
import sys
import time
from typing import Any, Callable

from host_tools._stdio import STATUS

_bars: list[Any] = []          # the tqdm bars being drawn, oldest first
_stages: dict[str, Any] = {}   # tool -> its stage line (a tqdm without a total)


def shown() -> bool:
    """True when a bar is drawn: stderr is a terminal and STATUS messages are shown."""
    try:
        tty = sys.stderr.isatty()
    except (AttributeError, ValueError, OSError):
        return False
    return bool(tty) and logging.getLogger("host_tools").isEnabledFor(STATUS)


def _tqdm(**kw: Any) -> Any:
    import os

    from tqdm import tqdm
    try:
        cols, rows = os.get_terminal_size(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        cols = rows = 0
    tqdm.monitor_interval = 0  # no monitor thread: the analyzer forks its fitting workers
    try:  # a terminal that gives no size (0 x 0: a bare pseudo-terminal) is taken as 80 x 24
        bar = tqdm(file=sys.stderr, dynamic_ncols=cols > 0, ncols=None if cols > 0 else 80,
                   nrows=None if rows > 0 else 24, **kw)
    except (OSError, ValueError):
        return None
    _bars.append(bar)
    return bar


def _close(bar: Any) -> None:
    if bar in _bars:
        _bars.remove(bar)
    try:
        bar.close()
    except (OSError, ValueError):
        pass


def write_above(text: str) -> bool:
    """Write ``text`` (a log message) above the bars being drawn; False when there is none."""
    if not _bars:
        return False
    from tqdm import tqdm
    try:
        tqdm.write(text, file=sys.stderr)
    except (OSError, ValueError):
        pass
    return True


class Progress:
    """A counted bar (``total`` units of ``unit``) on a terminal (and ``show``); elsewhere
    ``emit(line)`` for each :meth:`step` that gives a line.  Usable as a context manager."""

    def __init__(self, total: float | None, desc: str, unit: str = "it",
                 logger: logging.Logger | None = None,
                 emit: Callable[[str], Any] | None = None, leave: bool = True,
                 unit_scale: bool = False, bar_format: str | None = None, show: bool = True):
        self.log = logger or logging.getLogger("host_tools")
        self.emit = emit or (lambda line: self.log.log(STATUS, line))
        kw: dict[str, Any] = {"total": total, "desc": desc, "unit": unit, "leave": leave,
                              "unit_scale": unit_scale}
        if bar_format:
            kw["bar_format"] = bar_format
        self.bar = _tqdm(**kw) if show and shown() else None

    def _line(self, line: str | None) -> None:
        if line is None:
            return
        if self.bar is None:
            self.emit(line)
        else:
            self.log.info("%s", line)

    def _draw(self, fn: Callable[[Any], Any]) -> None:
        """``fn(bar)`` when a bar is drawn; a terminal gone drops the bar, the work goes on."""
        bar = self.bar
        if bar is None:
            return
        try:
            fn(bar)
        except (OSError, ValueError):
            _close(bar)
            self.bar = None

    def step(self, line: str | None = None, n: float = 1) -> None:
        """``n`` more units done; ``line``: the one-line message of this step."""
        self._draw(lambda bar: bar.update(n) if bar.total is None or bar.n + n < bar.total
                   else (bar.update(n), bar.refresh()))  # the last count always drawn
        self._line(line)

    def set(self, value: float, line: str | None = None) -> None:
        """The units done so far are ``value`` (e.g. the simulated seconds reached)."""
        self._draw(lambda bar: value != bar.n and bar.update(value - bar.n))  # <= 10 redraws/s
        self._line(line)

    def close(self) -> None:
        if self.bar is not None:
            _close(self.bar)
            self.bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def stage(tool: str, line: str, logger: logging.Logger,
          emit: Callable[[str], Any] | None = None) -> None:
    """A finished stage of ``tool``: on a terminal its stage line shows ``tool: line`` and the
    time since the first stage (``-v`` also writes the line above it); elsewhere ``emit(line)``
    (default: a STATUS message of ``logger``)."""
    bar = _stages.get(tool)
    if bar is None and shown():
        bar = _tqdm(total=None, desc=tool, bar_format="{desc} [{elapsed}]", leave=True)
        if bar is not None:
            _stages[tool] = bar
    if bar is None:
        (emit or (lambda s: logger.log(STATUS, s)))(line)
        return
    try:
        bar.set_description_str(f"{tool}: {line}")
    except (OSError, ValueError):
        end_stages(tool)
    logger.info("%s", line)


def stamped(tool: str, logger: logging.Logger) -> Callable[[str], None]:
    """``tool``'s one-line messages where no bar is drawn: STATUS messages of ``logger``,
    ``[tool HH:MM:SS] line``."""
    def emit(line: str) -> None:
        logger.log(STATUS, "[%s %s] %s", tool, time.strftime("%H:%M:%S"), line)
    return emit


def stages(tool: str, logger: logging.Logger) -> Callable[[str], None]:
    """``tool``'s finished stages as one callable: :func:`stage` with ``logger``, the lines
    :func:`stamped` where no stage line is drawn."""
    emit = stamped(tool, logger)

    def log(line: str) -> None:
        stage(tool, line, logger, emit=emit)
    return log


def end_stages(tool: str) -> None:
    """Close ``tool``'s stage line (it stays on the terminal with its last stage)."""
    bar = _stages.pop(tool, None)
    if bar is not None:
        _close(bar)
