"""Unit tests of the analyzer's physics-free pieces: noise floors, windows, regimes,
sparse regression, input-time reconstruction."""
from __future__ import annotations

import numpy as np
import pytest
from _native_skip import needs_native

from host_tools import params
from host_tools.analyzer import signals as sg
from host_tools.analyzer.prepare.timing import reconstruct_input_times


@pytest.mark.parametrize("seed", range(5))
def test_hf_noise_std_ignores_smooth_mismatch(seed):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1.5, 400)
    drift = 5.0 * np.sin(2 * t) + 3 * t ** 2  # large, smooth
    r = drift + rng.normal(0, 0.2, t.size)
    assert sg.hf_noise_std(r) == pytest.approx(0.2, rel=0.2)
    assert sg.robust_std(r) > 1.0  # the plain spread would be fooled


def test_quantization_std():
    # difference of two uniform quantization errors of step q: std q/sqrt(6)
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 100, 200000)
    y = x + rng.uniform(0, 5, x.size)
    d = (np.floor(y) - np.floor(x)) - (y - x)
    assert np.std(d) == pytest.approx(sg.quantization_std(1.0), rel=0.02)


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("dt_s,span_s", [(0.02, 1.5), (0.1, 3.0)])
def test_no_window_on_pure_noise(seed, dt_s, span_s):
    """Nor on a channel sampled slower than the merge gap (a 10 Hz camera)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, span_s, dt_s)
    w, m = sg.significant_windows(t, rng.normal(0, 1.0, t.size), 1.0)
    assert w == [] and not m.any()


def test_window_found_where_the_bump_is():
    rng = np.random.default_rng(1)
    t = np.arange(0, 1.5, 0.02)
    r = rng.normal(0, 1.0, t.size)
    r[(t > 0.6) & (t < 0.9)] += 4.0
    w, m = sg.significant_windows(t, r, 1.0)
    assert len(w) == 1
    assert 0.55 <= w[0].t_start_s <= 0.66 and 0.84 <= w[0].t_end_s <= 0.95
    assert w[0].rms > 3


@pytest.mark.parametrize("dt_s", [0.065, 0.1, 0.15])
def test_window_found_on_a_slowly_sampled_channel(dt_s):
    """A channel sampled slower than the merge gap (65 ms telemetry, a 10 Hz camera): a
    sustained offset of 5 floors is one window, not one window per sample, each too short to
    count (heldback16's friction case with 65 ms telemetry and a 10 Hz camera: no window at
    all where the camera's x stood 60 floors off)."""
    rng = np.random.default_rng(2)
    t = np.arange(0, 3.0, dt_s)
    r = rng.normal(0, 1.0, t.size)
    r[(t > 1.0) & (t < 2.0)] += 5.0
    w, m = sg.significant_windows(t, r, 1.0)
    assert len(w) == 1
    # within the smoothing span (2 samples either side) of the offset's edges
    assert abs(w[0].t_start_s - 1.0) <= 2 * dt_s + 1e-9
    assert abs(w[0].t_end_s - 2.0) <= 2 * dt_s + 1e-9
    assert w[0].rms > 3 and m.sum() >= 3


def test_best_regime_finds_speed_threshold():
    t = np.linspace(0, 1.5, 200)
    w = 30 * np.clip(t / 0.75, 0, 1)
    state = {"t": t, "w_r": w, "w_l": w, "a_r": np.gradient(w, t), "a_l": np.gradient(w, t),
             "tau_r": np.full_like(t, 0.05), "tau_l": np.full_like(t, 0.05),
             "u_r": w / 36, "u_l": w / 36, "yaw": np.zeros_like(t)}
    mask = w > 18
    reg = sg.best_regime(mask, sg.regime_candidates(state, tau_max=0.09))
    assert reg.description.startswith("wheel speed above")
    thr = float(reg.description.split()[3])
    assert 15 <= thr <= 21 and reg.score > 0.9


def test_best_regime_finds_turns_and_torque_limit():
    t = np.linspace(0, 1.5, 200)
    turning = (t > 0.5) & (t < 1.0)
    straight = np.where(t < 0.5, 8.0, 14.0)  # speeds alone cannot single out the turn
    w_r = np.where(turning, 12.0, straight)
    w_l = np.where(turning, 8.0, straight)
    tau = np.where(t < 0.3, 0.12, 0.04)
    state = {"t": t, "w_r": w_r, "w_l": w_l, "a_r": np.zeros_like(t), "a_l": np.zeros_like(t),
             "tau_r": tau, "tau_l": tau, "u_r": w_r / 36, "u_l": w_l / 36,
             "yaw": params.ROBOT["r"] * (w_r - w_l) / (2 * params.ROBOT["b"])}
    cands = sg.regime_candidates(state, tau_max=0.09)
    assert sg.best_regime(turning, cands).description == "only in turns"
    assert "exceeds tau_max" in sg.best_regime(tau > 0.09, cands).description
    assert sg.best_regime(np.zeros_like(turning), cands) is None


def test_stlsq_recovers_sparse_law():
    rng = np.random.default_rng(3)
    n = 500
    X = rng.normal(size=(n, 6))
    y = 2.0 * X[:, 1] - 0.5 * X[:, 4] + rng.normal(0, 0.01, n)
    names = [f"f{i}" for i in range(6)]
    terms = sg.stlsq(X, y, names)
    assert set(terms) == {"f1", "f4"}
    assert terms["f1"] == pytest.approx(2.0, rel=0.02)
    assert terms["f4"] == pytest.approx(-0.5, rel=0.05)


@pytest.mark.parametrize("phase", [0.0, 0.007, 0.019])
def test_reconstruct_input_times(phase):
    period, dt = 0.025, 0.02
    t = np.round(np.arange(0, 1.0, dt), 9)
    ticks = np.round(phase + np.arange(0, 1.1, period), 9)
    vals = np.arange(ticks.size, dtype=float)  # changes at every tick
    seen = vals[np.searchsorted(ticks, t, side="right") - 1].copy()
    seen[t < phase] = -1.0
    eff = reconstruct_input_times(t, [seen], period)
    ch = np.flatnonzero(np.diff(seen) != 0) + 1
    true_tick = ticks[np.searchsorted(ticks, t[ch], side="right") - 1]
    # the data pin the loop phase down to a few ms; the frame times are up to 20 ms late
    err = np.abs(eff[ch] - true_tick)
    assert err.max() <= 0.2 * period
    assert err.mean() < 0.5 * np.abs(t[ch] - true_tick).mean()
    # frames without a change keep their own time
    same = np.setdiff1d(np.arange(t.size), ch)
    np.testing.assert_array_equal(eff[same], t[same])


def test_reconstruct_input_times_falls_back_when_inconsistent():
    t = np.round(np.arange(0, 1.0, 0.02), 9)
    v = np.arange(t.size, dtype=float)  # changes every frame: faster than a 25 ms loop
    np.testing.assert_array_equal(reconstruct_input_times(t, [v], 0.025), t)


def test_significant_windows_of_a_channel_with_too_few_samples():
    """A channel left with fewer samples than the smoothing span (e.g. motor current whose
    frames all fall on the loop's ticks) has no window and no error."""
    for n in range(0, 5):
        w, m = sg.significant_windows(np.arange(n) * 0.02, np.full(n, 10.0), 0.1)
        assert w == [] and m.shape == (n,) and not m.any()


def test_quantization_step_of_an_adc_column():
    """The step of a magnitude-only current sense: long runs of exact zeros at rest, a few
    counts while driving, written with the file's rounding."""
    lsb = 5.0 / 1024 / 1.65
    rng = np.random.default_rng(4)
    raw = np.concatenate([np.zeros(300), np.round(40 + 3 * rng.normal(size=500)), np.zeros(200)])
    col = np.round(raw * lsb, 7)
    assert sg.quantization_step(col) == pytest.approx(lsb, rel=1e-3)
    assert sg.quantization_step(rng.normal(size=500)) == 0.0    # not quantized
    assert sg.quantization_step(np.zeros(50)) == 0.0


@needs_native(truth=True)
def test_current_floor_is_at_least_one_adc_count(tmp_path):
    """A run that rests a good part of the time, with a noiseless ADC: the current residual's
    MAD of second differences is well below a count (it had made a floor of 0.4 count), and a
    reading two counts off at rest would stand out of it.  The count comes from meta.json's
    current sense, or from the column's quantization step when the meta does not say."""
    from host_tools import truth
    from host_tools.analyzer.locate import floors as locate_floors
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    from host_tools.runfmt import load_run
    ref = {"kind": "segments", "accel": 0.5, "alpha": 2.0,
           "segments": [{"duration_s": 1.0}, {"duration_s": 1.5, "v": 0.3}, {"duration_s": 2.0}]}
    run = load_run(truth.simulate_run(tmp_path / "r", ref, None, clamp=True, duration_s=4.5,
                                      seed=3, recorder={"adc_noise_lsb": 0.0}))
    cs = truth.CURRENT_SENSE
    count = cs["adc_vref_v"] / 2 ** cs["adc_bits"] / cs["volts_per_amp"]
    assert np.mean(run.telemetry["current_r_a"] == 0) > 0.2
    prep = PI.prepare_timed(run)
    ch = CH.channels(prep, OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty")
    assert sg.hf_noise_std(ch["current_r_a"].resid) < 0.7 * count
    for meta_says in (True, False):
        if not meta_says:
            del run.meta["current_sense"]
        floors = locate_floors.noise_floors([prep], [ch])
        assert floors["current_r_a"] >= count * (1 - 1e-3), meta_says
        assert floors["current_l_a"] >= count * (1 - 1e-3), meta_says


@needs_native(truth=True)
def test_current_floor_is_the_adc_noise_where_the_current_flows(tmp_path):
    """A run that rests most of the time, read by a noisy magnitude-only ADC (7 LSB): at rest
    the ADC's noise is clipped at 0 counts, so the residual's MAD of second differences over all
    samples is about half the noise (0.52 sigma at nil current), and a flowing current's
    readings, whose noise is the ADC's whole sigma, stood out of that floor two or three times
    (heldback27's truth tour null).  The floor is the noise where the replayed current clears
    the clipping."""
    from host_tools import truth
    from host_tools.analyzer.locate import floors as locate_floors
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    from host_tools.runfmt import load_run
    ref = {"kind": "segments", "accel": 0.6, "alpha": 2.0,
           "segments": [{"duration_s": 2.0}, {"duration_s": 2.5, "v": 0.45},
                        {"duration_s": 4.0}, {"duration_s": 2.5, "v": 0.45}, {"duration_s": 3.0}]}
    run = load_run(truth.simulate_run(tmp_path / "r", ref, None, clamp=True, duration_s=14.0,
                                      seed=3, recorder={"adc_noise_lsb": 7.0}))
    cs = truth.CURRENT_SENSE
    sigma = 7.0 * cs["adc_vref_v"] / 2 ** cs["adc_bits"] / cs["volts_per_amp"]
    prep = PI.prepare_timed(run)
    ch = CH.channels(prep, OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty")
    for side in ("r", "l"):   # over all samples: the clipped rest's spread (0.64-0.68 sigma)
        assert sg.hf_noise_std(ch[f"current_{side}_a"].resid) < 0.75 * sigma, side
    floors = locate_floors.noise_floors([prep], [ch])
    for side in ("r", "l"):
        assert floors[f"current_{side}_a"] == pytest.approx(sigma, rel=0.2), side
