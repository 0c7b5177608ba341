"""Commands no telemetry frame reported (a loop faster than the telemetry, lost frames): their
fill refined with the controller's pattern, and the replay's uncertainty from them."""
from __future__ import annotations

import dataclasses
import json
import math
from typing import TYPE_CHECKING, Callable, Mapping, Sequence, cast

import numpy as np

from host_tools.analyzer.prepare.command_lag import Z_ESTIMATE
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.prepare.timing import TIMING_FROM_START
from host_tools.analyzer.replay.channels import channels
from host_tools.analyzer.replay.closedloop import CTL_KEYS, REPLAYABLE_CONTROLLERS, VELOCITY_LOOPS
from host_tools.analyzer.signals import robust_std
from host_tools.segments import segments_speeds

if TYPE_CHECKING:
    from host_tools.analyzer.replay.openloop import OpenLoopReplay


UNSEEN_PATTERN_HALF = 4   # unseen ticks on either side averaged into one tick's pattern (within 8 ticks)
UNSEEN_BRACKET_SIGMA = 3.0  # an unseen tick's command: within its bracket +- this many sigma
TICK_SHIFT_GAIN = 0.5        # _replay_tick_shift: a shift must cut the disagreement by this


def _replay_tick_shift(prep: PreparedRun, cl_sim: Mapping[str, np.ndarray], k: np.ndarray,
                       seen: np.ndarray) -> int:
    """The closed-loop replay's tick that matches each recorded tick is ``k`` plus this
    shift (-1, 0 or 1): the one under which the replay's duties bend where the reported ones
    do (least squares of their departures from the line through the neighbouring reported
    ticks).  A recording's tick phase a millisecond off its true value can put the replay's
    staircase and steps a whole tick early or late.  Tried only where the phase was estimated
    (:func:`fill_unseen_from_controller`)."""
    n = np.asarray(cl_sim["t_s"]).size
    # the reported ticks that every trial shift keeps inside the replay
    i = np.flatnonzero(seen & (k >= 1) & (k < n - 1))
    if i.size < 5:
        return 0
    x = k[i].astype(float)

    def bend(v: np.ndarray) -> np.ndarray:
        w = (x[1:-1] - x[:-2]) / np.maximum(x[2:] - x[:-2], 1e-9)
        return cast(np.ndarray, v[1:-1] - (v[:-2] + (v[2:] - v[:-2]) * w))
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


def fill_unseen_from_controller(prep: PreparedRun, cl_sim: Mapping[str, np.ndarray]
                                ) -> tuple[PreparedRun, int]:
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
    reproduces), is added to the fill.  Where the recording's tick phase was estimated, the
    replay's ticks are matched to the recording's a tick early or late when its bends say so
    (:func:`_replay_tick_shift`); where the ticks run from the experiment's start
    (``TIMING_FROM_START``: the closed-loop replay starts its controller at the same board
    time), the replay's tick k is the recording's tick k and no shift is tried: there is no
    phase to correct, and a shift the bends ask for there comes from bends whose height the
    nominal plant gets wrong (a clamp's release), which puts the staircase on the other ticks
    and the fill the wrong way on each of them.  The reported ticks stay as recorded.  Returns (the
    prepared run with the refined commands, a new value: ``prep`` is left as it is; the
    number of ticks changed, 0: ``prep`` itself)."""
    seen = prep.seen_ticks
    ts = np.asarray(cl_sim.get("t_s", np.zeros(0)), float)
    if seen is None or ts.size < 3 or bool(np.all(seen)):
        return prep, 0
    T = float(ts[1] - ts[0])
    period = float(prep.inner_period or 0.0)
    if T <= 0 or abs(T - period) > 1e-6 * max(period, 1e-9):
        return prep, 0
    k = np.round((prep.t_in - ts[0]) / T).astype(np.int64)
    if prep.timing != TIMING_FROM_START:
        k = k + _replay_tick_shift(prep, cl_sim, k, np.asarray(seen, bool))
    inside = (k >= 0) & (k < ts.size)
    k_seen = k[seen & inside]
    unseen = np.flatnonzero(~seen & inside)
    if k_seen.size < 2 or unseen.size == 0:
        return prep, 0

    i_seen = np.flatnonzero(seen)
    j_next = np.clip(np.searchsorted(i_seen, unseen), 1, i_seen.size - 1)
    prev_i, next_i = i_seen[j_next - 1], i_seen[j_next]
    ku = k[unseen]
    # the staircase's place of each unseen tick: the outer phase of the reported tick before
    # it, its distance from that tick and the distance between the two reported ticks that
    # bracket it.  A periodic staircase on a trend lies off the line through the reported
    # ticks by the same amount wherever this is the same, and by another amount (another
    # sign) where it is not, so the pattern is averaged within one place only.
    m = outer_ticks(prep)
    kp, kn = k[prev_i], k[next_i]
    place = (np.unique(np.stack([np.mod(kp, m), ku - kp, kn - kp], axis=1), axis=0,
                       return_inverse=True)[1].ravel()
             if m >= 2 else np.zeros(ku.size, np.int64))

    def pattern(u: np.ndarray) -> tuple[np.ndarray, float]:
        off = u[ku] - np.interp(ku, k_seen, u[k_seen])
        # averaged over the unseen ticks in the same place of the staircase within
        # 2 * UNSEEN_PATTERN_HALF ticks (every other tick unseen: UNSEEN_PATTERN_HALF on
        # either side), never over other, distant gaps
        smooth = np.empty_like(off)
        for pl in np.unique(place):
            sel = np.flatnonzero(place == pl)
            kk = ku[sel]
            c = np.concatenate([[0.0], np.cumsum(off[sel])])
            lo = np.searchsorted(kk, kk - 2 * UNSEEN_PATTERN_HALF, side="left")
            hi = np.searchsorted(kk, kk + 2 * UNSEEN_PATTERN_HALF, side="right")
            smooth[sel] = (c[hi] - c[lo]) / (hi - lo)
        # a single tick far off the line (a step: the end of a ramp, a clamp taking hold) is
        # the controller's, not an encoder count's: kept beyond 3 sigma of the tick-level
        # scatter (soft threshold), the scatter itself averaged away
        dev = off - smooth
        sigma = robust_std(dev) if dev.size > 4 else 0.0
        return smooth + np.sign(dev) * np.maximum(np.abs(dev) - 3.0 * sigma, 0.0), sigma

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
        return cast(np.ndarray, out)
    duty = (refined(prep.duty[0], "pwm_r"), refined(prep.duty[1], "pwm_l"))
    torque = prep.torque
    if prep.t_in_tau.size == prep.t_in.size and np.array_equal(prep.t_in_tau, prep.t_in):
        torque = (refined(prep.torque[0], "tau_cmd_r"), refined(prep.torque[1], "tau_cmd_l"))
    return dataclasses.replace(prep, duty=duty, torque=torque), int(unseen.size)


def fill_count_level(prep: PreparedRun) -> tuple[PreparedRun, int]:
    """The straight-line fill of the unreported ticks with the reported ticks' count
    quantization taken out, for a single wheel-speed loop (meta.json ``controller`` ``pi``).

    Such a loop's proportional term acts on the speed counted over one tick: one count more is
    2 pi / (counts a revolution x the loop's period), 1.69 rad/s for the robot's encoder at a
    2 ms loop, so the command sits on one of two levels a count apart, tick by tick.  A frame reports one tick's level, and for blocks of
    frames the same one (the frames alias the count beat); the line through the reported
    commands then runs a fraction of a level off the unreported ticks' mean, with one sign for
    the whole block, and held open loop that drifts the wheel speed by several noise floors.
    What the recording says: the reported tick's counted speed (``omega``) and the encoder
    counts of the frames, whose difference over an interval is the mean of the ticks' counted
    speeds over it exactly.  The command's dependence on the counted speed, ``g``, is the least
    squares slope of the reported commands' second differences on the reported speeds' (trend
    removed: each middle value minus the line through its neighbours at its time, which for
    unevenly spaced reported ticks, lost frames, is not their mean; the count steps are the only
    fast change of the counted speed), taken only where the reported data establish it
    (:func:`count_gain`: against the counted speed, significant, the commands at the duty's
    limit left out; fitted over the case's runs with the same loop, :func:`count_gains`, where
    the analysis sets ``prep.count_gains``; else that side is not moved); each unreported
    tick's fill moves by ``g x`` (the line through the reported counted speeds minus the
    count-mean speed, the latter taken through the intervals' mid-times and read half a period
    before the tick: its counted speed is the mean over the tick before it, which on a ramp
    lags the speed at the tick by acceleration x period / 2, three counts at a 25 ms loop on a
    33 rad/s^2 ramp); a tick between two reported commands at the duty's limit is not moved
    (the loop was held there), and a moved command stays inside the limits.  Returns (the run
    with those fills, a new value; the number of ticks changed, 0: ``prep`` itself)."""
    lv = _count_level(prep)
    if lv is None:
        return prep, 0
    unseen, tk, corr = lv
    duty = []
    for side, c in enumerate(corr):
        u = np.asarray(prep.duty[side], float).copy()
        if c is not None:
            u[unseen] = np.clip(u[unseen] + c(tk), -1.0, 1.0)
        duty.append(u)
    if all(c is None for c in corr):
        return prep, 0
    return dataclasses.replace(prep, duty=(duty[0], duty[1])), int(unseen.size)


def _reported_rows(prep: PreparedRun
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """A single wheel-speed loop's reported ticks: (their indices, the unreported ticks', the
    telemetry row of each reported tick, the reported ticks' ``lam``: each one's share of the
    way between its two neighbours in time), or None when the run is not such a loop, reports
    every tick or too few, or lacks the columns."""
    seen = prep.seen_ticks
    run = getattr(prep, "run", None)
    if seen is None or run is None or run.meta.get("controller") != "pi":
        return None
    seen = np.asarray(seen, bool)
    tel = prep.run.telemetry
    if any(c not in tel for c in ("enc_r", "enc_l", "omega_r", "omega_l", "t_s")):
        return None
    i_seen, unseen = np.flatnonzero(seen), np.flatnonzero(~seen)
    t_in = np.asarray(prep.t_in, float)
    t_tel = np.asarray(tel["t_s"], float)
    if unseen.size == 0 or i_seen.size < 5 or t_tel.size < 5:
        return None
    # the telemetry row of each reported tick (the nearest in time)
    row = np.clip(np.searchsorted(t_tel, t_in[i_seen]), 1, t_tel.size - 1)
    row = np.where(np.abs(t_tel[row - 1] - t_in[i_seen]) < np.abs(t_tel[row] - t_in[i_seen]),
                   row - 1, row)
    if np.unique(row).size != row.size or np.any(np.diff(t_tel[row]) <= 0):
        return None
    # the trend a reported tick's second difference takes out is the line through its two
    # neighbours at its own time: lost frames space the reported ticks unevenly, and the plain
    # mean of the neighbours leaves a share of the trend in it (30 % lost halved g)
    ts = t_in[i_seen]
    lam = (ts[1:-1] - ts[:-2]) / (ts[2:] - ts[:-2])
    return i_seen, unseen, row, lam


def _gain_series(prep: PreparedRun) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None:
    """Per side the reported commands, counted speeds and ``lam`` :func:`count_gain` fits."""
    rep = _reported_rows(prep)
    if rep is None:
        return None
    i_seen, _, row, lam = rep
    tel = prep.run.telemetry
    return [(np.asarray(prep.duty[side], float)[i_seen], np.asarray(tel[om], float)[row], lam)
            for side, om in enumerate(("omega_r", "omega_l"))]


def count_gains(preps: Sequence[PreparedRun]) -> list[tuple[float | None, float | None] | None]:
    """Per run, its single wheel-speed loop's count-level gain per side (:func:`count_gain`)
    fitted over every run of the case with the same loop (meta.json ``pi`` gains, loop period
    and encoder): one loop, one gain, established by all its runs' reported ticks (a run alone
    may hold too few triples inside the duty's limits, or too noisy ones); None for a run that
    is not such a loop."""
    series = [_gain_series(p) for p in preps]
    groups: dict[str, list[int]] = {}
    for i, (p, sr) in enumerate(zip(preps, series)):
        if sr is not None:
            key = json.dumps([p.run.meta.get("pi"), float(p.inner_period), int(p.ppr)],
                             sort_keys=True, default=str)
            groups.setdefault(key, []).append(i)
    out: list[tuple[float | None, float | None] | None] = [None] * len(preps)
    for members in groups.values():
        gs = tuple(count_gain([series[i][side] for i in members])  # type: ignore[index]
                   for side in (0, 1))
        for i in members:
            out[i] = (gs[0], gs[1])
    return out


def _count_level(prep: PreparedRun
                 ) -> tuple[np.ndarray, np.ndarray,
                            list[Callable[[np.ndarray], np.ndarray] | None]] | None:
    """What :func:`fill_count_level` moves: (the unreported ticks, their times, per side the
    move as a function of time, None where the reported commands do not follow the counted
    speed), or None when the run is not a single wheel-speed loop or lacks the columns.  The
    gain is ``prep.count_gains`` (:func:`count_gains`, the case's runs together) where set,
    else the run's own."""
    rep = _reported_rows(prep)
    if rep is None:
        return None
    i_seen, unseen, row, lam = rep
    tel = prep.run.telemetry
    t_in = np.asarray(prep.t_in, float)
    t_tel = np.asarray(tel["t_s"], float)
    q = 2.0 * math.pi / float(prep.ppr)
    ts = t_in[i_seen]
    # the counts are the frame's (its own time), the command and the counted speed its tick's
    tf = t_tel[row]
    dt = np.diff(tf)
    mid = 0.5 * (tf[1:] + tf[:-1])
    # a tick's counted speed is the count difference over the tick before it: the mean speed
    # over that tick, whose mid-time is half a period before the tick (on a trend, a 25 ms
    # loop's counted speed lags the speed at the tick by several counts)
    half = 0.5 * float(prep.inner_period or 0.0)
    q_tick = q / float(prep.inner_period) if prep.inner_period else math.inf
    corr: list[Callable[[np.ndarray], np.ndarray] | None] = []
    for side, (enc, om) in enumerate((("enc_r", "omega_r"), ("enc_l", "omega_l"))):
        us = np.asarray(prep.duty[side], float)[i_seen]
        w_rep = np.asarray(tel[om], float)[row]
        w_mean = np.diff(np.asarray(tel[enc], float)[row]) * q / dt
        g = (prep.count_gains[side] if prep.count_gains is not None
             else count_gain([(us, w_rep, lam)]))
        if g is None:
            corr.append(None)
            continue

        # where the reported commands on both sides are at the duty's limit the loop was held
        # there: its count response is not seen, and the unreported ticks are left on the line
        at_lim = np.abs(us) >= 1.0

        # the count level is at most what the quantization can make: a reported counted
        # speed is off the tick's mean speed by (r_before - r_tick) counts a tick, r the
        # position's residue below its count (in [0, 1)), so the line through two of them by
        # less than one count a tick, and an interval's counted mean speed by less than one
        # count over the interval; what the line departs from the counts' mean speed beyond
        # that is the speed's own curvature between the reported ticks, which the command
        # follows through all its terms, not by the count step's g
        def move(t: np.ndarray, g: float = g, w_rep: np.ndarray = w_rep,
                 w_mean: np.ndarray = w_mean, at_lim: np.ndarray = at_lim) -> np.ndarray:
            a = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 1)
            b = np.clip(np.searchsorted(ts, t, side="left"), 0, ts.size - 1)
            bound = q_tick + np.interp(t - half, mid, q / dt)
            lvl = np.clip(np.interp(t, ts, w_rep) - np.interp(t - half, mid, w_mean),
                          -bound, bound)
            return np.where(at_lim[a] & at_lim[b], 0.0, g * lvl)
        corr.append(move)
    return unseen, t_in[unseen], corr


COUNT_GAIN_Z = Z_ESTIMATE  # a count-level gain must exceed this many standard errors (one-sided 1 %)


def count_gain(series: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> float | None:
    """A single wheel-speed loop's count-level gain from its reported ticks (:func:`_count_level`)
    in one or more runs, each (reported commands, counted speeds, ``lam``): the least squares
    slope ``g`` of the commands' second differences on the counted speeds' (each middle value
    minus the line through its neighbours at its time, ``lam`` its share of the way from the
    first to the third), the commands' ``-g``; None where the reported data do not establish it.  A proportional term acts against the counted speed (the command falls
    when one count more is counted: ``g`` > 0; the duty's back-EMF term, counted speed /
    no-load speed, acts with it but is the smaller for any loop whose gain, (kp + ki x period)
    in N m per rad/s, exceeds stall torque / no-load speed, 0.021 for the robot's motor against
    the recorders' 0.04 or more; a loop below that is not moved), and ``g`` is taken only when it exceeds
    :data:`COUNT_GAIN_Z` standard errors; the standard error is the regression residuals',
    with the covariance of neighbouring triples (they share samples: lags 1 and 2) in a
    Newey-West sum.  Triples with a command at the duty's limit (+-1) are left out: a clamped
    command does not follow the count."""
    fit = count_gain_fit(series)
    if fit is None or fit[0] <= 0 or not fit[1] > COUNT_GAIN_Z:
        return None
    return fit[0]


def count_gain_fit(series: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]
                   ) -> tuple[float, float, int] | None:
    """:func:`count_gain`'s fit before its test: (``g``, ``g`` over its standard error, the
    triples used), or None with fewer than three triples inside the duty's limits."""
    pairs = []
    for us, w_rep, lam in series:
        free = np.abs(us) < 1.0
        ok = free[1:-1] & free[:-2] & free[2:]
        pairs.append(((us[1:-1] - ((1.0 - lam) * us[:-2] + lam * us[2:]))[ok],
                      (w_rep[1:-1] - ((1.0 - lam) * w_rep[:-2] + lam * w_rep[2:]))[ok]))
    den = sum(float(np.sum(d_w ** 2)) for _, d_w in pairs)
    n = sum(int(d_w.size) for _, d_w in pairs)
    if n < 3 or den <= 0:
        return None
    g = -sum(float(np.sum(d_u * d_w)) for d_u, d_w in pairs) / den
    # the slope's variance: sum_ij d_w_i d_w_j e_i e_j / den^2 over the triples |i - j| <= 2
    # apart in one run (a triple shares samples with the two on either side), Bartlett-weighted;
    # the runs are independent
    s = 0.0
    for d_u, d_w in pairs:
        p = d_w * (d_u + g * d_w)
        s += float(np.sum(p * p)) + 2.0 * sum((1.0 - k / 3.0) * float(np.sum(p[k:] * p[:-k]))
                                              for k in (1, 2))
    se = math.sqrt(max(s, 0.0)) / den
    return g, (g / se if se > 0 else math.copysign(math.inf, g)), n


UNSEEN_ENSEMBLE = 8        # replays with the unreported commands drawn from their uncertainty


ReplayUnc = dict[str, tuple[np.ndarray, np.ndarray]]  # channel -> (t, std) (PreparedRun.replay_unc)


def outer_ticks(prep: PreparedRun) -> int:
    """Inner ticks per outer period of a cascade (meta.json ``periods_s``: outer / inner), 1
    when the recorder gives none or its controller has no outer loop (a single wheel-speed
    loop such as ``pi``, whatever outer period meta.json gives)."""
    ctl = prep.run.meta.get("controller")
    if ctl is not None and ctl not in REPLAYABLE_CONTROLLERS:
        return 1
    per = prep.run.meta.get("periods_s") or {}
    inner, outer = float(per.get("inner", 0.0) or 0.0), float(per.get("outer", 0.0) or 0.0)
    return max(int(round(outer / inner)), 1) if inner > 0 else 1


def phase_term(prep: PreparedRun) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None:
    """The unreported ticks' offset within a cascade's outer period that the straight-line fill
    cannot see: (block of each unreported tick, per side the offset per unit draw), or None.

    A cascade whose outer period spans ``m = periods_s.outer / periods_s.inner >= 2`` inner
    ticks (meta.json) moves its command mostly at the outer tick (the torque) and a little at
    every tick (the speed feed-forward): while the wheels accelerate the duty is a staircase of
    ``m`` ticks.  A telemetry period that is not a whole number of outer periods reports one
    phase of that staircase for a block of frames (a 29 ms loop seen every 55 ms: the reported
    tick slides by 3 ms a frame, so for ~10 frames the same one of each pair is unreported),
    and the unreported tick lies off the line through the reported ones by up to one tick's
    change of the command, ``slope x inner period``, with a sign fixed by the phase: the same
    for the whole block, and nothing recorded says which.  The term is taken from the
    recording alone: the slope of the reported commands at each unreported tick times the inner
    period, for one draw in [-1, 1] per block of unreported ticks whose preceding reported tick
    keeps its phase within the outer period.  None when the recorder's controller is not a
    cascade (meta.json ``controller``, absent: the cascade; a single wheel-speed loop such as
    ``pi`` has no outer loop, whatever outer period meta.json gives), the outer period is a
    single tick, every tick is reported, or the fill is no longer the straight line
    (:func:`fill_unseen_from_controller` refined it with the controller's own staircase)."""
    seen = prep.seen_ticks
    m = outer_ticks(prep)
    if seen is None or m < 2:
        return None
    inner = float(prep.run.meta["periods_s"]["inner"])
    seen = np.asarray(seen, bool)
    i_seen, unseen = np.flatnonzero(seen), np.flatnonzero(~seen)
    if unseen.size == 0 or i_seen.size < 3:
        return None
    t = np.asarray(prep.t_in, float)
    if any(np.any(np.abs(np.asarray(u, float)[unseen]
                         - np.interp(t[unseen], t[i_seen], np.asarray(u, float)[i_seen])) > 1e-12)
           for u in prep.duty):
        return None
    # the ticks' index on the inner grid (its origin within the outer period is unknown and
    # does not matter: only where the reported phase changes does)
    k = np.round((t - (prep.tick_phase or 0.0)) / inner).astype(np.int64)
    j = np.clip(np.searchsorted(i_seen, unseen) - 1, 0, i_seen.size - 1)
    ph = k[i_seen[j]] % m
    block = np.concatenate([[0], np.cumsum(np.diff(ph) != 0)])
    off = []
    for u in prep.duty:
        us = np.asarray(u, float)[i_seen]
        slope = np.gradient(us, t[i_seen])
        off.append(np.interp(t[unseen], t[i_seen], slope) * inner)
    return block, (off[0], off[1])


def feedforward_gains(meta: Mapping[str, object]) -> tuple[float, float, float, float, float] | None:
    """(r, b, m_ff, I_ff, stall torque) of the recording's controller: the feed-forward mass and
    yaw inertia as lib/control configures them for meta.json's robot, motor and velocity loop
    (``controller_variant``), read through the ``ctl_*`` C ABI (``ff.m_kg``, ``ff.I_kgm2``); None
    where meta.json does not give them."""
    from host_tools.control import Controller
    try:
        robot = cast("Mapping[str, float]", meta["robot"])
        motor = cast("Mapping[str, float]", meta["motor"])
        params = {k: float(v) for part in (robot, motor) for k, v in part.items() if k in CTL_KEYS}
        variant = meta.get("controller_variant", "improved")
        ctl = Controller(fixed_point=False, params={"controller": VELOCITY_LOOPS[cast(str, variant)], **params})
        return (float(robot["r"]), float(robot["b"]), ctl.get("ff.m_kg"), ctl.get("ff.I_kgm2"),
                float(motor["stall_nm"]))
    except (KeyError, TypeError, ValueError):
        return None


def feedforward_term(prep: PreparedRun) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]] | None:
    """The cascade's acceleration feed-forward that the straight-line fill of unreported ticks
    cannot see: (the unseen ticks' indices, the gap of each, per side the feed-forward's
    departure from its own line through the reported ticks, in duty), or None.

    A cascade's outer step takes the reference's acceleration at its tick and adds
    ``(r/2) m_ff dv +- (r/2b) I_ff domega`` (m_ff, I_ff: :func:`feedforward_gains`) to each
    wheel's torque, in force from the next inner
    tick for one outer period.  A reference segment shorter than an outer period (a ramp the
    outer ticks see one sample of) makes that a pulse of one outer period, and when the frames
    that would report its ticks are lost no reported command shows it: the line through the
    reported ticks misses all of it; at a ramp's start or end inside a gap the line misses part
    of the step.  Needs a ``segments`` reference in meta.json (which lib/control does not
    replay, so nothing else refines the fill) and a cascade (meta.json ``controller`` absent or
    one lib/control replays) with an outer period of whole ticks.  The departure is drawn in
    :func:`input_uncertainty`, not added to the fill: where the torque command sits at the
    clamp (tau_max, a hard reversal) the feed-forward does not reach it (hb15_mj_payload_60s,
    hb25_mj_driver_voltage_drop_60s: the given commands' departure over it had a median of
    0.1-0.6, and the fill with it added was further off than without)."""
    seen = prep.seen_ticks
    meta = prep.run.meta
    ref = meta.get("reference")
    ctl = meta.get("controller")
    if (seen is None or not isinstance(ref, Mapping) or ref.get("kind") != "segments"
            or (ctl is not None and ctl not in REPLAYABLE_CONTROLLERS)):
        return None
    seen = np.asarray(seen, bool)
    i_seen, unseen = np.flatnonzero(seen), np.flatnonzero(~seen)
    if unseen.size == 0 or i_seen.size < 2:
        return None
    per = meta.get("periods_s") or {}
    inner, outer = float(per.get("inner", 0.0) or 0.0), float(per.get("outer", 0.0) or 0.0)
    m = int(round(outer / inner)) if inner > 0 else 0
    if m < 1 or abs(m * inner - outer) > 1e-9:
        return None
    t0 = float(cast(float, ref.get("t0_s", 0.0) or 0.0))
    k = np.round((np.asarray(prep.t_in, float) - t0) / inner).astype(np.int64)
    # the outer tick whose step is in force at inner tick k: the last one before it
    k_outer = m * np.floor_divide(k - 1, m)
    # a boundary within 1 us counts as reached (the recorder sums the durations in double
    # precision, on a 0.2 ms step)
    speeds = segments_speeds(ref, t0 + k_outer * inner, eps_s=1e-6)
    if speeds is None:
        return None
    acc = speeds[2:]
    gains = feedforward_gains(meta)
    if gains is None:
        return None
    r, b, m_ff, i_ff, stall = gains
    p_ff = 0.5 * r * m_ff * acc[0] / stall
    q_ff = 0.5 * r / b * i_ff * acc[1] / stall
    gap = np.concatenate([[0], np.cumsum(np.diff(unseen) > 1)])
    dep = []
    for f in (p_ff + q_ff, p_ff - q_ff):
        dep.append(f[unseen] - np.interp(unseen, i_seen, f[i_seen]))
    if not any(np.any(np.abs(d) > 0) for d in dep):
        return None
    return unseen, gap, (dep[0], dep[1])


def fill_spread(prep: PreparedRun
                ) -> tuple[np.ndarray, np.ndarray, list[float], list[np.ndarray]] | None:
    """The spread of the straight-line fill of the ticks no frame reported, as
    :func:`input_uncertainty` draws it: (the unseen ticks' indices, the gap of each (consecutive
    unseen ticks share one), per side the tick-level scatter's std, per side the bend's std at
    each unseen tick), or None when no tick is unseen or fewer than three are reported."""
    seen = prep.seen_ticks
    if seen is None:
        return None
    seen = np.asarray(seen, bool)
    i_seen = np.flatnonzero(seen)
    unseen = np.flatnonzero(~seen)
    if unseen.size == 0 or i_seen.size < 3:
        return None
    j = np.searchsorted(i_seen, unseen)
    a, b = np.clip(j - 1, 0, i_seen.size - 1), np.clip(j, 0, i_seen.size - 1)
    ts, tk = np.asarray(prep.t_in, float)[i_seen], np.asarray(prep.t_in, float)[unseen]
    # a gap: consecutive unseen ticks; its ticks share one draw of the bend (a ramp that went
    # on into the gap, or stopped early, does so for all of them)
    gap = np.concatenate([[0], np.cumsum(np.diff(unseen) > 1)])
    white, bend = [], []
    lv = _count_level(prep)
    for side, u in enumerate(prep.duty):
        us = np.asarray(u, float)[i_seen]
        if lv is not None and (move := lv[2][side]) is not None:
            # a single wheel-speed loop's reported commands sit on one of two count levels
            # (fill_count_level): the fill is the line through them with that level taken
            # out, and so is what it can miss
            us = us + move(ts)
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
    return unseen, gap, white, bend


def input_uncertainty(prep: PreparedRun, replay: "OpenLoopReplay",
                      n: int = UNSEEN_ENSEMBLE) -> ReplayUnc | None:
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
    / sqrt(1.5): the fill's own error for white scatter), drawn per tick.  A cascade whose outer
    period spans several inner ticks adds :func:`phase_term` where the fill is the straight
    line: the staircase's unreported phase, one uniform draw in [-1, 1] per block of frames
    that report the same phase, times that tick's change of the command (independent of the
    other draws: the variances add).  A cascade on a ``segments`` reference adds
    :func:`feedforward_term`: the reference's acceleration feed-forward's departure from its line
    through the reported ticks, which the feedback's response to the same reference change and
    the torque clamp take partly or wholly back, as one normal draw per gap of std
    ``|departure| / sqrt(3)``, shared by both wheels (one reference change moves both), from
    its own random stream (the other draws unchanged).  The replay turns the
    draws into the output errors they cause, large
    where the output is sensitive to the input (a slipping wheel, a step) and small elsewhere.
    Returns it as channel -> (t, std over the draws, the draws matched by sample time:
    :func:`_spread_over_draws`), or None when no tick is unseen (no draw); the pipeline puts it in the run's ``replay_unc``, which :func:`channels` attaches
    to the channels; decisions compare residuals with the noise floor and this uncertainty in
    quadrature (:meth:`Channel.deflated`).  Draws are seeded by the run's content, so an
    analysis is repeatable.  ``prep`` is left as it is."""
    spread = fill_spread(prep)
    if spread is None or n < 2:
        return None
    unseen, gap, white, bend = spread
    seed = int(np.uint32(int(np.sum(np.asarray(prep.run.telemetry["t_s"], float) * 1e3)) & 0xFFFFFFFF))
    rng = np.random.default_rng([seed, unseen.size])
    phase = phase_term(prep)
    # the phase term's draws from their own stream: the other draws stay as they are
    rng_ph = np.random.default_rng([seed, unseen.size, 2])
    ff = feedforward_term(prep)
    rng_ff = np.random.default_rng([seed, unseen.size, 3])
    base = cast("tuple[np.ndarray, np.ndarray]", tuple(np.asarray(u, float) for u in prep.duty))
    acc: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for _ in range(n):
        draw = []
        # one draw per block, shared by both wheels (the frames report the same tick of each)
        zp = None if phase is None else rng_ph.uniform(-1.0, 1.0, int(phase[0][-1]) + 1)
        # the feed-forward's share that reached the command: one draw per gap, both wheels
        zf = None if ff is None else rng_ff.standard_normal(int(ff[1][-1]) + 1)
        for side, (u, w, bd) in enumerate(zip(base, white, bend)):
            v = u.copy()
            z = rng.standard_normal(int(gap[-1]) + 1)
            v[unseen] += z[gap] * bd + rng.standard_normal(unseen.size) * w
            if phase is not None and zp is not None:
                v[unseen] += zp[phase[0]] * phase[1][side]
            if ff is not None and zf is not None:   # ff[0]: the same unseen ticks
                v[ff[0]] += zf[ff[1]] * ff[2][side] / math.sqrt(3.0)
            draw.append(np.clip(v, -1.0, 1.0))
        drawn = dataclasses.replace(prep, duty=cast("tuple[np.ndarray, np.ndarray]", tuple(draw)))
        for name, ch in channels(drawn, replay.simulate_windows(drawn, {}), "duty").items():
            acc.setdefault(name, []).append((ch.t, ch.resid))
    return {name: sd for name, v in acc.items()
            if (sd := _spread_over_draws(v)) is not None}


def _spread_over_draws(draws: list[tuple[np.ndarray, np.ndarray]]
                       ) -> tuple[np.ndarray, np.ndarray] | None:
    """(t, std over the draws) of one channel's residuals, drawn as (t, resid) per draw: at
    every sample time that at least half of the draws have, over those that have it.  A
    channel's samples may depend on the drawn commands (the current is compared only at
    samples away from a change of the duty, and a drawn unseen tick changes it), so the draws
    are matched by time, not by index; None without such a time."""
    if len({t.size for t, _ in draws}) == 1 and all(np.array_equal(t, draws[0][0])
                                                    for t, _ in draws):
        t = draws[0][0]
        return (t, np.std(np.array([r for _, r in draws]), axis=0)) if t.size else None
    times = np.unique(np.concatenate([t for t, _ in draws]))
    vals = np.full((len(draws), times.size), np.nan)
    for k, (t, r) in enumerate(draws):
        vals[k, np.searchsorted(times, t)] = r
    enough = np.sum(np.isfinite(vals), axis=0) >= max(2, (len(draws) + 1) // 2)
    if not enough.any():
        return None
    return times[enough], np.nanstd(vals[:, enough], axis=0)
