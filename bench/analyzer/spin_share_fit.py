"""Experiment: is the wheels' spin share k identifiable beside the ``load_transfer`` effect's
centre-of-mass height h from slipping runs?  (docs/analyzer.md, "The load transfer's h and the
spin share"; lib/slipmodel/README.md, "Load transfer and spin-up".)

The nominal model carries the spin-up as the rolling height k^ h_s added to h (k^ = 0.5,
params.json ``model.spin_share``; the plant's own theta'' spin term off).  While the wheels roll
(theta'' = a_x / r) that is exactly the pitch balance's k I_wy (theta''_r + theta''_l), so h and
k are one parameter, h + k h_s; only the intervals where a wheel slips (theta'' != a_x / r) can
tell them apart.  Per case this script builds the analyzer's own fit problem (the stages of
``pipeline.analyze`` up to ``detect_mismatch``: the same runs, channels, floors and windows) and
fits on it:

  nominal   h alone with the nominal model (the analyzer's load_transfer candidate)
  plant-k   h alone with the spin-up through the plant's own theta'' term at k (k^ h_s off),
            for k in --ks (k = 1 is the truth simulator's physics, MuJoCo's measured k is 0.5)
  joint     (h, k) together through the plant's own term, k in [0, 1]; sigma from the
            Gauss-Newton covariance inflated for correlated residuals as ``solver.param_std``
            does, and the correlation of h and k

Usage (nice it; one process; a short SLIP case takes a few seconds):

  nice .venv/bin/python bench/analyzer/spin_share_fit.py [--json OUT] CASE_DIR [CASE_DIR ...]

A CASE_DIR holds the run folders of one case (a suite ``runs/<case>``); its label (the suite's
``labels/<case>.json``, when present beside ``runs``) gives the true h.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares

from host_tools.analyzer import pipeline as PL
from host_tools.analyzer.fit.solver import effective_n
from host_tools.analyzer.replay.normal_forces import NormalForces, spin_height
from host_tools.analyzer.replay.openloop import OpenLoopReplay

SPIN = "_spin"  # pseudo-effect carrying k through the fit problem's replay cache key


class PlantSpinReplay(OpenLoopReplay):
    """The nominal duty replay with the spin-up through the plant's own theta'' term at the k
    of the pseudo-effect ``_spin`` (the rolling height off)."""

    def __init__(self, dt_s: float) -> None:
        super().__init__("duty", dt_s=dt_s, forces=NormalForces(spin_share=0.0))
        self.k = 0.0

    def _strip(self, effects: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
        if SPIN in effects:
            self.k = float(effects[SPIN]["k"])
        return {n: dict(p) for n, p in effects.items() if n != SPIN}

    def _ready(self, prep: Any, effects: Mapping[str, Mapping[str, float]]) -> Any:
        plant, src, t = super()._ready(prep, effects)
        plant.set("plant.spin_share", self.k)
        return plant, src, t

    def simulate(self, prep: Any, effects: Mapping[str, Mapping[str, float]]) -> Any:
        return super().simulate(prep, self._strip(effects))

    def simulate_windows(self, prep: Any, effects: Mapping[str, Mapping[str, float]],
                         which: Sequence[int] | None = None) -> Any:
        return super().simulate_windows(prep, self._strip(effects), which)


def _fit_h(fun: Any, h0: float) -> tuple[float, float]:
    s = least_squares(lambda x: fun(float(x[0])), [h0], bounds=([0.0], [0.3]),
                      diff_step=[0.02], x_scale=[0.01])
    return float(s.x[0]), float(2.0 * s.cost)


def analyze_case(case_dir: str, ks: Sequence[float], dt_s: float = 5e-4) -> dict[str, Any]:
    problem = PL.front(sorted(glob.glob(os.path.join(case_dir, "run-*"))), dt_s=dt_s).det.problem
    idx = list(range(len(problem.preps)))
    name = os.path.basename(os.path.normpath(case_dir))
    out: dict[str, Any] = {"case": name, "h_s": spin_height(problem.preps[0].robot)}
    label = os.path.join(os.path.dirname(os.path.dirname(os.path.normpath(case_dir))),
                         "labels", name + ".json")
    h0 = float(problem.preps[0].robot["h"])
    if os.path.exists(label):
        lab = json.load(open(label))
        out["engine"] = lab.get("engine")
        h_true = lab.get("effects", {}).get("load_transfer", {}).get("h")
        if h_true is not None:
            out["h_true"] = float(h_true)
            h0 = float(h_true)
    out["rss0"] = float(np.sum(problem.residual({}, idx) ** 2))
    out["h_nominal"], out["rss_nominal"] = _fit_h(
        lambda h: problem.residual({"load_transfer": {"h": h}}, idx), h0)
    problem._replay = PlantSpinReplay(dt_s)
    problem.forget()

    def res(h: float, k: float) -> np.ndarray:
        return problem.residual({"load_transfer": {"h": h}, SPIN: {"k": k}}, idx)
    out["plant_k"] = {}
    for k in ks:
        h, rss = _fit_h(lambda h, k=k: res(h, k), h0)
        out["plant_k"][f"{k:g}"] = {"h": h, "rss": rss}
    best = None
    for k0 in (0.0, 0.5, 1.0):
        s = least_squares(lambda x: res(float(x[0]), float(x[1])), [h0, k0],
                          bounds=([0.0, 0.0], [0.3, 1.0]), diff_step=[0.02, 0.02],
                          x_scale=[0.01, 0.2])
        if best is None or s.cost < best.cost:
            best = s
    assert best is not None
    r, jac = best.fun, best.jac
    s2 = float(np.sum(r ** 2)) / max(r.size - 2, 1)
    cov = np.linalg.pinv(jac.T @ jac) * s2 * (r.size / max(effective_n(r), 1.0))
    sh, sk = math.sqrt(max(cov[0, 0], 0.0)), math.sqrt(max(cov[1, 1], 0.0))
    out["joint"] = {"h": float(best.x[0]), "k": float(best.x[1]), "sigma_h": sh, "sigma_k": sk,
                    "corr": float(cov[0, 1] / (sh * sk)) if sh * sk > 0 else math.nan,
                    "rss": float(2.0 * best.cost), "s2": s2, "n": int(r.size),
                    "n_eff": float(effective_n(r))}
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--ks", default="0,0.5,1", help="k of the plant-k fits")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    ks = [float(v) for v in a.ks.split(",")]
    rows = []
    for c in a.cases:
        o = analyze_case(c, ks)
        rows.append(o)
        j, t = o["joint"], o.get("h_true", math.nan)
        pk = " ".join(f"k{k}:{1e3 * (v['h'] - t):+.1f}" for k, v in o["plant_k"].items())
        print(f"{o['case']:28s} {o.get('engine', '?'):7s} h {t:.4f}  h-h_true mm: nominal "
              f"{1e3 * (o['h_nominal'] - t):+.1f}  plant {pk}  joint {1e3 * (j['h'] - t):+.1f} "
              f"(sigma {1e3 * j['sigma_h']:.1f})  k {j['k']:.2f} sigma {j['sigma_k']:.2f} "
              f"corr {j['corr']:+.3f}", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
