"""Noise floors, per channel and pooled over the runs, estimated from the data: those of the
open-loop replays' channels and those of the closed-loop channels."""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from host_tools.analyzer import signals as sg
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import CUMULATIVE, Channel
from host_tools.analyzer.replay.closedloop import CLOSED_LOOP_CHANNELS


def _current_lsb_a() -> float:
    """One ADC count of the motor-current telemetry (protocol.json's scale of current_r)."""
    from host_tools import protocol
    for m in protocol.definition().by_name.values():
        for f in m.fields:
            if f.name == "current_r" and f.scale:
                return float(f.scale)
    return 0.0


def current_count_a(preps: Sequence[PreparedRun]) -> float:
    """One count of the motor-current sense, in A: the run's meta.json when it describes its
    current sense (``current_sense``: ``adc_vref_v / 2^adc_bits / volts_per_amp``), else the
    quantization step of the recorded current columns (:func:`signals.quantization_step`);
    the largest over the runs, 0 when neither says."""
    counts = []
    for p in preps:
        cs: Any = p.run.meta.get("current_sense") if isinstance(p.run.meta, Mapping) else None
        try:
            counts.append(float(cs["adc_vref_v"]) / 2 ** int(cs["adc_bits"])
                          / float(cs["volts_per_amp"]))
            continue
        except (TypeError, KeyError, ValueError, ZeroDivisionError):
            pass
        for side in ("r", "l"):
            col = p.run.telemetry.get(f"current_{side}_a")
            if col is not None and np.ptp(col) > 0:
                counts.append(sg.quantization_step(col))
    return max(counts, default=0.0)


HF_MIN_SAMPLES = 5   # signals.hf_noise_std's least samples for an estimate of its own


def pooled_hf_noise_std(res: Sequence[np.ndarray]) -> float:
    """The white part of a channel's residual over the runs (:func:`signals.hf_noise_std`): the
    RMS of the estimates of the runs with HF_MIN_SAMPLES finite samples or more (a shorter run
    gives no estimate, and counted as one of nil noise it pulled the floor down); when no run
    has that many (a 2 Hz camera over 2 s runs: three or four frames each), the robust std of
    all the runs' second differences pooled, over sqrt(6), the same estimate on the same
    differences; 0 with fewer than three of them."""
    xs = [np.asarray(x, float) for x in res]
    xs = [x[np.isfinite(x)] for x in xs]
    est = [sg.hf_noise_std(x) for x in xs if x.size >= HF_MIN_SAMPLES]
    if est:
        return float(np.sqrt(np.mean(np.square(est))))
    dd = np.concatenate([np.diff(x, 2) for x in xs if x.size >= 3] or [np.zeros(0)])
    return float(sg.robust_std(dd) / math.sqrt(6.0)) if dd.size >= 3 else 0.0


# The motor current's sense reads |I| through an ADC that reads no negative counts (protocol.json's
# current_sense, magnitude_only): where the current is within a few noise sigmas of nil, the
# ADC's noise is clipped at 0 counts, and the residual there holds a half-normal's spread
# (0.60 sigma, its second differences' MAD less still), not the noise that a flowing current
# carries.  The white part is therefore measured where the replayed current clears the clipping:
# on the second differences whose three samples all replay at least SENSE_LINEAR_K floors
# (a reading clipped with 2.3 % odds at 2 sigma), iterated once from the all-sample estimate.
# heldback27's truth tour null (ADC noise 7.0 LSB = 20.7 mA): 80 % of its samples near rest,
# floor 11.6-12.1 mA over all of them, 21.7 mA where the current flows.
SENSE_LINEAR_K = 2.0
SENSE_LINEAR_MIN = 30   # least second differences in the linear range for an estimate


def sense_linear_noise_std(chans: Sequence[Channel], floor0: float) -> float:
    """The white part of a magnitude-only current's residual where the replayed current is at
    least SENSE_LINEAR_K noise floors above nil (two passes, the first from ``floor0``); 0 when
    fewer than SENSE_LINEAR_MIN second differences qualify."""
    f = floor0
    est = 0.0
    for _ in range(2):
        dd = []
        for ch in chans:
            r = np.asarray(ch.resid, float)
            lin = np.isfinite(r) & (np.abs(np.asarray(ch.sim, float)) >= SENSE_LINEAR_K * f)
            if r.size < 3:
                continue
            ok = lin[:-2] & lin[1:-1] & lin[2:]
            dd.append(np.diff(r, 2)[ok])
        d = np.concatenate(dd) if dd else np.zeros(0)
        if d.size < SENSE_LINEAR_MIN:
            return est
        est = float(sg.robust_std(d) / math.sqrt(6.0))
        if est <= f:
            return est
        f = est
    return est


def noise_floors(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, Channel]]
                 ) -> dict[str, float]:
    """Per-channel noise floor, pooled over runs, estimated from the data:
    encoder quantization for wheel speeds and counts, at least one ADC count for the motor
    current (:func:`current_count_a`), the high-frequency part of the
    residual for everything (ground-truth camera noise shows up there), and for cumulative
    channels (counts, odometry) a 1 % tolerance of their range, since tiny speed differences
    integrate."""
    meta = preps[0].run.meta
    ppr = int(meta["encoder_ppr"])
    r = float(meta["robot"]["r"])
    b = float(meta["robot"]["b"])
    k = 2 * math.pi / ppr
    dts = np.concatenate([np.diff(p.run.telemetry["t_s"]) for p in preps])
    dt = float(np.median(dts))
    floors: dict[str, float] = {}
    names = sorted(set().union(*[set(c) for c in nominal]))  # report.json: one key order
    count_a = current_count_a(preps) if any(c.startswith("current") for c in names) else 0.0
    for c in names:
        res = [ch[c].resid for ch in nominal if c in ch]
        hf = pooled_hf_noise_std(res)
        if c.startswith("omega"):
            base = sg.quantization_std(k / dt)
        elif c.startswith("enc"):
            base = sg.quantization_std(1.0)
        elif c.startswith("current"):
            base = max(sg.quantization_std(_current_lsb_a()), 1e-6)
        elif c in ("x_odo_m", "y_odo_m"):
            base = r * k
        elif c == "phi_odo_rad":
            base = r * k / (2 * b)
        elif c in ("x_m", "y_m"):
            base = 2e-4
        elif c == "phi_rad":
            base = 2e-3
        else:
            base = 1e-6
        f = max(base, hf)
        if c.startswith("current"):
            # the noise where the current flows (sense_linear_noise_std), not the clipped
            # spread at rest
            f = max(f, sense_linear_noise_std([ch[c] for ch in nominal if c in ch], f))
            # never below one ADC count: a magnitude-only sense reads long runs of exact zeros
            # at rest, where the MAD of second differences is nil, and had put the floor at
            # 0.6 of a count, so that a reading two counts off stood out
            f = max(f, count_a)
        if c in CUMULATIVE:
            # within a replay window (a long run is compared window by window)
            span = max(max(ch[c].spans()) for ch in nominal if c in ch)
            f = max(f, 0.01 * span)
        floors[c] = f
    return floors

def closed_loop_floors(chans_per_run: Sequence[Mapping[str, Channel]]) -> dict[str, float]:
    """Noise floor of the closed-loop channels (recorded minus replayed controller output),
    from the data: the white part of the nominal residual (MAD of second differences), which
    holds the torque jumps that single encoder-count differences between the real wheel and the
    plant cause through the speed loop; at least the telemetry's resolution (0.1 mN m for the
    torque command, 2^-15 for the duty) as a uniform quantization std."""
    base = {"tau_cmd_r": 1e-4 / math.sqrt(12), "tau_cmd_l": 1e-4 / math.sqrt(12),
            "pwm_r": 2.0 ** -15 / math.sqrt(12), "pwm_l": 2.0 ** -15 / math.sqrt(12)}
    floors = {}
    for c in CLOSED_LOOP_CHANNELS:
        res = [ch[c].resid for ch in chans_per_run if ch and c in ch]
        if not res:
            continue
        hf = float(np.sqrt(np.mean([sg.hf_noise_std(x) ** 2 for x in res])))
        floors[c] = max(base[c], hf)
    return floors
