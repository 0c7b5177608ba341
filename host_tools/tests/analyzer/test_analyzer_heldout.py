"""The per-channel held-out rule of the analyzer: an update is not adopted if a channel that
measures physics gets worse on the held-out data beyond its noise and the nominal model's
tolerance (more than HELDOUT_TOL of sqrt(floor^2 + spread^2), and significant in a paired test
over the held-out samples whose standard error holds the noise's and the tolerance's share).
Derived channels (the recorder's odometry) are reported and veto nothing.  Fits must be
physically possible."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer import effects as fx
from host_tools.analyzer.fit.judge import (HELDOUT_TOL, HELDOUT_Z, Candidate,
                                           evaluate_candidate, heldout_channel_check, judge,
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


def test_a_growth_the_tolerance_allows_is_no_evidence():
    # the heading of a held-out run: white camera noise of one floor about a replay the nominal
    # matched; the update shifts the last two thirds of the run by 3 floors at once (a slip
    # episode it replays differently) where the tolerance ensemble's spread is 2 floors
    rng = np.random.default_rng(3)
    n = 600
    b = rng.normal(0.0, 1.0, n)
    shift = np.where(np.arange(n) >= n // 3, 3.0, 0.0)
    a = b - shift
    spread = np.where(shift > 0, 2.0, 0.05)
    worse, incr, z = paired_worse(b, a, 1.0)
    assert worse and incr > 1.0 and z > 10          # the noise alone: vetoed
    worse, incr2, z2 = paired_worse(b, a, 1.0, spread)
    assert not worse and incr2 == incr and 0 < z2 < HELDOUT_Z
    # the same growth where the replay is pinned (spread far below the change): still worse
    worse, _, z3 = paired_worse(b, a, 1.0, np.full(n, 0.2))
    assert worse and z3 > HELDOUT_Z
    # a spread where the update changes nothing does not excuse a change elsewhere
    worse, _, z4 = paired_worse(b, a, 1.0, np.where(shift > 0, 0.05, 5.0))
    assert worse and z4 > HELDOUT_Z


def test_the_size_test_is_against_the_floor_and_the_spread_together():
    # a consistent growth (1 floor on half the samples) where the replay is pinned,
    # in a channel whose other half the tolerance cannot pin (spread 4 floors, no change
    # there): significant, but small against sqrt(floor^2 + spread^2)
    rng = np.random.default_rng(4)
    n = 4000
    b = rng.normal(0.0, 1.0, n)
    half = np.arange(n) < n // 2
    a = b + np.where(half, 1.0, 0.0)
    worse, incr, z = paired_worse(b, a, 1.0)
    assert worse and HELDOUT_TOL < incr < 0.3 and z > HELDOUT_Z   # 0.3: 0.1 x sqrt(1 + 8)
    spread = np.where(half, 0.0, 4.0)
    worse, incr2, z2 = paired_worse(b, a, 1.0, spread)
    assert incr2 == incr and z2 == z and not worse   # the tolerance's share is 0 where it changed
    # samples whose replay is not pinned at all (an infinite spread) are left out
    worse, _, z5 = paired_worse(b, a, 1.0, np.where(half, 0.0, np.inf))
    assert worse and z5 > HELDOUT_Z


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
    assert chk["x_m"]["replay_spread"] == 0.0
    # the reference replay's spread at the held-out samples joins the judgement
    spreads = {"x_m": np.full(500, 4e-3)}
    chk = heldout_channel_check({"x_m": float(np.sqrt(np.mean(b ** 2)))},
                                {"x_m": float(np.sqrt(np.mean((b + 2e-3) ** 2)))},
                                {"x_m": 1e-3}, {"x_m": pairs["x_m"]}, spreads)
    assert chk["x_m"]["ok"] and not chk["x_m"]["worse"]
    assert abs(chk["x_m"]["replay_spread"] - 4e-3) < 1e-12
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
    # the single carries its creep speed as a nuisance beside its two coordinates; a pair not
    assert [q.name for q in params] == ["mu_s", "mu_k_over_mu_s", "v_creep"]
    assert [q.nuisance is not None for q in params] == [False, False, True]
    assert [q.name for q in params_for(["friction_coefficient", "wheel_radius"], p.meta,
                                       p.vocab)] == ["mu_s", "mu_k_over_mu_s", "r_eff"]
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


class _FoldProblem:
    """Three held-out runs of one channel: the update shifts run 2's pose by 3 floors where the
    reference replay's spread is 2.5 floors (the stub's channel_resids with ``spread``)."""

    def __init__(self):
        from host_tools.runfmt import validate_meta
        self.meta = validate_meta({})
        self.vocab = {"motor_back_emf": {"ke_ratio": 1.0}}
        self.floors = {"x_m": 1e-3}
        self.preps = [None, None, None]
        rng = np.random.default_rng(5)
        self.noise = [rng.normal(0.0, 1e-3, 300) for _ in range(3)]

    def fit(self, names, runs, part="all", x0=None, max_nfev=60, fixed=None):
        return FitResult(list(names), {"motor_back_emf": {"ke_ratio": 1.2}}, [1.2],
                         np.array([0.5]), 1.0, 900, [0.01], 1)

    def _runs(self, effects, runs, f):
        return np.concatenate([f(i, bool(effects)) for i in runs])

    def residual_segments(self, effects, runs, part="all", full=False):
        return [self.noise[i] / 1e-3 * (0.5 if effects else 2.0) for i in runs]

    def residual(self, effects, runs, part="all", full=False):
        return np.concatenate(self.residual_segments(effects, runs, part, full))

    def channel_resids(self, effects, runs, part="all", full=False, spread=False):
        if spread:
            return {"x_m": self._runs(effects, runs, lambda i, upd: np.full(300, 2.5e-3 if i == 2
                                                                             else 1e-5))}
        return {"x_m": self._runs(effects, runs, lambda i, upd: self.noise[i] - (
            3e-3 if (upd and i == 2) else 0.0))}

    def output_change(self, before, after, runs):
        return 2.0


def test_evaluate_candidate_keeps_the_reference_replays_spread_with_the_held_out_pairs():
    p = _FoldProblem()
    cand = evaluate_candidate(p, ["motor_back_emf"])
    b, a = cand.heldout_pairs["x_m"]
    u = cand.heldout_spread["x_m"]
    assert u.shape == b.shape == a.shape == (900,)
    # the pooled samples' segments, one per held-out run here (one channel each)
    assert list(cand.heldout_segments) == [300, 300, 300]
    assert cand.heldout_pooled[0].size == 900
    assert np.all(u[600:] == 2.5e-3) and np.all(u[:600] == 1e-5)
    judge(p, cand)
    chk = cand.heldout_per_channel["x_m"]
    assert chk["increase_noise_floors"] > 0.5 and chk["z"] < HELDOUT_Z
    assert cand.checks["heldout_channels"], cand.reasons
    # without the spread the same growth vetoes the update
    cand.heldout_spread = {}
    judge(p, cand)
    assert not cand.checks["heldout_channels"]


def test_the_spread_is_the_replays_uncertainty_without_the_sampling_band():
    from host_tools.analyzer.fit.problem import Problem
    from host_tools.analyzer.replay.channels import Channel

    t = np.linspace(0.0, 1.0, 6)
    chans = {"current_r_a": Channel("current_r_a", t, np.ones(6), np.zeros(6), "A",
                                    unc=np.full(6, 0.01), band=np.full(6, 5.0)),
             "x_m": Channel("x_m", t, np.ones(6), np.zeros(6), "m")}

    class _P(Problem):
        def sim_channels(self, effects, runs, full=False, fit_only=False):  # type: ignore[no-untyped-def]
            return [chans for _ in runs]

        def _split_t(self, prep):  # type: ignore[no-untyped-def]
            return 0.5

    p = _P.__new__(_P)
    p.preps = [None, None]  # type: ignore[list-item]
    u = p.channel_resids({}, [0, 1], spread=True)
    # the input spread and tolerance ensemble (Channel.unc), not the current's sampling band,
    # at the same samples as the residuals; zeros where the replay has none
    assert np.array_equal(u["current_r_a"], np.full(12, 0.01))
    assert np.array_equal(u["x_m"], np.zeros(12))
    late = p.channel_resids({}, [0], part="late", spread=True)
    assert late["x_m"].size == p.channel_resids({}, [0], part="late")["x_m"].size == 3
