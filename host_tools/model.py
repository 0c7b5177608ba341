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
from pathlib import Path
from typing import Any

FORMAT = "ddmodel/1"


class ModelError(ValueError):
    """A model file that cannot be used; the message names the file and the field."""


def load_model(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        model = json.loads(p.read_text())
    except FileNotFoundError:
        raise ModelError(f"{p}: no such model file") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(f"{p}: not readable JSON: {exc}") from None
    if not isinstance(model, dict) or model.get("format") != FORMAT:
        raise ModelError(f"{p}: 'format' is {model.get('format') if isinstance(model, dict) else None!r}, "
                         f"expected {FORMAT!r}")
    for group in ("robot", "motor", "effects"):
        value = model.get(group, {})
        if not isinstance(value, dict):
            raise ModelError(f"{p}: '{group}' must be an object")
    for group in ("robot", "motor"):
        for key, value in model.get(group, {}).items():
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ModelError(f"{p}: {group}.{key} = {value!r} is not a finite number")
    for effect, params in model.get("effects", {}).items():
        if not isinstance(params, dict):
            raise ModelError(f"{p}: effects.{effect} must be an object of parameters")
        for key, value in params.items():
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ModelError(f"{p}: effects.{effect}.{key} = {value!r} is not a finite number")
    return model


def plant_keys(model: dict[str, Any]) -> dict[str, float]:
    """lib/slipmodel keys (as `_native.Plant.set` and `fil --set` take them)."""
    keys: dict[str, float] = {}
    for group in ("robot", "motor"):
        for key, value in model.get(group, {}).items():
            keys[f"{group}.{key}"] = float(value)
    from host_tools.analyzer.effects import ADDED_PARAMETER_EFFECTS
    for effect, params in model.get("effects", {}).items():
        if effect in ADDED_PARAMETER_EFFECTS:
            continue   # a change of the robot's parameters, already folded into "robot"
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
