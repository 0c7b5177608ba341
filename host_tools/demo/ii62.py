"""II.6.2: the 44/48/72 rad/s² profiles with the clamp off, and the thesis controller's gain
grid."""
from __future__ import annotations

from host_tools.demo.common import (ACCEL_TIME_S, CONTROLLERS, GAIN_GRID_KL, GAIN_GRID_KX,
                                    THESIS_II62_PEAK_NM, THESIS_II62_SLIP)


import numpy as np


def _ii62_run(alpha: float, r_wheel: float, params: dict, actuator: str, T_s: float,
              ) -> tuple[dict, dict]:
    """One II.6.2 profile (wheel acceleration alpha for ACCEL_TIME_S, clamp off): slip, peak
    torque command, mean wheel acceleration over the ramp, distance lost to slip."""
    from host_tools.truth import INNER_S, nominal_closed_loop
    r = nominal_closed_loop("line", alpha * r_wheel, ACCEL_TIME_S * alpha * r_wheel, clamp=False,
                            T_s=T_s, actuator=actuator, params=params)
    slip = bool(r["slip_fine"].any())
    k_ramp = int(round(ACCEL_TIME_S / INNER_S))
    wheel = 0.5 * (r["dtheta_r_rad_s"] + r["dtheta_l_rad_s"])
    row = {"alpha_rad_s2": alpha, "slipped": slip,
           "first_slip_s": float(r["t_fine"][np.argmax(r["slip_fine"])]) if slip else None,
           "peak_tau_nm": float(np.nanmax(np.abs(np.r_[r["tau_cmd_r"], r["tau_cmd_l"]]))),
           "mean_wheel_accel_rad_s2": float((wheel[k_ramp] - wheel[0]) / ACCEL_TIME_S),
           "slip_loss_m": float(np.abs(r["x_odo_m"][:-1] - r["x_m"][:-1]).max()),
           "x_at_end_m": float(r["x_m"][-1]), "T_s": T_s,
           "actuator": "torque source" if actuator == "torque" else "motor"}
    return row, r


def _gain_sensitivity(r_wheel: float, T_s: float) -> dict:
    """II.6.2 with the thesis controller (torque source, clamp off) over a grid of k_x, k_l.
    Criterion for the gains: the slip pattern of the thesis (none at 44, slip at 48 and 72) and
    the smallest largest deviation of the peak torques from the captions."""
    rows = []
    for kx in GAIN_GRID_KX:
        for kl in GAIN_GRID_KL:
            params = {"controller": CONTROLLERS["thesis"], "k_x": kx, "k_l": kl}
            peaks, slips = {}, {}
            for alpha in THESIS_II62_PEAK_NM:
                row, _ = _ii62_run(alpha, r_wheel, params, "torque", T_s)
                peaks[f"{alpha:g}"], slips[f"{alpha:g}"] = row["peak_tau_nm"], row["slipped"]
            dev = max(abs(peaks[f"{a:g}"] - p) for a, p in THESIS_II62_PEAK_NM.items())
            pattern = all(slips[f"{a:g}"] == s for a, s in THESIS_II62_SLIP.items())
            rows.append({"k_x": kx, "k_l": kl, "peak_tau_nm": peaks, "slipped": slips,
                         "max_caption_dev_nm": dev, "slip_pattern_matches": pattern})
    ok = [r for r in rows if r["slip_pattern_matches"]]
    best = min(ok, key=lambda r: r["max_caption_dev_nm"]) if ok else None
    from host_tools.truth import Controller
    c = Controller(params={"controller": CONTROLLERS["thesis"]})
    chosen = {"k_x": c.get("k_x"), "k_l": c.get("k_l"), "k_a": c.get("k_a"), "k_y": c.get("k_y"),
              "k_phi": c.get("k_phi"), "k_il": c.get("k_il"), "k_ia": c.get("k_ia")}
    return {"grid": rows, "best": None if best is None else {"k_x": best["k_x"], "k_l": best["k_l"]},
            "chosen": chosen}
