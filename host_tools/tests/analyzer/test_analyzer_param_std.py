"""A fitted coordinate's 1-sigma uncertainty (fit/solver.py ``param_std``) where the data do not
see it: no estimate (inf), not the pseudo-inverse's zero."""
from __future__ import annotations

import math

import numpy as np

from host_tools.analyzer.fit.params import Param
from host_tools.analyzer.fit.solver import param_std


def _params() -> list[Param]:
    return [Param("wheel_radius", "r_eff", 0.03, 0.02, 0.05, 1e-4),
            Param("actuation_delay", "delay_s", 0.0, 0.0, 0.2, 0.0)]


def test_a_coordinate_the_residual_does_not_move_has_no_estimate():
    """A partner whose replay does not change at all over its finite-difference step (a delay
    of 1e-7 s under a coarser replay step) has a zero column in J: the pseudo-inverse gave it
    sigma 0, and a pair then counted it as significant at any distance from its neutral value."""
    rng = np.random.default_rng(3)
    r = rng.normal(0.0, 1.0, 400)
    J = np.column_stack([rng.normal(0.0, 5.0, 400), np.zeros(400)])
    std = param_std(J, r, _params(), [0, 1])
    assert math.isfinite(std[0]) and std[0] > 0
    assert std[1] == math.inf


def test_a_seen_coordinate_keeps_its_sigma():
    rng = np.random.default_rng(4)
    r = rng.normal(0.0, 1.0, 400)
    J = np.column_stack([rng.normal(0.0, 5.0, 400), rng.normal(0.0, 2.0, 400)])
    std = param_std(J, r, _params(), [0, 1])
    assert all(math.isfinite(s) and s > 0 for s in std)
    # the same figures as the covariance's diagonal
    from host_tools.analyzer.fit.solver import effective_n
    s2 = float(np.sum(r ** 2)) / (r.size - 2)
    cov = np.linalg.inv(J.T @ J) * s2 * (r.size / max(effective_n(r), 1.0))
    for i, p in enumerate(_params()):
        assert abs(std[i] - math.sqrt(cov[i, i]) * (p.hi - p.lo)) < 1e-9 * std[i]


def test_no_free_coordinate():
    """A held-out fold's refit with every coordinate pinned (an unidentified one held): no
    column, nothing to estimate."""
    r = np.random.default_rng(5).normal(0.0, 1.0, 50)
    std = param_std(np.zeros((50, 0)), r, _params(), [])
    assert all(math.isnan(s) for s in std)
