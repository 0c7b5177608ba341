"""The wheels' torque imbalance test (host_tools/analyzer/locate/wheels.py): the speeds' and the
currents' differences regressed together on the signature a per-wheel torque difference leaves
in them, with their correlation, the blocks' autocorrelation and the model's tolerance."""
from __future__ import annotations

import numpy as np
from _native_skip import needs_native

from host_tools.analyzer.locate.bias import BIAS_ALPHA, bias_test, pair_name
from host_tools.analyzer.replay.channels import Channel
from host_tools.analyzer.locate.wheels import IMBALANCE_STEP, imbalance_test, tolerance_cov

FIT = ("omega_r", "omega_l", "x_m", "y_m", "phi_rad", "current_r_a", "current_l_a")
W, I = pair_name("omega_r", "omega_l"), pair_name("current_r_a", "current_l_a")
N_TESTS = 10      # the fit channels, the two pairs and this test share the false-alarm rate


def _torque(t: np.ndarray, k: int) -> np.ndarray:
    """A torque-like profile: accelerate, cruise, brake (its sign flips, so its mean is small)."""
    a = 0.8 + 0.1 * k
    return np.where(t < a, 1.0, np.where(t < 2.0, 0.15, np.where(t < 2.0 + a, -1.0, 0.0)))


def _runs(rng, beta: float, *, amp_w: float = 0.6, amp_i: float = 0.9, rho_wi: float = 0.0,
          wander: float = 0.0, n_runs: int = 3, dur_s: float = 3.0, hz: float = 50.0,
          steady: bool = False):
    """(nominal, stepped) channels per run, floors 1.  The stepped replay moves the two wheels'
    speeds by +-amp_w * torque/sqrt(2)... (its contrast (r - l)/sqrt(2) is amp_w * torque) and
    the currents the other way (contrast -amp_i * torque); the recording holds ``beta`` times
    that change, white noise of one floor per wheel whose speed and current differences
    correlate by ``rho_wi``, a common wander of 1.5 floors (alike in both wheels) and, in the
    speeds' difference, an AR(1) wander of std ``wander`` floors decorrelating over 1.5 s.
    ``steady``: a constant torque (a climb) instead of the profile."""
    nominal, stepped = [], []
    for k in range(n_runs):
        t = np.arange(0.0, dur_s, 1.0 / hz)
        g = np.full(t.size, 0.5) if steady else _torque(t, k)
        zw = rng.standard_normal(t.size)
        zi = rho_wi * zw + np.sqrt(1 - rho_wi ** 2) * rng.standard_normal(t.size)
        common = 1.5 * np.sin(2 * np.pi * t / 2.5 + 1.7 * k)
        phi = np.exp(-1.0 / (hz * 1.5))
        ar = np.zeros(t.size)
        ar[0] = rng.standard_normal()
        for j in range(1, t.size):
            ar[j] = phi * ar[j - 1] + np.sqrt(1 - phi ** 2) * rng.standard_normal()
        diff_w = beta * amp_w * g + zw + wander * ar      # (r - l)/sqrt(2) of the speeds
        diff_i = -beta * amp_i * g + zi                    # ... of the currents
        nom, stp = {}, {}
        for c in FIT:
            rec = rng.standard_normal(t.size)
            nom[c] = Channel(c, t, rec, np.zeros(t.size), "u")
            stp[c] = Channel(c, t, np.zeros(t.size), np.zeros(t.size), "u")
        for (r, l), d, s in ((("omega_r", "omega_l"), diff_w, amp_w * g),
                             (("current_r_a", "current_l_a"), diff_i, -amp_i * g)):
            # r = common + d/sqrt(2), l = common - d/sqrt(2): (r - l)/sqrt(2) = d
            nom[r].rec = common + d / np.sqrt(2)
            nom[l].rec = common - d / np.sqrt(2)
            stp[r].sim = s / np.sqrt(2)
            stp[l].sim = -s / np.sqrt(2)
        nominal.append(nom)
        stepped.append(stp)
    return nominal, stepped


FLOORS = {c: 1.0 for c in FIT}


def test_an_imbalance_below_each_differences_threshold_is_found_combined():
    """A 10 % imbalance whose speeds' and currents' differences are each below the bias test's
    threshold (their mean is small: the torque flips sign when braking) is significant along
    its signature, and the regression gives the ratio."""
    found = 0
    for seed in range(10):
        nominal, stepped = _runs(np.random.default_rng(seed), 1.0)
        bias = bias_test(nominal, FLOORS, FIT)
        assert not bias[W]["significant"] and not bias[I]["significant"]
        res = imbalance_test(nominal, stepped, FLOORS, N_TESTS)
        assert res is not None and res["contrasts"] == [W, I]
        assert abs(res["ratio"] - IMBALANCE_STEP) < 0.03
        found += res["significant"]
    assert found >= 9, found


def test_the_combination_is_stronger_than_either_contrast():
    """Each contrast on its own along the same signature is weaker than the two together."""
    nominal, stepped = _runs(np.random.default_rng(11), 0.6)
    both = imbalance_test(nominal, stepped, FLOORS, N_TESTS)
    only_w = imbalance_test(nominal, stepped, FLOORS, N_TESTS, pairs=[("omega_r", "omega_l")])
    only_i = imbalance_test(nominal, stepped, FLOORS, N_TESTS,
                            pairs=[("current_r_a", "current_l_a")])
    assert both and only_w and only_i
    assert abs(both["t"]) > max(abs(only_w["t"]), abs(only_i["t"]))


def test_correlated_nulls_alarm_at_most_at_the_stated_rate():
    """Nulls whose speed and current differences correlate (0.7) and whose speeds' difference
    wanders over seconds (1 floor, AR(1) over 1.5 s): the share flagged stays within the
    test's share of BIAS_ALPHA.  Without the blocks' autocorrelation the wander is counted as
    many independent blocks."""
    rng = np.random.default_rng(5)
    trials = 200
    alarms = 0
    for _ in range(trials):
        nominal, stepped = _runs(rng, 0.0, rho_wi=0.7, wander=1.0)
        res = imbalance_test(nominal, stepped, FLOORS, N_TESTS, min_floors=0.0)
        alarms += bool(res and res["significant"])
    # this test's share is BIAS_ALPHA / N_TESTS = 0.1 %: binomial(200, 0.001) exceeds 2 with
    # probability 1e-3
    assert alarms <= 2, alarms
    assert BIAS_ALPHA == 0.01


def test_a_tiny_imbalance_is_not_a_mismatch():
    """0.1 of the step over 2 x 60 s is significant, but moves the contrasts by less than the
    smallest output change an update may make (0.5 floors): nothing could be named."""
    nominal, stepped = _runs(np.random.default_rng(3), 0.1, n_runs=2, dur_s=60.0)
    for chans in stepped:    # the torque profile repeated over the minute
        for c in chans.values():
            c.sim = np.tile(c.sim[:150], 20)[:c.t.size] if c.sim.any() else c.sim
    for chans, stp in zip(nominal, stepped):
        t = chans["omega_r"].t
        for (r, l), amp in ((("omega_r", "omega_l"), 1.0), (("current_r_a", "current_l_a"), 1.0)):
            d = (stp[r].sim - stp[l].sim) / np.sqrt(2)
            noise = np.random.default_rng(int(t.size) + len(r)).standard_normal(t.size)
            chans[r].rec = (0.1 * amp * d + noise) / np.sqrt(2)
            chans[l].rec = -(0.1 * amp * d + noise) / np.sqrt(2)
    res = imbalance_test(nominal, stepped, FLOORS, N_TESTS)
    assert abs(res["t"]) > res["t_threshold"]
    assert res["output_floors"] < 0.5
    assert not res["significant"]


def test_an_imbalance_within_the_models_tolerance_is_not_a_mismatch():
    """The tolerance draws' contrasts (common parameters, but a bias in the difference): where
    they allow a whole-run bias along the signature as large as the effect, it is no evidence."""
    from types import SimpleNamespace
    nominal, stepped = _runs(np.random.default_rng(2), 1.0)
    assert imbalance_test(nominal, stepped, FLOORS, N_TESTS)["significant"]
    rng = np.random.default_rng(8)
    wide = rng.normal(0.0, 3.0, 8)
    prep = SimpleNamespace(tolerance_draw_means={
        "omega_r": list(wide), "omega_l": list(-wide),
        "current_r_a": list(-wide), "current_l_a": list(wide)})
    cov = tolerance_cov(prep, FLOORS, (("omega_r", "omega_l"), ("current_r_a", "current_l_a")))
    assert cov[(W, I)] < 0 < cov[(W, W)]
    res = imbalance_test(nominal, stepped, FLOORS, N_TESTS, allowed=[cov] * 3)
    assert not res["significant"] and res["tolerance_se"] > 0


def test_a_run_without_current_joins_with_its_speeds():
    """A run whose current sense is missing adds its speed blocks; the others give both."""
    nominal, stepped = _runs(np.random.default_rng(4), 1.0)
    for c in ("current_r_a", "current_l_a"):
        del nominal[0][c]
    res = imbalance_test(nominal, stepped, FLOORS, N_TESTS)
    assert res["significant"] and res["blocks"] == 18


def test_autocorrelated_blocks_count_as_fewer_samples():
    """A speeds' difference that wanders over seconds under a steady torque (a climb): its
    blocks are not independent samples, and the test counts fewer (n_eff) and a smaller t.
    (With the currents' difference too, the regression weighs the wandering speeds down.)"""
    import host_tools.analyzer.locate.wheels as wheels
    nominal, stepped = _runs(np.random.default_rng(9), 0.0, wander=1.5, steady=True)
    speeds = [("omega_r", "omega_l")]
    res = imbalance_test(nominal, stepped, FLOORS, N_TESTS, pairs=speeds)
    assert res["n_eff"] < 0.7 * res["blocks"]
    lag1 = wheels._lag1
    try:
        wheels._lag1 = lambda x: 0.0
        naive = imbalance_test(nominal, stepped, FLOORS, N_TESTS, pairs=speeds)
    finally:
        wheels._lag1 = lag1
    assert naive["n_eff"] == naive["blocks"] and abs(naive["t"]) > abs(res["t"])


# Three 3 s truth-engine runs recorded as heldback8's `loop10_ticks_drop3` (a 10 ms loop, odometry
# at the ticks, 3 % lost frames), where each wheel pair's difference alone missed a 12 %
# imbalance (heldback8's truth-engine asymmetry, recorded so, was `no_mismatch`).
RECORDER = {"inner_s": 0.01, "odometry": "ticks", "tel_drop": 0.03}
REFS = [{"kind": "line", "accel": 0.8, "cruise": 0.6},
        {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.6},
        {"kind": "figure_eight", "accel": 0.6, "cruise": 0.5, "radius": 0.5}]


def _truth_runs(tmp_path, effects):
    from host_tools import truth
    return [truth.simulate_run(tmp_path / f"run-{i}", ref, effects, clamp=True, duration_s=3.0,
                               seed=90 + i, recorder=RECORDER) for i, ref in enumerate(REFS)]


@needs_native(truth=True)
def test_a_twelve_percent_imbalance_is_found_and_named_on_truth_engine_runs(tmp_path):
    """The analysis finds the imbalance through this test (the pairs' own tests stay below
    their thresholds), names motor_gain_asymmetry and fits its ratio."""
    import json

    from host_tools.__main__ import main as cli
    runs = _truth_runs(tmp_path, {"motor_gain_asymmetry": {"ratio": 0.88}})
    out = tmp_path / "out"
    assert cli(["analyze", *runs, "--out", str(out), "--jobs", "1", "--no-plots",
                "--effects", "motor_gain_asymmetry"]) == 0
    rep = json.load(open(out / "report.json"))
    assert rep["verdict"] == "explained"
    assert any("torque imbalance" in n for n in rep["notes"])
    assert not any("consistent bias" in n for n in rep["notes"])
    sel = {s["effect"]: s["params"] for s in rep["selected"]}
    assert abs(sel["motor_gain_asymmetry"]["ratio"] - 0.88) < 0.03


@needs_native(truth=True)
def test_the_same_runs_without_the_imbalance_stay_a_null(tmp_path):
    import json

    from host_tools.__main__ import main as cli
    runs = _truth_runs(tmp_path, {})
    out = tmp_path / "out"
    assert cli(["analyze", *runs, "--out", str(out), "--jobs", "1", "--no-plots"]) == 0
    assert json.load(open(out / "report.json"))["verdict"] == "no_mismatch"


def _slip_runs(rng, beta: float, *, slip_err: float = 3.0, every: int = 4, dur_s: float = 30.0,
               hz: float = 20.0):
    """(nominal, stepped) channels of one run, floors 1, where every ``every``-th 0.5 s block is
    a pinned slip (both wheels' replay uncertainty ``SLIP_UNC``: each wheel no evidence, the
    pair's difference evidence).  As on a hard-reversal null with the clamp off (heldback20's
    `hb20_tr_long_null_60s_hard`), the slips carry almost all of the signature (speeds +-1,
    currents -+0.5 floors against 0.05 elsewhere) and the replay's own error of the difference
    is several times the others' there: a constant of std ``slip_err`` floors (half of it in
    the currents) over each slip, beside one floor of white noise per sample everywhere.  The
    recording holds ``beta`` times the signature."""
    from host_tools.analyzer.locate.episodes import SLIP_UNC
    t = np.arange(0.0, dur_s, 1.0 / hz)
    blk = np.floor(t / 0.5 + 1e-9).astype(int)
    slip = blk % every == every // 2
    sign = np.where((blk // every) % 2 == 0, 1.0, -1.0)
    g = np.where(slip, sign, 0.05 * np.sin(2 * np.pi * t / 3.0))
    unc = np.where(slip, SLIP_UNC, 0.0)
    err = rng.standard_normal(blk.max() + 1)[blk] * slip_err * slip
    nom, stp = {}, {}
    for c in FIT:
        nom[c] = Channel(c, t, rng.standard_normal(t.size), np.zeros(t.size), "u", unc=unc)
        stp[c] = Channel(c, t, np.zeros(t.size), np.zeros(t.size), "u", unc=unc)
    for (r, l), s, e in ((("omega_r", "omega_l"), g, err),
                         (("current_r_a", "current_l_a"), -0.5 * g, -0.5 * err)):
        d = beta * s + e + rng.standard_normal(t.size)
        nom[r].rec = d / np.sqrt(2)
        nom[l].rec = -d / np.sqrt(2)
        stp[r].sim = s / np.sqrt(2)
        stp[l].sim = -s / np.sqrt(2)
    return [nom], [stp]


def test_slip_blocks_with_their_own_error_alarm_at_most_at_the_stated_rate():
    """Nulls whose pinned slips carry the signature and several times the other blocks' error:
    the slips' blocks get a covariance of their own (and the test the degrees of freedom of
    their count), so the share flagged stays within the test's share of BIAS_ALPHA.  With one
    covariance for all blocks those few slips counted as that many ordinary blocks (about a
    third of these nulls flagged, as heldback20's truth-engine hard-reversal null was)."""
    rng = np.random.default_rng(20)
    trials = 200
    alarms = 0
    for _ in range(trials):
        nominal, stepped = _slip_runs(rng, 0.0)
        res = imbalance_test(nominal, stepped, FLOORS, N_TESTS, min_floors=0.0)
        assert res is not None and res["blocks"] == 60
        alarms += bool(res["significant"])
    # binomial(200, 0.001) exceeds 2 with probability 1e-3 (one covariance: 17 of 200)
    assert alarms <= 2, alarms
    assert res["slip_blocks"] == 15


def test_an_imbalance_carried_by_slips_is_still_found():
    """A 15 % imbalance on the same runs (the slips' own error half a floor, several times the
    block means' noise elsewhere): found in each, its ratio within 0.04 (the slips' error moves
    it)."""
    step = 1.0 + 1.5 * (IMBALANCE_STEP - 1.0)
    for seed in range(10):
        nominal, stepped = _slip_runs(np.random.default_rng(100 + seed), 1.5, slip_err=0.5)
        res = imbalance_test(nominal, stepped, FLOORS, N_TESTS)
        assert res is not None and res["slip_blocks"] == 15
        assert res["significant"] and abs(res["ratio"] - step) < 0.04, res
