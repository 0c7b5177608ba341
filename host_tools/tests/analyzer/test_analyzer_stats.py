"""The analyzer's statistics: the consistent-bias detection (effective samples), the paired
adoption test, and the false-alarm rates they are built on."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer.locate.bias import BIAS_ALPHA, bias_test
from host_tools.analyzer.replay.channels import Channel

FIT = ("omega_r", "omega_l", "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")


def _runs(rng, bias: dict[str, float], n_runs: int = 3, dur_s: float = 3.0, hz: float = 50.0,
          floor: float = 1.0):
    """Per run, channels of white noise (std = floor) plus a constant bias per channel."""
    out = []
    for _ in range(n_runs):
        t = np.arange(0.0, dur_s, 1.0 / hz)
        chans = {}
        for c in FIT:
            rec = floor * rng.standard_normal(t.size) + bias.get(c, 0.0) * floor
            chans[c] = Channel(c, t, rec, np.zeros(t.size), "u")
        out.append(chans)
    return out


def test_a_consistent_bias_below_the_strong_window_is_found():
    """1.3 floors in one wheel's speed over three 3 s runs (the issue's motor-gain asymmetry):
    no sample is remarkable, no window reaches 3 floors, but the blocks agree."""
    rng = np.random.default_rng(1)
    runs = _runs(rng, {"omega_r": 1.3})
    res = bias_test(runs, {c: 1.0 for c in FIT}, FIT)
    assert res["omega_r"]["significant"]
    assert abs(res["omega_r"]["bias_floors"] - 1.3) < 0.2
    assert not any(res[c]["significant"] for c in FIT if c != "omega_r")


def test_white_noise_alarms_at_most_at_the_stated_rate():
    """Nulls of white noise: the share of analyses with any flagged channel stays near
    BIAS_ALPHA (Bonferroni makes it at most that)."""
    rng = np.random.default_rng(2)
    floors = {c: 1.0 for c in FIT}
    trials = 300
    alarms = sum(any(v["significant"] for v in bias_test(_runs(rng, {}), floors, FIT).values())
                 for _ in range(trials))
    # at most BIAS_ALPHA; binomial(300, 0.01) exceeds 8 with probability < 0.5 %
    assert alarms <= 8, alarms
    assert BIAS_ALPHA == 0.01


def test_a_significant_but_tiny_bias_is_not_a_mismatch():
    """0.3 floors over 2 x 60 s is significant, but below the smallest output change an update
    may make (0.5 floors), so nothing could be named: no detection."""
    rng = np.random.default_rng(3)
    runs = _runs(rng, {"current_r_a": 0.3}, n_runs=2, dur_s=60.0)
    res = bias_test(runs, {c: 1.0 for c in FIT}, FIT)
    assert abs(res["current_r_a"]["t"]) > res["current_r_a"]["t_threshold"]
    assert not res["current_r_a"]["significant"]


def test_slow_wander_without_a_consistent_sign_is_not_a_bias():
    """A residual that wanders by ±1.5 floors over seconds (a replay's model-tolerance drift)
    with no common sign across blocks: its blocks disagree, so it is not counted as many
    independent samples of one bias."""
    rng = np.random.default_rng(4)
    runs = _runs(rng, {})
    for k, chans in enumerate(runs):
        ch = chans["x_m"]
        ch.rec = ch.rec + 1.5 * np.sin(2 * np.pi * ch.t / 2.0 + k * 2.1)
    res = bias_test(runs, {c: 1.0 for c in FIT}, FIT)
    assert not res["x_m"]["significant"]


def test_a_bias_within_the_models_tolerance_is_not_a_mismatch():
    """The same 1.3 floors, where the nominal model's tolerance allows a whole-run bias of one
    floor in that channel (one set of parameters for all runs: it does not average out)."""
    rng = np.random.default_rng(1)
    runs = _runs(rng, {"omega_r": 1.3})
    floors = {c: 1.0 for c in FIT}
    assert bias_test(runs, floors, FIT)["omega_r"]["significant"]
    allowed = [{"omega_r": 1.0}] * len(runs)
    res = bias_test(runs, floors, FIT, allowed=allowed)
    assert not res["omega_r"]["significant"]
    assert res["omega_r"]["tolerance_floors"] == 1.0


def test_tolerance_draws_stay_within_the_tables_tolerance():
    """Robot parameters uniform within value ± tol (params.json), μk ≤ μs; the motor's datasheet
    constants are not drawn (their deviations are what the motor effects name)."""
    from host_tools import params as P
    from host_tools.analyzer.replay.tolerance import tolerance_draws
    rng = np.random.default_rng(5)
    draws = tolerance_draws(dict(P.ROBOT), 200, rng)
    for name in ("b", "mu_s", "m_r", "r"):
        vals = np.array([d[name] for d in draws])
        tol = P.TOLERANCES[("robot", name)]
        assert np.all(np.abs(vals - P.ROBOT[name]) <= tol + 1e-15)
        assert np.ptp(vals) > tol                  # the draws use the range
    assert all(d["mu_k"] <= d["mu_s"] for d in draws)
    assert not any(k in d for d in draws for k in P.MOTOR)
    assert "g" in draws[0] and "supply_v" not in draws[0]


def _heldout(rng, n=3000, gain=0.956):
    """Held-out residuals (floors): before = a model error (1.5 floors) + noise; after = that
    error reduced so that the pooled RMS falls by 1 - gain, the same noise."""
    noise = rng.standard_normal(n)
    err = 1.5 * np.sin(np.linspace(0, 60, n))
    before = err + noise
    target = gain * np.sqrt(np.mean(before ** 2))
    # scale the model error down until the after-RMS reaches the target
    for k in np.linspace(1.0, 0.0, 2001):
        after = k * err + noise
        if np.sqrt(np.mean(after ** 2)) <= target:
            break
    return before, after


def test_paired_test_adopts_a_small_but_consistent_held_out_gain():
    """The issue's track width: held-out error down 4.4 % over thousands of samples, each sample
    better; the fixed 5 % rule refused it, the paired test takes it.  Noise alone does not pass."""
    from host_tools.analyzer.fit.judge import paired_better
    rng = np.random.default_rng(6)
    before, after = _heldout(rng)
    ok, z = paired_better(before, after)
    assert ok and z > 2.33
    # the same noise re-drawn: no evidence of improvement in 95 of 100 tries at least
    wins = sum(paired_better(rng.standard_normal(3000), rng.standard_normal(3000))[0]
               for _ in range(100))
    assert wins <= 5


def _ar1(rng, n, rho):
    e = np.empty(n)
    e[0] = rng.standard_normal()
    for i in range(1, n):
        e[i] = rho * e[i - 1] + np.sqrt(1 - rho ** 2) * rng.standard_normal()
    return e


def test_fixed_design_error_holds_its_rate_under_the_tests_own_null():
    """The held-out test's null: the update changes the replay by a fixed D (fitted on other
    runs) and predicts the held-out run no better, mean(2 D s + D^2) = 0 (here the nominal
    misfit s = -D / 2), only the held-out noise random, correlated along each of four segments
    (lag-1 0.9).  With the segments' AR(1) factor the rate stays near the one-sided 1 %; counted
    as independent samples the same statistic passes about a third of the draws."""
    from host_tools.analyzer.fit.judge import paired_better
    rng = np.random.default_rng(11)
    n, k = 400, 4
    t = np.linspace(0.0, 1.0, n)
    D = np.concatenate([(j + 1) * 0.6 * np.sin(6 * t + j) for j in range(k)])
    s = -D / 2
    wins = wins_iid = 0
    for _ in range(300):
        e = np.concatenate([_ar1(rng, n, 0.9) for _ in range(k)])
        before, after = s + e, s + e + D
        wins += paired_better(before, after, segments=[n] * k)[0]
        wins_iid += paired_better(before, after, segments=[1] * (n * k))[0]
    assert wins <= 9            # 1 % of 300 is 3; 9 is beyond its binomial 99.9 % point
    assert wins_iid >= 60


def test_fixed_design_z_grows_with_an_effect_the_sample_spread_does_not():
    """A gain that grows along each run (a wheel radius off: the pose error grows with the
    distance driven), removed by the update, on 45 camera samples in each of three runs: the
    sample spread of after^2 - before^2 grows with the effect as its mean does, so that z stays
    bounded; the fixed-design error (only the noise random) gives a z that grows with it."""
    from host_tools.analyzer.fit.judge import paired_better
    rng = np.random.default_rng(12)
    n, k = 45, 3
    ramp = np.tile(np.linspace(0.0, 1.0, n) ** 2, k)
    e = np.concatenate([_ar1(rng, n, 0.8) for _ in range(k)])
    z_spread, z_fixed = [], []
    for g in (8.0, 32.0, 128.0):
        before, after = e + g * ramp, e
        z_spread.append(paired_better(before, after)[1])
        z_fixed.append(paired_better(before, after, segments=[n] * k)[1])
    # four times the effect each step: the sample spread's z is at its bound (2.9 here)
    assert z_spread[2] < 1.02 * z_spread[1] < 1.1 * z_spread[0] < 3.3
    assert z_fixed[2] > 3.5 * z_fixed[1] and z_fixed[1] > 3.5 * z_fixed[0] > 3.5 * 2.33
    # no segments (or segments that do not cover the samples): the sample spread's z
    assert paired_better(before, after, segments=[n] * (k - 1))[1] == z_spread[2]


def test_judge_uses_the_paired_test():
    from host_tools.analyzer.fit.judge import Candidate, judge
    from host_tools.analyzer.fit.params import FitResult
    from host_tools.runfmt import validate_meta
    rng = np.random.default_rng(7)
    before, after = _heldout(rng)

    class _P:
        meta = validate_meta({})
        vocab = {"motor_back_emf": {"ke_ratio": 1.0}}
        floors = {"omega_r": 0.1}
    fit = FitResult(["motor_back_emf"], {"motor_back_emf": {"ke_ratio": 1.2}}, [1.2],
                    np.array([0.5]), 10.0, 1000, [0.01], 10)
    hb, ha = float(np.sqrt(np.mean(before ** 2))), float(np.sqrt(np.mean(after ** 2)))
    assert ha > 0.95 * hb                         # below the old 5 % gain
    c = Candidate(["motor_back_emf"], fit, -200.0, hb, ha, {"omega_r": 0.5}, {"omega_r": 0.5},
                  [[1.19], [1.21]], 4.0, heldout_pooled=(before, after))
    judge(_P(), c)
    assert c.checks["heldout"] and c.heldout_z > 2.33, c.reasons
    c2 = Candidate(["motor_back_emf"], fit, -200.0, hb, hb, {"omega_r": 0.5}, {"omega_r": 0.5},
                   [[1.19], [1.21]], 4.0,
                   heldout_pooled=(before, before + 0.01 * rng.standard_normal(before.size)))
    judge(_P(), c2)
    assert not c2.checks["heldout"] and not c2.accepted


def test_a_pair_partner_whose_parameter_is_insignificant_is_dropped():
    """Gain asymmetry fitted at 1.10 ± 0.002 with a 6 ms delay ± 4 ms: the delay is within
    2.33 sigma of zero, so the pair is refused and the asymmetry stands alone."""
    from host_tools.analyzer.fit.judge import Candidate
    from host_tools.analyzer.fit.params import FitResult
    from host_tools.analyzer.select import _insignificant_partners
    from host_tools.runfmt import validate_meta

    class _P:
        meta = validate_meta({})
        vocab = {"motor_gain_asymmetry": {"ratio": 1.0}, "actuation_delay": {"delay_s": 0.0}}
        floors = {}

    def pair(delay_std):
        fit = FitResult(["motor_gain_asymmetry", "actuation_delay"],
                        {"motor_gain_asymmetry": {"ratio": 1.1},
                         "actuation_delay": {"delay_s": 0.006}}, [1.1, 0.006],
                        np.array([0.5, 0.1]), 10.0, 1000, [0.002, delay_std], 10)
        return Candidate(fit.effects, fit, -300.0, 2.0, 1.0, {}, {}, [[1.1, 0.006]], 3.0)
    assert [e for e, _ in _insignificant_partners(pair(0.004), _P())] == ["actuation_delay"]
    assert _insignificant_partners(pair(0.001), _P()) == []


def test_a_pair_partner_within_its_nominal_tolerance_is_dropped():
    """Wheel radius far off with a track width 1.3 mm off at 0.27 mm: 4.8 sigma by the fit
    alone, but inside what the table's half width and its tolerance allow (the size test a
    single track width fails: the one-sided 1 % point of the fit's normal error plus the
    uniform on +- tol), so the pair is refused and the
    radius stands alone; 2.5 tolerances off, the track width stays."""
    from host_tools import params as PP
    from host_tools.analyzer.fit.judge import Candidate
    from host_tools.analyzer.fit.params import FitResult
    from host_tools.analyzer.select import _insignificant_partners
    from host_tools.runfmt import validate_meta

    r0, b0 = PP.ROBOT["r"], PP.ROBOT["b"]
    b_tol = next(p.tol for p in PP.TABLE.group("robot") if p.name == "b")

    class _P:
        meta = validate_meta({})
        vocab = {"wheel_radius": {"r_eff": r0}, "track_width": {"b_eff": b0}}
        floors: dict[str, float] = {}

    def pair(db: float):
        fit = FitResult(["wheel_radius", "track_width"],
                        {"wheel_radius": {"r_eff": r0 * 1.02}, "track_width": {"b_eff": b0 + db}},
                        [r0 * 1.02, b0 + db], np.array([0.5, 0.5]), 10.0, 1000,
                        [r0 * 2e-4, 0.27e-3], 10)
        return Candidate(fit.effects, fit, -300.0, 2.0, 1.0, {}, {}, [[r0 * 1.02, b0 + db]], 3.0)
    assert 1.3e-3 / 0.27e-3 > 2.33  # significant by the fit's sigma alone
    assert [e for e, _ in _insignificant_partners(pair(1.3e-3), _P())] == ["track_width"]
    assert _insignificant_partners(pair(2.5 * b_tol), _P()) == []


def _detect(paths, with_tolerance: bool, monkeypatch):
    from host_tools.analyzer import pipeline as P
    from host_tools.analyzer.replay import nominal as N
    with monkeypatch.context() as mp:
        if not with_tolerance:
            mp.setattr(N, "tolerance_uncertainty", lambda *a, **k: None)
        return P.front(paths).det.mismatch_seen


def test_a_robot_within_its_tolerance_is_a_null_and_one_beyond_it_is_not(tmp_path, monkeypatch):
    """A track width 2 mm wider than Table II.2's (within its ±2.5 mm): arcs drift the camera
    pose tens of floors from the nominal replay, a mismatch without the tolerance ensemble and
    a null with it; 8 mm wider (three tolerances) still shows."""
    from host_tools.analyzer import synth

    def case(db):
        def factory(meta):
            pl = synth.nominal_plant(meta)  # the nominal robot but for its track width
            pl.set("robot.b", meta["robot"]["b"] + db)
            return pl
        return synth.make_case(tmp_path / f"b{db}", None, profiles=("turn", "turn", "ramp"),
                               seed=3, duration_s=3.0, plant_factory=factory)
    inside = case(0.002)
    assert _detect(inside, False, monkeypatch)
    assert not _detect(inside, True, monkeypatch)
    assert _detect(case(0.008), True, monkeypatch)


def test_the_camera_anchors_are_computed_once_per_window_and_slip_state(tmp_path):
    """The fits evaluate every window's camera anchor at every step; it reads only the
    recording, the windows and the slip episodes, so a prepared run carries its anchors as a
    value: computed when its windows or slip episodes are set, looked up after (the same
    values, not computed again), new ones with new slip episodes, the given run unchanged."""
    import dataclasses

    from host_tools.analyzer import pipeline as P
    from host_tools.analyzer import synth
    from host_tools.analyzer.prepare.inputs import prepare_runs
    from host_tools.analyzer.replay import anchors
    paths = synth.make_case(tmp_path / "c", None, profiles=("turn",), seed=1, duration_s=9.0)
    prep = prepare_runs(P._load_runs(paths, lambda m: None), lambda m: None)[0]
    assert len(prep.windows) > 1 and not prep.anchors
    t = prep.run.telemetry["t_s"]
    at = float(t[prep.windows[1][0]])
    calls = []
    real = anchors._gt_anchor_of

    def counted(*a, **k):
        calls.append(a[1])
        return real(*a, **k)
    anchors._gt_anchor_of = counted
    try:
        ready = anchors.with_anchors(prep)
        n = len(calls)
        assert n == 2 * (len(prep.windows) - 1) and at in calls and not prep.anchors
        first = anchors._gt_anchor(ready, at)
        again = anchors._gt_anchor(ready, at)
        assert first is again and len(calls) == n
        assert first == real(prep, at)
        slipped = anchors.with_anchors(dataclasses.replace(ready, slip_episodes=[(0.2, 0.4)]))
        assert len(calls) == 2 * n and anchors._gt_anchor(slipped, at) == real(slipped, at)
        assert ready.slip_episodes == [] and anchors._gt_anchor(ready, at) is first
        anchors._gt_anchor(prep, at)               # a run without its anchors computes it
        assert len(calls) == 2 * n + 1
    finally:
        anchors._gt_anchor_of = real


def test_grid_start_keeps_the_neutral_point_when_every_start_costs_infinity():
    """A replay that blows up at every start of the coarse grid (residuals so large that their
    squares overflow to inf) leaves the fit at its neutral point: no start was chosen before,
    and the two-parameter refinement failed on None (found by mypy)."""
    from host_tools.analyzer.fit.solver import grid_start
    base = np.array([0.5, 0.25])
    with np.errstate(over="ignore"):
        x0, nfev = grid_start(lambda x: np.full(4, 1e200), base.copy(), 3)
    assert isinstance(x0, np.ndarray) and np.array_equal(x0, base)
    assert nfev == 1 + 2 * 3 + 3
def test_a_slip_in_a_windowed_replay_is_no_evidence():
    """In a slip episode of the nominal replay the pose is no evidence from the slip's onset to
    the end of its window (the replay is re-anchored there) and the wheels within the episode;
    where the replay's own uncertainty of the pose exceeds its noise floor inside the episode
    (unpinned), the wheels stay out until BURN_IN_S after it."""
    from types import SimpleNamespace

    from host_tools.analyzer.locate.episodes import SLIP_UNC, UNPINNED_UNC, unpinned_episodes
    from host_tools.analyzer.prepare.run import BURN_IN_S, PreparedRun
    t = np.arange(0.0, 8.0, 0.02)
    seg = (t >= 4.0).astype(int)                  # two replay windows, the edge at 4 s

    def chans(pose_unc_in_slip: float) -> dict:
        out = {}
        for c in FIT:
            unc = np.full(t.size, 0.2)
            if c in ("x_m", "y_m", "phi_rad"):
                unc[(t > 1.5) & (t < 2.0)] = pose_unc_in_slip
            out[c] = Channel(c, t, 30.0 * (t > 1.2) * (t < 4.0), np.zeros(t.size), "u",
                             seg.copy(), unc)
        return out
    floors = {c: 1.0 for c in FIT}
    ep = (1.0, 2.5)
    def prep_of(episodes: list) -> PreparedRun:
        none = (np.zeros(0), np.zeros(0))
        return PreparedRun(SimpleNamespace(), t, t, none, none, t, {}, {}, (0.0, 0.0, 0.0), 1,
                           slip_episodes=episodes)
    nothing = prep_of([])
    quiet = chans(3.0)
    got = unpinned_episodes([nothing], [quiet], floors)
    assert got.episodes == [[]]
    assert all(np.all(ch.unc <= 3.0) for ch in got.nominal[0].values())
    assert got.preps[0].replay_unc is None
    prep = prep_of([ep])
    given = chans(0.8)
    got = unpinned_episodes([prep], [given], floors)
    assert got.episodes == [[]]
    pinned = got.nominal[0]
    # new values: the given channels and run are left as they are
    assert all(np.all(ch.unc <= 3.0) for ch in given.values()) and prep.replay_unc is None
    off = {c: pinned[c].unc >= UNPINNED_UNC for c in FIT}
    assert np.array_equal(off["x_m"], (t >= ep[0]) & (t < 4.0))       # to the window's end
    # the wheels within the episode: no evidence on their own, their difference kept
    assert not np.any(pinned["omega_r"].unc >= UNPINNED_UNC)
    assert np.array_equal(pinned["omega_r"].unc >= SLIP_UNC, (t >= ep[0]) & (t <= ep[1]))
    got = unpinned_episodes([prep_of([ep])], [chans(3.0)], floors)
    loose, prep = got.nominal[0], got.preps[0]
    assert got.episodes[0] and abs(got.episodes[0][0][0] - 1.52) < 0.011
    assert got.episodes[0][0][1] == ep[1]
    off = {c: loose[c].unc >= UNPINNED_UNC for c in FIT}
    assert np.array_equal(off["x_m"], (t >= ep[0]) & (t < 4.0))
    onset = got.episodes[0][0][0]
    assert np.array_equal(off["current_l_a"], (t >= onset) & (t <= ep[1] + BURN_IN_S))
    assert np.array_equal(loose["current_l_a"].unc >= SLIP_UNC,
                          (t >= ep[0]) & (t <= ep[1] + BURN_IN_S))
    # the run keeps it for every later replay (the fits attach prep.replay_unc)
    assert np.array_equal(prep.replay_unc["phi_rad"][1] >= UNPINNED_UNC, off["phi_rad"])
    # the deflated residual is nil there, and untouched elsewhere
    z = loose["x_m"].deflated(1.0)
    assert np.all(np.abs(z[off["x_m"]]) < 1e-6) and np.abs(z[(t > 0.5) & (t < 1.0)]).max() == 0
    z = loose["omega_r"].deflated(1.0)
    assert np.abs(z[(t > 3.1) & (t < 4.0)]).min() > 25


def _asymmetric_runs(rng, shift: float, n_runs: int = 3, dur_s: float = 3.0, hz: float = 50.0):
    """Per run, the fit channels' white noise (1 floor), and in the two currents a common
    wander of 1.5 floors over seconds (the replay's own error, alike in both wheels) plus
    -shift on the right wheel and +shift on the left (a motor-gain asymmetry)."""
    runs = _runs(rng, {}, n_runs, dur_s, hz)
    for k, chans in enumerate(runs):
        t = chans["current_r_a"].t
        common = 1.5 * np.sin(2 * np.pi * t / 2.5 + 1.7 * k)
        chans["current_r_a"].rec = chans["current_r_a"].rec + common - shift
        chans["current_l_a"].rec = chans["current_l_a"].rec + common + shift
    return runs


def test_a_wheel_asymmetry_shows_in_the_wheels_difference():
    """Opposite biases of 0.6 floors in the two currents under a common wander (heldback6's
    MuJoCo 10 % asymmetry: -0.64 and +0.48 floors): neither wheel is significant on its own,
    their difference is; the same wander without the asymmetry is nothing."""
    from host_tools.analyzer.locate.bias import pair_name
    floors = {c: 1.0 for c in FIT}
    name = pair_name("current_r_a", "current_l_a")
    found = 0
    for seed in range(10):
        res = bias_test(_asymmetric_runs(np.random.default_rng(seed), 0.6), floors, FIT)
        assert not res["current_r_a"]["significant"] and not res["current_l_a"]["significant"]
        assert abs(res[name]["bias_floors"] + 0.6 * np.sqrt(2)) < 0.3
        assert res[name]["block_s"] == 0.5 and res["current_r_a"]["block_s"] == 1.0
        found += res[name]["significant"]
        quiet = bias_test(_asymmetric_runs(np.random.default_rng(100 + seed), 0.0), floors, FIT)
        assert not any(v["significant"] for v in quiet.values())
    assert found >= 9, found


def test_the_tolerance_allows_little_bias_in_the_wheels_difference():
    """The tolerance draws are the robot's parameters, common to both wheels: their mean
    residuals move the two wheels alike, so the bias they allow in the difference is that of
    what differs, not the per-wheel one."""
    from types import SimpleNamespace

    from host_tools.analyzer.locate.bias import allowed_bias, pair_name
    rng = np.random.default_rng(7)
    common = rng.normal(0.0, 0.3, 8)
    prep = SimpleNamespace(
        tolerance_bias={"current_r_a": 0.3, "current_l_a": 0.3},
        tolerance_draw_means={"current_r_a": list(common + rng.normal(0, 0.01, 8)),
                              "current_l_a": list(common + rng.normal(0, 0.01, 8))})
    got = allowed_bias(prep, {"current_r_a": 1.0, "current_l_a": 1.0})
    assert got["current_r_a"] == 0.3
    assert got[pair_name("current_r_a", "current_l_a")] < 0.03
