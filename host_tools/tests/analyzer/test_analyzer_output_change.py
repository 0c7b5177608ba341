"""The output change an update makes (``Problem.output_change``): per fit channel, the RMS of
the change of its normalized residual; the largest over the channels.  An effect that moves
two channels of eight by one noise floor moves the outputs by one floor, whatever the other
six channels a recorder logs; a pooled RMS would give 0.5."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.replay.channels import Channel

CHANNELS = ["omega_r", "omega_l", "current_r_a", "current_l_a", "x_m", "y_m", "phi_rad",
            "enc_r"]
FLOOR = 0.1
T = np.linspace(0.0, 1.0, 50)


def _problem(moved: dict[str, float], unc: float | None = None) -> Problem:
    """A fit problem over one run whose replay with any effect moves the channels in
    ``moved`` by that many floors and leaves the others as they were."""
    p = object.__new__(Problem)
    p.fit_channels = list(CHANNELS)
    p.floors = {c: FLOOR for c in CHANNELS}

    def sim_channels(effects, runs, full=False, fit_only=False):
        shift = moved if effects else {}
        u = None if unc is None else np.full(T.size, unc)
        return [{c: Channel(c, T, np.zeros(T.size), -shift.get(c, 0.0) * FLOOR * np.ones(T.size),
                            "", unc=u) for c in CHANNELS} for _ in runs]
    p.sim_channels = sim_channels  # type: ignore[method-assign]
    return p


def test_the_largest_channel_counts_not_the_pool():
    p = _problem({"omega_r": 1.0, "current_r_a": -1.0})
    change = p.output_change({}, {"motor_gain_asymmetry": {"ratio": 1.1}}, [0])
    assert abs(change - 1.0) < 1e-9
    pooled = np.sqrt(2 / len(CHANNELS))      # what an RMS over all channels would give: 0.5
    assert change > pooled + 0.4


def test_no_change_is_zero_and_the_replay_uncertainty_deflates_it():
    assert _problem({}).output_change({}, {"x": {"a": 1.0}}, [0]) == 0.0
    # a replay uncertainty equal to the floor: the change counts sqrt(2) less
    p = _problem({"omega_r": 1.0}, unc=FLOOR)
    assert abs(p.output_change({}, {"x": {"a": 1.0}}, [0]) - 1 / np.sqrt(2)) < 1e-9
