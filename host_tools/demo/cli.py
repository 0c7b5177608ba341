"""``python -m host_tools demo``: its options, the two parts in turn and OUT_DIR/README.md."""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

from host_tools.demo.analyzer_part import analyzer_demo
from host_tools.demo.thesis import thesis_reproduction


from host_tools import humanize


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--skip-thesis", action="store_true", help="skip part 1 (II.6)")
    parser.add_argument("--skip-analyzer", action="store_true",
                        help="skip part 2 (the analyzer on the concealed-effect dataset)")
    parser.add_argument("--jobs", type=int, default=2, help="analyzer processes (default 2)")


def _index(out: str, elapsed_s: float) -> None:
    """OUT_DIR/README.md: where everything is."""
    L = ["# Main job results", ""]
    if os.path.isfile(os.path.join(out, "thesis", "README.md")):
        L.append("- Thesis reproduction (II.6): [thesis/README.md](thesis/README.md) — table against "
                 "the thesis's numbers; figures `thesis/ii61_torque_steps.png`, "
                 "`thesis/ii62_profiles.png`, `thesis/ii63_clamp.png`.")
    sp = os.path.join(out, "analyzer", "summary.json")
    if os.path.isfile(sp):
        with open(sp) as fh:
            sm = json.load(fh)
        sc = sm.get("score") or {}
        L.append("- Analyzer on the concealed-effect dataset: [analyzer/report/report.md]"
                 "(analyzer/report/report.md) (report.json, plots, model.json beside it); "
                 "`analyzer/fit_improvement.png`; runs under `analyzer/dataset/runs/`, hidden "
                 "label under `analyzer/dataset/labels/`.")
        L.append(f"  Hidden truth: {humanize.effects(sm['case']['effects'])}; the analyzer said "
                 f"`{sc.get('verdict')}`, selected {humanize.names(sc.get('selected') or [])}, "
                 f"named {humanize.names(sc.get('named') or [])}; main parameter "
                 f"{humanize.param_score(sc.get('param'))}.")
    L += ["", f"Made by `python -m host_tools demo` in {elapsed_s:.0f} s.", ""]
    with open(os.path.join(out, "README.md"), "w") as fh:
        fh.write("\n".join(L))


def main(args) -> int:
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    t0 = time.time()
    status = 0
    if not args.skip_thesis:
        print("part 1: thesis reproduction (II.6) on the nominal model", flush=True)
        thesis_reproduction(os.path.join(out, "thesis"))
        print(f"  -> {os.path.join(out, 'thesis', 'README.md')} ({time.time() - t0:.1f} s)",
              flush=True)
    if not args.skip_analyzer:
        print("part 2: the analyzer on a concealed-effect dataset from the truth simulator",
              flush=True)
        try:
            r = analyzer_demo(os.path.join(out, "analyzer"), jobs=args.jobs)
        except Exception as exc:  # report, do not hide
            print(f"  part 2 failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 1
        if r["rc"] != 0:
            print(f"  analyzer exited with {r['rc']}", file=sys.stderr)
            status = 1
        rep = r["report"] or {}
        sc = r.get("score") or {}
        print(f"  verdict: {rep.get('verdict')}; selected: "
              f"{humanize.selected(rep.get('selected'))}")
        print(f"  hidden truth: {humanize.effects(r['case']['effects'])}; all named: "
              f"{humanize.number(sc.get('named_all'))}; parameter: "
              f"{humanize.param_score(sc.get('param'))}")
        fit = rep.get("fit", {})
        for ch in ("omega_r", "x_m"):
            if ch in fit.get("heldout_rmse_before", {}):
                print(f"  held-out RMS {ch}: {fit['heldout_rmse_before'][ch]:.4g} -> "
                      f"{fit['heldout_rmse_after'][ch]:.4g}")
        print(f"  -> report: {os.path.join(r['report_dir'], 'report.md')} (report.json, plots, "
              f"model.json beside it); fit plot: {os.path.join(out, 'analyzer', 'fit_improvement.png')}")
    _index(out, time.time() - t0)
    print(f"done in {time.time() - t0:.1f} s; results under {out} (start at {os.path.join(out, 'README.md')})")
    return status
