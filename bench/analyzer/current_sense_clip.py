"""Measurement: a magnitude-only current sense with ADC noise, and the current channel's noise
floor (docs/analyzer.md, "Noise floors and windows"; heldback27's truth tour null).

The recorder (``host_tools.truth.recorder._shield_current``) logs |I| as ``clip(round(|I|/lsb
+ N(0, sigma)), 0, 1023)`` counts: at a current within a few sigma of nil the ADC's noise is
clipped at 0 counts.  Part 1 gives, per ADC noise and true level (in LSB), the reading's bias,
its std and the MAD-of-second-differences estimate (``signals.hf_noise_std``) of white readings,
all in sigma: at nil current the bias is +0.40 sigma, the std 0.59 sigma, the MAD estimate
0.4-0.6 sigma; from 3 sigma up the sense is linear.  Part 2 (``--runs DIR ...``, suite runs
with a current sense) gives per run directory the current residual of the nominal duty replay
binned by the replayed current (mean, std, MAD estimate) and the floor over all samples
(``pooled_hf_noise_std``) against the one where the replayed current clears the clipping
(``floors.sense_linear_noise_std``).

    PYTHONPATH=. python bench/analyzer/current_sense_clip.py [--runs CASE_DIR ...]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from host_tools.analyzer import signals as sg

LSB_A = 5.0 / 1024 / 1.65


def sense_table(sigmas=(1.0, 3.0, 6.2, 6.6, 7.0), levels=(0, 2, 5, 10, 20), n=400_000) -> None:
    rng = np.random.default_rng(1)
    print("sigma[LSB] level[LSB]  bias[sigma] bias[mA]  std[sigma]  MAD-d2[sigma]")
    for s in sigmas:
        for x in levels:
            v = np.clip(np.round(x + rng.normal(0.0, s, n)), 0, 1023)
            print(f"{s:10.1f} {x:10d} {(v.mean() - x) / s:+12.3f} {(v.mean() - x) * LSB_A * 1e3:+8.2f}"
                  f" {v.std() / s:11.3f} {sg.hf_noise_std(v) / s:14.3f}")


def case_figures(case_dir: Path) -> None:
    from host_tools.analyzer.locate import floors as LF
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    from host_tools.runfmt import load_run
    chans = []
    for rd in sorted(p for p in case_dir.iterdir() if (p / "telemetry.csv").exists()):
        prep = PI.prepare_timed(load_run(rd))
        chans.append(CH.channels(prep, OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty"))
    for c in ("current_r_a", "current_l_a"):
        cs = [ch[c] for ch in chans if c in ch]
        if not cs:
            continue
        r = np.concatenate([x.resid for x in cs])
        sim = np.abs(np.concatenate([x.sim for x in cs]))
        all_ = LF.pooled_hf_noise_std([x.resid for x in cs])
        lin = LF.sense_linear_noise_std(cs, all_)
        print(f"{case_dir.name} {c}: floor over all samples {all_ * 1e3:.1f} mA, where the current "
              f"clears the clipping {lin * 1e3:.1f} mA; {np.mean(sim < 0.01):.0%} of samples "
              f"replay below 10 mA")
        for lo, hi in ((0, 0.01), (0.01, 0.03), (0.03, 0.06), (0.06, 0.1), (0.1, 0.2), (0.2, 3)):
            m = (sim >= lo) & (sim < hi) & np.isfinite(r)
            if m.sum() > 5:
                print(f"   replay [{lo * 1e3:4.0f}, {hi * 1e3:4.0f}) mA n {m.sum():5d}: mean "
                      f"{r[m].mean() * 1e3:+6.2f} mA, std {r[m].std() * 1e3:5.1f}, "
                      f"MAD-d2 {sg.hf_noise_std(r[m]) * 1e3:5.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", nargs="*", type=Path, default=[],
                    help="suite case directories (each holding run-*/ directories)")
    a = ap.parse_args()
    sense_table()
    for d in a.runs:
        case_figures(d)


if __name__ == "__main__":
    main()
