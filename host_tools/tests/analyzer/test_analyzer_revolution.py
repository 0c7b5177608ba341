"""The once-per-revolution test (host_tools/analyzer/locate/revolution.py): a wheel speed's
residual regressed on cos/sin of its own wheel's angle, with a phase per run, the residual's
serial correlation (block scores), the model's tolerance on the same regressors and the
consistent-bias test's false-alarm share."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from _native_skip import needs_native

from host_tools.analyzer.locate.bias import BIAS_ALPHA, bias_test
from host_tools.analyzer.locate.revolution import REV_CHANNELS, revolution_of
from host_tools.analyzer.replay.channels import Channel

PPR = 1440
HZ = 50.0


def _run(rng, amp: float, phase: float, *, noise: float = 1.0, wander: float = 0.0,
         dur_s: float = 3.0, w_max: float = 12.0):
    """(a prepared-run stand-in with its counts, its wheel-speed channels, floors 1): both
    wheels ramp to ``w_max`` rad/s and cruise; the recorded speed carries ``amp`` floors of
    cos(wheel angle + ``phase``), white noise of ``noise`` floors and an AR(1) wander (lag-1
    0.9 per sample) of ``wander`` floors."""
    t = np.arange(0.0, dur_s, 1 / HZ)
    w = np.clip(t / 0.8, 0, 1) * w_max
    theta = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
    k = 2 * math.pi / PPR
    tel = {"t_s": t}
    chans = {}
    for side in ("r", "l"):
        enc = np.floor(theta / k)
        tel[f"enc_{side}"] = enc
        th_mid = 0.5 * (enc[1:] + enc[:-1]) * k
        e = np.zeros(t.size - 1)
        if wander:
            a = rng.normal(0, wander * math.sqrt(1 - 0.81), t.size - 1)
            for i in range(1, a.size):
                e[i] = 0.9 * e[i - 1] + a[i]
        rec = w[1:] + amp * np.cos(th_mid + phase) + rng.normal(0, noise, t.size - 1) + e
        chans[f"omega_{side}"] = Channel(f"omega_{side}", t[1:], rec, w[1:], "rad/s")
    prep = SimpleNamespace(run=SimpleNamespace(telemetry=tel), ppr=PPR, name="run")
    return prep, chans


FLOORS = {"omega_r": 1.0, "omega_l": 1.0}


def _test(runs, n_tests: int = 10, cache=None, alpha: float | None = None):
    preps = [p for p, _ in runs]
    chans = [c for _, c in runs]
    # an empty tolerance (draws that leave the replay as it is) unless given: no replays here
    cache = {"d": {c: [[np.zeros(ch[c].t.size) for ch in chans]] for c, _ in REV_CHANNELS}} \
        if cache is None else cache
    if alpha is None:
        return revolution_of(preps, chans, FLOORS, 5e-4, n_tests, cache=cache)
    import host_tools.analyzer.locate.revolution as rv
    from unittest import mock
    with mock.patch.object(rv, "BIAS_ALPHA", alpha), \
            mock.patch.object(rv.revolution_test, "__defaults__",
                              (alpha,) + rv.revolution_test.__defaults__[1:]):
        return revolution_of(preps, chans, FLOORS, 5e-4, n_tests, cache=cache)


def test_a_zero_mean_term_below_every_window_is_found_where_the_bias_test_sees_nothing():
    rng = np.random.default_rng(1)
    runs = [_run(rng, 1.2, ph) for ph in (0.3, 2.0, 4.1)]
    out = _test(runs)
    for c in ("omega_r", "omega_l"):
        assert out[c]["significant"], out[c]
        assert 0.9 < out[c]["amplitude_floors"] < 1.5
    bias = bias_test([c for _, c in runs], FLOORS, ["omega_r", "omega_l"])
    assert not any(v["significant"] for v in bias.values())


def test_each_run_has_its_own_phase():
    """Opposite phases in two runs cancel in a pooled regression; the per-run phases find it."""
    rng = np.random.default_rng(2)
    out = _test([_run(rng, 1.2, 0.0), _run(rng, 1.2, math.pi)])
    assert out["omega_r"]["significant"] and out["omega_r"]["runs"] == 2


def test_nulls_with_serially_correlated_residuals_alarm_at_most_at_the_stated_rate():
    """A slow wander (lag-1 0.9 per sample) on top of white noise: the block scores carry its
    variance at the regressors, so the false-alarm rate stays near alpha; treated as white
    noise the same residuals alarm far more often."""
    rng = np.random.default_rng(3)
    alpha, n = 0.1, 150
    alarms = naive = 0
    for _ in range(n):
        runs = [_run(rng, 0.0, 0.0, noise=0.3, wander=1.0) for _ in range(3)]
        out = _test(runs, n_tests=1, alpha=alpha)["omega_r"]
        alarms += out["F"] > out["F_threshold"]
        # the same regression with the white-noise variance of the residual
        from host_tools.analyzer.locate.revolution import _design, wheel_angle
        from scipy import stats
        stat = ss = dof = 0.0
        for p, ch in runs:
            X, z, _, _ = _design(ch["omega_r"], wheel_angle(p, ch["omega_r"], "enc_r"), 1.0)
            beta = np.linalg.lstsq(X, z, rcond=None)[0]
            stat += float(beta @ X.T @ X @ beta)
            ss += float(np.sum((z - X @ beta) ** 2))
            dof += z.size - 3
        naive += stat / 6 / (ss / dof) > stats.f.ppf(1 - alpha, 6, dof)
    assert alarms <= 2 * alpha * n, alarms
    assert naive > 3 * alpha * n, naive


def test_a_term_within_the_models_tolerance_is_not_a_mismatch():
    """The same term is a mismatch where the tolerance's draws leave the replay alone, and none
    where they could put as large a term on the same regressors (the draws are one parameter
    set for all the runs, so the term they allow is the same in each; the recorded one is)."""
    rng = np.random.default_rng(4)
    runs = [_run(rng, 1.2, 0.3) for _ in range(3)]
    assert _test(runs)["omega_r"]["significant"]
    draws = []
    for j in range(8):
        row = []
        for p, ch in runs:
            c = ch["omega_r"]
            i = np.clip(np.searchsorted(p.run.telemetry["t_s"], c.t), 1, c.t.size)
            th = 0.5 * (p.run.telemetry["enc_r"][i] + p.run.telemetry["enc_r"][i - 1]) \
                * 2 * math.pi / PPR
            row.append(1.5 * math.sqrt(2) * np.cos(th + 0.8 * j))
        draws.append(row)
    out = _test(runs, cache={"d": {"omega_r": draws, "omega_l": draws}})
    assert not out["omega_r"]["significant"]
    assert out["omega_r"]["tolerance_amplitude_floors"] > 1.5


def test_a_tiny_term_is_not_a_mismatch_however_significant():
    rng = np.random.default_rng(5)
    out = _test([_run(rng, 0.4, ph, noise=0.05) for ph in (0.3, 2.0)])["omega_r"]
    assert out["F"] > 10 * out["F_threshold"]
    assert out["rms_floors"] < 0.5 and not out["significant"]


def test_a_wheel_that_does_not_turn_is_left_out():
    rng = np.random.default_rng(6)
    out = _test([_run(rng, 0.0, 0.0, w_max=0.0)])
    assert out == {}


def test_the_share_counts_the_once_per_revolution_tests():
    """With more tests in the share the threshold rises: the family-wise rate is shared."""
    rng = np.random.default_rng(7)
    runs = [_run(rng, 0.0, 0.0) for _ in range(3)]
    assert _test(runs, n_tests=12)["omega_r"]["F_threshold"] > \
        _test(runs, n_tests=3)["omega_r"]["F_threshold"]
    assert _test(runs, n_tests=12)["omega_r"]["tests"] == 12
    assert BIAS_ALPHA > 0


# the recorder of heldback16's eccentric case: telemetry jitter and ADC noise hide every window
RECORDER = {"tel_jitter_s": 0.0065, "adc_noise_lsb": 2.3, "cam_hz": 150.0}
REFS = [{"kind": "line", "accel": 1.0, "cruise": 0.6},
        {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.6},
        {"kind": "figure_eight", "accel": 0.6, "cruise": 0.5, "radius": 0.5}]


def _truth_report(tmp_path, effects):
    import json

    from host_tools import truth
    from host_tools.__main__ import main as cli
    runs = [truth.simulate_run(tmp_path / f"run-{i}", ref, effects, clamp=True, duration_s=3.0,
                               seed=40 + i, recorder=RECORDER) for i, ref in enumerate(REFS)]
    out = tmp_path / "out"
    assert cli(["analyze", *runs, "--out", str(out), "--jobs", "1", "--no-plots"]) == 0
    return json.load(open(out / "report.json"))


@needs_native(truth=True)
def test_an_eccentric_wheel_under_jitter_and_adc_noise_is_an_unexplained_mismatch(tmp_path):
    rep = _truth_report(tmp_path, {"eccentric_wheel": {"eps": 0.03}})
    assert rep["verdict"] == "unexplained"
    assert any("once per revolution" in n for n in rep["notes"])


@needs_native(truth=True)
def test_the_same_runs_without_the_eccentric_wheel_stay_a_null(tmp_path):
    rep = _truth_report(tmp_path, {})
    assert rep["verdict"] == "no_mismatch"
    assert not any("once per revolution" in n for n in rep["notes"])
