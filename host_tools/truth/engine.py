"""One run's simulator set up: the reference, the recorder, the clock phases and the effects on
the chosen engine's physics (the truth simulator's own, or another engine's plant such as the
MuJoCo model driven through ``tr_set_plant``)."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from host_tools.control import REF_KINDS as _REF_KINDS
from host_tools.truth.references import reversal_reference, tour_reference
from host_tools.truth.sim import TruthSim


def configure(reference: Mapping, effects: Mapping | None, clamp: bool, duration_s: float,
              seed: int, rec: Mapping, rng: np.random.Generator, rng_rec: np.random.Generator,
              engine: str = "truth", engine_options: Mapping | None = None
              ) -> tuple[TruthSim, dict, str]:
    """A :class:`TruthSim` set up for one run (reference, recorder ``rec`` of
    :func:`recorder_config`, clock phases drawn from ``rng`` and ``rng_rec``, effects on the
    chosen engine's physics): returns (simulator, reference as written to meta.json, kind).
    :func:`simulate_run` and the engines' validation use it."""
    from host_tools.engines import ENGINES
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    if engine_options and engine != "mujoco":
        raise ValueError("engine options are the mujoco engine's")
    sim = TruthSim()
    reference = dict(reference)
    kind = reference.get("kind", "line")
    if kind in ("tour", "reversals"):
        make = tour_reference if kind == "tour" else reversal_reference
        reference = make(duration_s, seed, **{k: reference[k] for k in ("accel", "alpha")
                                              if k in reference})
        kind = "segments"
    if kind == "segments":
        sim.set("ref.kind", 3)
        sim.set("ref.accel", reference.get("accel", 0.6))
        sim.set("ref.alpha", reference.get("alpha", 2.0))
        sim.set_segments(reference.get("segments") or [])
        reference = {"kind": "segments", "accel": float(reference.get("accel", 0.6)),
                     "alpha": float(reference.get("alpha", 2.0)),
                     "segments": [{"duration_s": float(sg["duration_s"]), "v": float(sg.get("v", 0.0)),
                                   "omega": float(sg.get("omega", 0.0))}
                                  for sg in reference["segments"]]}
    elif kind in _REF_KINDS:
        sim.set("ref.kind", _REF_KINDS[kind])
        sim.set("ref.accel", reference.get("accel", 0.5))
        sim.set("ref.cruise", reference.get("cruise", 0.5))
        sim.set("ref.radius", reference.get("radius", 1.0))
    else:
        raise ValueError(f"reference kind must be one of {list(_REF_KINDS) + ['segments', 'tour']}, "
                         f"got {kind!r}")
    pi = rec["controller"] == "pi"
    sim.set("ctl.clamp", 1.0 if clamp and not pi else 0.0)
    sim.set("sim.duration", duration_s)
    inner = rec["inner_s"]
    sim.set("sim.inner_period", inner)
    sim.set("rec.controller", 1.0 if pi else 0.0)
    sim.set("rec.odometry", {"firmware": 0, "ticks": 1, "frames": 2}[rec["odometry"]])
    sim.set("rec.midpoint", 1.0 if rec["integration"] == "midpoint" else 0.0)
    sim.set("sim.tel_period", rec["tel_s"])
    sim.set("rec.tel_jitter", rec["tel_jitter_s"])
    sim.set("rec.pwm_in_force", 1.0 if rec["pwm"] == "in_force" else 0.0)
    # the delay of the duty in force: the plant's actuation delay, wherever the plant applies it
    sim.set("rec.pwm_delay", float(dict((effects or {}).get("actuation_delay", {})).get("delay_s", 0.0)))
    sim.set("rec.seed", float(rng_rec.integers(0, 2 ** 32)))
    # the board's telemetry phase against its tick, and the camera's own clock
    sim.set("sim.tel_phase", float(rng.choice([0.002, 0.004, 0.006, 0.008, 0.012])) % rec["tel_s"])
    sim.set("sim.cam_period", 1.0 / rec["cam_hz"])
    sim.set("sim.cam_phase", float(rng.uniform(0.0, 1.0 / rec["cam_hz"])))
    if engine == "mujoco":
        from host_tools.engines.mujoco_robot import MujocoRobot  # lazy: needs the mujoco package
        plant = MujocoRobot(effects, **dict(engine_options or {}))
        sim.set("sim.dt", plant.dt)
        sim.set_plant(plant)
    else:
        for name, params in (effects or {}).items():
            sim.set_effect(name, **dict(params))
    return sim, reference, kind
