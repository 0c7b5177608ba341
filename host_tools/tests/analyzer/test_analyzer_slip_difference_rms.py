"""The normalized-RMS rule counts a wheel pair's difference in a pinned slip deflated by the
difference's own replay uncertainty (``locate.mismatch.slip_difference_rss``), as it counts
every other sample: a slip the tolerance ensemble spreads by many floors is not that many floors
of mismatch, while a difference where the wheels were pinned keeps its full weight."""
from __future__ import annotations

import math

import numpy as np

from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.locate.episodes import SLIP_UNC
from host_tools.analyzer.locate.mismatch import slip_difference_rss
from host_tools.analyzer.replay.channels import Channel


class _OneRun:
    """The part of ``Problem`` the rule reads: one run's nominal channels, its floors."""
    named_slip_differences = Problem.named_slip_differences

    def __init__(self, chans: dict[str, Channel]) -> None:
        self.preps = [None]
        self.floors = {"omega_r": 0.05, "omega_l": 0.05}
        self.fit_channels = ["omega_r", "omega_l"]
        self._chans = chans

    def sim_channels(self, effects: object, runs: object, full: bool = False,
                     fit_only: bool = False) -> list[dict[str, Channel]]:
        return [self._chans]


def _pair(resid_r: np.ndarray, resid_l: np.ndarray, t: np.ndarray) -> dict[str, Channel]:
    unc = np.full(t.size, SLIP_UNC)      # both wheels in a pinned slip at every sample
    return {c: Channel(c, t, r, np.zeros(t.size), "rad/s", unc=unc)
            for c, r in (("omega_r", resid_r), ("omega_l", resid_l))}


def test_slip_difference_deflated_by_the_wheels_uncertainty_before_the_slip() -> None:
    t = np.arange(4) * 0.075
    f = 0.05
    # the difference (r - l)/sqrt(2) is 20 floors at every sample
    r = np.full(t.size, 20 * math.sqrt(2) * f)
    problem = _OneRun(_pair(r, np.zeros(t.size), t))
    # before the slip, the ensemble spread each wheel by 20 floors: the difference's uncertainty
    # is sqrt(20^2 + 20^2)/sqrt(2) = 20 floors
    spread = {"omega_r": (t, np.full(t.size, 20 * f)), "omega_l": (t, np.full(t.size, 20 * f))}
    raw, defl = slip_difference_rss(problem, [spread])    # type: ignore[arg-type]
    assert math.isclose(raw, t.size * 400.0, rel_tol=1e-9)
    assert math.isclose(defl, t.size * 400.0 / (1 + 400.0), rel_tol=1e-9)
    # pinned wheels (no spread before the slip): the difference keeps its full weight
    zero = {c: (t, np.zeros(t.size)) for c in spread}
    raw0, defl0 = slip_difference_rss(problem, [zero])    # type: ignore[arg-type]
    assert math.isclose(defl0, raw0, rel_tol=1e-12) and raw0 > 0
