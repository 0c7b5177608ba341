"""The spread of the straight-line fill of unreported ticks (replay.unseen.fill_spread, what
input_uncertainty draws; docs/analyzer.md "The replay's uncertainty from unreported
commands"): half a step at a single unreported tick, nothing on a straight stretch."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from host_tools.analyzer.replay import unseen as UN


def _prep(u: np.ndarray, seen: np.ndarray) -> SimpleNamespace:
    t = 0.025 * np.arange(u.size)
    return SimpleNamespace(seen_ticks=seen, t_in=t, duty=(u, u.copy()))


def test_a_step_at_an_unreported_tick_gives_half_the_step():
    n = 30
    seen = np.ones(n, bool)
    seen[2::3] = False          # every third tick unreported (38 ms frames, 25 ms loop)
    u = np.where(np.arange(n) >= 14, 0.5, 0.3)   # a step at tick 14, unreported
    unseen, gap, white, bend = UN.fill_spread(_prep(u, seen))
    assert np.array_equal(unseen, np.flatnonzero(~seen))
    assert np.array_equal(gap, np.arange(unseen.size))   # single ticks: one gap each
    i = int(np.flatnonzero(unseen == 14)[0])
    # the trend before (flat at 0.3) carried forward departs from the line 0.3 -> 0.5 by 0.1
    assert math.isclose(bend[0][i], 0.1 / math.sqrt(3.0), rel_tol=1e-9)
    far = np.abs(unseen - 14) > 3
    assert np.all(bend[0][far] == 0.0) and white[0] == 0.0


def test_nothing_unreported_gives_none():
    u = np.linspace(0.0, 1.0, 12)
    assert UN.fill_spread(_prep(u, np.ones(12, bool))) is None
    assert UN.fill_spread(SimpleNamespace(seen_ticks=None, t_in=np.zeros(12), duty=(u, u))) is None
