"""Measurement: heldback33's misses under the recorder ``wrapped_gt_tel150_loop67_frames_mid_
cam1p9`` (150 ms telemetry, 67 ms loop, frame odometry with midpoint integration, a 1.9 Hz
camera, wrapped ground-truth heading): ``hb33_mj_motor_gain_asymmetry``, ``hb33_mj_wheel_radius``,
``hb33_tr_load_transfer``: is the effect below what this recorder resolves, or does the
analyzer lose it?  (The effect's size in the recordings and the ``generate`` / ``effect``
sub-commands are those of ``stribeck_recorder.py``.)

Sub-commands (nice them; one process each; seconds each):

  generate SET CASE OUT [--without] [--default-recorder] [--recorder KEY=VALUE,...]
           [--param EFFECT.NAME=VALUE,...]
      the case as ``suite generate`` writes it, with its effects or ``--without`` (the same
      seeds, recorder and references); ``--default-recorder``: the firmware's own recorder
      (20 ms telemetry, 30 Hz camera, ...) in place of the case's, before ``--recorder``;
      ``--param``: the effect's parameters set to other sizes.

  detect RUNS_DIR
      the analyzer's detection stage on the runs (``pipeline.front``), in its own figures:
      the strong-window threshold and the significant windows of the fit channels (RMS in
      floors, residual deflated by the replay uncertainty as the window test sees it), the
      overall normalized RMS against ``MISMATCH_RMS``, each channel's bias test, the wheels'
      imbalance test and, per channel, the samples, the raw and deflated RMS and the median
      replay uncertainty in floors (what deflates them).

  forced RUNS_DIR EFFECT [EFFECT ...]
      as if the detection had seen a mismatch: each EFFECT fitted alone on the analysis's own
      problem and judged (``select.fit_candidates`` with ``mismatch_seen`` set): parameters,
      delta BIC, held-out error and paired z, output change, checks failed and why not.

  candidates REPORT_DIR [EFFECT]
      the report's fitted candidates (those naming EFFECT, or all singles): parameters, their
      standard error, delta BIC, held-out error before -> after with the paired z, checks
      failed and why not.

  past EFFECT [EFFECT ...]
      every earlier scored case of these effects (heldback24..33 bench.json under
      /work/wt/score-data): recorder, verdict, named effects and, from its report, the
      nominal normalized RMS and the largest window.

Example (heldback33's motor gain asymmetry; the same for the other two):

  B=bench/analyzer/hb33_recorder_misses.py; S=bench/analyzer/stribeck_recorder.py
  D=/tmp/hb33; H=/work/wt/score-data/heldback33; C=hb33_mj_motor_gain_asymmetry
  nice .venv/bin/python $B generate heldback33 $C $D/noeff_$C --without
  nice .venv/bin/python $B generate heldback33 $C $D/full_$C --default-recorder
  nice .venv/bin/python $S effect $H/runs/$C $D/noeff_$C/runs/$C $H/reports/$C
  nice .venv/bin/python $B detect $H/runs/$C; nice .venv/bin/python $B detect $D/noeff_$C/runs/$C
  nice .venv/bin/python -m host_tools analyze $D/full_$C/runs/$C/run-* --out $D/r_full_$C --jobs 1
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

SCORE = Path("/work/wt/score-data")


def generate(a: argparse.Namespace) -> None:
    from host_tools.suite import cases
    from host_tools.suite import generate as gen
    from host_tools.truth.recorder import recorder_config
    c = cases.get([a.case], which=a.set)[0]
    if a.without:
        c.effects = {}
    for kv in filter(None, a.param.split(",")):
        k, v = kv.split("=")
        eff, name = k.split(".")
        c.effects[eff][name] = float(v)
    rec = {} if a.default_recorder else dict(c.recorder)
    for kv in filter(None, a.recorder.split(",")):
        k, v = kv.split("=")
        try:
            rec[k] = float(v)
        except ValueError:
            rec[k] = v
    c.recorder = rec
    recorder_config(c.recorder)
    gen.generate_case(c, a.out, overwrite=True)
    print(a.out, c.effects, c.recorder, c.seed)


def detect(a: argparse.Namespace) -> None:
    from host_tools.analyzer.locate.mismatch import MISMATCH_RMS
    from host_tools.analyzer.pipeline import front
    runs = sorted(str(p) for p in Path(a.runs).iterdir() if p.name.startswith("run-"))
    notes: list[str] = []
    f = front(runs, notes=notes)
    det, loc = f.det, f.loc
    floors = loc.floors
    fit = det.problem.fit_channels
    sig = [e for e in loc.entries if e["channel"] in fit]
    print(f"== {a.runs}: {len(runs)} runs")
    print(f"   strong-window threshold {det.strong_k:.2f} floors; overall normalized RMS "
          f"{det.nrms0:.2f} (a mismatch above {MISMATCH_RMS} with a significant window); "
          f"mismatch seen: {det.mismatch_seen}")
    for e in sig:
        print(f"   window {e['run']} {e['channel']:12} {e['t_start_s']:.2f}-{e['t_end_s']:.2f} s "
              f"RMS {e['rms'] / e['noise_floor']:.2f} floors")
    if not sig:
        print("   no significant window in a fit channel")
    for c, v in (det.bias or {}).items():
        print(f"   bias {c:12} {v['bias_floors']:+.2f} floors, t {v['t']:.2f} against "
              f"{v['t_threshold']:.2f} ({v['blocks']} blocks){'  SIGNIFICANT' if v['significant'] else ''}")
    imb = det.imbalance
    if imb is not None:
        print(f"   wheels' imbalance: t {imb['t']:.2f} against {imb['t_threshold']:.2f} "
              f"({imb['blocks']} blocks of {imb['block_s']:g} s), gain ratio {imb['ratio']:.3f}, "
              f"{imb['output_floors']:.2f} floors of output{'  SIGNIFICANT' if imb['significant'] else ''}")
    print(f"   {'run':6} {'channel':12} {'n':>4} {'rms raw':>8} {'rms defl':>8} {'unc med':>8}")
    for prep, chans in zip(f.preps, f.nominal):
        for c in fit:
            ch = chans.get(c)
            if ch is None:
                continue
            r = ch.resid / floors[c]
            d = ch.deflated(floors[c]) / floors[c]
            ok = np.isfinite(r) & np.isfinite(d)
            unc = ch.total_unc
            u = (np.nanmedian(np.asarray(unc, float)) / floors[c]) if unc is not None else math.nan
            print(f"   {prep.name:6} {c:12} {int(ok.sum()):4d} {math.sqrt(np.mean(r[ok] ** 2)):8.2f} "
                  f"{math.sqrt(np.mean(d[ok] ** 2)):8.2f} {u:8.2f}")
    for n in notes:
        print(f"   note: {n[:300]}")


def forced(a: argparse.Namespace) -> None:
    import dataclasses
    from host_tools.analyzer.pipeline import front
    from host_tools.analyzer.fit.judge import paired_better
    from host_tools.analyzer.select import fit_candidates
    from host_tools.analyzer.fit.solver import effective_n
    runs = sorted(str(p) for p in Path(a.runs).iterdir() if p.name.startswith("run-"))
    f = front(runs, effects=a.effects)
    det = dataclasses.replace(f.det, mismatch_seen=True)
    print(f"== {a.runs}: detection saw a mismatch: {f.det.mismatch_seen} (forced on)")
    for c in fit_candidates(det, f.vocab_fit, 1, [], lambda _m: None):
        failed = [k for k, v in c.checks.items() if not v]
        print(f"   {c.name}: {c.fit.params} output {c.output_size:.2f} fl "
              f"dBIC {c.delta_bic:.1f} held-out {c.heldout_before:.3f} -> {c.heldout_after:.3f} "
              f"(paired z {c.heldout_z:.2f}) failed {failed}")
        for w in c.reasons:
            print(f"      why not: {w[:240]}")
        if c.heldout_pooled is not None:
            b, af = c.heldout_pooled
            print(f"      pooled held-out: {b.size} samples, effective n of the after residual "
                  f"{effective_n(af):.1f}")
        cam_b: list[np.ndarray] = []
        cam_a: list[np.ndarray] = []
        for ch, (b, af) in c.heldout_pairs.items():
            fl = f.loc.floors.get(ch)
            if fl is None or ch not in det.problem.fit_channels:
                continue
            ok = np.isfinite(b) & np.isfinite(af)
            bb, aa = b[ok] / fl, af[ok] / fl
            if ch in ("x_m", "y_m", "phi_rad"):
                cam_b.append(bb)
                cam_a.append(aa)
            z = paired_better(bb, aa)[1]
            print(f"      held-out {ch:12} n {bb.size:4d} RMS {math.sqrt(np.mean(bb ** 2)):6.2f} -> "
                  f"{math.sqrt(np.mean(aa ** 2)):6.2f} floors (undeflated), paired z alone {z:6.2f}")
        if cam_b:
            bb, aa = np.concatenate(cam_b), np.concatenate(cam_a)
            print(f"      held-out camera channels pooled (undeflated): n {bb.size}, paired z "
                  f"{paired_better(bb, aa)[1]:.2f}")


def candidates(a: argparse.Namespace) -> None:
    rep = json.loads((Path(a.report) / "report.json").read_text())
    print(f"== {a.report}: verdict {rep['verdict']}, selected "
          f"{[s['effect'] for s in rep.get('selected', [])]}")
    for c in rep["candidates"]:
        if (a.effect and a.effect not in c["effect"].split("+")) or (not a.effect and "+" in c["effect"]):
            continue
        failed = [k for k, v in c["checks"].items() if not v]
        print(f"   {c['effect']:34} {c['params']} +- {c.get('param_std')} dBIC {c['delta_bic']:.1f} "
              f"held-out {c['heldout_rmse_before']:.3f} -> {c['heldout_rmse_after']:.3f} "
              f"output {c['output_change_noise_floors']:.2f} fl; failed {failed}")
        for w in c["why_not"]:
            print(f"      why not: {w[:240]}")


def past(a: argparse.Namespace) -> None:
    for n in range(24, 34):
        p = SCORE / f"heldback{n}" / "bench.json"
        if not p.exists():
            continue
        for r in json.loads(p.read_text())["results"]:
            if r["true"] not in a.effects:
                continue
            rp = SCORE / f"heldback{n}" / "reports" / r["case"] / "report.json"
            extra = ""
            if rp.exists():
                rep = json.loads(rp.read_text())
                nrms = rep["fit"].get("normalized_rms_before")
                peak = max((x["peak_noise_floors"] for x in rep.get("localization", [])), default=0.0)
                sel = {s["effect"]: s.get("params") for s in rep.get("selected", [])}
                extra = f" nRMS {nrms} largest window {peak:.2f} fl {sel}"
            print(f"   {r['case']:32} {r['recorder']:44} {r['verdict']:12} "
                  f"{','.join(r['named']) or '-':28}{extra}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate")
    g.add_argument("set")
    g.add_argument("case")
    g.add_argument("out")
    g.add_argument("--without", action="store_true")
    g.add_argument("--default-recorder", action="store_true")
    g.add_argument("--recorder", default="")
    g.add_argument("--param", default="")
    d = sub.add_parser("detect")
    d.add_argument("runs")
    c = sub.add_parser("candidates")
    c.add_argument("report")
    c.add_argument("effect", nargs="?", default="")
    fo = sub.add_parser("forced")
    fo.add_argument("runs")
    fo.add_argument("effects", nargs="+")
    q = sub.add_parser("past")
    q.add_argument("effects", nargs="+")
    a = p.parse_args()
    {"generate": generate, "detect": detect, "forced": forced, "candidates": candidates,
     "past": past}[a.cmd](a)


if __name__ == "__main__":
    main()
