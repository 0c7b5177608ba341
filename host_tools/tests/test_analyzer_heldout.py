"""The per-channel held-out rule of the analyzer (issue 9: the held-out error is never worse
after the update): no channel's held-out RMSE may exceed sqrt(before^2 + (kappa*floor)^2)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from host_tools.analyzer.fit import (HELDOUT_KAPPA, Candidate, FitResult, heldout_channel_check,
                                     judge)


def test_limit_is_an_added_error_of_kappa_floors_in_quadrature():
    assert HELDOUT_KAPPA == 0.5
    chk = heldout_channel_check({"a": 0.3, "b": 3.0, "c": 1.0}, {"a": 0.58, "b": 3.05, "c": 1.2},
                                {"a": 1.0, "b": 1.0, "c": 1.0})
    assert chk["a"]["limit"] == pytest.approx(math.sqrt(0.09 + 0.25))
    assert chk["a"]["ok"] and not chk["b"]["ok"]          # 3.05 > sqrt(9.25) = 3.041
    assert not chk["c"]["ok"]                             # 1.2 > sqrt(1.25) = 1.118
    # a channel at its floor stays below the mismatch threshold of 1.25 floors
    assert chk["c"]["limit"] < 1.25
    # channels without a floor or an after value are not judged
    assert heldout_channel_check({"x": 1.0}, {}, {"x": 1.0}) == {}
    assert heldout_channel_check({"x": 1.0}, {"x": 2.0}, {}) == {}


class _Problem:
    def __init__(self):
        from host_tools.runfmt import validate_meta
        self.meta = validate_meta({})
        self.vocab = {"motor_back_emf": {"ke_ratio": 1.0}}
        self.floors = {"omega_r": 0.1, "x_m": 0.001}


def _cand(after_x_m):
    fit = FitResult(["motor_back_emf"], {"motor_back_emf": {"ke_ratio": 1.2}}, [1.2],
                    np.array([0.5]), 10.0, 1000, [0.01], 10)
    return Candidate(["motor_back_emf"], fit, -200.0, 5.0, 1.0,
                     {"omega_r": 0.5, "x_m": 0.0004}, {"omega_r": 0.1, "x_m": after_x_m},
                     [[1.19], [1.21]], 4.0)


def test_judge_rejects_an_update_that_makes_one_channel_worse_beyond_the_limit():
    p = _Problem()
    good = _cand(0.0006)   # limit sqrt(0.4^2 + 0.5^2) mm = 0.64 mm
    judge(p, good)
    assert good.accepted, good.reasons
    assert good.heldout_per_channel["x_m"]["ok"]
    bad = _cand(0.0007)    # pooled held-out still improves 5.0 -> 1.0, but x_m exceeds its limit
    judge(p, bad)
    assert not bad.checks["heldout"] and not bad.accepted
    assert not bad.heldout_per_channel["x_m"]["ok"] and bad.heldout_per_channel["omega_r"]["ok"]
    assert any("x_m" in r and "limit" in r for r in bad.reasons)
