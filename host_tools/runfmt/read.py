"""Read ``ddrun/1`` run folders (shared/spec/run-format.md): the files' text (UTF-8, no BOM,
no NUL), CSV columns of plain decimal numbers, meta.json, and a whole folder into a
:class:`~host_tools.runfmt.spec.Run`, validated on the way."""
from __future__ import annotations

import csv
import json
import math
import os
import re
import stat
from typing import IO, Any, Iterable

import numpy as np

from host_tools.runfmt.spec import (GROUNDTRUTH_REQUIRED, TELEMETRY_COLUMNS, Run, RunFormatError,
                                    show_value, display)
from host_tools.runfmt.validate import (_check_time, _check_units_groundtruth,
                                        _check_units_telemetry, split_unknown, validate_meta)

# Bounds of what the reader takes in.
_JSON_MAX_DEPTH = 64          # nesting of objects/arrays in meta.json
_MAX_FILE_BYTES = 1 << 30     # a run file larger than 1 GiB is refused, not read

# The least a run needs for the analyzer: it compares wheel speeds computed from
# differences of consecutive rows and smooths residuals over 5 samples, so telemetry needs
# 6 rows (5 differences).  The format itself needs one row; readers that look at single
# rows (timing, the logger's check) take that.
ANALYZER_MIN_ROWS = 6

# Numbers in the run format are plain decimal: optional sign, digits with an optional
# point, optional exponent.  Python's float() also takes '1_0', ' 1', 'infinity' and
# non-ASCII digits, none of which are numbers here.
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
_NONFINITE = re.compile(r"[+-]?(?:nan|inf|infinity)\Z", re.IGNORECASE)


def _position(data: bytes, offset: int) -> tuple[int, int]:
    """1-based line and character (counted in bytes of that line) of byte ``offset``."""
    line = data.count(b"\n", 0, offset) + 1
    start = data.rfind(b"\n", 0, offset) + 1
    return line, offset - start + 1


def _csv_column_at(data: bytes, line: int, char: int) -> str | None:
    """The header name of the field at (line, char) of a CSV file, counting commas (quoted
    commas are not special-cased; good enough to point at a cell)."""
    lines = data.split(b"\n", line)
    if line < 2 or len(lines) < line:
        return None
    header = lines[0].decode("utf-8", "replace").strip("\r").split(",")
    k = lines[line - 1][:char - 1].count(b",")
    return header[k].strip() if k < len(header) else None


def _read_bytes(path: str, limit: int = _MAX_FILE_BYTES) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (see :func:`_open_regular`); a
    file growing past the limit while read is refused too."""
    with _open_regular(path, limit) as fh:
        try:
            data = fh.read(limit + 1)
        except OSError as exc:
            raise RunFormatError(f"cannot read: {exc.strerror or exc}", path) from None
    if len(data) > limit:
        raise RunFormatError(f"grew past the {limit} bytes this reader takes while read", path)
    return data


def read_text(path: str, csv_file: bool = False, limit: int = _MAX_FILE_BYTES) -> str:
    """The text of a run file (a regular file of at most ``limit`` bytes): UTF-8 without
    byte-order mark and without NUL bytes; anything else raises :class:`RunFormatError`
    naming what it is and where."""
    data = _read_bytes(path, limit)
    if data.startswith(b"\xef\xbb\xbf"):
        raise RunFormatError("starts with a UTF-8 byte-order mark (bytes EF BB BF, invisible "
                             "in most editors); the run format is UTF-8 without one: save the "
                             "file without BOM", path, line=1, char=1)
    for bom, name in ((b"\xff\xfe", "UTF-16 little-endian"), (b"\xfe\xff", "UTF-16 big-endian")):
        if data.startswith(bom):
            raise RunFormatError(f"is {name} text (byte-order mark {bom.hex(' ').upper()}); "
                                 "the run format is UTF-8", path, line=1, char=1)
    nul = data.find(b"\x00")
    if nul >= 0:
        line, char = _position(data, nul)
        col = _csv_column_at(data, line, char) if csv_file else None
        raise RunFormatError("holds a NUL byte - UTF-16 or a binary file? The run format is "
                             "UTF-8 text", path, row=(line - 1 if csv_file and line > 1 and col
                                                      else None),
                             line=line, char=char, column=col)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, char = _position(data, exc.start)
        col = _csv_column_at(data, line, char) if csv_file else None
        raise RunFormatError(f"is not UTF-8: byte {data[exc.start]:02X} ({exc.reason}); the "
                             "run format is UTF-8 text", path,
                             row=(line - 1 if csv_file and line > 1 and col else None),
                             line=line, char=char, column=col) from None


def parse_number(cell: str) -> float | None:
    """A plain decimal number (``-1.5``, ``2e-3``, ``.5``), or None.  NaN, infinity,
    underscores, spaces inside and non-ASCII digits are not numbers here."""
    if not _DECIMAL.match(cell):
        return None
    return float(cell)


class _Lines:
    """The lines of a CSV file, read as bytes and checked one by one as the csv module asks
    for them (UTF-8, no byte-order mark, no NUL; the same messages as :func:`read_text`), so
    that the file is never held whole: the header is refused having read only the header,
    and the rows end up in numeric columns of 8 bytes a cell."""

    def __init__(self, fh: IO[bytes], path: str):
        self.fh, self.path = fh, path
        self.line_no = 0
        self.header: bytes | None = None

    def __iter__(self) -> _Lines:
        return self

    def _where(self, raw: bytes, off: int) -> tuple[int | None, str | None]:
        col = None
        if self.header is not None and self.line_no > 1:
            names = self.header.decode("utf-8", "replace").rstrip("\r\n").split(",")
            k = raw[:off].count(b",")
            col = names[k].strip() if k < len(names) else None
        return (self.line_no - 1 if col else None), col

    def __next__(self) -> str:
        raw = self.fh.readline()
        if not raw:
            raise StopIteration
        self.line_no += 1
        if self.line_no == 1:
            if raw.startswith(b"\xef\xbb\xbf"):
                raise RunFormatError("starts with a UTF-8 byte-order mark (bytes EF BB BF, "
                                     "invisible in most editors); the run format is UTF-8 "
                                     "without one: save the file without BOM", self.path,
                                     line=1, char=1)
            for bom, name in ((b"\xff\xfe", "UTF-16 little-endian"),
                              (b"\xfe\xff", "UTF-16 big-endian")):
                if raw.startswith(bom):
                    raise RunFormatError(f"is {name} text (byte-order mark "
                                         f"{bom.hex(' ').upper()}); the run format is UTF-8",
                                         self.path, line=1, char=1)
            self.header = raw
        nul = raw.find(b"\x00")
        if nul >= 0:
            row, col = self._where(raw, nul)
            raise RunFormatError("holds a NUL byte - UTF-16 or a binary file? The run format "
                                 "is UTF-8 text", self.path, row=row, line=self.line_no,
                                 char=nul + 1, column=col)
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            row, col = self._where(raw, exc.start)
            raise RunFormatError(f"is not UTF-8: byte {raw[exc.start]:02X} ({exc.reason}); the "
                                 "run format is UTF-8 text", self.path, row=row,
                                 line=self.line_no, char=exc.start + 1, column=col) from None


def _open_regular(path: str, limit: int = _MAX_FILE_BYTES) -> IO[bytes]:
    """A binary file object of a regular file of at most ``limit`` bytes.  Opened without
    blocking and checked on the open descriptor: a FIFO, a device (``/dev/zero``), a socket or
    a folder is refused, never waited on or read without end."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise RunFormatError(f"cannot read: {exc.strerror or exc}", path) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise RunFormatError("is not a regular file (a FIFO, a device or a folder is "
                                 "not read)", path)
        if st.st_size > limit:
            raise RunFormatError(f"is {st.st_size} bytes, larger than the {limit} this "
                                 "reader takes", path)
        return os.fdopen(fd, "rb", buffering=1 << 20)
    except BaseException:
        os.close(fd)
        raise


def read_groundtruth(path: str) -> dict[str, np.ndarray]:
    """A ground-truth CSV (``groundtruth.csv`` of a run, or a tracker's file in that layout:
    t_s, x_m, y_m, optional phi_rad that may have empty cells) with strictly increasing time;
    :class:`RunFormatError` naming the file, row and column otherwise.  No ``phi_rad`` column
    is added when the file has none."""
    gt = _read_csv(path, GROUNDTRUTH_REQUIRED, may_be_empty=("phi_rad",))
    _check_time(gt["t_s"], path)
    return gt


def _read_csv(path: str, required: Iterable[str], may_be_empty: Iterable[str] = ()
              ) -> dict[str, np.ndarray]:
    required = list(required)
    may_be_empty = set(may_be_empty)
    with _open_regular(path) as fh:
        lines = _Lines(fh, path)
        reader = csv.reader(lines, strict=True)
        try:
            try:
                header = next(reader)
            except StopIteration:
                raise RunFormatError("file is empty (no header row)", path) from None
            header = _check_header(header, required, path)
            columns, text_cols = _read_rows(reader, header, required, may_be_empty, path)
        except csv.Error as exc:
            line = reader.line_num
            raise RunFormatError(f"is not valid CSV: {exc}", path,
                                 row=line - 1 if line > 1 else None,
                                 line=line if line <= 1 else None) from None
        if text_cols:  # extra columns that are not numbers: a second pass keeps their text
            fh.seek(0)
            reader = csv.reader(_Lines(fh, path), strict=True)
            next(reader)
            idx = {h: header.index(h) for h in text_cols}
            texts: dict[str, list[str]] = {h: [] for h in text_cols}
            for row in reader:
                if not any(c.strip() for c in row):
                    continue
                for h, j in idx.items():
                    texts[h].append(row[j] if row[j].strip() else "")
            n = len(next(iter(columns.values())))
            for h in text_cols:
                columns[h] = np.array(texts[h][:n], dtype=object)
    return {h: columns[h] for h in header}


def _check_header(header: list[str], required: list[str], path: str) -> list[str]:
    header = [h.strip() for h in header]
    seen = set()
    for k, h in enumerate(header, start=1):
        if h == "":
            raise RunFormatError(f"header has an empty column name (field {k})", path, line=1)
        if h in seen:
            raise RunFormatError("column appears twice in the header", path, line=1, column=h)
        seen.add(h)
    for col in required:
        if col not in seen:
            shown = ", ".join(header)
            raise RunFormatError(
                f"missing required column (header has: {shown[:300]}"
                f"{'...' if len(shown) > 300 else ''})", path, line=1, column=col)
    return header


def _read_rows(reader: Iterable[list[str]], header: list[str], required: list[str],
               may_be_empty: set[str], path: str
               ) -> tuple[dict[str, Any], list[str]]:
    """Every data row into one array('d') per column (numbers checked as they come);
    returns the columns (numpy views) and the extra columns found not to be numbers."""
    from array import array

    ncol = len(header)
    known = [h in required or h in may_be_empty for h in header]
    blank_ok = [h in may_be_empty for h in header]
    cols = [array("d") for _ in header]
    text = [False] * ncol  # an extra column seen to hold text: no longer parsed
    nan = math.nan

    def take(row: list[str], n: int) -> None:
        if len(row) != ncol:
            raise RunFormatError(f"has {len(row)} fields, the header has {ncol}", path, row=n)
        for j in range(ncol):
            if text[j]:
                continue
            cell = row[j]
            if not cell.strip():
                if blank_ok[j]:
                    cols[j].append(nan)
                    continue
                if known[j]:
                    raise RunFormatError("empty value", path, row=n, column=header[j])
                text[j] = True
                continue
            v = parse_number(cell)
            if v is None:
                if known[j]:
                    if _NONFINITE.match(cell):
                        raise RunFormatError(f"value is {cell} (NaN and infinity are not "
                                             "allowed)", path, row=n, column=header[j])
                    raise RunFormatError(f"not a number: {show_value(cell)} (numbers are plain "
                                         "decimal, e.g. -1.5 or 2e-3)", path, row=n,
                                         column=header[j])
                text[j] = True
                continue
            if not math.isfinite(v):
                if known[j]:
                    raise RunFormatError(f"value {show_value(cell)} is too large for a double",
                                         path, row=n, column=header[j])
                text[j] = True
                continue
            cols[j].append(v)

    n = 0
    blanks: list[list[str]] = []  # blank rows not yet known to be trailing (those are dropped)
    for row in reader:
        if not any(c.strip() for c in row):
            blanks.append(row)
            continue
        for b in blanks:
            n += 1
            take(b, n)
        blanks.clear()
        n += 1
        take(row, n)
    if n == 0:
        raise RunFormatError("has a header but no data rows", path)
    out = {h: (np.frombuffer(c, dtype=np.float64) if len(c) else np.empty(0))
           for h, c, t in zip(header, cols, text) if not t}
    return out, [h for h, t in zip(header, text) if t]


def json_depth_ok(obj: Any, limit: int) -> bool:
    """True if ``obj`` nests objects/arrays at most ``limit`` deep (iterative walk)."""
    stack = [(obj, 1)]
    while stack:
        o, d = stack.pop()
        if isinstance(o, dict):
            if d > limit:
                return False
            stack.extend((v, d + 1) for v in o.values())
        elif isinstance(o, list):
            if d > limit:
                return False
            stack.extend((v, d + 1) for v in o)
    return True


def load_meta(path: str | os.PathLike) -> dict:
    """Read and validate ``meta.json`` of run folder ``path`` (defaults filled, unknown keys
    of ``robot``/``motor``/``periods_s`` still in place; see :func:`split_unknown`)."""
    mpath = os.path.join(os.fspath(path), "meta.json")
    if not os.path.isfile(mpath):
        raise RunFormatError("missing (every run folder needs meta.json)", mpath)
    text = read_text(mpath)
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RunFormatError(f"invalid JSON: {exc.msg}", mpath, line=exc.lineno,
                             char=exc.colno) from None
    except RecursionError:
        raise RunFormatError(f"JSON nested too deeply (this reader takes {_JSON_MAX_DEPTH} "
                             "levels)", mpath) from None
    except ValueError as exc:  # e.g. an integer with more digits than Python converts
        raise RunFormatError(f"invalid JSON: {exc}", mpath) from None
    if not json_depth_ok(meta, _JSON_MAX_DEPTH):
        raise RunFormatError(f"JSON nested more than {_JSON_MAX_DEPTH} levels deep", mpath)
    return validate_meta(meta, mpath)


def _time_overlap_note(tel_t: np.ndarray, gt_t: np.ndarray, gpath: str) -> str | None:
    t0, t1 = float(tel_t[0]), float(tel_t[-1])
    g0, g1 = float(gt_t[0]), float(gt_t[-1])
    if g1 < t0 or g0 > t1:
        return (f"{display(gpath)}: ground truth covers {g0:g}..{g1:g} s, wholly outside the "
                f"telemetry's {t0:g}..{t1:g} s; it is not used")
    return None


def load_run(path: str | os.PathLike | Run, check_units: bool = True,
             min_rows: int = 1) -> Run:
    """Load and validate one run folder; raise :class:`RunFormatError` on any problem.

    ``telemetry.csv`` needs at least ``min_rows`` data rows (the analyzer asks for
    :data:`ANALYZER_MIN_ROWS`).  A :class:`Run` passed in is
    returned as it is (already loaded)."""
    if isinstance(path, Run):
        return path
    path = os.fspath(path)
    if not os.path.isdir(path):
        raise RunFormatError("is not a directory (a run is a folder with meta.json and "
                             "telemetry.csv)", path)
    meta = load_meta(path)
    ignored = split_unknown(meta)
    tpath = os.path.join(path, "telemetry.csv")
    if not os.path.isfile(tpath):
        raise RunFormatError("missing (every run folder needs telemetry.csv)", tpath)
    tel = _read_csv(tpath, TELEMETRY_COLUMNS)
    n = int(tel["t_s"].size)
    if n < min_rows:
        why = (" (wheel speeds are compared over differences of rows and residuals are "
               "smoothed over 5 samples)" if min_rows == ANALYZER_MIN_ROWS else "")
        raise RunFormatError(f"has {n} data row{'s' if n != 1 else ''}; this tool needs at "
                             f"least {min_rows}{why}", tpath, row=n)
    _check_time(tel["t_s"], tpath)
    if check_units:
        _check_units_telemetry(tel, meta, tpath)
    gt = None
    notes: list[str] = []
    gpath = os.path.join(path, "groundtruth.csv")
    if os.path.isfile(gpath):
        gt = read_groundtruth(gpath)
        if "phi_rad" not in gt:
            gt["phi_rad"] = np.full(gt["t_s"].shape, np.nan)
        if check_units:
            _check_units_groundtruth(gt, tel, gpath)
        note = _time_overlap_note(tel["t_s"], gt["t_s"], gpath)
        if note:
            notes.append(note)
    elif os.path.exists(gpath):
        raise RunFormatError("is not a regular file", gpath)
    try:
        extra = sorted(f for f in os.listdir(path)
                       if f not in ("meta.json", "telemetry.csv", "groundtruth.csv"))
    except OSError as exc:
        raise RunFormatError(f"cannot list: {exc.strerror or exc}", path) from None
    for k in ignored:
        notes.append(f"{display(os.path.join(path, 'meta.json'))}: unknown key '{k}' ignored")
    return Run(path=path, meta=meta, telemetry=tel, groundtruth=gt, extra_files=extra,
               ignored_keys=ignored, notes=notes)


def label_runs(runs: list[Run]) -> None:
    """Give every run a distinct ``label``: its folder name, or as many trailing parts of
    its path as it takes to tell runs with one folder name apart (``a/run-0``,
    ``b/run-0``); the 1-based position is added where even the paths coincide."""
    parts = [display(os.path.abspath(r.path)).split(os.sep) for r in runs]
    for i, r in enumerate(runs):
        for k in range(1, len(parts[i]) + 1):
            mine = parts[i][-k:]
            if not any(j != i and p[-k:] == mine for j, p in enumerate(parts)):
                break
        label = "/".join(x for x in parts[i][-k:] if x)
        if any(j != i and p == parts[i] for j, p in enumerate(parts)):
            label = f"{label} (#{i + 1})"
        r.label = label or display(r.path)
