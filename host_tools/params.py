"""The robot's parameter table for the host tools, read from params/params.json.

params/params.json is the one place where Table II.2, the datasheet motor and the encoder's
counts per turn are written, each with its unit, the range every consumer accepts and its
thesis reference. params/generate.py turns it into lib/slipmodel's C++ header (through
:func:`load`, so the two cannot read it differently); the host tools take their defaults and
ranges from here.

    ROBOT, MOTOR      defaults of meta.json's "robot" and "motor" (the run format's keys)
    ENCODER_PPR       encoder counts per wheel turn
    MODEL             settings of the host's nominal model that no table gives (section "model":
                      not in meta.json nor the protocol)
    RANGES            {(group, name): (min, max)} of every value meta.json holds
    TOLERANCES        {(group, name): tol}: the true value lies within value +- tol
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

TABLE_PATH = Path(__file__).resolve().parent.parent / "params" / "params.json"

GROUPS = ("robot", "motor")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class TableError(ValueError):
    """A malformed parameter table."""


@dataclass(frozen=True)
class Param:
    group: str          # "robot", "motor" or "encoder"
    name: str
    value: float
    unit: str
    min: float
    max: float
    ref: str            # where the value comes from (thesis section, table)
    doc: str
    run_format: bool    # part of meta.json and the protocol's Params message
    tol: float = 0.0    # the true value lies within value +- tol (same unit)
    tol_ref: str = ""   # where that tolerance comes from


@dataclass(frozen=True)
class Table:
    doc: str
    params: tuple[Param, ...]   # robot and motor, in table order
    encoder: Param
    model: tuple[Param, ...] = ()  # the nominal model's settings (section "model")

    def group(self, group: str, run_format_only: bool = False) -> tuple[Param, ...]:
        return tuple(p for p in self.params
                     if p.group == group and (p.run_format or not run_format_only))

    def defaults(self, group: str, run_format_only: bool = True) -> dict[str, float]:
        return {p.name: p.value for p in self.group(group, run_format_only)}


def _param(group: str, spec: Any, integer: bool = False) -> Param:
    where = f"{group}.{spec.get('name', '?') if isinstance(spec, dict) else '?'}"
    if not isinstance(spec, dict):
        raise TableError(f"{where}: must be an object")
    for key in ("name", "value", "unit", "min", "max", "ref", "doc", "tol", "tol_ref"):
        if key not in spec:
            raise TableError(f"{where}: '{key}' missing")
    if not _NAME.match(str(spec["name"])):
        raise TableError(f"{where}: name must be a C identifier")
    nums = [spec[k] for k in ("value", "min", "max")]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
               for v in nums):
        raise TableError(f"{where}: value, min and max must be finite numbers")
    if integer and not all(float(v).is_integer() for v in nums):
        raise TableError(f"{where}: value, min and max must be integers")
    value, lo, hi = nums
    if not lo <= value <= hi:
        raise TableError(f"{where}: value {value} outside its range [{lo}, {hi}]")
    tol = spec["tol"]
    if not (isinstance(tol, (int, float)) and not isinstance(tol, bool) and math.isfinite(tol)
            and tol >= 0):
        raise TableError(f"{where}: tol must be a finite number >= 0")
    if not (lo <= value - tol and value + tol <= hi):
        raise TableError(f"{where}: value +- tol leaves the range [{lo}, {hi}]")
    if not str(spec["tol_ref"]).strip():
        raise TableError(f"{where}: tol_ref must say where the tolerance comes from")
    run_format = spec.get("run_format", True)
    if not isinstance(run_format, bool):
        raise TableError(f"{where}: run_format must be true or false")
    conv = int if integer else float
    return Param(group, spec["name"], conv(value), str(spec["unit"]), conv(lo), conv(hi),
                 str(spec["ref"]), str(spec["doc"]), run_format, float(tol), str(spec["tol_ref"]))


def parse(spec: Any) -> Table:
    """A :class:`Table` from the decoded JSON; raises :class:`TableError`."""
    if not isinstance(spec, dict) or not isinstance(spec.get("groups"), dict):
        raise TableError("must be an object with 'groups'")
    if set(spec["groups"]) != set(GROUPS):
        raise TableError(f"groups must be {GROUPS}, got {sorted(spec['groups'])}")
    params: list[Param] = []
    for group in GROUPS:
        entries = spec["groups"][group].get("params")
        if not isinstance(entries, list) or not entries:
            raise TableError(f"{group}: 'params' must be a non-empty list")
        params.extend(_param(group, e) for e in entries)
    names = [(p.group, p.name) for p in params]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise TableError(f"parameters named twice: {dup}")
    encoder = _param("encoder", spec.get("encoder"), integer=True)
    model: list[Param] = []
    if "model" in spec:
        entries = spec["model"].get("params") if isinstance(spec["model"], dict) else None
        if not isinstance(entries, list):
            raise TableError("model: 'params' must be a list")
        model = [_param("model", dict(e, run_format=False) if isinstance(e, dict) else e)
                 for e in entries]
        model_names = [p.name for p in model]
        if len(set(model_names)) != len(model_names):
            raise TableError(f"model: parameters named twice: {model_names}")
    return Table(str(spec.get("doc", "")), tuple(params), encoder, tuple(model))


def load(path: Path | str = TABLE_PATH) -> Table:
    """The table in ``path``; TableError naming the file (and line and character of a JSON
    error) when it cannot be read, is not JSON, or is nested beyond any table's depth."""
    try:
        with open(path, encoding="utf-8") as fh:
            spec = json.load(fh)
    except json.JSONDecodeError as exc:
        raise TableError(f"{path}, line {exc.lineno}, character {exc.colno}: invalid JSON: "
                         f"{exc.msg}") from None
    except RecursionError:
        raise TableError(f"{path}: invalid JSON: nested too deeply") from None
    except (OSError, ValueError) as exc:  # unreadable, not UTF-8, an integer too long
        raise TableError(f"{path}: {exc}") from None
    try:
        return parse(spec)
    except TableError as exc:
        raise TableError(f"{path}: {exc}") from None


TABLE = load()
ROBOT: dict[str, float] = TABLE.defaults("robot")
MOTOR: dict[str, float] = TABLE.defaults("motor")
ENCODER_PPR: int = int(TABLE.encoder.value)  # parsed as an integer (_param)
RANGES: dict[tuple[str, str], tuple[float, float]] = {
    (p.group, p.name): (p.min, p.max) for p in TABLE.params if p.run_format}
ENCODER_PPR_RANGE: tuple[int, int] = (int(TABLE.encoder.min), int(TABLE.encoder.max))
TOLERANCES: dict[tuple[str, str], float] = {(p.group, p.name): p.tol
                                             for p in TABLE.params + TABLE.model}
MODEL: dict[str, float] = {p.name: p.value for p in TABLE.model}


def resolve_param_ranges(protocol_spec: dict[str, Any]) -> dict[str, Any]:
    """protocol.json fields with ``"param": "group.name"`` take that parameter's range from this
    table as their ``min``/``max`` (in place; returns the spec).  protocol/generate.py and
    host_tools.protocol both call this, so the firmware's validator and the host check the
    same range, written once, here."""
    for msg in protocol_spec.get("messages", []):
        for f in msg.get("fields", []):
            key = f.get("param")
            if key is None:
                continue
            group, _, name = str(key).partition(".")
            if (group, name) not in RANGES:
                raise TableError(f"protocol field {msg.get('name')}.{f.get('name')}: "
                                 f"param {key!r} is not in {TABLE_PATH.name}")
            if "min" in f or "max" in f:
                raise TableError(f"protocol field {msg.get('name')}.{f.get('name')}: "
                                 "give either param or min/max, not both")
            f["min"], f["max"] = RANGES[(group, name)]
    return protocol_spec
