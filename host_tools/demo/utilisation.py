"""Torque utilisation at 72 rad/s² with the clamp on: on the nominal plant and on the firmware
in the loop."""
from __future__ import annotations

from host_tools.demo.common import ACCEL_TIME_S


import numpy as np


def _utilisation(r_wheel: float, j_roll: float, tau_max: float, params: dict) -> dict:
    """Torque utilisation during clamp-limited acceleration (II.6.3 profile, clamp on, motor,
    first 2 s): over the ticks in which the clamp acts on both wheels, the torque the wheels
    receive over slipmodel's tau_max (the traction the clamp is there to use; the clamp's own
    limit is tau_max less the back-EMF margin, lib/control/README.md), and over the commanded
    torque. The wheels roll (clamp on: no slip, checked), so the torque a wheel receives over a
    tick is the rolling inertia times its speed change over the tick divided by the tick."""
    from host_tools.truth import INNER_S, nominal_closed_loop
    r = nominal_closed_loop("line", 72.0 * r_wheel, ACCEL_TIME_S * 72.0 * r_wheel, clamp=True,
                            T_s=2.0, actuator="duty", params=params)
    clamped = (r["clamped_r"][:-1] > 0) & (r["clamped_l"][:-1] > 0)
    slipped = bool(r["slip_fine"].any())
    if not clamped.any() or slipped:
        return {"utilisation": None, "slipped": slipped, "clamped_ticks": int(clamped.sum())}
    wheel = 0.5 * (r["dtheta_r_rad_s"] + r["dtheta_l_rad_s"])
    delivered = j_roll * np.diff(wheel) / INNER_S
    cmd = 0.5 * (r["tau_cmd_r"][:-1] + r["tau_cmd_l"][:-1])
    k = np.flatnonzero(clamped)
    return {"utilisation": float(delivered[k].mean() / tau_max),
            "delivered_over_commanded": float(delivered[k].sum() / cmd[k].sum()),
            "clamped_ticks": int(k.size), "t_first_s": float(r["t_s"][k[0]]),
            "t_last_s": float(r["t_s"][k[-1]] + INNER_S), "tau_max_nm": tau_max,
            "mean_cmd_nm": float(cmd[k].mean()), "mean_delivered_nm": float(delivered[k].mean()),
            "slipped": False}


def _utilisation_fil(tau_max: float, r_wheel: float, log=print) -> dict:
    """The same in the firmware in the loop (the real firmware.elf in simavr against the plant,
    its duty ramped by the 1 kHz tick): 72 rad/s^2 straight, clamp on, 1.5 s. The clamped
    interval is where telemetry reports the commanded torque at the clamp's limit on both wheels;
    the delivered torque is the plant's motor torque (plant.csv) over that interval; slip is
    looked for there (the brake at the end of the experiment skids the wheels). Also, from
    plant.csv (0.5 ms rows): the start tick, the experiment's t = 0 (the motors brake at the
    inner tick ``duration`` after it, so it is the time the duty returns to 0 less
    ``duration``), the delay from it to the first nonzero duty, and the true peak tracking
    error over the experiment (the reference from lib/control, its t = 0 at the start tick)."""
    import tempfile
    from pathlib import Path

    from host_tools import fil
    try:
        elf = fil.build_firmware()
        fil.build_sim()
    except fil.FilError as exc:
        log(f"  firmware in the loop not available: {exc}")
        return {"utilisation": None, "error": str(exc)[:300]}
    exp = {"profile": "straight", "wheel_accel": 72.0, "accel_time": ACCEL_TIME_S, "duration": 1.5,
           "radius": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fil72"
        code, lg, _ = fil.record(out, elf, exp, clamp=True)
        tel = np.genfromtxt(out / "telemetry.csv", delimiter=",", names=True)
        pl = np.genfromtxt(out / "plant.csv", delimiter=",", names=True)
    if code != 0:
        return {"utilisation": None, "error": f"logger exit {code}: {lg.end_reason}"}
    start = _fil_start_and_error(pl, exp, r_wheel)
    on = ((np.abs(tel["tau_cmd_r"]) >= tel["tau_max"] - 2e-4) & (np.abs(tel["tau_cmd_l"]) >= tel["tau_max"] - 2e-4)
          & (tel["tau_max"] > 0))
    if not on.any():
        return {"utilisation": None, "error": "no clamped telemetry frame"}
    k0 = int(np.argmax(on))
    k1 = k0 + (int(np.argmin(on[k0:])) if not on[k0:].all() else int(on[k0:].size))
    t0, t1 = float(tel["t_s"][k0]), float(tel["t_s"][k1 - 1])
    m = (pl["t_s"] >= t0) & (pl["t_s"] <= t1)
    delivered = 0.5 * (np.abs(pl["tau_r_nm"][m]) + np.abs(pl["tau_l_nm"][m]))
    return {"utilisation": float(delivered.mean() / tau_max), "t_first_s": t0, "t_last_s": t1,
            "telemetry_frames": int(k1 - k0), "mean_delivered_nm": float(delivered.mean()),
            "tau_max_nm": tau_max, "slipped": bool((pl["slipping_r"][m] > 0).any() or (pl["slipping_l"][m] > 0).any()),
            **start}


def _fil_start_and_error(pl: np.ndarray, exp: dict, r_wheel: float) -> dict:
    """Start tick, delay to the first nonzero duty and true peak error of a FIL straight run
    (see _utilisation_fil)."""
    from host_tools.control import Controller
    on = (pl["duty_r"] != 0) | (pl["duty_l"] != 0)
    if not on.any() or on[-1]:
        return {"start_latency_ms": None, "peak_error_m": None}
    i1 = int(np.argmax(on))
    i2 = int(np.flatnonzero(on)[-1]) + 1  # the brake
    t_start = float(pl["t_s"][i2]) - exp["duration"]
    m = (pl["t_s"] >= t_start) & (pl["t_s"] < pl["t_s"][i2])
    ref = Controller()
    ref.set_reference("line", exp["wheel_accel"] * r_wheel, exp["accel_time"] * exp["wheel_accel"] * r_wheel, 1.0)
    t = pl["t_s"][m] - t_start
    xr = np.array([ref.reference(float(ti))[0] for ti in t])
    yr = np.array([ref.reference(float(ti))[1] for ti in t])
    err = np.hypot(pl["x_m"][m] - xr, pl["y_m"][m] - yr)
    k = int(np.argmax(err))
    return {"start_tick_s": t_start, "start_latency_ms": 1e3 * (float(pl["t_s"][i1]) - t_start),
            "peak_error_m": float(err[k]), "t_peak_error_s": float(t[k])}
