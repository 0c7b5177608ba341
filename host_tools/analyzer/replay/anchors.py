"""Where a replay window starts: the camera-corrected pose at a window's start (its anchors,
computed with the run's windows and slip episodes), and the pose shift that only follows from
the replayed wheels turning otherwise than the recorded counts.  Where the windows are and
the slip episodes: :mod:`.edges`."""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, cast

import numpy as np

from host_tools.analyzer.effects import folded_robot
from host_tools.analyzer.prepare.odometry import encoder_odometry, wrap_angle, odometry_times
from host_tools.analyzer.prepare.run import BURN_IN_S, GAP_S, PreparedRun
from host_tools.analyzer.signals import missing_sample_gap_s


def _line_at(t: np.ndarray, v: np.ndarray, at: float) -> float:
    """Value at ``at`` of a straight line fitted to (t, v)."""
    tt = t - at
    if tt.size < 2 or np.ptp(tt) <= 0:
        return float(np.mean(v))
    A = np.column_stack([np.ones_like(tt), tt])
    return float(np.linalg.lstsq(A, v, rcond=None)[0][0])


def _line_se_at(t: np.ndarray, v: np.ndarray, at: float) -> float:
    """The standard error of :func:`_line_at`'s value at ``at``: the residual's variance about
    the line, s^2 (n - 2 degrees of freedom), times 1/n + (mean of t - at)^2 / Sxx, inflated by
    the residual's lag-1 correlation r1 as an AR(1)'s (1 + r1) / (1 - r1) (r1 below nil taken as
    nil, the factor at most n: a residual that bends smoothly within the span is one error, not
    n).  0 with fewer than four samples."""
    tt = np.asarray(t, float) - at
    n = tt.size
    if n < 4 or np.ptp(tt) <= 0:
        return 0.0
    A = np.column_stack([np.ones_like(tt), tt])
    res = v - A @ np.linalg.lstsq(A, v, rcond=None)[0]
    s2 = float(np.sum(res ** 2)) / (n - 2)
    den = float(np.sum(res[:-1] ** 2))
    r1 = min(max(float(np.sum(res[:-1] * res[1:])) / den, 0.0), 1.0) if den > 0 else 0.0
    infl = min((1.0 + r1) / (1.0 - r1), float(n)) if r1 < 1.0 else float(n)
    xbar = float(tt.mean())
    sxx = float(np.sum((tt - xbar) ** 2))
    return math.sqrt(s2 * (1.0 / n + xbar ** 2 / sxx) * infl)


ANCHOR_HALF_S = 1.5
MIN_SPREAD_M = 0.1


def _anchor_key(prep: PreparedRun, at: float, half: float
                ) -> tuple[float, float, tuple[tuple[float, ...], ...]]:
    return (float(at), float(half), tuple(tuple(e) for e in prep.slip_episodes))


def with_anchors(prep: PreparedRun) -> PreparedRun:
    """``prep`` with the camera anchors of its windows (``PreparedRun.anchors``): at each
    window's early start (:func:`window_start`) and at its first frame (the camera channels,
    ``replay.channels``), for the run's slip episodes.  A fit evaluates them for every window
    at every step (28 % of a 2 x 60 s analysis's time when each was computed there); they read
    only the recording, the windows and the slip episodes, so they are computed here, whenever
    those change (``_with_windows``, ``_with_slip_episodes``), and looked up after."""
    t = prep.run.telemetry["t_s"]
    found: dict[tuple[float, float, tuple[tuple[float, ...], ...]], dict[str, float] | None] = {}
    for w, (i_a, _) in enumerate(prep.windows):
        if w == 0 or i_a == 0:
            continue
        for i in (_early_start(t, i_a), i_a):
            key = _anchor_key(prep, float(t[i]), ANCHOR_HALF_S)
            if key not in found:
                found[key] = _gt_anchor_of(prep, float(t[i]), ANCHOR_HALF_S)
    return dataclasses.replace(prep, anchors=found)


def _gt_anchor(prep: "PreparedRun", at: float, half: float = ANCHOR_HALF_S
               ) -> dict[str, float] | None:
    """The camera anchor at ``at``: the run's own (:func:`with_anchors`) when it has it, else
    computed (:func:`_gt_anchor_of`).  The returned dict is shared: read it, do not change it."""
    key = _anchor_key(prep, at, half)
    if key in prep.anchors:
        return prep.anchors[key]
    return _gt_anchor_of(prep, at, half)


def _gt_anchor_of(prep: "PreparedRun", at: float, half: float = ANCHOR_HALF_S
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
    if _after_gap(prep.run.telemetry["t_s"], at) and slip_containing(prep, at) is not None:
        # a window started after a gap inside a slip (:func:`window_start`)
        cam = camera_state(prep, at)
        return None if cam is None else {c: cam[c] for c in ("x_m", "y_m", "phi_rad")}
    tel = prep.run.telemetry
    t = tel["t_s"]
    tg = gt["t_s"]
    # within the slip-free span around ``at`` (across a slip the odometry stops following the body)
    lo, hi = at - half, at + half
    for a, b in prep.slip_episodes:
        if b <= at:
            lo = max(lo, b)
        elif a >= at:
            hi = min(hi, a)
    po = np.unwrap(tel["phi_odo_rad"])
    # the recorded pose at the time it was computed (a tick or the frame)
    to, keep = np.unique(odometry_times(prep), return_index=True)
    xo_, yo_, po_ = tel["x_odo_m"][keep], tel["y_odo_m"][keep], po[keep]
    here = {"x_m": float(np.interp(at, to, xo_)), "y_m": float(np.interp(at, to, yo_)),
            "phi_rad": float(np.interp(at, to, po_))}
    # the two are compared at the samples of the sparser series, the denser one interpolated
    # there (the error of a straight line between two samples grows with the square of their
    # interval) between two of its samples that miss none: a camera sample between two frames
    # further apart than a missing frame's gap is not used, where the odometry would be a
    # straight line in time while the robot accelerates (a camera sample in the middle of a
    # 0.65 s gap at 2 m/s^2 is 0.1 m off it), nor a frame between two camera samples further
    # apart than a missing one's
    fin = np.isfinite(gt["x_m"]) & np.isfinite(gt["y_m"])
    tgf = tg[fin]
    ph_all = gt.get("phi_rad")
    if to.size > 2 and tgf.size > 2 and np.median(np.diff(tgf)) < np.median(np.diff(to)):
        jg = np.clip(np.searchsorted(tgf, to), 1, tgf.size - 1)
        m = ((to >= lo) & (to <= hi) & (to >= tgf[0]) & (to <= tgf[-1])
             & (tgf[jg] - tgf[jg - 1] <= missing_sample_gap_s(tgf)))
        if m.sum() < 3:
            return None
        tm = to[m]
        odo = {"x_m": xo_[m], "y_m": yo_[m], "phi_rad": po_[m]}
        gx, gy = (np.interp(tm, tgf, np.asarray(gt[c], float)[fin]) for c in ("x_m", "y_m"))
        ph = None
        if ph_all is not None and (okp := np.isfinite(ph_all)).sum() >= 2:
            tp = tg[okp]
            jp = np.clip(np.searchsorted(tp, tm), 1, tp.size - 1)
            ph = np.where(tp[jp] - tp[jp - 1] <= missing_sample_gap_s(tp),
                          np.interp(tm, tp, np.unwrap(np.asarray(ph_all, float)[okp])), np.nan)
    else:
        m = (tg >= lo) & (tg <= hi) & (tg >= t[0]) & (tg <= t[-1])
        if t.size > 2:
            j = np.clip(np.searchsorted(t, tg, side="right"), 1, t.size - 1)
            m &= (t[j] - t[j - 1]) <= missing_sample_gap_s(t)
        if m.sum() < 3:
            return None
        tm = tg[m]
        odo = {"x_m": np.interp(tm, to, xo_), "y_m": np.interp(tm, to, yo_),
               "phi_rad": np.interp(tm, to, po_)}
        gx, gy = gt["x_m"][m], gt["y_m"][m]
        ph = None if ph_all is None else np.asarray(ph_all, float)[m]
    ok = np.isfinite(ph) if ph is not None else np.zeros(tm.size, bool)
    # camera = R(delta) odometry + c over the span.  delta from the positions (2-D Procrustes)
    # when the robot travels far enough for the direction of travel to pin it down better than
    # the camera's headings do (1 mm over a 0.3 m spread: ~0.5 mrad), else from the headings
    # (a straight line in time); c a straight line in time
    ox, oy = odo["x_m"] - odo["x_m"].mean(), odo["y_m"] - odo["y_m"].mean()
    spread = float(np.sqrt(np.mean(ox ** 2 + oy ** 2)))
    if spread >= MIN_SPREAD_M or ok.sum() < 3 or ph is None:  # (ph None: ok is all False)
        qx, qy = gx - gx.mean(), gy - gy.mean()
        delta_at = float(np.arctan2(np.sum(ox * qy - oy * qx), np.sum(ox * qx + oy * qy)))
        delta = np.full(tm.size, delta_at)
    else:
        d = ph[ok] - odo["phi_rad"][ok]
        d0 = float(np.median(wrap_angle(d)))
        dl = d0 + wrap_angle(d - d0)
        A = np.column_stack([np.ones(ok.sum()), tm[ok] - at])
        coef: np.ndarray | list[Any] = np.linalg.lstsq(A, dl, rcond=None)[0] if np.ptp(tm[ok]) > 0 else [np.mean(dl), 0]
        delta = coef[0] + coef[1] * (tm - at)
        delta_at = float(coef[0])
    cx = gx - (np.cos(delta) * odo["x_m"] - np.sin(delta) * odo["y_m"])
    cy = gy - (np.sin(delta) * odo["x_m"] + np.cos(delta) * odo["y_m"])
    ca, sa = math.cos(delta_at), math.sin(delta_at)
    out = {"x_m": ca * here["x_m"] - sa * here["y_m"] + _line_at(tm, cx, at),
           "y_m": sa * here["x_m"] + ca * here["y_m"] + _line_at(tm, cy, at),
           # the anchor's own uncertainty in position (a window's camera channels carry it)
           "sd_x_m": _line_se_at(tm, cx, at), "sd_y_m": _line_se_at(tm, cy, at)}
    out["phi_rad"] = here["phi_rad"] + delta_at
    return out


def _after_gap(t: np.ndarray, at: float) -> bool:
    """Whether board time ``at`` is a frame that follows a telemetry gap (longer than GAP_S)."""
    i = int(np.searchsorted(t, at))
    return 0 < i < t.size and float(t[i]) == at and float(t[i] - t[i - 1]) > GAP_S


def slip_containing(prep: PreparedRun, at: float) -> tuple[float, float] | None:
    """The slip episode (onset, end) of ``prep`` that board time ``at`` falls inside, or None."""
    for a, b in prep.slip_episodes:
        if a < at < b:
            return (a, b)
    return None


def camera_state(prep: PreparedRun, at: float) -> dict[str, float] | None:
    """The body's pose and velocity at board time ``at`` from the camera alone: a parabola in
    time through the camera samples within ROLL_BLOCK_S either side (the span over which
    :func:`rolling_test_of` takes the camera's rates as straight lines), its value and slope
    at ``at``; the velocity as forward (``v``) and sideways (``w``) speed along the fitted
    heading and the heading rate (``omega``).  Used where ``at`` falls inside a slip episode:
    there the odometry does not follow the body, so neither the camera-minus-odometry offset
    (:func:`_gt_anchor_of`) nor the wheels' rolling say where the body is or how it moves,
    and the camera does.  None with fewer than ROLL_MIN_FRAMES camera samples there."""
    gt = prep.run.groundtruth
    if gt is None or gt.get("phi_rad") is None:
        return None
    tg = np.asarray(gt["t_s"], float)
    x, y, ph = (np.asarray(gt[c], float) for c in ("x_m", "y_m", "phi_rad"))
    m = ((tg >= at - ROLL_BLOCK_S) & (tg <= at + ROLL_BLOCK_S)
         & np.isfinite(x) & np.isfinite(y) & np.isfinite(ph))
    if m.sum() < ROLL_MIN_FRAMES or np.ptp(tg[m]) <= 0:
        return None
    tt = tg[m] - at
    fit = {c: np.polyfit(tt, v, 2) for c, v in (("x_m", x[m]), ("y_m", y[m]),
                                                  ("phi_rad", np.unwrap(ph[m])))}
    phi = float(fit["phi_rad"][2])
    vx, vy = float(fit["x_m"][1]), float(fit["y_m"][1])
    c, s = math.cos(phi), math.sin(phi)
    return {"x_m": float(fit["x_m"][2]), "y_m": float(fit["y_m"][2]), "phi_rad": phi,
            "v": c * vx + s * vy, "w": -s * vx + c * vy, "omega": float(fit["phi_rad"][1])}


def _slope_at(t: np.ndarray, v: np.ndarray, at: float) -> float:
    """Slope at ``at`` of the parabola fitted to (t, v) (three or more samples)."""
    return float(np.polyfit(np.asarray(t, float) - at, v, 2)[1])


def _early_start(t: np.ndarray, i_a: int) -> int:
    """The frame a window that begins at frame ``i_a`` starts its replay from: BURN_IN_S
    earlier, not before a gap."""
    first = i_a
    while first > 0 and t[first] - t[first - 1] <= GAP_S and t[i_a] - t[first - 1] <= BURN_IN_S:
        first -= 1
    return first


def window_start(prep: PreparedRun, w: int,
                 effects: Mapping[str, Mapping[str, float]] | None = None
                 ) -> tuple[float, tuple[float, float, float],
                        tuple[float, float, float, float, float] | None]:
    """(start time, start pose, start velocity or None) of replay window ``w``: the run's
    start pose at rest for the first window; otherwise BURN_IN_S before the window (not before
    a gap), moving as the recording says: wheel speeds from the counts around that frame,
    the body rolling with them on the geometry of the plant with ``effects``, pose from the
    camera (else the recorded odometry)."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    i_a, _ = prep.windows[w]
    if w == 0 or i_a == 0:
        return float(prep.t_grid[0]), prep.start_pose, None
    first = _early_start(t, i_a)
    k = 2 * np.pi / prep.ppr
    j0, j1 = max(first - 2, 0), min(first + 2, t.size - 1)
    if first > 0 and t[first] - t[first - 1] > GAP_S:
        j0 = first  # the frame before is across a gap
    if j0 == first and j1 - j0 >= 2:
        # the counts after the frame only (a gap before it, or the run's start): their mean
        # rate is the speed half their span later, off by that time's acceleration; the slope
        # at the frame of the parabola through them is not
        w_r, w_l = (_slope_at(t[j0:j1 + 1], np.asarray(tel[f"enc_{s}"][j0:j1 + 1], float) * k,
                              float(t[first])) for s in ("r", "l"))
    elif j1 > j0:
        w_r = float((tel["enc_r"][j1] - tel["enc_r"][j0]) * k / (t[j1] - t[j0]))
        w_l = float((tel["enc_l"][j1] - tel["enc_l"][j0]) * k / (t[j1] - t[j0]))
    else:
        w_r = w_l = 0.0
    geo = folded_robot(prep.robot, effects or {})
    r, b = float(geo["r"]), float(geo["b"])
    vel = (r * (w_r + w_l) / 2, 0.0, r * (w_r - w_l) / (2 * b), w_r, w_l)
    cam = None
    if _after_gap(t, float(t[first])) and slip_containing(prep, float(t[first])) is not None:
        # started after a gap inside a slip episode (the edge rules move every other window
        # start out of one, ``edges.edges_outside_slip``; a gap's cannot be moved): the body
        # does not roll with its wheels there and the odometry does not follow it, so it
        # starts as the camera shows it, turning and sliding, its wheels as the counts say
        cam = camera_state(prep, float(t[first]))
    if cam is not None:
        vel = (cam["v"], cam["w"], cam["omega"], w_r, w_l)
    pose = (float(tel["x_odo_m"][first]), float(tel["y_odo_m"][first]),
            float(tel["phi_odo_rad"][first]))
    an = _gt_anchor(prep, float(t[first]))
    if an is not None:
        pose = (an["x_m"], an["y_m"], an.get("phi_rad", pose[2]))
    return float(t[first]), pose, vel


def _count_anchor_shift(prep: PreparedRun, sim: Mapping[str, np.ndarray], t: np.ndarray,
                        th_r: np.ndarray, th_l: np.ndarray, i_a: int, i_b: int,
                        tg: np.ndarray, effects: Mapping[str, Mapping[str, float]] | None = None
                        ) -> dict[str, np.ndarray]:
    """The part of the replayed pose that only follows from the replay's wheels turning
    otherwise than the recorded counts say, at the camera times ``tg``; zero unless the run's
    inputs are partly unrecorded (``count_anchored_pose``).

    When some inner ticks' commands were never recorded (a loop faster than the telemetry),
    the replayed wheels drift from the real ones by what the filled-in commands miss, and the
    open-loop pose inherits that drift: millimetres within seconds, above the camera's noise,
    on a null.  The wheels' own motion is tested by the wheel-speed, count and current
    channels; the camera channels are then compared against the replay's pose moved by the
    odometry difference (lib/control's odometry, on the geometry of the replayed plant: the
    nominal one folded with the candidate ``effects``) between the replayed and the recorded
    wheel angles, over the frame intervals in which the replay's wheels roll
    (a slipping wheel's extra turning does not move the body).  What remains in the camera
    channels is what the counts cannot show: the geometry (wheel radius, track width) and
    slip."""
    zero = np.zeros(tg.size)
    if not prep.count_anchored_pose or t.size < 2:
        return {"x_m": zero, "y_m": zero, "phi_rad": zero}
    tel = prep.run.telemetry
    k = 2 * np.pi / prep.ppr
    # the body moves by the replayed plant's wheel radius and track width per wheel angle: a
    # candidate's fitted r_eff / b_eff, not the nominal ones (with those, a right radius fit
    # had left the updated camera channels off by the nominal-to-fitted ratio)
    geo = folded_robot(prep.robot, effects or {})
    r, b = float(geo["r"]), float(geo["b"])
    g = np.asarray(sim["t_s"], float)
    pose0 = cast("tuple[float, float, float]",
                 tuple(float(np.interp(t[0], g, np.asarray(sim[c], float)))
                       for c in ("x_m", "y_m", "phi_rad")))
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
    xs, ys, ps = encoder_odometry(q_sim[0], q_sim[1], t, r, b, prep.ppr, pose0)
    xr, yr, pr = encoder_odometry(q_rec[0], q_rec[1], t, r, b, prep.ppr, pose0)
    # lib/control's odometry wraps its heading to [-pi, pi); the two wrap at different frames
    # when they differ near +-pi, so the difference is taken of the unwrapped headings (both
    # start at pose0) before it is interpolated to the camera times
    dphi = np.unwrap(np.asarray(ps, float)) - np.unwrap(np.asarray(pr, float))
    return {"x_m": np.interp(tg, t, xs - xr), "y_m": np.interp(tg, t, ys - yr),
            "phi_rad": np.interp(tg, t, dphi)}


# The recording's own test of rolling (:func:`rolling_test`): blocks of ROLL_BLOCK_S, and a false
# alarm per run at ROLL_ALPHA (Bonferroni over its blocks); the geometry's scale is fitted over
# the blocks whose counts' rate is ROLL_SCALE_Z of its noise, when there are ROLL_SCALE_MIN.
ROLL_BLOCK_S = 0.25
ROLL_ALPHA = 0.01
ROLL_MIN_FRAMES = 4
ROLL_SCALE_Z = 10.0
ROLL_SCALE_MIN = 8


def _mad_step_sigma(v: np.ndarray) -> float:
    """One sample's noise in the series ``v`` from its second differences (robust: 1.4826 MAD
    / sqrt(6)); 0 without enough samples."""
    if v.size < 5:
        return 0.0
    d2 = v[2:] - 2 * v[1:-1] + v[:-2]
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _scale(cam: np.ndarray, cnt: np.ndarray, sd: np.ndarray) -> float:
    """The median ratio of the camera's rate to the counts' over the blocks where the counts'
    rate is ROLL_SCALE_Z of the noise ``sd`` (1 with fewer than ROLL_SCALE_MIN)."""
    m = np.isfinite(cam) & np.isfinite(cnt) & (np.abs(cnt) > ROLL_SCALE_Z * sd)
    return float(np.median(cam[m] / cnt[m])) if m.sum() >= ROLL_SCALE_MIN else 1.0


@dataclasses.dataclass(frozen=True)
class RollingTest:
    """The recording's camera against its counts, block by block (:func:`rolling_test`)."""
    t0: np.ndarray          # each block's start (board time)
    t1: np.ndarray          # ... and end
    z_heading: np.ndarray   # |camera minus counts heading rate| / its allowed spread (nan: no test)
    z_speed: np.ndarray     # |camera minus counts forward speed| / its allowed spread
    z_limit: float          # either above this: the body does not roll with its wheels there

    def rolling(self, i: int) -> bool | None:
        """Block ``i`` rolls (True), does not (False), or cannot be told (None: too few
        camera frames)."""
        zh, zv = self.z_heading[i], self.z_speed[i]
        if not (np.isfinite(zh) and np.isfinite(zv)):
            return None
        return bool(zh <= self.z_limit and zv <= self.z_limit)


_ROLLING: list[tuple[Any, Any, tuple[float, float, int], RollingTest | None]] = []
ROLLING_CACHE = 16


def rolling_test(prep: PreparedRun) -> RollingTest | None:
    """:func:`rolling_test_of` ``prep``, computed once per recording (it reads only the
    recording and the nominal geometry, and the window rules ask for it in every round): the
    last ROLLING_CACHE are kept, each known by its telemetry and camera tables themselves."""
    tel, gt = prep.run.telemetry, prep.run.groundtruth
    if gt is None:
        return None
    key = (float(prep.robot["r"]), float(prep.robot["b"]), int(prep.ppr))
    for t_ref, g_ref, k, res in _ROLLING:
        if t_ref is tel and g_ref is gt and k == key:
            return res
    res = rolling_test_of(prep)
    _ROLLING.append((tel, gt, key, res))
    del _ROLLING[:-ROLLING_CACHE]
    return res


def rolling_test_of(prep: PreparedRun) -> RollingTest | None:
    """Whether the recorded body rolls with its recorded wheels, in blocks of ROLL_BLOCK_S:
    the camera's heading rate and forward speed (its x, y velocity along its heading) against
    the counts' (lib/control's odometry: ``r (w_r - w_l) / 2b`` and ``r (w_r + w_l) / 2``),
    each as the slope of a straight line fitted over the block's camera frames.  While the
    wheels roll the two agree up to the camera's noise (a sample's, from the second differences
    of the camera's own series) through the fit, and the geometry: the robot's wheel radius and
    track width may be off the nominal ones (the vocabulary's ``wheel_radius`` and
    ``track_width``), so the counts' rates are scaled by the camera's median ratio to them over
    the run's blocks that move (a slip's blocks are few), and params.json's ``tol`` of ``r``
    and ``b`` times the counts' rate joins the spread.  A block where either rate differs by
    more than ``z_limit`` of that spread (a false alarm of ROLL_ALPHA per run, Bonferroni over
    its blocks) is one where the body does not follow the wheels: a slip that the recording
    shows.  The forward speed is used, not the sideways one, so that a camera marker off the
    axle's centre (a sideways ``omega d`` in a turn) is no slip.  None without a camera (or
    with too few frames)."""
    from statistics import NormalDist
    from host_tools import params as P
    gt = prep.run.groundtruth
    if gt is None or gt.get("phi_rad") is None:
        return None
    tel = prep.run.telemetry
    t = np.asarray(tel["t_s"], float)
    tg_all = np.asarray(gt["t_s"], float)
    ph_all = np.asarray(gt["phi_rad"], float)
    ok = (np.isfinite(ph_all) & np.isfinite(gt["x_m"]) & np.isfinite(gt["y_m"])
          & (tg_all >= t[0]) & (tg_all <= t[-1]))
    if ok.sum() < ROLL_MIN_FRAMES or t.size < 2:
        return None
    tg = tg_all[ok]
    phc = np.unwrap(ph_all[ok])
    xc, yc = np.asarray(gt["x_m"], float)[ok], np.asarray(gt["y_m"], float)[ok]
    r, b = float(prep.robot["r"]), float(prep.robot["b"])
    k = 2 * np.pi / prep.ppr
    th_r = np.interp(tg, t, np.asarray(tel["enc_r"], float) * k)
    th_l = np.interp(tg, t, np.asarray(tel["enc_l"], float) * k)
    pho = r * (th_r - th_l) / (2 * b)
    so = r * (th_r + th_l) / 2
    rel_r = P.TOLERANCES.get(("robot", "r"), 0.0) / r
    rel_h = math.hypot(rel_r, P.TOLERANCES.get(("robot", "b"), 0.0) / b)
    s_ph = _mad_step_sigma(phc - pho)
    s_xy = max(_mad_step_sigma(xc), _mad_step_sigma(yc))
    edges = np.arange(float(t[0]), float(t[-1]), ROLL_BLOCK_S)
    n = edges.size
    w_c, w_o, v_c, v_o, sxx = (np.full(n, np.nan) for _ in range(5))
    idx = np.searchsorted(tg, np.concatenate([edges, [edges[-1] + ROLL_BLOCK_S]]))
    for i in range(n):
        a, e = idx[i], idx[i + 1]
        if e - a < ROLL_MIN_FRAMES:
            continue
        tt = tg[a:e] - tg[a:e].mean()
        sxx[i] = float(np.sum(tt ** 2))
        if not sxx[i] > 0:
            continue

        def slope(v: np.ndarray) -> float:
            return float(np.sum(tt * (v - v.mean())) / sxx[i])
        head = float(np.mean(phc[a:e]))
        w_c[i], w_o[i] = slope(phc[a:e]), slope(pho[a:e])
        v_c[i] = slope(xc[a:e]) * math.cos(head) + slope(yc[a:e]) * math.sin(head)
        v_o[i] = slope(so[a:e])
    with np.errstate(invalid="ignore", divide="ignore"):
        noise_h, noise_v = s_ph / np.sqrt(sxx), s_xy / np.sqrt(sxx)
        k_h, k_v = _scale(w_c, w_o, noise_h), _scale(v_c, v_o, noise_v)
        sd_h = np.hypot(noise_h, rel_h * np.abs(k_h * w_o))
        sd_v = np.hypot(noise_v, rel_r * np.abs(k_v * v_o))
        zh = np.abs(w_c - k_h * w_o) / sd_h
        zv = np.abs(v_c - k_v * v_o) / sd_v
    z_limit = NormalDist().inv_cdf(1 - ROLL_ALPHA / (2 * max(n, 1)))
    return RollingTest(edges, edges + ROLL_BLOCK_S, zh, zv, z_limit)


def with_recorded_slip(prep: PreparedRun, episodes: list[tuple[float, float]]
                       ) -> list[tuple[float, float]]:
    """The nominal replay's slip ``episodes`` (onset, end), each carried on while the recording
    shows its body still not rolling with its wheels right after it (:func:`rolling_test`: from
    the first block that starts at or after the episode's end, through the blocks that fail the
    test, to the first that passes or cannot be told).

    Where the duty saturates in a reversal, both wheels slip and the body's yaw is free: whether
    it grips again at the episode's end or goes on spinning with its wheels slipping is a fork
    that the nominal replay decides one way and the recording may take the other (the MuJoCo
    tuning set's 60 s null: the replay gripped again at 47.45 s, the recording spun at up to
    8.7 rad/s on wheels turning backwards at 34 rad/s, its camera still to 0.1 m/s, until the
    wheels stopped at 54.0 s; the plant started in the spin the camera shows spins on, its wheels
    within 0.2 rad/s of the recording's, while the window started rolling ran 2.6 rad/s and
    1 m/s off).  A window started there from the rolling state is started in a state the robot
    was not in, and the replay that gripped again is no evidence of where the recording goes:
    the episode is the recording's, to where it rolls again, for every rule that follows the
    slip episodes (edges out of slips, the cut after one, the anchors' slip-free spans, and
    ``locate.episodes.unpinned_episodes``; an episode inside one carried on is left as it is,
    the rules take the longer).  A slip only the recording shows, with no episode of the nominal
    replay before it, is left as evidence (a lower friction shows there), unless it is where a
    window starts after a telemetry gap (longer than GAP_S): no command is known in the gap and
    the window before ends at it, so no replay saw that slip begin.  Where the first block that
    starts after the gap's end fails the test (the block across the gap is not read: its counts
    are a straight line there), the recording's own episode runs from the last frame before the
    gap through the blocks that fail, and the window starts as the camera shows the body
    (:func:`window_start`)."""
    rt = rolling_test(prep)
    if rt is None:
        return sorted(episodes)

    def carried(i: int, end: float) -> float:
        while i < rt.t0.size and rt.rolling(i) is False:
            end = float(rt.t1[i])
            i += 1
        return end
    out: list[tuple[float, float]] = []
    for a, b in sorted(episodes):
        out.append((a, carried(int(np.searchsorted(rt.t0, b - 1e-9)), b)))
    t = prep.run.telemetry["t_s"]
    for w, (i_a, _) in enumerate(prep.windows):
        if w == 0 or i_a == 0 or not t[i_a] - t[i_a - 1] > GAP_S:
            continue
        i = int(np.searchsorted(rt.t0, float(t[i_a])))
        if i < rt.t0.size and rt.rolling(i) is False:
            out.append((float(t[i_a - 1]), carried(i, float(t[i_a]))))
    return sorted(out)
