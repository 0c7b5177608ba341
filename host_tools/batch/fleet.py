"""The fleet table (one row per run set) and the fleet report (each robot's fitted parameters
over time, with a drift test).

Table columns: ``set_id, robot, date, name, status, verdict, error, rc, wall_s,
peak_rss_mb, n_runs, selected`` (the selected effects, ``;``-separated), ``mismatch_rms_before``
and ``mismatch_rms_after`` (the report's ``fit.normalized_rms_before/after``: the residual RMS
over the fit channels in units of their noise floors, nominal model and updated model), and
for every parameter any selected effect of the fleet has, ``<effect>.<param>`` and
``<effect>.<param>_std`` (the fit's 1-sigma uncertainty: the report's ``param_std`` of the
selected fit) -- empty where the set did not select that effect.

Drift test (:func:`trend_test`), per robot and parameter, on the days the parameter was
fitted: a weighted straight line through the values, with weights 1 / (sigma_i^2 + tau^2),
where sigma_i is the fit's uncertainty and tau^2 the day-to-day scatter beyond it (a
moment estimate from the residuals about the line, DerSimonian-Laird for a regression); the
slope's variance is scaled by the residuals' chi^2 per degree of freedom when that is above 1
(Knapp-Hartung) and tested against zero with Student's t (n - 2 degrees of freedom).  A
parameter is flagged as drifting when its p-value is below ``alpha`` divided by the number of
series tested (Bonferroni: ``alpha`` is the chance of any false flag in the whole fleet).  The
tolerance is thus the measurements' own: a slope within what the fitted uncertainties and the
scatter between days allow is not flagged, however large it looks in percent.
"""
from __future__ import annotations

import datetime as dt
import math
import os
import re
from typing import Sequence

import numpy as np

#: fewest fitted days a series needs to be tested
MIN_POINTS = 4
#: chance of at least one false drift flag in the whole fleet
ALPHA = 0.01
BASE_COLUMNS = ("set_id", "robot", "date", "name", "status", "verdict", "error", "rc",
                "wall_s", "peak_rss_mb", "n_runs", "selected", "mismatch_rms_before",
                "mismatch_rms_after")


def _selected_params(rec: dict) -> dict[str, tuple[float, float | None]]:
    """{effect.param: (value, std)} of the selected effects of one record's report."""
    rep = rec.get("report") or {}
    out = {}
    for s in rep.get("selected") or []:
        eff = s.get("effect", "")
        cand = next((c for c in rep.get("candidates") or [] if c.get("effect") == eff), {})
        std = cand.get("param_std") or {}
        for k, v in (s.get("params") or {}).items():
            if not isinstance(v, (int, float)):
                continue
            name = k if "." in k else f"{eff}.{k}"  # a pair's keys are effect.param already
            sd = std.get(k)
            out[name] = (float(v), float(sd) if isinstance(sd, (int, float)) else None)
    return out


def rows(records: Sequence[dict]) -> tuple[list[dict], list[str]]:
    """The table's rows and its parameter columns (sorted)."""
    params: set[str] = set()
    out = []
    for rec in records:
        rep = rec.get("report") or {}
        fit = rep.get("fit") or {}
        row = {"set_id": rec.get("set_id"), "robot": rec.get("robot") or "",
               "date": rec.get("date") or "", "name": rec.get("name") or "",
               "status": rec.get("status"), "verdict": rep.get("verdict"),
               "error": rec.get("error"), "rc": rec.get("rc"), "wall_s": rec.get("wall_s"),
               "peak_rss_mb": rec.get("peak_rss_mb"), "n_runs": len(rec.get("runs") or []),
               "selected": ";".join(s.get("effect", "") for s in rep.get("selected") or []),
               "mismatch_rms_before": fit.get("normalized_rms_before"),
               "mismatch_rms_after": fit.get("normalized_rms_after")}
        for name, (v, sd) in _selected_params(rec).items():
            params.add(name)
            row[name], row[f"{name}_std"] = v, sd
        out.append(row)
    return out, sorted(params)


def write_table(records: Sequence[dict], out_dir: str) -> tuple[str, str]:
    """Write ``fleet.parquet`` and ``fleet.csv`` (atomically, each); returns their paths."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    rs, params = rows(records)
    cols: dict[str, pa.Array] = {}
    types = {"rc": pa.int32(), "n_runs": pa.int32(), "wall_s": pa.float64(),
             "peak_rss_mb": pa.float64(), "mismatch_rms_before": pa.float64(),
             "mismatch_rms_after": pa.float64()}
    for c in BASE_COLUMNS:
        cols[c] = pa.array([r.get(c) for r in rs], type=types.get(c, pa.string()))
    for p in params:
        for c in (p, f"{p}_std"):
            cols[c] = pa.array([r.get(c) for r in rs], type=pa.float64())
    table = pa.table(cols)
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for name, write in (("fleet.parquet", lambda t, f: pq.write_table(t, f)),
                        ("fleet.csv", lambda t, f: pacsv.write_csv(t, f))):
        path = os.path.join(out_dir, name)
        tmp = f"{path}.tmp{os.getpid()}"
        write(table, tmp)
        os.replace(tmp, path)
        paths.append(path)
    return paths[0], paths[1]


def trend_test(t: Sequence[float], y: Sequence[float], sigma: Sequence[float | None]) -> dict:
    """Weighted linear trend of ``y`` over ``t`` with per-point 1-sigma ``sigma`` (None: 0)
    and an estimated extra scatter tau (see the module's docstring).  Returns slope, its
    standard error, t statistic, two-sided p-value, tau, intercept, n."""
    from scipy import stats

    t = np.asarray(t, float)
    y = np.asarray(y, float)
    s2 = np.array([0.0 if s is None or not math.isfinite(s) else s * s for s in sigma])
    n = t.size
    if n < 3 or np.ptp(t) == 0:
        return {"n": n, "slope": float("nan"), "se": float("nan"), "t": float("nan"),
                "p": float("nan"), "tau": float("nan"), "intercept": float("nan")}
    X = np.column_stack([np.ones(n), t - t.mean()])
    # a floor under the variances: a reported sigma of 0 must not make one day's weight infinite
    floor = (1e-6 * (np.std(y) or abs(np.mean(y)) or 1.0)) ** 2

    def wls(var):
        w = 1.0 / np.maximum(var, floor)
        XtW = X.T * w
        cov = np.linalg.inv(XtW @ X)
        beta = cov @ (XtW @ y)
        r = y - X @ beta
        return w, cov, beta, r, float(np.sum(w * r * r))

    w, cov, beta, r, Q = wls(s2)
    # DerSimonian-Laird moment estimate of tau^2 for a meta-regression
    W = np.diag(w)
    P = W - W @ X @ cov @ X.T @ W
    tau2 = max(0.0, (Q - (n - 2)) / float(np.trace(P)))
    w, cov, beta, r, Q = wls(s2 + tau2)
    scale = max(1.0, Q / (n - 2))  # Knapp-Hartung
    se = math.sqrt(cov[1, 1] * scale)
    tstat = beta[1] / se if se > 0 else float("inf")
    p = float(2 * stats.t.sf(abs(tstat), n - 2))
    return {"n": n, "slope": float(beta[1]), "se": se, "t": float(tstat), "p": p,
            "tau": math.sqrt(tau2), "intercept": float(beta[0] - beta[1] * t.mean())}


def _day(date: str) -> float | None:
    try:
        return float(dt.date.fromisoformat(date).toordinal())
    except ValueError:
        return None


def drift(records: Sequence[dict], alpha: float = ALPHA, min_points: int = MIN_POINTS
          ) -> list[dict]:
    """One entry per robot and fitted parameter: its series, the trend test, and ``flag``."""
    by: dict[tuple[str, str], list[tuple[float, str, float, float | None]]] = {}
    for rec in records:
        if rec.get("status") != "ok" or not rec.get("robot"):
            continue
        day = _day(rec.get("date") or "")
        if day is None:
            continue
        for name, (v, sd) in _selected_params(rec).items():
            by.setdefault((rec["robot"], name), []).append((day, rec["date"], v, sd))
    series = []
    for (robot, name), pts in sorted(by.items()):
        pts.sort()
        entry = {"robot": robot, "param": name, "dates": [p[1] for p in pts],
                 "t_day": [p[0] for p in pts], "value": [p[2] for p in pts],
                 "std": [p[3] for p in pts], "tested": len(pts) >= min_points}
        if entry["tested"]:
            entry["test"] = trend_test([p[0] - pts[0][0] for p in pts], entry["value"],
                                       entry["std"])
        series.append(entry)
    m = sum(1 for s in series if s["tested"])
    for s in series:
        s["threshold_p"] = alpha / m if m else alpha
        s["flag"] = bool(s["tested"] and s["test"]["p"] < s["threshold_p"])
    return series


def _plot(s: dict, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = s["t_day"][0]
    t = np.array(s["t_day"]) - t0
    y = np.array(s["value"])
    sd = np.array([v if v is not None else 0.0 for v in s["std"]])
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.errorbar(t, y, yerr=2 * sd, fmt="o", color="k", ms=4, capsize=3,
                label="fitted value, ±2σ of the fit")
    if s.get("tested"):
        tt = s["test"]
        line = tt["intercept"] + tt["slope"] * t
        ax.plot(t, line, "-", color="tab:red" if s["flag"] else "tab:blue",
                label=f"trend {tt['slope']:+.3g}/day, p = {tt['p']:.2g}"
                      + (" DRIFT" if s["flag"] else ""))
        if tt["tau"] > 0:
            ax.fill_between(t, line - 2 * tt["tau"], line + 2 * tt["tau"], color="0.85",
                            label="±2τ day-to-day scatter")
    ax.set_xlabel(f"days since {s['dates'][0]}")
    ax.set_ylabel(s["param"])
    ax.set_title(f"{s['robot']}: {s['param']}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text)


def write_report(records: Sequence[dict], out_dir: str, alpha: float = ALPHA,
                 plots: bool = True) -> tuple[str, list[dict]]:
    """Write ``fleet.md`` and ``plots/<robot>__<param>.png``; returns (path, drift series)."""
    series = drift(records, alpha)
    os.makedirs(out_dir, exist_ok=True)
    if plots:
        os.makedirs(os.path.join(out_dir, "plots"), exist_ok=True)
    n_ok = sum(1 for r in records if r.get("status") == "ok")
    flagged = [s for s in series if s["flag"]]
    m = sum(1 for s in series if s["tested"])
    L = ["# Fleet report", "",
         f"{len(records)} run sets, {n_ok} analyzed, {len(records) - n_ok} failed; "
         f"{len({r.get('robot') for r in records})} robots.", "",
         f"Drift test: per robot and fitted parameter with at least {MIN_POINTS} fitted days, "
         "a weighted linear trend against the fits' uncertainties and the day-to-day scatter "
         f"(t test of the slope); flagged when p < {alpha:g} / {max(m, 1)} series "
         f"= {alpha / max(m, 1):.2g} (family-wise false-flag chance {alpha:g}).", "",
         "## Flagged drifts", ""]
    if flagged:
        L += ["| robot | parameter | first | last | slope per day | ±1σ | p |", "|---|---|---|---|---|---|---|"]
        for s in flagged:
            tt = s["test"]
            L.append(f"| {s['robot']} | {s['param']} | {s['value'][0]:.5g} ({s['dates'][0]}) | "
                     f"{s['value'][-1]:.5g} ({s['dates'][-1]}) | {tt['slope']:+.3g} | "
                     f"{tt['se']:.2g} | {tt['p']:.2g} |")
    else:
        L.append("None.")
    L += ["", "## Every robot and parameter", "",
          "| robot | parameter | fitted days | mean | slope per day | ±1σ | τ (scatter) | p | drift |",
          "|---|---|---|---|---|---|---|---|---|"]
    for s in series:
        if s["tested"]:
            tt = s["test"]
            L.append(f"| {s['robot']} | {s['param']} | {tt['n']} | {np.mean(s['value']):.5g} | "
                     f"{tt['slope']:+.3g} | {tt['se']:.2g} | {tt['tau']:.2g} | {tt['p']:.2g} | "
                     f"{'**yes**' if s['flag'] else 'no'} |")
        else:
            L.append(f"| {s['robot']} | {s['param']} | {len(s['value'])} | "
                     f"{np.mean(s['value']):.5g} | - | - | - | - | not tested |")
    quiet = sorted({r.get("robot") for r in records if r.get("status") == "ok"} -
                   {s["robot"] for s in series} - {"", None})
    if quiet:
        L += ["", "No effect selected on any analyzed day (nothing to trend): " +
              ", ".join(quiet) + "."]
    failed = [r for r in records if r.get("status") != "ok"]
    if failed:
        L += ["", "## Failed run sets", "", "| set | status | error |", "|---|---|---|"]
        for r in failed:
            L.append(f"| {r.get('set_id')} | {r.get('status')} | "
                     f"{str(r.get('error') or '').replace('|', '/')[:200]} |")
    if plots:
        L += ["", "## Plots", ""]
        for s in series:
            name = f"{_safe(s['robot'])}__{_safe(s['param'])}.png"
            _plot(s, os.path.join(out_dir, "plots", name))
            L.append(f"![{s['robot']} {s['param']}](plots/{name})")
    path = os.path.join(out_dir, "fleet.md")
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        fh.write("\n".join(L) + "\n")
    os.replace(tmp, path)
    return path, series
