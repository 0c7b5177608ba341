"""Writing the analysis: report.json (mismatch-report/1), report.md, PNG plots and the
updated model-parameter file (ddmodel/1)."""
from __future__ import annotations

import json
import math
import os
from typing import Any, Callable, Mapping

import numpy as np

from host_tools.analyzer.fit.params import fitted_nuisance, is_nuisance, vocabulary_only
from host_tools.analyzer.report import outputs
from host_tools.analyzer.report.sections import REPORT_FORMAT, Analysis
from host_tools.analyzer.report.series import BAND_K, Series
from host_tools.analyzer.signals import round_sig
from host_tools.runfmt import display

# PNG plots of run x channel series at most (report.html shows every one)
MAX_PLOTS = 16


def _finite(obj: Any) -> Any:
    """JSON has no NaN/inf: replace them by None."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (np.floating,)):
        return _finite(float(obj))
    if isinstance(obj, (np.integer,)):
        return int(obj)
    return obj


def report_dict(an: Analysis) -> dict[str, Any]:
    cands = []
    for c in an.candidates:
        entry: dict[str, Any] = {"effect": c.name, "params": {}, "delta_bic": round_sig(c.delta_bic, 5),
                 "heldout_rmse_before": round_sig(c.heldout_before), "heldout_rmse_after":
                     round_sig(c.heldout_after),
                 "accepted": c.accepted, "checks": dict(c.checks), "why_not": c.reasons,
                 "output_change_noise_floors": round_sig(c.output_size),
                 "heldout_per_channel": {ch: {q: (round_sig(x) if isinstance(x, float) else x)
                                              for q, x in v.items()}
                                         for ch, v in c.heldout_per_channel.items()},
                 "param_std": {}, "unidentified": list(c.fit.unidentified)}
        for e, ps in vocabulary_only(c.fit.params).items():
            for k, v in ps.items():
                key = k if len(c.effects) == 1 else f"{e}.{k}"
                entry["params"][key] = round_sig(v, 5)
        # 1-sigma uncertainty of each fitted coordinate (e.g. mu_k_over_mu_s for friction)
        nuis = {e: fitted_nuisance(c.fit, e) for e in c.effects}
        for (e, k), sd in zip(c.fit.coords, c.fit.std):
            if is_nuisance(e, k):
                continue
            key = k if len(c.effects) == 1 else f"{e}.{k}"
            entry["param_std"][key] = round_sig(sd)
        # the fit's nuisance parameters where it kept them (the load transfer's spin share k):
        # not vocabulary parameters, so beside params
        if any(nuis.values()):
            entry["nuisance"] = {(k if len(c.effects) == 1 else f"{e}.{k}"):
                                 {q: round_sig(x, 4) for q, x in v.items()}
                                 for e, d in nuis.items() for k, v in d.items()}
        # the profile set of a coordinate profiled by the fit (mu_s), beside its value
        entry["param_interval"] = {(k if len(c.effects) == 1 else f"{e}.{k}"): interval_entry(iv)
                                   for (e, k), iv in _intervals(c).items()}
        cands.append(entry)
    selected = [dict(s) for s in an.selected]
    chosen = _chosen_intervals(an)
    for s in selected:
        ivs = {k: interval_entry(iv) for (e, k), iv in chosen.items() if e == s["effect"]}
        if ivs:
            s["interval"] = ivs
    rep: dict[str, Any] = _finite({
        "format": REPORT_FORMAT,
        "verdict": an.verdict,
        "mismatch": an.mismatch,
        "selected": selected,
        "candidates": cands,
        "fit": an.fit_table,
        "hint": an.hint,
        "torque_replay_mismatch": an.torque_mismatch,
        "closed_loop": an.closed_loop,
        "recorder": an.recorder,
        "localization": an.localization,
        "notes": an.notes,
        "runs": [display(r.path) for r in an.runs],
        "heldout_rmse_units": "candidates' heldout_rmse_* are normalized: RMS of residual / "
                              "noise floor over the fit channels",
        "elapsed_s": round(an.timing_s, 2),
    })
    return rep


def plot_choice(runs: list[tuple[int, list[Series]]], max_plots: int = MAX_PLOTS) -> list[Series]:
    """The (run, channel) series that get a PNG, in this order: each run's largest mismatch
    first (every run represented), then the largest mismatches of all runs.  A series' size is
    its largest RMS over a mismatch window in noise floors, then its overall RMS in noise floors
    (a run without windows shows the channel closest to leaving its noise)."""
    def size(s: Series) -> tuple[float, float]:
        f = s.floor if s.floor > 0 else 1.0
        return (s.worst_floors(), float(np.sqrt(np.mean(s.resid_nominal ** 2))) / f
                if s.t.size else 0.0)
    ranked = [sorted(series, key=size, reverse=True) for _, series in runs]
    chosen = [r[0] for r in ranked if r][:max_plots]
    rest = sorted((s for r in ranked for s in r[1:]), key=size, reverse=True)
    return chosen + rest[:max(0, max_plots - len(chosen))]


def _png_name(s: Series) -> str:
    return f"{s.run}_{s.channel}.png".replace(os.sep, "_")


def _plots(an: Analysis, staging: str, runs: list[tuple[int, list[Series]]]) -> list[str]:
    """PNG plots (see :func:`plot_choice`) and one x–y path per run."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    for s in plot_choice(runs):
        kind = "closed loop" if s.replay == "closed_loop" else "simulation"
        fig, ax = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True,
                               gridspec_kw={"height_ratios": [2, 1]})
        ax[0].plot(s.t, s.rec, "k.", ms=3, label="recording")
        ax[0].plot(s.t, s.nominal, "-", color="tab:red", lw=1.2, label=f"nominal {kind}")
        ax[1].fill_between(s.t, -s.band, s.band, color="0.85", lw=0,
                           label=f"noise band (±{BAND_K:g} floors)")
        ax[1].plot(s.t, s.resid_nominal, "-", color="tab:red", lw=1, label="nominal residual")
        if s.updated is not None:
            ax[0].plot(s.t, s.updated, "-", color="tab:blue", lw=1.2, label=f"updated {kind}")
            ax[1].plot(s.t, s.resid_updated, "-", color="tab:blue", lw=1,
                       label="updated residual")
        out = s.outside_band()
        if out.any():   # shaded only where the nominal residual leaves its band
            ax[1].fill_between(s.t, -s.band, s.band, where=out, color="tab:orange", alpha=0.5,
                               lw=0, label="outside the band")
        for k, (a, b) in enumerate(s.windows):
            for x in ax:
                x.axvline(a, color="tab:orange", ls="--", lw=0.9,
                          label="mismatch window edges" if (k == 0 and x is ax[0]) else None)
                x.axvline(b, color="tab:orange", ls="--", lw=0.9)
        for k, e in enumerate(s.anchor_edges):
            for x in ax:
                x.axvline(e, color="0.5", ls=":", lw=0.9,
                          label="re-anchored (new replay window)" if (k == 0 and x is ax[0])
                          else None)
        ax[0].set_ylabel(f"{s.channel} [{s.unit}]")
        ax[1].set_ylabel("residual")
        ax[1].set_xlabel("t [s]")
        ax[0].set_title(f"{s.run}: {s.channel} ({len(s.windows)} mismatch windows, largest "
                        f"{s.worst_floors():.3g} noise floors)", fontsize=10)
        ax[0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        ax[1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        fig.tight_layout()
        name = _png_name(s)
        fig.savefig(os.path.join(staging, name), dpi=90)
        plt.close(fig)
        files.append(name)
    for i, series in runs:
        by = {s.channel: s for s in series}
        for xc, yc, what in (("x_m", "y_m", "ground truth"), ("x_odo_m", "y_odo_m", "odometry")):
            if xc in by and yc in by and by[xc].t.size == by[yc].t.size:
                break
        else:
            continue
        x, y = by[xc], by[yc]
        fig, ax = plt.subplots(figsize=(6, 5.5))
        ax.plot(x.rec, y.rec, "k.", ms=2, label=f"recording ({what})")
        ax.plot(x.nominal, y.nominal, "-", color="tab:red", lw=1.2, label="nominal simulation")
        if x.updated is not None and y.updated is not None:
            ax.plot(x.updated, y.updated, "-", color="tab:blue", lw=1.2,
                    label="updated simulation")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"{x.run}: x–y path", fontsize=10)
        ax.legend(fontsize=7, loc="best")
        fig.tight_layout()
        name = f"{x.run}_path.png".replace(os.sep, "_")
        fig.savefig(os.path.join(staging, name), dpi=90)
        plt.close(fig)
        files.append(name)
    return files


VERDICT_MEANS = {
    "no_mismatch": "the recordings agree with the nominal model within their noise: nothing "
                   "needs to be added to the model.",
    "explained": "the recordings disagree with the nominal model beyond their noise, and the "
                 "effects below bring the disagreement back within the noise, also on data "
                 "they were not fitted to.",
    "unexplained": "the recordings disagree with the nominal model beyond their noise, and no "
                   "effect of the vocabulary (alone or in pairs) accounts for it; where it is "
                   "is listed below.",
}


def _intervals(c: Any) -> dict[tuple[str, str], Any]:
    """(effect, parameter) -> the fit's profile set (``FitResult.intervals``) of candidate
    ``c``."""
    return {(key.split(".", 1)[0], key.split(".", 1)[1]): iv
            for key, iv in getattr(c.fit, "intervals", {}).items()}


def _chosen_intervals(an: Analysis) -> dict[tuple[str, str], Any]:
    """The profile sets of the candidate whose effects are the selected ones."""
    want = {s["effect"] for s in an.selected}
    for c in an.candidates:
        if set(c.effects) == want:
            return _intervals(c)
    return {}


def interval_entry(iv: Any) -> dict[str, Any]:
    """report.json's form of a profile set (``fit.params.ProfileInterval``): ``lo``/``hi`` its
    edges (null on the side the data do not bound: ``upper_bound`` gives ``hi`` only, the
    value at most ``hi``; ``lower_bound`` ``lo`` only; ``unbounded`` neither), ``kind``,
    ``level`` (two-sided for ``two_sided``, one-sided for a bound), ``flat`` (the stretch over
    which the cost equals its minimum) and ``possible`` (the range scanned)."""
    lo = None if iv.kind in ("upper_bound", "unbounded") else round_sig(iv.lo, 5)
    hi = None if iv.kind in ("lower_bound", "unbounded") else round_sig(iv.hi, 5)
    return {"lo": lo, "hi": hi, "kind": iv.kind, "level": iv.level,
            "flat": [round_sig(iv.flat[0], 5), round_sig(iv.flat[1], 5)],
            "possible": [round_sig(iv.possible[0], 5), round_sig(iv.possible[1], 5)]}


def interval_text(name: str, e: dict[str, Any]) -> str:
    """report.md's words for :func:`interval_entry`."""
    from host_tools import humanize
    pct = f"{e['level']:.0%}"
    if e["kind"] == "two_sided":
        return f"{humanize.number(e['lo'])} ≤ {name} ≤ {humanize.number(e['hi'])} ({pct})"
    if e["kind"] == "upper_bound":
        return f"{name} ≤ {humanize.number(e['hi'])} ({pct} one-sided)"
    if e["kind"] == "lower_bound":
        return f"{name} ≥ {humanize.number(e['lo'])} ({pct} one-sided)"
    return f"{name} not bounded within {humanize.number(e['possible'][0])}–" \
           f"{humanize.number(e['possible'][1])}"


def _chosen_std(an: Analysis) -> dict[tuple[str, str], float]:
    """1-sigma uncertainty of each selected parameter (the fit's ``param_std``), by (effect,
    parameter), from the candidate whose effects are the selected ones."""
    want = {s["effect"] for s in an.selected}
    for c in an.candidates:
        if set(c.effects) == want:
            return {(e, k): sd for (e, k), sd in zip(c.fit.coords, c.fit.std)
                    if not is_nuisance(e, k)}
    return {}


def _pm(v: float, sd: float | None) -> str:
    from host_tools import humanize
    if sd is None or not math.isfinite(sd):
        return humanize.number(v)
    return f"{humanize.number(v)} ± {humanize.number(sd, 2)}"


def summary_lines(an: Analysis) -> list[str]:
    """report.md's opening, read in ten seconds: the verdict and what it means, the selected
    effects with value ± uncertainty, the ties and the measurement that would separate them."""
    from host_tools import humanize
    ft = an.fit_table or {}
    L = ["# Mismatch report", "", "## Summary", "",
         f"**Verdict: {an.verdict.replace('_', ' ')}** — {VERDICT_MEANS.get(an.verdict, '')}"]
    b, a = ft.get("normalized_rms_before"), ft.get("normalized_rms_after")
    if b is not None:
        L.append("")
        L.append(f"Disagreement in noise floors (normalized RMS over the fit channels, noise = 1): "
                 f"nominal model {humanize.number(b, 3)}"
                 + (f", updated model {humanize.number(a, 3)}." if an.selected and a is not None
                    else "."))
    L.append("")
    std = _chosen_std(an)
    if an.selected:
        L.append("Selected effects (value ± one standard deviation of the fit):")
        L.append("")
        for s in an.selected:
            ps = ", ".join(f"{k} = {_pm(v, std.get((s['effect'], k)))}"
                           for k, v in s["params"].items())
            extra = [f"{k} = {humanize.number(v, 2)}" for (e, k), v in std.items()
                     if e == s["effect"] and k not in s["params"]]
            if extra:
                ps += f" (uncertainty of {', '.join(extra)})"
            if s.get("unidentified"):
                ps += (f"; {', '.join(s['unidentified'])} not identified by these data, kept "
                       "nominal (or the nearest value the data allow)")
            for k, v in (s.get("nuisance") or {}).items():
                ps += (f"; fitted beside it (not a vocabulary parameter): {k} = "
                       f"{_pm(v['value'], v.get('std'))}")
                if "lo" in v and "hi" in v:
                    ps += (f" (of the values tried, {humanize.number(v['lo'])} to "
                           f"{humanize.number(v['hi'])} fit within 95 %)")
            ivs = {k: interval_entry(iv) for (e, k), iv in _chosen_intervals(an).items()
                   if e == s["effect"]}
            if ivs:
                ps += "; profile set: " + ", ".join(interval_text(k, v) for k, v in ivs.items())
            L.append(f"- **{s['effect']}**: {ps or 'no parameter'}")
            for q in s.get("equivalent") or []:
                sep = (s.get("separating_measurement") or {}).get(q) or "not known"
                L.append(f"  - ties with **{q}** on these data (as good by BIC and on held-out "
                         f"data); the measurement that would separate them: {sep}")
            if not s.get("equivalent"):
                L.append("  - no other effect explains these data as well")
        L.append("")
    elif an.verdict != "no_mismatch":
        L += ["No effect is selected.", ""]
    n_w = len(an.mismatch)
    if n_w:
        L.append(f"Mismatch windows: {n_w} (table under Details).")
        L.append("")
    L += ["Runs: " + ", ".join(f"`{r.name}`" for r in an.runs), "",
          "Interactive plots of every run and channel: [report.html](report.html); every sample: "
          "`series/<run>.csv`.", ""]
    return L


def _md(an: Analysis, rep: dict[str, Any], plots: list[str]) -> str:
    L = summary_lines(an) + ["# Details", ""]
    if an.selected:
        L += ["## Selected effects", "", "| effect | parameters | cannot be told apart from | "
              "measurement that would separate them |", "|---|---|---|---|"]
        for s in an.selected:
            ps = ", ".join(f"{k} = {v:g}" for k, v in s["params"].items())
            sep = "; ".join(f"{k}: {v}" for k, v in s.get("separating_measurement", {}).items())
            if s.get("unidentified"):
                ps += f" ({', '.join(s['unidentified'])}: not identified by these data, kept nominal)"
            L.append(f"| {s['effect']} | {ps} | {', '.join(s['equivalent']) or '-'} | "
                     f"{sep or '-'} |")
        L.append("")
    if an.hint:
        L += ["## Hint (sparse regression, not a vocabulary effect)", "",
              f"{an.hint['text']} (R² = {an.hint['r2']})", ""]
    L += ["## Where the mismatch is", ""]
    if an.mismatch:
        L += ["| run | channel | replay | window [s] | rms | noise floor | regime |",
              "|---|---|---|---|---|---|---|"]
        for m in an.mismatch[:60]:
            L.append(f"| {m['run']} | {m['channel']} | {m['replay']} | "
                     f"{m['t_start_s']:.3f}–{m['t_end_s']:.3f} | {m['rms']:.3g} | "
                     f"{m['noise_floor']:.3g} | {m['regime']} |")
        if len(an.mismatch) > 60:
            L.append(f"| … {len(an.mismatch) - 60} more in report.json | | | | | | |")
    else:
        L.append("No significant window: the recordings agree with the nominal model within "
                 "the noise floors below.")
    if an.localization:
        L += ["", "### In time (fit channels merged)", "",
              "| run | span [s] | peak (noise floors) | channels | after the update (noise floors) |",
              "|---|---|---|---|---|"]
        for z in an.localization[:40]:
            aft = z["rms_after_update_noise_floors"]
            L.append(f"| {z['run']} | {z['t_start_s']:.2f}–{z['t_end_s']:.2f} | "
                     f"{z['peak_noise_floors']:.3g} | {', '.join(z['channels'])} | "
                     f"{'-' if aft is None else f'{aft:.3g}'} |")
        if len(an.localization) > 40:
            L.append(f"| … {len(an.localization) - 40} more in report.json | | | | |")
    L += ["", "## Errors before and after (RMSE per channel)", "",
          f"Held-out method: {an.fit_table['heldout_method']}.", "",
          f"Held-out rule: {an.fit_table.get('heldout_rule', '-')}.", "",
          "| channel | noise floor | fit: nominal | fit: updated | held-out: nominal | "
          "held-out: updated | held-out: not worse |", "|---|---|---|---|---|---|---|"]
    ft = an.fit_table
    hc = ft.get("heldout_check", {})
    for c in ft["rmse_before"]:
        g: Callable[[Mapping[str, Any]], str] = lambda d: (f"{d[c]:.4g}" if d.get(c) is not None else "-")  # noqa: E731
        lim = (("worse (derived: no veto)" if hc[c].get("worse") else "ok") if hc[c]["ok"]
               else "WORSE") if c in hc else "-"
        L.append(f"| {c} | {g(ft['noise_floor'])} | {g(ft['rmse_before'])} | "
                 f"{g(ft['rmse_after'])} | {g(ft['heldout_rmse_before'])} | "
                 f"{g(ft['heldout_rmse_after'])} | {lim} |")
    L += ["", "## Candidates (best first)", "",
          "| effect | fitted | ΔBIC | held-out (normalized) before → after | accepted | why not |",
          "|---|---|---|---|---|---|"]
    for c in rep["candidates"]:
        ps = ", ".join(f"{k}={v:.4g}" for k, v in c["params"].items() if v is not None)
        L.append(f"| {c['effect']} | {ps} | {c['delta_bic']:.1f} | "
                 f"{c['heldout_rmse_before']:.3g} → {c['heldout_rmse_after']:.3g} | "
                 f"{'yes' if c['accepted'] else 'no'} | {'; '.join(c['why_not'][:2])} |")
    cl = an.closed_loop or {}
    L += ["", "## Closed-loop replay through lib/control (the torque the firmware should have "
          "commanded)", ""]
    if cl.get("channels"):
        L += ["The firmware's fixed-point controller drives the plant on its own schedule from "
              "the run's reference and clamp setting; recorded minus replayed controller "
              "output. Shown, not used to decide.", "",
              "| channel | noise floor | nominal closed loop | updated closed loop |",
              "|---|---|---|---|"]
        for c in cl["channels"]:
            L.append(f"| {c} | {cl['noise_floor'][c]:.3g} | {cl['rmse_nominal'][c]:.3g} | "
                     f"{cl['rmse_updated'][c]:.3g} |")
        L += ["", f"Normalized RMS (noise = 1): nominal {cl['normalized_rms_nominal']}, "
              f"updated {cl['normalized_rms_updated']}."]
    for rr in cl.get("runs", []):
        if not rr["replayed"]:
            L.append(f"- `{rr['run']}` not replayed in closed loop: {'; '.join(rr['problems'])}")
        for a in rr.get("assumptions", []):
            L.append(f"- `{rr['run']}`: assumed {a}")
    if an.notes:
        L += ["", "## Notes", ""] + [f"- {n}" for n in an.notes]
    if plots:
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    L += ["", f"Updated model parameters: `model.json` (tau_max = "
          f"{an.model['tau_max_nm']['min']:.4g} N m).", ""]
    return "\n".join(L)


def _outputs(an: Analysis, staging: str, plots: bool) -> dict[str, Any]:
    """Write every output file into ``staging``; report.json's content (its ``outputs``: the
    files' names relative to OUT_DIR)."""
    from host_tools.analyzer.report import html as report_html
    from host_tools.analyzer.report import series as sr

    runs = list(sr.all_series(an))
    names = []
    for i, ser in runs:
        n = sr.file_name(an, i)
        if n in names:
            n = n[:-4] + f"-{i}.csv"
        outputs.write_text(staging, n, sr.to_csv(ser))
        names.append(n)
    files = _plots(an, staging, runs) if plots else []
    names += files
    outputs.write_text(staging, "report.html",
                       report_html.report_html(an, summary_lines(an), runs))
    names.append("report.html")
    rep = report_dict(an)
    rep["series"] = [n for n in names if n.startswith("series/")]
    rep["outputs"] = ["report.json", "report.md", "model.json"] + names
    outputs.write_text(staging, "report.md", _md(an, rep, files))
    outputs.write_text(staging, "model.json", json.dumps(_finite(an.model), indent=2) + "\n")
    outputs.write_text(staging, "report.json", json.dumps(rep, indent=2) + "\n")
    return rep


def write_outputs(an: Analysis, out_dir: str, plots: bool = True,
                  staging: str | None = None, on_commit: Callable[[], object] | None = None
                  ) -> dict[str, Any]:
    """Write the output set into ``out_dir``, all or nothing (report/outputs.py): staged in
    ``staging`` (a fresh folder of :func:`outputs.create_staging`; made here when None), then
    committed.  Returns report.json's content.  On any failure the staging folder is removed
    and ``out_dir`` keeps its previous set."""
    if staging is None:
        staging = outputs.create_staging(out_dir)
    try:
        rep = _outputs(an, staging, plots)
        outputs.commit(staging, out_dir, rep["outputs"], on_commit)
    except BaseException:
        outputs.remove_staging(staging)
        raise
    return rep
