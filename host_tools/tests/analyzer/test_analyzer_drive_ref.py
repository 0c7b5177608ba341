"""The closed-loop replay's setup reads a drive reference (the latched Drive targets the logger
writes) and a recording that starts idle before the run's first tick."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer.replay.closedloop import closed_loop_setup

META = {"torque_clamp": True, "periods_s": {"inner": 0.025, "outer": 0.05, "telemetry": 0.02}}
DRIVE = {"kind": "drive", "t0_s": 1.0, "accel": 1.0, "alpha": 4.0,
         "commands": [{"t_s": 1.0, "v": 0.3, "omega": 0.0}, {"t_s": 2.0, "v": 0.0, "omega": 0.5}]}


def _frames(t_first=0.4, t_end=3.0, torque_before=0.0):
    t = np.arange(t_first, t_end, 0.02) + 0.002
    tau = np.where(t < 1.0, torque_before, np.round(np.floor((t - 1.0) / 0.025) * 1e-3, 6))
    return t, tau, tau


def test_drive_reference_is_replayable_and_idle_frames_before_t0_are_left_out():
    t, tr, tl = _frames()
    setup, problems, assumptions = closed_loop_setup({**META, "reference": DRIVE}, t, tr, tl)
    assert problems == [] and setup is not None
    assert setup["kind"] == "drive" and setup["t0_s"] == 1.0
    assert setup["drive"]["commands"][1] == {"t_s": 2.0, "v": 0.0, "omega": 0.5}
    assert any("before the run's first tick" in a for a in assumptions)


def test_frames_before_t0_that_command_torque_make_t0_wrong():
    t, tr, tl = _frames(torque_before=0.01)
    setup, problems, _ = closed_loop_setup({**META, "reference": DRIVE}, t, tr, tl)
    assert setup is None and "command torque" in problems[0]


def test_malformed_drive_commands_are_a_problem():
    t, tr, tl = _frames()
    bad = dict(DRIVE, commands=[{"t_s": 1.0, "v": "fast", "omega": 0.0}])
    setup, problems, _ = closed_loop_setup({**META, "reference": bad}, t, tr, tl)
    assert setup is None and "reference.commands" in problems[0]
    setup, problems, _ = closed_loop_setup({**META, "reference": dict(DRIVE, alpha=None)}, t, tr, tl)
    assert setup is None and "reference.alpha" in problems[0]
