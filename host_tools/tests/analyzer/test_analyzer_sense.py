"""The motor-current sense reads |I| through an ADC that reads no negative counts: near nil its
noise is clipped at 0 and a reading is sigma / sqrt(2 pi) high on average.  A current channel
replays that mean reading (``signals.clipped_reading_mean``, with the channel's noise floor as
sigma: ``locate.mismatch.with_sense_noise``), so that a run resting most of its time is not a
bias over many samples."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from _native_skip import needs_native


@pytest.mark.parametrize("sigma_counts", [1.0, 3.0, 11.0])
def test_the_mean_reading_is_the_adcs(sigma_counts: float) -> None:
    """Against the ADC itself (Gaussian noise, rounded to counts, none below 0), 400,000 draws
    per level: within 0.02 sigma from nil to five sigma; sigma / sqrt(2 pi) at nil; the level
    itself far above the noise and without noise."""
    from host_tools.analyzer import signals as sg
    rng = np.random.default_rng(7)
    s = sigma_counts
    for m in (0.0, 0.3 * s, s, 2 * s, 5 * s):
        adc = np.clip(np.round(m + rng.normal(0.0, s, 400_000)), 0, None).mean()
        model = float(sg.clipped_reading_mean(np.array([m]), s)[0])
        assert abs(adc - model) < 0.02 * s, (s, m, adc, model)
    assert float(sg.clipped_reading_mean(np.array([0.0]), s)[0]) == pytest.approx(
        s / math.sqrt(2 * math.pi), rel=1e-12)
    assert float(sg.clipped_reading_mean(np.array([20 * s]), s)[0]) == pytest.approx(20 * s,
                                                                                      rel=1e-12)
    m = np.array([0.0, 0.5, 2.0])
    assert np.array_equal(sg.clipped_reading_mean(m, 0.0), m)


@needs_native(truth=True)
@pytest.mark.parametrize("seed", [3, 4])
def test_a_resting_run_read_by_a_noisy_sense_is_not_biased_at_rest(tmp_path: Path,
                                                                   seed: int) -> None:
    """A 14 s run that rests 9 s of it, its currents read with 11 LSB of ADC noise (heldback36's
    truth tour null: 80 % of its samples near nil): at the samples whose replayed |I| is within
    half a floor of nil the residual of |I| is 0.3-0.4 floors high on average (the clipped
    noise), that of the mean reading within 0.1 floors of nil; the noise taken is the
    channel's floor, which here is the ADC's (its noise where the current flows)."""
    from host_tools import truth
    from host_tools.analyzer import pipeline as PL
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    ref = {"kind": "segments", "accel": 0.6, "alpha": 2.0,
           "segments": [{"duration_s": 2.0}, {"duration_s": 2.5, "v": 0.45},
                        {"duration_s": 4.0}, {"duration_s": 2.5, "v": 0.45}, {"duration_s": 3.0}]}
    path = truth.simulate_run(tmp_path / "r", ref, None, clamp=True, duration_s=14.0, seed=seed,
                              recorder={"adc_noise_lsb": 11.0})
    fr = PL.front([path])
    prep, floors = fr.preps[0], fr.loc.floors
    cs = truth.CURRENT_SENSE
    sigma = 11.0 * cs["adc_vref_v"] / 2 ** cs["adc_bits"] / cs["volts_per_amp"]
    assert prep.sense_noise_a == (floors["current_r_a"], floors["current_l_a"])
    raw = CH.channels(dataclasses.replace(prep, sense_noise_a=None),
                      OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty")
    for c in ("current_r_a", "current_l_a"):
        f = floors[c]
        assert f == pytest.approx(sigma, rel=0.2), c
        rest = np.abs(raw[c].sim) < 0.5 * f
        assert rest.sum() > 400, c
        assert np.array_equal(raw[c].t, fr.nominal[0][c].t)
        assert raw[c].resid[rest].mean() / f > 0.25, c
        assert abs(fr.nominal[0][c].resid[rest].mean() / f) < 0.1, c
        # where the current flows the replay is |I| as it was
        flow = np.abs(raw[c].sim) > 3 * f
        assert flow.sum() > 20
        assert np.allclose(fr.nominal[0][c].sim[flow], raw[c].sim[flow], rtol=1e-3)
