"""The replay windows of a long run out of its nominal replay's slip episodes: an edge moved out
of a slip (:func:`edges_outside_slip`), a cut after one, and two windows joined where an edge
still falls in one."""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from host_tools.analyzer.prepare.run import BURN_IN_S, GAP_S, PreparedRun
from host_tools.analyzer.replay.anchors import with_anchors, with_recorded_slip

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
    """``prep`` with the slip episodes of its nominal replay in its windows, each carried on
    while the recording goes on slipping after it (``anchors.with_recorded_slip``), and the
    camera anchors for them."""
    return with_anchors(dataclasses.replace(prep, slip_episodes=with_recorded_slip(
        prep, slip_episodes_of(replay.simulate_windows(prep, {})))))


def _with_windows(prep: PreparedRun, wins: list[list[int]]) -> PreparedRun:
    """``prep`` with other windows (and the camera anchors for them)."""
    return with_anchors(dataclasses.replace(
        prep, windows=[(int(x[0]), int(x[1])) for x in wins]))


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
