"""Run the analyzer on every suite case and score it against the hidden labels.

Prints the confusion matrix (true effect vs named), parameter errors, false alarms on nulls,
held-out improvement, physically impossible fits, the analysis time and peak memory of the
long runs, and total time, each with its target (``TARGETS``). The analyzer is called as the
acceptance harness calls it: ``python -m host_tools analyze RUN... --out DIR``; its wall time
and the peak resident memory of its process tree (sampled every 0.1 s) are measured.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from typing import Any

from host_tools import _progress, runfmt
from host_tools._stdio import STATUS
from host_tools.suite.generate import generate_case

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: the analyzer's targets (the held-back set's figures are the ones that count, docs/suite.md):
#: shares of cases, the slowest analysis per run length (s; ``long_s`` for lengths not listed in
#: ``time_s``) and the peak memory (MB)
TARGETS = {"null_ok": 1.0, "named": 0.95, "param": 0.90, "oov_ok": 1.0, "impossible": 0,
           "time_s": {"20 s": 30.0}, "long_s": 60.0, "long_mb": 1024.0}


def time_target_s(length: str) -> float:
    """The slowest analysis allowed for runs of ``length`` (s)."""
    return float(TARGETS["time_s"].get(length, TARGETS["long_s"]))
#: analyzer time limit per case: past it the case is stopped and scored as a timeout
DEFAULT_TIMEOUT_S = 300.0

_log = logging.getLogger(__name__)


def _tree_rss_kb(root: int) -> int:
    """Resident memory of a process and all its descendants (kB), from /proc."""
    children: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as fh:
                st = fh.read()
            ppid = int(st[st.rindex(")") + 2:].split()[1])
            with open(f"/proc/{d}/statm") as fh:
                pages = int(fh.read().split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(d))
        rss[int(d)] = pages * (os.sysconf("SC_PAGE_SIZE") // 1024)
    total, todo = 0, [root]
    while todo:
        p = todo.pop()
        total += rss.get(p, 0)
        todo.extend(children.get(p, []))
    return total


def run_analyzer(runs: list[str], out_dir: str, jobs: int = 2, log=None,
                 timeout_s: float | None = None, perf: dict | None = None
                 ) -> tuple[int, dict | None]:
    """Run ``python -m host_tools analyze``; returns (exit code, report) and fills ``perf``
    (when given) with {wall_s, peak_rss_mb, timeout}. The exit code is -9 when it ran past
    ``timeout_s`` and was stopped."""
    cmd = [sys.executable, "-m", "host_tools", "analyze", *runs, "--out", out_dir,
           "--jobs", str(jobs)]
    os.makedirs(out_dir, exist_ok=True)
    rp = os.path.join(out_dir, "report.json")
    if os.path.isfile(rp):
        os.remove(rp)
    err_path = os.path.join(out_dir, ".analyzer.stderr")
    t0 = time.time()
    peak = 0
    timed_out = False
    with open(err_path, "w+") as err, open(os.path.join(out_dir, ".analyzer.stdout"), "w+") as so:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=so, stderr=err, start_new_session=True)
        while proc.poll() is None:
            peak = max(peak, _tree_rss_kb(proc.pid))
            if timeout_s is not None and time.time() - t0 > timeout_s:
                timed_out = True
                os.killpg(proc.pid, signal.SIGKILL)  # the analyzer's own process group
                proc.wait()
                break
            time.sleep(0.1)
        wall = time.time() - t0
        so.seek(0)
        err.seek(0)
        out_text, err_text = so.read(), err.read()
    for f in (err_path, os.path.join(out_dir, ".analyzer.stdout")):
        os.remove(f)
    if log is not None:
        log.write(out_text + err_text)
        if timed_out:
            log.write(f"\nstopped after {timeout_s:g} s (bench time limit)\n")
    rc = -9 if timed_out else proc.returncode
    report = None
    if rc == 0 and os.path.isfile(rp):
        with open(rp) as fh:
            report = json.load(fh)
    elif rc != 0 and not timed_out:
        _log.log(STATUS, "%s", err_text[-2000:].rstrip("\n"))
    if perf is not None:
        perf.update(wall_s=wall, peak_rss_mb=peak / 1024.0, timeout=timed_out)
    return rc, report


def _fits(report: dict) -> list[tuple[str, str, dict]]:
    """(where, effect, {param: value}) of every reported fit, pairs split into their effects."""
    out = []
    for where in ("selected", "candidates"):
        for s in report.get(where, []) or []:
            eff, params = s.get("effect", ""), s.get("params") or {}
            by: dict[str, dict] = {}
            for k, v in params.items():
                e, _, p = k.rpartition(".") if "." in k else (eff, "", k)
                by.setdefault(e, {})[p] = v
            for e, ps in by.items():
                out.append((where, e, ps))
    return out


def impossible_fits(report: dict | None) -> list[str]:
    """Reported fits (selected or candidates) that no physical robot has, by the analyzer's own
    physical ranges (host_tools.analyzer.effects.physically_possible): mu_k > mu_s, negative
    masses, friction, delays or lags, non-positive radii or ratios, non-finite values, a slope
    beyond +-90 degrees."""
    from host_tools.analyzer.effects import physically_possible
    return [f"{where} {eff}.{why}" for where, eff, ps in _fits(report or {})
            for why in physically_possible(eff, ps)]


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
           "length": label.get("length", "short"), "long": label.get("long", False),
           "recorder": label.get("recorder_name", "firmware"),
           "verdict": (report.get("verdict") if report else
                       "timeout" if rc == -9 else f"error (exit {rc})"),
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
        # worse beyond the noise: a channel that measures physics whose held-out error grew by
        # more than the tolerance and significantly (the paired test the report states per
        # channel in fit.heldout_check); derived channels (odometry) excluded
        chk = fit.get("heldout_check", {})
        res["heldout_worse_significant"] = sorted(
            ch for ch, v in chk.items() if isinstance(v, dict) and v.get("worse")
            and not v.get("derived"))
        res["elapsed_s"] = report.get("elapsed_s")
    res["impossible"] = impossible_fits(report)
    return res


class ScoreFileError(ValueError):
    """A stored score, report or label that cannot be used; the message names the file."""


def _read_json_file(path: str) -> Any:
    from host_tools import runfmt

    try:
        text = runfmt.read_text(path, limit=64 << 20)
        return json.loads(text)
    except runfmt.RunFormatError as exc:
        raise ScoreFileError(str(exc)) from None
    except json.JSONDecodeError as exc:
        raise ScoreFileError(f"{runfmt.display(path)}, line {exc.lineno}, character {exc.colno}: "
                             f"invalid JSON: {exc.msg} (re-run the bench for this case)") from None
    except (RecursionError, ValueError) as exc:
        raise ScoreFileError(f"{runfmt.display(path)}: invalid JSON: "
                             f"{'nested too deeply' if isinstance(exc, RecursionError) else exc}") from None


def _checked_score(path: str, r: Any) -> dict:
    """A stored score that summarize() can use (tried on its own), or ScoreFileError."""
    from host_tools import runfmt

    try:
        if not isinstance(r, dict):
            raise TypeError("not a JSON object")
        summarize([r], 0.0)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, ZeroDivisionError) as exc:
        what = f"key {exc}" if isinstance(exc, KeyError) else str(exc)
        raise ScoreFileError(f"{runfmt.display(path)}: not a score of this suite ({type(exc).__name__}: "
                             f"{what}); re-run the bench for this case") from None
    return r


def collect(data_dir: str, case_list: list, rescore: bool = False) -> list[dict]:
    """The scores of earlier bench runs (reports/<case>/score.json) for these cases; with
    ``rescore``, scored again from the stored report.json and label (scorer changes).  A
    stored file that cannot be used raises ScoreFileError naming it, before anything is
    written; the rescored files are then each written beside and renamed into place."""
    from host_tools import runfmt

    out, rewrite = [], []
    for c in case_list:
        p = os.path.join(data_dir, "reports", c.name, "score.json")
        if not os.path.isfile(p):
            raise FileNotFoundError(f"{p}: case {c.name} was not benchmarked yet")
        r = _checked_score(p, _read_json_file(p))
        if rescore:
            rp = os.path.join(data_dir, "reports", c.name, "report.json")
            report = None
            if r.get("rc") == 0 and os.path.isfile(rp):
                report = _read_json_file(rp)
            lp = os.path.join(data_dir, "labels", f"{c.name}.json")
            label = _read_json_file(lp)
            try:
                scored = score_case(label, r.get("rc", 1), report)
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise ScoreFileError(f"{runfmt.display(rp)} or {runfmt.display(lp)}: cannot be "
                                     f"scored ({type(exc).__name__}: {exc})") from None
            r = _checked_score(p, dict(scored, **{k: r[k] for k in ("case_s", "analysis_s", "peak_rss_mb")
                                                  if k in r}))
            rewrite.append((p, r))
        out.append(r)
    for p, r in rewrite:
        runfmt.write_atomic(p, json.dumps(r, indent=2))
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
    # stricter than the target: the verdict is 'explained' and no effect but the true ones is
    # selected (equivalents allowed). An 'unexplained' case that lists a dozen equivalents
    # names the true effect without telling it apart.
    m["named_exact"] = sum(1 for r in effs if r.get("named_all") and r["verdict"] == "explained"
                           and {p for e in r["selected"] for p in (e or "").split("+")}
                           <= set(r["true"].split("+"))) / max(1, len(effs))
    perr = [r["param"].get("rel_err_deviation") for r in effs]
    perr_v = [r["param"].get("rel_err_value") for r in effs]
    m["param"] = sum(1 for e in perr if e is not None and e <= 0.25) / max(1, len(effs))
    m["param_value"] = sum(1 for e in perr_v if e is not None and e <= 0.25) / max(1, len(effs))
    m["oov_ok"] = sum(r["ok"] for r in oovs) / max(1, len(oovs))
    m["heldout_worse"] = sum(1 for r in results if r.get("heldout_worse_channels"))
    m["heldout_worse_significant"] = sum(1 for r in results if r.get("heldout_worse_significant"))
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
    imp = [r for r in results if r.get("impossible")]
    if imp:
        L.append("")
        L.append("physically impossible fits")
        for r in imp:
            L.append(f"  {r['case']:<{w}} " + "; ".join(r["impossible"][:4]) +
                     (f" (+{len(r['impossible']) - 4})" if len(r["impossible"]) > 4 else ""))
    m["impossible"] = len(imp)
    m["impossible_selected"] = sum(1 for r in imp if any(x.startswith("selected") for x in r["impossible"]))
    # analysis time and peak memory by run length (the time targets: ``time_target_s``)
    lengths = [ln for ln in ("20 s", "1 min", "2 min", "10 min") if any(r.get("length") == ln for r in results)]
    if any(r.get("analysis_s") is not None for r in results):
        L.append("")
        L.append("analysis time (wall) and peak memory of the analyzer's process tree, by run length")
        for ln in ["short"] + lengths:
            rs = [r for r in results if r.get("length", "short") == ln and r.get("analysis_s") is not None]
            if rs:
                L.append(f"  {ln:<7} {len(rs):3d} cases: max {max(r['analysis_s'] for r in rs):7.1f} s "
                         f"(median {sorted(r['analysis_s'] for r in rs)[len(rs) // 2]:.1f} s), peak "
                         f"{max(r.get('peak_rss_mb', 0.0) for r in rs):6.0f} MB"
                         + (f", {sum(1 for r in rs if r.get('rc') == -9)} stopped at the time limit"
                            if any(r.get("rc") == -9 for r in rs) else ""))
    L.append("")
    L.append(f"{'figure':<52} {'measured':>10} {'target':>10}")
    m["false_alarms"] = sum(1 for r in nulls if not r["ok"])
    def pct(key, group):  # a share of a group of cases, or "no cases"
        return f"{100 * m[key]:.0f} %" if group else "no cases"
    rows = [("nulls giving no_mismatch", pct("null_ok", nulls), f"{100 * TARGETS['null_ok']:.0f} %",
             m["null_ok"] >= TARGETS["null_ok"] or not nulls),
            ("false alarms on nulls", f"{m['false_alarms']}/{len(nulls)}", "0", m["false_alarms"] == 0),
            ("effect cases naming every true effect (sel./equiv.)", pct("named", effs),
             f">= {100 * TARGETS['named']:.0f} %", m["named"] >= TARGETS["named"] or not effs),
            ("effect cases naming at least one true effect", pct("named_any", effs), "—", True),
            ("  ... explained, only true effects selected", pct("named_exact", effs), "—", True),
            ("main parameter within 25 % (deviation from nominal)", pct("param", effs),
             f">= {100 * TARGETS['param']:.0f} %", m["param"] >= TARGETS["param"] or not effs),
            ("main parameter within 25 % (value)", pct("param_value", effs), "—", True),
            ("out-of-vocabulary cases giving unexplained", pct("oov_ok", oovs), f"{100 * TARGETS['oov_ok']:.0f} %",
             m["oov_ok"] >= TARGETS["oov_ok"] or not oovs),
            ("cases whose held-out error got worse (all channels)", f"{m['heldout_worse_overall']}", "0", m["heldout_worse_overall"] == 0),
            ("cases with a physics channel worse beyond its noise", f"{m['heldout_worse_significant']}", "0", m["heldout_worse_significant"] == 0),
            ("cases with a channel whose held-out error grew at all", f"{m['heldout_worse']}", "—", True),
            ("cases with a physically impossible fit (any reported)", f"{m['impossible']}", "0", m["impossible"] == 0),
            ("  of which in a selected effect", f"{m['impossible_selected']}", "0", m["impossible_selected"] == 0)]
    for ln in lengths:
        rs = [r for r in results if r.get("length") == ln and r.get("analysis_s") is not None]
        if not rs:
            continue
        t_max = max(r["analysis_s"] for r in rs)
        mb_max = max(r.get("peak_rss_mb", 0.0) for r in rs)
        stopped = any(r.get("rc") == -9 for r in rs)
        m[f"time_{ln}"], m[f"mb_{ln}"] = t_max, mb_max
        rows.append((f"{ln} runs: slowest analysis (s)", (">" if stopped else "") + f"{t_max:.0f}",
                     f"<= {time_target_s(ln):.0f}", t_max <= time_target_s(ln) and not stopped))
        rows.append((f"{ln} runs: peak memory (MB)", f"{mb_max:.0f}", f"<= {TARGETS['long_mb']:.0f}",
                     mb_max <= TARGETS["long_mb"]))
    for name, val, tgt, ok in rows:
        L.append(f"{name:<52} {val:>10} {tgt:>10}  {'met' if ok else 'MISSED'}")
    L.append(f"cases: {len(results)} ({len(nulls)} nulls, {len(effs)} effect, {len(oovs)} outside the "
             f"vocabulary); total time {total_s:.0f} s")
    m["total_s"] = total_s
    return "\n".join(L), m


def _case_runs(case, data_dir: str, regenerate: bool) -> list[str]:
    run_root = os.path.join(data_dir, "runs", case.name)
    if regenerate or not os.path.isdir(run_root):
        return generate_case(case, data_dir, overwrite=True)
    return sorted(os.path.join(run_root, d) for d in os.listdir(run_root))


def _bench_dask(data_dir: str, case_list: list, jobs: int, regenerate: bool, out,
                timeout_s: float | None, scheduler: str) -> list[dict]:
    """The cases as one batch (host_tools.batch): on a local Dask cluster of ``jobs`` workers
    (``scheduler`` "local") or on the cluster at the address ``scheduler``."""
    from host_tools.batch.run import run_batch
    from host_tools.batch.sets import RunSet
    sets = [RunSet("", "", c.name, _case_runs(c, data_dir, regenerate)) for c in case_list]
    recs, _ = run_batch(sets, os.path.join(data_dir, "reports"), workers=jobs,
                        scheduler=None if scheduler == "local" else scheduler,
                        timeout_s=timeout_s, redo=True, progress=out)
    results = []
    for case, rec in zip(case_list, recs):
        rp = os.path.join(data_dir, "reports", case.name, "report.json")
        rc = {"timeout": -9, "lost": 1}.get(rec["status"], rec.get("rc"))
        rc = 1 if rc is None else rc
        report = None
        if rc == 0 and os.path.isfile(rp):
            with open(rp) as fh:
                report = json.load(fh)
        with open(os.path.join(data_dir, "labels", f"{case.name}.json")) as fh:
            r = score_case(json.load(fh), rc, report)
        r.update(case_s=rec.get("wall_s"), analysis_s=rec.get("wall_s"),
                 peak_rss_mb=rec.get("peak_rss_mb", 0.0))
        with open(os.path.join(data_dir, "reports", case.name, "score.json"), "w") as fh:
            json.dump(r, fh, indent=2)
        results.append(r)
    return results


def bench(data_dir: str, case_list: list, jobs: int = 2, regenerate: bool = True,
          out=print, timeout_s: float | None = DEFAULT_TIMEOUT_S,
          scheduler: str | None = None) -> tuple[list[dict], dict, str]:
    """``scheduler``: None runs the cases one after the other here; "local" or a Dask
    scheduler's address runs them as one batch (host_tools.batch)."""
    t0 = time.time()
    results = [] if scheduler is None else \
        _bench_dask(data_dir, case_list, jobs, regenerate, out, timeout_s, scheduler)
    bar = _progress.Progress(len(case_list), "suite bench", unit="case", logger=_log, emit=out,
                             show=scheduler is None)
    for i, case in enumerate(case_list if scheduler is None else []):
        tc = time.time()
        runs = _case_runs(case, data_dir, regenerate)
        with open(os.path.join(data_dir, "labels", f"{case.name}.json")) as fh:
            label = json.load(fh)
        rep_dir = os.path.join(data_dir, "reports", case.name)
        os.makedirs(rep_dir, exist_ok=True)
        with open(os.path.join(rep_dir, "analyzer.log"), "w") as log:
            perf: dict = {}
            rc, report = run_analyzer(runs, rep_dir, jobs=jobs, log=log, timeout_s=timeout_s,
                                      perf=perf)
        r = score_case(label, rc, report)
        r["case_s"] = time.time() - tc
        r["analysis_s"] = perf["wall_s"]
        r["peak_rss_mb"] = perf["peak_rss_mb"]
        runfmt.write_atomic(os.path.join(rep_dir, "score.json"), json.dumps(r, indent=2))
        results.append(r)
        bar.step(f"[{i + 1}/{len(case_list)}] {case.name}: {'OK' if r['ok'] else 'MISS'} "
                 f"verdict {r['verdict']} named {r['named']} (analysis {r['analysis_s']:.0f} s, "
                 f"{r['peak_rss_mb']:.0f} MB; case {r['case_s']:.0f} s)")
    bar.close()
    text, m = summarize(results, time.time() - t0)
    runfmt.write_atomic(os.path.join(data_dir, "bench.json"),
                        json.dumps({"results": results, "metrics": m}, indent=2))
    runfmt.write_atomic(os.path.join(data_dir, "bench.txt"), text + "\n")
    return results, m, text
