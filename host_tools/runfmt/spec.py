"""What ``ddrun/1`` is (shared/spec/run-format.md): the version tag, the meta.json defaults, the
column names, the :class:`Run` a reader returns and the :class:`RunFormatError` every problem
raises.  Reading, validating and writing live beside this module (``read``, ``validate``,
``write``)."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

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


def show_value(v: Any, limit: int = 80) -> str:
    """A value for a message: numpy scalars as plain numbers, long values cut."""
    if isinstance(v, np.generic):
        v = v.item()
    try:
        text = repr(v)
    except (RecursionError, ValueError):
        text = f"<{type(v).__name__}>"
    return text if len(text) <= limit else text[:limit] + "..."


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
