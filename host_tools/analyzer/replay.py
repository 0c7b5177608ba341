"""Replay a recorded run through the plant and put recording and simulation side by side.

The plant is lib/slipmodel's, reached through host_tools._native (never re-implemented
here).  A *replayer* turns (prepared run, effects) into simulated plant outputs; the
open-loop ones drive the plant with the recorded duty or the recorded torque command.
:class:`ClosedLoopReplay` runs the firmware's controller (lib/control through its C ABI)
against the plant and reproduces the torque and duty the firmware should have commanded.

:func:`channels` then maps a recording and a simulation onto common channels, each a
pair (recorded, simulated) on the recording's own time base."""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from host_tools import params as param_table
from host_tools import protocol as P
from host_tools.runfmt import Run
from host_tools.analyzer.signals import robust_std

# Channels compared (name -> kind).  "fit" channels enter the output-error fit.
CHANNELS = ("omega_r", "omega_l", "enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad",
            "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")
FIT_CHANNELS = ("omega_r", "omega_l", "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")
# Channels the recorder derives from others (odometry from the encoder counts): reported, never
# evidence about physics on their own; a disagreement there while the counts agree is a finding
# about the recorder (its odometry schedule, integration rule or geometry).
DERIVED = ("x_odo_m", "y_odo_m", "phi_odo_rad")
CUMULATIVE = ("enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad")


def reconstruct_input_times(t: np.ndarray, values: list[np.ndarray], period: float,
                            arc_position: float = 0.5, phase: float | None = None) -> np.ndarray:
    """When the recorded inputs change between two telemetry frames, the change happened at a
    tick of the loop that sets them (period ``period``), somewhere in (t[k-1], t[k]].  Find the
    tick phase that puts one tick in every such interval and return, per frame, the time the
    value it reports took effect.  Falls back to the frame times when no phase fits (e.g. the
    loop is not periodic, or faster than telemetry).

    The data pin the phase down to an arc of feasible phases (5 ms wide for a 25 ms loop seen
    at 50 Hz); ``arc_position`` picks the phase along it (0 start, 0.5 centre, 1 end), unless
    ``phase`` gives it (e.g. from :func:`board_rate_phase`)."""
    t = np.asarray(t, float)
    eff = t.copy()
    if phase is None:
        arc = _feasible_arc(t, values, period)
        if arc is None:
            return eff
        start, width, ks = arc
        phase = (start + float(np.clip(arc_position, 0.0, 1.0)) * width) % period
    else:
        ks = _changes(t, values)
        if ks.size == 0 or period <= 0:
            return eff
    tick = phase + np.floor((t[ks] - phase) / period + 1e-9) * period
    ok = tick > t[ks - 1] + 1e-9
    eff[ks[ok]] = tick[ok]
    return eff


def tick_phase(t: np.ndarray, values: list[np.ndarray], period: float,
               arc_position: float = 0.5) -> float | None:
    """The phase in [0, period) of the loop that sets ``values`` (see
    :func:`reconstruct_input_times`), or None when the data do not pin it down."""
    arc = _feasible_arc(np.asarray(t, float), values, period)
    if arc is None:
        return None
    start, width, _ = arc
    return float((start + float(np.clip(arc_position, 0.0, 1.0)) * width) % period)


def _changes(t: np.ndarray, values: list[np.ndarray]) -> np.ndarray:
    """Indices of the frames at which any of ``values`` differs from the frame before."""
    changed = np.zeros(t.size, bool)
    for v in values:
        changed[1:] |= np.diff(np.asarray(v, float)) != 0
    return np.flatnonzero(changed)


def _feasible_arc(t: np.ndarray, values: list[np.ndarray], period: float):
    """(first phase, width, frames where an input changed) of the arc of tick phases that put a
    tick in every interval in which an input changed; None when the data do not pin it down."""
    if t.size < 3 or period <= 0:
        return None
    ks = _changes(t, values)
    if ks.size == 0:
        return None
    dt_tel = float(np.median(np.diff(t)))
    if period < dt_tel * 0.999:  # loop faster than telemetry: several ticks per interval
        return None
    phases = np.linspace(0.0, period, 400, endpoint=False)
    bad = np.zeros(phases.size, int)
    for j, phase in enumerate(phases):
        # latest tick <= t[k] must lie after t[k-1] (a tick on a frame counts as before it)
        tick = phase + np.floor((t[ks] - phase) / period + 1e-9) * period
        bad[j] = int(np.sum(~(tick > t[ks - 1] + 1e-9)))
    # tolerate a few changes that no phase explains (timing jitter at coincidences)
    if bad.min() > max(1, int(0.05 * ks.size)):  # not one periodic loop: keep frame times
        return None
    feasible = bad == bad.min()
    if feasible.all():
        return None
    start = int(np.flatnonzero(~feasible)[0])
    rolled = np.roll(feasible, -start)
    best_len, best_start, run_start = 0, 0, None
    for j, f in enumerate(np.append(rolled, False)):
        if f and run_start is None:
            run_start = j
        elif not f and run_start is not None:
            if j - run_start > best_len:
                best_len, best_start = j - run_start, run_start
            run_start = None
    step = period / phases.size
    return ((best_start + start) % phases.size) * step, (best_len - 1) * step, ks


RAMP_STEP_S = 1e-3   # the firmware's duty ramp steps once per 1 kHz scheduler tick


def _ramped_duty(t: np.ndarray, duty: tuple, phase: float, period: float,
                 latency: np.ndarray | None) -> tuple[np.ndarray, tuple]:
    """The duty of a recorder that ramps it between its ticks (meta ``duty_ramp``: this
    project's firmware, src/motor.cpp): at a tick it sets d_k, then every millisecond adds the
    slope s_k the torque->PWM map chose, and a frame reports the duty in force at its own time.
    Per tick, two frames inside it give s_k and d_k; a tick with one frame takes the slope
    interpolated from the ticks within two of it that have two (the slope changes smoothly
    while a clamped wheel accelerates; it is 0 where nothing is ramped; at the tick where the
    clamp lets go one frame cannot tell, and the neighbours' slope is off for a tick or two;
    the line to the next frame instead, tried on the firmware in the loop, was worse: the
    velocity loop's next duty does not continue the ramp). Returns the input times (the tick,
    then each millisecond) and the duties."""
    t = np.asarray(t, float)
    n_ms = max(1, int(round(period / RAMP_STEP_S)))
    k0 = math.floor((t[0] - phase) / period + 1e-9)
    k1 = math.floor((t[-1] - phase) / period + 1e-9)
    ticks = phase + period * np.arange(k0, k1 + 1)
    lat = (np.interp(ticks, t, latency) if latency is not None else np.zeros(ticks.size))
    kf = np.floor((t - phase) / period + 1e-9).astype(np.int64) - k0      # tick of each frame
    # ramp steps in force at each frame: the 1 kHz ticks after the duty was set
    m_f = np.clip(np.floor((t - ticks[kf]) / RAMP_STEP_S + 1e-9), 0, n_ms - 1)
    m_f = np.where(t - ticks[kf] < lat[kf], 0, m_f)
    out_t = (ticks[:, None] + np.arange(n_ms)[None, :] * RAMP_STEP_S)
    out_t[:, 0] += lat
    out = []
    for v in duty:
        v = np.asarray(v, float)
        slope = np.full(ticks.size, np.nan)
        base = np.full(ticks.size, np.nan)
        for k in np.unique(kf):
            sel = np.flatnonzero(kf == k)
            ms = m_f[sel]
            if sel.size >= 2 and ms.max() > ms.min():
                a, b = sel[np.argmin(ms)], sel[np.argmax(ms)]
                slope[k] = (v[b] - v[a]) / (m_f[b] - m_f[a])
        have = np.flatnonzero(np.isfinite(slope))
        for k in np.unique(kf):
            if not np.isfinite(slope[k]):
                near = have[np.abs(have - k) <= 2]
                slope[k] = float(np.interp(k, near, slope[near])) if near.size else 0.0
            sel = np.flatnonzero(kf == k)
            base[k] = float(np.mean(v[sel] - slope[k] * m_f[sel]))
        known = np.flatnonzero(np.isfinite(base))
        # ticks no frame reported (a gap): on the line between the reported ones, unramped
        base = np.interp(np.arange(ticks.size), known, base[known])
        slope = np.where(np.isin(np.arange(ticks.size), known), slope, 0.0)
        slope = np.nan_to_num(slope)
        out.append((base[:, None] + slope[:, None] * np.arange(n_ms)[None, :]).ravel())
    return out_t.ravel(), (out[0], out[1])


def experiment_start_s(run: Run) -> float | None:
    """Board time of the experiment's first tick, when the run says: ``reference.t0_s`` in
    meta.json, or board time 0 when the recording starts within a frame interval and a tick of
    it (the clock started with the experiment, as the closed-loop replay assumes too; the
    truth simulator's recorders). None otherwise: the start is then placed from the frames."""
    ref = run.meta.get("reference")
    if isinstance(ref, Mapping) and ref.get("t0_s") is not None:
        return float(ref["t0_s"])
    t = np.asarray(run.telemetry["t_s"], float)
    period = float(run.meta.get("periods_s", {}).get("inner", 0.0) or 0.0)
    if t.size < 2 or period <= 0:
        return None
    dt_tel = float(np.median(np.diff(t)))
    return 0.0 if 0.0 <= t[0] <= dt_tel + period else None


def compute_latency_s(run: Run) -> np.ndarray | None:
    """Per frame, how long after its tick the reported duty took effect, when the recorder says:
    this project's firmware writes the duty at the end of the inner task's computation
    (src/app.cpp) and reports that task's duration with every frame (``inner_last_cyc``,
    protocol/protocol.json, at its ``f_cpu_hz``).  0.64 ms on the firmware in the loop: on a
    noiseless camera a replay that applies the duty at the tick is off by three floors.
    None for a recorder without that column."""
    tel = run.telemetry
    cyc = tel.get("inner_last_cyc")
    if cyc is None:
        return None
    cyc = np.asarray(cyc, float)
    if cyc.size != tel["t_s"].size or not np.all(np.isfinite(cyc)) or np.all(cyc <= 0):
        return None
    from host_tools import protocol
    f_cpu = float(protocol.definition().timing["f_cpu_hz"])
    period = float(run.meta.get("periods_s", {}).get("inner", 0.0) or 0.0)
    return np.clip(cyc / f_cpu, 0.0, period if period > 0 else None)


OUTLIER_COUNTS = 5.0   # board_rate_phase: a frame this far off at every phase is left out ...
OUTLIER_SHARE = 0.05   # ... up to this share of the frames


def board_rate_phase(tel: Mapping[str, np.ndarray], period: float, ppr: int,
                     arc: tuple[float, float] | None = None, step: float = 5e-5) -> float | None:
    """The inner loop's tick phase from the recording alone (no model): the board's wheel
    speed (``omega_r/l``, III.1) is the count difference over the last inner period, computed
    at a tick and reported by the next telemetry frame, while the counts (``enc_r/l``) are read
    at the frame's own time.  For a trial phase, the speeds the board would have reported are
    computed from the recorded counts, interpolated linearly at the ticks; the phase whose speeds
    agree best with the recorded ones is taken, searched along ``arc`` = (first phase, width)
    when given (the phases consistent with the input changes), else over a whole period.
    None when the recorded speeds do not depend on the phase (no acceleration, no data)."""
    t = np.asarray(tel["t_s"], float)
    if t.size < 5 or period <= 0:
        return None
    k = 2 * np.pi / ppr
    sides = []
    for side in ("r", "l"):
        w = np.asarray(tel.get(f"omega_{side}", np.zeros(0)), float)
        n = np.asarray(tel.get(f"enc_{side}", np.zeros(0)), float)
        if w.size != t.size or n.size != t.size or not np.all(np.isfinite(w)):
            return None
        sides.append((n, w))
    start, width = arc if arc is not None else (0.0, period - step)
    phases = start + np.arange(0.0, width + 0.5 * step, step)

    # counts interpolated across a gap in the telemetry (lost frames) are no measurement
    dt_med = float(np.median(np.diff(t)))
    gap_end = np.flatnonzero(np.diff(t) > 1.5 * dt_med) + 1

    # The counts between two frames: linear interpolation when the loop is at least as slow as
    # the telemetry. For a faster loop both ends of most count differences fall into one frame
    # interval, where a straight line gives the same difference at every phase: there a cubic
    # spline through the counts keeps the curvature (the wheel acceleration) that carries the
    # phase.
    if period < 0.999 * dt_med and t.size >= 4:
        from scipy.interpolate import CubicSpline
        interps = [CubicSpline(t, n) for n, _ in sides]
    else:
        interps = [(lambda x, n=n: np.interp(x, t, n)) for n, _ in sides]

    def errors(phase: float) -> tuple[np.ndarray, np.ndarray]:
        """Per frame: usable, and the larger of the two wheels' |reported - predicted| speed."""
        tick = phase + np.floor((t - phase) / period + 1e-9) * period   # latest tick <= frame
        ok = tick - period >= t[0]
        for g in gap_end:   # [tick - period, tick] must not reach into a gap
            ok &= ~((tick > t[g - 1]) & (tick - period < t[g]))
        e = np.zeros(t.size)
        for (n, w), f in zip(sides, interps):
            e = np.maximum(e, np.abs(w - k * (f(tick) - f(tick - period)) / period))
        return ok, e

    errs = [errors(float(p)) for p in phases]
    # A frame whose speed no phase makes a count difference (more than OUTLIER_COUNTS counts
    # per period off at every phase: a speed estimate restarted when an experiment ends, a
    # glitch) says nothing about the phase; up to OUTLIER_SHARE of the frames are left out.
    # A recorder with more such frames does not report count differences at all.
    e_min = np.min([np.where(ok, e, np.inf) for ok, e in errs], axis=0)
    outlier = np.isfinite(e_min) & (e_min > OUTLIER_COUNTS * k / period)
    if outlier.sum() > OUTLIER_SHARE * max(1, int(np.isfinite(e_min).sum())):
        return None

    def score(j: int) -> float:
        ok, e = errs[j]
        ok = ok & ~outlier
        return float(np.sum(e[ok] ** 2)) if ok.sum() >= 3 else math.inf

    sc = np.array([score(j) for j in range(phases.size)])
    if not np.isfinite(sc).any() or np.ptp(sc[np.isfinite(sc)]) <= 1e-12 * (1 + np.nanmin(sc)):
        return None
    j = int(np.nanargmin(sc))
    # Only a recorder whose wheel speed is the count difference over the last inner period
    # (III.1, this project's firmware) pins the phase down; at the best phase its speeds then
    # agree with the counts to about one count per period.  Another recorder (a filtered speed,
    # another period, speeds at the frames) must not move the input timing: that could shift
    # the inputs by most of a period and hide an actuation delay.
    n_ok = int(np.sum(errs[j][0] & ~outlier))
    if n_ok < 3 or math.sqrt(sc[j] / n_ok) > 1.5 * k / period:
        return None
    best = float(phases[j])
    if 0 < j < phases.size - 1 and np.all(np.isfinite(sc[j - 1:j + 2])):
        # parabola through the minimum and its neighbours
        den = sc[j - 1] - 2 * sc[j] + sc[j + 1]
        if den > 0:
            best += float(np.clip(0.5 * (sc[j - 1] - sc[j + 1]) / den, -0.5, 0.5)) * step
    return best % period


@dataclass
class PreparedRun:
    """A run with its inputs reconstructed for replay."""

    run: Run
    t_in: np.ndarray          # time at which each duty sample takes effect
    t_in_tau: np.ndarray      # time at which each torque-command sample takes effect
    duty: tuple[np.ndarray, np.ndarray]
    torque: tuple[np.ndarray, np.ndarray]
    t_grid: np.ndarray        # times at which the simulation is sampled
    robot: dict
    motor: dict
    start_pose: tuple[float, float, float]
    ppr: int
    extras: dict = field(default_factory=dict)
    # replay windows: frame index ranges [i_a, i_b) covering the run (see make_windows)
    windows: list = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.run.name

    def window_times(self, w: int) -> tuple[float, float]:
        t = self.run.telemetry["t_s"]
        i_a, i_b = self.windows[w]
        return float(t[i_a]), float(t[i_b - 1])


# Long recordings are replayed in windows re-anchored to the recording (multiple shooting): one
# open-loop integration over minutes drifts by centimetres as any two integrations of the same
# wheel motion do, and that drift is not physics.  A run up to SINGLE_WINDOW_S long is one
# window from its start pose at rest (how every short experiment starts).  Longer runs are cut
# into windows of WINDOW_S; a window after the first starts BURN_IN_S earlier from the
# recorded state (wheel speeds from the counts, pose from the camera or the odometry), and its
# cumulative and pose channels are compared as increments from the window's start.  A gap in
# the telemetry (longer than GAP_S) always ends a window.
SINGLE_WINDOW_S = 6.0
WINDOW_S = 4.0
BURN_IN_S = 0.5
GAP_S = 0.5


def note_slip_episodes(prep: "PreparedRun", sims: "WindowSims") -> int:
    """Record the slip episodes of a nominal replay ``sims`` (``extras["slip_episodes"]``, board
    times): across a slip the recorder's odometry stops following the body, so a window's
    camera anchor is fitted within the slip-free span around it.  Returns their number."""
    episodes = []
    for _, sim in sims:
        slip = (np.asarray(sim.get("slip_r", 0)) > 0) | (np.asarray(sim.get("slip_l", 0)) > 0)
        if not np.any(slip):
            continue
        g = sim["t_s"]
        starts = np.flatnonzero(~slip[:-1] & slip[1:]) + 1
        if slip[0]:
            starts = np.concatenate([[0], starts])
        ends = np.flatnonzero(slip[:-1] & ~slip[1:])
        for a in starts:
            later = ends[ends >= a]
            episodes.append((float(g[a]), float(g[later[0] + 1]) if later.size else float(g[-1])))
    prep.extras["slip_episodes"] = sorted(episodes)
    return len(episodes)


def make_windows(t: np.ndarray, single_s: float = SINGLE_WINDOW_S, window_s: float = WINDOW_S,
                 gap_s: float = GAP_S) -> list[tuple[int, int]]:
    """Frame index ranges [i_a, i_b) of the replay windows (see above)."""
    t = np.asarray(t, float)
    n = t.size
    gaps = np.flatnonzero(np.diff(t) > gap_s) + 1
    bounds = [0] + [int(g) for g in gaps] + [n]
    out: list[tuple[int, int]] = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b <= a:
            continue
        span = t[b - 1] - t[a]
        if not gaps.size and span <= single_s:
            out.append((a, b))
            continue
        k = max(1, int(round(span / window_s)))
        edges = np.searchsorted(t[a:b], t[a] + span * np.arange(1, k) / k) + a
        idx = [a] + [int(e) for e in edges] + [b]
        for i0, i1 in zip(idx[:-1], idx[1:]):
            if i1 > i0:
                out.append((i0, i1))
    return out


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
    gappy = t.size > 1 and float(np.max(np.diff(t))) > max(period, dt_tel) * 1.5
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
        dense = lambda v: np.interp(ticks, known, np.asarray(v, float)[first])  # noqa: E731
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
        t_in, duty = _ramped_duty(t, duty, phase, period, latency)
    # the input takes effect at t_in[k] and holds until the next one; the simulation is sampled
    # at the union of input times and telemetry times
    grid = np.unique(np.concatenate([t, t_in, t_in_tau]))
    windows = make_windows(t)
    return PreparedRun(run=run, t_in=t_in, t_in_tau=t_in_tau, windows=windows,
                       duty=duty, torque=torque,
                       t_grid=grid, robot=dict(run.meta["robot"]), motor=dict(run.meta["motor"]),
                       start_pose=run.start_pose, ppr=int(run.meta["encoder_ppr"]),
                       extras={"arc_position": arc_position, "inner_period": period,
                               # the inner loop's tick phase: the firmware's odometry is
                               # computed at its ticks (see channels())
                               "tick_phase": phase,
                               # per input tick: reported by a frame (None: every input is)
                               "seen_ticks": seen,
                               "t_steps": t_steps,
                               # camera channels against the count-anchored pose (channels())
                               "count_anchored_pose": bool(
                                   period > 0 and t.size > 1 and period < 0.999 * dt_tel)})


UNSEEN_PATTERN_HALF = 4   # unseen ticks on either side averaged into one tick's pattern (within 8 ticks)
UNSEEN_BRACKET_SIGMA = 3.0  # an unseen tick's command: within its bracket +- this many sigma
TICK_SHIFT_GAIN = 0.5        # _replay_tick_shift: a shift must cut the disagreement by this


def _replay_tick_shift(prep: PreparedRun, cl_sim: Mapping[str, np.ndarray], k: np.ndarray,
                       seen: np.ndarray) -> int:
    """The closed-loop replay's tick that matches each recorded tick is ``k`` plus this
    shift (-1, 0 or 1): the one under which the replay's duties bend where the reported ones
    do (least squares of their departures from the line through the neighbouring reported
    ticks).  A recording's tick phase a millisecond off its true value can put the replay's
    staircase and steps a whole tick early or late."""
    n = np.asarray(cl_sim["t_s"]).size
    # the reported ticks that every trial shift keeps inside the replay
    i = np.flatnonzero(seen & (k >= 1) & (k < n - 1))
    if i.size < 5:
        return 0
    x = k[i].astype(float)

    def bend(v: np.ndarray) -> np.ndarray:
        w = (x[1:-1] - x[:-2]) / np.maximum(x[2:] - x[:-2], 1e-9)
        return v[1:-1] - (v[:-2] + (v[2:] - v[:-2]) * w)
    best, best_s, err0 = np.inf, 0, np.inf
    for s in (0, -1, 1):
        ks = k[i] + s
        err = 0.0
        for col, rec in (("pwm_r", prep.duty[0]), ("pwm_l", prep.duty[1])):
            if col in cl_sim:
                d = bend(np.asarray(rec, float)[i]) - bend(np.asarray(cl_sim[col], float)[ks])
                err += float(np.sum(d ** 2))
        if s == 0:
            err0 = err
        if err < best:
            best, best_s = err, s
    # a shift must at least halve the disagreement: a slipping run's duties bend little, and
    # a near tie is no evidence against the phase
    return best_s if best < TICK_SHIFT_GAIN * err0 else 0


def fill_unseen_from_controller(prep: PreparedRun, cl_sim: Mapping[str, np.ndarray]) -> int:
    """Refine the commands of the ticks no frame reported (a loop faster than the telemetry,
    lost frames) with the pattern of the controller that produced them.

    :func:`prepare` fills such a tick on the straight line between the reported ones.  A
    cascade whose outer loop updates the torque only every other inner tick makes a staircase
    instead: the duty rises mostly at the outer ticks, so the unreported ticks lie off that line
    by the same sign for as long as the wheels accelerate (8e-3 of duty on a clamped 72 rad/s^2
    start with a 10 ms loop seen at 50 Hz); held open loop, that bias drifts a slipping wheel's
    speed by about one noise floor.  The closed-loop replay of the same controller
    (``cl_sim``, per tick) has the staircase: its unreported ticks' offset from its own line
    through the reported ticks, averaged over the UNSEEN_PATTERN_HALF unreported ticks on
    either side (tick-level differences come from single encoder counts, which no replay
    reproduces), is added to the fill.  The reported ticks stay as recorded.  Returns the
    number of ticks changed."""
    seen = prep.extras.get("seen_ticks")
    ts = np.asarray(cl_sim.get("t_s", np.zeros(0)), float)
    if seen is None or ts.size < 3 or bool(np.all(seen)):
        return 0
    T = float(ts[1] - ts[0])
    period = float(prep.extras.get("inner_period") or 0.0)
    if T <= 0 or abs(T - period) > 1e-6 * max(period, 1e-9):
        return 0
    k = np.round((prep.t_in - ts[0]) / T).astype(np.int64)
    k = k + _replay_tick_shift(prep, cl_sim, k, np.asarray(seen, bool))
    inside = (k >= 0) & (k < ts.size)
    k_seen = k[seen & inside]
    unseen = np.flatnonzero(~seen & inside)
    if k_seen.size < 2 or unseen.size == 0:
        return 0

    def pattern(u: np.ndarray) -> tuple[np.ndarray, float]:
        off = u[k[unseen]] - np.interp(k[unseen], k_seen, u[k_seen])
        # averaged over the unseen ticks within 2 * UNSEEN_PATTERN_HALF ticks (every other
        # tick unseen: UNSEEN_PATTERN_HALF on either side), never over other, distant gaps
        ku = k[unseen]
        c = np.concatenate([[0.0], np.cumsum(off)])
        lo = np.searchsorted(ku, ku - 2 * UNSEEN_PATTERN_HALF, side="left")
        hi = np.searchsorted(ku, ku + 2 * UNSEEN_PATTERN_HALF, side="right")
        smooth = (c[hi] - c[lo]) / (hi - lo)
        # a single tick far off the line (a step: the end of a ramp, a clamp taking hold) is
        # the controller's, not an encoder count's: kept beyond 3 sigma of the tick-level
        # scatter (soft threshold), the scatter itself averaged away
        dev = off - smooth
        sigma = robust_std(dev) if dev.size > 4 else 0.0
        return smooth + np.sign(dev) * np.maximum(np.abs(dev) - 3.0 * sigma, 0.0), sigma

    i_seen = np.flatnonzero(seen)
    j_next = np.clip(np.searchsorted(i_seen, unseen), 1, i_seen.size - 1)
    prev_i, next_i = i_seen[j_next - 1], i_seen[j_next]

    def refined(v: np.ndarray, col: str) -> np.ndarray:
        out = np.asarray(v, float).copy()
        if col in cl_sim:
            off, sigma = pattern(np.asarray(cl_sim[col], float))
            # the replay's step can fall a tick or two off the recording's (its ramp ends on
            # its own ticks): an unreported command stays within the reported ones that
            # bracket it, widened by UNSEEN_BRACKET_SIGMA of the tick-level scatter
            lo = np.minimum(out[prev_i], out[next_i]) - UNSEEN_BRACKET_SIGMA * sigma
            hi = np.maximum(out[prev_i], out[next_i]) + UNSEEN_BRACKET_SIGMA * sigma
            out[unseen] = np.clip(out[unseen] + off, lo, hi)
        return out
    prep.duty = (refined(prep.duty[0], "pwm_r"), refined(prep.duty[1], "pwm_l"))
    if prep.t_in_tau.size == prep.t_in.size and np.array_equal(prep.t_in_tau, prep.t_in):
        prep.torque = (refined(prep.torque[0], "tau_cmd_r"), refined(prep.torque[1], "tau_cmd_l"))
    prep.extras["unseen_fill"] = "closed-loop pattern"
    return int(unseen.size)


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
        timing = "ticks from the experiment's start"
    if phase is None and fast:
        # a loop faster than the telemetry whose phase the recording does not pin down: a
        # frame reports the latest tick before it, on average half a period earlier
        phase = float((t[0] - 0.5 * period) % period)
        timing = "half a period before the frames (phase not identified)"
        unc = 0.5 * period
    prep = prepare(run, 0.5, phase)
    prep.extras["timing"] = timing
    prep.extras["phase_uncertainty_s"] = unc
    rec = recorder_odometry(prep)
    prep.extras["recorder_odometry"] = rec
    prep.extras["odo_schedule"] = rec.get("schedule", "ticks")
    return prep


def _tick_of_frame(prep: PreparedRun, t: np.ndarray) -> np.ndarray | None:
    """Time of the latest inner tick at or before each time in ``t`` (None: phase unknown)."""
    phase = prep.extras.get("tick_phase")
    period = float(prep.extras.get("inner_period") or 0.0)
    if phase is None or period <= 0:
        return None
    return phase + np.floor((t - phase) / period + 1e-9) * period


def odometry_times(prep: PreparedRun) -> np.ndarray:
    """When the pose that each telemetry frame reports was computed: the latest inner tick for
    a recorder that integrates at its ticks (this project's firmware), the frame itself for one
    that integrates at the frames (see :func:`recorder_odometry`)."""
    t = prep.run.telemetry["t_s"]
    if prep.extras.get("odo_schedule") == "frames":
        return t
    tk = _tick_of_frame(prep, t)
    return t if tk is None else np.maximum(tk, t[0])


def recorder_odometry(prep: PreparedRun) -> dict:
    """How the recorder's odometry columns relate to its own encoder counts, from the recording
    alone: lib/control's odometry (exact arc, III.2-III.4) of the recorded counts is computed
    at the inner ticks (counts interpolated there; a frame reports the latest tick's pose, as
    this project's firmware does) and at the frames, each window by window from the recorded
    pose, and compared with the recorded odometry.  The better schedule is taken; if even it
    differs by more than a few counts of wheel travel, the recorder computes odometry
    differently (integration rule, wheel geometry, schedule) and that is a finding about the
    recorder, not about the physics."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    r, b, ppr = float(prep.robot["r"]), float(prep.robot["b"]), prep.ppr
    k = 2 * np.pi / ppr
    tol_m, tol_rad = 10 * r * k, 10 * r * k / (2 * b)   # ten counts of wheel travel
    wins = prep.windows or [(0, t.size)]
    ticks_all = _tick_of_frame(prep, t)
    errs: dict[str, list[np.ndarray]] = {"frames": [], "ticks": []}
    for i_a, i_b in wins:
        tw = t[i_a:i_b]
        if tw.size < 2:
            continue
        pose0 = (tel["x_odo_m"][i_a], tel["y_odo_m"][i_a], tel["phi_odo_rad"][i_a])
        rec = np.column_stack([tel["x_odo_m"][i_a:i_b], tel["y_odo_m"][i_a:i_b],
                               tel["phi_odo_rad"][i_a:i_b]])
        cand = {"frames": _odometry(tel["enc_r"][i_a:i_b], tel["enc_l"][i_a:i_b], tw, r, b, ppr,
                                    pose0)}
        if ticks_all is not None:
            tk = ticks_all[i_a:i_b]
            uniq, idx = np.unique(tk, return_inverse=True)
            # counts at the ticks, interpolated over the whole run (the first tick of a window
            # lies before its first frame)
            # (not across a gap: after one, a tick before the window's first frame gets its
            # counts on the line through the window's first two frames)
            after_gap = i_a > 0 and t[i_a] - t[i_a - 1] > GAP_S and i_b - i_a >= 2
            at_t = np.maximum(uniq, t[0])

            def counts_at(n):
                c = np.interp(at_t, t, n)
                if after_gap:
                    early = at_t < t[i_a]
                    slope = (n[i_a + 1] - n[i_a]) / (t[i_a + 1] - t[i_a])
                    c[early] = n[i_a] + slope * (at_t[early] - t[i_a])
                return np.floor(c + 1e-9)
            cr, cl = counts_at(tel["enc_r"]), counts_at(tel["enc_l"])
            if uniq.size >= 2:
                xo, yo, po = _odometry(cr, cl, at_t + 1e-9 * np.arange(at_t.size), r, b, ppr,
                                       pose0)
                cand["ticks"] = (xo[idx], yo[idx], po[idx])
        for name, (xo, yo, po) in cand.items():
            errs[name].append(np.column_stack([rec[:, 0] - xo, rec[:, 1] - yo,
                                               _wrap(rec[:, 2] - po)]))
    out: dict = {}
    for name, e in errs.items():
        if not e:
            continue
        e = np.vstack(e)
        out[name] = {"rms_m": float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))),
                     "rms_rad": float(np.sqrt(np.mean(e[:, 2] ** 2)))}
    if not out:
        return {}
    best = min(out, key=lambda n: out[n]["rms_m"] / tol_m + out[n]["rms_rad"] / tol_rad)
    res = {"schedule": best, "tolerance_m": tol_m, "tolerance_rad": tol_rad, "by_schedule": out}
    res["agrees"] = bool(out[best]["rms_m"] <= tol_m and out[best]["rms_rad"] <= tol_rad)
    return res


def _zoh(t_in: np.ndarray, v: np.ndarray, grid: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(t_in, grid, side="right") - 1
    idx = np.clip(idx, 0, v.size - 1)
    out = v[idx].astype(float)
    out[grid < t_in[0]] = 0.0
    return out


class OpenLoopReplay:
    """Drive the plant with the recorded duty ("duty") or torque command ("torque")."""

    def __init__(self, mode: str = "duty", dt_s: float = 5e-4, plant_factory: Any = None):
        if mode not in ("duty", "torque"):
            raise ValueError(f"mode must be 'duty' or 'torque', not {mode!r}")
        self.mode = mode
        self.name = f"open-loop {mode}"
        self.dt_s = dt_s
        self._factory = plant_factory
        self._plants: dict = {}

    def _plant(self, robot: dict, motor: dict):
        key = (tuple(sorted(robot.items())), tuple(sorted(motor.items())))
        p = self._plants.get(key)
        if p is None:
            factory = self._factory
            if factory is None:
                from host_tools import _native  # the one physics, via the C ABI
                factory = _native.Plant
            p = factory(robot=robot, motor=motor)
            self._plants[key] = p
        return p

    def _ready(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]]):
        """(plant with ``effects`` switched on, the replayed inputs, their times)."""
        plant = self._plant(prep.robot, prep.motor)
        plant.clear_effects()
        for name, params in effects.items():
            plant.set_effect(name, **{k: float(v) for k, v in params.items()})
        if self.mode == "duty":
            return plant, prep.duty, prep.t_in
        return plant, prep.torque, prep.t_in_tau

    def simulate(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]]
                 ) -> dict[str, np.ndarray]:
        plant, src, t_in = self._ready(prep, effects)
        grid = prep.t_grid
        # The plant is stepped on the replay grid itself (telemetry times and reconstructed
        # input times), each input held from its row to the next.  lib/slipmodel's
        # Plant::set_time keeps the actuation-delay line across the clock re-alignment at every
        # row, so no special time grid is needed.
        in_r = _zoh(t_in, src[0], grid)
        in_l = _zoh(t_in, src[1], grid)
        out = plant.simulate(grid, in_r, in_l, mode=self.mode, dt_s=self.dt_s,
                             start_pose=prep.start_pose)
        res = {k: np.asarray(v, float) for k, v in out.items() if k in _NEEDED}
        res["t_s"] = grid.copy()
        return res

    def simulate_windows(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]],
                         which: Sequence[int] | None = None) -> "WindowSims":
        """Per replay window (``which``, default all): the plant outputs on the window's part of
        the replay grid, started as :func:`window_start` says.  A one-window run gives the same
        simulation as :meth:`simulate`."""
        if len(prep.windows) <= 1 and (which is None or list(which) == [0]):
            return WindowSims([(0, self.simulate(prep, effects))])
        plant, src, t_in = self._ready(prep, effects)
        out = []
        for w in (range(len(prep.windows)) if which is None else which):
            t0, pose, vel = window_start(prep, w)
            t_end = prep.window_times(w)[1]
            grid = prep.t_grid[(prep.t_grid >= t0 - 1e-12) & (prep.t_grid <= t_end + 1e-12)]
            if grid.size < 2:
                continue
            in_r = _zoh(t_in, src[0], grid)
            in_l = _zoh(t_in, src[1], grid)
            o = plant.simulate(grid, in_r, in_l, mode=self.mode, dt_s=self.dt_s,
                               start_pose=pose, start_velocity=vel)
            res = {k: np.asarray(v, float) for k, v in o.items() if k in _NEEDED}
            res["t_s"] = grid.copy()
            out.append((w, res))
        return WindowSims(out)


class WindowSims(list):
    """[(window index, plant outputs)] of a windowed replay."""


def _line_at(t: np.ndarray, v: np.ndarray, at: float) -> float:
    """Value at ``at`` of a straight line fitted to (t, v)."""
    tt = t - at
    if tt.size < 2 or np.ptp(tt) <= 0:
        return float(np.mean(v))
    A = np.column_stack([np.ones_like(tt), tt])
    return float(np.linalg.lstsq(A, v, rcond=None)[0][0])


ANCHOR_HALF_S = 1.5
MIN_SPREAD_M = 0.1


def _gt_anchor(prep: "PreparedRun", at: float, half: float = ANCHOR_HALF_S
               ) -> dict[str, float] | None:
    """The true pose at board time ``at``, for re-anchoring a replay window: the recorder's
    odometry there, corrected by the camera-minus-odometry offset fitted as a straight line over
    ``half`` seconds either side.  Odometry is precise over a short time but drifts; the camera
    does not drift but is noisy sample by sample; their offset changes slowly, so a fit over
    many camera samples removes most of the camera's noise (a single camera heading, 0.01 rad,
    would turn a 2 m window by 2 cm).  None without camera samples there."""
    gt = prep.run.groundtruth
    if gt is None:
        return None
    tel = prep.run.telemetry
    t = tel["t_s"]
    tg = gt["t_s"]
    # within the slip-free span around ``at`` (across a slip the odometry stops following the body)
    lo, hi = at - half, at + half
    for a, b in prep.extras.get("slip_episodes", ()):
        if b <= at:
            lo = max(lo, b)
        elif a >= at:
            hi = min(hi, a)
    m = (tg >= lo) & (tg <= hi) & (tg >= t[0]) & (tg <= t[-1])
    if m.sum() < 3:
        return None
    tm = tg[m]
    po = np.unwrap(tel["phi_odo_rad"])
    # the recorded pose at the time it was computed (a tick or the frame)
    to, keep = np.unique(odometry_times(prep), return_index=True)
    xo_, yo_, po_ = tel["x_odo_m"][keep], tel["y_odo_m"][keep], po[keep]
    odo = {"x_m": np.interp(tm, to, xo_), "y_m": np.interp(tm, to, yo_),
           "phi_rad": np.interp(tm, to, po_)}
    here = {"x_m": float(np.interp(at, to, xo_)), "y_m": float(np.interp(at, to, yo_)),
            "phi_rad": float(np.interp(at, to, po_))}
    # camera = R(delta) odometry + c over the span.  delta from the positions (2-D Procrustes)
    # when the robot travels far enough for the direction of travel to pin it down better than
    # the camera's headings do (1 mm over a 0.3 m spread: ~0.5 mrad), else from the headings
    # (a straight line in time); c a straight line in time
    gx, gy = gt["x_m"][m], gt["y_m"][m]
    ph = gt.get("phi_rad")
    ok = np.isfinite(ph[m]) if ph is not None else np.zeros(tm.size, bool)
    ox, oy = odo["x_m"] - odo["x_m"].mean(), odo["y_m"] - odo["y_m"].mean()
    spread = float(np.sqrt(np.mean(ox ** 2 + oy ** 2)))
    if spread >= MIN_SPREAD_M or ok.sum() < 3:
        qx, qy = gx - gx.mean(), gy - gy.mean()
        delta_at = float(np.arctan2(np.sum(ox * qy - oy * qx), np.sum(ox * qx + oy * qy)))
        delta = np.full(tm.size, delta_at)
    else:
        d = ph[m][ok] - odo["phi_rad"][ok]
        d0 = float(np.median(_wrap(d)))
        dl = d0 + _wrap(d - d0)
        A = np.column_stack([np.ones(ok.sum()), tm[ok] - at])
        coef = np.linalg.lstsq(A, dl, rcond=None)[0] if np.ptp(tm[ok]) > 0 else [np.mean(dl), 0]
        delta = coef[0] + coef[1] * (tm - at)
        delta_at = float(coef[0])
    cx = gx - (np.cos(delta) * odo["x_m"] - np.sin(delta) * odo["y_m"])
    cy = gy - (np.sin(delta) * odo["x_m"] + np.cos(delta) * odo["y_m"])
    ca, sa = math.cos(delta_at), math.sin(delta_at)
    out = {"x_m": ca * here["x_m"] - sa * here["y_m"] + _line_at(tm, cx, at),
           "y_m": sa * here["x_m"] + ca * here["y_m"] + _line_at(tm, cy, at)}
    out["phi_rad"] = here["phi_rad"] + delta_at
    return out


def window_start(prep: PreparedRun, w: int) -> tuple[float, tuple, tuple | None]:
    """(start time, start pose, start velocity or None) of replay window ``w``: the run's
    start pose at rest for the first window; otherwise BURN_IN_S before the window (not before
    a gap), moving as the recording says: wheel speeds from the counts around that frame,
    the body rolling with them, pose from the camera (else the recorded odometry)."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    i_a, _ = prep.windows[w]
    if w == 0 or i_a == 0:
        return float(prep.t_grid[0]), prep.start_pose, None
    first = i_a
    while first > 0 and t[first] - t[first - 1] <= GAP_S and t[i_a] - t[first - 1] <= BURN_IN_S:
        first -= 1
    k = 2 * np.pi / prep.ppr
    j0, j1 = max(first - 2, 0), min(first + 2, t.size - 1)
    if first > 0 and t[first] - t[first - 1] > GAP_S:
        j0 = first  # the frame before is across a gap
    if j1 > j0:
        w_r = float((tel["enc_r"][j1] - tel["enc_r"][j0]) * k / (t[j1] - t[j0]))
        w_l = float((tel["enc_l"][j1] - tel["enc_l"][j0]) * k / (t[j1] - t[j0]))
    else:
        w_r = w_l = 0.0
    r, b = float(prep.robot["r"]), float(prep.robot["b"])
    vel = (r * (w_r + w_l) / 2, 0.0, r * (w_r - w_l) / (2 * b), w_r, w_l)
    pose = (float(tel["x_odo_m"][first]), float(tel["y_odo_m"][first]),
            float(tel["phi_odo_rad"][first]))
    an = _gt_anchor(prep, float(t[first]))
    if an is not None:
        pose = (an["x_m"], an["y_m"], an.get("phi_rad", pose[2]))
    return float(t[first]), pose, vel


_NEEDED = {"x_m", "y_m", "phi_rad", "theta_r_rad", "theta_l_rad", "dtheta_r_rad_s",
           "dtheta_l_rad_s", "tau_r_nm", "tau_l_nm", "v_m_s", "omega_rad_s", "slip_r", "slip_l",
           "i_r_a", "i_l_a"}


REF_KINDS = ("line", "arc", "figure_eight")
# meta.json "controller" values that mean lib/control's cascade (absent: assumed)
REPLAYABLE_CONTROLLERS = ("improved", "cascade")
# meta.json "controller_variant": the cascade's velocity loop (absent: the firmware's default,
# improved), the protocol's names and codes (the C ABI's "controller" key takes the same codes)
VELOCITY_LOOPS = dict(P.definition().enums["controller"])
CLOSED_LOOP_CHANNELS = ("tau_cmd_r", "tau_cmd_l", "pwm_r", "pwm_l")


def closed_loop_setup(meta: Mapping, t: np.ndarray, tau_r: np.ndarray, tau_l: np.ndarray
                      ) -> tuple[dict | None, list[str], list[str]]:
    """What the closed-loop replay needs from a run, or why it cannot run.

    Returns (setup, problems, assumptions).  ``setup`` is None when a problem makes the replay
    impossible.  Needed: ``meta["reference"]`` = ``{"kind": line|arc|figure_eight, "accel":
    m/s^2, "cruise": m/s, "radius": m (arc, figure eight)}`` (the free-text ``experiment`` is
    not parsed: that would be guessing), ``torque_clamp``, ``periods_s.inner``/``outer``.
    ``reference.t0_s`` is the board time of the controller's first tick (reference time 0);
    when absent it is taken as 0 (the board clock starts with the experiment, as the truth
    simulator writes) and that assumption is checked against the recording: every change of
    the recorded torque command must fall in a telemetry interval that contains a tick."""
    problems: list[str] = []
    assumptions: list[str] = []
    ctl = meta.get("controller")
    if ctl is not None and ctl not in REPLAYABLE_CONTROLLERS:
        return None, [f"meta.json controller {ctl!r} is not one that lib/control replays "
                      f"({', '.join(REPLAYABLE_CONTROLLERS)})"], []
    variant = meta.get("controller_variant", "improved")
    if not isinstance(variant, str) or variant not in VELOCITY_LOOPS:
        return None, [f"meta.json controller_variant {variant!r} is not a velocity loop of "
                      f"lib/control ({', '.join(VELOCITY_LOOPS)})"], []
    ref = meta.get("reference")
    if not isinstance(ref, Mapping):
        msg = ("meta.json has no structured 'reference' ({kind, accel, cruise, radius}); "
               "the free-text 'experiment' is not parsed, so the reference the firmware "
               "tracked is unknown")
        cmds = meta.get("commands")
        if isinstance(cmds, list) and any(isinstance(c, Mapping) and c.get("command") == "Start"
                                          for c in cmds):
            msg += ("; the logged Start command gives the profile but not the board time at "
                    "which the experiment started, which the replay would need (reference.t0_s)")
        return None, [msg], []
    kind = ref.get("kind")
    if kind not in REF_KINDS:
        return None, [f"meta.json reference.kind {kind!r} is not one of {list(REF_KINDS)}"], []
    vals = {}
    need = ["accel", "cruise"] + (["radius"] if kind != "line" else [])
    for k in need:
        v = ref.get(k)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            problems.append(f"meta.json reference.{k} is missing or not a number")
        else:
            vals[k] = float(v)
    if "torque_clamp" not in meta:
        problems.append("meta.json has no 'torque_clamp': the clamp setting the firmware ran "
                        "with is unknown")
    periods = meta.get("periods_s", {})
    inner, outer = float(periods.get("inner", 0.0)), float(periods.get("outer", 0.0))
    ratio = round(outer / inner) if inner > 0 else 0
    if inner <= 0 or ratio < 1 or abs(ratio * inner - outer) > 1e-9:
        problems.append(f"periods_s inner {inner} / outer {outer}: the outer loop is not a whole "
                        "number of inner ticks")
    if problems:
        return None, problems, []
    t0 = ref.get("t0_s")
    if t0 is None:
        t0 = 0.0
        assumptions.append("reference.t0_s not in meta.json: the controller's first tick (reference "
                           "time 0) is taken at board time 0")
        if float(t[0]) - t0 > 10.0 * inner * max(ratio, 1):
            problems.append(f"reference.t0_s not in meta.json and the first telemetry frame is at "
                            f"board time {float(t[0]):g} s, not near 0: the board clock does not "
                            f"start with the experiment, so the controller's first tick is unknown")
            return None, problems, assumptions
    t0 = float(t0)
    if t0 > float(t[0]) + inner:
        problems.append(f"reference.t0_s = {t0} s is after the first telemetry frame's tick")
        return None, problems, assumptions
    # the recorded torque command must change only in intervals that contain a tick
    ch = np.flatnonzero((np.diff(tau_r) != 0) | (np.diff(tau_l) != 0)) + 1
    ch = ch[t[ch - 1] >= t0]
    if ch.size:
        tick = t0 + np.floor((t[ch] - t0) / inner + 1e-9) * inner
        bad = int(np.sum(~(tick > t[ch - 1] + 1e-9)))
        if bad > max(1, int(0.05 * ch.size)):
            problems.append(f"{bad} of {ch.size} changes of the recorded torque command fall "
                            f"between ticks of a {inner * 1e3:g} ms schedule starting at "
                            f"t0 = {t0:g} s: the tick times are not known")
            return None, problems, assumptions
    return ({"kind": kind, "accel": vals["accel"], "cruise": vals["cruise"],
             "radius": vals.get("radius", 1.0), "clamp": bool(meta["torque_clamp"]),
             "t0_s": t0, "inner_s": inner, "outer_every": int(ratio),
             "controller": VELOCITY_LOOPS[variant]}, [], assumptions)


_CTL_KEYS = (*param_table.ROBOT, *param_table.MOTOR)  # the controller's nominal keys in meta.json


class ClosedLoopReplay:
    """Closed-loop replay through lib/control: the firmware's fixed-point cascade, configured
    with the run's nominal parameters, reference and clamp setting, drives the lib/slipmodel
    plant (with or without candidate effects) on the firmware's schedule: an inner step every
    ``periods_s.inner`` on the plant's encoder counts (floor of angle x ppr / 2 pi), an outer
    step every ``periods_s.outer`` after the inner step of the same tick.  It reproduces the
    torque and duty the firmware should have commanded.

    The loop is lib/closedloop's driver (C ABI ``cl_*``, bound by
    :class:`host_tools.control.ClosedLoop`), which steps plant and controller forward tick by
    tick: cost linear in the run length."""

    name = "closed-loop"

    def __init__(self, dt_s: float = 5e-4):
        self.dt_s = dt_s

    @staticmethod
    def available() -> tuple[bool, str]:
        try:
            from host_tools.control import ClosedLoop  # noqa: F401  (lib/closedloop C ABI)
        except Exception as exc:  # pragma: no cover - depends on the build
            return False, f"the lib/control C ABI could not be loaded: {exc}"
        return True, ""

    def setup(self, prep: "PreparedRun") -> tuple[dict | None, list[str], list[str]]:
        tel = prep.run.telemetry
        setup, problems, assumptions = closed_loop_setup(prep.run.meta, tel["t_s"],
                                                         tel["tau_cmd_r"], tel["tau_cmd_l"])
        # the loader fills missing meta keys with the run format's defaults: say when the
        # clamp setting is such a default rather than recorded
        try:
            import json
            import os
            with open(os.path.join(prep.run.path, "meta.json")) as fh:
                raw = json.load(fh)
        except (OSError, ValueError):
            raw = None
        if isinstance(raw, Mapping) and "torque_clamp" not in raw and setup is not None:
            assumptions.append("torque_clamp not in meta.json: the run format's default "
                               f"({str(setup['clamp']).lower()}) is used")
        return setup, problems, assumptions

    def simulate(self, prep: "PreparedRun", effects: Mapping[str, Mapping[str, float]],
                 setup: dict | None = None) -> dict[str, np.ndarray]:
        """Per tick: ``t_s`` (board time), the controller's columns (``tau_cmd_r`` ... ``pwm_l``)
        and the plant's state at the tick (wheel angles ``theta_r_rad``, ``theta_l_rad``, ...).
        Raises ValueError when the run lacks what the replay needs (see
        :func:`closed_loop_setup`)."""
        from host_tools.control import ClosedLoop  # lib/closedloop through its C ABI
        if setup is None:
            setup, problems, _ = self.setup(prep)
            if setup is None:
                raise ValueError("closed-loop replay impossible: " + "; ".join(problems))
        meta = prep.run.meta
        ctl = {part: {k: float(v) for k, v in meta[part].items() if k in _CTL_KEYS}
               for part in ("robot", "motor")}
        T, t0 = setup["inner_s"], setup["t0_s"]
        t_end = float(prep.run.telemetry["t_s"][-1])
        n = int(math.floor((t_end - t0) / T + 1e-9)) + 1
        loop = ClosedLoop(setup["kind"], setup["accel"], setup["cruise"], setup["radius"],
                          fixed_point=True, clamp=setup["clamp"], ctl_robot=ctl["robot"],
                          ctl_motor=ctl["motor"], plant_robot=prep.robot, plant_motor=prep.motor,
                          effects=effects, t0_s=t0, inner_s=T, outer_every=setup["outer_every"],
                          ppr=prep.ppr, plant_dt_s=self.dt_s, start_pose=prep.start_pose,
                          ctl_params={"controller": setup["controller"]},
                          # the firmware's 1 kHz duty ramp, where the recorder says it ramps
                          duty_ramp=bool(prep.run.meta.get("duty_ramp", False)))
        return loop.run(n)


def closed_loop_channels(prep: "PreparedRun", sim: Mapping[str, np.ndarray]) -> dict:
    """Recorded against replayed controller outputs at the telemetry frames: a frame reports
    the output of the latest tick at or before it."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    ts = np.asarray(sim["t_s"], float)
    T = float(ts[1] - ts[0]) if ts.size > 1 else 1.0
    idx = np.floor((t - ts[0]) / T + 1e-6).astype(int)
    ok = (idx >= 0) & (idx < ts.size)
    out = {}
    for c in CLOSED_LOOP_CHANNELS:
        unit = "N m" if c.startswith("tau") else "1"
        out[c] = Channel(c, t[ok], np.asarray(tel[c], float)[ok],
                         np.asarray(sim[c], float)[idx[ok]], unit)
    return out


# -------------------------------------------------------------------------- channels


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _odometry(counts_r: np.ndarray, counts_l: np.ndarray, t: np.ndarray, r: float, b: float,
              ppr: int, pose0: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Encoder odometry of cumulative counts, computed by lib/control's own odometry (the
    firmware's formula, III.1-III.4) through the ctl_odometry_series C ABI."""
    from host_tools import _native  # the C ABI library (built on first use)
    lib = _native.library()
    fn = lib.ctl_odometry_series  # signature: host_tools/native/control_capi.h
    i32p = ctypes.POINTER(ctypes.c_int32)
    dp = ctypes.POINTER(ctypes.c_double)
    n = len(t)
    cr = np.ascontiguousarray(counts_r, dtype=np.int32)
    cl = np.ascontiguousarray(counts_l, dtype=np.int32)
    tt = np.ascontiguousarray(t, dtype=np.float64)
    x, y, phi = (np.empty(n) for _ in range(3))
    rc = fn(r, b, int(ppr), n, cr.ctypes.data_as(i32p), cl.ctypes.data_as(i32p), tt.ctypes.data_as(dp),
            float(pose0[0]), float(pose0[1]), float(pose0[2]),
            x.ctypes.data_as(dp), y.ctypes.data_as(dp), phi.ctypes.data_as(dp))
    if rc < 0:
        raise ValueError(f"ctl_odometry_series failed ({rc}): r={r}, b={b}, ppr={ppr}")
    return x, y, phi


def _theta_at(sim: Mapping[str, np.ndarray], side: str, times: np.ndarray) -> np.ndarray:
    """Wheel angle between the simulation's rows: cubic Hermite on the angle and its rate
    (the rows are up to a telemetry period apart; linear interpolation would be off by a
    good part of a count while the wheel accelerates)."""
    g = np.asarray(sim["t_s"], float)
    th = np.asarray(sim[f"theta_{side}_rad"], float)
    w = np.asarray(sim.get(f"dtheta_{side}_rad_s", np.gradient(th, g)), float)
    times = np.clip(np.asarray(times, float), g[0], g[-1])
    i = np.clip(np.searchsorted(g, times, side="right") - 1, 0, g.size - 2)
    h = g[i + 1] - g[i]
    s = np.where(h > 0, (times - g[i]) / np.where(h > 0, h, 1.0), 0.0)
    h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
    h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
    return h00 * th[i] + h10 * h * w[i] + h01 * th[i + 1] + h11 * h * w[i + 1]


def _replay_odometry(prep: PreparedRun, sim: Mapping[str, np.ndarray], t: np.ndarray,
                     th0_r: float, th0_l: float, pose0) -> tuple[np.ndarray, ...]:
    """The odometry a telemetry frame reports: the firmware integrates it at its inner-loop
    ticks from the counts of that tick, and a frame carries the pose of the latest tick at or
    before it (the counts in the same frame are read at the frame's own time).  With the tick
    phase reconstructed (:func:`prepare`), the simulated counts are taken at the ticks and the
    pose is reported like that; without it, at the frame times."""
    k = 2 * np.pi / prep.ppr
    r, b = float(prep.robot["r"]), float(prep.robot["b"])
    phase = prep.extras.get("tick_phase")
    period = float(prep.extras.get("inner_period") or 0.0)
    if phase is None or period <= 0 or prep.extras.get("odo_schedule") == "frames":
        q_r = np.floor((_theta_at(sim, "r", t) - th0_r) / k)
        q_l = np.floor((_theta_at(sim, "l", t) - th0_l) / k)
        return _odometry(q_r, q_l, t, r, b, prep.ppr, pose0)
    # ticks from the last one at or before the first frame to the last frame
    n0 = math.floor((t[0] - phase) / period + 1e-9)
    n1 = math.floor((t[-1] - phase) / period + 1e-9)
    ticks = phase + period * np.arange(n0, n1 + 1)
    q_r = np.floor((_theta_at(sim, "r", ticks) - th0_r) / k + 1e-9)
    q_l = np.floor((_theta_at(sim, "l", ticks) - th0_l) / k + 1e-9)
    xo, yo, po = _odometry(q_r, q_l, ticks, r, b, prep.ppr, pose0)
    idx = np.clip(np.floor((t - phase) / period + 1e-9).astype(int) - n0, 0, ticks.size - 1)
    return xo[idx], yo[idx], po[idx]


CURRENT_SETTLE_S = 1e-3
# the tick phase of a loop faster than the telemetry, from a cubic through the counts: within
# 2 ms on the tuning cases recorded with a 10 ms loop
FAST_PHASE_UNCERTAINTY_S = 2e-3


def _last_change(t_in: np.ndarray, values: tuple, t: np.ndarray) -> np.ndarray:
    """Time of the latest change of any of ``values`` (held from ``t_in``) at or before ``t``."""
    ch = np.zeros(t_in.size, bool)
    ch[0] = True
    for v in values:
        ch[1:] |= np.diff(np.asarray(v, float)) != 0
    tc = t_in[ch]
    i = np.searchsorted(tc, t, side="right") - 1
    return np.where(i >= 0, tc[np.maximum(i, 0)], -np.inf)


def _tick_before(t_steps: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Latest of ``t_steps`` at or before each ``t`` (-inf before the first)."""
    i = np.searchsorted(t_steps, t, side="right") - 1
    return np.where(i >= 0, t_steps[np.maximum(i, 0)], -np.inf)


@dataclass
class Channel:
    name: str
    t: np.ndarray
    rec: np.ndarray
    sim: np.ndarray
    unit: str
    seg: np.ndarray | None = None   # replay window of each sample (None: one window)
    unc: np.ndarray | None = None   # the replay's own uncertainty per sample (input_uncertainty)

    @property
    def resid(self) -> np.ndarray:
        d = self.rec - self.sim
        return _wrap(d) if self.name in ("phi_rad", "phi_odo_rad") else d

    def deflated(self, floor: float) -> np.ndarray:
        """The residual in units of the noise floor widened by the replay's uncertainty:
        ``resid * floor / sqrt(floor^2 + unc^2)`` (the residual itself when ``unc`` is None),
        so that anything that compares it with ``floor`` compares the residual with the two
        added in quadrature."""
        r = self.resid
        if self.unc is None or floor <= 0:
            return r
        return r * (floor / np.sqrt(floor ** 2 + self.unc ** 2))

    def spans(self) -> list[float]:
        """Range of the recorded values within each replay window."""
        if self.seg is None or self.rec.size == 0:
            return [float(np.ptp(self.rec))] if self.rec.size else [0.0]
        return [float(np.ptp(self.rec[self.seg == s])) for s in np.unique(self.seg)]


def channels(prep: PreparedRun, sim, mode: str = "duty") -> dict[str, Channel]:
    """Recording against simulation on common channels.  ``sim`` is one simulation of the whole
    run (:meth:`OpenLoopReplay.simulate`) or the windows of :meth:`~OpenLoopReplay.simulate_windows`;
    windows are compared each from its own start and concatenated."""
    n = prep.run.telemetry["t_s"].size
    if not isinstance(sim, WindowSims):
        return _with_uncertainty(prep, _channels_window(prep, sim, 0, n, None))
    parts = [_channels_window(prep, s, *prep.windows[w], w) for w, s in sim]
    out: dict[str, Channel] = {}
    for name in CHANNELS:
        got = [c[name] for c in parts if name in c]
        if not got:
            continue
        out[name] = Channel(name, np.concatenate([c.t for c in got]),
                            np.concatenate([c.rec for c in got]),
                            np.concatenate([c.sim for c in got]), got[0].unit,
                            np.concatenate([c.seg for c in got]))
    return _with_uncertainty(prep, out)


def _with_uncertainty(prep: PreparedRun, chans: dict[str, Channel]) -> dict[str, Channel]:
    """Attach the run's replay uncertainty (``extras["replay_unc"]``: channel -> (t, unc), from
    :func:`input_uncertainty`) to its channels, at their sample times."""
    unc = prep.extras.get("replay_unc")
    if unc:
        for name, ch in chans.items():
            if name in unc and ch.t.size:
                ch.unc = np.interp(ch.t, *unc[name])
    return chans


UNSEEN_ENSEMBLE = 8        # replays with the unreported commands drawn from their uncertainty


def input_uncertainty(prep: PreparedRun, replay: "OpenLoopReplay",
                      n: int = UNSEEN_ENSEMBLE) -> int:
    """The replay's uncertainty from the commands no frame reported (a loop faster than the
    telemetry, lost frames), per channel and sample: the spread of ``n`` replays whose unseen
    ticks' duties are drawn from what the reported ones allow.

    The fill of an unseen tick (:func:`prepare`, :func:`fill_unseen_from_controller`) assumes
    that the commands run on a line between the reported ones around the gap.  Where they bend
    (a step, the end of a ramp, a clamp letting go), the bend may fall anywhere in the gap:
    the trend of the reported commands before the gap carried forward, or the trend after it
    carried back, departs from that line by ``dev`` at the unseen tick (half a step for a
    single unseen tick; growing into a long gap of lost frames), and the unseen command is
    taken as uniform between the line and that departure, std ``dev / sqrt(3)``, one draw
    shared by the ticks of a gap.  On a straight stretch ``dev`` vanishes and what remains is
    the tick-level scatter of the reported commands (robust std of their second differences,
    / sqrt(1.5): the fill's own error for white scatter), drawn per tick.  The replay turns the
    draws into the output errors they cause, large
    where the output is sensitive to the input (a slipping wheel, a step) and small elsewhere.
    Stored in ``extras["replay_unc"]`` (channel -> (t, std over the draws)) and attached to the
    channels by :func:`channels`; decisions compare residuals with the noise floor and this
    uncertainty in quadrature (:meth:`Channel.deflated`).  Draws are seeded by the run's
    content, so an analysis is repeatable.  Returns the number of unseen ticks (0: no draw)."""
    seen = prep.extras.get("seen_ticks")
    if seen is None:
        return 0
    seen = np.asarray(seen, bool)
    i_seen = np.flatnonzero(seen)
    unseen = np.flatnonzero(~seen)
    if unseen.size == 0 or i_seen.size < 3 or n < 2:
        return 0
    j = np.searchsorted(i_seen, unseen)
    a, b = np.clip(j - 1, 0, i_seen.size - 1), np.clip(j, 0, i_seen.size - 1)
    ts, tk = np.asarray(prep.t_in, float)[i_seen], np.asarray(prep.t_in, float)[unseen]
    # a gap: consecutive unseen ticks; its ticks share one draw of the bend (a ramp that went
    # on into the gap, or stopped early, does so for all of them)
    gap = np.concatenate([[0], np.cumsum(np.diff(unseen) > 1)])
    white, bend = [], []
    for u in prep.duty:
        us = np.asarray(u, float)[i_seen]
        dd = us[1:-1] - 0.5 * (us[:-2] + us[2:])
        white.append(robust_std(dd) / math.sqrt(1.5) if dd.size > 4 else 0.0)
        line = np.interp(tk, ts, us)
        s_a = np.where(a >= 1, (us[a] - us[a - 1]) / np.maximum(ts[a] - ts[a - 1], 1e-9), 0.0)
        s_b = np.where(b + 1 < us.size, (us[np.minimum(b + 1, us.size - 1)] - us[b])
                       / np.maximum(ts[np.minimum(b + 1, us.size - 1)] - ts[b], 1e-9), 0.0)
        fwd = us[a] + s_a * (tk - ts[a])
        bwd = us[b] - s_b * (ts[b] - tk)
        dev = np.minimum(np.maximum(np.abs(fwd - line), np.abs(bwd - line)), 1.0)
        bend.append(dev / math.sqrt(3.0))
    seed = int(np.uint32(int(np.sum(np.asarray(prep.run.telemetry["t_s"], float) * 1e3)) & 0xFFFFFFFF))
    rng = np.random.default_rng([seed, unseen.size])
    base = tuple(np.asarray(u, float) for u in prep.duty)
    acc: dict[str, list[np.ndarray]] = {}
    t_of: dict[str, np.ndarray] = {}
    try:
        for _ in range(n):
            draw = []
            for u, w, bd in zip(base, white, bend):
                v = u.copy()
                z = rng.standard_normal(int(gap[-1]) + 1)
                v[unseen] += z[gap] * bd + rng.standard_normal(unseen.size) * w
                draw.append(np.clip(v, -1.0, 1.0))
            prep.duty = tuple(draw)
            for name, ch in channels(prep, replay.simulate_windows(prep, {}), "duty").items():
                acc.setdefault(name, []).append(ch.resid)
                t_of[name] = ch.t
    finally:
        prep.duty = base
    prep.extras["replay_unc"] = {name: (t_of[name], np.std(np.array(v), axis=0))
                                 for name, v in acc.items()
                                 if len({a.size for a in v}) == 1 and t_of[name].size}
    return int(unseen.size)


def _channels_window(prep: PreparedRun, sim: Mapping[str, np.ndarray], i_a: int, i_b: int,
                     w: int | None) -> dict[str, Channel]:
    """Channels of the frames [i_a, i_b) against ``sim``.  A window that does not start the run
    is compared as increments from its first frame (counts, odometry, camera pose)."""
    run = prep.run
    tel = run.telemetry
    t_all = tel["t_s"]
    t = t_all[i_a:i_b]
    g = np.asarray(sim["t_s"], float)
    anchored = i_a > 0

    def at(name: str, times: np.ndarray) -> np.ndarray:
        return np.interp(times, g, np.asarray(sim[name], float))

    def seg(size: int) -> np.ndarray | None:
        return None if w is None else np.full(size, w, dtype=np.int32)

    k = 2 * np.pi / prep.ppr
    th_r, th_l = at("theta_r_rad", t), at("theta_l_rad", t)
    out: dict[str, Channel] = {}
    # wheel speeds: count differences over each telemetry period that the simulation covers
    lo = max(i_a, 1)
    while lo < i_b and t_all[lo - 1] < g[0] - 1e-9:
        lo += 1
    kk = np.arange(lo, i_b)
    dt = t_all[kk] - t_all[kk - 1]
    for side in ("r", "l"):
        enc = tel[f"enc_{side}"]
        th = at(f"theta_{side}_rad", t_all[kk])
        th_prev = at(f"theta_{side}_rad", t_all[kk - 1])
        out[f"omega_{side}"] = Channel(f"omega_{side}", t_all[kk], (enc[kk] - enc[kk - 1]) * k / dt,
                                       (th - th_prev) / dt, "rad/s", seg(kk.size))
    for side, th in (("r", th_r), ("l", th_l)):
        enc = tel[f"enc_{side}"][i_a:i_b]
        out[f"enc_{side}"] = Channel(f"enc_{side}", t, enc - enc[0], (th - th[0]) / k, "counts",
                                     seg(t.size))
    # odometry of the simulated encoders (quantized like the real ones), from the recorded pose
    # at the window's first frame
    pose0 = (tel["x_odo_m"][i_a], tel["y_odo_m"][i_a], tel["phi_odo_rad"][i_a])
    xo, yo, po = _replay_odometry(prep, sim, t, th_r[0], th_l[0], pose0)
    out["x_odo_m"] = Channel("x_odo_m", t, tel["x_odo_m"][i_a:i_b], xo, "m", seg(t.size))
    out["y_odo_m"] = Channel("y_odo_m", t, tel["y_odo_m"][i_a:i_b], yo, "m", seg(t.size))
    out["phi_odo_rad"] = Channel("phi_odo_rad", t, tel["phi_odo_rad"][i_a:i_b], po, "rad",
                                 seg(t.size))
    # The recorded torque command is what the controller wanted; an open-loop replay only knows
    # the torque the plant delivered, so tau_cmd is compared by the closed-loop replay only.
    # Motor current: the shield reports its magnitude.
    if "i_r_a" in sim:
        for side in ("r", "l"):
            col = f"current_{side}_a"
            cur = tel.get(col)
            # a constant column (e.g. all zero) is a sensor that is not there
            if cur is not None and cur.dtype.kind == "f" and np.ptp(cur) > 0:
                # the current follows the duty within the armature's electrical time, and where
                # in that transient the ADC sampled is not known: samples within CURRENT_SETTLE_S
                # of a change of the duty are left out
                t_steps = prep.extras.get("t_steps")
                dt_in = (t - _last_change(prep.t_in, prep.duty, t) if t_steps is None
                         else t - _tick_before(np.asarray(t_steps, float), t))
                keep = dt_in >= CURRENT_SETTLE_S
                unc = float(prep.extras.get("phase_uncertainty_s") or 0.0)
                if unc > 0:
                    # where the ticks are known only to within unc, a sample that close to a
                    # tick may sit on either side of it: left out as well
                    steps = prep.t_in if t_steps is None else np.asarray(t_steps, float)
                    j = np.searchsorted(steps, t, side="left")
                    nxt = np.where(j < steps.size, steps[np.minimum(j, steps.size - 1)], np.inf)
                    keep &= (dt_in >= CURRENT_SETTLE_S + unc) & (nxt - t > unc)
                if keep.sum() < max(3, keep.size // 4):
                    continue   # the frames coincide with the loop's ticks: no settled sample
                out[col] = Channel(col, t[keep], np.asarray(tel[col][i_a:i_b], float)[keep],
                                   np.abs(at(f"i_{side}_a", t[keep])), "A",
                                   None if w is None else seg(int(keep.sum())))
    gt = run.groundtruth
    if gt is not None:
        tg_all = gt["t_s"]
        t_hi = t_all[i_b] if i_b < t_all.size else t_all[-1] + 1e-9
        inside = (tg_all >= max(g[0], t[0])) & (tg_all < t_hi) & (tg_all <= g[-1])
        tg = tg_all[inside]
        if tg.size >= 3:
            an = _gt_anchor(prep, float(t[0])) if anchored else None
            shift = _count_anchor_shift(prep, sim, t, th_r, th_l, i_a, i_b, tg)
            pos = {c: at(c, tg) - shift[c] for c in ("x_m", "y_m")}
            if anchored:
                # re-anchored in pose, not only in position: the replay's increments are
                # turned by the heading it is off the anchor at the window's first frame (its
                # early start's transient, a few mrad, would otherwise grow into a cross-track
                # drift of millimetres per metre)
                p0 = {c: float(at(c, t[:1])[0]) for c in ("x_m", "y_m")}
                ref = {c: an[c] if an is not None else float(gt[c][inside][0])
                       for c in ("x_m", "y_m")}
                rot = 0.0
                if an is not None and an.get("phi_rad") is not None:
                    rot = float(_wrap(np.array([an["phi_rad"] - float(at("phi_rad", t[:1])[0])]))[0])
                dx, dy = pos["x_m"] - p0["x_m"], pos["y_m"] - p0["y_m"]
                cr, sr = math.cos(rot), math.sin(rot)
                pos = {"x_m": cr * dx - sr * dy + ref["x_m"], "y_m": sr * dx + cr * dy + ref["y_m"]}
            for c in ("x_m", "y_m"):
                out[c] = Channel(c, tg, gt[c][inside], pos[c], "m", seg(tg.size))
            ph = gt["phi_rad"][inside]
            ok = np.isfinite(ph)
            if ok.sum() >= 3:
                # compared modulo 2 pi (Channel.resid wraps)
                sv = at("phi_rad", tg[ok]) - shift["phi_rad"][ok]
                if anchored:
                    ref = (an or {}).get("phi_rad")
                    if ref is None:
                        ref = float(ph[ok][0])
                    sv = sv - float(at("phi_rad", t[:1])[0]) + ref
                out["phi_rad"] = Channel("phi_rad", tg[ok], ph[ok], sv, "rad", seg(int(ok.sum())))
    return out


def _count_anchor_shift(prep: PreparedRun, sim: Mapping[str, np.ndarray], t: np.ndarray,
                        th_r: np.ndarray, th_l: np.ndarray, i_a: int, i_b: int,
                        tg: np.ndarray) -> dict[str, np.ndarray]:
    """The part of the replayed pose that only follows from the replay's wheels turning
    otherwise than the recorded counts say, at the camera times ``tg``; zero unless the run's
    inputs are partly unrecorded (``extras["count_anchored_pose"]``).

    When some inner ticks' commands were never recorded (a loop faster than the telemetry),
    the replayed wheels drift from the real ones by what the filled-in commands miss, and the
    open-loop pose inherits that drift: millimetres within seconds, above the camera's noise,
    on a null.  The wheels' own motion is tested by the wheel-speed, count and current
    channels; the camera channels are then compared against the replay's pose moved by the
    odometry difference (lib/control's odometry, the nominal geometry) between the replayed
    and the recorded wheel angles, over the frame intervals in which the replay's wheels roll
    (a slipping wheel's extra turning does not move the body).  What remains in the camera
    channels is what the counts cannot show: the geometry (wheel radius, track width) and
    slip."""
    zero = np.zeros(tg.size)
    if not prep.extras.get("count_anchored_pose") or t.size < 2:
        return {"x_m": zero, "y_m": zero, "phi_rad": zero}
    tel = prep.run.telemetry
    k = 2 * np.pi / prep.ppr
    r, b = float(prep.robot["r"]), float(prep.robot["b"])
    g = np.asarray(sim["t_s"], float)
    pose0 = tuple(float(np.interp(t[0], g, np.asarray(sim[c], float)))
                  for c in ("x_m", "y_m", "phi_rad"))
    q_sim = [np.floor((th - th[0]) / k + 1e-9) for th in (th_r, th_l)]
    q_rec = [np.asarray(tel[f"enc_{s}"][i_a:i_b], float) - float(tel[f"enc_{s}"][i_a])
             for s in ("r", "l")]
    # a replayed wheel that slips turns without moving the body: the replay's extra turning
    # over a frame interval in which it slips is not carried into the pose
    slip = ((np.asarray(sim.get("slip_r", np.zeros(g.size))) > 0) |
            (np.asarray(sim.get("slip_l", np.zeros(g.size))) > 0))
    if slip.size == g.size and slip.any():
        cs = np.concatenate([[0], np.cumsum(slip)])
        idx = np.searchsorted(g, t, side="right")
        slipped = (cs[idx[1:]] - cs[idx[:-1]]) > 0
        for j in (0, 1):
            inc = np.diff(q_sim[j] - q_rec[j])
            inc[slipped] = 0.0
            q_sim[j] = q_rec[j] + np.concatenate([[0.0], np.cumsum(inc)])
    xs, ys, ps = _odometry(q_sim[0], q_sim[1], t, r, b, prep.ppr, pose0)
    xr, yr, pr = _odometry(q_rec[0], q_rec[1], t, r, b, prep.ppr, pose0)
    return {"x_m": np.interp(tg, t, xs - xr), "y_m": np.interp(tg, t, ys - yr),
            "phi_rad": np.interp(tg, t, ps - pr)}


def state_table(prep: PreparedRun) -> dict[str, np.ndarray]:
    """Operating state at the telemetry frames (from the recording), for regime search."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    k = 2 * np.pi / prep.ppr
    w_r = np.gradient(tel["enc_r"] * k, t)
    w_l = np.gradient(tel["enc_l"] * k, t)
    from host_tools.analyzer.signals import smooth
    w_r, w_l = smooth(w_r, 3), smooth(w_l, 3)
    return {"t": t, "w_r": w_r, "w_l": w_l,
            "a_r": smooth(np.gradient(w_r, t), 3), "a_l": smooth(np.gradient(w_l, t), 3),
            "tau_r": tel["tau_cmd_r"], "tau_l": tel["tau_cmd_l"],
            "u_r": tel["pwm_r"], "u_l": tel["pwm_l"],
            "yaw": float(prep.robot["r"]) * (w_r - w_l) / (2 * float(prep.robot["b"]))}
