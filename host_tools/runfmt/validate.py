"""Validate ``ddrun/1`` content (shared/spec/run-format.md): meta.json's values and ranges,
increasing time, units that look wrong (milliseconds, degrees, millimetres, rpm), and that
runs analysed together come from one robot."""
from __future__ import annotations

import copy
import math
import os
from typing import Any, Mapping

import numpy as np

from host_tools import params
from host_tools.runfmt.spec import DEFAULT_META, FORMAT, Run, RunFormatError, show_value, display

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

# The smallest step any tool simulates the plant with (the analyzer's --dt lower bound).  The
# plant steps explicitly: a robot whose fastest physical mode is quicker than half this step
# cannot be simulated stably by any tool (see _check_physics).
PLANT_DT_MIN_S = 1e-4

# The largest yaw rate a wheeled robot of this kind can plausibly reach, rad/s.
# A heading recorded in degrees turns 57 times faster than the same one in rad.
_MAX_YAW_RATE = 60.0


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
        raise RunFormatError(f"unknown format version {show_value(fmt)}; this tool reads {FORMAT!r}",
                             file, column="format")
    for key in ("robot", "motor", "periods_s"):
        if key in meta and not isinstance(meta[key], Mapping):
            raise RunFormatError(f"'{key}' must be an object", file, column=key)
    full = _merge_defaults(meta)
    for (group, key), (lo, hi) in _PARAM_RANGES.items():
        value = full[group][key]
        name = f"{group}.{key}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RunFormatError(f"'{name}' must be a number, got {show_value(value)}", file,
                                 column=name)
        if isinstance(value, float) and not math.isfinite(value):
            raise RunFormatError(f"'{name}' is {value}", file, column=name)
        if not lo <= value <= hi:
            raise RunFormatError(
                f"'{name}' = {value} is outside the plausible range [{lo}, {hi}] (SI units: "
                "metres, kilograms, seconds, volts, N m) - wrong units?", file, column=name)
    _check_physics(full, file)
    ppr = full["encoder_ppr"]
    if not _is_number(ppr) or not _PPR_MIN <= ppr <= _PPR_MAX or ppr != int(ppr):
        raise RunFormatError(f"'encoder_ppr' must be an integer in [{_PPR_MIN}, {_PPR_MAX}], got "
                             f"{show_value(ppr)}", file, column="encoder_ppr")
    full["encoder_ppr"] = int(ppr)
    if not isinstance(full["torque_clamp"], bool):
        raise RunFormatError(f"'torque_clamp' must be true or false, got "
                             f"{show_value(full['torque_clamp'])}", file, column="torque_clamp")
    if "start_pose" in full:
        sp = full["start_pose"]
        lim = (_START_POS_MAX_M, _START_POS_MAX_M, _START_PHI_MAX_RAD)
        if (not isinstance(sp, (list, tuple)) or len(sp) != 3
                or not all(_is_number(v) and abs(v) <= m for v, m in zip(sp, lim))):
            raise RunFormatError(
                f"'start_pose' must be [x_m, y_m, phi_rad] with |x|, |y| <= {_START_POS_MAX_M:g} m "
                f"and |phi| <= {_START_PHI_MAX_RAD:g} rad, got {show_value(sp)}", file,
                column="start_pose")
    ref = full.get("reference")
    if isinstance(ref, Mapping):
        if "kind" in ref and not isinstance(ref["kind"], str):
            raise RunFormatError(f"'reference.kind' must be a string, got {show_value(ref['kind'])}",
                                 file, column="reference.kind")
        for k in ("accel", "cruise", "radius", "t0_s"):
            v = ref.get(k)
            if v is None:
                continue
            if not _is_number(v) or abs(v) > 1e6:
                raise RunFormatError(f"'reference.{k}' must be a number within +-1e6, got "
                                     f"{show_value(v)}", file, column=f"reference.{k}")
    return full


def wheel_time_constant_s(meta: Mapping[str, Any]) -> float:
    """The fastest mode of the plant: a slipping wheel's speed settles against the motor's
    back-EMF damping, stall_nm / no_load_rad_s (N m s/rad), with the time constant
    I_wy * no_load_rad_s / stall_nm.  An explicit step longer than twice it diverges."""
    r, m = meta["robot"], meta["motor"]
    return float(r["I_wy"]) * float(m["no_load_rad_s"]) / float(m["stall_nm"])


def max_stable_plant_dt_s(meta: Mapping[str, Any]) -> float:
    """The longest explicit plant step that stays stable for this robot (validated meta)."""
    return 2.0 * wheel_time_constant_s(meta)


def _check_physics(full: dict, file: str) -> None:
    """Values inside their unit ranges that no robot can have, refused with the reason.

    * The static loads (thesis II.27-II.29): the caster carries N_c = m g d / (d + e) and the
      wheels m g e / (d + e).  e = 0 puts the centre of mass over the caster contact: the
      wheels carry no load and cannot drive (and with d = 0 too the loads are 0/0).
    * The plant's fastest mode (:func:`wheel_time_constant_s`) must allow a stable step of
      :data:`PLANT_DT_MIN_S`: an I_wy far too small for the motor (1e-9 kg m^2) makes every
      replay diverge."""
    r = full["robot"]
    if not r["e"] > 0:
        loads = ("0/0: undefined" if not r["d"] + r["e"] > 0 else "m g e / (d + e) = 0")
        raise RunFormatError(
            f"'robot.e' = {r['e']}: the centre of mass sits over the caster contact, so the "
            f"wheels' normal load is {loads} and they cannot drive; e (centre of mass to "
            "caster contact) must be > 0 m", file, column="robot.e")
    tau = wheel_time_constant_s(full)
    if not tau * 2.0 >= PLANT_DT_MIN_S:
        raise RunFormatError(
            f"'robot.I_wy' = {r['I_wy']} kg m^2 with this motor: a slipping wheel settles "
            f"against the back-EMF with time constant I_wy * no_load_rad_s / stall_nm = "
            f"{tau:.3g} s, shorter than half the plant's smallest step ({PLANT_DT_MIN_S:g} s), so "
            "no simulation of this robot is stable - a wheel inertia that small is not physical "
            "(wrong units?)", file, column="robot.I_wy")


def _is_number(v: Any) -> bool:
    """A JSON number that is finite (integers of any size included), not a boolean."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    return isinstance(v, int) or math.isfinite(v)



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
                        f"runs disagree on '{name}': {show_value(va)} in {display(ref.path)} but "
                        f"{show_value(vb)} in {display(run.path)}; runs analysed together must come "
                        "from one robot",
                        os.path.join(run.path, "meta.json"), column=name)
