"""A cascade whose outer period spans two inner ticks, seen by frames slower than two ticks (a
40 ms loop seen every 85 ms): the reported tick slides by 5 ms a frame, so the unreported ticks
change their place in the outer loop's staircase every few frames (an even tick between odd
reported ones, then an odd one between even ones, then two in one gap), and each place lies
off the line through the reported ticks by its own amount and sign.  The closed-loop replay's
pattern is averaged over the unreported ticks of the same place only
(replay.unseen.fill_unseen_from_controller, docs/analyzer.md "Ticks no frame reported"):
pooled over all places it cancels itself and the fill keeps most of the line's error (the
MuJoCo `hb20_mj_null_slow`, run 2: 4 wheel-speed floors during acceleration)."""
from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools.analyzer.replay import unseen as UN  # noqa: E402
from _unseen_replay import line_seen_slowly  # noqa: E402

LINE = {"kind": "line", "accel": 0.6, "cruise": 0.5}   # the ramp ends at 0.83 s
INNER_S = 0.04
TEL_S = 0.085


@pytest.fixture(scope="module")
def slow_frames(tmp_path_factory):
    """(prepared run, the commands the controller gave at its ticks, the closed-loop replay)."""
    out = line_seen_slowly(tmp_path_factory.mktemp("place"), LINE, 22, INNER_S, TEL_S)
    assert UN.outer_ticks(out[0]) == 2
    return out


def test_the_pattern_is_averaged_within_one_place_of_the_staircase(slow_frames, monkeypatch):
    prep, given, cl = slow_frames
    seen = np.asarray(prep.seen_ticks, bool)
    ramp = ~seen & (prep.t_in < 0.85)   # the unreported ticks while the wheels accelerate

    def err(p) -> float:
        return float(np.sqrt(np.mean([np.square(p.duty[s] - given[s])[ramp] for s in (0, 1)])))
    line = err(prep)
    refined, n = UN.fill_unseen_from_controller(prep, cl)
    assert n > 0 and np.array_equal(refined.duty[0][seen], given[0][seen])
    # measured: the line 0.0104 of duty off, the pattern averaged within a place 0.0027
    assert err(refined) < 0.35 * line, (line, err(refined))
    # pooled over the places (a single-tick outer loop's averaging): 0.0074, most of the line's
    monkeypatch.setattr(UN, "outer_ticks", lambda p: 1)
    pooled, _ = UN.fill_unseen_from_controller(prep, cl)
    assert err(pooled) > 0.5 * line
    assert err(refined) < 0.5 * err(pooled)


def test_outer_ticks_from_the_recorders_periods(slow_frames):
    prep = slow_frames[0]
    assert UN.outer_ticks(prep) == 2
    run = copy.deepcopy(prep.run)
    run.meta["controller"] = "pi"
    assert UN.outer_ticks(dataclasses.replace(prep, run=run)) == 1   # no outer loop
    run = copy.deepcopy(prep.run)
    run.meta["periods_s"] = {"inner": INNER_S}
    assert UN.outer_ticks(dataclasses.replace(prep, run=run)) == 1   # none given
