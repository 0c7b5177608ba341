"""Where the held-out paired z of a candidate comes from: ``python bench/analyzer/heldout_paired_z.py
RUNS_DIR [RUNS_DIR ...] [--effect motor_lag]``.

Measurement only (no rule).  For each case (a directory of runs, as the suite writes them) the
script builds the analyzer's own fit problem (``pipeline.front(paths).det.problem``), fits the
candidate on all runs and repeats ``fit.judge.evaluate_candidate``'s held-out folds (leave one
run out up to ``HELDOUT_FOLDS`` runs), keeping each fold's held-out residuals apart.  It prints:

- the pooled paired test exactly as ``fit.judge.paired_better`` forms it (d = after² − before²
  over all held-out samples of all fit channels, in floors²; z = −mean(d) / (sd(d) / √n_eff),
  n_eff the AR(1) count of the pooled *after* residual);
- per held-out run: samples, RMS before/after, mean(d), sd(d), n_eff (of the run's concatenated
  after residual, and summed over its channels, each channel's own AR(1)), the share of the run's
  Σd in its 5 most improved samples, its share of Σd, the
  run's own z, and per fit channel of that run the samples and Σd;
- how concentrated Σd is (its share in the 5/10/20 most improved samples), the share of samples
  improved, the z with the raw sample count (no AR(1) correction);
- the z with a noise-only standard error 2 RMS(a − b)/√n_eff (d's noise part when before and
  after share the noise), no tolerance share: a measurement, not a rule;
- two alternative aggregations for comparison (not rules): one value per run (the runs' mean
  d, t over runs) and the runs' own z combined as Σ z_i / √k (Stouffer).
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
sys.path.insert(0, ROOT)


def _labelled(pb, effects, runs):
    """Problem.residual's samples of ``runs`` with their channel names (same order)."""
    out = []
    for i, chans in zip(runs, pb.sim_channels(effects, runs, False, fit_only=True)):
        for c in pb.fit_channels:
            ch = chans.get(c)
            if ch is None:
                continue
            r = ch.deflated(pb.floors[c]) / pb.floors[c]
            out.append((c, np.where(np.isfinite(r), r, 1e6)))
        for d, _t in pb.slip_differences(chans):
            out.append(("slip_diff", np.where(np.isfinite(d), d, 1e6)))
    return out


def case(path: str, effect: str) -> None:
    from host_tools.analyzer import pipeline as pl
    from host_tools.analyzer.fit.judge import heldout_folds, paired_better
    from host_tools.analyzer.fit.solver import effective_n

    paths = sorted(os.path.join(path, d) for d in os.listdir(path)
                   if os.path.exists(os.path.join(path, d, "meta.json")))
    pb = pl.front(paths).det.problem
    runs = list(range(len(pb.preps)))
    full = pb.fit([effect], runs)
    print(f"== {os.path.basename(path.rstrip('/'))}: {len(runs)} runs, {effect} "
          f"{ {k: round(v, 5) for k, v in full.params[effect].items()} }")
    pool_b, pool_a, rows = [], [], []
    for train, test, ptrain, ptest in heldout_folds(len(runs)):
        f = pb.fit([effect], train, part=ptrain, x0=full.x, max_nfev=25, fixed=full.fixed)
        lb = _labelled(pb, {}, test)
        la = _labelled(pb, f.params, test)
        rb = np.concatenate([v for _, v in lb])
        ra = np.concatenate([v for _, v in la])
        pool_b.append(rb)
        pool_a.append(ra)
        per_ch: dict[str, list[float]] = {}
        # n_eff summed channel by channel (each channel's own AR(1)), against the concatenation's
        seg_neff = sum(effective_n(v) for _, v in la if v.size)
        if [c for c, _ in lb] == [c for c, _ in la]:
            for (c, vb), (_, va) in zip(lb, la):
                if vb.size == va.size:
                    e = per_ch.setdefault(c, [0, 0.0])
                    e[0] += vb.size
                    e[1] += float(np.sum(va ** 2 - vb ** 2))
        rows.append((test, rb, ra, per_ch, seg_neff))
    b, a = np.concatenate(pool_b), np.concatenate(pool_a)
    ok, z = paired_better(b, a)
    d = a ** 2 - b ** 2
    n_eff = effective_n(a)
    print(f"  pooled: n {d.size}, n_eff(after) {n_eff:.1f}, RMS {math.sqrt(np.mean(b**2)):.3f} -> "
          f"{math.sqrt(np.mean(a**2)):.3f}, mean d {np.mean(d):.3f}, sd d {np.std(d, ddof=1):.3f}, "
          f"paired z {z:.2f} ({'better' if ok else 'not significant'})")
    tot = float(np.sum(d))
    srt = np.sort(d)
    top = {q: float(np.sum(srt[:q]) / tot) if tot else math.nan for q in (5, 10, 20)}
    z_n = -float(np.mean(d)) / (float(np.std(d, ddof=1)) / math.sqrt(d.size))
    # d = a² − b² = (a − b)(a + b); with a and b sharing the same noise e (floors, sd 1) its noise
    # part is 2 e (a − b): the change's own RMS sets a noise-only standard error
    chg = float(np.sqrt(np.mean((a - b) ** 2)))
    z_chg = -float(np.mean(d)) / (2.0 * chg / math.sqrt(n_eff)) if chg > 0 else math.nan
    print(f"  RMS of the change (a - b) {chg:.3f} floors; z with the noise-only error "
          f"2 rms(a - b) / sqrt(n_eff) {z_chg:.2f} (no tolerance share; not a rule)")
    print(f"  share of sum d in its 5/10/20 most negative samples: {top[5]:.2f}/{top[10]:.2f}/"
          f"{top[20]:.2f}; samples improved (d < 0) {np.mean(d < 0):.2f}, worse {np.mean(d > 0):.2f}; "
          f"z with n instead of n_eff {z_n:.2f}; n_eff/n {n_eff / d.size:.2f}")
    means, zs = [], []
    for test, rb, ra, per_ch, seg_neff in rows:
        di = ra ** 2 - rb ** 2
        ne = effective_n(ra)
        sd = float(np.std(di, ddof=1)) if di.size > 1 else math.nan
        zi = -float(np.mean(di)) / (sd / math.sqrt(ne)) if sd and sd > 0 else math.nan
        means.append(float(np.mean(di)))
        zs.append(zi)
        print(f"  run {test}: n {di.size}, RMS {math.sqrt(np.mean(rb**2)):.3f} -> "
              f"{math.sqrt(np.mean(ra**2)):.3f}, mean d {np.mean(di):.3f}, sd d {sd:.3f}, "
              f"n_eff {ne:.1f} (per channel summed {seg_neff:.1f}), top-5 share "
              f"{np.sum(np.sort(di)[:5]) / np.sum(di) if np.sum(di) else math.nan:.2f}, share of sum d {np.sum(di) / tot if tot else math.nan:.2f}, z {zi:.2f}")
        for c, (n, s) in sorted(per_ch.items(), key=lambda kv: kv[1][1]):
            print(f"      {c:14s} n {n:5d}  sum d {s:9.1f}  mean d {s / max(n, 1):8.3f}")
    k = len(means)
    if k > 1:
        m, s = float(np.mean(means)), float(np.std(means, ddof=1))
        print(f"  one value per run: mean {m:.3f}, sd {s:.3f}, t {-m / (s / math.sqrt(k)):.2f} "
              f"(k {k}); Stouffer sum z_i/sqrt(k) {np.nansum(zs) / math.sqrt(k):.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/heldout_paired_z.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+", help="directories of one case's runs")
    ap.add_argument("--effect", default="motor_lag")
    args = ap.parse_args(argv)
    for p in args.cases:
        case(p, args.effect)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
