"""Measurement: where a Stribeck effect shows in a recording, and what the analyzer's detection
saw of it (heldback32's ``hb32_mj_stribeck``, missed as ``no_mismatch``).

Sub-commands (nice them; one process each; seconds each):

  generate SET CASE OUT [--without] [--recorder KEY=VALUE,...] [--seed-offset N]
      the case's runs and labels as ``suite generate`` writes them, with its effects
      (or ``--without``: none, the same seeds, recorder and references), its recorder or
      ``--recorder`` over it, its seed plus N.

  effect WITH_RUNS WITHOUT_RUNS REPORT_DIR
      the same runs recorded with and without the effect (``generate``; same seed, so the
      same frames and noise draws): per run and channel the RMS and the largest of the
      difference in the noise floors of the analyzer's report (REPORT_DIR/report.json,
      the analysis of WITH_RUNS), where the largest sits and which share of its
      sum of squares falls in the frames where a wheel truly slips (labels' truth.csv).

  ensemble CASE_RUNS [--only run-0,run-1]
      per run and fit channel (RMS, largest, in noise floors): the recording against the
      nominal duty replay, the replay uncertainty the decisions divide by, and how far the
      nominal model's own range moves the replay: each corner of the left-out normal forces
      (the wheels' mass share 0/1, the centre of mass at 0/h_max, the spin share at its
      range's ends) and mu scaled to the ends of their relative range.

  detect REPORT_DIR ...
      from each report's series: per fit channel the RMS of the nominal residual in floors,
      raw and deflated by the replay uncertainty (what the windows and the normalized RMS
      compare), the largest 0.25 s window RMS (raw, deflated) against the strong-window
      threshold, and the report's localization peaks.

Example (the case, its null twin, the same case at a full-rate recorder):

  B=bench/analyzer/stribeck_recorder.py; D=/tmp/st
  nice .venv/bin/python $B generate heldback32 hb32_mj_stribeck $D/noeff --without
  nice .venv/bin/python $B generate heldback32 hb32_mj_stribeck $D/full \\
      --recorder tel_s=0.02,tel_drop=0,heading_tel=unwrapped
  nice .venv/bin/python -m host_tools analyze $D/noeff/runs/hb32_mj_stribeck/run-* --out $D/r_noeff
  nice .venv/bin/python $B effect /work/wt/score-data/heldback32/runs/hb32_mj_stribeck \\
      $D/noeff/runs/hb32_mj_stribeck /work/wt/score-data/heldback32/reports/hb32_mj_stribeck
  nice .venv/bin/python $B detect /work/wt/score-data/heldback32/reports/hb32_mj_stribeck $D/r_noeff
"""
from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import numpy as np

CHANNELS = ("omega_r", "omega_l", "current_r_a", "current_l_a", "x_m", "y_m", "phi_rad",
            "enc_r", "enc_l", "tau_cmd_r", "tau_cmd_l", "pwm_r", "pwm_l")
FIT = ("omega_r", "omega_l", "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")


def _csv(path: Path) -> dict[str, np.ndarray]:
    with open(path) as fh:
        rows = list(csv.reader(fh))
    head, body = rows[0], rows[1:]
    out = {}
    for j, h in enumerate(head):
        try:
            out[h] = np.array([float(r[j]) if r[j] != "" else math.nan for r in body])
        except ValueError:
            out[h] = np.array([r[j] for r in body])
    return out


def generate(a: argparse.Namespace) -> None:
    from host_tools.suite import cases
    from host_tools.suite import generate as gen
    from host_tools.truth.recorder import recorder_config
    c = cases.get([a.case], which=a.set)[0]
    if a.without:
        c.effects = {}
    if a.recorder:
        extra: dict[str, object] = {}
        for kv in a.recorder.split(","):
            k, v = kv.split("=")
            try:
                extra[k] = float(v)
            except ValueError:
                extra[k] = v
        c.recorder = {**c.recorder, **extra}
        recorder_config(c.recorder)
    c.seed += a.seed_offset
    gen.generate_case(c, a.out, overwrite=True)
    print(a.out, c.effects, c.recorder, c.seed)


def effect(a: argparse.Namespace) -> None:
    rep = json.loads((Path(a.report) / "report.json").read_text())
    floors = rep["fit"]["noise_floor"]
    w_root, n_root = Path(a.with_runs), Path(a.without_runs)
    labels = w_root.parent.parent / "labels" / w_root.name
    print(f"{'run':6} {'channel':12} {'rms [fl]':>9} {'max [fl]':>9} {'at t [s]':>9} "
          f"{'slip share':>10} {'frames':>6}")
    for rd in sorted(p for p in w_root.iterdir() if p.name.startswith("run-")):
        nd = n_root / rd.name
        tw, tn = _csv(rd / "telemetry.csv"), _csv(nd / "telemetry.csv")
        gw, gn = _csv(rd / "groundtruth.csv"), _csv(nd / "groundtruth.csv")
        truth = _csv(labels / f"{rd.name}.truth.csv") if (labels / f"{rd.name}.truth.csv").exists() else None
        for ch in CHANNELS:
            src_w, src_n = (gw, gn) if ch in gw else (tw, tn)
            if ch not in src_w or ch not in floors:
                continue
            if src_w["t_s"].size != src_n["t_s"].size or np.max(np.abs(src_w["t_s"] - src_n["t_s"])) > 1e-9:
                print(f"{rd.name} {ch}: frames differ between the two recordings")
                continue
            d = (src_w[ch] - src_n[ch]) / floors[ch]
            if ch == "phi_rad":
                d = (np.angle(np.exp(1j * (src_w[ch] - src_n[ch])))) / floors[ch]
            k = int(np.argmax(np.abs(d)))
            share = math.nan
            if truth is not None and src_w is tw:
                slip_all = (truth["true_slip_r"] > 0.5) | (truth["true_slip_l"] > 0.5)
                # the truth has every frame the recorder made, lost ones too: match by time
                k_t = np.clip(np.searchsorted(truth["t_s"], src_w["t_s"] - 1e-6), 0, slip_all.size - 1)
                slip = slip_all[k_t]
                if np.sum(d ** 2) > 0:
                    share = float(np.sum(d[slip] ** 2) / np.sum(d ** 2))
            print(f"{rd.name:6} {ch:12} {math.sqrt(np.mean(d ** 2)):9.2f} {d[k]:9.2f} "
                  f"{src_w['t_s'][k]:9.3f} {share:10.2f} {d.size:6d}")


def _windows(t: np.ndarray, r: np.ndarray, width: float = 0.25) -> float:
    best = 0.0
    for t0 in t:
        m = (t >= t0) & (t < t0 + width)
        if np.count_nonzero(m) >= 3:
            best = max(best, float(np.sqrt(np.mean(r[m] ** 2))))
    return best


def detect(a: argparse.Namespace) -> None:
    for rep_dir in a.reports:
        rep_dir = Path(rep_dir)
        rep = json.loads((rep_dir / "report.json").read_text())
        floors = rep["fit"]["noise_floor"]
        print(f"== {rep_dir}  verdict {rep['verdict']}")
        for loc in rep.get("localization", []):
            print(f"   window {loc['run']} {loc['t_start_s']:.2f}-{loc['t_end_s']:.2f} s peak "
                  f"{loc['peak_noise_floors']:.2f} floors {','.join(loc['channels'])}")
        tot_raw = tot_defl = 0.0
        n_tot = 0
        print(f"   {'run':6} {'channel':12} {'rms raw':>8} {'rms defl':>8} {'win raw':>8} {'win defl':>8}")
        for sp in sorted((rep_dir / "series").glob("run-*.csv")):
            s = _csv(sp)
            for ch in FIT:
                m = (s["channel"] == ch) & (s["replay"] == "duty")
                if not np.any(m):
                    continue
                fl = floors[ch]
                r = s["residual_nominal"][m] / fl
                unc = np.nan_to_num(s["replay_uncertainty"][m]) / fl
                ok = np.isfinite(r)
                r, unc, t = r[ok], unc[ok], s["t_s"][m][ok]
                rd = r / np.sqrt(1 + unc ** 2)
                tot_raw += float(np.sum(r ** 2))
                tot_defl += float(np.sum(rd ** 2))
                n_tot += r.size
                print(f"   {sp.stem:6} {ch:12} {math.sqrt(np.mean(r ** 2)):8.2f} "
                      f"{math.sqrt(np.mean(rd ** 2)):8.2f} {_windows(t, r):8.2f} {_windows(t, rd):8.2f}")
        print(f"   normalized RMS over the fit channels: raw {math.sqrt(tot_raw / max(n_tot, 1)):.2f}, "
              f"deflated {math.sqrt(tot_defl / max(n_tot, 1)):.2f}")


def ensemble(a: argparse.Namespace) -> None:
    """Per run: the nominal model's own range on each fit channel against the recording."""
    from host_tools.analyzer.pipeline import front
    from host_tools.analyzer.replay.channels import channels
    from host_tools.analyzer.replay.normal_forces import NormalForces, spin_range
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    runs = sorted(str(p) for p in Path(a.runs).iterdir() if p.name.startswith("run-"))
    f = front(runs)
    floors = f.loc.floors
    k_lo, k_hi = spin_range()
    duty = f.ol.duty
    for i, prep in enumerate(f.preps):
        if a.only and prep.name not in a.only.split(","):
            continue
        lo = left_out_normal_forces(prep.robot)
        nom = channels(prep, duty.simulate_windows(prep, {}), duty.mode)
        print(f"== {prep.name}: relative mu range of the left-out normal forces {lo.mu_range[0]:+.3f}"
              f" .. {lo.mu_range[1]:+.3f}")
        print(f"   {'draw':34} " + " ".join(f"{c:>12}" for c in FIT if c in nom))
        print(f"   {'recording - nominal (RMS, max)':34} " + " ".join(f"{math.sqrt(np.mean((nom[c].resid / floors[c]) ** 2)):5.1f},"
                                   f"{np.max(np.abs(nom[c].resid / floors[c])):6.1f}" for c in FIT if c in nom))
        unc = prep.replay_unc or {}
        print(f"   {'replay uncertainty (median, max)':34} " + " ".join(
            f"{np.median(np.interp(nom[c].t, *unc[c])) / floors[c]:5.1f},"
            f"{np.max(np.interp(nom[c].t, *unc[c])) / floors[c]:6.1f}" if c in unc else f"{'-':>12}"
            for c in FIT if c in nom))
        corners: list[tuple[str, dict[str, float], NormalForces]] = []
        for share in (0.0, 1.0):
            for h in (0.0, lo.h_max_m):
                for k in (k_lo, k_hi):
                    corners.append((f"share {share:.0f} h {h * 1e3:4.1f} mm k {k:.2f}", {},
                                    NormalForces(share, h, k)))
        for mu in (-0.10, +0.03):
            corners.append((f"mu x {1 + mu:.2f} (no other change)",
                            {"mu_s": prep.robot["mu_s"] * (1 + mu), "mu_k": prep.robot["mu_k"] * (1 + mu)},
                            NormalForces()))
        for name, params, forces in corners:
            rep = OpenLoopReplay(duty.mode, dt_s=duty.dt_s, forces=forces, params=params or None)
            ch = channels(prep, rep.simulate_windows(prep, {}), duty.mode)
            cells = []
            for c in FIT:
                if c not in nom:
                    continue
                d = (ch[c].resid - nom[c].resid) / floors[c]
                cells.append(f"{math.sqrt(np.mean(d ** 2)):5.1f},{np.max(np.abs(d)):6.1f}")
            print(f"   {name:34} " + " ".join(cells))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate")
    g.add_argument("set")
    g.add_argument("case")
    g.add_argument("out")
    g.add_argument("--without", action="store_true")
    g.add_argument("--recorder", default="")
    g.add_argument("--seed-offset", type=int, default=0)
    e = sub.add_parser("effect")
    e.add_argument("with_runs")
    e.add_argument("without_runs")
    e.add_argument("report")
    d = sub.add_parser("detect")
    d.add_argument("reports", nargs="+")
    n = sub.add_parser("ensemble")
    n.add_argument("runs")
    n.add_argument("--only", default="")
    a = p.parse_args()
    {"generate": generate, "effect": effect, "detect": detect, "ensemble": ensemble}[a.cmd](a)


if __name__ == "__main__":
    main()
