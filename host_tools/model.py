"""The analyzer's updated model (`model.json`, format ddmodel/1, see docs/analyzer.md), loaded
for the simulators and the firmware.

- the plant (`_native.Plant`) and the firmware-in-the-loop simulator take it as lib/slipmodel
  keys: `robot.*`, `motor.*`, `<effect>.<param>` and `<effect>.enabled` (`plant_keys`);
- the firmware takes the friction coefficients, from which it computes τmax (II.51) itself,
  through the SetMu command (`firmware_mu`), and the wheel radius, half track, back-EMF ratio
  and voltage drop through SetModel (`firmware_model`); `python -m host_tools log --model`,
  `fil record --model`, `drive --model` and `Robot(model=...)` send both.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from host_tools import params as param_table

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


def firmware_model(model: dict[str, Any], path: str | Path = "model") -> dict[str, float]:
    """The SetModel values of a model: wheel radius ``r`` and half track ``b`` (the model's
    robot, in which the analyzer folds wheel_radius and track_width; params/params.json's where
    the model has none), and the motor's back-EMF
    ratio and voltage drop relative to the datasheet motor the firmware holds (params/params.json).

    The model's motor is the one the recording's torque->duty map assumed (meta.json ``motor``:
    the datasheet motor with the fit the firmware had then, slip::motor_as_driven), and its
    effects motor_back_emf / driver_voltage_drop act on top of it.  With S the supply, stall
    torque st and no-load speed nl, the motor a map assumes is st (S - D)/S u - k st w/nl; so the
    total relative to the datasheet (st0, nl0) is D = S - st_m (S - D_m)/st0 and
    k = k_m (st_m/nl_m) (nl0/st0) (the inverse of motor_as_driven, composed)."""
    robot, motor, eff = model.get("robot", {}), model.get("motor", {}), model.get("effects", {})
    robot = {**param_table.ROBOT, **robot}  # a key the model leaves out: the nominal value
    sheet = param_table.MOTOR
    supply = float(motor.get("supply_v", sheet["supply_v"]))
    if abs(supply - sheet["supply_v"]) > 1e-9 * sheet["supply_v"]:
        raise ModelError(f"{path}: motor.supply_v = {supply} differs from the firmware's "
                         f"{sheet['supply_v']} V (params/params.json); SetModel cannot change it")
    st_m = float(motor.get("stall_nm", sheet["stall_nm"]))
    nl_m = float(motor.get("no_load_rad_s", sheet["no_load_rad_s"]))
    k_m = float(eff.get("motor_back_emf", {}).get("ke_ratio", 1.0))
    d_m = float(eff.get("driver_voltage_drop", {}).get("volts", 0.0))
    drop = supply - st_m * (supply - d_m) / sheet["stall_nm"]
    ke = k_m * (st_m / nl_m) * (sheet["no_load_rad_s"] / sheet["stall_nm"])
    return {"r": float(robot["r"]), "b": float(robot["b"]),
            "ke_ratio": round(ke, 4), "drop_v": round(0.0 if abs(drop) < 1e-9 else drop, 3)}


def firmware_commands(model: dict[str, Any], path: str | Path = "model"
                      ) -> tuple[tuple[float, float], dict[str, float]]:
    """(SetMu (mu_s, mu_k), SetModel values) of a model, checked against the protocol's ranges
    (ModelError naming the file and the field)."""
    from host_tools import protocol as P
    mu = firmware_mu(model, path)
    values = firmware_model(model, path)
    d = P.definition()
    try:
        d.raw_values("SetMu", {"mu_s": mu[0], "mu_k": mu[1]})
        d.raw_values("SetModel", values)
    except P.ProtocolError as exc:
        raise ModelError(f"{path}: cannot be sent to the firmware: {exc}") from None
    return mu, values
