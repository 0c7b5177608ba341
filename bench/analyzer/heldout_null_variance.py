"""The adoption's held-out paired test against its own null: ``python
bench/analyzer/heldout_null_variance.py survey [--sets 24-33]`` and ``python
bench/analyzer/heldout_null_variance.py case RUNS_DIR EFFECT [EFFECT ...] [--out FILE]``,
``... summary FILE``.

Measurement only (no rule).

``survey`` reads the stored blind reports (``/work/wt/score-data/heldbackN/reports/*/report.json``)
and lists every candidate refused by the held-out test alone (``checks.heldout`` false, every
other check true), with its label (true / wrong effect), held-out RMS before -> after, the
paired z from ``why_not``, its delta BIC, and the delta BIC of the case's best accepted single
(a candidate that passes the held-out test is the selected single only if its BIC is lower).

``case`` rebuilds a candidate's held-out residuals as ``fit.judge.evaluate_candidate`` forms
them (the analyzer's own problem, ``pipeline.front(paths).det.problem``; each fold refitted
from the full fit as there), sample by sample with their channel, run and the replay's
uncertainty, and computes with d = a^2 - b^2 (a, b the held-out residuals after / before, in
floors, deflated as ``Problem.residual``) and D = a - b (the update's change):

- ``z_cur``: ``fit.judge.paired_better`` (sd(d) / sqrt(n_eff), n_eff the AR(1) count of the
  concatenated after residual);
- ``z_noise``: the variance of mean(d) that the noise alone gives under the fixed design: with
  b = s + e (s the nominal model's systematic misfit, e the noise, sd 1 floor after deflation
  or less) and D fixed by the fold's fit (fitted on the other runs, independent of the held-out
  noise), d = 2 D s + D^2 + 2 D e, so var(mean d) = 4 sum_ij D_i D_j cov(e_i, e_j) / n^2,
  taken per segment (one channel of one run) as sum D_i^2 (1 + rho) / (1 - rho), rho the lag-1
  correlation of the segment's after residual (0 .. 0.995);
- ``z_noise_a``: the same with the noise variance max(1, a_i^2) (a misfit left counted as noise:
  an-z29-rule's form);
- ``z_seg``: the same with each segment's noise variance its after residual's mean square (a
  misfit left counted as noise, averaged over the segment; below 1 where the residual is);
- ``z_hac``: Newey-West (Bartlett, lag floor(4 (n/100)^(2/9))) per segment of D_i a_i, |a_i|
  floored at 1, uncentred;
- ``z_noise_tol``: z_noise's error and the tolerance's coherent share in quadrature, 2 mean(|D| u),
  u the replay's uncertainty (``Channel.unc``) deflated like the residual (the per-channel veto's
  bound, HELDOUT_RULE);
- per held-out run: mean d, its noise-only z; over the runs a t (k - 1 df) of the runs' mean d
  and Stouffer's sum of the runs' noise-only z over sqrt(k).

``summary`` prints the JSON lines ``case`` appended.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import re
import sys

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
sys.path.insert(0, ROOT)
SCORE = "/work/wt/score-data"


def _sets(spec: str) -> list[int]:
    a, _, b = spec.partition("-")
    return list(range(int(a), int(b or a) + 1))


def survey(sets: list[int]) -> None:
    n_all = 0
    for n in sets:
        for rp in sorted(glob.glob(f"{SCORE}/heldback{n}/reports/*/report.json")):
            case = rp.split("/")[-2]
            r = json.load(open(rp))
            lab = json.load(open(f"{SCORE}/heldback{n}/labels/{case}.json"))
            true = set(lab.get("true_effects", []))
            acc = [c for c in r["candidates"] if c.get("accepted") and "+" not in c["effect"]]
            best = min((c["delta_bic"] for c in acc), default=math.nan)
            for c in r["candidates"]:
                ch = c.get("checks", {})
                if ch.get("heldout") is not False or not all(v for k, v in ch.items()
                                                              if k != "heldout"):
                    continue
                n_all += 1
                effs = set(c["effect"].split("+"))
                z = next((float(m.group(1)) for w in c.get("why_not", [])
                          for m in [re.search(r"paired z ([-\d.]+)", w)] if m), math.nan)
                b, a = c["heldout_rmse_before"], c["heldout_rmse_after"]
                kind = "TRUE" if effs <= true else ("part" if effs & true else "wrong")
                wins = "-" if math.isnan(best) else ("BIC<best" if c["delta_bic"] < best
                                                     else "BIC>best")
                print(f"{case:32s} {c['effect']:22s} {kind:5s} {b:7.3g} -> {a:<7.3g} "
                      f"{a / b:5.2f}  z {z:5.2f}  dBIC {c['delta_bic']:8.1f}  best acc "
                      f"{best:8.1f} {wins:8s} verdict {r['verdict']:12s} expect "
                      f"{lab.get('expect')}")
    print(f"{n_all} candidates refused by the held-out test alone")


def _rho(v: np.ndarray) -> float:
    if v.size < 3:
        return 0.0
    x, y = v[:-1] - v.mean(), v[1:] - v.mean()
    den = float(np.sqrt(np.sum(x * x) * np.sum(y * y)))
    return min(max(0.0 if den == 0 else float(np.sum(x * y) / den), 0.0), 0.995)


def _newey_west(x: np.ndarray) -> float:
    """Long-run variance of sum(x) (uncentred, Bartlett weights, lag floor(4 (n/100)^(2/9)))."""
    n = x.size
    if n == 0:
        return 0.0
    lag = min(int(4 * (n / 100.0) ** (2.0 / 9.0)), n - 1)
    v = float(np.sum(x * x))
    for j in range(1, lag + 1):
        v += 2 * (1 - j / (lag + 1)) * float(np.sum(x[j:] * x[:-j]))
    return v


def _labelled(pb, effects, runs):
    """Problem.residual's samples of ``runs``: (run, channel, residual in floors, deflated
    replay uncertainty in floors), in Problem.residual's order."""
    out = []
    for i, chans in zip(runs, pb.sim_channels(effects, runs, False, fit_only=True)):
        for c in pb.fit_channels:
            ch = chans.get(c)
            if ch is None:
                continue
            f = pb.floors[c]
            r = ch.deflated(f) / f
            tu = ch.total_unc
            u = (np.zeros(r.size) if ch.unc is None
                 else np.abs(ch.unc) / np.sqrt(f ** 2 + (tu if tu is not None else 0.0) ** 2))
            out.append((i, c, np.where(np.isfinite(r), r, 1e6), np.where(np.isfinite(u), u, 0.0)))
        for d, _t in pb.slip_differences(chans):
            out.append((i, "slip_diff", np.where(np.isfinite(d), d, 1e6), np.zeros(d.size)))
    return out


def stats(segs_b, segs_a) -> dict:
    from host_tools.analyzer.fit.judge import paired_better
    b = np.concatenate([s[2] for s in segs_b])
    a = np.concatenate([s[2] for s in segs_a])
    ok, z_cur = paired_better(b, a)
    d = a ** 2 - b ** 2
    n = d.size
    var1 = vara = vseg = 0.0
    tol = 0.0
    hac = 0.0
    per_run: dict[int, list[float]] = {}
    for (i, c, rb, u), (_, _, ra, _) in zip(segs_b, segs_a):
        D = ra - rb
        k = (1 + _rho(ra)) / (1 - _rho(ra))
        v1 = float(np.sum(D ** 2)) * k
        var1 += v1
        vara += float(np.sum(D ** 2 * np.maximum(1.0, ra ** 2))) * k
        vseg += v1 * float(np.mean(ra ** 2))
        tol += float(np.sum(np.abs(D) * u))
        hac += _newey_west(D * np.maximum(1.0, np.abs(ra)) * np.sign(ra))
        e = per_run.setdefault(i, [0.0, 0.0, 0])
        e[0] += float(np.sum(ra ** 2 - rb ** 2))
        e[1] += v1
        e[2] += ra.size
    m = float(np.mean(d))
    se1 = 2 * math.sqrt(var1) / n
    sea = 2 * math.sqrt(vara) / n
    set_ = 2 * tol / n
    runs = {}
    for i, (s, v, cnt) in sorted(per_run.items()):
        runs[i] = {"n": cnt, "mean_d": s / cnt, "z_noise": -s / (2 * math.sqrt(v)) if v else math.nan}
    md = [r["mean_d"] for r in runs.values()]
    kk = len(md)
    t_runs = (-float(np.mean(md)) / (float(np.std(md, ddof=1)) / math.sqrt(kk))
              if kk > 1 and np.std(md) > 0 else math.nan)
    stouffer = float(np.nansum([r["z_noise"] for r in runs.values()]) / math.sqrt(kk))
    return {"n": n, "rms_b": math.sqrt(float(np.mean(b ** 2))), "rms_a": math.sqrt(float(np.mean(a ** 2))),
            "mean_d": m, "sd_d": float(np.std(d, ddof=1)), "rms_D": math.sqrt(float(np.mean((a - b) ** 2))),
            "z_cur": z_cur, "z_noise": -m / se1 if se1 else math.nan,
            "z_noise_a": -m / sea if sea else math.nan,
            "z_noise_tol": -m / math.hypot(se1, set_) if se1 or set_ else math.nan,
            "z_seg": -m / (2 * math.sqrt(vseg) / n) if vseg > 0 else math.nan,
            "z_hac": -m / (2 * math.sqrt(hac) / n) if hac > 0 else math.nan,
            "se_noise": se1, "se_tol": set_, "runs": runs, "t_runs": t_runs, "k": kk,
            "stouffer_noise": stouffer}


def case(path: str, effects: list[str], out: str | None, ref: str | None = None) -> None:
    from host_tools.analyzer import pipeline as pl
    from host_tools.analyzer.fit.judge import heldout_folds
    paths = sorted(os.path.join(path, d) for d in os.listdir(path)
                   if os.path.exists(os.path.join(path, d, "meta.json")))
    pb = pl.front(paths).det.problem
    runs = list(range(len(pb.preps)))
    for eff in effects:
        names = eff.split("+")
        full = pb.fit(names, runs)
        sb, sa = [], []
        rfull = pb.fit(ref.split("+"), runs) if ref else None
        for train, test, ptrain, _pt in heldout_folds(len(runs)):
            f = pb.fit(names, train, part=ptrain, x0=full.x, max_nfev=25, fixed=full.fixed)
            rp = {}
            if rfull is not None and ref:
                rp = pb.fit(ref.split("+"), train, part=ptrain, x0=rfull.x, max_nfev=25,
                            fixed=rfull.fixed).params
            lb, la = _labelled(pb, rp, test), _labelled(pb, f.params, test)
            for x, y in zip(lb, la):
                if x[2].size == y[2].size and x[1] == y[1]:
                    sb.append(x)
                    sa.append(y)
        s = stats(sb, sa)
        s.update({"case": os.path.basename(path.rstrip("/")), "effect": eff + (f" vs {ref}" if ref else ""),
                  "params": {e: {k: round(v, 6) for k, v in p.items()} for e, p in full.params.items()}})
        print(_line(s), flush=True)
        if out:
            with open(out, "a") as fh:
                fh.write(json.dumps(s) + "\n")


def _line(s: dict) -> str:
    runs = " ".join(f"r{i}:{r['mean_d']:.2f}/{r['z_noise']:.1f}" for i, r in s["runs"].items())
    return (f"{s['case']:32s} {s['effect']:20s} n {s['n']:5d} RMS {s['rms_b']:.3g}->{s['rms_a']:.3g} "
            f"mean d {s['mean_d']:.3g} sd d {s['sd_d']:.3g} rms D {s['rms_D']:.3g} | z_cur "
            f"{s['z_cur']:.2f} z_noise {s['z_noise']:.1f} z_noise_a {s['z_noise_a']:.1f} "
            f"z_noise_tol {s['z_noise_tol']:.2f} z_seg {s.get('z_seg', math.nan):.1f} z_hac {s.get('z_hac', math.nan):.1f} (se {s['se_noise']:.3g}, tol {s['se_tol']:.3g}) "
            f"| runs mean d/z {runs} t_runs {s['t_runs']:.2f} (k {s['k']}) Stouffer "
            f"{s['stouffer_noise']:.1f}")


STATS = ("z_cur", "z_noise", "z_noise_a", "z_seg", "z_hac", "z_noise_tol")


def table(path: str, z: float = 2.33) -> None:
    """The JSON lines of ``case`` against the stored reports and labels: per row its role
    (sel: the report's selected effect(s); ref: a pair against one of its singles; alone: refused
    by the held-out test alone), the label (TRUE: every effect a true one), and how many rows of
    each role pass each statistic at ``z``."""
    rows = [json.loads(ln) for ln in open(path)]
    counts: dict[tuple[str, str], list[int]] = {}
    for s in rows:
        n = int(re.match(r"hb(\d+)_", s["case"]).group(1))
        lab = json.load(open(f"{SCORE}/heldback{n}/labels/{s['case']}.json"))
        rep = json.load(open(f"{SCORE}/heldback{n}/reports/{s['case']}/report.json"))
        true = set(lab.get("true_effects", []))
        eff = s["effect"].split(" vs ")[0]
        sel = "+".join(x["effect"] for x in rep["selected"])
        role = "ref" if " vs " in s["effect"] else ("sel" if eff == sel else "alone")
        kind = "TRUE" if set(eff.split("+")) <= true else "wrong"
        print(f"{role:5s} {kind:5s} {lab.get('expect', ''):12s} " + _line(s))
        c = counts.setdefault((role, kind), [0] * (len(STATS) + 1))
        c[0] += 1
        for j, k in enumerate(STATS):
            c[j + 1] += int(s.get(k, math.nan) > z)
    print(f"rows passing z > {z}: role kind n " + " ".join(STATS))
    for (role, kind), c in sorted(counts.items()):
        print(f"  {role:5s} {kind:5s} {c[0]:4d} " + " ".join(f"{v:{len(k)}d}" for k, v in
                                                          zip(STATS, c[1:])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/heldout_null_variance.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("survey")
    p.add_argument("--sets", default="24-33")
    p = sub.add_parser("case")
    p.add_argument("runs_dir")
    p.add_argument("effects", nargs="+")
    p.add_argument("--out")
    p.add_argument("--ref", help="compare against this effect (fitted on the same folds), not nominal")
    p = sub.add_parser("summary")
    p.add_argument("file")
    a = ap.parse_args(argv)
    if a.cmd == "survey":
        survey(_sets(a.sets))
    elif a.cmd == "case":
        case(a.runs_dir, a.effects, a.out, a.ref)
    else:
        table(a.file)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
