"""The per-channel held-out rule of the analyzer (issue 9: the held-out error is never worse
after the update): an update is adopted only if no compared channel's held-out RMSE is larger
after it than before it, with no tolerance."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer.fit import (Candidate, FitResult, heldout_channel_check, judge,
                                     no_worse)


def test_no_channel_may_get_worse_at_all():
    chk = heldout_channel_check({"a": 0.3, "b": 3.0, "c": 1.0, "d": 2.0, "e": 0.3},
                                {"a": 0.3001, "b": 2.9, "c": 1.0, "d": 0.5, "e": 0.30004},
                                {"a": 1.0, "b": 1.0, "c": 1.0, "d": 1.0, "e": 1.0})
    assert not chk["a"]["ok"]                 # a hair worse, far below its floor: refused
    assert chk["b"]["ok"] and chk["c"]["ok"] and chk["d"]["ok"]   # better or equal
    # compared as the report states them (4 significant digits): 0.30004 reads 0.3
    assert chk["e"]["ok"] and no_worse(0.30004, 0.3) and not no_worse(0.30006, 0.3)
    assert all(v["limit"] == v["before"] for v in chk.values())
    assert chk["d"]["increase_noise_floors"] == -1.5
    # channels without a floor or an after value are not judged
    assert heldout_channel_check({"x": 1.0}, {}, {"x": 1.0}) == {}
    assert heldout_channel_check({"x": 1.0}, {"x": 2.0}, {}) == {}


class _Problem:
    def __init__(self):
        from host_tools.runfmt import validate_meta
        self.meta = validate_meta({})
        self.vocab = {"motor_back_emf": {"ke_ratio": 1.0}}
        self.floors = {"omega_r": 0.1, "x_m": 0.001, "enc_r": 100.0}


def _cand(after_x_m, after_enc=10.0):
    fit = FitResult(["motor_back_emf"], {"motor_back_emf": {"ke_ratio": 1.2}}, [1.2],
                    np.array([0.5]), 10.0, 1000, [0.01], 10)
    return Candidate(["motor_back_emf"], fit, -200.0, 5.0, 1.0,
                     {"omega_r": 0.5, "x_m": 0.0004, "enc_r": 10.0},
                     {"omega_r": 0.1, "x_m": after_x_m, "enc_r": after_enc},
                     [[1.19], [1.21]], 4.0)


def test_judge_rejects_an_update_that_makes_any_channel_worse():
    p = _Problem()
    good = _cand(0.0004)           # x_m unchanged, omega_r much better
    judge(p, good)
    assert good.accepted, good.reasons
    assert good.checks["heldout_channels"] and good.heldout_per_channel["x_m"]["ok"]
    bad = _cand(0.00041)           # pooled held-out 5.0 -> 1.0, but x_m grows by 0.01 floors
    judge(p, bad)
    assert bad.checks["heldout"] and not bad.checks["heldout_channels"] and not bad.accepted
    assert not bad.heldout_per_channel["x_m"]["ok"] and bad.heldout_per_channel["omega_r"]["ok"]
    assert any("x_m" in r and "larger after the update" in r for r in bad.reasons)
    # a channel outside the fitting cost (encoder counts) is judged the same way
    enc = _cand(0.0004, after_enc=10.5)
    judge(p, enc)
    assert not enc.accepted and not enc.heldout_per_channel["enc_r"]["ok"]
