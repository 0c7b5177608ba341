"""The MuJoCo engine against lib/slipmodel (the project's plant) and the truth simulator's
physics, on rolling and slipping nulls. ``python -m host_tools.engines.validate`` prints the
figures that docs/suite.md states and host_tools/tests/engines/test_mujoco_engine.py holds.

Two comparisons per scenario (the firmware's controller, lib/control's reference):

* **open loop** (the plants alone): the duties of the nominal closed loop (lib/slipmodel with
  the firmware's controller, :func:`host_tools.truth.nominal_closed_loop`) applied tick by tick
  to lib/slipmodel's plant (``Plant.simulate``, duty mode) and to the MuJoCo model;
* **closed loop** (plant and recorder): the same controller and reference on lib/slipmodel
  (lib/closedloop), on the truth simulator's physics and on the MuJoCo model (both through
  ``sim/truth``'s recorder).

Two configurations: ``physical`` (the MuJoCo model as the suite uses it: each wheel's mass on
its axle, the load transfer of the centre of mass's height, the motors' reaction on the
chassis) against the nominal lib/slipmodel and the truth simulator; ``matched`` (the MuJoCo
model with the thesis's mass distribution, ``lumped``, and all three engines with
``load_transfer`` at the table's ``h``), where what is left is what the engines do differently
with the same assumptions (soft contacts, the friction switch, the spin-momentum pitch term).

Figures: the end-point distance of the axle centre and the heading difference at the end,
the RMS difference of the wheel speeds over the run (both wheels), the first time a wheel
slips (``-`` for none).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from host_tools import _native, truth
from host_tools.params import ROBOT

R = ROBOT["r"]


@dataclass(frozen=True)
class Scenario:
    name: str
    kind: str
    accel: float
    cruise: float
    radius: float
    clamp: bool
    duration_s: float


#: the nulls: straight runs at 48 and 72 rad/s^2 of wheel acceleration with the clamp off
#: (both slip in lib/slipmodel; 48 is at the traction limit, 72 well past it),
#: a gentle line, an arc and a figure eight (both circles)
SCENARIOS = (
    Scenario("straight_48", "line", 48 * R, 24 * R, 1.0, False, 2.0),
    Scenario("straight_72", "line", 72 * R, 36 * R, 1.0, False, 2.0),
    Scenario("gentle_line", "line", 0.3, 0.15, 1.0, True, 2.5),
    Scenario("arc", "arc", 0.8, 0.5, 0.5, True, 3.0),
    Scenario("figure_eight", "figure_eight", 1.0, 0.5, 0.5, True, 8.0),
)
#: the truth recorder's telemetry period in the comparison (fine, for the slip onset)
TEL_S = 0.002


def _onset(t: np.ndarray, slip: np.ndarray) -> float:
    k = np.flatnonzero(slip)
    return float(t[k[0]]) if k.size else math.nan


def _figures(ref: dict, other: dict) -> dict:
    """End-point distance (mm), heading difference (mrad), wheel-speed RMS difference (rad/s)
    of ``other`` against ``ref``, both as dicts of t_s, x_m, y_m, phi_rad, w_r, w_l, slip."""
    t = ref["t_s"]
    wr = np.interp(t, other["t_s"], other["w_r"])
    wl = np.interp(t, other["t_s"], other["w_l"])
    rms = math.sqrt(float(np.mean(np.concatenate([(wr - ref["w_r"]) ** 2, (wl - ref["w_l"]) ** 2]))))
    end = math.hypot(other["x_m"][-1] - ref["x_m"][-1], other["y_m"][-1] - ref["y_m"][-1])
    return {"end_mm": 1e3 * end, "phi_mrad": 1e3 * abs(other["phi_rad"][-1] - ref["phi_rad"][-1]),
            "w_rms": rms, "onset_s": _onset(other["t_s"], other["slip"])}


CONFIGS = ("physical", "matched")
#: the effect all three engines get in the matched configuration
MATCHED_EFFECTS = {"load_transfer": {"h": ROBOT["h"]}}


def _plant(config: str) -> _native.Plant:
    p = _native.Plant()
    if config == "matched":
        for name, ps in MATCHED_EFFECTS.items():
            p.set_effect(name, **ps)
    return p


def _mujoco(config: str):
    from host_tools.engines.mujoco_robot import MujocoRobot
    if config == "matched":
        return MujocoRobot(MATCHED_EFFECTS, lumped=True)
    return MujocoRobot()


def open_loop(sc: Scenario, config: str = "physical") -> dict[str, dict]:
    """The nominal closed loop's duties replayed on lib/slipmodel's plant and on MuJoCo."""
    cl = truth.nominal_closed_loop(sc.kind, sc.accel, sc.cruise, sc.radius, clamp=sc.clamp,
                                   T_s=sc.duration_s, plant=_plant(config))
    t = cl["t_s"]
    ur = np.nan_to_num(cl["pwm_r"])
    ul = np.nan_to_num(cl["pwm_l"])
    sm = _plant(config).simulate(t, ur, ul, mode="duty")
    out = {"slipmodel": {"t_s": t, "x_m": sm["x_m"], "y_m": sm["y_m"], "phi_rad": sm["phi_rad"],
                         "w_r": sm["dtheta_r_rad_s"], "w_l": sm["dtheta_l_rad_s"],
                         "slip": (sm["slip_r"] != 0) | (sm["slip_l"] != 0)}}
    p = _mujoco(config)
    n = int(round(sc.duration_s / p.dt))
    rows = []
    k = 0
    for i in range(n + 1):
        ti = i * p.dt
        while k + 1 < t.size and t[k + 1] <= ti + 1e-9:
            k += 1
        if abs(ti - t[k]) < 1e-9:
            s = p.state()
            rows.append((ti, s[0], s[1], s[2], s[5], s[6], s[7] + s[8]))
        if i < n:
            p.step(ti, ur[k], ul[k])
    a = np.array(rows)
    # slip seen at every step, not only at the ticks
    out["mujoco"] = dict(zip(("t_s", "x_m", "y_m", "phi_rad", "w_r", "w_l", "slip"), a.T))
    out["mujoco"]["slip"] = a[:, 6] > 0
    return out


def closed_loop(sc: Scenario, config: str = "physical") -> dict[str, dict]:
    """The firmware's controller on lib/slipmodel (lib/closedloop), on the truth simulator's
    physics and on MuJoCo (sim/truth's recorder)."""
    cl = truth.nominal_closed_loop(sc.kind, sc.accel, sc.cruise, sc.radius, clamp=sc.clamp,
                                   T_s=sc.duration_s, plant=_plant(config))
    out = {"slipmodel": {"t_s": cl["t_s"], "x_m": cl["x_m"], "y_m": cl["y_m"],
                         "phi_rad": cl["phi_rad"], "w_r": cl["dtheta_r_rad_s"],
                         "w_l": cl["dtheta_l_rad_s"], "slip": cl["slip_any"]}}
    out["slipmodel"]["slip_t"] = (cl["t_fine"], cl["slip_fine"])
    ref = {"kind": sc.kind, "accel": sc.accel, "cruise": sc.cruise, "radius": sc.radius}
    effects = MATCHED_EFFECTS if config == "matched" else None
    for engine in ("truth", "mujoco"):
        rec = truth.recorder_config(tel_s=TEL_S)
        sim, _, _ = truth.configure(ref, effects, sc.clamp, sc.duration_s, 0, rec,
                                    np.random.default_rng(0), np.random.default_rng(1), engine,
                                    {"lumped": True} if config == "matched" and engine == "mujoco"
                                    else None)
        sim.set("sim.tel_phase", 0.0)
        tel, _ = sim.run()
        out[engine] = {"t_s": tel["t_s"], "x_m": tel["true_x_m"], "y_m": tel["true_y_m"],
                       "phi_rad": tel["true_phi_rad"], "w_r": tel["true_dtheta_r"],
                       "w_l": tel["true_dtheta_l"],
                       "slip": (tel["true_slip_r"] != 0) | (tel["true_slip_l"] != 0)}
    sm = out["slipmodel"]
    t_f, s_f = sm.pop("slip_t")
    sm["onset_fine"] = _onset(t_f, s_f)
    return out


def figures(scenarios=SCENARIOS, configs=CONFIGS) -> list[dict]:
    """One row per scenario, configuration and comparison: each engine against lib/slipmodel."""
    rows = []
    for config in configs:
        for sc in scenarios:
            base = {"config": config, "scenario": sc.name}
            ol = open_loop(sc, config)
            f = _figures(ol["slipmodel"], ol["mujoco"])
            rows.append({**base, "loop": "open", "engine": "mujoco", **f,
                         "onset_ref_s": _onset(ol["slipmodel"]["t_s"], ol["slipmodel"]["slip"])})
            cl = closed_loop(sc, config)
            for engine in ("truth", "mujoco"):
                f = _figures(cl["slipmodel"], cl[engine])
                rows.append({**base, "loop": "closed", "engine": engine, **f,
                             "onset_ref_s": cl["slipmodel"]["onset_fine"]})
    return rows


def _fmt_onset(x: float) -> str:
    return "-" if math.isnan(x) else f"{x:.3f}"


def table(rows: list[dict]) -> str:
    lines = ["| config | scenario | loop | engine | end point (mm) | heading (mrad) | wheel speed RMS (rad/s) "
             "| slip onset (s) | lib/slipmodel's onset (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['config']} | {r['scenario']} | {r['loop']} | {r['engine']} | {r['end_mm']:.1f} | "
                     f"{r['phi_mrad']:.1f} | {r['w_rms']:.3f} | {_fmt_onset(r['onset_s'])} | "
                     f"{_fmt_onset(r['onset_ref_s'])} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """``python -m host_tools.engines.validate``: the validation table (markdown)."""
    import argparse
    ap = argparse.ArgumentParser(prog="python -m host_tools.engines.validate", description=main.__doc__)
    ap.add_argument("--scenario", action="append", choices=[s.name for s in SCENARIOS],
                    help="only these scenarios (default: all)")
    ap.add_argument("--config", action="append", choices=CONFIGS,
                    help="only these configurations (default: both)")
    a = ap.parse_args(argv)
    scs = [s for s in SCENARIOS if not a.scenario or s.name in a.scenario]
    print(table(figures(scs, a.config or CONFIGS)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
