"""Measurement: the truth simulator's wheel breakaways against the analyzer's nominal replay.

For one suite case on the truth engine, every run is simulated again with the case's seed,
recorder and effects (the same physics; the telemetry at every 0.2 ms simulation step, from
five runs with the frame phase shifted by one step, no jitter) and checked against the
recorded hidden truth.  Per run it prints:

* each breakaway of the truth (a wheel stuck before the step and slipping after it): the
  wheel's longitudinal traction from its own balance, F = (tau - I_wy dW/dt) / r, over the
  truth's normal force (mu_s by construction), the truth's N against the normal force the
  nominal model (replay/normal_forces.py: the wheels on the axle, the transfer at
  h + k^ h_s driven by the body's acceleration) gives for the same motion, and F / N_nominal:
  the mu_s the nominal model's normal force needs for the same breakaway;
* N_truth / N_nominal while slipping and while stuck;
* the controller ticks no telemetry frame reported (two ticks between two frames) and where
  the analyzer's replayed duty (``prepare_timed``: reconstructed input times, recorded duty)
  differs from the duty in force in the truth for longer than one step;
* the replay at ``--effects`` in four variants: the analyzer's inputs or the truth's exact
  duty, the nominal model's normal forces or the truth's (``c1``: the wheels on the axle, the
  transfer at h and the whole spin-up through the plant's own theta'' term, k = 1): each
  wheel's slip episodes beside the truth's and the pose error against the hidden truth.

Usage (nice it; a 4-run case takes about 20 s):
  PYTHONPATH=. .venv/bin/python bench/analyzer/truth_breakaway.py --set heldback14 \\
      --case hb14_tr_friction_coefficient --runs RUNS/hb14_tr_friction_coefficient \\
      --labels LABELS/hb14_tr_friction_coefficient \\
      --effects '{"friction_coefficient": {"mu_s": 0.201, "mu_k": 0.191}}' [--run 2]
"""
from __future__ import annotations

import argparse
import glob
import json
import os
from typing import Any

import numpy as np

from host_tools import _native
from host_tools.analyzer.prepare.inputs import prepare_timed
from host_tools.analyzer.replay.normal_forces import NormalForces, plant_config
from host_tools.analyzer.replay.openloop import _zoh
from host_tools.runfmt import load_run
from host_tools.suite import cases as C
from host_tools.truth.engine import configure
from host_tools.truth.recorder import recorder_config

N_PHASE = 5  # telemetry every 1 ms (the key's lower bound), five phases of the 0.2 ms step
#: the truth's normal-force physics in the nominal plant: wheels on the axle, the table's h,
#: the plant's own spin term at k = 1 (bench/analyzer/nominal_normal_forces.py's ``c1``)
TRUTH_LIKE = NormalForces(1.0, None, 0.0)


def fine_truth(case: C.Case, k: int) -> dict[str, np.ndarray]:
    """Experiment ``k`` of ``case`` on the truth simulator, its telemetry (hidden columns
    included) at every simulation step."""
    ref, clamp, dur = case.experiments[k]
    parts = []
    for p in range(N_PHASE):
        rec = recorder_config(case.recorder)
        rng = np.random.default_rng(case.seed + k)
        rng_rec = np.random.default_rng([case.seed + k, 16])
        sim, _, _ = configure(ref, case.effects, clamp, dur, case.seed + k, rec, rng, rng_rec,
                              case.engine, case.engine_options or None)
        dt = sim.get("sim.dt")
        sim.set("sim.tel_period", N_PHASE * dt)
        sim.set("sim.tel_phase", p * dt)
        sim.set("rec.tel_jitter", 0.0)
        tel, _ = sim.run()
        parts.append(tel)
    out = {c: np.concatenate([t[c] for t in parts]) for c in parts[0]}
    order = np.argsort(out["t_s"], kind="stable")
    return {c: v[order] for c, v in out.items()}


def nominal_normal(robot: dict[str, float], ax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nominal model's wheel loads (right, left) on a straight line for a body
    acceleration ``ax`` (the plant's step 2 with plant_config's robot and load_transfer h)."""
    cfg = plant_config(robot, {})
    r = cfg.robot
    m = r["m_r"] + 2 * r["m_w"]
    h_eff = cfg.effects["load_transfer"]["h"]
    nc = (m * r["g"] * r["d"] - m * ax * h_eff) / (r["d"] + r["e"])
    nw = m * r["g"] - np.clip(nc, 0.0, m * r["g"])
    return 0.5 * nw, 0.5 * nw


def episodes(flag: np.ndarray) -> list[tuple[int, int]]:
    """(first index, first index after) of each run of True in ``flag``."""
    f = np.r_[False, np.asarray(flag, bool), False].astype(np.int8)
    d = np.diff(f)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _eps(t: np.ndarray, flag: np.ndarray) -> str:
    return ", ".join(f"{t[a]:.4f}-{t[min(b, t.size - 1)]:.4f}" for a, b in episodes(flag)) or "-"


def replay(robot: dict[str, float], motor: dict[str, float], effects: dict[str, Any], forces: NormalForces, t: np.ndarray,
           u_r: np.ndarray, u_l: np.ndarray, start_pose: Any) -> dict[str, np.ndarray]:
    """The nominal plant with ``effects`` and the normal-force physics ``forces`` driven by the
    duties ``u_r``, ``u_l`` held over [t[n], t[n+1])."""
    cfg = plant_config(robot, effects, forces)
    p = _native.Plant(robot=cfg.robot, motor=motor)
    for key, value in cfg.keys.items():
        p.set(key, value)
    if forces is TRUTH_LIKE:
        p.set("plant.spin_share", 1.0)
    p.clear_effects()
    for name, params in cfg.effects.items():
        p.set_effect(name, **{k: float(v) for k, v in params.items()})
    return p.simulate(t, u_r, u_l, mode="duty", dt_s=5e-4, start_pose=start_pose)


def analyse(case: C.Case, k: int, run_dir: str, hidden: str | None, effects: dict[str, Any]) -> None:
    tr = fine_truth(case, k)
    t = tr["t_s"]
    dt = float(np.median(np.diff(t)))
    if hidden and os.path.exists(hidden):
        h = np.genfromtxt(hidden, delimiter=",", names=True)
        idx = np.searchsorted(t, h["t_s"] - 1e-9)
        err = max(float(np.max(np.abs(tr[c][idx] - h[c]) / (1e-9 + np.max(np.abs(h[c])))))
                  for c in ("true_x_m", "true_dtheta_r", "true_N_r", "true_tau_l_nm"))
        print(f"run-{k}: fine truth against the recorded hidden truth: largest relative "
              f"difference {err:.1e} over {h.size} frames (stale data if not ~1e-9)")
    run = load_run(run_dir)
    robot, motor = dict(run.meta["robot"]), dict(run.meta["motor"])
    r, iw, m = robot["r"], robot["I_wy"], robot["m_r"] + 2 * robot["m_w"]
    # row n: the state at t_n and the torque, normal force and stick flag of the step ending there
    W = {s: tr[f"true_dtheta_{s}"] for s in "rl"}
    F = {s: np.r_[0.0, (tr[f"true_tau_{s}_nm"][1:] - iw * np.diff(W[s]) / dt) / r] for s in "rl"}
    a_body = np.r_[0.0, (F["r"][1:] + F["l"][1:]) / m]
    nn = dict(zip("rl", nominal_normal(robot, np.r_[0.0, a_body[:-1]])))  # previous step's a
    slip = {s: tr[f"true_slip_{s}"] > 0 for s in "rl"}
    print("  breakaways of the truth (the step ending at t):")
    print("   wheel  t [s]   duty   tau[Nm]  W[rad/s]  F/N_truth  N_truth  N_nom   "
          "Ntr/Nnom  F/N_nom")
    for s in "rl":
        for n in np.flatnonzero(~slip[s][:-1] & slip[s][1:]) + 1:
            n_t = tr[f"true_N_{s}"][n]
            print(f"   {s}    {t[n]:.4f}  {tr[f'pwm_{s}'][n]:.3f}  {tr[f'true_tau_{s}_nm'][n]:.4f}  "
                  f"{W[s][n - 1]:7.2f}    {F[s][n] / n_t:.4f}    {n_t:.3f}  {nn[s][n]:.3f}   "
                  f"{n_t / nn[s][n]:.4f}    {F[s][n] / nn[s][n]:.4f}")
    for s in "rl":
        q = tr[f"true_N_{s}"] / nn[s]
        st = ~slip[s] & (t > 0.001)
        sl = slip[s] & (t > 0.001)
        sl_txt = (f"while slipping median {np.median(q[sl]):.4f} max {q[sl].max():.4f}; "
                  if sl.any() else "")
        print(f"  {s}: N_truth/N_nom {sl_txt}while stuck median {np.median(q[st]):.4f} "
              f"max {q[st].max():.4f}; largest stuck F/N_truth {np.max(F[s][st] / tr[f'true_N_{s}'][st]):.4f}")
    # the analyzer's inputs against the truth's duty in force
    prep = prepare_timed(run)
    tf = np.asarray(run.telemetry["t_s"], float)
    period = float(run.meta["periods_s"]["inner"])
    ticks = np.arange(0.0, t[-1] - 1e-9, period)
    unseen = [x for x in ticks[1:] if not np.any((tf >= x - 1e-9) & (tf < x + period - 1e-9))]
    print(f"  inputs: tick phase {prep.tick_phase} (truth 0), largest frame gap "
          f"{np.max(np.diff(tf)) * 1e3:.1f} ms for a {period * 1e3:.0f} ms loop, ticks no frame "
          f"reported: {', '.join(f'{x:.3f}' for x in unseen) or '-'}")
    u_an = {s: _zoh(prep.t_in, prep.duty[i], t) for i, s in enumerate("rl")}
    for s in "rl":
        bad = [(a, b) for a, b in episodes(np.abs(u_an[s] - tr[f"pwm_{s}"]) > 1e-9) if b - a > 2]
        print(f"  {s}: replayed duty off the truth's for more than two steps: " + (", ".join(
            f"{t[a]:.4f}-{t[b - 1] + dt:.4f} ({u_an[s][a]:.4f} for {tr[f'pwm_{s}'][a]:.4f})"
            for a, b in bad) or "-"))
    print(f"  replays at {json.dumps(effects)} (slip episodes per wheel; pose error against the "
          f"hidden truth at the end and its RMS after 0.35 s):")
    for s in "rl":
        print(f"   truth                   {s}: {_eps(t, slip[s])}")
    late = t > 0.35
    for inputs in ("analyzer", "exact"):
        u = u_an if inputs == "analyzer" else {s: tr[f"pwm_{s}"] for s in "rl"}
        for fname, forces in (("nominal", NormalForces()), ("truth-like", TRUTH_LIKE)):
            o = replay(robot, motor, effects, forces, t, u["r"], u["l"], prep.start_pose)
            for s in "rl":
                print(f"   {inputs:8s} {fname:10s}   {s}: {_eps(t, o[f'slip_{s}'] > 0)}")
            errs = []
            for c in ("x_m", "y_m", "phi_rad"):
                e = o[c] - tr[f"true_{c}"]
                errs.append(f"{c} {e[-1]:+.2e} ({np.sqrt(np.mean(e[late] ** 2)):.1e})")
            print("                             " + ", ".join(errs))


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--set", required=True)
    ap.add_argument("--case", required=True)
    ap.add_argument("--runs", required=True, help="the case's run folders (runs/<case>)")
    ap.add_argument("--labels", help="the hidden truth folder (labels/<case>)")
    ap.add_argument("--effects", default="{}", help="the replays' effects (JSON)")
    ap.add_argument("--run", type=int, action="append", help="run index (default all)")
    a = ap.parse_args()
    case = C.get([a.case], which=a.set)[0]
    if case.engine != "truth":
        raise SystemExit("a truth-engine case is needed")
    dirs = sorted(glob.glob(os.path.join(a.runs, "run-*")))
    for k in a.run if a.run is not None else range(len(dirs)):
        hidden = os.path.join(a.labels, f"run-{k}.truth.csv") if a.labels else None
        analyse(case, k, dirs[k], hidden, json.loads(a.effects))


if __name__ == "__main__":
    main()
