"""Synthetic runs for developing and testing the analyzer.

The "truth" here is the nominal plant itself (lib/slipmodel via host_tools._native, with the
nominal model's normal forces, replay/normal_forces.py) with an effect switched on.  That is NOT a proof of the analyzer -- the fitting model and the data
come from the same code.  The real proof is the independent truth simulator's suite (host_tools.suite).

Each run: duty commands set by a 25 ms inner loop, 50 Hz telemetry with quantized encoders,
board wheel speed and odometry from the counts at the inner-loop ticks (each frame reports
the latest tick's, like the firmware), and a 30 Hz camera
ground truth with noise and dropouts."""
from __future__ import annotations

import os
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from host_tools import runfmt

PROFILES: dict[str, Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]] = {
    # straight: ramp to a high duty, hold (speed-dependent effects)
    "ramp": lambda t: (np.clip(t / 0.5, 0, 1) * 0.8, np.clip(t / 0.5, 0, 1) * 0.8),
    # a turn at moderate duty
    "turn": lambda t: (np.clip(t / 0.3, 0, 1) * 0.6, np.clip(t / 0.3, 0, 1) * 0.3),
    # small duties first (deadband, Coulomb friction), then a step up
    "slow": lambda t: (np.where(t < 0.8, np.clip(t / 0.6, 0, 1) * 0.15, 0.45),
                       np.where(t < 0.8, np.clip(t / 0.6, 0, 1) * 0.15, 0.45)),
    # accelerate, then brake to zero duty (deceleration, coasting)
    "brake": lambda t: (np.where(t < 0.8, 0.6, 0.0) * np.clip(t / 0.2, 0, 1),
                        np.where(t < 0.8, 0.6, 0.0) * np.clip(t / 0.2, 0, 1)),
}


def _odometry(counts_r: np.ndarray, counts_l: np.ndarray, t: np.ndarray, r: float, b: float,
              ppr: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from host_tools.analyzer.prepare.odometry import encoder_odometry as odo
    return odo(counts_r, counts_l, t, r, b, ppr, (0.0, 0.0, 0.0))


def nominal_plant(meta: Mapping[str, Any],
                  effects: Mapping[str, Mapping[str, float]] | None = None) -> Any:
    """lib/slipmodel's plant of the nominal model for a run's meta.json (its robot and motor),
    with its normal forces (replay/normal_forces.py ``plant_config``) and ``effects``: the
    synthetic runs' "truth" by default, and the base of a test's own variant of it."""
    from host_tools import _native
    from host_tools.analyzer.replay.normal_forces import plant_config
    cfg = plant_config(meta["robot"], effects or {})
    plant = _native.Plant(robot=cfg.robot, motor=meta["motor"])
    for key, value in cfg.keys.items():
        plant.set(key, value)
    for name, params in cfg.effects.items():
        plant.set_effect(name, **params)
    return plant


def make_run(path: str | os.PathLike[str], profile: str, effects: Mapping[str, Mapping[str, float]]
             | None = None, duration_s: float = 1.5, seed: int = 0, meta: Mapping[str, Any] | None = None,
             gt_noise_m: float = 1e-3, gt_noise_rad: float = 0.01, gt_rate_hz: float = 30.0,
             dropout: float = 0.05, plant_factory: Callable[..., Any] | None = None,
             tick_phase: float | None = None) -> str:
    rng = np.random.default_rng(seed)
    full = runfmt.validate_meta(dict(meta or {}, experiment=f"synthetic {profile}",
                                     source="synthetic (nominal plant + effects)"))
    per = full["periods_s"]
    t_tel = np.round(np.arange(0.0, duration_s + 1e-9, per["telemetry"]), 9)
    # the inner loop's ticks have their own phase against the telemetry frames
    phase = float(rng.uniform(0.0, per["inner"])) if tick_phase is None else float(tick_phase)
    ticks = np.round(phase + np.arange(0.0, duration_s + 1e-9, per["inner"]), 9)
    t_gt = np.round(np.arange(0.5 / gt_rate_hz, duration_s, 1.0 / gt_rate_hz), 9)
    keep = rng.random(t_gt.size) > dropout
    t_gt = t_gt[keep]
    grid = np.unique(np.concatenate([t_tel, ticks, t_gt]))
    u_r_t, u_l_t = PROFILES[profile](ticks)
    idx = np.searchsorted(ticks, grid, side="right") - 1
    u_r = np.where(idx >= 0, u_r_t[np.maximum(idx, 0)], 0.0)
    u_l = np.where(idx >= 0, u_l_t[np.maximum(idx, 0)], 0.0)
    if plant_factory is None:  # the nominal model's plant with the effects
        factory = nominal_plant
        truth = nominal_plant(full, effects or {})
    else:
        factory = plant_factory
        truth = factory(full)
        for name, params in (effects or {}).items():
            truth.set_effect(name, **params)
    out = truth.simulate(grid, u_r, u_l, mode="duty", start_pose=(0.0, 0.0, 0.0))
    nominal = factory(full)
    nom = nominal.simulate(grid, u_r, u_l, mode="duty")
    # the torque command is set with the duty, at the inner-loop ticks
    at_tick = np.searchsorted(grid, ticks)
    tick_of = np.searchsorted(ticks, grid, side="right") - 1
    tau_r = np.where(tick_of >= 0, nom["tau_r_nm"][at_tick][np.maximum(tick_of, 0)], 0.0)
    tau_l = np.where(tick_of >= 0, nom["tau_l_nm"][at_tick][np.maximum(tick_of, 0)], 0.0)
    at_tel = np.searchsorted(grid, t_tel)
    at_gt = np.searchsorted(grid, t_gt)
    ppr = full["encoder_ppr"]
    k = 2 * np.pi / ppr
    enc_r = np.floor(out["theta_r_rad"][at_tel] / k)
    enc_l = np.floor(out["theta_l_rad"][at_tel] / k)
    # the firmware's odometry runs at the inner-loop ticks on that tick's counts (wheel speed =
    # count difference over the inner period, III.1, and the pose); a frame reports the values
    # of the latest tick at or before it
    tq_r = np.floor(out["theta_r_rad"][at_tick] / k)
    tq_l = np.floor(out["theta_l_rad"][at_tick] / k)
    xt, yt, pt = _odometry(tq_r, tq_l, ticks, full["robot"]["r"], full["robot"]["b"], ppr)
    wt_r = np.diff(tq_r, prepend=tq_r[0]) * k / per["inner"]
    wt_l = np.diff(tq_l, prepend=tq_l[0]) * k / per["inner"]
    last = np.searchsorted(ticks, t_tel + 1e-9, side="right") - 1
    om_r = np.where(last >= 0, wt_r[np.maximum(last, 0)], 0.0)
    om_l = np.where(last >= 0, wt_l[np.maximum(last, 0)], 0.0)
    x = np.where(last >= 0, xt[np.maximum(last, 0)], 0.0)
    y = np.where(last >= 0, yt[np.maximum(last, 0)], 0.0)
    phi = np.where(last >= 0, pt[np.maximum(last, 0)], 0.0)
    tel = {"t_s": t_tel, "enc_r": enc_r.astype(int), "enc_l": enc_l.astype(int),
           "omega_r": om_r, "omega_l": om_l,
           # the torque the firmware's datasheet model attributes to the applied duty
           "tau_cmd_r": tau_r[at_tel], "tau_cmd_l": tau_l[at_tel],
           "pwm_r": u_r[at_tel], "pwm_l": u_l[at_tel],
           "x_odo_m": x, "y_odo_m": y, "phi_odo_rad": phi}
    gt = {"t_s": t_gt,
          "x_m": out["x_m"][at_gt] + rng.normal(0, gt_noise_m, t_gt.size),
          "y_m": out["y_m"][at_gt] + rng.normal(0, gt_noise_m, t_gt.size),
          "phi_rad": out["phi_rad"][at_gt] + rng.normal(0, gt_noise_rad, t_gt.size)}
    runfmt.write_run(path, full, tel, gt, overwrite=True)
    return os.fspath(path)


def make_case(root: str | os.PathLike[str], effects: Mapping[str, Mapping[str, float]] | None,
              profiles: Sequence[str] = ("ramp", "turn", "slow", "brake"), seed: int = 0,
              **kw: Any) -> list[str]:
    """One case: a run per profile, all with the same hidden effects."""
    paths = []
    for i, prof in enumerate(profiles):
        p = os.path.join(os.fspath(root), f"run-{i + 1:02d}-{prof}")
        paths.append(make_run(p, prof, effects, seed=seed * 100 + i, **kw))
    return paths
