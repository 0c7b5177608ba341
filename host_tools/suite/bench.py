"""Run the analyzer on every suite case and score it against the hidden labels.

Prints the confusion matrix (true effect vs named), parameter errors, false alarms on nulls,
held-out improvement and total time, each with issue 9's target. The analyzer is called as the
acceptance harness calls it: ``python -m host_tools analyze RUN... --out DIR``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from host_tools.suite import cases as C
from host_tools.suite.generate import generate_case

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TARGETS = {"null_ok": 1.0, "named": 0.90, "param": 0.80, "oov_ok": 1.0, "heldout_worse": 0}


def run_analyzer(runs: list[str], out_dir: str, jobs: int = 2, log=None) -> tuple[int, dict | None]:
    cmd = [sys.executable, "-m", "host_tools", "analyze", *runs, "--out", out_dir,
           "--jobs", str(jobs)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if log is not None:
        log.write(proc.stdout + proc.stderr)
    rp = os.path.join(out_dir, "report.json")
    report = None
    if proc.returncode == 0 and os.path.isfile(rp):
        with open(rp) as fh:
            report = json.load(fh)
    elif proc.returncode != 0:
        sys.stderr.write(proc.stderr[-2000:])
    return proc.returncode, report


def _named(report: dict) -> set[str]:
    out = set()
    for s in report.get("selected", []):
        out.add(s.get("effect", ""))
        out.update(s.get("equivalent", []) or [])
    # pairs may be reported as "a+b"
    return {p for e in out for p in e.split("+")}


def _fitted_param(report: dict, effect: str, param: str) -> tuple[float | None, str]:
    """The analyzer's value of ``effect.param``: from the selected effect, else from its own
    candidate fit when it is listed as equivalent to a selected one, else from a pair."""
    for s in report.get("selected", []):
        if s.get("effect") == effect and param in s.get("params", {}):
            return float(s["params"][param]), "selected"
        for k, v in (s.get("params") or {}).items():
            if k == f"{effect}.{param}":
                return float(v), "selected pair"
    if effect in _named(report):
        for c in report.get("candidates", []):
            if c.get("effect") == effect and param in c.get("params", {}):
                return float(c["params"][param]), "equivalent's candidate fit"
    return None, "not named"


def score_case(label: dict, rc: int, report: dict | None) -> dict:
    res = {"case": label["case"], "expect": label["expect"], "rc": rc,
           "true": "+".join(label["true_effects"]) or
           ("+".join(label["effects"]) if label["effects"] else "null"),
           "verdict": report.get("verdict") if report else f"error (exit {rc})",
           "selected": [s.get("effect") for s in (report or {}).get("selected", [])],
           "named": sorted(_named(report)) if report else []}
    if label["expect"] == "no_mismatch":
        res["ok"] = res["verdict"] == "no_mismatch"
    elif label["expect"] == "unexplained":
        res["ok"] = res["verdict"] == "unexplained"
    else:
        truth = set(label["true_effects"])
        res["named_all"] = truth <= set(res["named"])
        res["named_any"] = bool(truth & set(res["named"]))
        res["ok"] = res["named_all"]
        mp = label["main_param"]
        val, how = _fitted_param(report or {}, mp["effect"], mp["param"])
        res["param"] = {"effect": mp["effect"], "name": mp["param"], "true": mp["value"],
                        "fitted": val, "how": how}
        if val is not None:
            res["param"]["rel_err_value"] = abs(val - mp["value"]) / abs(mp["value"])
            dev = mp["value"] - mp["nominal"]
            res["param"]["rel_err_deviation"] = abs((val - mp["nominal"]) - dev) / abs(dev)
    if report:
        fit = report.get("fit", {})
        before, after = fit.get("heldout_rmse_before", {}), fit.get("heldout_rmse_after", {})
        ratios = {ch: after[ch] / before[ch] for ch in before if ch in after and before[ch] > 0}
        res["heldout_worst_ratio"] = max(ratios.values()) if ratios else None
        floor = fit.get("noise_floor", {})
        chans = [ch for ch in ratios if floor.get(ch, 0) > 0]
        if chans:  # all channels together, each in units of its noise floor
            nb = sum((before[ch] / floor[ch]) ** 2 for ch in chans) / len(chans)
            na = sum((after[ch] / floor[ch]) ** 2 for ch in chans) / len(chans)
            res["heldout_overall_ratio"] = (na / nb) ** 0.5 if nb > 0 else None
        # "never worse", channel by channel, on the values as the report states them: any
        # increase counts (no tolerance)
        res["heldout_worse_channels"] = sorted(ch for ch in before if ch in after and
                                               after[ch] > before[ch])
        res["elapsed_s"] = report.get("elapsed_s")
    return res


def collect(data_dir: str, case_list: list, rescore: bool = False) -> list[dict]:
    """The scores of earlier bench runs (reports/<case>/score.json) for these cases; with
    ``rescore``, scored again from the stored report.json and label (scorer changes)."""
    out = []
    for c in case_list:
        p = os.path.join(data_dir, "reports", c.name, "score.json")
        if not os.path.isfile(p):
            raise FileNotFoundError(f"{p}: case {c.name} was not benchmarked yet")
        with open(p) as fh:
            r = json.load(fh)
        if rescore:
            rp = os.path.join(data_dir, "reports", c.name, "report.json")
            report = None
            if r.get("rc") == 0 and os.path.isfile(rp):
                with open(rp) as fh:
                    report = json.load(fh)
            with open(os.path.join(data_dir, "labels", f"{c.name}.json")) as fh:
                label = json.load(fh)
            r = dict(score_case(label, r.get("rc", 1), report), case_s=r.get("case_s", 0.0))
            with open(p, "w") as fh:
                json.dump(r, fh, indent=2)
        out.append(r)
    return out


def summarize(results: list[dict], total_s: float) -> tuple[str, dict]:
    L = []
    nulls = [r for r in results if r["expect"] == "no_mismatch"]
    effs = [r for r in results if r["expect"] == "explained"]
    oovs = [r for r in results if r["expect"] == "unexplained"]
    # confusion matrix: true label -> what the analyzer said
    L.append("confusion (true -> analyzer: verdict [named effects])")
    w = max(len(r["case"]) for r in results)
    for r in results:
        said = r["verdict"] + (" " + ",".join(r["selected"]) if r["selected"] else "")
        extra = ""
        if r.get("named") and set(r["named"]) - set(r["selected"]):
            extra = f" (equivalent: {','.join(sorted(set(r['named']) - set(r['selected'])))})"
        L.append(f"  {'OK ' if r['ok'] else 'MISS'} {r['case']:<{w}}  -> {said}{extra}")
    # compact matrix over effect names
    labels = sorted({e for r in effs for e in r.get("named", [])} | {"no_mismatch", "unexplained"})
    L.append("")
    L.append("confusion matrix: true effect(s) -> counts of what the analyzer named (selected or "
             "equivalent; the verdict when nothing is named)")
    by_true: dict[str, dict[str, int]] = {}
    for r in results:
        t = r.get("true") or r["case"]
        row = by_true.setdefault(t, {})
        keys = r.get("named") or [r["verdict"]]
        if r["verdict"] in ("no_mismatch", "unexplained"):
            keys = [r["verdict"]]
        for k in keys:
            row[k] = row.get(k, 0) + 1
    for t, row in sorted(by_true.items()):
        L.append(f"  {t:<28} " + ", ".join(f"{k}: {v}" for k, v in sorted(row.items())))
    # figures against targets
    m = {}
    m["null_ok"] = sum(r["ok"] for r in nulls) / max(1, len(nulls))
    m["named"] = sum(r.get("named_all", False) for r in effs) / max(1, len(effs))
    m["named_any"] = sum(r.get("named_any", False) for r in effs) / max(1, len(effs))
    perr = [r["param"].get("rel_err_deviation") for r in effs]
    perr_v = [r["param"].get("rel_err_value") for r in effs]
    m["param"] = sum(1 for e in perr if e is not None and e <= 0.25) / max(1, len(effs))
    m["param_value"] = sum(1 for e in perr_v if e is not None and e <= 0.25) / max(1, len(effs))
    m["oov_ok"] = sum(r["ok"] for r in oovs) / max(1, len(oovs))
    m["heldout_worse"] = sum(1 for r in results if r.get("heldout_worse_channels"))
    m["heldout_worse_overall"] = sum(1 for r in results
                                     if (r.get("heldout_overall_ratio") or 0) > 1.001)
    L.append("")
    L.append("parameter errors (main parameter; error of the deviation from nominal, and of the value)")
    for r in effs:
        p = r["param"]
        if p["fitted"] is None:
            L.append(f"  {r['case']:<{w}} {p['effect']}.{p['name']}: true {p['true']:.4g}, not fitted ({p['how']})")
        else:
            L.append(f"  {r['case']:<{w}} {p['effect']}.{p['name']}: true {p['true']:.4g}, fitted "
                     f"{p['fitted']:.4g} ({p['how']}); deviation err {100 * p['rel_err_deviation']:.0f} %, "
                     f"value err {100 * p['rel_err_value']:.1f} %")
    L.append("")
    L.append("held-out error after/before: all channels (RMS in noise floors) and the worst channel")
    for r in results:
        if r.get("heldout_worst_ratio") is not None:
            L.append(f"  {r['case']:<{w}} {r.get('heldout_overall_ratio') or float('nan'):.3f}  "
                     f"worst {r['heldout_worst_ratio']:.3f}"
                     + (f"  WORSE: {','.join(r['heldout_worse_channels'])}" if r["heldout_worse_channels"] else ""))
    L.append("")
    L.append(f"{'figure':<52} {'measured':>10} {'target':>10}")
    m["false_alarms"] = sum(1 for r in nulls if not r["ok"])
    rows = [("nulls giving no_mismatch", f"{100 * m['null_ok']:.0f} %", "100 %", m["null_ok"] >= 1.0),
            ("false alarms on nulls", f"{m['false_alarms']}/{len(nulls)}", "0", m["false_alarms"] == 0),
            ("effect cases naming every true effect (sel./equiv.)", f"{100 * m['named']:.0f} %", ">= 90 %", m["named"] >= 0.9),
            ("effect cases naming at least one true effect", f"{100 * m['named_any']:.0f} %", "—", True),
            ("main parameter within 25 % (deviation from nominal)", f"{100 * m['param']:.0f} %", ">= 80 %", m["param"] >= 0.8),
            ("main parameter within 25 % (value)", f"{100 * m['param_value']:.0f} %", "—", True),
            ("out-of-vocabulary cases giving unexplained", f"{100 * m['oov_ok']:.0f} %", "100 %", m["oov_ok"] >= 1.0),
            ("cases whose held-out error got worse (all channels)", f"{m['heldout_worse_overall']}", "0", m["heldout_worse_overall"] == 0),
            ("cases with a channel whose held-out error got worse", f"{m['heldout_worse']}", "0", m["heldout_worse"] == 0)]
    for name, val, tgt, ok in rows:
        L.append(f"{name:<52} {val:>10} {tgt:>10}  {'met' if ok else 'MISSED'}")
    L.append(f"cases: {len(results)} ({len(nulls)} nulls, {len(effs)} effect, {len(oovs)} outside the "
             f"vocabulary); total time {total_s:.0f} s")
    m["total_s"] = total_s
    return "\n".join(L), m


def bench(data_dir: str, case_list: list, jobs: int = 2, regenerate: bool = True,
          out=print) -> tuple[list[dict], dict, str]:
    t0 = time.time()
    results = []
    for i, case in enumerate(case_list):
        tc = time.time()
        run_root = os.path.join(data_dir, "runs", case.name)
        if regenerate or not os.path.isdir(run_root):
            runs = generate_case(case, data_dir, overwrite=True)
        else:
            runs = sorted(os.path.join(run_root, d) for d in os.listdir(run_root))
        with open(os.path.join(data_dir, "labels", f"{case.name}.json")) as fh:
            label = json.load(fh)
        rep_dir = os.path.join(data_dir, "reports", case.name)
        os.makedirs(rep_dir, exist_ok=True)
        with open(os.path.join(rep_dir, "analyzer.log"), "w") as log:
            rc, report = run_analyzer(runs, rep_dir, jobs=jobs, log=log)
        r = score_case(label, rc, report)
        r["case_s"] = time.time() - tc
        with open(os.path.join(rep_dir, "score.json"), "w") as fh:
            json.dump(r, fh, indent=2)
        results.append(r)
        out(f"[{i + 1}/{len(case_list)}] {case.name}: {'OK' if r['ok'] else 'MISS'} "
            f"verdict {r['verdict']} named {r['named']} ({r['case_s']:.0f} s)")
    text, m = summarize(results, time.time() - t0)
    with open(os.path.join(data_dir, "bench.json"), "w") as fh:
        json.dump({"results": results, "metrics": m}, fh, indent=2)
    with open(os.path.join(data_dir, "bench.txt"), "w") as fh:
        fh.write(text + "\n")
    return results, m, text
