"""Writing the analysis: report.json (mismatch-report/1), report.md, PNG plots and the
updated model-parameter file (ddmodel/1)."""
from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from host_tools.analyzer.report.sections import REPORT_FORMAT, Analysis
from host_tools.analyzer.signals import round_sig
from host_tools.runfmt import display


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


def report_dict(an: Analysis) -> dict:
    cands = []
    for c in an.candidates:
        entry = {"effect": c.name, "params": {}, "delta_bic": round_sig(c.delta_bic, 5),
                 "heldout_rmse_before": round_sig(c.heldout_before), "heldout_rmse_after":
                     round_sig(c.heldout_after),
                 "accepted": c.accepted, "checks": dict(c.checks), "why_not": c.reasons,
                 "output_change_noise_floors": round_sig(c.output_size),
                 "heldout_per_channel": {ch: {q: (round_sig(x) if isinstance(x, float) else x)
                                              for q, x in v.items()}
                                         for ch, v in c.heldout_per_channel.items()},
                 "param_std": {}, "unidentified": list(c.fit.unidentified)}
        for e, ps in c.fit.params.items():
            for k, v in ps.items():
                key = k if len(c.effects) == 1 else f"{e}.{k}"
                entry["params"][key] = round_sig(v, 5)
        # 1-sigma uncertainty of each fitted coordinate (e.g. mu_k_over_mu_s for friction)
        for (e, k), sd in zip(c.fit.coords, c.fit.std):
            key = k if len(c.effects) == 1 else f"{e}.{k}"
            entry["param_std"][key] = round_sig(sd)
        cands.append(entry)
    return _finite({
        "format": REPORT_FORMAT,
        "verdict": an.verdict,
        "mismatch": an.mismatch,
        "selected": an.selected,
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


def _plots(an: Analysis, out_dir: str, max_plots: int = 16) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    chans = sorted({(i, c) for (i, c), w in an.windows.items() if w})
    if an.verdict == "no_mismatch" or not chans:
        chans = [(i, c) for i in range(len(an.preps)) for c in ("omega_r",)
                 if c in an.nominal[i]]
    for i, c in chans[:max_plots]:
        closed = c not in an.nominal[i]
        if closed:  # a closed-loop channel (recorded vs replayed controller output)
            ch = an.cl_nominal[i].get(c) if i < len(an.cl_nominal) else None
            if ch is None:
                continue
            upd = an.cl_updated[i].get(c) if (i < len(an.cl_updated) and
                                               an.closed_loop.get("updated_effects")) else None
        else:
            ch = an.nominal[i][c]
            upd = an.updated[i][c] if (an.updated is not None and c in an.updated[i]) else None
        kind = "closed loop" if closed else "simulation"
        fig, ax = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True,
                               gridspec_kw={"height_ratios": [2, 1]})
        ax[0].plot(ch.t, ch.rec, "k.", ms=3, label="recording")
        ax[0].plot(ch.t, ch.sim, "-", color="tab:red", lw=1.2, label=f"nominal {kind}")
        ax[1].plot(ch.t, ch.resid, "-", color="tab:red", lw=1, label="nominal residual")
        if upd is not None:
            u = upd
            ax[0].plot(u.t, u.sim, "-", color="tab:blue", lw=1.2, label=f"updated {kind}")
            ax[1].plot(u.t, u.resid, "-", color="tab:blue", lw=1, label="updated residual")
        f = an.floors.get(c, an.closed_loop.get("noise_floor", {}).get(c) or 0)
        for a in (ax[1],):
            a.axhspan(-3 * f, 3 * f, color="0.85", label="±3 noise floors")
        for w in an.windows.get((i, c), []):
            for a in ax:
                a.axvspan(w.t_start_s, w.t_end_s, color="orange", alpha=0.25)
        ax[0].set_ylabel(f"{c} [{ch.unit}]")
        ax[1].set_ylabel("residual")
        ax[1].set_xlabel("t [s]")
        ax[0].set_title(f"{an.preps[i].name}: {c} (windows of significant mismatch shaded)")
        ax[0].legend(fontsize=8)
        ax[1].legend(fontsize=7, loc="best")
        fig.tight_layout()
        name = f"{an.preps[i].name}_{c}.png".replace(os.sep, "_")
        fig.savefig(os.path.join(out_dir, name), dpi=90)
        plt.close(fig)
        files.append(name)
    return files


def _md(an: Analysis, rep: dict, plots: list[str]) -> str:
    L = ["# Mismatch report", "", f"**Verdict: `{an.verdict}`**", "",
         "Runs: " + ", ".join(f"`{r.name}`" for r in an.runs), ""]
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
        g = lambda d: (f"{d[c]:.4g}" if d.get(c) is not None else "-")  # noqa: E731
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


def _write_text(path: str, text: str) -> None:
    """Write ``text`` as UTF-8 to a temporary file, then rename it over ``path``: a failure
    (a full disk) leaves the previous file or none, never a truncated one.  Characters that
    UTF-8 cannot hold (undecodable bytes of a path) are written as backslash escapes."""
    tmp = path + ".tmp"
    try:
        with open(tmp, "w", encoding="utf-8", errors="backslashreplace") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def write_outputs(an: Analysis, out_dir: str, plots: bool = True) -> dict:
    os.makedirs(out_dir, exist_ok=True)
    rep = report_dict(an)
    _write_text(os.path.join(out_dir, "report.json"), json.dumps(rep, indent=2) + "\n")
    _write_text(os.path.join(out_dir, "model.json"),
                json.dumps(_finite(an.model), indent=2) + "\n")
    files = _plots(an, out_dir) if plots else []
    _write_text(os.path.join(out_dir, "report.md"), _md(an, rep, files))
    return rep
