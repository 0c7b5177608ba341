"""The run with its input times reconstructed (:func:`prepare`, :func:`prepare_timed`), and the
stage that prepares every run of an analysis (:func:`prepare_runs`)."""
from __future__ import annotations

import dataclasses
import math
from typing import Callable, Sequence

import numpy as np

from host_tools.runfmt import Run
from host_tools.analyzer.prepare.odometry import recorder_odometry
from host_tools.analyzer.prepare.run import PreparedRun, make_windows
from host_tools.analyzer.prepare.timing import (_feasible_arc, _fill_unreported, _ramped_duty,
                                                at_rest_until, board_rate_phase,
                                                compute_latency_s, experiment_start_s,
                                                reconstruct_input_times, tick_phase,
                                                unreported_ticks, TIMING_FROM_START)

# the tick phase of a loop faster than the telemetry, from a cubic through the counts: within
# 2 ms on the tuning cases recorded with a 10 ms loop
FAST_PHASE_UNCERTAINTY_S = 2e-3


def prepare(run: Run, arc_position: float = 0.5, phase: float | None = None) -> PreparedRun:
    """The run with its input times reconstructed: the inner loop's tick phase is ``phase`` if
    given, else the point ``arc_position`` along the arc of phases consistent with the input
    changes."""
    tel = run.telemetry
    t = tel["t_s"]
    period = float(run.meta["periods_s"]["inner"])
    duty_in = [tel["pwm_r"], tel["pwm_l"]]
    if phase is None:
        phase = tick_phase(t, duty_in, period, arc_position)
    t_in = reconstruct_input_times(t, duty_in, period, arc_position, phase)
    # the torque command is set at the same ticks as the duty
    t_in_tau = reconstruct_input_times(t, [tel["tau_cmd_r"], tel["tau_cmd_l"]], period,
                                       arc_position, phase)
    # a first frame that already carries a command reports the tick before it: the robot
    # started moving there (the replay starts at rest at that tick, not at the first frame);
    # when the run says when its experiment started (experiment_start_s), there
    t_start = experiment_start_s(run)
    if phase is not None and period > 0:
        tick0 = phase + math.floor((t[0] - phase) / period + 1e-9) * period
        if t_start is not None:
            tick0 = t_start
        if t[0] - period < tick0 < t[0] or (t_start is not None and tick0 < t[0]):
            if tel["pwm_r"][0] != 0 or tel["pwm_l"][0] != 0:
                t_in[0] = tick0
            if tel["tau_cmd_r"][0] != 0 or tel["tau_cmd_l"][0] != 0:
                t_in_tau[0] = tick0
    duty = (np.asarray(tel["pwm_r"], float), np.asarray(tel["pwm_l"], float))
    torque = (np.asarray(tel["tau_cmd_r"], float), np.asarray(tel["tau_cmd_l"], float))
    dt_tel = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    latency = compute_latency_s(run)
    # a frame interval that holds two ticks leaves the first unreported (a lost or late frame,
    # or frames as fast as the loop with jitter: 28.8-30 ms gaps of 20 ms frames at +-5.5 ms
    # against a 25 ms loop); counted at the phase, and only from the experiment's first command
    # on (unreported_ticks): a frame late or lost at rest before it leaves none
    rest_until = (at_rest_until(t, phase, period, duty_in + [tel["tau_cmd_r"], tel["tau_cmd_l"]],
                                t_start) if phase is not None else -math.inf)
    gappy = phase is not None and unreported_ticks(t, phase, period, rest_until).size > 0
    if phase is not None and period > 0 and (period < 0.999 * dt_tel or gappy):
        # A loop faster than the telemetry, or frames lost: a frame reports the value of the
        # latest tick before it, and the ticks between two frames went unseen.  Their values
        # are taken on the straight line between the two reported ones (a smooth controller's
        # output), each held from its tick.
        known = phase + np.floor((t - phase) / period + 1e-9) * period
        known, first = np.unique(known, return_index=True)
        n_first = math.floor((known[0] - phase) / period + 1e-9)
        started = tel["pwm_r"][0] != 0 or tel["pwm_l"][0] != 0
        if started and t_start is not None:
            # ticks from the experiment's start on (the first one at the start itself)
            n_first = min(n_first, math.floor((t_start - phase) / period + 1e-9) + 1)
        elif started:
            # the first frame already reports a command: the experiment started after the frame
            # before it would have been sent, at the earliest tick after t[0] - one frame
            # interval; those ticks carry commands no frame reported
            n_first = min(n_first, math.floor((t[0] - dt_tel - phase) / period + 1e-9) + 1)
        ticks = phase + period * np.arange(n_first,
                                           math.floor((t[-1] - phase) / period + 1e-9) + 1)
        if started and t_start is not None:
            # the first tick is the start itself (a tick the phase puts a little earlier is it)
            ticks = np.concatenate([[t_start], ticks[ticks > t_start + 0.5 * period]])
        dense: Callable[[np.ndarray], np.ndarray] = lambda v: _fill_unreported(  # noqa: E731
            ticks, known, np.asarray(v, float)[first], rest_until)
        duty = (dense(duty[0]), dense(duty[1]))
        torque = (dense(torque[0]), dense(torque[1]))
        t_in, t_in_tau = ticks.copy(), ticks.copy()
        seen = np.isin(np.round((ticks - phase) / period).astype(np.int64),
                       np.round((known - phase) / period).astype(np.int64))
    else:
        seen = None
    if latency is not None:
        # the board's duty is written when the tick's computation ends (see compute_latency_s)
        t_in = t_in + (latency if t_in.size == t.size else np.interp(t_in, t, latency))
        if t_in_tau.size == t_in.size:
            t_in_tau = t_in.copy()
    t_steps = None   # ramped duty: where a tick set it (the motor current's transients)
    if (run.meta.get("duty_ramp") and phase is not None and period >= 0.999 * dt_tel
            and seen is None):
        t_steps = t_in
        t_in, duty = _ramped_duty(t, duty, phase, period, latency, rest_until)
    # the input takes effect at t_in[k] and holds until the next one; the simulation is sampled
    # at the union of input times and telemetry times
    grid = np.unique(np.concatenate([t, t_in, t_in_tau]))
    windows = make_windows(t)
    return PreparedRun(run=run, t_in=t_in, t_in_tau=t_in_tau, windows=windows,
                       duty=duty, torque=torque,
                       t_grid=grid, robot=dict(run.meta["robot"]), motor=dict(run.meta["motor"]),
                       start_pose=run.start_pose, ppr=int(run.meta["encoder_ppr"]),
                       inner_period=period, tick_phase=phase, seen_ticks=seen,
                       t_steps=t_steps,
                       count_anchored_pose=bool(period > 0 and t.size > 1
                                                and period < 0.999 * dt_tel))


def prepare_timed(run: Run) -> PreparedRun:
    """:func:`prepare` with the tick phase taken from the recording alone: along the arc
    consistent with the input changes, where the board's reported wheel speeds agree best
    with the recorded counts (:func:`board_rate_phase`); the arc's centre when they do not
    depend on the phase.  No model enters, so the timing cannot absorb a mismatch of the
    nominal model (choosing it by the nominal replay's error did: it shifted the inputs by up
    to 3 ms to hide an effect, and the updated model then inherited the wrong timing)."""
    tel = run.telemetry
    period = float(run.meta["periods_s"]["inner"])
    arc = _feasible_arc(np.asarray(tel["t_s"], float), [tel["pwm_r"], tel["pwm_l"]], period)
    phase = board_rate_phase(tel, period, int(run.meta["encoder_ppr"]),
                             None if arc is None else arc[:2])
    t = np.asarray(tel["t_s"], float)
    fast = t.size > 1 and period > 0 and period < 0.999 * float(np.median(np.diff(t)))
    timing = ("board wheel speeds against recorded counts" if phase is not None
              else "centre of the input-change arc" if arc is not None else "frame times")
    # how far the ticks may be from where they are put (a loop faster than the telemetry: the
    # cubic through the counts pins the phase to about FAST_PHASE_UNCERTAINTY_S)
    unc = FAST_PHASE_UNCERTAINTY_S if fast else 0.0
    t0 = experiment_start_s(run)
    if fast and t0 is not None:
        # the run says when its experiment, and so its loop, started: the ticks are at
        # t0 + n * period.  The cubic's curvature is weak where the wheels barely accelerate
        # (a slow run's phase came out 4.7 ms off, and a current sample taken at a tick was
        # compared as if settled)
        phase = float(t0 % period)
        timing = TIMING_FROM_START
    if phase is None and fast:
        # a loop faster than the telemetry whose phase the recording does not pin down: a
        # frame reports the latest tick before it, on average half a period earlier
        phase = float((t[0] - 0.5 * period) % period)
        timing = "half a period before the frames (phase not identified)"
        unc = 0.5 * period
    prep = dataclasses.replace(prepare(run, 0.5, phase), timing=timing, phase_uncertainty_s=unc)
    rec = recorder_odometry(prep)
    return dataclasses.replace(prep, recorder_odometry=rec,
                               odo_schedule=rec.get("schedule", "ticks"))


def prepare_runs(runs: Sequence[Run], log: Callable[[str], None]) -> list[PreparedRun]:
    """Input timing and preparation (:func:`prepare_timed`) of every run: when each recorded
    duty and torque command took effect on the board, the replay grid, and the replay windows.
    A long run is cut into windows re-anchored to the recording, so that the open-loop
    replay's errors do not integrate over the whole run."""
    preps = [prepare_timed(r) for r in runs]
    n_win = sum(len(p.windows) for p in preps)
    if n_win > len(preps):
        log(f"long run(s): replayed in {n_win} windows re-anchored to the recording")
    return preps
