"""Measurement: does a "one robot" consistency test of the nominal model's tolerance separate
effects hidden inside the tolerance from nulls?

The analyzer divides each residual sample by the replay uncertainty, which holds the tolerance
ensemble's per-sample spread (``replay.tolerance.tolerance_uncertainty``): each run, each
sample, may sit at a different corner of the tolerance.  The tolerance describes one robot,
though: one vector of tolerance coordinates must explain every run of a case.  Here, per run,
the residual (recording minus the nominal duty replay, the analyzer's fit channels and replay
windows, in noise floors widened by the input spread only: ``noise_floors``,
``input_uncertainty``) is fitted as a linear combination of the output changes of the
tolerance's coordinates (one replay per coordinate at the end of its range, so a coefficient
of 1 is the whole tolerance; the columns in the same units):

  mu      mu_s and mu_k both -tol          gap   mu_s +tol (mu_k kept)
  b e d g h m_r I_rz I_wz I_wy r m_w       each +tol (params.json, the run's own value)
  share   the wheels' mass off the axle (share 0)
  com_h   the centre of mass at 0          spin  the spin share at the low end of its range

Each run's rows are scaled by sqrt(n_eff / n) (``solver.effective_n`` per channel of that run's
own fit residual: the analyzer's correction for correlation), directions are kept to
numerical rank (a singular value of 1e-6 in that unit), and the likelihood-ratio (Wald)
statistic of "the coefficient vectors equal across runs" is

  X = RSS(one c for all runs) - sum_r RSS(c_r),   dof = sum_r rank_r - rank(joint),

chi-square with dof under noise alone.  Also the F form (X / dof over the per-run fits'
residual mean square: robust to a residual the tolerance does not span), and the share of the
nominal residual's sum of squares the common c and the per-run c_r explain; and B, the common
fit held inside the tolerance box against the unbounded one (``_box_test``).

Sub-commands (nice them; one process; about 1-10 s per case, 120 cases in 6 min):

  measure OUT.jsonl SET:CASE ... [--evidence] [--basis corner] [--root DIR]
                                      one JSON line per case (appended; SET heldbackN, runs
                                      read from DIR/SET/runs/CASE, read only).  --evidence:
                                      the samples the analyzer takes as no evidence (the
                                      nominal replay's unpinned slip episodes of a run of
                                      several windows) weigh 0; --basis corner: one
                                      column, the low-traction corner of the left-out
                                      normal forces (does one fraction of it explain
                                      every run?)
  summary OUT.jsonl [--hidden a,b] [--named c,d]
                                      the distributions per engine (_mj_ / _tr_) and group

Example:

  B=bench/analyzer/one_robot.py
  PYTHONPATH=. nice -n 10 .venv/bin/python $B measure /tmp/or.jsonl --evidence \\
      heldback32:hb32_mj_stribeck heldback32:hb32_mj_null_slip        # (and --basis corner)
  .venv/bin/python $B summary /tmp/or.jsonl --hidden hb32_mj_stribeck
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

ROOT = "/work/wt/score-data"
# numerical rank only: in the linear-Gaussian model a direction of any size adds chi-square(1)
# to the statistic; a cut at the noise (1) lets the common fit use directions that each run's
# own fit dropped, and miscounts the dof
SV_MIN = 1e-6


def _coords(robot: dict[str, float], basis: str = "tolerance"
            ) -> list[tuple[str, dict[str, float], object]]:
    from host_tools import params as P
    from host_tools.analyzer.replay.normal_forces import NOMINAL, NormalForces, spin_range
    if basis == "corner":
        # one column: the left-out normal forces' low-traction corner (the wheels' mass off the
        # axle, the centre of mass at 0, the spin share at its low end) in one replay
        return [("corner", {}, NormalForces(share=0.0, com_h_m=0.0,
                                            spin_share=spin_range()[0]))]
    tol = {n: t for (g, n), t in P.TOLERANCES.items() if g == "robot" and t > 0 and n in robot}
    out: list[tuple[str, dict[str, float], object]] = []
    out.append(("mu", {"mu_s": robot["mu_s"] - tol["mu_s"], "mu_k": robot["mu_k"] - tol["mu_k"]},
                NOMINAL))
    out.append(("gap", {"mu_s": robot["mu_s"] + tol["mu_s"]}, NOMINAL))
    for n, t in tol.items():
        if n in ("mu_s", "mu_k"):
            continue
        out.append((n, {n: robot[n] + t}, NOMINAL))
    out.append(("share", {}, NormalForces(share=0.0)))
    out.append(("com_h", {}, NormalForces(com_h_m=0.0)))
    out.append(("spin", {}, NormalForces(spin_share=spin_range()[0])))
    return out


def _case_matrices(run_dirs: list[str], evidence: bool = False, basis: str = "tolerance"
                   ) -> dict[str, object]:
    """Per run: y (weighted residual, floors), J (weighted output change per coordinate),
    the channel of each row; the coordinate names; the floors.  ``evidence``: the samples the
    analyzer takes as no evidence (``locate.episodes.unpinned_episodes`` on its nominal
    channels, tolerance spread included, as ``locate_mismatch`` calls it) get weight 0."""
    from host_tools import runfmt
    from host_tools.analyzer.locate.floors import noise_floors
    from host_tools.analyzer.prepare.inputs import prepare_runs
    from host_tools.analyzer.replay.channels import FIT_CHANNELS, channels, wrap_angle
    from host_tools.analyzer.replay.edges import edges_outside_slip
    from host_tools.analyzer.replay.nominal import replay_closed_loop
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    from host_tools.analyzer.replay.unseen import input_uncertainty
    import dataclasses

    def quiet(_: str) -> None:
        pass

    dt = 5e-4
    runs = [runfmt.load_run(p) for p in run_dirs]
    preps = prepare_runs(runs, quiet)
    preps, _ = replay_closed_loop(preps, dt, [], quiet)
    duty = OpenLoopReplay("duty", dt_s=dt)
    preps = [edges_outside_slip(p, duty)[0] if len(p.windows) > 1 else p for p in preps]
    uncs = [input_uncertainty(p, duty) for p in preps]
    preps = [p if u is None else dataclasses.replace(p, replay_unc=u) for p, u in zip(preps, uncs)]
    nominal = [channels(p, duty.simulate_windows(p, {}), "duty") for p in preps]
    floors = noise_floors(preps, nominal)
    no_ev: list[dict[str, np.ndarray]] = [{} for _ in preps]
    if evidence:
        from host_tools.analyzer.locate.episodes import unpinned_episodes
        from host_tools.analyzer.replay.tolerance import tolerance_uncertainty
        tp = []
        for p in preps:
            tol = tolerance_uncertainty(p, duty)
            tp.append(p if tol is None else dataclasses.replace(p, replay_unc=tol.replay_unc))
        t_nom = [channels(p, duty.simulate_windows(p, {}), "duty") for p in tp]
        t_floors = noise_floors(tp, t_nom)
        un = unpinned_episodes(tp, t_nom, t_floors)
        for i, (before, after) in enumerate(zip(t_nom, un.nominal)):
            for c, ch in after.items():
                b = before[c].unc
                if ch.unc is not None and b is not None and ch.unc.size == b.size:
                    no_ev[i][c] = ch.unc >= 1e8
    coords = _coords(preps[0].robot, basis)
    per_run = []
    for i_run, (p, nom) in enumerate(zip(preps, nominal)):
        chans = [c for c in FIT_CHANNELS if c in nom and c in floors and nom[c].t.size]
        ys, ws, chs = [], [], []
        for c in chans:
            ch = nom[c]
            unc = ch.total_unc
            fl = floors[c]
            w = 1.0 / fl if unc is None else 1.0 / np.sqrt(fl ** 2 + unc ** 2)
            w = np.array(np.broadcast_to(w, ch.t.shape), float)
            if c in no_ev[i_run] and no_ev[i_run][c].size == w.size:
                w[no_ev[i_run][c]] = 0.0
            ys.append(ch.resid * w)
            ws.append(w)
            chs.append(np.full(ch.t.size, c))
        cols = []
        for _, params, forces in coords:
            rep = OpenLoopReplay("duty", dt_s=dt, forces=forces, params=params)  # type: ignore[arg-type]
            got = channels(p, rep.simulate_windows(p, {}), "duty")
            col = []
            for c, w in zip(chans, ws):
                d = got[c].sim - nom[c].sim if got[c].sim.size == nom[c].sim.size else \
                    np.full(nom[c].t.size, np.nan)
                if c == "phi_rad":
                    d = wrap_angle(d)
                col.append(d * w)
            cols.append(np.concatenate(col))
        y = np.concatenate(ys)
        J = np.column_stack(cols)
        ok = np.isfinite(y) & np.all(np.isfinite(J), axis=1) & (np.concatenate(ws) > 0)
        per_run.append({"name": p.name, "y": y[ok], "J": J[ok], "ch": np.concatenate(chs)[ok]})
    return {"runs": per_run, "coords": [c[0] for c in coords], "floors": floors}


def _lsq(J: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float, int, np.ndarray, np.ndarray]:
    """Truncated-SVD least squares: (c, rss, rank, covariance (unit noise), the kept
    directions as columns)."""
    k = J.shape[1]
    if J.size == 0:
        return np.zeros(k), float(y @ y), 0, np.zeros((k, k)), np.zeros((k, 0))
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    keep = s >= SV_MIN
    Uk, sk, Vk = U[:, keep], s[keep], Vt[keep].T
    c = Vk @ ((Uk.T @ y) / sk)
    r = y - J @ c
    cov = Vk @ np.diag(1.0 / sk ** 2) @ Vk.T
    return c, float(r @ r), int(keep.sum()), cov, Vk


def _bounds(name: str) -> tuple[float, float]:
    """The coefficient's range inside the tolerance (1 = the column's replay).  ``gap``'s own
    box is mu_s - mu_k within 2 tol together with ``mu``; taken as [-2, 2] (a superset)."""
    from host_tools.analyzer.replay.normal_forces import SPIN_SHARE, spin_range
    if name == "gap":
        return -2.0, 2.0
    if name in ("share", "com_h"):
        return 0.0, 1.0
    if name == "spin":
        lo, hi = spin_range()
        return (-(hi - SPIN_SHARE) / (SPIN_SHARE - lo) if SPIN_SHARE > lo else 0.0), 1.0
    return -1.0, 1.0


def _box_test(coords: list[str], JJ: np.ndarray, Y: np.ndarray, rss_j: float, rank_j: int
              ) -> dict[str, object]:
    """The joint fit with every coefficient inside the tolerance (:func:`_bounds`) against the
    unbounded one: B = RSS(bounded) - RSS(unbounded) (the same weighting), at most chi-square
    with rank_joint degrees of freedom when the robot is inside its tolerance (a
    chi-bar-square; its 1 % point taken as chi-square's, conservative)."""
    from scipy.optimize import lsq_linear
    from scipy.stats import chi2
    lo = np.array([_bounds(n)[0] for n in coords])
    hi = np.array([_bounds(n)[1] for n in coords])
    use = np.linalg.norm(JJ, axis=0) > 1e-9
    cb = np.zeros(len(coords))
    if use.any():
        cb[use] = lsq_linear(JJ[:, use], Y, bounds=(lo[use], hi[use]), method="bvls").x
    r = Y - JJ @ cb
    B = max(float(r @ r) - rss_j, 0.0)
    return {"B": B, "B_over_q99": float(B / chi2.ppf(0.99, rank_j)) if rank_j > 0 else math.nan,
            "c_box": {n: float(v) for n, v in zip(coords, cb)}}


def one_robot(m: dict[str, object]) -> dict[str, object]:
    """The test of ``m`` (:func:`_case_matrices`): the runs' own fits against one common fit,
    both at numerical rank (:data:`SV_MIN`), dof = sum of the runs' ranks - the joint rank."""
    from scipy.stats import chi2
    from scipy.stats import f as fdist

    from host_tools.analyzer.fit.solver import effective_n
    runs: list[dict[str, np.ndarray]] = m["runs"]  # type: ignore[assignment]
    coords: list[str] = m["coords"]  # type: ignore[assignment]
    per: list[dict[str, object]] = []
    ys, Js = [], []
    rss0 = 0.0
    rss_own = 0.0
    for r in runs:
        y, J, ch = r["y"], r["J"], r["ch"]
        c, rss, _, _, _ = _lsq(J, y)
        res = y - J @ c
        n_eff = sum(effective_n(res[ch == k]) for k in np.unique(ch))
        scale = math.sqrt(n_eff / max(y.size, 1))
        ys.append(y * scale)
        Js.append(J * scale)
        rss0 += float(y @ y)
        rss_own += rss
        c_s, rss_s, rank, cov, _ = _lsq(J * scale, y * scale)
        per.append({"run": str(r["name"]), "n": int(y.size), "n_eff": float(n_eff),
                    "rms0": float(math.sqrt(np.mean(y ** 2))) if y.size else 0.0,
                    "rss0": float(y @ y), "rss_own": rss, "rss_own_s": rss_s, "rank": rank,
                    "c": {k: float(v) for k, v in zip(coords, c_s)},
                    "c_std": {k: float(math.sqrt(max(v, 0.0)))
                              for k, v in zip(coords, np.diag(cov))}})
    Y, JJ = np.concatenate(ys), np.vstack(Js)
    c_j, _, rank_j, _, _ = _lsq(JJ, Y)
    rj = Y - JJ @ c_j
    rss_j_s = float(rj @ rj)
    rss_j = 0.0
    for r, p in zip(runs, per):
        res = r["y"] - r["J"] @ c_j
        p["rss_common"] = float(res @ res)
        rss_j += p["rss_common"]
    box = _box_test(coords, JJ, Y, rss_j_s, rank_j)
    rss_s_sum = sum(float(p["rss_own_s"]) for p in per)  # type: ignore[arg-type]
    X = max(rss_j_s - rss_s_sum, 0.0)
    ranks = sum(int(p["rank"]) for p in per)  # type: ignore[call-overload]
    dof = ranks - rank_j
    n_s = sum(float(p["n_eff"]) for p in per)  # type: ignore[arg-type]
    dof2 = max(n_s - ranks, 1.0)
    s2 = rss_s_sum / dof2
    out = {"X": X, "dof": dof,
           "p": float(chi2.sf(X, dof)) if dof > 0 else math.nan,
           "X_over_q99": float(X / chi2.ppf(0.99, dof)) if dof > 0 else math.nan,
           "F": float(X / dof / s2) if dof > 0 and s2 > 0 else math.nan,
           "F_over_q99": (float(X / dof / s2 / fdist.ppf(0.99, dof, dof2))
                          if dof > 0 and s2 > 0 else math.nan),
           "s2": s2, "rank_joint": rank_j,
           "explained_common": 1.0 - rss_j / rss0 if rss0 > 0 else math.nan,
           "explained_own": 1.0 - rss_own / rss0 if rss0 > 0 else math.nan,
           "rms0": math.sqrt(rss0 / max(sum(int(p["n"]) for p in per), 1)),  # type: ignore[call-overload]
           "c_common": {k: float(v) for k, v in zip(coords, c_j)},
           **box, "runs": per}
    return out


def measure(a: argparse.Namespace) -> None:
    for spec in a.cases:
        set_, case = spec.split(":")
        root = Path(a.root) / set_ / "runs" / case
        run_dirs = sorted(str(p) for p in root.iterdir() if p.name.startswith("run-"))
        t0 = time.time()
        try:
            res = one_robot(_case_matrices(run_dirs, a.evidence, a.basis))
        except Exception as exc:  # a case that does not replay is reported, not fatal
            res = {"error": repr(exc)}
        res.update({"set": set_, "case": case, "evidence": a.evidence, "basis": a.basis,
                    "elapsed_s": time.time() - t0})
        with open(a.out, "a") as fh:
            fh.write(json.dumps(res) + "\n")
        if "error" in res:
            print(f"{case}: {res['error']}", flush=True)
        else:
            print(f"{case:34} X {res['X']:9.1f} dof {res['dof']:3d} X/q99 {res['X_over_q99']:7.2f} "
                  f"F/q99 {res['F_over_q99']:6.2f} expl common {res['explained_common']:.2f} "
                  f"own {res['explained_own']:.2f} rms0 {res['rms0']:.2f} "
                  f"({res['elapsed_s']:.0f} s)", flush=True)


def summary(a: argparse.Namespace) -> None:
    rows = {}
    for line in open(a.out):
        d = json.loads(line)
        rows[d["case"]] = d
    hidden = set(a.hidden.split(",")) if a.hidden else set()
    named = set(a.named.split(",")) if a.named else set()

    def group(c: str) -> str:
        if c in hidden:
            return "hidden"
        if c in named:
            return "named"
        return "null" if "null" in c else "other"

    for eng in ("_mj_", "_tr_"):
        for g in ("null", "hidden", "named", "other"):
            sel = [d for c, d in sorted(rows.items()) if eng in c and group(c) == g and "X" in d]
            if not sel:
                continue
            for key in ("X_over_q99", "F_over_q99", "B_over_q99", "explained_common"):
                v = np.array([d.get(key, math.nan) for d in sel], float)
                v = v[np.isfinite(v)]
                if v.size:
                    print(f"{eng.strip('_')} {g:6} n={len(sel):3d} {key:16} min {v.min():8.2f} "
                          f"median {np.median(v):8.2f} max {v.max():8.2f}"
                          + (f"  >1: {int(np.sum(v > 1))}" if key != "explained_common" else ""))
            if g in ("hidden", "named") or a.all:
                for d in sel:
                    cc = d["c_common"]
                    print(f"     {d['case']:34} X {d['X']:9.1f} dof {d['dof']:3d} "
                          f"X/q99 {d['X_over_q99']:7.2f} F/q99 {d['F_over_q99']:6.2f} "
                          f"common {d['explained_common']:.2f} own {d['explained_own']:.2f} "
                          f"rms0 {d['rms0']:.2f} B/q99 {d.get('B_over_q99', math.nan):.2f}; c "
                          + " ".join(f"{k} " + " ".join(f"{r['c'][k]:+.2f}" for r in d["runs"])
                                     + f" (common {cc[k]:+.2f})" for k in ("corner", "mu", "share")
                                     if k in cc))
    errs = [c for c, d in rows.items() if "error" in d]
    if errs:
        print("errors:", errs)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("measure")
    m.add_argument("out")
    m.add_argument("cases", nargs="+")
    m.add_argument("--root", default=ROOT)
    m.add_argument("--basis", choices=("tolerance", "corner"), default="tolerance",
                   help="corner: one column, the low-traction corner of the left-out normal "
                        "forces (share 0, centre of mass at 0, spin share low)")
    m.add_argument("--evidence", action="store_true",
                   help="weight 0 where the analyzer takes a sample as no evidence")
    s = sub.add_parser("summary")
    s.add_argument("out")
    s.add_argument("--hidden", default="")
    s.add_argument("--named", default="")
    s.add_argument("--all", action="store_true")
    a = p.parse_args()
    {"measure": measure, "summary": summary}[a.cmd](a)


if __name__ == "__main__":
    main()
