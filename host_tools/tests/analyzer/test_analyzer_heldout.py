"""The per-channel held-out rule of the analyzer: an update is not adopted if a channel that
measures physics gets worse on the held-out data beyond its noise (more than HELDOUT_TOL noise
floors, and significant in a paired test over the held-out samples).  Derived channels (the
recorder's odometry) are reported and veto nothing.  Fits must be physically possible."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer import effects as fx
from host_tools.analyzer.fit.judge import (HELDOUT_TOL, Candidate, heldout_channel_check, judge,
                                           paired_worse)
from host_tools.analyzer.fit.params import FitResult, effects_dict, params_for
from host_tools.params import ROBOT


def test_paired_test_needs_size_and_significance():
    rng = np.random.default_rng(1)
    b = rng.normal(0, 1.0, 2000)
    # the same residual plus a systematic error of 0.5 floors: worse
    worse, incr, z = paired_worse(b, b + 0.5, 1.0)
    assert worse and incr > HELDOUT_TOL and z > 10
    # an increase of 1e-4 floors, however consistent: no evidence
    worse, incr, z = paired_worse(b, b * 1.0001, 1.0)
    assert not worse and 0 < incr < HELDOUT_TOL
    # better: never worse
    assert not paired_worse(b + 0.5, b, 1.0)[0]
    # a large but noisy change of two samples' worth: not significant
    a = b[:200].copy()
    a[:3] += 6.0
    worse, incr, z = paired_worse(b[:200], a, 1.0)
    assert incr > HELDOUT_TOL and not worse


def test_channel_check_marks_derived_channels_without_veto():
    rng = np.random.default_rng(2)
    b = rng.normal(0, 1e-3, 500)
    pairs = {"x_odo_m": (b, b + 2e-3), "x_m": (b, b + 2e-3), "omega_r": (b * 100, b * 50)}
    chk = heldout_channel_check({c: float(np.sqrt(np.mean(v[0] ** 2))) for c, v in pairs.items()},
                                {c: float(np.sqrt(np.mean(v[1] ** 2))) for c, v in pairs.items()},
                                {"x_odo_m": 1e-3, "x_m": 1e-3, "omega_r": 0.1}, pairs)
    assert chk["x_odo_m"]["derived"] and chk["x_odo_m"]["worse"] and chk["x_odo_m"]["ok"]
    assert not chk["x_m"]["derived"] and chk["x_m"]["worse"] and not chk["x_m"]["ok"]
    assert chk["omega_r"]["ok"] and not chk["omega_r"]["worse"]
    # channels without a floor or an after value are not judged
    assert heldout_channel_check({"x": 1.0}, {}, {"x": 1.0}) == {}
    assert heldout_channel_check({"x": 1.0}, {"x": 2.0}, {}) == {}


class _Problem:
    def __init__(self):
        from host_tools.runfmt import validate_meta
        self.meta = validate_meta({})
        self.vocab = {"motor_back_emf": {"ke_ratio": 1.0},
                      "friction_coefficient": {"mu_s": ROBOT["mu_s"], "mu_k": ROBOT["mu_k"]}}
        self.floors = {"omega_r": 0.1, "x_m": 0.001, "enc_r": 100.0, "y_odo_m": 1e-4}


def _cand(after_x_m, after_enc=10.0, after_odo=1e-5):
    fit = FitResult(["motor_back_emf"], {"motor_back_emf": {"ke_ratio": 1.2}}, [1.2],
                    np.array([0.5]), 10.0, 1000, [0.01], 10)
    return Candidate(["motor_back_emf"], fit, -200.0, 5.0, 1.0,
                     {"omega_r": 0.5, "x_m": 0.0004, "enc_r": 10.0, "y_odo_m": 1e-5},
                     {"omega_r": 0.1, "x_m": after_x_m, "enc_r": after_enc, "y_odo_m": after_odo},
                     [[1.19], [1.21]], 4.0)


def test_judge_rejects_an_update_that_makes_a_physics_channel_worse_beyond_noise():
    p = _Problem()
    good = _cand(0.00041)          # x_m grows by 0.01 floors: no evidence, adopted
    judge(p, good)
    assert good.accepted, good.reasons
    bad = _cand(0.0006)            # x_m grows by 0.2 floors
    judge(p, bad)
    assert bad.checks["heldout"] and not bad.checks["heldout_channels"] and not bad.accepted
    assert any("x_m" in r and "larger after the update" in r for r in bad.reasons)
    enc = _cand(0.0004, after_enc=25.0)   # counts are physics too
    judge(p, enc)
    assert not enc.accepted and not enc.heldout_per_channel["enc_r"]["ok"]
    odo = _cand(0.0004, after_odo=1e-3)   # the recorder's odometry 9 floors worse: no veto
    judge(p, odo)
    assert odo.accepted, odo.reasons
    assert odo.heldout_per_channel["y_odo_m"]["worse"] and odo.recorder_notes


def test_friction_is_fitted_with_mu_k_at_most_mu_s():
    p = _Problem()
    params = params_for(["friction_coefficient"], p.meta, p.vocab)
    assert [q.name for q in params] == ["mu_s", "mu_k_over_mu_s"]
    for xs in np.linspace(0, 1, 6):
        for xk in np.linspace(0, 1, 6):
            d = effects_dict(params, [q.from_x(x) for q, x in zip(params, (xs, xk))])
            fc = d["friction_coefficient"]
            assert set(fc) == {"mu_s", "mu_k"} and fc["mu_k"] <= fc["mu_s"] + 1e-15
    # the neutral point is the nominal pair
    d = effects_dict(params, [q.neutral for q in params])["friction_coefficient"]
    assert abs(d["mu_s"] - ROBOT["mu_s"]) < 1e-12 and abs(d["mu_k"] - ROBOT["mu_k"]) < 1e-12
    assert fx.physically_possible("friction_coefficient", {"mu_s": 0.2, "mu_k": 0.22})
    assert not fx.physically_possible("friction_coefficient", {"mu_s": 0.25, "mu_k": 0.22})


def test_judge_rejects_a_physically_impossible_fit():
    p = _Problem()
    c = _cand(0.0004)
    c.fit.params = {"motor_back_emf": {"ke_ratio": -0.2}}
    judge(p, c)
    assert not c.checks["physical"] and not c.accepted
