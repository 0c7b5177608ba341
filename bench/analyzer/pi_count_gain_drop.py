"""Measurement: the gain ``g`` (command per rad/s of counted speed) that a single wheel-speed
loop's count-level fill (replay.unseen.fill_count_level; docs/analyzer.md "Ticks no frame
reported") fits from the reported ticks, with the second differences' trend taken as the plain
mean of the two neighbours (before) and as the line through them at the middle tick's time
(after), for recordings that lose frames (the reported ticks unevenly spaced) and the same case
re-recorded without losses (``suite bench ... --recorder tel_drop=0``, same seed: the same
physics and the same ticks, every frame kept), and the rule's (replay.unseen.count_gain_fit: the
line at the tick's time over the triples whose commands are inside the duty's limits, with its
z; the fill takes it when g > 0 and z > COUNT_GAIN_Z, else that side is not moved) for each
run alone and, as the analysis does, for the case's runs together (replay.unseen.count_gains).

For each run and side it prints both fits, the count a tick (2 pi / ppr / inner period, rad/s)
and ``g`` x that (the command's level step that the fill takes out), and, with ``--full`` (the
case with a frame at every tick, ``--recorder tel_drop=0,tel_s=<inner_s>``), the true level
step: the median drop of the command at the ticks whose counted speed is one count above the
tick before's on a cruise.  With ``--span T0,T1`` it also prints the mean move the fill makes
on the unreported ticks there (the analyzer's code as checked out).

Usage (one process, a few seconds):

  PYTHONPATH=. .venv/bin/python bench/analyzer/pi_count_gain_drop.py \
      --runs OUT/runs/CASE [--runs OUT_DROP0/runs/CASE] [--full OUT_FULL/runs/CASE] \
      [--span 1.48,1.64]
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools import runfmt  # noqa: E402
from host_tools.analyzer.prepare.inputs import prepare_runs  # noqa: E402
from host_tools.analyzer.replay.unseen import (  # noqa: E402
    COUNT_GAIN_Z, _count_level, _gain_series, count_gain_fit, count_gains)


def _gains(prep, side: int) -> tuple[float, float, tuple[float, float, int] | None]:  # type: ignore[no-untyped-def]
    """(g with the plain mean of the neighbours, g with the line at the tick's time, both over
    every triple; the rule's fit: g, z, triples inside the duty's limits)."""
    seen = np.asarray(prep.seen_ticks, bool)
    t = np.asarray(prep.t_in, float)
    tel = prep.run.telemetry
    i_seen = np.flatnonzero(seen)
    t_tel = np.asarray(tel["t_s"], float)
    row = np.clip(np.searchsorted(t_tel, t[i_seen]), 1, t_tel.size - 1)
    row = np.where(np.abs(t_tel[row - 1] - t[i_seen]) < np.abs(t_tel[row] - t[i_seen]),
                   row - 1, row)
    us = np.asarray(prep.duty[side], float)[i_seen]
    w = np.asarray(tel[("omega_r", "omega_l")[side]], float)[row]
    ts = t[i_seen]
    out = []
    for lam in (np.full(ts.size - 2, 0.5), (ts[1:-1] - ts[:-2]) / (ts[2:] - ts[:-2])):
        d_u = us[1:-1] - ((1.0 - lam) * us[:-2] + lam * us[2:])
        d_w = w[1:-1] - ((1.0 - lam) * w[:-2] + lam * w[2:])
        out.append(-float(np.sum(d_u * d_w)) / float(np.sum(d_w ** 2)))
    return out[0], out[1], count_gain_fit([(us, w, (ts[1:-1] - ts[:-2]) / (ts[2:] - ts[:-2]))])


def _true_step(full: runfmt.Run, side: int, step: float) -> float:
    """Median command drop at a one-count rise of the counted speed, every tick reported."""
    tel = full.telemetry
    u = np.asarray(tel[("pwm_r", "pwm_l")[side]], float)
    w = np.asarray(tel[("omega_r", "omega_l")[side]], float)
    dw, du = np.diff(w), np.diff(u)
    up = np.abs(dw - step) < 0.1 * step
    return -float(np.median(du[up])) if up.any() else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", action="append", required=True, help="case folder (repeatable)")
    ap.add_argument("--full", default=None, help="same case, a frame at every tick")
    ap.add_argument("--span", default=None, metavar="T0,T1")
    a = ap.parse_args(argv)
    span = tuple(float(x) for x in a.span.split(",")) if a.span else None
    for case in a.runs:
        names = sorted(p.name for p in Path(case).iterdir() if (p / "meta.json").exists())
        runs = [runfmt.load_run(os.path.join(case, n)) for n in names]
        quiet: list[str] = []
        preps = prepare_runs(runs, quiet.append)
        print(f"== {case}")
        # the analysis fits the gain over the case's runs with the same loop (count_gains)
        series = [sr for sr in (_gain_series(p) for p in preps) if sr is not None]
        for side in (0, 1):
            fit = count_gain_fit([sr[side] for sr in series]) if series else None
            if fit is not None:
                print(f"  case {'rl'[side]} (the runs together): g {fit[0]:.4f} z {fit[1]:.1f} "
                      f"over {fit[2]} triples")
        pooled = count_gains(preps)
        for name, p in zip(names, preps):
            if p.seen_ticks is None:
                print(f"  {name}: every tick reported")
                continue
            step = 2.0 * math.pi / float(p.ppr) / float(p.inner_period)
            n_tel = len(p.run.telemetry["t_s"])
            if pooled[preps.index(p)] is not None:
                p = dataclasses.replace(p, count_gains=pooled[preps.index(p)])
            lv = _count_level(p)
            for side in (0, 1):
                g0, g1, fit = _gains(p, side)
                line = (f"  {name} {'rl'[side]}: frames {n_tel}, count a tick {step:.3f} rad/s; "
                        f"g plain mean {g0:.4f} (level {g0 * step:.4f}), "
                        f"line at the tick's time {g1:.4f} (level {g1 * step:.4f})")
                if fit is None:
                    line += "; rule: fewer than 3 triples inside the duty's limits, not moved"
                else:
                    taken = fit[0] > 0 and fit[1] > COUNT_GAIN_Z
                    line += (f"; rule: g {fit[0]:.4f} z {fit[1]:.1f} over {fit[2]} triples, "
                             + ("taken" if taken else "not moved"))
                if a.full:
                    full = runfmt.load_run(os.path.join(a.full, name))
                    line += f"; true level step {_true_step(full, side, step):.4f}"
                if span is not None and lv is not None and lv[2][side] is not None:
                    tk = lv[1]
                    m = (tk >= span[0]) & (tk <= span[1])
                    if m.any():
                        mv = lv[2][side](tk[m])  # type: ignore[misc]
                        line += f"; fill's mean move {span[0]:g}-{span[1]:g} s {float(np.mean(mv)):+.4f}"
                print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
