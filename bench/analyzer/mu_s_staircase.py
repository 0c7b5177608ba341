"""Measurement: the analyzer's fit cost of a case along mu_s at a fixed mu_k, per run, with the
profile set's threshold (fit/problem.py ``_profile_set``: chi2(0.95, 1) s^2 n / n_eff).

A breakaway of the replay happens at a controller tick or not at all, so between two ticks'
required traction ratios the cost does not depend on mu_s: it is a staircase, and a profile set
taken on it is the stair (or stairs) within the threshold of the lowest one.  Each line gives
the total cost, the cost per run and each run's replayed slip episodes (on the analyzer's grid).

``--variant`` replays with another normal-force physics (bench/analyzer/nominal_normal_forces.py's
variants: the nominal model's own tolerance).  ``--unseen-ticks`` runs the same with the experiment of a proposed change (not the analyzer's
rule): ``prepare.inputs.prepare`` treats a run whose largest frame gap exceeds one inner period
(rather than 1.5 of the larger of it and the frame interval) as one whose frames may leave ticks
unreported, so that such ticks are filled between their reported neighbours.

Usage (nice it; seconds per case):
  PYTHONPATH=. .venv/bin/python bench/analyzer/mu_s_staircase.py RUNS/hb14_tr_friction_coefficient \\
      --mu-k 0.1976 --mu-s 0.199,0.201,0.2225,0.2246,0.2275,0.2299,0.232 [--unseen-ticks]
"""
from __future__ import annotations

import argparse
import glob
import inspect
import os
import sys
from typing import Any

import numpy as np
from scipy.stats import chi2

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", ".."), HERE]

_RULE = "gappy = t.size > 1 and float(np.max(np.diff(t))) > max(period, dt_tel) * 1.5"
_EXPERIMENT = "gappy = t.size > 1 and float(np.max(np.diff(t))) > period * 1.0001"


def unseen_ticks_experiment() -> None:
    """Replace prepare.inputs' functions by the same source with the one-period gap test."""
    import host_tools.analyzer.prepare.inputs as inputs
    src = inspect.getsource(inputs)
    if _RULE not in src:
        raise SystemExit("prepare/inputs.py no longer has the rule this experiment replaces")
    exec(compile(src.replace(_RULE, _EXPERIMENT), inputs.__file__, "exec"), inputs.__dict__)


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("case_dir")
    ap.add_argument("--mu-k", type=float, required=True)
    ap.add_argument("--mu-s", required=True, help="comma-separated values")
    ap.add_argument("--unseen-ticks", action="store_true")
    ap.add_argument("--variant", default="base",
                    help="the replay plant's normal-force physics (nominal_normal_forces.VARIANTS)")
    a = ap.parse_args()
    if a.unseen_ticks:
        unseen_ticks_experiment()
    from bench_fit_scaling import _problem  # the fit problem as the pipeline builds it
    from nominal_normal_forces import VARIANTS, nominal_plant
    from host_tools.analyzer.fit.solver import effective_n
    from host_tools.analyzer.replay.openloop import OpenLoopReplay

    with nominal_plant(VARIANTS[a.variant]):
        staircase(a, _problem(sorted(glob.glob(os.path.join(a.case_dir, "run-*")))), effective_n,
                  OpenLoopReplay)


def staircase(a: argparse.Namespace, det: Any, effective_n: Any, OpenLoopReplay: Any) -> None:
    """Print the cost per mu_s of the detection ``det``'s fit problem (see the module)."""
    pr = det.problem
    preps = pr.preps
    every = list(range(len(preps)))
    rp = OpenLoopReplay("duty", dt_s=5e-4)
    best: tuple[float, float, np.ndarray] | None = None
    for mu_s in (float(v) for v in a.mu_s.split(",")):
        fx = {"friction_coefficient": {"mu_s": mu_s, "mu_k": a.mu_k}}
        r = pr.residual(fx, every)
        cost = float(np.sum(r ** 2))
        if best is None or cost < best[0]:
            best = (cost, mu_s, r)
        per = [float(np.sum(pr.residual(fx, [k]) ** 2)) for k in every]
        slips = []
        for k, prep in enumerate(preps):
            s = rp.simulate(prep, fx)
            g = s["t_s"]
            for w in "rl":
                f = np.r_[False, np.asarray(s[f"slip_{w}"]) > 0, False].astype(np.int8)
                d = np.diff(f)
                on, off = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
                if on.size:
                    slips.append(f"{k}{w} " + ",".join(
                        f"{g[i]:.3f}-{g[min(int(j), g.size - 1)]:.3f}" for i, j in zip(on, off)))
        print(f"mu_s {mu_s:.4f}: cost {cost:.2f} | per run " + " ".join(f"{p:.2f}" for p in per)
              + " | slips " + "; ".join(slips))
    if best is not None:
        cost, mu_s, r = best
        scale = cost / max(r.size - 2, 1) * r.size / max(effective_n(r), 1.0)
        print(f"lowest cost at mu_s {mu_s}: n {r.size}, n_eff {effective_n(r):.0f}; the profile "
              f"set's threshold above it {chi2.ppf(0.95, 1) * scale:.2f}")


if __name__ == "__main__":
    main()
