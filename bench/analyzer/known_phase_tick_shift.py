"""Measurement: where the closed-loop replay's one-tick shift (replay/unseen._replay_tick_shift)
would move the replay's ticks against the recording's, on runs whose ticks run from the
experiment's start (prepare/timing.TIMING_FROM_START, where the rule no longer tries it) and on
runs whose tick phase was estimated (where it still does); and, given the same case recorded
with a frame at every tick, how far the fill of the unreported ticks is from the commands the
recorder gave with the shift and without it (docs/analyzer.md, "Ticks no frame reported", and
the rule's row in "Which data each rule was settled on").

Survey (one line per run with unreported ticks and a closed-loop replay; every case folder
under each CASES_ROOT):

  PYTHONPATH=. nice .venv/bin/python bench/analyzer/known_phase_tick_shift.py \
      /work/wt/score-data/heldback{13..30}/runs

Fill error of one case against its full-rate recording (``suite generate ... --recorder
tel_s=<inner_s>``):

  PYTHONPATH=. nice .venv/bin/python bench/analyzer/known_phase_tick_shift.py \
      --case OUT/runs/CASE --full OUT_FULL/runs/CASE
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools import runfmt  # noqa: E402
from host_tools.analyzer.prepare.inputs import prepare_runs  # noqa: E402
from host_tools.analyzer.prepare.timing import TIMING_FROM_START  # noqa: E402
from host_tools.analyzer.replay.closedloop import ClosedLoopReplay  # noqa: E402
from host_tools.analyzer.replay.openloop import OpenLoopReplay  # noqa: E402
from host_tools.analyzer.replay.channels import channels  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402

ESTIMATED = "board wheel speeds against recorded counts"   # any timing but TIMING_FROM_START


def _runs(case_dir: str) -> list[runfmt.Run]:
    names = sorted(n for n in os.listdir(case_dir)
                   if os.path.exists(os.path.join(case_dir, n, "meta.json")))
    return [runfmt.load_run(os.path.join(case_dir, n)) for n in names]


def _shift(prep, cl) -> int:
    ts = np.asarray(cl["t_s"], float)
    k = np.round((prep.t_in - ts[0]) / (ts[1] - ts[0])).astype(np.int64)
    return UN._replay_tick_shift(prep, cl, k, np.asarray(prep.seen_ticks, bool))


def _replayed(case_dir: str):
    """(prepared run, closed-loop replay) of each run with unreported ticks that replays."""
    clr = ClosedLoopReplay(dt_s=5e-4)
    for p in prepare_runs(_runs(case_dir), lambda s: None):
        if p.seen_ticks is None or bool(np.all(p.seen_ticks)):
            continue
        setup, _, _ = clr.setup(p)
        if setup is not None:
            yield p, clr.simulate(p, {}, setup)


def survey(roots: list[str]) -> None:
    count: collections.Counter = collections.Counter()
    for root in roots:
        for case in sorted(os.listdir(root)):
            for p, cl in _replayed(os.path.join(root, case)):
                s = _shift(p, cl)
                count[(p.timing, s)] += 1
                if s != 0:
                    print(f"{case} {p.name}: timing '{p.timing}', the bends' shift {s:+d} "
                          f"({'not tried' if p.timing == TIMING_FROM_START else 'applied'})")
    for (timing, s), n in sorted(count.items()):
        print(f"runs timed '{timing}': shift {s:+d} on {n}")


def _given(prep, full: runfmt.Run) -> tuple[np.ndarray, np.ndarray]:
    inner = float(prep.inner_period)
    tf = np.asarray(full.telemetry["t_s"], float)
    kf = np.floor(tf / inner + 1e-9).astype(np.int64)
    idx = np.searchsorted(kf, np.round(prep.t_in / inner).astype(np.int64))
    return (np.asarray(full.telemetry["pwm_r"], float)[idx],
            np.asarray(full.telemetry["pwm_l"], float)[idx])


def _rms(x: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.square(x)))) if np.size(x) else float("nan")


def fill_error(case_dir: str, full_dir: str) -> None:
    duty = OpenLoopReplay("duty", dt_s=5e-4)
    for p, cl in _replayed(case_dir):
        given = _given(p, runfmt.load_run(os.path.join(full_dir, p.name)))
        uns = ~np.asarray(p.seen_ticks, bool)
        truth = channels(dataclasses.replace(p, duty=given),
                         duty.simulate_windows(dataclasses.replace(p, duty=given), {}), "duty")
        line = _rms(np.concatenate([(p.duty[s] - given[s])[uns] for s in (0, 1)]))
        print(f"== {p.name}: timing '{p.timing}', the bends' shift {_shift(p, cl):+d}; "
              f"unreported {int(uns.sum())} of {uns.size} ticks; line {line:.4f} of duty off")
        for lab, q in (("no shift", p), ("the bends' shift", dataclasses.replace(p, timing=ESTIMATED))):
            f, _ = UN.fill_unseen_from_controller(q, cl)
            e = _rms(np.concatenate([(f.duty[s] - given[s])[uns] for s in (0, 1)]))
            ch = channels(f, duty.simulate_windows(f, {}), "duty")
            w = _rms(ch["omega_r"].sim - truth["omega_r"].sim)
            print(f"   {lab:>16}: fill {e:.4f} of duty off; duty replay's omega_r off by "
                  f"{w:.4f} rad/s RMS from the fill alone")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("roots", nargs="*", help="folders of case folders (survey)")
    ap.add_argument("--case", help="one case folder (fill error; needs --full)")
    ap.add_argument("--full", help="the same case recorded with a frame at every tick")
    a = ap.parse_args(argv)
    if a.case:
        if not a.full:
            ap.error("--case needs --full")
        fill_error(a.case, a.full)
    if a.roots:
        survey(a.roots)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
