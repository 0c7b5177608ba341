"""Measurement: where a wheel breaks away on the MuJoCo engine against the analyzer's nominal
model (lib/slipmodel through the nominal replay plant) at the same, true, friction coefficients.

Sub-commands (nice them; one process each; seconds each, ``profile`` about ten):

  log CASE K --set SET --out FILE.npz [--check RUN_DIR] [--switch stock|force]
      re-simulate run K of a suite case (its effects, recorder, seed) with every MuJoCo step
      logged: motor torques, each wheel's contact force in the robot's frame (normal,
      longitudinal, lateral), slip speed, the engine's slip state and the coefficient in force,
      the caster's normal force, the chassis' pitch.  ``--check``: the re-simulated telemetry
      must equal the stored run's (duty and frame times).  ``--switch force``: the
      counterfactual engine below.

  events FILE.npz [RUN_DIR]
      per breakaway of the MuJoCo log (slip state off -> on): |F|/N at the switch, the time the
      contact spent on its cone (|F| >= 0.995 mu_s N) before it; with RUN_DIR the analyzer's
      nominal duty replay at the true mu_s, mu_k beside it.

  cone FILE.npz [RUN_DIR] [--fine S]
      every stretch of the MuJoCo log on the cone while mu_s is in force (span, largest slip
      speed, whether it ended in the switch to mu_k); with RUN_DIR the nominal model's
      stretches of stick demand above mu_s N (its replay with the wheels never released), their
      peak F/(mu_s N) and excess impulse, and MuJoCo's N against the nominal model's there.

  compare FILE.npz RUN_DIR [--mu MU_S,MU_K ...]
      slip state of the MuJoCo log against the nominal replay's at the true and other mu.

  generate CASE --set SET --out DIR [--switch force|stock]
      the case's runs and labels as ``suite generate`` writes them, on MuJoCo with its friction
      switch as it is (slip speed above SLIP_ON_M_S) or force-based (to mu_k as soon as the
      contact force reaches mu_s N, the nominal model's and the truth simulator's breakaway).

  profile CASE_DIR --mu-k MU_K --grid MU_S,... [--v-s V,...]
      the analyzer's fit cost over mu_s at fixed mu_k, with lib/slipmodel's stick/slip law or
      with the drop to mu_k spread over slip speed by the plant's Stribeck law tied to mu_s.

  gain CASE_DIR --effect EFFECT:KEY=VALUE,... [--after S]
      where an effect improves the fit residual: the drop of the squared normalized residual
      from the nominal replay per fit channel, summed over samples in (or --after s past) a
      slip of the nominal replay, a saturated duty, a reversal of the wheels' mean speed, and
      the rest.

  grid RUN_DIR ... [--mu-s MU_S --mu-k MU_K]
      runs whose replay grid has steps under 1 ns, and what merging those rows changes.

  ramp --mu-s MU_S --mu-k MU_K --rate NM_PER_S [--lumped]
      a slow, symmetric joint-torque ramp from rest on MuJoCo and on the nominal plant (torque
      mode): torque, traction and normal force at each one's breakaway, the ratio of the
      breakaway torques (the mu_s the nominal model would need to break away at MuJoCo's torque).

Example:

  nice .venv/bin/python bench/analyzer/mujoco_breakaway.py log hb13_mj_friction_coefficient 2 \
      --set heldback13 --out /tmp/mb/hb13_fc_2.npz \
      --check /work/wt/score-data/heldback13/runs/hb13_mj_friction_coefficient/run-2
  nice .venv/bin/python bench/analyzer/mujoco_breakaway.py cone /tmp/mb/hb13_fc_2.npz \
      /work/wt/score-data/heldback13/runs/hb13_mj_friction_coefficient/run-2 --fine 0.0005
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

FIELDS = ("t", "tau_r", "tau_l", "N_r", "N_l", "N_c", "F_r", "F_l", "L_r", "L_l", "s_r", "s_l",
          "slide_r", "slide_l", "mu_r", "mu_l", "pitch", "v")


def _contact_forces(rob: Any) -> list[float]:
    """(N_r, N_l, N_c, F_r, F_l, L_r, L_l): each wheel's ground force in the robot's frame
    (normal, longitudinal along the heading, lateral) and the caster's normal force."""
    mj, m, dd = rob._mj, rob.model, rob.data
    w, x, y, z = dd.qpos[3:7]
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    hx, hy = math.cos(yaw), math.sin(yaw)
    f = np.zeros(6)
    acc = {rob._gid[0]: np.zeros(3), rob._gid[1]: np.zeros(3), rob._gcaster: np.zeros(3)}
    for k in range(dd.ncon):
        c = dd.contact[k]
        gid = c.geom1 if c.geom1 in acc else c.geom2 if c.geom2 in acc else None
        if gid is None:
            continue
        mj.mj_contactForce(m, dd, k, f)
        fw = np.asarray(c.frame).reshape(3, 3).T @ f[:3]  # world frame, on geom2 from geom1
        if gid == c.geom1:
            fw = -fw
        acc[gid] += fw
    out = [acc[rob._gid[0]][2], acc[rob._gid[1]][2], acc[rob._gcaster][2]]
    for gid in rob._gid:
        out.append(acc[gid][0] * hx + acc[gid][1] * hy)
    for gid in rob._gid:
        out.append(-acc[gid][0] * hy + acc[gid][1] * hx)
    return [float(v) for v in out]


def _pitch(rob: Any) -> float:
    w, x, y, z = rob.data.qpos[3:7]
    return float(math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))))


def _record(rob: Any, rows: list[list[float]]) -> None:
    n_r, n_l, n_c, f_r, f_l, l_r, l_l = _contact_forces(rob)
    w, x, y, z = rob.data.qpos[3:7]
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    v = float(rob.data.qvel[0] * math.cos(yaw) + rob.data.qvel[1] * math.sin(yaw))
    rows.append([float(rob.data.time), rob.tau[0], rob.tau[1], n_r, n_l, n_c, f_r, f_l, l_r,
                 l_l, rob.slip_speed[0], rob.slip_speed[1], float(rob.sliding[0]),
                 float(rob.sliding[1]), rob._mu_set[0] or 0.0, rob._mu_set[1] or 0.0,
                 _pitch(rob), v])


def log_case_run(set_name: str, case_name: str, k: int, out: Path, switch: str = "stock"
                 ) -> dict[str, Any]:
    """Re-simulate run ``k`` of the case with every MuJoCo step logged (see the module doc),
    with the engine's friction switch ``stock`` or ``force`` (:func:`_force_switch`)."""
    from host_tools import runfmt
    from host_tools.truth.run import simulate_run
    from host_tools.engines import mujoco_robot
    from host_tools.suite import cases
    case = cases.get([case_name], which=set_name)[0]
    if case.engine != "mujoco":
        raise SystemExit(f"{case_name} is not a MuJoCo case")
    ref, clamp, dur = case.experiments[k]
    rows: list[list[float]] = []
    orig = mujoco_robot.MujocoRobot.step

    def step(self: Any, t: float, u_r: float, u_l: float) -> None:
        if switch == "force":
            _force_switch(self, orig, t, u_r, u_l)
        else:
            orig(self, t, u_r, u_l)
        _record(self, rows)

    mujoco_robot.MujocoRobot.step = step  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, f"run-{k}")
            simulate_run(path, ref, case.effects, clamp=clamp, duration_s=dur,
                               seed=case.seed + k, recorder=case.recorder, engine=case.engine,
                               engine_options=case.engine_options or None)
            tel = runfmt.load_run(path).telemetry
    finally:
        mujoco_robot.MujocoRobot.step = orig  # type: ignore[method-assign]
    arr = np.asarray(rows, float)
    fc = case.effects.get("friction_coefficient", {})
    meta = {"case": case_name, "run": k, "set": set_name, "effects": case.effects,
            "mu_s": fc.get("mu_s"), "mu_k": fc.get("mu_k"), "reference": ref, "clamp": clamp}
    cols: dict[str, Any] = {f: arr[:, i] for i, f in enumerate(FIELDS)}
    cols.update(meta=json.dumps(meta), tel_pwm_r=np.asarray(tel["pwm_r"], float),
                tel_t=np.asarray(tel["t_s"], float))
    np.savez_compressed(out, **cols)
    return meta


def _force_switch(rob: Any, stock_step: Any, t: float, u_r: float, u_l: float) -> None:
    """One step of the counterfactual engine of ``generate --switch force``: MuJoCo's step with
    a force-based friction switch.  A sticking contact goes to mu_k as soon as its force reaches
    the cone (|F| >= 0.999 mu_s N: the nominal model's and the truth simulator's breakaway), and
    back to mu_s once its force is inside the mu_k cone (|F| < 0.995 mu_k N) with the slip speed
    under SLIP_OFF_M_S."""
    from host_tools.engines import mujoco_robot as mr
    before = list(rob.sliding)
    on, off = mr.SLIP_ON_M_S, mr.SLIP_OFF_M_S
    mr.SLIP_ON_M_S = mr.SLIP_OFF_M_S = math.inf  # the stock update then never switches
    try:
        stock_step(rob, t, u_r, u_l)
    finally:
        mr.SLIP_ON_M_S, mr.SLIP_OFF_M_S = on, off
    n_r, n_l, _n_c, f_r, f_l, l_r, l_l = _contact_forces(rob)
    for i, (n, f, lat) in enumerate(((n_r, f_r, l_r), (n_l, f_l, l_l))):
        ratio = math.hypot(f, lat) / n if n > 1e-9 else 0.0
        if not before[i]:
            rob.sliding[i] = ratio >= 0.999 * rob.mu_s
        else:
            rob.sliding[i] = not (ratio < 0.995 * rob.mu_k and rob.slip_speed[i] < off)


def generate_variant(set_name: str, case_name: str, out: Path, switch: str) -> list[str]:
    """The case's runs and labels (as ``suite generate``) under ``out``, on the MuJoCo engine
    with its friction switch ``stock`` (the slip-speed thresholds) or ``force``
    (:func:`_force_switch`)."""
    from host_tools.engines import mujoco_robot as mr
    from host_tools.suite import cases, generate
    case = cases.get([case_name], which=set_name)[0]
    stock = mr.MujocoRobot.step
    if switch == "force":
        def step(self: Any, t: float, u_r: float, u_l: float) -> None:
            _force_switch(self, stock, t, u_r, u_l)
        mr.MujocoRobot.step = step  # type: ignore[method-assign]
    try:
        return generate.generate_case(case, str(out), overwrite=True)
    finally:
        mr.MujocoRobot.step = stock  # type: ignore[method-assign]


def _load(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    z = np.load(path)
    return json.loads(str(z["meta"])), {f: z[f] for f in z.files if f != "meta"}


def mujoco_events(d: dict[str, np.ndarray], mu_s: float, pre_s: float = 0.05
                  ) -> list[dict[str, Any]]:
    """Each breakaway (slip state off -> on) of each wheel in a MuJoCo log."""
    t = d["t"]
    ev = []
    for side in ("r", "l"):
        sl, F, N, L, s = d[f"slide_{side}"], d[f"F_{side}"], d[f"N_{side}"], d[f"L_{side}"], d[f"s_{side}"]
        ratio = np.hypot(F, L) / np.maximum(N, 1e-9)
        on = np.flatnonzero((sl[1:] > 0.5) & (sl[:-1] < 0.5)) + 1
        if sl[0] > 0.5:
            on = np.r_[0, on]
        for i in on:
            j0 = max(int(np.searchsorted(t, t[i] - pre_s)), 0)
            seg = ratio[j0:i + 1]
            # the contact's time on the cone before the switch
            k = i - 1
            while k >= 0 and ratio[k] >= 0.995 * mu_s and sl[k] < 0.5:
                k -= 1
            t_cone = t[i] - t[min(k + 1, i)]
            ev.append({"wheel": side, "t": float(t[i]), "ratio_at_switch": float(ratio[i - 1] if i else ratio[0]),
                       "ratio_max_pre": float(seg.max()), "N": float(N[i - 1] if i else N[0]),
                       "N_c": float(d["N_c"][i - 1] if i else d["N_c"][0]),
                       "F": float(F[i - 1] if i else F[0]), "tau": float(d[f"tau_{side}"][i]),
                       "t_on_cone_s": float(t_cone), "s_cone_entry": float(s[min(k + 1, i)]),
                       "pitch_mrad": float(1e3 * d["pitch"][i])})
    return sorted(ev, key=lambda e: e["t"])


def prepared(run_dir: str) -> Any:
    """The run as the analyzer replays it: prepared, and its inputs refined by the closed-loop
    replay (``pipeline.analyze``'s first two stages)."""
    from host_tools import runfmt
    from host_tools.analyzer.prepare.inputs import prepare_runs
    from host_tools.analyzer.replay.nominal import replay_closed_loop
    preps = prepare_runs([runfmt.load_run(run_dir)], lambda _m: None)
    preps, _cl = replay_closed_loop(preps, 5e-4, [], lambda _m: None)
    return preps[0]


def nominal_replay(run_dir: str, mu_s: float, mu_k: float, fine_s: float = 1e-3
                   ) -> dict[str, np.ndarray]:
    """The analyzer's nominal open-loop duty replay of the run at mu_s, mu_k, on the run's
    replay grid refined to ``fine_s`` (inputs held as the analyzer holds them)."""
    from host_tools.analyzer.replay.openloop import OpenLoopReplay, _zoh
    prep = prepared(run_dir)
    rp = OpenLoopReplay("duty")
    plant, src, t_in = rp._ready(prep, {"friction_coefficient": {"mu_s": mu_s, "mu_k": mu_k}})
    g = prep.t_grid
    grid = g
    if fine_s > 0:  # refined, without points within 1 us of the run's own grid
        extra = np.arange(g[0], g[-1], fine_s)
        near = np.abs(extra[:, None] - g[None, :]).min(axis=1) < 1e-6
        grid = np.unique(np.r_[g, extra[~near]])
    out = plant.simulate(grid, _zoh(t_in, src[0], grid), _zoh(t_in, src[1], grid), mode="duty",
                         dt_s=rp.dt_s, start_pose=prep.start_pose)
    out = {k: np.asarray(v, float) for k, v in out.items()}
    out["t_s"] = grid
    return out


def nominal_onsets(o: dict[str, np.ndarray]) -> list[tuple[str, float]]:
    ev = []
    for side in ("r", "l"):
        s = o[f"slip_{side}"] > 0.5
        on = np.flatnonzero(s[1:] & ~s[:-1]) + 1
        if s[0]:
            on = np.r_[0, on]
        ev += [(side, float(o["t_s"][i])) for i in on]
    return sorted(ev, key=lambda e: e[1])


def _head(path: Path, extra: str = "") -> tuple[dict[str, Any], dict[str, np.ndarray], float, float]:
    """A log, its true mu_s and mu_k, and a header line printed."""
    meta, d = _load(path)
    mu_s, mu_k = float(meta["mu_s"]), float(meta["mu_k"])
    print(f"# {meta['case']} run-{meta['run']}: mu_s {mu_s}, mu_k {mu_k}, {meta['reference']}, "
          f"clamp {meta['clamp']}{extra}")
    return meta, d, mu_s, mu_k


def cmd_events(a: argparse.Namespace) -> int:
    _meta, d, mu_s, mu_k = _head(a.file)
    ev = mujoco_events(d, mu_s)
    nom = nominal_replay(str(a.run_dir), mu_s, mu_k) if a.run_dir else None
    hdr = ("wheel  t_mj[s] |F|/N@sw  max50ms  on-cone[ms] s_entry[mm/s]  N_mj    N_c_mj  "
           "pitch[mrad]")
    if nom is not None:
        hdr += "  N_nom   F_nom/N_nom  t_nom_first_slip[s]"
    print(hdr)
    for e in ev:
        line = (f"{e['wheel']:5s}  {e['t']:.4f}  {e['ratio_at_switch']:.4f}  {e['ratio_max_pre']:.4f}"
                f"  {1e3 * e['t_on_cone_s']:8.1f}  {1e3 * e['s_cone_entry']:10.2f}  {e['N']:.3f}"
                f"  {e['N_c']:.3f}  {e['pitch_mrad']:8.2f}")
        if nom is not None:
            i = int(np.clip(np.searchsorted(nom["t_s"], e["t"]) - 1, 0, nom["t_s"].size - 1))
            sd = e["wheel"]
            n_nom = nom[f"N_{sd}"][i]
            f_nom = math.hypot(nom[f"F_{sd}_n"][i], nom[f"L_{sd}_n"][i])
            s = nom[f"slip_{sd}"] > 0.5
            j = np.flatnonzero(s & (nom["t_s"] >= e["t"] - 0.3))
            t_first = float(nom["t_s"][j[0]]) if j.size else float("nan")
            line += f"  {n_nom:.3f}  {f_nom / max(n_nom, 1e-9):.4f}  {t_first:.4f}"
        print(line)
    if nom is not None:
        print("# nominal replay's slip onsets (wheel, t):",
              ", ".join(f"{w}@{t:.4f}" for w, t in nominal_onsets(nom)))
        # slipping time of each wheel in both
        for sd in ("r", "l"):
            tm = d["t"]
            mj_frac = float(np.mean(d[f"slide_{sd}"] > 0.5))
            nom_frac = float(np.mean(np.interp(tm, nom["t_s"], nom[f"slip_{sd}"]) > 0.5))
            print(f"# wheel {sd}: fraction of the run slipping: MuJoCo {mj_frac:.3f}, "
                  f"nominal {nom_frac:.3f}")
    return 0


def cone_episodes(d: dict[str, np.ndarray], mu_s: float) -> list[dict[str, Any]]:
    """Each stretch of a MuJoCo log on which a wheel's contact is on its cone (|F| >= 0.995
    mu_s N) while the engine still has it sticking (mu_s in force): its span, the largest slip
    speed reached and whether it ended in the switch to mu_k."""
    t = d["t"]
    out = []
    for side in ("r", "l"):
        sl = d[f"slide_{side}"] > 0.5
        ratio = np.hypot(d[f"F_{side}"], d[f"L_{side}"]) / np.maximum(d[f"N_{side}"], 1e-9)
        on = (ratio >= 0.995 * mu_s) & ~sl
        idx = np.flatnonzero(on)
        if not idx.size:
            continue
        for g in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            nxt = min(g[-1] + 1, t.size - 1)
            out.append({"wheel": side, "t0": float(t[g[0]]), "dur_ms": 1e3 * float(t[g[-1]] - t[g[0]] + (t[1] - t[0])),
                        "s_max_mm_s": 1e3 * float(d[f"s_{side}"][g].max()),
                        "switched": bool(sl[nxt]), "N": float(d[f"N_{side}"][g].mean())})
    return sorted(out, key=lambda e: e["t0"])


def nominal_overdemand(o: dict[str, np.ndarray], mu_s: float) -> list[dict[str, Any]]:
    """Each stretch on which the nominal model's longitudinal stick demand (its replay with the
    wheels never released) exceeds mu_s N: span, peak F/N, and the slip speed the excess would
    build on the wheel alone, (integral of F - mu_s N) r^2 / I_wy (an upper bound: the body
    takes a share of it).  Longitudinal only: lib/slipmodel splits two stuck wheels' lateral
    force by their remaining capacity, so a wheel at its limit carries none of it (MuJoCo's
    outer wheel on its cone carries almost none either)."""
    from host_tools import params as P
    robot = P.TABLE.defaults("robot", run_format_only=True)
    m_w = float(robot["I_wy"]) / float(robot["r"]) ** 2
    t = o["t_s"]
    out = []
    for side in ("r", "l"):
        f = np.abs(o[f"F_{side}_n"])
        n = o[f"N_{side}"]
        ex = f - mu_s * n
        idx = np.flatnonzero(ex > 0)
        if not idx.size:
            continue
        for g in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            gg = np.r_[g, min(g[-1] + 1, t.size - 1)]
            imp = float(np.sum(ex[g] * np.diff(t[gg])))
            out.append({"wheel": side, "t0": float(t[g[0]]), "dur_ms": 1e3 * float(t[gg[-1]] - t[g[0]]),
                        "peak_ratio": float((f[g] / n[g]).max()), "s_equiv_mm_s": 1e3 * imp / m_w})
    return sorted(out, key=lambda e: e["t0"])


def cmd_cone(a: argparse.Namespace) -> int:
    _meta, d, mu_s, mu_k = _head(a.file)
    eps = cone_episodes(d, mu_s)
    sw = [e for e in eps if e["switched"]]
    print(f"MuJoCo: {len(eps)} stretches on the cone while sticking, {len(sw)} ended in the switch "
          f"to mu_k; largest slip speed on the cone without a switch "
          f"{max([e['s_max_mm_s'] for e in eps if not e['switched']] or [0.0]):.2f} mm/s")
    for e in eps[: a.max_rows]:
        print(f"  {e['wheel']} t {e['t0']:.4f} {e['dur_ms']:6.1f} ms  slip speed max "
              f"{e['s_max_mm_s']:.2f} mm/s  {'-> mu_k' if e['switched'] else 'stays stuck'}")
    if a.run_dir:
        o = nominal_replay(str(a.run_dir), 5.0, mu_k, a.fine)
        ov = nominal_overdemand(o, mu_s)
        ratios = []
        for e in eps:  # MuJoCo's normal force on the cone against the nominal model's there
            w = (d["t"] >= e["t0"]) & (d["t"] <= e["t0"] + 1e-3 * e["dur_ms"])
            n_nom = np.interp(d["t"][w], o["t_s"], o[f"N_{e['wheel']}"])
            ratios.append(float(np.mean(d[f"N_{e['wheel']}"][w] / n_nom)))
        if ratios:
            print(f"MuJoCo's N / the nominal model's N on the cone stretches: mean "
                  f"{np.mean(ratios):.4f}, range {min(ratios):.4f}-{max(ratios):.4f}")
        mj_sl = {sd: d[f"slide_{sd}"] > 0.5 for sd in ("r", "l")}
        print(f"nominal stick demand above mu_s N: {len(ov)} stretches")
        for e in ov[: a.max_rows]:
            i = int(np.clip(np.searchsorted(d["t"], e["t0"]), 0, d["t"].size - 1))
            print(f"  {e['wheel']} t {e['t0']:.4f} {e['dur_ms']:6.1f} ms  peak |F|/N {e['peak_ratio']:.4f}"
                  f" ({e['peak_ratio'] / mu_s:.3f} mu_s)  excess impulse as slip speed on the wheel "
                  f"{e['s_equiv_mm_s']:.2f} mm/s  MuJoCo {'sliding' if mj_sl[e['wheel']][i] else 'stuck'}")
    return 0


def cmd_compare(a: argparse.Namespace) -> int:
    """Slip state of MuJoCo's log against the nominal replay's at the true and at other mu_s."""
    _meta, d = _load(a.file)
    n_sw = {sd: int(np.sum((d[f"slide_{sd}"][1:] > 0.5) & (d[f"slide_{sd}"][:-1] < 0.5))
                    + (d[f"slide_{sd}"][0] > 0.5)) for sd in ("r", "l")}
    _meta, d, mu_s, mu_k = _head(
        a.file, f"; MuJoCo slipping {np.mean(d['slide_r'] > 0.5):.3f} (r) "
        f"{np.mean(d['slide_l'] > 0.5):.3f} (l) of the run, breakaways r {n_sw['r']} l {n_sw['l']}")
    pairs = [("true", mu_s, mu_k)]
    for spec in a.mu or []:
        ms, mk = (float(x) for x in spec.split(","))
        pairs.append((spec, ms, mk))
    t = d["t"]
    for name, ms, mk in pairs:
        o = nominal_replay(str(a.run_dir), ms, mk, a.fine)
        parts = []
        for sd in ("r", "l"):
            nom = np.interp(t, o["t_s"], o[f"slip_{sd}"]) > 0.5
            mj = d[f"slide_{sd}"] > 0.5
            on = int(np.sum(nom[1:] & ~nom[:-1]) + nom[0])
            parts.append(f"{sd}: slipping {nom.mean():.3f}, onsets {on}, nominal-only "
                         f"{1e3 * np.sum(nom & ~mj) * (t[1] - t[0]):.0f} ms, MuJoCo-only "
                         f"{1e3 * np.sum(mj & ~nom) * (t[1] - t[0]):.0f} ms")
        print(f"  nominal at mu_s {ms:.4f} mu_k {mk:.4f} ({name}): " + "; ".join(parts))
    return 0


def case_problem(case_dir: Path) -> tuple[Any, Any, Any]:
    """(the prepared runs, the nominal open-loop replays, the fit problem) of the case's runs,
    as the pipeline builds them."""
    from host_tools.analyzer.pipeline import front

    fr = front([str(p) for p in sorted(case_dir.iterdir()) if (p / "meta.json").is_file()])
    return fr.preps, fr.ol, fr.det.problem


def cmd_profile(a: argparse.Namespace) -> int:
    """mu_s profile of the analyzer's fit cost (``Problem.residual`` over all runs, the
    pipeline's own problem) at a fixed mu_k, with lib/slipmodel's stick/slip law (v_s 0) or with
    the static-to-kinetic drop spread over slip speed by the plant's Stribeck law tied to mu_s
    (mu_k0 = mu_s, v_s given): the nominal model with a breakaway like MuJoCo's."""
    preps, ol, problem = case_problem(a.case_dir)
    grid = [float(x) for x in a.grid.split(",")]
    for vs in (float(x) for x in a.v_s.split(",")):
        row = []
        for ms in grid:
            fx: dict[str, dict[str, float]] = {"friction_coefficient": {"mu_s": ms, "mu_k": a.mu_k}}
            if vs > 0:
                fx["stribeck"] = {"mu_k0": ms, "v_s": vs}
            row.append((ms, float(np.sum(problem.residual(fx, list(range(len(preps)))) ** 2))))
        best = min(row, key=lambda r: r[1])
        print(f"v_s {1e3 * vs:g} mm/s: " + " ".join(f"{ms:.4f}:{c:.0f}" for ms, c in row)
              + f"  | lowest at mu_s {best[0]:.4f}")
    return 0


def cmd_gain(a: argparse.Namespace) -> int:
    """Where an effect's fit improves the analyzer's fit residual: per fit channel, the drop
    of the squared normalized residual (deflated, over the floor: what the fit weighs) from the
    nominal replay to the replay with EFFECT, summed over the samples of each class: the
    nominal duty replay slipping (either wheel) or within --after s of a slip, duty saturated
    (|pwm| >= 0.99) within --after s, the wheels' mean recorded speed reversing within
    --after s, and the rest; over the fit's windows, or every sample with --full."""
    preps, ol, problem = case_problem(a.case_dir)
    name, _, kv = a.effect.partition(":")
    fx = {name: {k: float(v) for k, v in (p.split("=") for p in kv.split(",") if p)}}
    idx = list(range(len(preps)))
    nom = problem.sim_channels({}, idx, a.full, fit_only=True)
    eff = problem.sim_channels(fx, idx, a.full, fit_only=True)
    tot: dict[str, dict[str, float]] = {}
    for i, (cn, ce) in enumerate(zip(nom, eff)):
        prep = preps[i]
        sims = ol.duty.simulate_windows(prep, {})
        ts = np.concatenate([s["t_s"] for _, s in sims])
        slip = np.concatenate([(s["slip_r"] > 0.5) | (s["slip_l"] > 0.5) for _, s in sims])
        tel = prep.run.telemetry
        tt = np.asarray(tel["t_s"], float)
        sat = (np.abs(np.asarray(tel["pwm_r"], float)) >= 0.99) | \
            (np.abs(np.asarray(tel["pwm_l"], float)) >= 0.99)
        wm = 0.5 * (np.asarray(tel["omega_r"], float) + np.asarray(tel["omega_l"], float))
        big = np.abs(wm) > 2.0
        sgn = np.sign(wm[big])
        rev_t = tt[big][1:][sgn[1:] != sgn[:-1]]

        def near(t: np.ndarray, ev_t: np.ndarray) -> np.ndarray:
            if not ev_t.size:
                return np.zeros(t.size, bool)
            j = np.searchsorted(ev_t, t, side="right") - 1
            ok = j >= 0
            out = np.zeros(t.size, bool)
            out[ok] = t[ok] - ev_t[j[ok]] <= a.after
            return out
        slip_t = ts[slip]
        sat_t = tt[sat]
        for c in problem.fit_channels:
            if c not in cn or c not in ce:
                continue
            f = problem.floors[c]
            r0 = cn[c].deflated(f) / f
            r1 = ce[c].deflated(f) / f
            t = cn[c].t
            d = r0 ** 2 - r1 ** 2
            cls = np.where(near(t, slip_t), "slip", np.where(near(t, sat_t), "saturated",
                           np.where(near(t, rev_t) | near(-t, -rev_t[::-1]), "reversal",
                                    "rest")))
            row = tot.setdefault(c, {})
            for k in ("slip", "saturated", "reversal", "rest"):
                m = cls == k
                row[k] = row.get(k, 0.0) + float(np.sum(d[m]))
                row["n_" + k] = row.get("n_" + k, 0.0) + float(np.sum(m))
    print(f"drop of the squared normalized residual, nominal -> {a.effect} (samples in brackets)")
    for c, row in tot.items():
        print(f"{c:12s} " + "  ".join(f"{k} {row[k]:9.1f} [{int(row['n_' + k])}]"
                                      for k in ("slip", "saturated", "reversal", "rest")))
    return 0


def cmd_grid(a: argparse.Namespace) -> int:
    """Runs whose replay grid (the analyzer's, after the closed-loop stage) has steps under 1 ns,
    and what merging those rows changes in the nominal duty replay at the given friction."""
    from host_tools.analyzer.replay.openloop import OpenLoopReplay, _zoh
    n_tiny = n_diff = 0
    fx = {"friction_coefficient": {"mu_s": a.mu_s, "mu_k": a.mu_k}} if a.mu_s else {}
    for run in a.runs:
        prep = prepared(str(run))
        g = prep.t_grid
        dg = np.diff(g)
        if not np.any(dg < 1e-9):
            continue
        n_tiny += 1
        rp = OpenLoopReplay("duty")
        plant, src, t_in = rp._ready(prep, fx)

        def sim(grid: np.ndarray) -> dict[str, Any]:
            out: dict[str, Any] = plant.simulate(
                grid, _zoh(t_in, src[0], grid), _zoh(t_in, src[1], grid), mode="duty",
                dt_s=rp.dt_s, start_pose=prep.start_pose)
            return out
        keep = np.r_[dg >= 1e-9, True]  # the later row of a pair: it holds the new input
        x, y = sim(g), sim(g[keep])
        ds = max(int(np.sum((x[f"slip_{sd}"][keep] > 0.5) != (y[f"slip_{sd}"] > 0.5))) for sd in "rl")
        dw = max(float(np.max(np.abs(x[f"dtheta_{sd}_rad_s"][keep] - y[f"dtheta_{sd}_rad_s"])))
                 for sd in "rl")
        fx_max = max(float(np.max(np.abs(x[f"F_{sd}_n"]))) for sd in "rl")
        fy_max = max(float(np.max(np.abs(y[f"F_{sd}_n"]))) for sd in "rl")
        if ds or dw > 1e-3:
            n_diff += 1
            print(f"{run}: {int(np.sum(dg < 1e-9))} sub-ns steps; slip rows differing {ds}, "
                  f"max |d omega| {dw:.3f} rad/s, max |F| {fx_max:.3f} N (merged {fy_max:.3f} N)")
    print(f"{n_diff} of {n_tiny} runs with sub-ns replay-grid steps replay differently once those "
          f"rows are merged (of {len(a.runs)} runs)")
    return 0


def ramp_mujoco(mu_s: float, mu_k: float, rate: float, lumped: bool, t_end: float
                ) -> dict[str, np.ndarray]:
    from host_tools.engines import mujoco_robot as mr
    rob: Any = mr.MujocoRobot({"friction_coefficient": {"mu_s": mu_s, "mu_k": mu_k}},
                              lumped=lumped)
    rows: list[list[float]] = []
    n = int(round(t_end / rob.dt))
    mj, m, dd = rob._mj, rob.model, rob.data
    for k in range(n):
        tau = rate * k * rob.dt
        rob.tau = [tau, tau]
        for i in (0, 1):
            mu = rob._mu(i, 0.0)
            if mu != rob._mu_set[i]:
                rob._gf[rob._gid[i], 0] = mu
                rob._mu_set[i] = mu
        dd.ctrl[0] = dd.ctrl[1] = tau
        mj.mj_step(m, dd)
        res = rob._res_buf
        for i in (0, 1):
            mj.mj_objectVelocity(m, dd, rob._c["geom"], rob._gid[i], res, 0)
            s = math.hypot(res[3] - rob.r * res[1], res[4] + rob.r * res[0])
            rob.slip_speed[i] = s
            rob.sliding[i] = s > (mr.SLIP_OFF_M_S if rob.sliding[i] else mr.SLIP_ON_M_S)
        _record(rob, rows)
        if k * rob.dt > 0.01 and all(r[12] > 0.5 for r in rows[-int(0.02 / rob.dt):]):
            break  # sliding for 20 ms
    arr = np.asarray(rows, float)
    return {f: arr[:, i] for i, f in enumerate(FIELDS)}


def ramp_nominal(mu_s: float, mu_k: float, rate: float, t_end: float, dt: float = 2e-4
                 ) -> dict[str, np.ndarray]:
    from host_tools import _native
    from host_tools import params as P
    from host_tools.analyzer.replay.normal_forces import plant_config
    robot = P.TABLE.defaults("robot", run_format_only=True)
    motor = P.TABLE.defaults("motor", run_format_only=True)
    cfg = plant_config(robot, {"friction_coefficient": {"mu_s": mu_s, "mu_k": mu_k}})
    plant = _native.Plant(robot=cfg.robot, motor=motor)
    for key, value in cfg.keys.items():
        plant.set(key, value)
    plant.clear_effects()
    for name, ps in cfg.effects.items():
        plant.set_effect(name, **{k: float(v) for k, v in ps.items()})
    t = np.arange(0.0, t_end, dt)
    tau = rate * t
    o = plant.simulate(t, tau, tau, mode="torque", dt_s=dt)
    return {k: np.asarray(v, float) for k, v in o.items()}


def cmd_ramp(a: argparse.Namespace) -> int:
    t_end = a.t_end
    mj = ramp_mujoco(a.mu_s, a.mu_k, a.rate, a.lumped, t_end)
    nom = ramp_nominal(a.mu_s, a.mu_k, a.rate, t_end)
    i = int(np.argmax(mj["slide_r"] > 0.5)) if np.any(mj["slide_r"] > 0.5) else None
    j = int(np.argmax(nom["slip_r"] > 0.5)) if np.any(nom["slip_r"] > 0.5) else None
    print(f"# ramp {a.rate} N m/s on both wheels, mu_s {a.mu_s}, mu_k {a.mu_k}"
          f"{', lumped MuJoCo' if a.lumped else ''}")
    if i is None or j is None:
        print(f"no breakaway within {t_end} s (MuJoCo {i}, nominal {j})")
        return 1
    ratio = np.hypot(mj["F_r"], mj["L_r"]) / np.maximum(mj["N_r"], 1e-9)
    k_cone = int(np.argmax(ratio >= 0.995 * a.mu_s))
    tm, tn = mj["tau_r"][i], nom["tau_r_nm"][j]
    print(f"MuJoCo : cone reached t {mj['t'][k_cone]:.4f} s tau {mj['tau_r'][k_cone]:.5f} N m, "
          f"slip speed there {1e3 * mj['s_r'][k_cone]:.2f} mm/s, N {mj['N_r'][k_cone]:.4f} N; "
          f"switch to mu_k t {mj['t'][i]:.4f} s tau {tm:.5f} N m, |F|/N before "
          f"{ratio[i - 1]:.4f}, N {mj['N_r'][i - 1]:.4f} N, caster {mj['N_c'][i - 1]:.4f} N")
    jb = max(j - 2, 0)  # row j - 1's forces are those of the releasing step
    print(f"nominal: breakaway t {nom['t_s'][j]:.4f} s tau {tn:.5f} N m, N {nom['N_r'][jb]:.4f} N, "
          f"|F|/N before {abs(nom['F_r_n'][jb]) / nom['N_r'][jb]:.4f}, caster "
          f"{nom['N_c'][jb]:.4f} N")
    print(f"tau ratio MuJoCo/nominal {tm / tn:.4f}: the nominal model breaks away at MuJoCo's "
          f"torque with mu_s = {a.mu_s * tm / tn:.4f}; N ratio at the switch "
          f"{mj['N_r'][i - 1] / nom['N_r'][jb]:.4f}; cone->switch delay "
          f"{1e3 * (mj['t'][i] - mj['t'][k_cone]):.1f} ms = {(tm - mj['tau_r'][k_cone]) / tm * 100:.2f} % "
          f"of the torque")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("log")
    p.add_argument("case")
    p.add_argument("run", type=int)
    p.add_argument("--set", required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--switch", choices=("stock", "force"), default="stock")
    p.add_argument("--check", type=Path, default=None, metavar="RUN_DIR")
    p = sub.add_parser("events")
    p.add_argument("file", type=Path)
    p.add_argument("run_dir", nargs="?", type=Path, default=None)
    p = sub.add_parser("cone")
    p.add_argument("file", type=Path)
    p.add_argument("run_dir", nargs="?", type=Path, default=None)
    p.add_argument("--fine", type=float, default=0.0, help="refine the replay grid (s); 0: the "
                   "analyzer's grid")
    p.add_argument("--max-rows", type=int, default=40)
    p = sub.add_parser("compare")
    p.add_argument("file", type=Path)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--mu", action="append", metavar="MU_S,MU_K", help="another pair to replay")
    p.add_argument("--fine", type=float, default=0.0)
    p = sub.add_parser("generate")
    p.add_argument("case")
    p.add_argument("--set", required=True)
    p.add_argument("--switch", choices=("stock", "force"), default="force")
    p.add_argument("--out", type=Path, required=True)
    p = sub.add_parser("profile")
    p.add_argument("case_dir", type=Path)
    p.add_argument("--mu-k", type=float, required=True)
    p.add_argument("--grid", required=True, help="mu_s values, comma-separated")
    p.add_argument("--v-s", default="0,0.005", help="Stribeck speeds (m/s), 0: none")
    p = sub.add_parser("gain")
    p.add_argument("case_dir", type=Path)
    p.add_argument("--effect", required=True, help="EFFECT:KEY=VALUE,... e.g. motor_lag:tau_s=0.0022")
    p.add_argument("--after", type=float, default=0.3, help="s after an event still its class")
    p.add_argument("--full", action="store_true", help="every sample, not the fit's windows")
    p = sub.add_parser("grid")
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--mu-s", type=float, default=0.0)
    p.add_argument("--mu-k", type=float, default=0.0)
    p = sub.add_parser("ramp")
    p.add_argument("--mu-s", type=float, required=True)
    p.add_argument("--mu-k", type=float, required=True)
    p.add_argument("--rate", type=float, default=0.05, help="N m/s per wheel")
    p.add_argument("--lumped", action="store_true")
    p.add_argument("--t-end", type=float, default=6.0)
    a = ap.parse_args(argv)
    if a.cmd == "log":
        a.out.parent.mkdir(parents=True, exist_ok=True)
        meta = log_case_run(a.set, a.case, a.run, a.out, a.switch)
        print(f"logged {meta['case']} run-{meta['run']} -> {a.out}")
        if a.check:
            from host_tools import runfmt
            tel = runfmt.load_run(str(a.check)).telemetry
            z = np.load(a.out)
            same = (np.array_equal(np.asarray(tel["pwm_r"], float), z["tel_pwm_r"])
                    and np.array_equal(np.asarray(tel["t_s"], float), z["tel_t"]))
            print(f"telemetry {'identical to' if same else 'DIFFERENT from'} {a.check}")
            return 0 if same else 1
        return 0
    if a.cmd == "events":
        return cmd_events(a)
    if a.cmd == "cone":
        return cmd_cone(a)
    if a.cmd == "compare":
        return cmd_compare(a)
    if a.cmd == "profile":
        return cmd_profile(a)
    if a.cmd == "grid":
        return cmd_grid(a)
    if a.cmd == "gain":
        return cmd_gain(a)
    if a.cmd == "generate":
        for path in generate_variant(a.set, a.case, a.out, a.switch):
            print(path)
        return 0
    return cmd_ramp(a)


if __name__ == "__main__":
    sys.exit(main())
