"""Measurement: the size test's figures (``fit/judge.significant_deviation``, SIZE_RULE) for the
friction-like candidates of finished analyses: how far the fitted deviation lies beyond the
allowance for the normal forces' left-out physics, against the threshold the test uses
(``judge.size_threshold``: the one-sided 1 % point of the fit's normal error plus the nominal
parameter's uniform one) and the one it used before (2.33 x sqrt(sigma^2 + tol^2/3)), and what a
statistical combination of the allowance itself would give (docs/analyzer.md, "Which data each
rule was settled on", the size threshold's row).

For every ``friction_coefficient``, ``stribeck`` and ``load_transfer`` candidate of every
report given (a suite ``--out`` directory's ``reports/<case>/report.json``; the case's
``runs/<case>/run-0/meta.json`` gives the nominal robot) it prints, per judged parameter (μs and
μk = (μk/μs)·μs of the friction fit, μk0 of Stribeck, h of the load transfer):

  dev          fitted value - nominal value (also of the fitted coordinate mu_k/mu_s, whose
               tolerance is propagated from both and which has no left-out range)
  parts        the allowance's parts (``effects.left_out_ranges``: the wheels' mass, the centre
               of mass's height, the spin share), each (lo, hi)
  [lo, hi]     their sum (the allowance)
  sd, tol      the fit's 1-sigma (an unidentified μs: 0, as the judge takes it) and params.json's
               tolerance (0.006 for μs, μk; 0 for h)
  beyond       |dev| beyond [lo, hi]
  thr          size_threshold(sd, tol): the test counts beyond > thr
  thr_old      2.33 x sqrt(sd^2 + tol^2/3), the threshold before (z_now = beyond / its sigma)
  z_gum        |dev - sum(mid)| / sqrt(sd^2 + tol^2/3 + sum(width^2/12)): every part of the
               allowance taken as the uniform distribution the tolerance ensemble draws it from,
               combined in quadrature (measured, not adopted: it drops the premise that any
               robot inside the allowance is no evidence -- the planar corner, all parts at
               their low ends, would count at z 2.5)
  limit / limit_old   the smallest downward deviation that counts at the fit's sigma, in % of the
               nominal value

and, for the candidate, whether every other acceptance check passed (``others``), its output
change in noise floors, and the case's verdict and selection.  ``--true`` adds, where the
case's ``score.json`` gives the true value of the judged effect's main parameter, whether the
true deviation itself counts at the fit's sigma (is the effect above the test's detection limit
at all?).

Usage:  .venv/bin/python bench/analyzer/size_allowance.py OUT_DIR [OUT_DIR ...] [--cases a,b]
        [--effects friction_coefficient,stribeck,load_transfer] [--changed] [--true]
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import sys
from typing import Any, Mapping, Sequence

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools import params as P  # noqa: E402
from host_tools.analyzer import effects as fx  # noqa: E402
from host_tools.analyzer.fit.judge import SIZE_Z, size_threshold  # noqa: E402

PART_NAMES = ("wheels' mass", "c.o.m. height", "spin share")


def figures(dev: float, sd: float | None, tol: float,
            parts: Sequence[tuple[float, float]]) -> dict[str, Any]:
    """The size test's figures for one judged parameter (see the module's docstring)."""
    s_fit = sd if sd is not None and math.isfinite(sd) else 0.0
    lo = sum(min(a, b) for a, b in parts)
    hi = sum(max(a, b) for a, b in parts)
    beyond = dev - hi if dev > hi else (lo - dev if dev < lo else 0.0)
    s = math.hypot(s_fit, tol / math.sqrt(3.0))
    z_now = beyond / s if s > 0 else (math.inf if beyond > 0 else 0.0)
    mid = sum((a + b) / 2.0 for a, b in parts)
    var = sum((b - a) ** 2 / 12.0 for a, b in parts)
    s_gum = math.sqrt(s * s + var)
    z_gum = abs(dev - mid) / s_gum if s_gum > 0 else (math.inf if dev != mid else 0.0)
    thr = size_threshold(s_fit, tol)
    return {"dev": dev, "parts": [(float(a), float(b)) for a, b in parts], "lo": lo, "hi": hi,
            "sd": s_fit, "tol": tol, "beyond": beyond, "thr": thr, "thr_old": SIZE_Z * s,
            "pass": beyond > thr and dev != 0.0, "pass_old": beyond > SIZE_Z * s and dev != 0.0,
            "z_now": z_now, "z_gum": z_gum, "limit": lo - thr, "limit_old": lo - SIZE_Z * s}


def judged(cand: Mapping[str, Any], meta: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """The judged parameters of a single friction-like candidate, as ``judge.judge`` takes
    them."""
    e, p = cand["effect"], cand["params"]
    st = cand.get("param_std") or {}
    r = meta["robot"]
    tol_mu = float(P.TOLERANCES[("robot", "mu_s")])
    tol_muk = float(P.TOLERANCES[("robot", "mu_k")])
    out: dict[str, dict[str, Any]] = {}
    if e == "friction_coefficient":
        out["mu_s"] = figures(p["mu_s"] - r["mu_s"], st.get("mu_s"), tol_mu,
                              fx.left_out_ranges(e, "mu_s", meta))
        sr = st.get("mu_k_over_mu_s")
        # the fitted coordinate mu_k/mu_s: its tolerance propagated, no left-out range
        out["mu_k_over_mu_s"] = figures(p["mu_k"] / p["mu_s"] - r["mu_k"] / r["mu_s"], sr,
                                        fx._ratio_tol(meta), ())
        # mu_k = ratio * mu_s: its sigma the ratio's times mu_s (judged_sets' slope)
        out["mu_k"] = figures(p["mu_k"] - r["mu_k"], None if sr is None else p["mu_s"] * sr,
                              tol_muk, fx._friction_left_out("mu_k")(meta))
    elif e == "stribeck":
        out["mu_k0"] = figures(p["mu_k0"] - r["mu_k"], st.get("mu_k0"), tol_muk,
                               fx.left_out_ranges(e, "mu_k0", meta))
    elif e == "load_transfer":
        parts = fx.left_out_ranges(e, "h", meta)
        if cand.get("nuisance"):
            parts = parts[:1]   # a kept spin share takes its range out (left_out_ranges)
        out["h"] = figures(p["h"] - r["h"], st.get("h"), 0.0, parts)
    return out


def cases_of(out_dir: str, only: set[str] | None) -> list[tuple[str, str, str]]:
    rows = []
    for rep in sorted(glob.glob(os.path.join(out_dir, "reports", "*", "report.json"))):
        case = os.path.basename(os.path.dirname(rep))
        if only and case not in only:
            continue
        metas = sorted(glob.glob(os.path.join(out_dir, "runs", case, "run-*", "meta.json")))
        if metas:
            rows.append((case, rep, metas[0]))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dirs", nargs="+")
    ap.add_argument("--cases", default="")
    ap.add_argument("--effects", default="friction_coefficient,stribeck,load_transfer")
    ap.add_argument("--changed", action="store_true",
                    help="only candidates whose other checks all pass and whose size verdict "
                         "the two thresholds give differently")
    ap.add_argument("--true", action="store_true")
    a = ap.parse_args(argv)
    only = {c for c in a.cases.split(",") if c} or None
    effects = {e for e in a.effects.split(",") if e}
    for out_dir in a.out_dirs:
        for case, rep, meta_path in cases_of(out_dir, only):
            R = json.load(open(rep))
            meta = json.load(open(meta_path))
            sc_path = os.path.join(os.path.dirname(rep), "score.json")
            S = json.load(open(sc_path)) if os.path.exists(sc_path) else {}
            sel = [s if isinstance(s, str) else s.get("effect", "?")
                   for s in R.get("selected", [])]
            head = f"{case} [{S.get('true', '?')}] {R['verdict']} selected={','.join(sel) or '-'}"
            printed = False
            for c in R.get("candidates", []):
                if c["effect"] not in effects:
                    continue
                J = judged(c, meta)
                if not J:
                    continue
                others = all(v for k, v in c["checks"].items() if k != "size")
                pass_new = any(j["pass"] for j in J.values())
                pass_old = any(j["pass_old"] for j in J.values())
                if a.changed and not (others and pass_new != pass_old):
                    continue
                if not printed:
                    print(head)
                    printed = True
                print(f"  {c['effect']}: {c['params']} size={pass_new} (before: {pass_old})"
                      f" others={others} output={c.get('output_change_noise_floors')} floors,"
                      f" held-out {c['heldout_rmse_before']} -> {c['heldout_rmse_after']}")
                for name, j in J.items():
                    nom = (meta["robot"]["mu_s"] if name == "mu_s" else
                           meta["robot"]["h"] if name == "h" else
                           meta["robot"]["mu_k"] / meta["robot"]["mu_s"]
                           if name == "mu_k_over_mu_s" else meta["robot"]["mu_k"])
                    names = PART_NAMES[1:] if name == "h" else PART_NAMES
                    parts = ", ".join(f"{n} [{lo:+.5f}, {hi:+.5f}]"
                                      for n, (lo, hi) in zip(names, j["parts"]))
                    print(f"    {name}: dev {j['dev']:+.5f} ({100 * j['dev'] / nom:+.1f} %), "
                          f"allowance [{j['lo']:+.5f}, {j['hi']:+.5f}] = {parts}; "
                          f"sd {j['sd']:.5f} tol {j['tol']}; beyond {j['beyond']:.5f} against "
                          f"{j['thr']:.5f} (before {j['thr_old']:.5f}, z {j['z_now']:.2f}); "
                          f"z_gum {j['z_gum']:.2f}; at this sigma it counts below "
                          f"{j['limit']:+.5f} ({100 * j['limit'] / nom:+.1f} %; before "
                          f"{100 * j['limit_old'] / nom:+.1f} %)")
                tp = S.get("param") or {}
                if a.true and tp.get("effect") == c["effect"] and tp.get("true") is not None:
                    name = tp["name"]
                    jt = dict(J.get(name) or {})
                    if jt:
                        nom = meta["robot"].get(name, meta["robot"].get("mu_k"))
                        t = figures(float(tp["true"]) - float(nom), jt["sd"], jt["tol"],
                                    jt["parts"])
                        print(f"    true {name} {tp['true']}: dev {t['dev']:+.5f}, beyond "
                              f"{t['beyond']:.5f}: counts {t['pass']} (before {t['pass_old']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
