"""The white part of a channel's residual over runs too short for an estimate of their own (a
2 Hz camera over 2 s runs: three or four frames each, heldback24's `hb24_tr_stribeck`): the
runs' second differences pooled (locate.floors.pooled_hf_noise_std).  Each run alone gave
nothing and counted as nil noise, so the camera's floor stayed at its 0.2 mm / 2 mrad base
while the frames scattered by 1 mm / 10 mrad, and its channels read 2.4-3 noise floors
whatever the model."""
from __future__ import annotations

import numpy as np

from host_tools.analyzer import signals as sg
from host_tools.analyzer.locate.floors import HF_MIN_SAMPLES, pooled_hf_noise_std


def test_short_runs_pool_their_second_differences():
    rng = np.random.default_rng(3)
    runs = [rng.normal(0.0, 1e-3, n) for n in [3, 4, 4, 4] * 10]
    assert all(sg.hf_noise_std(r) == 0.0 for r in runs)   # no run gives one on its own
    est = pooled_hf_noise_std(runs)
    assert 0.7e-3 < est < 1.3e-3, est


def test_a_run_without_an_estimate_does_not_count_as_nil_noise():
    rng = np.random.default_rng(4)
    long = rng.normal(0.0, 1e-3, 400)
    short = rng.normal(0.0, 1e-3, HF_MIN_SAMPLES - 1)
    assert pooled_hf_noise_std([long, short]) == sg.hf_noise_std(long)
    assert pooled_hf_noise_std([long, long]) == sg.hf_noise_std(long)


def test_too_few_differences_give_nothing():
    assert pooled_hf_noise_std([np.array([0.0, 1.0]), np.array([2.0, 0.5])]) == 0.0
    assert pooled_hf_noise_std([]) == 0.0
