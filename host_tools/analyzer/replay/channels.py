"""Recording against simulation on common channels, each a pair (recorded, simulated) on the
recording's own time base."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Collection, Mapping, cast

import numpy as np

from host_tools.analyzer import signals as sg
from host_tools.analyzer.prepare.odometry import encoder_odometry, wrap_angle
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.anchors import _count_anchor_shift, _gt_anchor
from host_tools.analyzer.replay.openloop import WindowSims

# Channels compared (name -> kind).  "fit" channels enter the output-error fit.
CHANNELS = ("omega_r", "omega_l", "enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad",
            "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")
FIT_CHANNELS = ("omega_r", "omega_l", "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")
# Channels the recorder derives from others (odometry from the encoder counts): reported, never
# evidence about physics on their own; a disagreement there while the counts agree is a finding
# about the recorder (its odometry schedule, integration rule or geometry).
DERIVED = ("x_odo_m", "y_odo_m", "phi_odo_rad")
CUMULATIVE = ("enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad")


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
    return cast(np.ndarray, h00 * th[i] + h10 * h * w[i] + h01 * th[i + 1] + h11 * h * w[i + 1])


def _replay_odometry(prep: PreparedRun, sim: Mapping[str, np.ndarray], t: np.ndarray,
                     th0_r: float, th0_l: float, pose0: tuple[float, float, float]
                     ) -> tuple[np.ndarray, ...]:
    """The odometry a telemetry frame reports: the firmware integrates it at its inner-loop
    ticks from the counts of that tick, and a frame carries the pose of the latest tick at or
    before it (the counts in the same frame are read at the frame's own time).  With the tick
    phase reconstructed (:func:`prepare`), the simulated counts are taken at the ticks and the
    pose is reported like that; without it, at the frame times."""
    k = 2 * np.pi / prep.ppr
    r, b = float(prep.robot["r"]), float(prep.robot["b"])
    phase = prep.tick_phase
    period = float(prep.inner_period or 0.0)
    if phase is None or period <= 0 or prep.odo_schedule == "frames":
        q_r = np.floor((_theta_at(sim, "r", t) - th0_r) / k)
        q_l = np.floor((_theta_at(sim, "l", t) - th0_l) / k)
        return encoder_odometry(q_r, q_l, t, r, b, prep.ppr, pose0)
    # ticks from the last one at or before the first frame to the last frame
    n0 = math.floor((t[0] - phase) / period + 1e-9)
    n1 = math.floor((t[-1] - phase) / period + 1e-9)
    ticks = phase + period * np.arange(n0, n1 + 1)
    q_r = np.floor((_theta_at(sim, "r", ticks) - th0_r) / k + 1e-9)
    q_l = np.floor((_theta_at(sim, "l", ticks) - th0_l) / k + 1e-9)
    xo, yo, po = encoder_odometry(q_r, q_l, ticks, r, b, prep.ppr, pose0)
    idx = np.clip(np.floor((t - phase) / period + 1e-9).astype(int) - n0, 0, ticks.size - 1)
    return xo[idx], yo[idx], po[idx]


CURRENT_SETTLE_S = 1e-3


def _last_change(t_in: np.ndarray, values: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
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
    # the sampling band of this replay's own samples (current at a duty step, _sampling_band),
    # joined to ``unc`` in quadrature; kept apart so that it is not carried into replay_unc
    band: np.ndarray | None = None

    @property
    def total_unc(self) -> np.ndarray | None:
        """``unc`` and ``band`` in quadrature (None when neither is set)."""
        if self.band is None:
            return self.unc
        if self.unc is None:
            return self.band
        return cast(np.ndarray, np.sqrt(self.unc ** 2 + self.band ** 2))

    @property
    def resid(self) -> np.ndarray:
        d = self.rec - self.sim
        return wrap_angle(d) if self.name in ("phi_rad", "phi_odo_rad") else d

    def deflated(self, floor: float) -> np.ndarray:
        """The residual in units of the noise floor widened by the replay's uncertainty:
        ``resid * floor / sqrt(floor^2 + unc^2)`` with ``unc`` the replay's uncertainty and the
        sampling band in quadrature (the residual itself when neither is set),
        so that anything that compares it with ``floor`` compares the residual with the two
        added in quadrature."""
        r = self.resid
        unc = self.total_unc
        if unc is None or floor <= 0:
            return r
        return r * (floor / np.sqrt(floor ** 2 + unc ** 2))

    def spans(self) -> list[float]:
        """Range of the recorded values within each replay window."""
        if self.seg is None or self.rec.size == 0:
            return [float(np.ptp(self.rec))] if self.rec.size else [0.0]
        return [float(np.ptp(self.rec[self.seg == s])) for s in np.unique(self.seg)]


def channels(prep: PreparedRun, sim: Mapping[str, np.ndarray] | WindowSims, mode: str = "duty",
             only: Collection[str] | None = None) -> dict[str, Channel]:
    """Recording against simulation on common channels.  ``sim`` is one simulation of the whole
    run (:meth:`OpenLoopReplay.simulate`) or the windows of :meth:`~OpenLoopReplay.simulate_windows`;
    windows are compared each from its own start and concatenated.  ``only`` (channel names):
    the groups of channels none of which is named are not computed (a fit's residual)."""
    n = prep.run.telemetry["t_s"].size
    if not isinstance(sim, WindowSims):
        return _with_uncertainty(prep, _channels_window(prep, sim, 0, n, None, None, only))
    parts = [_channels_window(prep, s, *prep.windows[w], w, sim.effects, only) for w, s in sim]
    out: dict[str, Channel] = {}
    for name in CHANNELS:
        got = [c[name] for c in parts if name in c]
        if not got:
            continue
        band = (None if all(c.band is None for c in got) else
                np.concatenate([c.band if c.band is not None else np.zeros(c.t.size)
                                for c in got]))
        out[name] = Channel(name, np.concatenate([c.t for c in got]),
                            np.concatenate([c.rec for c in got]),
                            np.concatenate([c.sim for c in got]), got[0].unit,
                            np.concatenate([c.seg for c in got]), band=band)
    return _with_uncertainty(prep, out)


def _with_uncertainty(prep: PreparedRun, chans: dict[str, Channel]) -> dict[str, Channel]:
    """The channels with the run's replay uncertainty (``replay_unc``: channel -> (t, unc),
    from :func:`input_uncertainty`) at their sample times; ``chans`` is left as it is."""
    unc = prep.replay_unc
    if not unc:
        return chans
    return {name: (dataclasses.replace(ch, unc=np.interp(ch.t, *unc[name]))
                   if name in unc and ch.t.size else ch)
            for name, ch in chans.items()}


@dataclass
class _Window:
    """The frames [i_a, i_b) of a run and the simulation ``sim`` they are compared with."""

    prep: PreparedRun
    sim: Mapping[str, np.ndarray]
    i_a: int
    i_b: int
    w: int | None
    effects: Mapping[str, Mapping[str, float]] | None = None   # those the plant ran with

    def __post_init__(self) -> None:
        self.tel = self.prep.run.telemetry
        self.t_all = self.tel["t_s"]
        self.t = self.t_all[self.i_a:self.i_b]
        self.g = np.asarray(self.sim["t_s"], float)
        self.k = 2 * np.pi / self.prep.ppr
        self.th_r, self.th_l = self.at("theta_r_rad", self.t), self.at("theta_l_rad", self.t)

    def at(self, name: str, times: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, np.interp(times, self.g, np.asarray(self.sim[name], float)))

    def seg(self, size: int) -> np.ndarray | None:
        return None if self.w is None else np.full(size, self.w, dtype=np.int32)


def _channels_window(prep: PreparedRun, sim: Mapping[str, np.ndarray], i_a: int, i_b: int,
                     w: int | None, effects: Mapping[str, Mapping[str, float]] | None = None,
                     only: Collection[str] | None = None) -> dict[str, Channel]:
    """Channels of the frames [i_a, i_b) against ``sim`` (simulated with ``effects``).  A window
    that does not start the run is compared as increments from its first frame (counts,
    odometry, camera pose)."""
    win = _Window(prep, sim, i_a, i_b, w, effects)
    out: dict[str, Channel] = {}
    for names, group in _GROUPS:
        if only is None or any(c in only for c in names):
            out.update(group(win))
    return out


def _wheel_channels(win: _Window) -> dict[str, Channel]:
    """Wheel speeds (count differences over each telemetry period that the simulation covers)
    and counts."""
    tel, t_all, t, k, at, seg = win.tel, win.t_all, win.t, win.k, win.at, win.seg
    out: dict[str, Channel] = {}
    lo = max(win.i_a, 1)
    while lo < win.i_b and t_all[lo - 1] < win.g[0] - 1e-9:
        lo += 1
    kk = np.arange(lo, win.i_b)
    dt = t_all[kk] - t_all[kk - 1]
    # the count difference's quantization over each sample's own frame interval, beyond what
    # the noise floor holds at the run's median interval (jittered frames)
    band = sg.count_rate_band(dt, float(np.median(np.diff(t_all))) if t_all.size > 1 else 0.0, k)
    band_or_none = band if band.any() else None
    for side in ("r", "l"):
        enc = tel[f"enc_{side}"]
        th = at(f"theta_{side}_rad", t_all[kk])
        th_prev = at(f"theta_{side}_rad", t_all[kk - 1])
        out[f"omega_{side}"] = Channel(f"omega_{side}", t_all[kk], (enc[kk] - enc[kk - 1]) * k / dt,
                                       (th - th_prev) / dt, "rad/s", seg(kk.size),
                                       band=band_or_none)
    for side, th in (("r", win.th_r), ("l", win.th_l)):
        enc = tel[f"enc_{side}"][win.i_a:win.i_b]
        out[f"enc_{side}"] = Channel(f"enc_{side}", t, enc - enc[0], (th - th[0]) / k, "counts",
                                     seg(t.size))
    return out


def _odometry_channels(win: _Window) -> dict[str, Channel]:
    """Odometry of the simulated encoders (quantized like the real ones), from the recorded pose
    at the window's first frame."""
    tel, t, seg, i_a, i_b = win.tel, win.t, win.seg, win.i_a, win.i_b
    pose0 = (tel["x_odo_m"][i_a], tel["y_odo_m"][i_a], tel["phi_odo_rad"][i_a])
    xo, yo, po = _replay_odometry(win.prep, win.sim, t, win.th_r[0], win.th_l[0], pose0)
    return {"x_odo_m": Channel("x_odo_m", t, tel["x_odo_m"][i_a:i_b], xo, "m", seg(t.size)),
            "y_odo_m": Channel("y_odo_m", t, tel["y_odo_m"][i_a:i_b], yo, "m", seg(t.size)),
            "phi_odo_rad": Channel("phi_odo_rad", t, tel["phi_odo_rad"][i_a:i_b], po, "rad",
                                   seg(t.size))}


def _current_channels(win: _Window) -> dict[str, Channel]:
    """Motor current (the shield reports its magnitude) at the samples taken after it settled.

    The recorded torque command is what the controller wanted; an open-loop replay only knows
    the torque the plant delivered, so tau_cmd is compared by the closed-loop replay only."""
    prep, tel, t, w = win.prep, win.tel, win.t, win.w
    out: dict[str, Channel] = {}
    if "i_r_a" not in win.sim:
        return out
    for side in ("r", "l"):
        col = f"current_{side}_a"
        cur = tel.get(col)
        # a constant column (e.g. all zero) is a sensor that is not there
        if cur is not None and cur.dtype.kind == "f" and np.ptp(cur) > 0:
            # the current follows the duty within the armature's electrical time, and where
            # in that transient the ADC sampled is not known: samples within CURRENT_SETTLE_S
            # of a change of the duty are left out
            t_steps = prep.t_steps
            dt_in = (t - _last_change(prep.t_in, prep.duty, t) if t_steps is None
                     else t - _tick_before(np.asarray(t_steps, float), t))
            keep = dt_in >= CURRENT_SETTLE_S
            unc = float(prep.phase_uncertainty_s or 0.0)
            if unc > 0:
                # where the ticks are known only to within unc, a sample that close to a
                # tick may sit on either side of it: left out as well
                steps = prep.t_in if t_steps is None else np.asarray(t_steps, float)
                j = np.searchsorted(steps, t, side="left")
                nxt = np.where(j < steps.size, steps[np.minimum(j, steps.size - 1)], np.inf)
                keep &= (dt_in >= CURRENT_SETTLE_S + unc) & (nxt - t > unc)
            if keep.sum() < max(3, keep.size // 4):
                continue   # the frames coincide with the loop's ticks: no settled sample
            tk = t[keep]
            mag = np.abs(win.at(f"i_{side}_a", tk))
            if prep.sense_noise_a is not None:
                # what the sense reads on average, its noise clipped at nil (locate.mismatch)
                mag = sg.clipped_reading_mean(mag, prep.sense_noise_a[side == "l"])
            out[col] = Channel(col, tk, np.asarray(tel[col][win.i_a:win.i_b], float)[keep],
                               mag, "A",
                               None if w is None else win.seg(int(keep.sum())),
                               band=_sampling_band(win, side, tk))
    return out


# Two replay rows closer than this are the same instant (a frame at an input's time).
MIN_ROW_GAP_S = 1e-6


def _sampling_band(win: _Window, side: str, t: np.ndarray) -> np.ndarray | None:
    """Per current sample at ``t``: the band of where in its tick the recorder sampled.  A
    recorder reads the current at some instant of the frame's tick that the analyzer does not
    know (at the tick before the duty is written, at the frame, anywhere between); where the
    duty stepped at that tick, what it reads lies anywhere between the replay's current just
    before the step and at the frame.  Taken as uniform over that range, its RMS distance from
    the replayed value is |I(t) - I(tick-)| / sqrt(3) (the convention of the input spread,
    ``replay.unseen``); nil where the duty did not change at the tick.  The step's size is
    this replay's own, so an effect that changes the current (back-EMF, driver drop, lag)
    keeps the band of the replay that carries it.  None: no step at any sample.

    The replay's rows are the frames and the input times, and its current at a row already
    follows that row's input, so I(tick-) is the current of the rows before the tick under
    the input held before it, carried on to the tick along the line through the last two of
    them (the armature current runs nearly straight within a tick as the wheel's speed and
    back-EMF change: on a 20 ms PI loop it fell by 5 noise floors within one tick); with one
    such row, its value."""
    prep = win.prep
    t_in = np.asarray(prep.t_in, float)
    duty = np.asarray(prep.duty[0 if side == "r" else 1], float)
    g = win.g
    if t_in.size < 2 or t.size == 0 or g.size < 2:
        return None
    steps = t_in if prep.t_steps is None else np.asarray(prep.t_steps, float)
    j = np.searchsorted(steps, t, side="right") - 1
    tick = steps[np.maximum(j, 0)]
    i_now = np.searchsorted(t_in, t, side="right") - 1
    i_before = np.searchsorted(t_in, tick, side="left") - 1   # the input held before the tick
    r1 = np.searchsorted(g, tick, side="left") - 1            # the replay's last row before it
    stepped = (j >= 0) & (i_before >= 0) & (i_now >= 0) & (r1 >= 0)
    stepped &= duty[np.maximum(i_now, 0)] != duty[np.maximum(i_before, 0)]
    if not stepped.any():
        return None
    cur = np.abs(np.asarray(win.sim[f"i_{side}_a"], float))
    r1 = np.maximum(r1, 0)
    r0 = np.maximum(r1 - 1, 0)
    held_from = t_in[np.maximum(i_before, 0)]
    # rows closer than a microsecond are one instant (a frame at an input's time): no line
    line = (r0 < r1) & (g[r0] >= held_from - 1e-12) & (g[r1] - g[r0] >= MIN_ROW_GAP_S)
    slope = np.where(line, (cur[r1] - cur[r0]) / np.where(line, g[r1] - g[r0], 1.0), 0.0)
    before = cur[r1] + slope * (tick - g[r1])
    delta = np.abs(np.abs(win.at(f"i_{side}_a", t)) - before)
    out: np.ndarray = np.where(stepped, delta / math.sqrt(3.0), 0.0)
    return out


def _camera_channels(win: _Window) -> dict[str, Channel]:
    """The camera's pose against the replay's; a window that does not start the run is
    re-anchored at its first frame (:func:`_gt_anchor`)."""
    prep, t_all, t, g, at, seg = win.prep, win.t_all, win.t, win.g, win.at, win.seg
    i_a, i_b = win.i_a, win.i_b
    anchored = i_a > 0
    out: dict[str, Channel] = {}
    gt = prep.run.groundtruth
    if gt is None:
        return out
    tg_all = gt["t_s"]
    t_hi = t_all[i_b] if i_b < t_all.size else t_all[-1] + 1e-9
    inside = (tg_all >= max(g[0], t[0])) & (tg_all < t_hi) & (tg_all <= g[-1])
    tg = tg_all[inside]
    if tg.size < 3:
        return out
    an = _gt_anchor(prep, float(t[0])) if anchored else None
    shift = _count_anchor_shift(prep, win.sim, t, win.th_r, win.th_l, i_a, i_b, tg, win.effects)
    pos = {c: at(c, tg) - shift[c] for c in ("x_m", "y_m")}
    if anchored:
        # re-anchored in pose, not only in position: the replay's increments are
        # turned by the heading it is off the anchor at the window's first frame (its
        # early start's transient, a few mrad, would otherwise grow into a cross-track
        # drift of millimetres per metre)
        # without an anchor (too few camera samples in the slip-free span around the first
        # frame), the replay is tied to the window's first camera sample at that sample's own
        # time: tied at the first frame instead, it would carry the robot's motion between the
        # two (up to a camera period: 0.3 rad, 0.3 m at 1.5 Hz) as an offset over the window
        t_ref = t[:1] if an is not None else tg[:1]
        p0 = {c: float(at(c, t_ref)[0] - (shift[c][0] if an is None else 0.0))
              for c in ("x_m", "y_m")}
        ref = {c: an[c] if an is not None else float(gt[c][inside][0])
               for c in ("x_m", "y_m")}
        rot = 0.0
        if an is not None and an.get("phi_rad") is not None:
            rot = float(wrap_angle(np.array([an["phi_rad"] - float(at("phi_rad", t[:1])[0])]))[0])
        elif an is None and np.isfinite(gt["phi_rad"][inside][0]):
            rot = float(wrap_angle(np.array([float(gt["phi_rad"][inside][0])
                                             - float(at("phi_rad", tg[:1])[0])
                                             + float(shift["phi_rad"][0])]))[0])
        dx, dy = pos["x_m"] - p0["x_m"], pos["y_m"] - p0["y_m"]
        cr, sr = math.cos(rot), math.sin(rot)
        pos = {"x_m": cr * dx - sr * dy + ref["x_m"], "y_m": sr * dx + cr * dy + ref["y_m"]}
    for c in ("x_m", "y_m"):
        # a window re-anchored to the camera carries its anchor's standard error in position
        # over its samples (constant: the whole window is placed by it), in quadrature with the
        # replay's uncertainty; under a camera of micrometres it can be the largest term
        sd = float(an.get(f"sd_{c}", 0.0)) if anchored and an is not None else 0.0
        out[c] = Channel(c, tg, gt[c][inside], pos[c], "m", seg(tg.size),
                         band=np.full(tg.size, sd) if sd > 0 else None)
    ph = gt["phi_rad"][inside]
    ok = np.isfinite(ph)
    if ok.sum() >= 3:
        # compared modulo 2 pi (Channel.resid wraps)
        sv = at("phi_rad", tg[ok]) - shift["phi_rad"][ok]
        if anchored:
            ref_phi = (an or {}).get("phi_rad")
            if ref_phi is None:
                # the first camera heading, at its own time (as the position above)
                sv = sv - float(sv[0]) + float(ph[ok][0])
            else:
                sv = sv - float(at("phi_rad", t[:1])[0]) + ref_phi
        out["phi_rad"] = Channel("phi_rad", tg[ok], ph[ok], sv, "rad", seg(int(ok.sum())))
    return out


# The channels each group computes, in the order _channels_window adds them.
_GROUPS = ((("omega_r", "omega_l", "enc_r", "enc_l"), _wheel_channels),
           (("x_odo_m", "y_odo_m", "phi_odo_rad"), _odometry_channels),
           (("current_r_a", "current_l_a"), _current_channels),
           (("x_m", "y_m", "phi_rad"), _camera_channels))
