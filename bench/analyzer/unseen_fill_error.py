"""Measurement: how far the analyzer's commands for the inner ticks no telemetry frame reported
(a loop faster than the telemetry; docs/analyzer.md, "Ticks no frame reported" and "The
replay's uncertainty from unreported commands") are from the commands the recorder gave, and
what that does to the duty replay's wheel-speed channels.

Needs two recordings of the same case with the same seed and engine: ``--runs`` with the
recorder under study (e.g. a 29 ms loop seen every 55 ms) and ``--full`` with the telemetry
period set to the inner period (``suite bench ... --recorder tel_s=<inner_s>``), whose frames
report every tick: the recorder's physics and controller do not depend on the telemetry
period, so its reported duties are the ticks' true commands.

For each run it prints:
  * the fill's error on the unreported ticks (the line between the reported ones, and the
    line refined by the closed-loop replay's pattern, or for a PI loop with its count
    quantization taken out (``fill_count_level``), as the analyzer replays them), RMS and
    the mean over blocks of constant parity of the reported ticks, against the input
    uncertainty the analyzer assumes for them (std of its uniform draw: bend / sqrt 3, and
    the tick-level scatter);
  * the nominal duty replay's wheel-speed residual (RMS, rad/s, and in the channel's noise
    floor as the analysis computed it) with the analyzer's commands and with the true ones
    on every tick, overall and where |wheel acceleration| > 12 rad/s^2 (the report's regime).

Usage (nice it; one process, ~1 min for two 20 s runs):

  PYTHONPATH=. nice .venv/bin/python bench/analyzer/unseen_fill_error.py \
      --runs OUT/runs/CASE --full OUT_FULL/runs/CASE [--dump 0.4,0.9]
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
from host_tools.analyzer.locate.floors import noise_floors  # noqa: E402
from host_tools.analyzer.prepare.run import PreparedRun  # noqa: E402
from host_tools.analyzer.replay.channels import Channel  # noqa: E402
from host_tools.analyzer.replay.nominal import (replay_channels, replay_closed_loop,  # noqa: E402
                                                replay_open_loop)
from host_tools.analyzer.replay.unseen import (fill_spread,  # noqa: E402
                                               fill_unseen_from_controller, input_uncertainty)
from host_tools.analyzer.signals import robust_std  # noqa: E402

ACC_REGIME = 12.0  # rad/s^2: the report's "during acceleration" predicate


def _true_ticks(full: runfmt.Run, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tick index, duty r, duty l) reported by a recording whose frames see every tick."""
    t = np.asarray(full.telemetry["t_s"], float)
    k = np.floor(t / period + 1e-9).astype(np.int64)
    k, first = np.unique(k, return_index=True)
    return (k, np.asarray(full.telemetry["pwm_r"], float)[first],
            np.asarray(full.telemetry["pwm_l"], float)[first])


def _with_true_duty(prep: PreparedRun, k_true: np.ndarray,
                    u_true: tuple[np.ndarray, np.ndarray]) -> PreparedRun:
    """``prep`` with every tick's command the recorder's own (the unseen ones included)."""
    period = float(prep.inner_period)
    k = np.round(np.asarray(prep.t_in, float) / period).astype(np.int64)
    duty = []
    for side, u in enumerate(u_true):
        v = np.asarray(prep.duty[side], float).copy()
        idx = np.searchsorted(k_true, k)
        ok = (idx < k_true.size) & (k_true[np.minimum(idx, k_true.size - 1)] == k)
        v[ok] = u[idx[ok]]
        duty.append(v)
    return dataclasses.replace(prep, duty=(duty[0], duty[1]))


def _rms(x: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.square(x)))) if np.size(x) else float("nan")


def _omega_stats(ch: Channel, floor: float) -> str:
    r = ch.resid
    acc = np.gradient(ch.sim, ch.t)
    m = np.abs(acc) > ACC_REGIME
    rms = math.sqrt(float(np.mean(r ** 2)))
    rms_a = math.sqrt(float(np.mean(r[m] ** 2))) if m.any() else float("nan")
    rms_q = math.sqrt(float(np.mean(r[~m] ** 2)))
    return (f"RMS {rms:.4f} rad/s ({rms / floor:.2f} floors); |acc|>{ACC_REGIME:g}: "
            f"{rms_a:.4f} ({rms_a / floor:.2f} floors, n={int(m.sum())}); else {rms_q:.4f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", required=True, help="case folder of the recorder under study")
    ap.add_argument("--full", required=True, help="same case, telemetry at the inner period")
    ap.add_argument("--dump", default=None, metavar="T0,T1",
                    help="also print every tick between board times T0 and T1 (s): reported or "
                         "not, the true duty, the analyzer's, the error, the torque command; and "
                         "every wheel-speed sample there: recording, duty replay with the "
                         "analyzer's and with the true commands, the input uncertainty drawn")
    a = ap.parse_args(argv)
    span = tuple(float(x) for x in a.dump.split(",")) if a.dump else None
    names = sorted(p.name for p in Path(a.runs).iterdir() if (p / "meta.json").exists())
    runs = [runfmt.load_run(os.path.join(a.runs, n)) for n in names]
    fulls = [runfmt.load_run(os.path.join(a.full, n)) for n in names]
    quiet: list[str] = []
    preps0 = prepare_runs(runs, quiet.append)
    preps, _ = replay_closed_loop(preps0, 5e-4, [], quiet.append)
    ol = replay_open_loop(preps, 5e-4)
    floors = noise_floors(ol.preps, ol.nominal)
    for p0, p, pu, full, nom in zip(preps0, preps, ol.preps, fulls, ol.nominal):
        period = float(p.inner_period)
        print(f"== {p.name}: inner {period * 1e3:g} ms, telemetry "
              f"{float(np.median(np.diff(p.run.telemetry['t_s']))) * 1e3:g} ms, tick phase "
              f"{p.tick_phase}, timing: {p.timing}")
        if p.seen_ticks is None:
            print("   every tick reported")
            continue
        k_true, ur, ul = _true_ticks(full, period)
        k = np.round(np.asarray(p.t_in, float) / period).astype(np.int64)
        seen = np.asarray(p.seen_ticks, bool)
        idx = np.searchsorted(k_true, k)
        ok = (idx < k_true.size) & (k_true[np.minimum(idx, k_true.size - 1)] == k)
        unseen = ~seen & ok
        print(f"   ticks {k.size}, unreported {int((~seen).sum())} "
              f"({100 * (~seen).mean():.0f} %)")
        chk = max(float(np.max(np.abs(np.asarray(p.duty[s])[seen & ok]
                                      - (ur, ul)[s][idx[seen & ok]]))) for s in (0, 1))
        print(f"   reported ticks against the full recording: max |duty diff| {chk:.2e}")
        if span is not None:
            tf = np.asarray(full.telemetry["t_s"], float)
            kf = np.floor(tf / period + 1e-9).astype(np.int64)
            tau = dict(zip(kf.tolist(), np.asarray(full.telemetry["tau_cmd_r"], float).tolist()))
            for i in np.flatnonzero((p.t_in >= span[0]) & (p.t_in <= span[1]) & ok):
                u = float(ur[idx[i]])
                print(f"     tick {k[i]:5d} {p.t_in[i]:7.3f} s {'reported' if seen[i] else '  unseen'}"
                      f"  duty_r true {u:.4f} analyzer {p.duty[0][i]:.4f} error "
                      f"{p.duty[0][i] - u:+.4f}  tau_cmd_r {tau.get(int(k[i]), float('nan')):.4f}")
        # the parity of the reported ticks (which of the two ticks of an outer period a frame
        # sees) and its blocks
        i_seen = np.flatnonzero(seen)
        par = np.interp(np.arange(k.size), i_seen, (k[i_seen] % 2).astype(float))
        for side, (lab, u_true) in enumerate((("r", ur), ("l", ul))):
            e_line = np.asarray(p0.duty[side])[unseen] - u_true[idx[unseen]]
            e_ref = np.asarray(p.duty[side])[unseen] - u_true[idx[unseen]]
            print(f"   duty {lab}: fill error on unreported ticks: line RMS {np.sqrt(np.mean(e_line ** 2)):.4f}"
                  f" mean {np.mean(e_line):+.4f}; refined RMS {np.sqrt(np.mean(e_ref ** 2)):.4f} "
                  f"mean {np.mean(e_ref):+.4f}; robust std {robust_std(e_ref):.4f}")
            for pv in (0, 1):
                m = par[unseen] == pv
                if m.any():
                    print(f"      reported ticks {'even' if pv == 0 else 'odd'}: n {int(m.sum())}, "
                          f"refined mean {np.mean(e_ref[m]):+.4f} RMS {np.sqrt(np.mean(e_ref[m] ** 2)):.4f}")
        # unreported ticks whose fill error lies beyond 4 std of the spread the analyzer draws
        # for them (bend / sqrt 3 and the tick-level scatter in quadrature): commands that no
        # reported one shows (a pulse hidden by the frame pattern and lost frames)
        fs = fill_spread(pu)
        if fs is not None:
            us_i, _, white, bend = fs
            pos = np.searchsorted(us_i, np.flatnonzero(unseen))
            for side, u_true in enumerate((ur, ul)):
                e = np.asarray(p.duty[side])[unseen] - u_true[idx[unseen]]
                sd = np.sqrt(bend[side][pos] ** 2 + white[side] ** 2)
                far = np.abs(e) > 4.0 * sd
                print(f"   duty {'rl'[side]}: unreported ticks beyond 4 std of the drawn spread: "
                      f"{int(far.sum())} of {e.size}" + "".join(
                          f"; {float(tt):.3f} s error {float(ee):+.4f} std {float(ss):.4f}"
                          for tt, ee, ss in zip(np.asarray(p.t_in)[unseen][far][:6], e[far][:6],
                                                sd[far][:6])))
        unc = input_uncertainty(p, ol.duty)
        p_true = _with_true_duty(pu, k_true, (ur, ul))
        tru = replay_channels(p_true, ol.duty, {})
        # the closed-loop pattern rule (fill_unseen_from_controller) with an exact closed-loop
        # replay: the recorder's own commands on every tick as the "replay"
        ticks = k_true * period
        exact = {"t_s": ticks, "pwm_r": ur, "pwm_l": ul}
        p_pat, n_pat = fill_unseen_from_controller(dataclasses.replace(pu, duty=p0.duty), exact)
        pat = replay_channels(p_pat, ol.duty, {})
        for side, u_true in enumerate((ur, ul)):
            e = np.asarray(p_pat.duty[side])[unseen] - u_true[idx[unseen]]
            print(f"   duty {'rl'[side]}: with the pattern of an exact closed-loop replay ({n_pat} "
                  f"ticks): fill error RMS {np.sqrt(np.mean(e ** 2)):.4f}")
        for lab in ("omega_r", "omega_l"):
            fl = float(floors[lab]) if lab in floors else float("nan")
            print(f"   {lab} (floor {fl:.4f}): analyzer's commands: {_omega_stats(nom[lab], fl)}")
            print(f"   {lab}                  true commands:     {_omega_stats(tru[lab], fl)}")
            print(f"   {lab}   exact closed-loop pattern:     {_omega_stats(pat[lab], fl)}")
            if unc and lab in unc and nom[lab].t.size == tru[lab].t.size:
                err = nom[lab].sim - tru[lab].sim   # the replay's error from the fill alone
                u = np.interp(nom[lab].t, *unc[lab])
                acc = np.abs(np.gradient(tru[lab].sim, tru[lab].t)) > ACC_REGIME
                print(f"   {lab} replay error from the fill: RMS {_rms(err):.4f} rad/s "
                      f"(|acc|>{ACC_REGIME:g}: {_rms(err[acc]):.4f}); input uncertainty the "
                      f"analyzer assumes: RMS {_rms(u):.4f} (|acc|>{ACC_REGIME:g}: "
                      f"{_rms(u[acc]):.4f}); ratio {_rms(u) / _rms(err):.2f} "
                      f"({_rms(u[acc]) / _rms(err[acc]):.2f})")
        if span is not None and unc:
            for lab in ("omega_r", "omega_l"):
                if lab not in unc or nom[lab].t.size != tru[lab].t.size:
                    continue
                u = np.interp(nom[lab].t, *unc[lab])
                for i in np.flatnonzero((nom[lab].t >= span[0]) & (nom[lab].t <= span[1])):
                    print(f"     {lab} {nom[lab].t[i]:7.3f} s recording {nom[lab].rec[i]:+.4f} "
                          f"replay {nom[lab].sim[i]:+.4f} (resid {nom[lab].resid[i]:+.4f}) "
                          f"true-command replay {tru[lab].sim[i]:+.4f} (resid "
                          f"{tru[lab].resid[i]:+.4f}) input unc {u[i]:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
