"""The prepared run (a run with its inputs reconstructed) and its replay windows."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from host_tools.runfmt import Run


@dataclass
class PreparedRun:
    """A run with its inputs reconstructed for replay."""

    run: Run
    t_in: np.ndarray          # time at which each duty sample takes effect
    t_in_tau: np.ndarray      # time at which each torque-command sample takes effect
    duty: tuple[np.ndarray, np.ndarray]
    torque: tuple[np.ndarray, np.ndarray]
    t_grid: np.ndarray        # times at which the simulation is sampled
    robot: dict[str, Any]
    motor: dict[str, Any]
    start_pose: tuple[float, float, float]
    ppr: int
    # replay windows: frame index ranges [i_a, i_b) covering the run (see make_windows)
    windows: list[tuple[int, int]] = field(default_factory=list)
    # input timing (prepare): the inner loop's period and its tick phase (None: not pinned
    # down); the firmware's odometry is computed at its ticks (see replay.channels)
    inner_period: float = 0.0
    tick_phase: float | None = None
    # per input tick: reported by a frame (None: every input is)
    seen_ticks: np.ndarray | None = None
    # a single wheel-speed loop's count-level gain per side, fitted over the case's runs
    # (replay.unseen.count_gains; None: the run's own)
    count_gains: tuple[float | None, float | None] | None = None
    # ramped duty: the ticks that set it (the motor current's transients)
    t_steps: np.ndarray | None = None
    # camera channels against the count-anchored pose (replay.anchors._count_anchor_shift)
    count_anchored_pose: bool = False
    # prepare_timed: how the tick phase was found, how far the ticks may be off, and how the
    # recorder's odometry relates to its counts (prepare.odometry.recorder_odometry)
    timing: str | None = None
    phase_uncertainty_s: float = 0.0
    recorder_odometry: dict[str, Any] | None = None
    odo_schedule: str | None = None        # "ticks" or "frames"
    # the motor-current sense's noise (A, right and left; locate.mismatch): a current channel
    # replays the sense's mean reading, its noise clipped at nil (signals.clipped_reading_mean);
    # None: |I| itself
    sense_noise_a: tuple[float, float] | None = None
    # replay: the nominal replay's slip episodes (board times; replay.anchors) and the replay's
    # uncertainty from unreported commands (channel -> (t, std); replay.unseen)
    slip_episodes: list[tuple[float, float]] = field(default_factory=list)
    replay_unc: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    tolerance_bias: dict[str, float] | None = None  # channel -> whole-run bias the model's tolerance allows
    tolerance_draw_means: dict[str, list[float]] | None = None  # channel -> each tolerance draw's mean residual
    # the camera anchors of the windows as they are (replay.anchors.with_anchors): (board time,
    # half span, slip episodes) -> pose, or None without camera samples there
    anchors: Mapping[tuple[float, float, tuple[tuple[float, ...], ...]],
                     dict[str, float] | None] = field(default_factory=dict)

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
