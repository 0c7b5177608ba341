"""Where a replay window starts: slip episodes, the camera-corrected pose at a window's start,
and the pose shift that only follows from the replayed wheels turning otherwise than the
recorded counts."""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, Mapping, cast

import numpy as np

from host_tools.analyzer.effects import folded_robot
from host_tools.analyzer.prepare.odometry import encoder_odometry, wrap_angle, odometry_times
from host_tools.analyzer.prepare.run import BURN_IN_S, GAP_S, PreparedRun

if TYPE_CHECKING:
    from host_tools.analyzer.replay.openloop import OpenLoopReplay, WindowSims


def slip_episodes_of(sims: "WindowSims") -> list[tuple[float, float]]:
    """The slip episodes (onset, end) of a nominal replay ``sims`` (board times, sorted), a
    prepared run's ``slip_episodes``: across a slip the recorder's odometry stops following
    the body, so a window's camera anchor is fitted within the slip-free span around it."""
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
    return sorted(episodes)


def _with_slip_episodes(prep: PreparedRun, replay: "OpenLoopReplay") -> PreparedRun:
    """``prep`` with the slip episodes of its nominal replay in its windows."""
    return dataclasses.replace(prep, slip_episodes=slip_episodes_of(
        replay.simulate_windows(prep, {})))


def _with_windows(prep: PreparedRun, wins: list[list[int]]) -> PreparedRun:
    """``prep`` with other windows (and an empty camera-anchor cache)."""
    return dataclasses.replace(prep, windows=[(int(x[0]), int(x[1])) for x in wins],
                               anchor_cache={})


MAX_EDGE_MOVES = 6


def edges_outside_slip(prep: PreparedRun, replay: "OpenLoopReplay") -> tuple[PreparedRun, int]:
    """Move the edges between replay windows out of the nominal replay's slip episodes, with
    the episodes (``slip_episodes_of``) of the windows as they end up.

    A window after the first starts from the recorded state: the wheel speeds from the counts
    with the body rolling with them, and the pose from the recorder's odometry corrected onto
    the camera.  Across a slip neither holds — the body does not roll with the wheels and the
    odometry stops following it (the camera-minus-odometry heading moved by 4 rad within 1.5 s
    of a braking reversal on the truth simulator's 60 s null) — so a window whose early start
    or first frame falls in a slip begins in a state the robot was never in, and its replay
    stays off the recording for the whole window (100–570 camera floors there, while the
    window before, integrating through the slip, stayed within 3).  An edge inside or just
    after an episode is moved to ``BURN_IN_S`` after the episode's end: the window before
    integrates through the slip as the model says, and the next one starts rolling and is
    re-anchored to the camera where the odometry follows the body again.  An episode that
    still runs at the end of the window's replay is seen to its end in the next round (at most
    ``MAX_EDGE_MOVES``).  An edge that would pass the next one removes it (the two windows
    become one).  Returns (the prepared run with those windows and episodes, a new value:
    ``prep`` is left as it is; the number of edges moved)."""
    t = prep.run.telemetry["t_s"]
    moved_total = 0
    for _ in range(MAX_EDGE_MOVES):
        prep = _with_slip_episodes(prep, replay)
        wins = [list(w) for w in prep.windows]
        moved = 0
        w = 1
        while w < len(wins):
            i_a = wins[w][0]
            # only an edge inside one stretch of telemetry (a gap always ends a window)
            if wins[w - 1][1] != i_a or t[i_a] - t[i_a - 1] > GAP_S:
                w += 1
                continue
            lo = t[i_a] - BURN_IN_S
            late = [b for a, b in prep.slip_episodes if a < t[i_a] and b > lo]
            if not late:
                w += 1
                continue
            target = max(late) + BURN_IN_S
            j = int(np.searchsorted(t, target))
            if j >= wins[w][1] - 1:
                # past the next edge: the two windows become one
                wins[w - 1][1] = wins[w][1]
                del wins[w]
            else:
                wins[w - 1][1] = j
                wins[w][0] = j
                w += 1
            moved += 1
        if not moved:
            break
        prep = _with_windows(prep, wins)
        moved_total += moved
    prep, _ = _edges_after_slip(prep)
    prep, _ = _join_edges_in_slip(prep, replay)
    return prep, moved_total


def _join_edges_in_slip(prep: PreparedRun, replay: "OpenLoopReplay") -> tuple[PreparedRun, int]:
    """Remove the edges that are still in a slip episode of the windows as they end up (the
    rule of :func:`edges_outside_slip`), joining the two windows, until none is.  A window
    started from the recorded state where the recording slips and the nominal replay had not
    (an edge moved there or cut there) slips at its own start, and moving the edge again can
    land in the next such slip: on heldback6's MuJoCo 60 s run with a 40 ms actuation delay
    an edge ended the rounds 0.5 s into a slip and its window stayed 6 cm (59 camera floors)
    off the recording to its end.  The joined window integrates through the slip, where its
    pose is no evidence (``locate.episodes.unpinned_episodes``).  Returns (the prepared run,
    whose ``slip_episodes`` are those of the final windows; the number of edges removed)."""
    t = prep.run.telemetry["t_s"]
    removed = 0
    while True:
        prep = _with_slip_episodes(prep, replay)
        wins = [list(w) for w in prep.windows]
        keep = [wins[0]]
        for w in wins[1:]:
            i_a = w[0]
            lo = t[i_a] - BURN_IN_S
            joined = (keep[-1][1] == i_a and t[i_a] - t[i_a - 1] <= GAP_S
                      and any(a < t[i_a] and b > lo for a, b in prep.slip_episodes))
            if joined:
                keep[-1][1] = w[1]
            else:
                keep.append(w)
        if len(keep) == len(wins):
            return prep, removed
        removed += len(wins) - len(keep)
        prep = _with_windows(prep, keep)


MIN_REANCHOR_S = 1.0


def _edges_after_slip(prep: PreparedRun) -> tuple[PreparedRun, list[int]]:
    """Cut a window ``BURN_IN_S`` after a slip episode ends, so that the pose is re-anchored
    to the camera there: the slip distance is the contact's, which no plant reproduces in
    detail, and the pose after a slip carries its error to the end of the window (the pose
    channels are no evidence from a slip's onset to the window's end,
    ``locate.episodes.unpinned_episodes``).  A cut needs ``MIN_REANCHOR_S`` without slip after
    it and that much of the window on either side; it is not made across a telemetry gap.  Returns
    (the prepared run with those windows, the frames of the edges added)."""
    t = prep.run.telemetry["t_s"]
    eps = prep.slip_episodes
    wins = [list(w) for w in prep.windows]
    added: list[int] = []
    for b in sorted({b for _, b in eps}):
        target = b + BURN_IN_S
        if any(a2 <= target + MIN_REANCHOR_S and b2 > b for a2, b2 in eps):
            continue
        j = int(np.searchsorted(t, target))
        for w, (i_a, i_b) in enumerate(wins):
            if not (i_a < j < i_b - 1):
                continue
            if (t[j] - t[i_a] >= MIN_REANCHOR_S and t[i_b - 1] - t[j] >= MIN_REANCHOR_S
                    and not np.any(np.diff(t[max(i_a, j - 1):j + 1]) > GAP_S)
                    and not np.any((t[i_a:j] >= b) & (np.diff(t[i_a:j + 1]) > GAP_S))):
                wins[w:w + 1] = [[i_a, j], [j, i_b]]
                added.append(j)
            break
    return (_with_windows(prep, wins) if added else prep), added


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
    """:func:`_gt_anchor_of` memoized per run: it reads only the recording and the run's slip
    episodes, and a fit evaluates it for every window at every step (28 % of a 2 x 60 s
    analysis's time before).  The returned dict is shared: read it, do not change it."""
    key = (float(at), float(half), tuple(tuple(e) for e in prep.slip_episodes))
    if key not in prep.anchor_cache:
        prep.anchor_cache[key] = _gt_anchor_of(prep, at, half)
    return prep.anchor_cache[key]


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
    if spread >= MIN_SPREAD_M or ok.sum() < 3 or ph is None:  # (ph None: ok is all False)
        qx, qy = gx - gx.mean(), gy - gy.mean()
        delta_at = float(np.arctan2(np.sum(ox * qy - oy * qx), np.sum(ox * qx + oy * qy)))
        delta = np.full(tm.size, delta_at)
    else:
        d = ph[m][ok] - odo["phi_rad"][ok]
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
           "y_m": sa * here["x_m"] + ca * here["y_m"] + _line_at(tm, cy, at)}
    out["phi_rad"] = here["phi_rad"] + delta_at
    return out


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
    geo = folded_robot(prep.robot, effects or {})
    r, b = float(geo["r"]), float(geo["b"])
    vel = (r * (w_r + w_l) / 2, 0.0, r * (w_r - w_l) / (2 * b), w_r, w_l)
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
