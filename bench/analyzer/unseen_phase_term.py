"""Experiment (a proposal, not a rule): the replay's uncertainty from unreported commands with
one more term for a cascade whose outer period spans several inner ticks (meta.json
``periods_s.outer`` / ``periods_s.inner`` >= 2) seen by frames that report one phase of that
period for a block of frames (a 29 ms loop seen every 55 ms: the reported tick slides by 3 ms a
frame, so for ~10 frames every other tick is unreported and always the same one of the pair).

Where the controller moves its command within the outer period (the torque set at the outer
tick, the speed feedforward every tick), the unreported phase lies off the line through the
reported one by up to one tick's change of the command, with one sign for the whole block:
nothing recorded says where inside the pair the command moved. The term is taken from the
recording alone (the run's periods and the reported commands): per unreported tick,
``|slope of the reported commands| x inner period``, times one uniform draw in [-1, 1] per block
of frames that report the same phase (the bend term's convention, std dev/sqrt 3). Its own
replays' spread is joined in quadrature to ``replay.unseen.input_uncertainty``'s (patched here)
on the runs whose unreported ticks were not refined by the closed-loop replay's pattern (a
reference lib/control does not replay, e.g. the truth simulator's ``segments`` tours), and the
analysis runs as usual.

Usage (nice it; one process):

  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_phase_term.py [--off] CASE_DIR ...

Prints per case: verdict, the three largest windows of the duty replay in noise floors (the
strong-window threshold for comparison) and the selected effects with their fitted values.
``--off``: the analyzer as it is (the same script without the patch, for a like-for-like
comparison).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import os
import sys
from pathlib import Path
from typing import cast

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools.analyzer import pipeline  # noqa: E402
from host_tools.analyzer.locate.mismatch import strong_threshold  # noqa: E402
from host_tools.analyzer.prepare.run import PreparedRun  # noqa: E402
from host_tools.analyzer.replay import nominal as NOM  # noqa: E402
from host_tools.analyzer.replay.openloop import OpenLoopReplay  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402
from host_tools.analyzer.replay.channels import channels  # noqa: E402


def phase_term(prep: PreparedRun) -> tuple[np.ndarray, np.ndarray] | None:
    """(block of each unreported tick, per side the half-width of its phase offset), or None
    when the run's outer period is a single tick or every tick is reported."""
    seen = prep.seen_ticks
    per = prep.run.meta.get("periods_s", {})
    inner, outer = float(per.get("inner", 0.0) or 0.0), float(per.get("outer", 0.0) or 0.0)
    m = int(round(outer / inner)) if inner > 0 else 0
    if seen is None or m < 2:
        return None
    seen = np.asarray(seen, bool)
    i_seen, unseen = np.flatnonzero(seen), np.flatnonzero(~seen)
    if unseen.size == 0 or i_seen.size < 3:
        return None
    t = np.asarray(prep.t_in, float)
    if any(np.any(np.abs(np.asarray(u, float)[unseen]
                         - np.interp(t[unseen], t[i_seen], np.asarray(u, float)[i_seen])) > 1e-12)
           for u in prep.duty):
        return None   # refined by the closed-loop replay's pattern (fill_unseen_from_controller)
    k = np.round((t - (prep.tick_phase or 0.0)) / inner).astype(np.int64)
    # the phase (within the outer period) of the reported tick before each unreported one: a
    # block is a run of unreported ticks whose reported neighbours keep their phase
    j = np.clip(np.searchsorted(i_seen, unseen) - 1, 0, i_seen.size - 1)
    ph = k[i_seen[j]] % m
    block = np.concatenate([[0], np.cumsum(np.diff(ph) != 0)])
    half = []
    for u in prep.duty:
        us = np.asarray(u, float)[i_seen]
        slope = np.gradient(us, t[i_seen]) if us.size > 1 else np.zeros(us.size)
        half.append(np.abs(np.interp(t[unseen], t[i_seen], slope)) * inner)
    return block, np.array(half)


def input_uncertainty_with_phase(prep: PreparedRun, replay: OpenLoopReplay,
                                 n: int = UN.UNSEEN_ENSEMBLE) -> UN.ReplayUnc | None:
    """``unseen.input_uncertainty`` (bend per gap, white per tick) joined in quadrature with
    the spread of ``n`` replays whose unreported ticks carry only :func:`phase_term`'s offsets
    (one uniform draw in [-1, 1] per block, times each tick's half-width): independent draws,
    so their variances add."""
    base = UN.input_uncertainty(prep, replay, n)
    pt = phase_term(prep)
    if pt is None or base is None:
        return base
    block, half = pt
    unseen = np.flatnonzero(~np.asarray(prep.seen_ticks, bool))
    seed = int(np.uint32(int(np.sum(np.asarray(prep.run.telemetry["t_s"], float) * 1e3)) & 0xFFFFFFFF))
    rng = np.random.default_rng([seed, unseen.size, 2])
    acc: dict[str, list[np.ndarray]] = {}
    t_of: dict[str, np.ndarray] = {}
    for _ in range(n):
        zb = rng.uniform(-1.0, 1.0, int(block[-1]) + 1)
        draw = []
        for side, u in enumerate(prep.duty):
            v = np.asarray(u, float).copy()
            v[unseen] += zb[block] * half[side]
            draw.append(np.clip(v, -1.0, 1.0))
        drawn = dataclasses.replace(prep, duty=cast("tuple[np.ndarray, np.ndarray]", tuple(draw)))
        for name, ch in channels(drawn, replay.simulate_windows(drawn, {}), "duty").items():
            acc.setdefault(name, []).append(ch.resid)
            t_of[name] = ch.t
    out = dict(base)
    for name, v in acc.items():
        if name in base and len({x.size for x in v}) == 1 and t_of[name].size:
            t_b, s_b = base[name]
            s_p = np.std(np.array(v), axis=0)
            out[name] = (t_b, np.sqrt(s_b ** 2 + np.interp(t_b, t_of[name], s_p) ** 2))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", help="case folders (a suite runs/<case>)")
    ap.add_argument("--off", action="store_true", help="the analyzer as it is")
    a = ap.parse_args(argv)
    if not a.off:
        NOM.input_uncertainty = input_uncertainty_with_phase  # type: ignore[attr-defined]  # replay_open_loop calls this name
    for case in a.cases:
        runs = sorted(str(p) for p in Path(case).iterdir() if (p / "meta.json").exists())
        with contextlib.redirect_stderr(io.StringIO()):
            an = pipeline.analyze(runs, jobs=1, log=lambda m: None)
        total = sum(float(r.telemetry["t_s"][-1] - r.telemetry["t_s"][0]) for r in an.runs)
        duty = [e for e in an.mismatch if e.get("replay") == "duty"]
        top = sorted(duty, key=lambda e: -e["rms"] / e["noise_floor"])[:3]
        print(f"{Path(case).name} [{'as is' if a.off else 'phase term'}]: {an.verdict}; "
              f"{len(duty)} windows, strong at {strong_threshold(total):.2f} floors; largest: "
              + ", ".join(f"{e['run']} {e['channel']} {e['t_start_s']:.2f}-{e['t_end_s']:.2f} s "
                          f"{e['rms'] / e['noise_floor']:.2f}" for e in top)
              + "; selected: " + (", ".join(f"{s['effect']} {s['params']}" for s in an.selected)
                                  or "-"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
