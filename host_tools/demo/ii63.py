"""II.6.3: 72 rad/s² with the clamp on and off, the traction floor, the error budget and the
parameter change that would give the thesis's 0.16 m."""
from __future__ import annotations

from host_tools.demo.common import _total_mass_kg, ACCEL_TIME_S, CONTROLLERS


import numpy as np


def _ii63_run(r_wheel: float, params: dict, clamp: bool, actuator: str, T_s: float,
              plant=None) -> tuple[dict, dict, np.ndarray]:
    """II.6.3: 72 rad/s^2 for ACCEL_TIME_S, then cruise; the true tracking error."""
    from host_tools.truth import INNER_S, nominal_closed_loop
    alpha = 72.0
    r = nominal_closed_loop("line", alpha * r_wheel, ACCEL_TIME_S * alpha * r_wheel, clamp=clamp,
                            T_s=T_s, actuator=actuator, params=params, plant=plant)
    err = np.hypot(r["x_m"] - r["x_ref"], r["y_m"] - r["y_ref"])
    at = {f"err_at_{ts:g}s_m": float(err[int(round(ts / INNER_S))]) for ts in (3.0, 8.0) if ts <= T_s}
    entry = {"actuator": "motor" if actuator == "duty" else "torque source", "clamp": clamp,
             "slipped": bool(r["slip_fine"].any()),
             "slip_steps": int(np.count_nonzero(r["slip_fine"])),
             "peak_error_m": float(err.max()), "t_peak_error_s": float(r["t_s"][int(np.argmax(err))]),
             **at, "final_err_m": float(err[-1]), "T_s": T_s,
             "rms_err_m": float(np.sqrt(np.mean(err ** 2))),
             "odo_drift_m": float(np.abs(r["x_odo_m"][:-1] - r["x_m"][:-1]).max()),
             "peak_tau_nm": float(np.nanmax(np.abs(r["tau_cmd_r"]))),
             # the first tick whose command is nonzero (0: the start tick commands at once)
             "first_command_s": float(r["t_s"][int(np.argmax(np.abs(r["tau_cmd_r"][:-1]) > 0))]),
             # the clamp's limit at the start (slipmodel's tau_max less the back-EMF margin)
             "clamp_limit_nm": float(r["tau_max_r"][0])}
    return entry, r, err


def _ii63_floor(plant, a_ref: float, t_acc: float, target_m: float) -> dict:
    """The smallest peak tracking error any controller can reach on the profile (from rest,
    a_ref for t_acc, then cruise), from the traction limit of Table II.2 (lib/slipmodel's
    parameters and static normal forces): the body is pushed only through the two wheel
    contacts, so m_t a <= mu_s (N_r + N_l). Accelerating at a_max from the start keeps x(t) <=
    a_max t^2 / 2 for any controller, and the error grows until the robot reaches the cruise
    speed at t1 = a_ref t_acc / a_max; at t1 it is (a_ref t_acc^2 / 2)(a_ref / a_max - 1).
    Also: what a_max (and so mu_s, or the weight share on the wheels) makes that floor target_m."""
    m_t = _total_mass_kg(plant)
    mu_s, g = plant.get("robot.mu_s"), plant.get("robot.g")
    n_r, n_l, _ = plant.normal_forces()
    a_max = mu_s * (n_r + n_l) / m_t
    half = 0.5 * a_ref * t_acc ** 2
    floor = half * max(a_ref / a_max - 1.0, 0.0)
    a_target = a_ref / (1.0 + target_m / half)  # floor(a_target) = target_m
    return {"a_max_m_s2": a_max, "a_ref_m_s2": a_ref, "t_acc_s": t_acc, "floor_m": floor,
            "wheel_weight_share": (n_r + n_l) / (m_t * g), "target_m": target_m,
            "a_for_target_m_s2": a_target,
            "alpha_for_target_rad_s2": a_target / plant.get("robot.r"),
            "mu_s_for_target": mu_s * a_target / a_max,
            "wheel_weight_share_for_target": a_target / (mu_s * g)}


def _ii63_budget(floor: dict, runs: dict, tau_max: float, util: dict) -> dict:
    """Where the improved controller's clamped II.6.3 peak error (motor) goes, above the floor.
    Rolling, a wheel's torque and the body's acceleration are proportional, so the floor
    formula with a_max scaled by the share s of tau_max the wheels get, (a_ref T^2/2)(a_ref /
    (s a_max) - 1), gives the peak of a robot that gets that share from t = 0: s = the clamp's
    limit (tau_max less the back-EMF margin), then s = the measured utilisation. The ideal
    torque source delivers the clamp's limit exactly, the motor adds its torque-speed line (the
    profile ends at 98 % of no-load speed); a robot that starts late by dt ends dt later at the
    cruise speed v_c, v_c dt further behind."""
    half = 0.5 * floor["a_ref_m_s2"] * floor["t_acc_s"] ** 2
    a_max, a_ref = floor["a_max_m_s2"], floor["a_ref_m_s2"]
    on, ts = runs["clamp_on"], runs["clamp_on_torque_source"]
    share_limit = on["clamp_limit_nm"] / tau_max
    u = util["improved"]["utilisation"]
    return {"floor_m": floor["floor_m"],
            "clamp_limit_share": share_limit,
            "floor_at_clamp_limit_m": half * (a_ref / (share_limit * a_max) - 1.0),
            "utilisation": u,
            "floor_at_utilisation_m": half * (a_ref / (u * a_max) - 1.0) if u else None,
            "torque_source_m": ts["peak_error_m"], "motor_m": on["peak_error_m"],
            "first_command_s": on["first_command_s"],
            "cost_per_25ms_start_delay_m": a_ref * floor["t_acc_s"] * 0.025}


def _ii63_parameter_change(floor: dict, r_wheel: float) -> dict:
    """II.6.3 run with mu_s raised to the value whose floor is the thesis's 0.16 m (mu_k scaled
    with it), in the plant and in the controller's tau_max; and with mu_k lowered to 0.18 (mu_s
    as Table II.2), which changes only the clamp-off error. 8 s (the peaks come before)."""
    from host_tools import _native
    base = _native.Plant()
    mu_s0, mu_k0 = base.get("robot.mu_s"), base.get("robot.mu_k")
    out = {}
    cases = {"mu_s_for_target": {"mu_s": floor["mu_s_for_target"],
                                 "mu_k": floor["mu_s_for_target"] * mu_k0 / mu_s0},
             "mu_k_0.18": {"mu_s": mu_s0, "mu_k": 0.18}}
    for case, mu in cases.items():
        out[case] = {"mu_s": mu["mu_s"], "mu_k": mu["mu_k"]}
        for cname, cid in CONTROLLERS.items():
            for actuator in ("torque", "duty"):
                for clamp in (True, False):
                    if case == "mu_s_for_target" and not clamp:
                        continue
                    plant = _native.Plant()
                    plant.set("robot.mu_s", mu["mu_s"])
                    plant.set("robot.mu_k", mu["mu_k"])
                    entry, _, _ = _ii63_run(r_wheel, {"controller": cid, **mu}, clamp, actuator, 8.0,
                                            plant=plant)
                    name = ("clamp_on" if clamp else "clamp_off") + ("" if actuator == "duty" else "_torque_source")
                    out[case].setdefault(cname, {})[name] = entry
    return out


def _mu_s_for_peak(r_wheel: float, target_m: float, controller: str, lo: float, hi: float,
                   iters: int = 12) -> dict:
    """The mu_s (mu_k scaled with it) at which the given controller's clamped II.6.3 run with an
    ideal torque source peaks at target_m (bisection; the peak falls as mu_s rises)."""
    from host_tools import _native
    base = _native.Plant()
    ratio = base.get("robot.mu_k") / base.get("robot.mu_s")

    def peak(mu_s: float) -> float:
        plant = _native.Plant()
        plant.set("robot.mu_s", mu_s)
        plant.set("robot.mu_k", mu_s * ratio)
        params = {"controller": CONTROLLERS[controller], "mu_s": mu_s, "mu_k": mu_s * ratio}
        entry, _, _ = _ii63_run(r_wheel, params, True, "torque", 4.0, plant=plant)
        return entry["peak_error_m"]

    p_lo, p_hi = peak(lo), peak(hi)
    if not p_hi <= target_m <= p_lo:
        return {"controller": controller, "mu_s": None, "peak_lo_m": p_lo, "peak_hi_m": p_hi,
                "range": [lo, hi]}
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if peak(mid) > target_m:
            lo = mid
        else:
            hi = mid
    return {"controller": controller, "mu_s": hi, "mu_k": hi * ratio, "peak_error_m": peak(hi),
            "T_s": 4.0}
