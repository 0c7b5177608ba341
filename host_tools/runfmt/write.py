"""Write ``ddrun/1`` run folders (shared/spec/run-format.md): :class:`RunWriter` streams
``telemetry.csv`` row by row and writes ``meta.json``; :func:`write_groundtruth` and
:func:`write_run` write from whole columns."""
from __future__ import annotations

import json
import math
import os
from typing import Any, Iterable, Mapping, TextIO

import numpy as np

from host_tools.runfmt.spec import (GROUNDTRUTH_COLUMNS, TELEMETRY_COLUMNS, RunFormatError,
                                    show_value)
from host_tools.runfmt.validate import _check_time, validate_meta

def write_atomic(path: str | os.PathLike, text: str, fsync: bool = True) -> None:
    """Write ``text`` (UTF-8; characters UTF-8 cannot hold, such as undecodable bytes of a
    path, as backslash escapes) beside ``path`` into a file created exclusively (a name
    nobody holds, never a stale ``.tmp`` or a link someone left), then rename it over
    ``path``: the previous file or the new one, never a torn one, and nothing is written
    through a link or into a file this call did not create.  A failure removes the
    temporary file and raises."""
    import tempfile

    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=folder, prefix="." + os.path.basename(path) + ".", suffix=".tmp")
    try:
        with open(fd, "w", encoding="utf-8", errors="backslashreplace") as fh:
            fh.write(text)
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def _fmt(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        raise TypeError("booleans are not column values")
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))


class RunWriter:
    """Stream a run folder: ``meta.json`` at once, ``telemetry.csv`` row by row.

    ``columns`` fixes the column order; by default it is the required columns
    followed by the extra keys of the first row, in their order.  Every row must
    carry every column.  Rows are flushed to disk every ``flush_every`` rows so a
    crash loses at most that many.  Refuses to overwrite an existing run unless
    ``overwrite=True``.
    """

    def __init__(self, path: str | os.PathLike, meta: Mapping[str, Any] | None = None,
                 columns: Iterable[str] | None = None, flush_every: int = 1,
                 overwrite: bool = False):
        self.path = os.fspath(path)
        self.meta = validate_meta(dict(meta or {}), os.path.join(self.path, "meta.json"))
        os.makedirs(self.path, exist_ok=True)
        self._tpath = os.path.join(self.path, "telemetry.csv")
        if not overwrite:
            for f in ("meta.json", "telemetry.csv"):
                p = os.path.join(self.path, f)
                if os.path.exists(p):
                    raise RunFormatError("already exists; refusing to overwrite a recorded run", p)
        with open(os.path.join(self.path, "meta.json"), "w") as fh:
            json.dump(self.meta, fh, indent=2)
            fh.write("\n")
        self._columns = list(columns) if columns is not None else None
        if self._columns is not None:
            self._check_columns(self._columns)
        self._fh: TextIO | None = open(self._tpath, "w", newline="")
        self._header_written = False
        self._rows = 0
        self._last_t: float | None = None
        self._flush_every = max(1, int(flush_every))
        if self._columns is not None:
            self._write_header()

    def _check_columns(self, cols: list[str]) -> None:
        for c in TELEMETRY_COLUMNS:
            if c not in cols:
                raise RunFormatError("missing required column", self._tpath, column=c)
        if len(set(cols)) != len(cols):
            raise RunFormatError("duplicate column names", self._tpath)

    def _write_header(self) -> None:
        assert self._fh is not None and self._columns is not None  # (callers: open, columns set)
        self._fh.write(",".join(self._columns) + "\n")
        self._header_written = True

    @property
    def rows_written(self) -> int:
        return self._rows

    def write_row(self, row: Mapping[str, Any]) -> None:
        if self._fh is None:
            raise RunFormatError("writer is closed", self._tpath)
        n = self._rows + 1
        if self._columns is None:
            cols = list(TELEMETRY_COLUMNS) + [k for k in row if k not in TELEMETRY_COLUMNS]
            for c in TELEMETRY_COLUMNS:
                if c not in row:
                    raise RunFormatError("missing required column", self._tpath, row=n, column=c)
            self._columns = cols
            self._write_header()
        cells = []
        for c in self._columns:
            if c not in row:
                raise RunFormatError("missing value", self._tpath, row=n, column=c)
            v = row[c]
            if isinstance(v, str):
                if c in TELEMETRY_COLUMNS:
                    raise RunFormatError(f"not a number: {show_value(v)}", self._tpath, row=n, column=c)
                cells.append(v)
                continue
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise RunFormatError(f"not a number: {show_value(v)}", self._tpath, row=n, column=c) from None
            if not math.isfinite(f):
                raise RunFormatError(f"value is {f} (NaN and infinity are not allowed)",
                                     self._tpath, row=n, column=c)
            cells.append(_fmt(v))
        extra = [k for k in row if k not in self._columns]
        if extra:
            raise RunFormatError(f"unknown column(s) {extra} not in the header {self._columns}",
                                 self._tpath, row=n)
        t = float(row["t_s"])
        if self._last_t is not None and not t > self._last_t:
            raise RunFormatError(f"time does not increase: {t!r} after {self._last_t!r}",
                                 self._tpath, row=n, column="t_s")
        self._fh.write(",".join(cells) + "\n")  # a failed write leaves the writer's state as it was
        self._last_t = t
        self._rows = n
        if n % self._flush_every == 0:
            self.flush()

    def flush(self) -> None:
        if self._fh is not None:
            self._fh.flush()

    def write_groundtruth(self, t_s, x_m, y_m, phi_rad=None) -> None:
        write_groundtruth(self.path, t_s, x_m, y_m, phi_rad)

    def close(self) -> None:
        if self._fh is not None:
            fh, self._fh = self._fh, None
            try:
                if not self._header_written:  # no rows: still leave a valid header
                    self._columns = list(TELEMETRY_COLUMNS)
                    fh.write(",".join(self._columns) + "\n")
                    self._header_written = True
                fh.flush()
            finally:
                fh.close()

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_groundtruth(path: str | os.PathLike, t_s, x_m, y_m, phi_rad=None,
                      overwrite: bool = False) -> str:
    """Write ``groundtruth.csv`` into run folder ``path``.  ``phi_rad`` may be None
    (column left empty) or contain NaN for samples without a heading; a dropout is
    a missing row, never a NaN position."""
    path = os.fspath(path)
    gpath = os.path.join(path, "groundtruth.csv")
    t = np.asarray(t_s, dtype=float)
    cols = {"t_s": t, "x_m": np.asarray(x_m, dtype=float), "y_m": np.asarray(y_m, dtype=float)}
    phi = None if phi_rad is None else np.asarray(phi_rad, dtype=float)
    for name, arr in list(cols.items()) + ([("phi_rad", phi)] if phi is not None else []):
        if arr.ndim != 1 or arr.shape != t.shape:
            raise RunFormatError(f"has shape {arr.shape}, t_s has {t.shape}", gpath, column=name)
    for name, arr in cols.items():
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise RunFormatError(f"value is {arr[bad[0]]} (drop the row for a dropout)", gpath,
                                 row=int(bad[0]) + 1, column=name)
    if phi is not None:
        bad = np.flatnonzero(np.isinf(phi))
        if bad.size:
            raise RunFormatError("value is infinite", gpath, row=int(bad[0]) + 1, column="phi_rad")
    _check_time(t, gpath)
    if os.path.exists(gpath) and not overwrite:
        raise RunFormatError("already exists; refusing to overwrite", gpath)
    os.makedirs(path, exist_ok=True)
    with open(gpath, "w", newline="") as fh:
        fh.write(",".join(GROUNDTRUTH_COLUMNS) + "\n")
        for i in range(t.size):
            p = "" if phi is None or not np.isfinite(phi[i]) else repr(float(phi[i]))
            fh.write(f"{float(t[i])!r},{float(cols['x_m'][i])!r},{float(cols['y_m'][i])!r},{p}\n")
    return gpath


def write_run(path: str | os.PathLike, meta: Mapping[str, Any], telemetry: Mapping[str, Any],
              groundtruth: Mapping[str, Any] | None = None, overwrite: bool = False) -> str:
    """Write a whole run from columns (dict of equal-length arrays) in one call."""
    cols = list(TELEMETRY_COLUMNS) + [k for k in telemetry if k not in TELEMETRY_COLUMNS]
    for c in TELEMETRY_COLUMNS:
        if c not in telemetry:
            raise RunFormatError("missing required column",
                                 os.path.join(os.fspath(path), "telemetry.csv"), column=c)
    arrays = {c: np.asarray(telemetry[c]) for c in cols}
    n = len(arrays["t_s"])
    with RunWriter(path, meta, columns=cols, flush_every=max(n, 1), overwrite=overwrite) as w:
        for i in range(n):
            w.write_row({c: arrays[c][i] for c in cols})
    if groundtruth is not None:
        write_groundtruth(path, groundtruth["t_s"], groundtruth["x_m"], groundtruth["y_m"],
                          groundtruth.get("phi_rad"), overwrite=overwrite)
    return os.fspath(path)
