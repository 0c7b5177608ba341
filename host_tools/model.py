"""The analyzer's updated model (`model.json`, format ddmodel/1, see docs/analyzer.md), loaded
for the simulators and the firmware.

- the plant (`_native.Plant`) and the firmware-in-the-loop simulator take it as lib/slipmodel
  keys: `robot.*`, `motor.*`, `<effect>.<param>` and `<effect>.enabled` (`plant_keys`);
- the firmware takes the friction coefficients, from which it computes τmax (II.51) itself,
  through the SetMu command (`firmware_mu`; `python -m host_tools log --model` and
  `python -m host_tools fil record --model` send it).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

FORMAT = "ddmodel/1"


class ModelError(ValueError):
    """A model file that cannot be used; the message names the file and the field."""


MAX_BYTES = 16 << 20   # a model.json is a few KB
MAX_DEPTH = 64


def _number(p: str, where: str, value: Any) -> float:
    """A finite JSON number (not a boolean: ``true`` is not 1.0 here)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ModelError(f"{p}: {where} = {value!r} is not a number")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise ModelError(f"{p}: {where} = {value!r} is not a finite number")
    return v


def load_model(path: str | Path) -> dict[str, Any]:
    """Read and check a ddmodel/1 file; ModelError naming the file and the field on any
    problem (not UTF-8, invalid or too deeply nested JSON, huge numbers, booleans, robot or
    motor values outside the run format's ranges or physically impossible)."""
    from host_tools import runfmt

    p = runfmt.display(str(path))
    if not os.path.exists(path):
        raise ModelError(f"{p}: no such model file")
    try:
        text = runfmt.read_text(str(path), limit=MAX_BYTES)
    except runfmt.RunFormatError as exc:
        raise ModelError(str(exc)) from None
    try:
        model = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelError(f"{p}, line {exc.lineno}, character {exc.colno}: not readable JSON: {exc.msg}") from None
    except RecursionError:
        raise ModelError(f"{p}: not readable JSON: nested more than {MAX_DEPTH} levels deep") from None
    except ValueError as exc:  # an integer of more digits than Python converts
        raise ModelError(f"{p}: not readable JSON: {exc}") from None
    if not runfmt.json_depth_ok(model, MAX_DEPTH):
        raise ModelError(f"{p}: JSON nested more than {MAX_DEPTH} levels deep")
    if not isinstance(model, dict) or model.get("format") != FORMAT:
        shown = model.get("format") if isinstance(model, dict) else None
        raise ModelError(f"{p}: 'format' is {runfmt.show_value(shown)}, expected {FORMAT!r}")
    for group in ("robot", "motor", "effects"):
        value = model.get(group, {})
        if not isinstance(value, dict):
            raise ModelError(f"{p}: '{group}' must be an object")
    for group in ("robot", "motor"):
        for key, value in model.get(group, {}).items():
            _number(p, f"{group}.{key}", value)
    for effect, params in model.get("effects", {}).items():
        if not isinstance(params, dict):
            raise ModelError(f"{p}: effects.{effect} must be an object of parameters")
        for key, value in params.items():
            _number(p, f"effects.{effect}.{key}", value)
    # the robot and motor the model describes: the run format's ranges and physics
    known = {g: {k: v for k, v in model.get(g, {}).items() if k in runfmt.DEFAULT_META[g]}
             for g in ("robot", "motor")}
    try:
        runfmt.validate_meta(known, p)
    except runfmt.RunFormatError as exc:
        raise ModelError(str(exc)) from None
    return model


def plant_keys(model: dict[str, Any]) -> dict[str, float]:
    """lib/slipmodel keys (as `_native.Plant.set` and `fil --set` take them)."""
    keys: dict[str, float] = {}
    for group in ("robot", "motor"):
        for key, value in model.get(group, {}).items():
            keys[f"{group}.{key}"] = float(value)
    for effect, params in model.get("effects", {}).items():
        keys[f"{effect}.enabled"] = 1.0
        for key, value in params.items():
            keys[f"{effect}.{key}"] = float(value)
    return keys


def firmware_mu(model: dict[str, Any], path: str | Path = "model") -> tuple[float, float]:
    """(mu_s, mu_k) for the firmware's SetMu command, from which it computes its τmax."""
    robot = model.get("robot", {})
    if "mu_s" not in robot or "mu_k" not in robot:
        raise ModelError(f"{path}: robot.mu_s and robot.mu_k are needed for the firmware")
    return float(robot["mu_s"]), float(robot["mu_k"])
