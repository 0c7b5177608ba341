"""Read, validate and write run folders (``ddrun/1``, see shared/spec/run-format.md).

A run is a folder with ``meta.json``, ``telemetry.csv`` and optionally
``groundtruth.csv``.  This module is the one place that knows that layout:

* :func:`load_run` reads a folder into a :class:`Run` (meta with defaults filled,
  unknown keys kept; telemetry and ground truth as dicts of numpy columns) and
  validates it;
* :class:`RunWriter` streams ``telemetry.csv`` row by row (flushing as it goes)
  and writes ``meta.json``; :func:`write_groundtruth` writes ``groundtruth.csv``;
* :func:`check_compatible` refuses a set of runs whose parameters disagree.

Every problem raises :class:`RunFormatError`, whose message names the file and,
where it applies, the data row (1-based, the header is not counted), the line
of the file and the column.
"""
from __future__ import annotations

import copy
import csv
import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np

from host_tools import params, protocol

FORMAT = "ddrun/1"

# The robot, motor and encoder defaults are the parameter table's (params/params.json); the
# task periods are the protocol's task table (protocol/protocol.json), the firmware's schedule.
_PERIODS_S = {t["name"]: t["period_us"] / 1e6 for t in protocol.definition().timing["tasks"]}

DEFAULT_META: dict[str, Any] = {
    "format": FORMAT,
    "experiment": "",
    "source": "robot",
    "torque_clamp": False,
    "robot": dict(params.ROBOT),
    "motor": dict(params.MOTOR),
    "encoder_ppr": params.ENCODER_PPR,
    "periods_s": {k: _PERIODS_S[k] for k in ("inner", "outer", "telemetry")},
}

TELEMETRY_COLUMNS = ("t_s", "enc_r", "enc_l", "omega_r", "omega_l", "tau_cmd_r", "tau_cmd_l",
                     "pwm_r", "pwm_l", "x_odo_m", "y_odo_m", "phi_odo_rad")
GROUNDTRUTH_COLUMNS = ("t_s", "x_m", "y_m", "phi_rad")
GROUNDTRUTH_REQUIRED = ("t_s", "x_m", "y_m")  # phi_rad may be absent or empty

# Accepted ranges of the physical parameters (SI): the parameter table's.  They catch wrong
# units (millimetres, grams, degrees), not unusual robots, so they are generous.
_PARAM_RANGES = {
    **params.RANGES,
    ("periods_s", "inner"): (1e-5, 10.0), ("periods_s", "outer"): (1e-5, 10.0),
    ("periods_s", "telemetry"): (1e-5, 10.0),
}

# Bounds of the meta values that have no unit range above.
_PPR_MIN, _PPR_MAX = params.ENCODER_PPR_RANGE  # encoder counts per wheel turn
_START_POS_MAX_M = 10_000.0   # |x|, |y| of start_pose
_START_PHI_MAX_RAD = 1_000.0  # |phi| of start_pose (about 160 turns)
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

# The largest yaw rate a wheeled robot of this kind can plausibly reach, rad/s.
# A heading recorded in degrees turns 57 times faster than the same one in rad.
_MAX_YAW_RATE = 60.0


class RunFormatError(ValueError):
    """A run folder (or a set of runs) is not valid ``ddrun/1``.

    Attributes ``file``, ``row`` (1-based data row), ``column`` say where; ``line`` and
    ``char`` (1-based) locate a problem in the text where no data row applies (JSON, the
    header, an encoding error).  A file name that is not valid UTF-8 is shown with
    backslash escapes.
    """

    def __init__(self, message: str, file: str | os.PathLike | None = None,
                 row: int | None = None, column: str | None = None,
                 line: int | None = None, char: int | None = None):
        self.file = None if file is None else display(os.fspath(file))
        self.row = row
        self.column = column
        self.line = line if line is not None or row is None else row + 1
        self.char = char
        self.reason = message
        where = []
        if self.file is not None:
            where.append(self.file)
        if row is not None:
            where.append(f"row {row} (line {row + 1})")
        elif line is not None:
            where.append(f"line {line}")
        if char is not None:
            where.append(f"character {char}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__((": ".join([", ".join(where), message])) if where else message)


def display(text: str | bytes) -> str:
    """``text`` (a path) as printable UTF-8: bytes that are not UTF-8 (kept by Python as
    surrogate escapes) and control characters become backslash escapes."""
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    out = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    if any(ord(c) < 32 or ord(c) == 127 for c in out):
        out = "".join(c if 32 <= ord(c) != 127 else f"\\x{ord(c):02x}" for c in out)
    return out


@dataclass
class Run:
    """One loaded run.  ``telemetry``/``groundtruth`` map column name -> 1-D float array.

    ``meta["robot"]``, ``meta["motor"]`` and ``meta["periods_s"]`` hold only the keys this
    format defines; unknown keys found there are kept in ``ignored_keys`` (``"robot.x"`` ->
    value).  ``notes`` says what the reader noticed but did not refuse (e.g. ground truth
    outside the telemetry's time range).  ``label`` names the run in reports: the folder
    name, or a longer part of the path where two runs share a folder name
    (:func:`label_runs`)."""

    path: str
    meta: dict
    telemetry: dict[str, np.ndarray]
    groundtruth: dict[str, np.ndarray] | None = None
    extra_files: list[str] = field(default_factory=list)
    ignored_keys: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    label: str | None = None

    @property
    def name(self) -> str:
        if self.label is not None:
            return self.label
        return display(os.path.basename(os.path.normpath(self.path)))

    def __fspath__(self) -> str:
        return self.path

    @property
    def start_pose(self) -> tuple[float, float, float]:
        sp = self.meta.get("start_pose", [0.0, 0.0, 0.0])
        return (float(sp[0]), float(sp[1]), float(sp[2]))

    @property
    def t_s(self) -> np.ndarray:
        return self.telemetry["t_s"]


# ----------------------------------------------------------------------------- meta


def _merge_defaults(meta: Mapping[str, Any]) -> dict:
    out = copy.deepcopy(DEFAULT_META)
    for key, value in meta.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict):
            sub = out[key]
            sub.update(copy.deepcopy(dict(value)))
        else:
            out[key] = copy.deepcopy(value)
    return out


def validate_meta(meta: Mapping[str, Any], file: str = "meta.json") -> dict:
    """Return ``meta`` with defaults filled in, or raise :class:`RunFormatError`."""
    if not isinstance(meta, Mapping):
        raise RunFormatError("must hold a JSON object", file)
    fmt = meta.get("format", FORMAT)
    if fmt != FORMAT:
        raise RunFormatError(f"unknown format version {_show(fmt)}; this tool reads {FORMAT!r}",
                             file, column="format")
    for key in ("robot", "motor", "periods_s"):
        if key in meta and not isinstance(meta[key], Mapping):
            raise RunFormatError(f"'{key}' must be an object", file, column=key)
    full = _merge_defaults(meta)
    for (group, key), (lo, hi) in _PARAM_RANGES.items():
        value = full[group][key]
        name = f"{group}.{key}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RunFormatError(f"'{name}' must be a number, got {_show(value)}", file,
                                 column=name)
        if isinstance(value, float) and not math.isfinite(value):
            raise RunFormatError(f"'{name}' is {value}", file, column=name)
        if not lo <= value <= hi:
            raise RunFormatError(
                f"'{name}' = {value} is outside the plausible range [{lo}, {hi}] (SI units: "
                "metres, kilograms, seconds, volts, N m) - wrong units?", file, column=name)
    ppr = full["encoder_ppr"]
    if not _is_number(ppr) or not _PPR_MIN <= ppr <= _PPR_MAX or ppr != int(ppr):
        raise RunFormatError(f"'encoder_ppr' must be an integer in [{_PPR_MIN}, {_PPR_MAX}], got "
                             f"{_show(ppr)}", file, column="encoder_ppr")
    full["encoder_ppr"] = int(ppr)
    if not isinstance(full["torque_clamp"], bool):
        raise RunFormatError(f"'torque_clamp' must be true or false, got "
                             f"{_show(full['torque_clamp'])}", file, column="torque_clamp")
    if "start_pose" in full:
        sp = full["start_pose"]
        lim = (_START_POS_MAX_M, _START_POS_MAX_M, _START_PHI_MAX_RAD)
        if (not isinstance(sp, (list, tuple)) or len(sp) != 3
                or not all(_is_number(v) and abs(v) <= m for v, m in zip(sp, lim))):
            raise RunFormatError(
                f"'start_pose' must be [x_m, y_m, phi_rad] with |x|, |y| <= {_START_POS_MAX_M:g} m "
                f"and |phi| <= {_START_PHI_MAX_RAD:g} rad, got {_show(sp)}", file,
                column="start_pose")
    ref = full.get("reference")
    if isinstance(ref, Mapping):
        if "kind" in ref and not isinstance(ref["kind"], str):
            raise RunFormatError(f"'reference.kind' must be a string, got {_show(ref['kind'])}",
                                 file, column="reference.kind")
        for k in ("accel", "cruise", "radius", "t0_s"):
            v = ref.get(k)
            if v is None:
                continue
            if not _is_number(v) or abs(v) > 1e6:
                raise RunFormatError(f"'reference.{k}' must be a number within +-1e6, got "
                                     f"{_show(v)}", file, column=f"reference.{k}")
    return full


def _is_number(v: Any) -> bool:
    """A JSON number that is finite (integers of any size included), not a boolean."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    return isinstance(v, int) or math.isfinite(v)


def _show(v: Any, limit: int = 80) -> str:
    """A value for a message: numpy scalars as plain numbers, long values cut."""
    if isinstance(v, np.generic):
        v = v.item()
    try:
        text = repr(v)
    except (RecursionError, ValueError):
        text = f"<{type(v).__name__}>"
    return text if len(text) <= limit else text[:limit] + "..."


def split_unknown(meta: dict) -> dict[str, Any]:
    """Remove the keys of ``robot``, ``motor`` and ``periods_s`` that the format does not
    define from ``meta`` (in place); return them as ``{"robot.key": value}``."""
    out: dict[str, Any] = {}
    for group in ("robot", "motor", "periods_s"):
        sub = meta.get(group)
        if not isinstance(sub, dict):
            continue
        for k in [k for k in sub if k not in DEFAULT_META[group]]:
            out[f"{group}.{k}"] = sub.pop(k)
    return out


# ------------------------------------------------------------------------------ CSV


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


def read_text(path: str, csv_file: bool = False) -> str:
    """The text of a run file: UTF-8 without byte-order mark and without NUL bytes;
    anything else raises :class:`RunFormatError` naming what it is and where."""
    try:
        size = os.path.getsize(path)
        if size > _MAX_FILE_BYTES:
            raise RunFormatError(f"is {size} bytes, larger than the {_MAX_FILE_BYTES} this "
                                 "reader takes", path)
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise RunFormatError(f"cannot read: {exc.strerror or exc}", path) from None
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


def _read_csv(path: str, required: Iterable[str], may_be_empty: Iterable[str] = ()
              ) -> dict[str, np.ndarray]:
    required = list(required)
    may_be_empty = set(may_be_empty)
    text = read_text(path, csv_file=True)
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        try:
            header = next(reader)
        except StopIteration:
            raise RunFormatError("file is empty (no header row)", path) from None
        rows = list(reader)
    except csv.Error as exc:
        line = reader.line_num
        raise RunFormatError(f"is not valid CSV: {exc}", path,
                             row=line - 1 if line > 1 else None,
                             line=line if line <= 1 else None) from None
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
    # drop trailing blank lines only
    while rows and not any(c.strip() for c in rows[-1]):
        rows.pop()
    if not rows:
        raise RunFormatError("has a header but no data rows", path)
    columns: dict[str, list] = {h: [] for h in header}
    for i, row in enumerate(rows, start=1):
        if len(row) != len(header):
            raise RunFormatError(f"has {len(row)} fields, the header has {len(header)}", path, row=i)
        for h, cell in zip(header, row):
            columns[h].append(cell.strip())
    out: dict[str, np.ndarray] = {}
    for h in header:
        cells = columns[h]
        known = h in required or h in may_be_empty
        values = np.empty(len(cells))
        ok = True
        for i, cell in enumerate(cells, start=1):
            if cell == "":
                if h in may_be_empty:
                    values[i - 1] = np.nan
                    continue
                if known:
                    raise RunFormatError("empty value", path, row=i, column=h)
                ok = False
                break
            v = parse_number(cell)
            if v is None:
                if known:
                    if _NONFINITE.match(cell):
                        raise RunFormatError(f"value is {cell} (NaN and infinity are not "
                                             "allowed)", path, row=i, column=h)
                    raise RunFormatError(f"not a number: {_show(cell)} (numbers are plain "
                                         "decimal, e.g. -1.5 or 2e-3)", path, row=i, column=h)
                ok = False
                break
            if not math.isfinite(v):
                if known:
                    raise RunFormatError(f"value {_show(cell)} is too large for a double",
                                         path, row=i, column=h)
                ok = False
                break
            values[i - 1] = v
        out[h] = values if ok else np.array(cells, dtype=object)  # extra text column: kept as is
    return out


def _check_time(t: np.ndarray, path: str, col: str = "t_s") -> None:
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0]) + 2  # data row of the second sample
        raise RunFormatError(
            f"time does not increase: {float(t[i - 1])!r} after {float(t[i - 2])!r}", path,
            row=i, column=col)


def _wrapped_heading_rate(t: np.ndarray, phi: np.ndarray, window_s: float = 0.1) -> float:
    """Largest heading rate over ~window_s, with 2*pi wraps between samples removed."""
    ok = np.isfinite(phi)
    t, phi = t[ok], phi[ok]
    if t.size < 2:
        return 0.0
    d = np.diff(phi)
    d = d - 2 * np.pi * np.round(d / (2 * np.pi))
    cum = np.concatenate([[0.0], np.cumsum(d)])
    j = np.searchsorted(t, t + window_s)
    j = np.minimum(j, t.size - 1)
    span = t[j] - t
    m = span >= 0.5 * window_s
    if not np.any(m):
        span = np.array([t[-1] - t[0]])
        return float(abs(cum[-1]) / span[0]) if span[0] > 0 else 0.0
    return float(np.max(np.abs(cum[j][m] - cum[m]) / span[m]))


def _unwrap(phi: np.ndarray) -> np.ndarray:
    """Heading with jumps of about 2 pi between samples removed."""
    return np.unwrap(phi) if phi.size else phi


def _ratio(a: np.ndarray, b: np.ndarray) -> float | None:
    """Least-squares scale k with a ~= k*b, or None when b carries too little signal."""
    bb = float(np.dot(b, b))
    if bb <= 0:
        return None
    return float(np.dot(a, b) / bb)


def _check_units_telemetry(tel: dict[str, np.ndarray], meta: dict, path: str) -> None:
    t = tel["t_s"]
    period = meta["periods_s"]["telemetry"]
    if t.size >= 3:
        med = float(np.median(np.diff(t)))
        if med > 50 * period:
            raise RunFormatError(
                f"median time step is {med:g} but periods_s.telemetry is {period:g} s - is time "
                "in milliseconds? It must be in seconds", path, column="t_s")
    for col in ("pwm_r", "pwm_l"):
        m = float(np.max(np.abs(tel[col])))
        if m > 1.0 + 1e-9:
            i = int(np.argmax(np.abs(tel[col]))) + 1
            raise RunFormatError(f"duty {tel[col][i - 1]:g} is outside [-1, 1] - percent or "
                                 "timer counts instead of a fraction?", path, row=i, column=col)
    stall = meta["motor"]["stall_nm"]
    for col in ("tau_cmd_r", "tau_cmd_l"):
        m = float(np.max(np.abs(tel[col])))
        if m > 20 * stall:
            i = int(np.argmax(np.abs(tel[col]))) + 1
            raise RunFormatError(f"torque {tel[col][i - 1]:g} is more than 20 times the motor "
                                 f"stall torque {stall:g} N m - N mm instead of N m?", path,
                                 row=i, column=col)
    ppr = meta["encoder_ppr"]
    r = meta["robot"]["r"]
    b = meta["robot"]["b"]
    rad_per_count = 2 * np.pi / ppr
    th_r = tel["enc_r"] * rad_per_count
    th_l = tel["enc_l"] * rad_per_count
    # wheel speeds against encoder differences
    if t.size >= 3:
        for side, th in (("r", th_r), ("l", th_l)):
            col = f"omega_{side}"
            w_enc = np.diff(th) / np.diff(t)
            w_rec = 0.5 * (tel[col][1:] + tel[col][:-1])
            if np.max(np.abs(w_enc)) > 20 * rad_per_count / period:  # enough signal
                k = _ratio(w_rec, w_enc)
                if k is not None and (k > 4.0 or k < -4.0):
                    hint = ("rpm" if 6 < abs(k) < 14 else "deg/s" if 35 < abs(k) < 90 else
                            "another unit")
                    raise RunFormatError(
                        f"wheel speed is {k:.3g} times the speed from '{'enc_' + side}' differences"
                        f" - {hint} instead of rad/s?", path, column=col)
    # odometry against encoder distance and heading
    dist_enc = float(np.sum(np.abs(np.diff(0.5 * r * (th_r + th_l)))))
    path_odo = float(np.sum(np.hypot(np.diff(tel["x_odo_m"]), np.diff(tel["y_odo_m"]))))
    if dist_enc > 0.01:
        k = path_odo / dist_enc
        if k > 20:
            raise RunFormatError(
                f"odometry path length is {k:.3g} times the encoder distance - millimetres "
                "instead of metres?", path, column="x_odo_m")
    phi_enc = r * (th_r - th_l) / (2 * b)
    phi_enc = phi_enc - phi_enc[0]
    phi_odo = _unwrap(tel["phi_odo_rad"])
    phi_odo = phi_odo - phi_odo[0]
    if np.max(np.abs(phi_enc)) > 0.2:
        k = _ratio(phi_odo, phi_enc)
        if k is not None and abs(k) > 10:
            raise RunFormatError(
                f"heading turns {k:.3g} times as much as the encoders imply - degrees instead of "
                "radians?", path, column="phi_odo_rad")
    rate = _wrapped_heading_rate(t, tel["phi_odo_rad"])
    if rate > _MAX_YAW_RATE:
        raise RunFormatError(
            f"heading changes at {rate:.3g} /s, above any plausible yaw rate ({_MAX_YAW_RATE} "
            "rad/s) - degrees instead of radians?", path, column="phi_odo_rad")


def _check_units_groundtruth(gt: dict[str, np.ndarray], tel: dict[str, np.ndarray],
                             path: str) -> None:
    t = gt["t_s"]
    if "phi_rad" in gt and np.any(np.isfinite(gt["phi_rad"])):
        rate = _wrapped_heading_rate(t, gt["phi_rad"])
        if rate > _MAX_YAW_RATE:
            raise RunFormatError(
                f"heading changes at {rate:.3g} /s, above any plausible yaw rate "
                f"({_MAX_YAW_RATE} rad/s) - degrees instead of radians?", path, column="phi_rad")
        # headings may be wrapped to (-pi, pi] or unwrapped, in either file: compare the
        # unwrapped spans (degrees survive unwrapping: the yaw-rate check above has already
        # refused steps large enough to be mistaken for a 2 pi wrap)
        ok = np.isfinite(gt["phi_rad"])
        phi_gt = _unwrap(gt["phi_rad"][ok])
        phi_odo = np.interp(t[ok], tel["t_s"], _unwrap(tel["phi_odo_rad"]))
        span_odo = float(np.ptp(phi_odo)) if phi_odo.size else 0.0
        span_gt = float(np.ptp(phi_gt)) if phi_gt.size else 0.0
        if span_odo > 0.3 and span_gt > 20 * span_odo:
            raise RunFormatError(
                f"heading spans {span_gt:.3g} while odometry spans {span_odo:.3g} rad - "
                "degrees instead of radians?", path, column="phi_rad")
    span_gt = max(float(np.ptp(gt["x_m"])), float(np.ptp(gt["y_m"])))
    span_odo = max(float(np.ptp(tel["x_odo_m"])), float(np.ptp(tel["y_odo_m"])))
    if span_odo > 0.02 and span_gt > 50 * span_odo:
        raise RunFormatError(
            f"position spans {span_gt:.3g} while odometry spans {span_odo:.3g} m - millimetres "
            "instead of metres?", path, column="x_m")


# ----------------------------------------------------------------------------- load


def _json_depth_ok(obj: Any, limit: int) -> bool:
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
    if not _json_depth_ok(meta, _JSON_MAX_DEPTH):
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
        gt = _read_csv(gpath, GROUNDTRUTH_REQUIRED, may_be_empty=("phi_rad",))
        _check_time(gt["t_s"], gpath)
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


# Keys whose values must agree across runs analysed together.
_SHARED_KEYS = ("robot", "motor", "encoder_ppr")


def check_compatible(runs: list[Run], rel_tol: float = 1e-9) -> None:
    """Raise :class:`RunFormatError` if runs disagree on the robot, motor or encoder."""
    if len(runs) < 2:
        return
    ref = runs[0]
    for run in runs[1:]:
        for key in _SHARED_KEYS:
            a, b = ref.meta[key], run.meta[key]
            pairs = ([(f"{key}.{k}", a.get(k), b.get(k)) for k in sorted(set(a) | set(b))]
                     if isinstance(a, dict) else [(key, a, b)])
            for name, va, vb in pairs:
                same = (va == vb) if not (isinstance(va, (int, float)) and
                                          isinstance(vb, (int, float))) else \
                    math.isclose(va, vb, rel_tol=rel_tol, abs_tol=0.0)
                if not same:
                    raise RunFormatError(
                        f"runs disagree on '{name}': {_show(va)} in {display(ref.path)} but "
                        f"{_show(vb)} in {display(run.path)}; runs analysed together must come "
                        "from one robot",
                        os.path.join(run.path, "meta.json"), column=name)


# ---------------------------------------------------------------------------- write


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
        self._fh = open(self._tpath, "w", newline="")
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
                    raise RunFormatError(f"not a number: {_show(v)}", self._tpath, row=n, column=c)
                cells.append(v)
                continue
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise RunFormatError(f"not a number: {_show(v)}", self._tpath, row=n, column=c) from None
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
