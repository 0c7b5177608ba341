"""The truth engine's wheel loads against the nominal model's, for tests whose fitted friction
follows them (the truth's whole spin-up reacts, k = 1, against the nominal k^ h_s)."""
from __future__ import annotations

from pathlib import Path


def slip_load_ratio(hidden: Path) -> float:
    """Over the truth runs' slipping samples (their hidden ``true_*`` columns): the wheels' true
    load against what the nominal model's normal forces give for the same motion
    (replay/normal_forces.py: N_c (d_c + e_c) = m_t g d_c - m_t a_x (h + k^ h_s), a_x the true
    forward acceleration)."""
    import numpy as np

    from host_tools import params
    from host_tools.analyzer.replay.normal_forces import plant_config
    cfg = plant_config(params.ROBOT, {})
    R = cfg.robot
    m, H = R["m_r"] + 2 * R["m_w"], cfg.effects["load_transfer"]["h"]
    true_load = nominal_load = 0.0
    for f in sorted(hidden.glob("*.truth.csv")):
        tab = np.genfromtxt(f, delimiter=",", names=True)
        t, ph = tab["t_s"], tab["true_phi_rad"]
        v = (np.gradient(tab["true_x_m"], t) * np.cos(ph) + np.gradient(tab["true_y_m"], t) * np.sin(ph))
        a_x = np.gradient(v, t)
        n_c = np.clip((m * R["g"] * R["d"] - m * a_x * H) / (R["d"] + R["e"]), 0.0, m * R["g"])
        slip = (tab["true_slip_r"] > 0) | (tab["true_slip_l"] > 0)
        true_load += float(np.sum((tab["true_N_r"] + tab["true_N_l"])[slip]))
        nominal_load += float(np.sum((m * R["g"] - n_c)[slip]))
    return true_load / nominal_load
