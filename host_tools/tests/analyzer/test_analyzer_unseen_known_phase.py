"""A cascade with a 60 ms inner loop seen every 135 ms whose ticks are placed from the
experiment's start (the truth simulator's recorders: board time 0, where the closed-loop replay
starts its controller too): the replay's tick k is the recording's tick k, so the one-tick shift
that makes up for an estimated tick phase is not tried (replay.unseen.fill_unseen_from_controller,
docs/analyzer.md "Ticks no frame reported").  On the clamped 1 m/s^2 line the bends of the
reported commands at the clamp's release are larger than the nominal replay's, and the bends'
least squares take the replay a tick late: its outer-loop staircase then falls on the other
ticks and the fill goes the wrong way on every unreported tick of the ramp (the MuJoCo
`hb30_mj_null_slip`, run 3: the fill 0.0256 of duty off against the line's 0.0177, the duty
replay's wheel speeds 0.36 rad/s off, 5.7 floors)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools.analyzer.prepare import timing as PT  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402
from _unseen_replay import line_seen_slowly  # noqa: E402

LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}
INNER_S = 0.06
TEL_S = 0.135


@pytest.fixture(scope="module")
def clamped_line(tmp_path_factory):
    """(prepared run, the commands the controller gave at its ticks, the closed-loop replay)."""
    return line_seen_slowly(tmp_path_factory.mktemp("known_phase"), LINE, 1, INNER_S, TEL_S)


def test_no_tick_shift_when_the_ticks_run_from_the_experiments_start(clamped_line):
    prep, given, cl = clamped_line
    assert prep.timing == PT.TIMING_FROM_START
    seen = np.asarray(prep.seen_ticks, bool)
    k = np.round((prep.t_in - cl["t_s"][0]) / (cl["t_s"][1] - cl["t_s"][0])).astype(np.int64)
    # the case at issue: the bends alone would take the replay a tick late
    assert UN._replay_tick_shift(prep, cl, k, seen) == 1

    def err(p) -> float:
        return float(np.sqrt(np.mean([np.square(p.duty[s] - given[s])[~seen] for s in (0, 1)])))
    line = err(prep)
    refined, n = UN.fill_unseen_from_controller(prep, cl)
    assert n == int((~seen).sum())
    # measured: the line 0.0178 of duty off, the fill on the replay's own ticks 0.0127 (on the
    # ticks one later, 0.0257)
    assert err(refined) < 0.8 * line, (line, err(refined))


def test_an_estimated_phase_still_tries_the_shift(clamped_line, monkeypatch):
    """The same run with its tick phase estimated (not from the experiment's start): the
    shift is tried and, here, taken; the fill then follows the replay a tick late."""
    prep, given, cl = clamped_line
    est = dataclasses.replace(prep, timing="board wheel speeds against recorded counts")
    calls = []
    shift = UN._replay_tick_shift
    monkeypatch.setattr(UN, "_replay_tick_shift", lambda *a: calls.append(1) or shift(*a))
    a, _ = UN.fill_unseen_from_controller(prep, cl)
    assert not calls
    b, _ = UN.fill_unseen_from_controller(est, cl)
    assert calls
    assert not np.allclose(a.duty[0], b.duty[0])
