"""Measurement and prototype: the commands of unreported ticks of a single-loop PI recorder
(``controller: "pi"``, a 25 ms loop seen by 38 ms frames: a third of the ticks unreported)
against the straight-line fill (docs/analyzer.md, "Ticks no frame reported") and the spread
``replay.unseen.input_uncertainty`` gives it; and a prototype "spike term" for that spread.

The PI's torque has an acceleration feed-forward of the reference: where the reference's
acceleration is on for less than a tick (a small speed change, a turn-rate change), one tick
carries a command pulse that neither neighbour shows.  An unreported tick with such a pulse is
filled on the line between its reported neighbours; the bend term of ``input_uncertainty``
(trends of the reported commands carried into the gap) cannot see it, since the reported
commands around it run straight.

Prototype (``--spike``): the rate and size of such one-tick excursions measured on the
reported ticks that have both tick neighbours' commands reported (a run seen at 38/25 ms
reports pairs of consecutive ticks: for a reported tick with reported ticks on either side,
how far its command lies beyond both, soft-thresholded at 3 sigma of the tick-level scatter);
the RMS of that excursion over those ticks is the std of an unreported tick's excursion,
assuming the frames' phase is independent of the reference's events.  It is added in
quadrature to the white (per tick, independent) draw of ``input_uncertainty``.  Nothing but
the reported commands enters: no controller, no reference, no engine.

A second prototype (``analyze --pulse``), local instead of a spread: a duty window at or above
the strong threshold is re-measured after the best move of ONE unreported tick within
PULSE_REACH_S before it (or inside it), per side within +- the largest tick-to-tick change of
the command that the run's reported pairs of consecutive ticks show beyond their trend
(:func:`tick_step_bound`: the controller's largest one-tick move seen, e.g. a feed-forward
step where a ramp starts, the same size as a one-tick pulse where a ramp lasts under a tick);
the window keeps the RMS left (least squares on the replay's linear response to each side's
move, re-replayed).  One free tick per window, bounded by what the recording shows.

Sub-commands (nice them; one process each):

  ticks --runs CASE_DIR --full FULL_CASE_DIR [--at RUN:T0,T1]
      per run and side: the unreported ticks' fill error (line - true) against the std the
      analyzer draws for them (bend, white; and the spike term), the count beyond 3 and 5
      sigma, the five largest with their shape (``spike``: the true command beyond both
      reported neighbours; ``step``: between them), the share of the error's energy in spikes.
      ``--at``: every unreported tick in that span.  FULL_CASE_DIR: the same case recorded with
      frames at the loop's period (``suite generate ... --recorder tel_s=0.025``), whose
      reported commands are every tick's.

  windows CASE_DIR [--full FULL_CASE_DIR] [--spike] [--frac F]
      the nominal duty replay's windows (locate stage, before any fit) at >= F of the strong
      threshold, with the analyzer's commands, and with FULL's on the unreported ticks (which
      windows the fill makes), each with and without the spike term.

  analyze CASE_DIR ... [--spike [rms|event]] [--pulse]
      the whole analysis: verdict, the three largest duty windows against the strong
      threshold, the selected effects; ``--spike``: with the spread prototype (``rms``: the
      excursions' RMS on every unreported tick; ``event``: their largest, uniform, where the
      reported commands bend); ``--pulse``: with the window prototype (prints each strong
      window's RMS before and after, and the tick).

  strong CASE_DIR ...
      the locate stage only, with the window prototype: per case the strong duty windows in
      the fit channels before and after, and the window whose RMS one tick's move lowers most
      (a case that keeps a strong window keeps its route to a mismatch).

Commands used for the report (analyzer at d50386a + fill_spread split out of
input_uncertainty, no change of behaviour):

  PYTHONPATH=. nice .venv/bin/python -m host_tools.suite generate --set heldback15 \\
      --cases hb15_mj_long_null_60s --recorder tel_s=0.025 --out /tmp/an-pi/mjfull
  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_pi_spike.py ticks \\
      --runs /work/wt/score-data/heldback15/runs/hb15_mj_long_null_60s \\
      --full /tmp/an-pi/mjfull/runs/hb15_mj_long_null_60s --at run-0:14.6,15.05
  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_pi_spike.py windows \\
      /work/wt/score-data/heldback15/runs/hb15_mj_long_null_60s \\
      --full /tmp/an-pi/mjfull/runs/hb15_mj_long_null_60s
  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_pi_spike.py analyze [--pulse] \\
      /work/wt/score-data/heldback15/runs/hb15_mj_long_null_60s
  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_pi_spike.py strong CASE_DIR ...
  # the truth engine's twin (seed offsets 0-2), each with its every-tick recording:
  PYTHONPATH=. nice .venv/bin/python -m host_tools.suite generate --set heldback15 \\
      --cases hb15_mj_long_null_60s --engine truth --seed-offset S [--recorder tel_s=0.025] \\
      --out DIR
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import math
import os
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools import runfmt  # noqa: E402
from host_tools.analyzer import pipeline  # noqa: E402
from host_tools.analyzer.locate.mismatch import locate_mismatch, strong_threshold  # noqa: E402
from host_tools.analyzer.prepare.inputs import prepare_runs  # noqa: E402
from host_tools.analyzer.prepare.run import PreparedRun  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402
from host_tools.analyzer.replay.nominal import replay_closed_loop, replay_open_loop  # noqa: E402
from host_tools.analyzer.signals import robust_std  # noqa: E402

SPIKE_SCATTER_SIGMA = 3.0   # excursions within this many sigma of the tick-level scatter: scatter

_fill_spread = UN.fill_spread


def spike_std(prep: PreparedRun, stat: str = "rms") -> list[float]:
    """Per side, the RMS of the one-tick excursion beyond both tick neighbours over the reported
    ticks whose two tick neighbours are reported too (soft-thresholded at SPIKE_SCATTER_SIGMA
    of the scatter of those excursions), 0 where no such tick exists."""
    seen = prep.seen_ticks
    if seen is None:
        return [0.0, 0.0]
    seen = np.asarray(seen, bool)
    i = np.flatnonzero(seen[1:-1] & seen[:-2] & seen[2:]) + 1
    # a 38/25 ms run reports no three consecutive ticks: the neighbours one or two ticks away,
    # both reported, the nearer each side
    if i.size < 10:
        i_seen = np.flatnonzero(seen)
        i = i_seen[1:-1]
        nb = (i_seen[:-2], i_seen[2:])
        near = (i - nb[0] <= 2) & (nb[1] - i <= 2) & ((i - nb[0] == 1) | (nb[1] - i == 1))
        i, lo_i, hi_i = i[near], nb[0][near], nb[1][near]
    else:
        lo_i, hi_i = i - 1, i + 1
    out = []
    for u in prep.duty:
        u = np.asarray(u, float)
        if i.size < 10:
            out.append(0.0)
            continue
        a, b, c = u[lo_i], u[i], u[hi_i]
        x = np.maximum(b - np.maximum(a, c), 0.0) - np.maximum(np.minimum(a, c) - b, 0.0)
        s = robust_std(b - 0.5 * (a + c))
        x = np.sign(x) * np.maximum(np.abs(x) - SPIKE_SCATTER_SIGMA * s, 0.0)
        out.append(math.sqrt(float(np.mean(x ** 2))) if stat == "rms" else float(np.max(np.abs(x))))
    return out


SPIKE_MODE = {"mode": "rms"}


def fill_spread_with_spike(prep: PreparedRun) -> Any:
    """``replay.unseen.fill_spread`` with the spike term: ``rms`` (SPIKE_MODE): :func:`spike_std`
    added to the white draw of every unreported tick; ``event``: the run's largest one-tick
    excursion A (over its reported ticks with both tick neighbours reported) as a uniform draw
    in [-A, A] (std A / sqrt 3) added to the bend's std at the unreported ticks where the
    reported commands bend (the bend's departure beyond SPIKE_SCATTER_SIGMA x the white
    scatter: a step, a ramp's start or end, where the reference changes)."""
    spread = _fill_spread(prep)
    if spread is None:
        return None
    unseen, gap, white, bend = spread
    if SPIKE_MODE["mode"] == "event":
        amp = spike_std(prep, "max")
        bend2 = [np.where(b * math.sqrt(3.0) > SPIKE_SCATTER_SIGMA * w,
                          np.hypot(b, a / math.sqrt(3.0)), b)
                 for b, w, a in zip(bend, white, amp)]
        return unseen, gap, white, bend2
    sp = spike_std(prep)
    return unseen, gap, [math.hypot(w, s) for w, s in zip(white, sp)], bend


def _case_runs(case: str) -> list[str]:
    return sorted(str(p) for p in Path(case).iterdir() if (p / "meta.json").exists())


def _true_duty(prep: PreparedRun, full: runfmt.Run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ok, duty r, duty l) at ``prep``'s ticks from a recording that reports every tick."""
    period = float(prep.inner_period)
    t = np.asarray(full.telemetry["t_s"], float)
    kf = np.floor(t / period + 1e-9).astype(np.int64)
    kf, first = np.unique(kf, return_index=True)
    k = np.round(np.asarray(prep.t_in, float) / period).astype(np.int64)
    idx = np.clip(np.searchsorted(kf, k), 0, kf.size - 1)
    ok = kf[idx] == k
    return (ok, np.asarray(full.telemetry["pwm_r"], float)[first][idx],
            np.asarray(full.telemetry["pwm_l"], float)[first][idx])


def cmd_ticks(a: argparse.Namespace) -> int:
    names = [Path(p).name for p in _case_runs(a.runs)]
    runs = [runfmt.load_run(os.path.join(a.runs, n)) for n in names]
    fulls = [runfmt.load_run(os.path.join(a.full, n)) for n in names]
    preps = prepare_runs(runs, lambda m: None)
    at = None
    if a.at:
        r, span = a.at.split(":")
        at = (r, *(float(x) for x in span.split(",")))
    for p, full in zip(preps, fulls):
        spread = UN.fill_spread(p)
        if spread is None:
            print(f"== {p.name}: every tick reported")
            continue
        unseen, _gap, white, bend = spread
        ok, ur, ul = _true_duty(p, full)
        seen = np.asarray(p.seen_ticks, bool)
        i_seen = np.flatnonzero(seen)
        j = np.clip(np.searchsorted(i_seen, unseen), 1, i_seen.size - 1)
        prev_i, next_i = i_seen[j - 1], i_seen[j]
        sp = spike_std(p)
        amp = spike_std(p, "max")
        t = np.asarray(p.t_in, float)
        print(f"== {p.name}: ticks {t.size}, unreported {unseen.size}; reported ticks against "
              f"the full recording: max |diff| "
              f"{max(float(np.max(np.abs(np.asarray(p.duty[s])[seen & ok] - (ur, ul)[s][seen & ok]))) for s in (0, 1)):.1e}")
        for side, u_true in enumerate((ur, ul)):
            u = np.asarray(p.duty[side], float)
            m = ok[unseen]
            e = (u[unseen] - u_true[unseen])[m]
            sd0 = np.hypot(bend[side][m], white[side])
            sd1 = np.hypot(sd0, sp[side])
            ev = bend[side][m] * math.sqrt(3.0) > SPIKE_SCATTER_SIGMA * white[side]
            sd2 = np.hypot(np.where(ev, np.hypot(bend[side][m], amp[side] / math.sqrt(3.0)),
                                    bend[side][m]), white[side])
            z0 = e / np.maximum(sd0, 1e-12)
            lo = np.minimum(u[prev_i], u[next_i])[m]
            hi = np.maximum(u[prev_i], u[next_i])[m]
            tv = u_true[unseen][m]
            beyond = np.maximum(tv - hi, lo - tv)
            spike = beyond > SPIKE_SCATTER_SIGMA * white[side]
            e2 = float(np.sum(e ** 2))
            print(f"   duty {'rl'[side]}: fill error RMS {math.sqrt(float(np.mean(e ** 2))):.4f}, "
                  f"std drawn (bend+white) RMS {math.sqrt(float(np.mean(sd0 ** 2))):.4f} "
                  f"(white {white[side]:.4f}); |z| > 3: {int(np.sum(np.abs(z0) > 3))}, > 5: "
                  f"{int(np.sum(np.abs(z0) > 5))} of {e.size}; spikes beyond both neighbours: "
                  f"{int(spike.sum())}, {100 * float(np.sum(e[spike] ** 2)) / max(e2, 1e-30):.0f} % "
                  f"of the error's energy; spike term {sp[side]:.4f} -> std RMS "
                  f"{math.sqrt(float(np.mean(sd1 ** 2))):.4f}, |z| > 3: "
                  f"{int(np.sum(np.abs(e / sd1) > 3))}, > 5: {int(np.sum(np.abs(e / sd1) > 5))}; "
                  f"event term A {amp[side]:.4f} on {int(ev.sum())} ticks -> std RMS "
                  f"{math.sqrt(float(np.mean(sd2 ** 2))):.4f}, |z| > 3: "
                  f"{int(np.sum(np.abs(e / sd2) > 3))}, > 5: {int(np.sum(np.abs(e / sd2) > 5))}")
            order = np.argsort(-np.abs(z0))[:5]
            tk = t[unseen][m]
            for q in order:
                print(f"      t {tk[q]:7.3f} s true {tv[q]:+.4f} fill {u[unseen][m][q]:+.4f} error "
                      f"{e[q]:+.4f}  bend sd {bend[side][m][q]:.4f}  z {z0[q]:+6.1f} "
                      f"(event term: {e[q] / sd2[q]:+5.1f})  "
                      f"{'spike' if spike[q] else 'step '} (neighbours {lo[q]:+.4f}..{hi[q]:+.4f})")
            if at is not None and at[0] == p.name:
                for q in np.flatnonzero((tk >= at[1]) & (tk <= at[2])):
                    print(f"      [at] t {tk[q]:7.3f} s true {tv[q]:+.4f} fill "
                          f"{u[unseen][m][q]:+.4f} error {e[q]:+.4f} bend sd "
                          f"{bend[side][m][q]:.4f} white {white[side]:.4f} z {z0[q]:+6.1f} "
                          f"{'spike' if spike[q] else 'step'}")
    return 0


def _windows(preps: Sequence[PreparedRun], total: float) -> list[dict[str, Any]]:
    quiet: list[str] = []
    with contextlib.redirect_stderr(io.StringIO()):
        preps2, _cl = replay_closed_loop(list(preps), 5e-4, [], quiet.append)
        ol = replay_open_loop(preps2, 5e-4)
        _p, _n, loc = locate_mismatch(ol.preps, ol.nominal, ol.nominal_t, _cl.nominal,
                                      quiet.append)
    return [e for e in loc.entries]


def _with_true(preps: Sequence[PreparedRun], fulls: Sequence[runfmt.Run]) -> list[PreparedRun]:
    out = []
    for p, full in zip(preps, fulls):
        if p.seen_ticks is None:
            out.append(p)
            continue
        ok, ur, ul = _true_duty(p, full)
        unseen = ~np.asarray(p.seen_ticks, bool) & ok
        duty = [np.asarray(p.duty[s], float).copy() for s in (0, 1)]
        for s, u in enumerate((ur, ul)):
            duty[s][unseen] = u[unseen]
        out.append(dataclasses.replace(p, duty=(duty[0], duty[1])))
    return out


def _overlap(w: dict[str, Any], ws: Sequence[dict[str, Any]]) -> float:
    """The largest ratio (RMS / floor) of the windows of ``ws`` on ``w``'s run and channel that
    overlap it, 0 if none."""
    return max((v["rms"] / v["noise_floor"] for v in ws
                if v["run"] == w["run"] and v["channel"] == w["channel"]
                and v["t_start_s"] <= w["t_end_s"] and v["t_end_s"] >= w["t_start_s"]), default=0.0)


def cmd_windows(a: argparse.Namespace) -> int:
    paths = _case_runs(a.case)
    runs = [runfmt.load_run(p) for p in paths]
    total = sum(float(r.telemetry["t_s"][-1] - r.telemetry["t_s"][0]) for r in runs)
    thr = strong_threshold(total)
    preps = prepare_runs(runs, lambda m: None)
    variants: list[tuple[str, list[PreparedRun]]] = [("fill", preps)]
    if a.full:
        fulls = [runfmt.load_run(os.path.join(a.full, Path(p).name)) for p in paths]
        variants.append(("true", _with_true(preps, fulls)))
    for spike in ((False, True) if a.spike else (False,)):
        UN.fill_spread = fill_spread_with_spike if spike else _fill_spread
        found: dict[str, list[dict[str, Any]]] = {}
        for lab, pr in variants:
            found[lab] = _windows(pr, total)
        for lab in found:
            ws = found[lab]
            big = sorted((w for w in ws if w["rms"] / w["noise_floor"] >= a.frac * thr),
                         key=lambda w: -w["rms"] / w["noise_floor"])
            print(f"{Path(a.case).name} [{lab} commands on unreported ticks"
                  f"{', spike term ' + a.spike if spike else ''}]: strong at {thr:.2f}; "
                  f"{len(ws)} windows, {len(big)} >= {a.frac:g} x: " + ", ".join(
                      f"{w['run']} {w['channel']} {w['t_start_s']:.3f}-{w['t_end_s']:.3f} "
                      f"{w['rms'] / w['noise_floor']:.2f}"
                      + (f" (true: {_overlap(w, found['true']):.2f})"
                         if lab == "fill" and a.full else "") for w in big[:8]) if lab == "fill"
                  else "")
        if a.full:
            big = [w for w in found["fill"] if w["rms"] / w["noise_floor"] >= a.frac * thr]
            gone = [w for w in big if _overlap(w, found["true"]) < a.frac * thr]
            print(f"   SUMMARY {Path(a.case).name}{' spike ' + a.spike if spike else ''}: "
                  f"near-threshold windows (>= {a.frac:g} x {thr:.2f}) with the fill "
                  f"{len(big)}, of which below that with the true commands {len(gone)}; "
                  f"largest fill {max((w['rms'] / w['noise_floor'] for w in found['fill']), default=0):.2f}, "
                  f"largest true {max((w['rms'] / w['noise_floor'] for w in found['true']), default=0):.2f}; "
                  f"windows fill {len(found['fill'])}, true {len(found['true'])}")
    UN.fill_spread = _fill_spread
    return 0


PULSE_REACH_S = 0.25   # unreported ticks this long before a window can have made it


def tick_step_bound(prep: PreparedRun) -> list[float]:
    """Per side, the largest change of the command from one tick to the next seen among the
    reported pairs of consecutive ticks, beyond the trend of the reported commands around the
    pair (the line through the reported ticks before and after it): how far the controller
    moved its command within one tick somewhere in the run (a feed-forward step where a ramp
    starts: the edge of the same size as a one-tick pulse where a ramp lasts under a tick)."""
    seen = prep.seen_ticks
    if seen is None:
        return [0.0, 0.0]
    seen = np.asarray(seen, bool)
    t = np.asarray(prep.t_in, float)
    i_seen = np.flatnonzero(seen)
    # pairs (i, i + 1) both reported, with a reported tick before and after the pair
    j = np.flatnonzero((np.diff(i_seen) == 1)[1:-1]) + 1
    out = []
    for u in prep.duty:
        u = np.asarray(u, float)
        if j.size == 0:
            out.append(0.0)
            continue
        a, b = i_seen[j], i_seen[j + 1]
        lo, hi = i_seen[j - 1], i_seen[j + 2]
        slope = (u[hi] - u[lo]) / np.maximum(t[hi] - t[lo], 1e-9)
        out.append(float(np.max(np.abs(u[b] - u[a] - slope * (t[b] - t[a])))))
    return out


def _window_rms(ch: Any, floor: float, t0: float, t1: float) -> np.ndarray:
    m = (ch.t >= t0 - 1e-9) & (ch.t <= t1 + 1e-9)
    out: np.ndarray = np.asarray(ch.deflated(floor), float)[m]
    return out


def pulse_profiled(prep: PreparedRun, nominal: Any, floors: Any, entry: dict[str, Any],
                   replay: Any) -> tuple[float, float, float]:
    """The window's RMS (floors) with the best single unreported tick within PULSE_REACH_S
    before it (or inside it) moved within +- :func:`tick_step_bound` of its fill, per side
    (least squares on the replay's linear response to each side's move, then re-replayed):
    (that RMS in floors, the tick's time, 0 when no tick fits)."""
    from host_tools.analyzer.replay.channels import channels
    c, t0, t1 = entry["channel"], float(entry["t_start_s"]), float(entry["t_end_s"])
    fl = float(floors[c])
    r0 = _window_rms(nominal[c], fl, t0, t1)
    best = (math.sqrt(float(np.mean(r0 ** 2))) / fl, 0.0)
    if prep.seen_ticks is None:
        return best[0], best[1], best[0]
    bound = tick_step_bound(prep)
    t = np.asarray(prep.t_in, float)
    cand = np.flatnonzero(~np.asarray(prep.seen_ticks, bool) & (t >= t0 - PULSE_REACH_S)
                          & (t <= t1))
    base = [np.asarray(u, float) for u in prep.duty]
    # only the replay window that holds the entry's middle (a long run's windows re-anchor)
    tf = np.asarray(prep.run.telemetry["t_s"], float)
    i_mid = int(np.searchsorted(tf, 0.5 * (t0 + t1)))
    which = [next((w for w, (ia, ib) in enumerate(prep.windows) if ia <= i_mid < ib), 0)]

    def resid(dr: float, dl: float, k: int) -> np.ndarray:
        d = [base[0].copy(), base[1].copy()]
        if k >= 0:
            d[0][k] += dr
            d[1][k] += dl
        q = dataclasses.replace(prep, duty=(np.clip(d[0], -1, 1), np.clip(d[1], -1, 1)))
        return _window_rms(channels(q, replay.simulate_windows(q, {}, which), "duty")[c],
                           fl, t0, t1)
    if len(prep.windows) > 1:
        r0 = resid(0.0, 0.0, -1)   # the same window replayed alone
        if r0.size == 0:
            return best[0], best[1], best[0]
    for k in cand:
        h = 0.01
        sr = (resid(h, 0.0, int(k)) - r0) / h
        sl = (resid(0.0, h, int(k)) - r0) / h
        S = np.stack([sr, sl], axis=1)
        x, *_ = np.linalg.lstsq(S, -r0, rcond=None)
        x = np.clip(x, [-bound[0], -bound[1]], [bound[0], bound[1]])
        r = resid(float(x[0]), float(x[1]), int(k))
        v = math.sqrt(float(np.mean(r ** 2))) / fl
        if v < best[0]:
            best = (v, float(t[k]))
    return best[0], best[1], math.sqrt(float(np.mean(r0 ** 2))) / fl


def _with_pulse(locate: Any, replay: Any, log: Any) -> Any:
    """``locate_mismatch`` whose duty windows at the strong threshold or above get the RMS
    left after the best single unreported tick's move (:func:`pulse_profiled`)."""
    def wrapped(preps: Any, nominal: Any, nominal_t: Any, cl_nominal: Any, lg: Any) -> Any:
        preps2, nom2, loc = locate(preps, nominal, nominal_t, cl_nominal, lg)
        total = sum(float(p.run.telemetry["t_s"][-1] - p.run.telemetry["t_s"][0]) for p in preps2)
        thr = strong_threshold(total)
        names = [p.name for p in preps2]
        for e in loc.entries:
            if e["rms"] < thr * e["noise_floor"]:
                continue
            i = names.index(e["run"])
            v, tk, v0 = pulse_profiled(preps2[i], nom2[i], loc.floors, e, replay)
            log(f"   pulse: {e['run']} {e['channel']} {e['t_start_s']:.3f}-{e['t_end_s']:.3f} s "
                f"{v0:.2f} -> {v:.2f} floors (tick at {tk:.3f} s; bound "
                f"{', '.join(f'{b:.4f}' for b in tick_step_bound(preps2[i]))})")
            e["rms"] = v * e["noise_floor"]
        return preps2, nom2, loc
    return wrapped


def cmd_strong(a: argparse.Namespace) -> int:
    """The locate stage only, with the window prototype: how many strong duty windows each
    case has before and after (a case that keeps one keeps its route to a mismatch)."""
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    replay = OpenLoopReplay("duty", dt_s=5e-4)
    for case in a.cases:
        runs = [runfmt.load_run(p) for p in _case_runs(case)]
        total = sum(float(r.telemetry["t_s"][-1] - r.telemetry["t_s"][0]) for r in runs)
        thr = strong_threshold(total)
        lines: list[str] = []
        with contextlib.redirect_stderr(io.StringIO()):
            preps = prepare_runs(runs, lambda m: None)
            preps, cl = replay_closed_loop(preps, 5e-4, [], lambda m: None)
            ol = replay_open_loop(preps, 5e-4)
            before: list[dict[str, Any]] = []

            def spy(*args: Any) -> Any:
                out = locate_mismatch(*args)
                before.extend(dict(e) for e in out[2].entries)
                return out
            loc_fn = _with_pulse(spy, replay, lines.append)
            _p, _n, loc = loc_fn(ol.preps, ol.nominal, ol.nominal_t, cl.nominal, lambda m: None)
        from host_tools.analyzer.replay.channels import FIT_CHANNELS
        n0 = sum(e["rms"] >= thr * e["noise_floor"] for e in before if e["channel"] in FIT_CHANNELS)
        n1 = sum(e["rms"] >= thr * e["noise_floor"] for e in loc.entries
                 if e["channel"] in FIT_CHANNELS)
        pairs = [(float(ln.split("->")[0].split()[-1]), float(ln.split("->")[1].split()[0]), ln)
                 for ln in lines if "->" in ln]
        low = min(pairs, key=lambda q: q[1] / max(q[0], 1e-9), default=None)
        print(f"{Path(case).name}: strong at {thr:.2f}; strong duty windows in fit channels "
              f"{n0} -> {n1}" + ("  ALL GONE" if n0 and not n1 else "")
              + (f"; the largest share one tick explains: {low[0]:.2f} -> {low[1]:.2f} floors "
                 f"(ratio {low[1] / max(low[0], 1e-9):.3f}): {low[2].strip()}" if low else ""),
              flush=True)
    return 0


def cmd_analyze(a: argparse.Namespace) -> int:
    if a.spike:
        UN.fill_spread = fill_spread_with_spike
    if a.pulse:
        from host_tools.analyzer.replay.openloop import OpenLoopReplay
        # the name the pipeline calls
        pipeline.locate_mismatch = _with_pulse(  # type: ignore[attr-defined]
            locate_mismatch, OpenLoopReplay("duty", dt_s=5e-4), print)
    for case in a.cases:
        with contextlib.redirect_stderr(io.StringIO()):
            an = pipeline.analyze(_case_runs(case), jobs=1, log=lambda m: None)
        total = sum(float(r.telemetry["t_s"][-1] - r.telemetry["t_s"][0]) for r in an.runs)
        duty = [e for e in an.mismatch if e.get("replay") == "duty"]
        top = sorted(duty, key=lambda e: -e["rms"] / e["noise_floor"])[:3]
        sp = [spike_std(p) for p in an.preps]
        print(f"{Path(case).name} [{'spike term ' + a.spike if a.spike else 'pulse' if a.pulse else 'as is'}]: {an.verdict}; "
              f"spike std per run {', '.join(f'{s[0]:.4f}/{s[1]:.4f}' for s in sp)}; "
              f"{len(duty)} windows, strong at {strong_threshold(total):.2f}; largest: "
              + ", ".join(f"{e['run']} {e['channel']} {e['t_start_s']:.2f}-{e['t_end_s']:.2f} s "
                          f"{e['rms'] / e['noise_floor']:.2f}" for e in top)
              + "; selected: " + (", ".join(f"{s['effect']} {s['params']}" for s in an.selected)
                                  or "-"), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("ticks")
    p.add_argument("--runs", required=True)
    p.add_argument("--full", required=True)
    p.add_argument("--at", default=None, metavar="RUN:T0,T1")
    p = sub.add_parser("windows")
    p.add_argument("case")
    p.add_argument("--full", default=None)
    p.add_argument("--spike", nargs="?", const="rms", default=None, choices=("rms", "event"))
    p.add_argument("--frac", type=float, default=0.75)
    p = sub.add_parser("analyze")
    p.add_argument("cases", nargs="+")
    p.add_argument("--spike", nargs="?", const="rms", default=None, choices=("rms", "event"))
    p.add_argument("--pulse", action="store_true",
                   help="strong windows re-measured after the best single unreported tick's "
                        "move within the run's largest reported tick-to-tick change")
    p = sub.add_parser("strong")
    p.add_argument("cases", nargs="+")
    a = ap.parse_args(argv)
    if a.cmd in ("windows", "analyze") and a.spike:
        SPIKE_MODE["mode"] = a.spike
    return {"ticks": cmd_ticks, "windows": cmd_windows, "analyze": cmd_analyze,
            "strong": cmd_strong}[a.cmd](a)


if __name__ == "__main__":
    raise SystemExit(main())
