"""Measurement: the friction single's fit with its creep speed decided (``Problem._fit_creep``)
and with the creep pinned (the nominal model's Coulomb switch), on every friction case of
held-back sets (tuning data once scored).

``python bench/analyzer/friction_creep.py --sets 24-35 [--data /work/wt/score-data] [--out F]``

Each case's stored runs (``DATA/heldbackN/runs/CASE``, labels beside them: the cases whose only
true effect is ``friction_coefficient``) go through the pipeline's front (as ``analyze`` builds
its fit problem); the friction single is fitted both ways on all runs. Printed per case: the
engine (from the case name: ``_mj_`` MuJoCo, ``_tr_`` the truth engine), true mu_s, mu_s and
mu_k without creep, with the creep decided, the kept speed and its grid set, and the error of
the deviation from the nominal mu_s; per engine the count within 25 % of the deviation each way
and the median error of mu_s.  One process, seconds per case (nice it).
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import sys
from pathlib import Path

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, ROOT)


def _sets(spec: str) -> list[int]:
    out: list[int] = []
    for part in spec.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/friction_creep.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", required=True, help="held-back set numbers, e.g. 24-35 or 13,20")
    ap.add_argument("--data", default="/work/wt/score-data",
                    help="folder with heldbackN/{runs,labels} (suite generate's output)")
    ap.add_argument("--out", help="also write one JSON line per case here")
    a = ap.parse_args(argv)
    from host_tools import params as P
    from host_tools.analyzer.effects import CREEP_KEY
    from host_tools.analyzer.fit.params import fitted_nuisance
    from host_tools.analyzer.pipeline import front
    nominal = float(P.ROBOT["mu_s"])
    rows = []
    sink = open(a.out, "a") if a.out else None
    for s in _sets(a.sets):
        d = os.path.join(a.data, f"heldback{s}")
        for lab in sorted(glob.glob(os.path.join(d, "labels", "*.json"))):
            with open(lab) as fh:
                label = json.load(fh)
            if label.get("true_effects") != ["friction_coefficient"]:
                continue
            case = label["case"]
            runs = sorted(str(p) for p in Path(d, "runs", case).iterdir()
                          if (p / "meta.json").is_file())
            problem = front(runs).det.problem
            idx = list(range(len(problem.preps)))
            fit = problem.fit(["friction_coefficient"], idx)
            c_idx = fit.coords.index(("friction_coefficient", CREEP_KEY))
            plain = problem.fit(["friction_coefficient"], idx, fixed={c_idx: 0.0})
            true = float(label["effects"]["friction_coefficient"]["mu_s"])
            f0, f1 = plain.params["friction_coefficient"], fit.params["friction_coefficient"]
            e0 = abs(f0["mu_s"] - true) / abs(nominal - true)
            e1 = abs(f1["mu_s"] - true) / abs(nominal - true)
            nu = fitted_nuisance(fit, "friction_coefficient").get(CREEP_KEY)
            row = {"case": case, "engine": "mujoco" if "_mj_" in case else "truth",
                   "true_mu_s": true, "plain": f0, "creep": f1, "kept": nu,
                   "dev_err_plain": e0, "dev_err_creep": e1}
            rows.append(row)
            kept = (f"v {1e3 * nu['value']:g} mm/s [{1e3 * nu['lo']:g}, {1e3 * nu['hi']:g}]"
                    if nu else "no creep")
            print(f"{case:34s} true {true:.3f}  plain {f0['mu_s']:.4f}/{f0['mu_k']:.4f} "
                  f"({100 * e0:4.0f} %)  creep {f1['mu_s']:.4f}/{f1['mu_k']:.4f} "
                  f"({100 * e1:4.0f} %)  {kept}", flush=True)
            if sink:
                sink.write(json.dumps(row) + "\n")
                sink.flush()
    for eng in ("mujoco", "truth"):
        r = [x for x in rows if x["engine"] == eng]
        if not r:
            continue
        print(f"{eng}: {len(r)} cases, creep kept in {sum(1 for x in r if x['kept'])}; "
              f"mu_s within 25 % of the deviation: plain "
              f"{sum(x['dev_err_plain'] <= 0.25 for x in r)}, creep "
              f"{sum(x['dev_err_creep'] <= 0.25 for x in r)}; median mu_s - true: plain "
              f"{statistics.median(x['plain']['mu_s'] - x['true_mu_s'] for x in r):+.4f}, "
              f"creep {statistics.median(x['creep']['mu_s'] - x['true_mu_s'] for x in r):+.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
