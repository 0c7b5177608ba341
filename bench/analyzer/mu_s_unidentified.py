"""Measurement: why a truth-engine friction change leaves mu_s unidentified, and what mu_k does.

For each suite case (its runs and its label with the true mu_s, mu_k) it prints:

* the truth's slips (label's hidden truth, ``true_slip_r/l``): per run and wheel the number of
  grip -> slip onsets, how many start in the first 10 ms (a start that slips at once: its onset
  says only that mu_s is below the first torque), the median and total slip time;
* the analyzer's friction fit as the pipeline makes it (``Problem.fit``: mu_s, mu_k, whether
  mu_s is pinned as unidentified, the profile set) and the same fit with every coordinate
  free (``pin_unidentified=False``: the profile's own minimum);
* the identifiability test of ``solver.unidentified_given`` at the free solution: the 1-sigma
  of mu_s from the residual's change over a tenth of mu_s's possible range [mu_k, 2 mu_k]
  with mu_k held, against UNIDENTIFIED of that range, beside the profile set's own sigma;
* mu_k refitted with mu_s pinned at the nominal model's point on its line (mu_k mu_s0/mu_k0),
  at the true mu_s, at the profile set's upper edge and over a grid of mu_s in the set
  (the profile over mu_s with mu_k re-minimized): mu_k and the cost (sum of squares of the
  normalized residual) against the free fit's, with the set's threshold
  (chi2(0.95, 1) s^2 n / n_eff); and each run's cost over the same grid and 2 % beyond the set's
  edge with mu_k held (which run bounds mu_s);
* a summary table over the cases: the true mu_k/mu_s, the truth's onsets after the first 10 ms
  (and the telemetry frames inside their slips), the cost's spread over the profile grid in
  units of the set's threshold, mu_k's and mu_s's errors, and the share of mu_s's deviation
  from the nominal missed by the pipeline's point, the profile's minimum and the set's midpoint.

``--variant c1`` replays with the truth simulator's normal-force physics (the whole spin-up
through the plant's own theta'' term, bench/analyzer/nominal_normal_forces.py): mu_k's error
that remains is not the normal forces'.

Usage (nice it; a few seconds to a minute per case):
  PYTHONPATH=. .venv/bin/python bench/analyzer/mu_s_unidentified.py \\
      SCORE/heldback26/runs/hb26_tr_friction_coefficient [more case dirs ...] [--grid 6] [--variant c1]
  (the label is read from ../labels/CASE.json beside the runs directory)
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import sys

import numpy as np
from scipy.stats import chi2

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", ".."), HERE]

FX = "friction_coefficient"


def truth_slips(label_dir: str, experiments: list) -> tuple[list[str], int, int]:
    """Per run and wheel: onsets, onsets in the first 10 ms, median and total slip time; and
    over the case the onsets after the first 10 ms (a breakaway under a torque the data see
    rise: what carries mu_s) and the telemetry frames inside their slips."""
    out = []
    late_on = late_frames = 0
    for k, f in enumerate(sorted(glob.glob(os.path.join(label_dir, "run-*.truth.csv")))):
        d = np.genfromtxt(f, delimiter=",", names=True)
        t = d["t_s"]
        dt = float(np.median(np.diff(t)))
        parts = []
        for w in "rl":
            s = np.r_[0, (d[f"true_slip_{w}"] > 0).astype(np.int8), 0]
            on, off = np.flatnonzero(np.diff(s) == 1), np.flatnonzero(np.diff(s) == -1)
            dur = (off - on) * dt
            early = t[np.minimum(on, t.size - 1)] < 0.01 + t[0]
            late_on += int(np.sum(~early))
            late_frames += int(np.sum((off - on)[~early]))
            parts.append(f"{w}: {on.size} onsets ({int(early.sum())} at start), median "
                         f"{(np.median(dur) if dur.size else 0) * 1e3:.0f} ms, total "
                         f"{dur.sum():.2f} s")
        clamp = experiments[k].get("clamp") if k < len(experiments) else None
        out.append(f"  {os.path.basename(f).split('.')[0]} (clamp {clamp}, telemetry "
                   f"{dt * 1e3:.0f} ms): " + "; ".join(parts))
    return out, late_on, late_frames


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--grid", type=int, default=6, help="points of mu_s's profile in the set")
    ap.add_argument("--variant", default="base",
                    help="the replay plant's normal-force physics (nominal_normal_forces.VARIANTS;"
                         " c1: the truth's, to tell the normal forces' share of mu_k's error)")
    a = ap.parse_args()
    from nominal_normal_forces import VARIANTS, nominal_plant
    with nominal_plant(VARIANTS[a.variant]):
        run(a)


def run(a: argparse.Namespace) -> None:
    """Print the module's figures for every case of ``a.cases``."""
    from bench_fit_scaling import _problem  # the fit problem as the pipeline builds it
    from host_tools.analyzer.fit.params import params_for
    from host_tools.analyzer.fit.solver import UNIDENTIFIED, effective_n

    rows: list[tuple] = []
    for case in a.cases:
        case = case.rstrip("/")
        name = os.path.basename(case)
        lab = json.load(open(os.path.join(os.path.dirname(os.path.dirname(case)), "labels",
                                          name + ".json")))
        true = lab["effects"].get(FX, {})
        print(f"== {name} (recorder {lab.get('recorder_name')}): true mu_s {true.get('mu_s')}"
              f" mu_k {true.get('mu_k')}")
        lines, late_on, late_frames = truth_slips(
            os.path.join(os.path.dirname(os.path.dirname(case)), "labels", name),
            lab.get("experiments", []))
        for line in lines:
            print(line)
        pr = _problem(sorted(glob.glob(os.path.join(case, "run-*")))).problem
        runs = list(range(len(pr.preps)))
        ps = params_for([FX], pr.meta, pr.vocab)
        ratio0 = ps[1].neutral

        def show(f: object) -> str:
            v = f.params[FX]   # type: ignore[attr-defined]
            return f"mu_s {v['mu_s']:.4f} mu_k {v['mu_k']:.4f} cost {f.rss:.2f}"  # type: ignore[attr-defined]

        dflt = pr.fit([FX], runs)
        iv = dflt.intervals.get(f"{FX}.mu_s")
        print(f"  pipeline fit: {show(dflt)} unidentified {dflt.unidentified or '-'}"
              + (f"; set [{iv.lo:.4f}, {iv.hi:.4f}] {iv.kind}, sigma {iv.sigma:.4f}, flat "
                 f"[{iv.flat[0]:.4f}, {iv.flat[1]:.4f}]" if iv else ""))
        free = pr.fit([FX], runs, pin_unidentified=False)
        mu_s, mu_k = free.params[FX]["mu_s"], free.params[FX]["mu_k"]
        print(f"  free fit:     {show(free)}")

        def res(s: float, k: float) -> np.ndarray:
            return pr.residual({FX: {"mu_s": s, "mu_k": k}}, runs)
        r = res(mu_s, mu_k)
        lo, hi = mu_k, min(mu_k / 0.5, ps[0].hi)
        h = 0.1 * (hi - lo)
        v2 = mu_s + h if mu_s + h <= hi else mu_s - h
        d = (res(v2, mu_k) - r) / (v2 - mu_s)
        s2 = float(np.sum(r ** 2)) / max(r.size - 2, 1)
        infl = r.size / max(effective_n(r), 1.0)
        dd = float(d @ d)
        sd = math.sqrt(s2 * infl / dd) if dd > 0 else math.inf
        thr = float(chi2.ppf(0.95, 1)) * s2 * infl
        print(f"  unidentified_given: step {mu_s:.4f} -> {v2:.4f} (a tenth of [{lo:.4f}, "
              f"{hi:.4f}]): cost change {float(np.sum((r + d * (v2 - mu_s)) ** 2) - np.sum(r ** 2)):+.2f}"
              f", sigma {sd:.4f} against {UNIDENTIFIED} x range = {UNIDENTIFIED * (hi - lo):.4f}"
              f" -> {'UNIDENTIFIED' if sd > UNIDENTIFIED * (hi - lo) else 'identified'}; "
              f"n {r.size}, n/n_eff {infl:.1f}, set threshold {thr:.2f}")

        def pinned(v: float) -> tuple[float, float]:
            f = pr.fit([FX], runs, fixed={0: float(np.clip(ps[0].to_x(v), 0, 1))})
            return f.params[FX]["mu_k"], f.rss
        pts = [("nominal ratio", mu_k / ratio0)]
        if "mu_s" in true:
            pts.append(("true mu_s", float(true["mu_s"])))
        if iv is not None:
            pts.append(("set's upper edge", float(iv.hi)))
        for lbl, v in pts:
            k, c = pinned(v)
            print(f"  mu_s pinned at {lbl} {v:.4f}: mu_k {k:.4f}, cost {c:.2f} "
                  f"({c - free.rss:+.2f} from the free fit)")
        spread = math.nan
        if iv is not None and a.grid > 1:
            prof = []
            costs = []
            for v in np.linspace(max(iv.lo, mu_k), iv.hi, a.grid):
                k, c = pinned(float(v))
                costs.append(c)
                prof.append(f"{v:.4f}:{k:.4f}/{c - free.rss:+.1f}")
            print("  profile mu_s: mu_k / cost - free cost: " + "  ".join(prof))
            spread = (max(costs) - min(costs)) / thr
            print(f"  cost per run with mu_k held at {mu_k:.4f} (which run bounds mu_s):")
            for v in [*np.linspace(max(iv.lo, mu_k), iv.hi, a.grid), 1.02 * iv.hi]:
                per = [float(np.sum(pr.residual({FX: {"mu_s": float(v), "mu_k": mu_k}}, [j])
                                    ** 2)) for j in runs]
                print(f"    mu_s {v:.4f}: " + " ".join(f"{c:9.2f}" for c in per))
        if "mu_k" in true:
            print(f"  errors: mu_k {100 * (dflt.params[FX]['mu_k'] / true['mu_k'] - 1):+.1f} %, "
                  f"mu_s (pipeline) {100 * (dflt.params[FX]['mu_s'] / true['mu_s'] - 1):+.1f} %,"
                  f" mu_s (free) {100 * (mu_s / true['mu_s'] - 1):+.1f} %; share of mu_s's "
                  f"deviation missed: pipeline "
                  f"{abs(dflt.params[FX]['mu_s'] - true['mu_s']) / abs(ps[0].neutral - true['mu_s']):.0%}"
                  f", free {abs(mu_s - true['mu_s']) / abs(ps[0].neutral - true['mu_s']):.0%}")
            mus = dflt.params[FX]["mu_s"]
            dev = abs(ps[0].neutral - true["mu_s"])
            mid = 0.5 * (iv.lo + iv.hi) if iv is not None else math.nan
            rows.append((name, bool(dflt.unidentified), true["mu_k"] / true["mu_s"], late_on,
                         late_frames, spread,
                         100 * (dflt.params[FX]["mu_k"] / true["mu_k"] - 1),
                         100 * (mus / true["mu_s"] - 1), abs(mus - true["mu_s"]) / dev,
                         abs(mu_s - true["mu_s"]) / dev, abs(mid - true["mu_s"]) / dev))
        sys.stdout.flush()
    if rows:
        print("\ncase | mu_s unidentified | true mu_k/mu_s | onsets after 10 ms (frames in "
              "them) | cost spread over the set / threshold | mu_k error % | mu_s error % | "
              "share of mu_s's deviation missed: pipeline, profile minimum, set midpoint")
        for r in rows:
            print(f"{r[0]} | {'yes' if r[1] else 'no'} | {r[2]:.3f} | {r[3]} ({r[4]}) | "
                  f"{r[5]:.2f} | {r[6]:+.1f} | {r[7]:+.1f} | {r[8]:.0%}, {r[9]:.0%}, "
                  f"{r[10]:.0%}")
        for flag in (True, False):
            sel = [r for r in rows if r[1] == flag]
            if sel:
                print(f"mu_s {'unidentified' if flag else 'identified'}: {len(sel)} cases; "
                      f"mu_k error % median {np.median([r[6] for r in sel]):+.1f} "
                      f"[{min(r[6] for r in sel):+.1f}, {max(r[6] for r in sel):+.1f}]; "
                      f"|mu_s error| % median {np.median([abs(r[7]) for r in sel]):.1f}; "
                      f"misses (> 25 % of the deviation): pipeline "
                      f"{sum(r[8] > 0.25 for r in sel)}, profile minimum "
                      f"{sum(r[9] > 0.25 for r in sel)}, set midpoint "
                      f"{sum(r[10] > 0.25 for r in sel)}")


if __name__ == "__main__":
    main()
