"""When the recorded inputs took effect: the tick phase of the loop that sets them, from the
input changes and the board's wheel speeds, the firmware's duty ramp and its write latency."""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from host_tools.control import SCHED_TICK_S as RAMP_STEP_S  # the duty ramp's step
from host_tools.runfmt import Run

#: PreparedRun.timing of a loop faster than the telemetry whose ticks are put at the run's
#: experiment start plus whole periods (:func:`experiment_start_s`): no phase is estimated, and
#: the closed-loop replay starts its controller at the same time
TIMING_FROM_START = "ticks from the experiment's start"


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
    eff: np.ndarray = t.copy()
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


def at_rest_until(t: np.ndarray, phase: float, period: float, commands: list[np.ndarray],
                  t_start: float | None = None) -> float:
    """Board time up to which the board commanded nothing (-inf when the recording does not
    say): the tick that the last frame reporting no command before the first that does
    reports (``commands``: the reported inputs per frame), or, when the run says when its
    experiment started (``t_start``, :func:`experiment_start_s`), half a period before that
    start (the tolerance the tick-by-tick inputs give it), whichever is later."""
    t = np.asarray(t, float)
    bound = -math.inf
    if t.size == 0 or period <= 0:
        return bound
    active = np.zeros(t.size, bool)
    for v in commands:
        active |= np.asarray(v, float) != 0
    j = int(np.argmax(active)) if active.any() else 0
    if j >= 1:
        bound = phase + math.floor((t[j - 1] - phase) / period + 1e-9) * period
    if t_start is not None:
        bound = max(bound, t_start - 0.5 * period)
    return bound


def unreported_ticks(t: np.ndarray, phase: float, period: float,
                     rest_until: float = -math.inf) -> np.ndarray:
    """The ticks of the loop (``phase``, ``period``) between the first frame's and the last
    frame's that no frame reports, after ``rest_until`` (:func:`at_rest_until`: before it
    the board commanded nothing, so no command went unreported).  A frame reports the latest
    tick at or before it, so a tick goes unreported where one frame interval (t[k-1], t[k]]
    holds two ticks (a lost or late frame, or frames as fast as the loop with jitter); a frame
    interval longer than a period need not hold two (32.7 ms from 20.5 ms with ticks at
    18.9 + 25 n ms holds one)."""
    t = np.asarray(t, float)
    if t.size < 2 or period <= 0:
        return np.zeros(0)
    n = np.floor((t - phase) / period + 1e-9).astype(np.int64)   # the tick each frame reports
    every = np.arange(int(n.min()), int(n.max()) + 1)
    ticks = phase + period * every[~np.isin(every, n)].astype(float)
    return ticks[ticks > rest_until + 1e-9]


def _fill_unreported(ticks: np.ndarray, known: np.ndarray, values: np.ndarray,
                     rest_until: float) -> np.ndarray:
    """Values at ``ticks`` from those at the reported ticks ``known``: on the line between the
    reported ones, but held from the last reported one up to ``rest_until`` (the board
    commanded nothing there: no line toward the experiment's first command)."""
    out: np.ndarray = np.interp(ticks, known, values)
    rest = ticks <= rest_until + 1e-9
    if rest.any():
        i = np.searchsorted(known, ticks[rest] + 1e-9, side="right") - 1
        out[rest] = values[np.maximum(i, 0)]
    return out


def _feasible_arc(t: np.ndarray, values: list[np.ndarray], period: float
                  ) -> tuple[float, float, np.ndarray] | None:
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




def _ramped_duty(t: np.ndarray, duty: tuple[np.ndarray, np.ndarray], phase: float, period: float,
                 latency: np.ndarray | None, rest_until: float = -math.inf
                 ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The duty of a recorder that ramps it between its ticks (meta ``duty_ramp``: this
    project's firmware, src/motor.cpp): at a tick it sets d_k, then every millisecond adds the
    slope s_k the torque->PWM map chose, and a frame reports the duty in force at its own time.
    Per tick, two frames inside it give s_k and d_k; a tick with one frame takes the slope
    interpolated from the ticks within two of it that have two (the slope changes smoothly
    while a clamped wheel accelerates; it is 0 where nothing is ramped; at the tick where the
    clamp lets go one frame cannot tell, and the neighbours' slope is off for a tick or two;
    the line to the next frame instead, tried on the firmware in the loop, was worse: the
    velocity loop's next duty does not continue the ramp). Ticks no frame reported take the
    line between the reported ones, unramped. Up to ``rest_until`` (:func:`at_rest_until`)
    the board commanded nothing: no ramp, and an unreported tick holds the duty reported
    before it. Returns the input times (the tick, then each millisecond) and the duties."""
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
        # no ramp while the board commanded nothing (a tick with one frame at rest would
        # otherwise take the slope of the experiment's first ticks)
        slope[ticks <= rest_until + 1e-9] = 0.0
        have = np.flatnonzero(np.isfinite(slope))
        for k in np.unique(kf):
            if not np.isfinite(slope[k]):
                near = have[np.abs(have - k) <= 2]
                slope[k] = float(np.interp(k, near, slope[near])) if near.size else 0.0
            sel = np.flatnonzero(kf == k)
            base[k] = float(np.mean(v[sel] - slope[k] * m_f[sel]))
        known = np.flatnonzero(np.isfinite(base))
        # ticks no frame reported (a gap): on the line between the reported ones, unramped
        # (held while the board commanded nothing)
        base = _fill_unreported(ticks, ticks[known], base[known], rest_until)
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
    if period < step:  # a loop faster than the search step: ten phases across its period
        step = period / 10
    start, width = arc if arc is not None else (0.0, period - step)
    phases = start + np.arange(0.0, width + 0.5 * step, step)
    if phases.size == 0:    # a period shorter than the phase step: nothing to choose
        return None

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
