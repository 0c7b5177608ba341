"""One closed-loop run of the truth simulator written as a ``ddrun/1`` run folder, the true
state apart."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

import numpy as np

from host_tools import runfmt
from host_tools.truth.engine import configure
from host_tools.truth.recorder import (CURRENT_SENSE, NOMINAL_META_MOTOR, NOMINAL_META_ROBOT, PPR,
                                       TELEMETRY_SPEC_COLUMNS, _shield_current, recorder_config,
                                       wrap_heading)
from host_tools.truth.sim import TruthSim


def simulate_run(path: str | os.PathLike, reference: Mapping, effects: Mapping | None = None,
                 clamp: bool = True, duration_s: float = 2.0, seed: int = 0,
                 cam_noise_m: float | None = None, cam_noise_rad: float | None = None,
                 cam_dropout: float | None = None,
                 experiment: str | None = None, hidden_dir: str | os.PathLike | None = None,
                 overwrite: bool = False, recorder: Mapping | None = None,
                 engine: str = "truth", engine_options: Mapping | None = None) -> str:
    """Simulate one closed-loop run with the truth simulator and write it as a ``ddrun/1`` run
    folder at ``path`` (meta.json with the NOMINAL parameters, telemetry.csv with the spec
    columns and the shield's motor current, groundtruth.csv from a noisy camera with dropouts).
    The true state (``true_*`` columns) goes to ``hidden_dir/<run name>.truth.csv`` when
    ``hidden_dir`` is given — never into the run folder.

    ``reference``: ``{"kind": "line"|"arc"|"figure_eight", "accel": m/s², "cruise": m/s,
    "radius": m}`` or ``{"kind": "segments", "accel": m/s², "alpha": rad/s², "segments":
    [{"duration_s", "v", "omega"}, ...]}`` or ``{"kind": "tour"}`` (:func:`tour_reference` for
    ``duration_s`` and ``seed``) or ``{"kind": "reversals"}`` (:func:`reversal_reference`);
    ``effects``: ``{name: {param: value}}`` (vocabulary or
    EXTRA_EFFECTS); ``recorder``: options of :data:`RECORDER_DEFAULTS` (the camera arguments
    override the recorder's camera noise and dropout when given). ``engine``: the physics the
    recorder drives, ``"truth"`` (``sim/truth``'s own) or ``"mujoco"``
    (:class:`host_tools.engines.mujoco_robot.MujocoRobot` with ``effects`` and
    ``engine_options``, e.g. ``{"inductance_h": 0.002}``); the run folder does not say which."""
    rec = recorder_config(recorder, **{k: v for k, v in (("cam_noise_m", cam_noise_m),
                                                         ("cam_noise_rad", cam_noise_rad),
                                                         ("cam_dropout", cam_dropout))
                                       if v is not None})
    rng = np.random.default_rng(seed)
    rng_rec = np.random.default_rng([seed, 16])  # the recorder's variants draw from their own stream
    sim, reference, kind = configure(reference, effects, clamp, duration_s, seed, rec, rng,
                                     rng_rec, engine, engine_options)
    pi = rec["controller"] == "pi"
    inner = rec["inner_s"]
    tel, cam = sim.run()
    # camera: noise and dropouts (independent drops plus one short burst)
    keep = rng.random(cam["t_s"].size) > rec["cam_dropout"]
    if cam["t_s"].size > 20:
        b0 = int(rng.integers(5, cam["t_s"].size - 10))
        keep[b0:b0 + int(rng.integers(2, 6))] = False
    gt = {"t_s": np.round(cam["t_s"][keep], 6),
          "x_m": cam["x_m"][keep] + rng.normal(0, rec["cam_noise_m"], keep.sum()),
          "y_m": cam["y_m"][keep] + rng.normal(0, rec["cam_noise_m"], keep.sum()),
          "phi_rad": cam["phi_rad"][keep] + rng.normal(0, rec["cam_noise_rad"], keep.sum())}
    if rec["heading_gt"] == "wrapped":
        gt["phi_rad"] = wrap_heading(gt["phi_rad"])
    if kind == "segments":
        ref_desc = (f"segments: {len(reference['segments'])} speed ramps, cruises, arcs, stops "
                    f"and turns over {sum(s['duration_s'] for s in reference['segments']):g} s")
    else:
        ref_desc = (f"{kind}, accel {reference.get('accel', 0.5)} m/s^2, cruise "
                    f"{reference.get('cruise', 0.5)} m/s" +
                    (f", radius {reference.get('radius')} m" if kind != "line" else ""))
    ref_meta = ({"kind": kind, **{k: float(v) for k, v in reference.items() if k != "kind"}}
                if kind != "segments" else reference)
    motor = dict(NOMINAL_META_MOTOR)
    meta = {"format": "ddrun/1",
            "experiment": experiment or f"{'PI wheel-speed loop' if pi else 'closed loop'}: {ref_desc}",
            "source": "simulator", "torque_clamp": bool(clamp) and not pi,
            "robot": dict(NOMINAL_META_ROBOT), "motor": motor,
            "encoder_ppr": PPR, "periods_s": {"inner": inner, "outer": 2 * inner,
                          "telemetry": rec["tel_s"]},
            "controller": "pi" if pi else "cascade"}
    if pi:
        # no lib/control reference: the closed loop is not lib/control's and cannot be replayed
        # with it; the PI loop's own reference and gains are written instead
        meta["speed_reference"] = ref_meta
        meta["pi"] = {k: sim.get(f"pi.{k}") for k in ("kp", "ki", "j_ff", "tau_limit")}
    else:
        meta["reference"] = ref_meta
    meta["duration_s"] = duration_s
    if rec["current"]:  # with the nominal stall current (the truth's default)
        meta["current_sense"] = dict(CURRENT_SENSE, stall_a=TruthSim().get("motor.stall_a"))
    telemetry = {c: tel[c] for c in TELEMETRY_SPEC_COLUMNS}
    telemetry["t_s"] = np.round(telemetry["t_s"], 6)
    for c in ("enc_r", "enc_l"):
        telemetry[c] = telemetry[c].astype(np.int64)
    if rec["current"]:
        telemetry["current_r_a"] = _shield_current(tel["true_i_r_a"], rng_rec, rec["adc_noise_lsb"])
        telemetry["current_l_a"] = _shield_current(tel["true_i_l_a"], rng_rec, rec["adc_noise_lsb"])
    if rec["heading_tel"] == "wrapped":
        telemetry["phi_odo_rad"] = wrap_heading(telemetry["phi_odo_rad"])
    if rec["tel_drop"] > 0:  # lost frames: independent drops plus one burst; first and last kept
        n = telemetry["t_s"].size
        keep_t = rng_rec.random(n) > rec["tel_drop"]
        if n > 40:
            b0 = int(rng_rec.integers(10, n - 20))
            keep_t[b0:b0 + int(rng_rec.integers(3, 11))] = False
        keep_t[0] = keep_t[-1] = True
        telemetry = {c: v[keep_t] for c, v in telemetry.items()}
    runfmt.write_run(path, meta, telemetry, gt, overwrite=overwrite)
    if hidden_dir is not None:
        os.makedirs(hidden_dir, exist_ok=True)
        name = Path(path).name
        cols = ["t_s"] + [c for c in tel if c.startswith("true_") or c == "clamped"]
        np.savetxt(os.path.join(hidden_dir, f"{name}.truth.csv"),
                   np.column_stack([tel[c] for c in cols]), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.9g")
    return os.fspath(path)
