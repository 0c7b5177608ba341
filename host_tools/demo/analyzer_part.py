"""Part 2 of the main job: the analyzer on the built-in concealed-effect dataset from the truth
simulator, scored against its hidden label, with the fit-improvement plot."""
from __future__ import annotations

import json
import os
import time

import numpy as np

from host_tools import humanize
from host_tools.demo.common import _plt


def analyzer_demo(out_dir: str, jobs: int = 2, log=print) -> dict:
    """Generate the built-in concealed-effect dataset with the truth simulator (deterministic,
    a few seconds) and run the analyzer on it, as the acceptance harness does."""
    from host_tools.suite import bench
    from host_tools.suite import cases as suite_cases
    from host_tools.suite import generate
    from host_tools.suite.conceal import evidence
    case = suite_cases.demo_case()
    data_dir = os.path.join(out_dir, "dataset")
    runs = generate.generate_case(case, data_dir, overwrite=True)
    label_path = os.path.join(data_dir, "labels", f"{case.name}.json")
    log(f"  dataset: {len(runs)} closed-loop runs from the truth simulator under "
        f"{os.path.join(data_dir, 'runs', case.name)} (hidden label: {label_path})")
    ev = evidence(case, data_dir)
    log(f"  concealment: tracking error over the last 40 % of the runs {1e3 * ev['late_m']:.0f} mm "
        f"(nominal robot: {1e3 * ev['late_null_m']:.0f} mm); duty differs by up to {ev['duty']:.2f}")
    rep_dir = os.path.join(out_dir, "report")
    log(f"  analyzing: python -m host_tools analyze {' '.join(_short(r) for r in runs)} "
        f"--out {_short(rep_dir)}")
    t0 = time.time()
    rc, report = bench.run_analyzer(runs, rep_dir, jobs=jobs)
    elapsed = time.time() - t0
    score = None
    if report is not None:
        with open(label_path) as fh:
            score = bench.score_case(json.load(fh), rc, report)
        _fit_plot(report, os.path.join(out_dir, "fit_improvement.png"))
    summary = {"case": case.label(), "evidence": ev, "analyzer_rc": rc, "analyzer_s": elapsed,
               "score": score}
    with open(os.path.join(out_dir, "summary.json"), "w") as fh:
        json.dump(summary, fh, indent=2)
    return {"rc": rc, "report_dir": rep_dir, "report": report, "case": case.label(),
            "score": score, "evidence": ev}


def _short(p: str) -> str:
    rel = os.path.relpath(p)
    return p if rel.startswith("..") else rel


def _fit_plot(report: dict, path: str) -> None:
    """Per channel: RMS error of the nominal and of the updated model, on the fitting data and
    held out, in units of the channel's noise floor."""
    plt = _plt()
    fit = report.get("fit", {})
    floor = fit.get("noise_floor", {})
    chans = [c for c in fit.get("rmse_before", {}) if c in floor and floor[c] > 0]
    if not chans:
        return
    x = np.arange(len(chans))
    fig, ax = plt.subplots(figsize=(max(6, 0.9 * len(chans) + 2), 4))
    for i, (key, lab, col) in enumerate((("rmse_before", "nominal, fit data", "C3"),
                                         ("rmse_after", "updated, fit data", "C2"),
                                         ("heldout_rmse_before", "nominal, held out", "C1"),
                                         ("heldout_rmse_after", "updated, held out", "C0"))):
        vals = [fit.get(key, {}).get(c, np.nan) / floor[c] for c in chans]
        ax.bar(x + (i - 1.5) * 0.2, vals, 0.2, label=lab, color=col)
    ax.axhline(1.0, color="k", ls=":", lw=1, label="noise floor")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels(chans, rotation=30, ha="right")
    ax.set_ylabel("RMS error / noise floor")
    ax.set_title(f"verdict {report.get('verdict')}: selected "
                 f"{humanize.selected(report.get('selected'))}", fontsize=9, wrap=True)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))  # outside: never over a bar
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
