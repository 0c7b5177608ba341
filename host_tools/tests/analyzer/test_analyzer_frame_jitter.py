"""Wheel speeds from frames of uneven spacing: the speed channel is a count difference over each
frame's own interval, off by up to a count whatever the interval, so a frame that follows its
neighbour closely reads a coarse speed; the noise floor holds the quantization at the median
interval, and the excess rides along as a per-sample spread (``signals.count_rate_band``,
``replay/channels.py``'s wheel channels)."""
from __future__ import annotations

import math

import numpy as np
from _native_skip import needs_native

from host_tools import params
from host_tools.analyzer import signals as sg
from host_tools.analyzer.replay.channels import Channel

PPR = params.ENCODER_PPR
COUNT = 2 * math.pi / PPR
# heldback22's `jitter90_adc50_cam205`: 20 ms frames, each moved uniformly by up to +-9 ms
JITTER_S, FRAME_S = 0.009, 0.02


def _jittered_frames(rng: np.random.Generator, duration_s: float) -> np.ndarray:
    t = np.arange(FRAME_S, duration_s, FRAME_S) + rng.uniform(-JITTER_S, JITTER_S,
                                                              int(duration_s / FRAME_S) - 1)
    return np.sort(np.round(t, 4))


def test_the_band_is_nil_for_regular_frames_and_the_quantization_excess_otherwise():
    dt = np.array([0.004, 0.01, 0.02, 0.03])
    band = sg.count_rate_band(dt, 0.02, COUNT)
    q = COUNT / dt / math.sqrt(6.0)
    assert band[2] == 0.0 and band[3] == 0.0
    np.testing.assert_allclose(band[:2], np.sqrt(q[:2] ** 2 - q[2] ** 2))
    assert not sg.count_rate_band(np.full(5, 0.02), 0.02, COUNT).any()


def test_a_quantized_wheel_under_frame_jitter_reads_one_floor_in_every_interval():
    """A wheel accelerating at 57 rad/s^2 seen through the table's encoder at jittered frame
    times, against its exact speed: the count-difference speed's error is about 1/sqrt(6)
    counts per interval, so in rad/s it grows as the interval shrinks; with the floor at the
    median interval the frames under 8 ms apart read several floors, the band brings every
    interval back to about one."""
    rng = np.random.default_rng(5)
    t = _jittered_frames(rng, 60.0)
    theta = 0.5 * 57.0 * (t % 3.0) ** 2 + 17.0 * t     # ramps, always forward
    enc = np.floor(theta / COUNT)
    dt = np.diff(t)
    rec = np.diff(enc) * COUNT / dt
    sim = np.diff(theta) / dt
    floor = sg.quantization_std(COUNT / float(np.median(dt)))
    ch = Channel("omega_l", t[1:], rec, sim, "rad/s",
                 band=sg.count_rate_band(dt, float(np.median(dt)), COUNT))
    raw, z = ch.resid / floor, ch.deflated(floor) / floor
    short, rest = dt < 0.008, dt >= 0.008
    assert short.sum() > 100
    assert np.sqrt(np.mean(raw[short] ** 2)) > 3.0      # without the band
    for sel in (short, rest):
        assert 0.85 < np.sqrt(np.mean(z[sel] ** 2)) < 1.15
    assert np.max(np.abs(z)) < 3.0


LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}


def _speed_channels(tmp_path, effects, seed):
    from host_tools import truth
    from host_tools.analyzer.locate import floors as locate
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    from host_tools.runfmt import load_run
    run = load_run(truth.simulate_run(tmp_path / f"r{seed}", LINE, effects, clamp=True,
                                      duration_s=3.0, seed=seed,
                                      recorder={"tel_jitter_s": JITTER_S}))
    prep = PI.prepare_timed(run)
    chans = CH.channels(prep, OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty")
    return run.telemetry["t_s"], chans, locate.noise_floors([prep], [chans])


@needs_native(truth=True)
def test_a_null_under_frame_jitter_stays_within_the_floors(tmp_path):
    """The truth simulator's line run (heldback22's `hb22_tr_null_std`, first run) with +-9 ms
    frame jitter, seed 2: a frame 3-5 ms after its neighbour reads a wheel speed 4.5 floors
    off the nominal replay; with the band, no sample reaches 3 and the band is nil on every
    interval at or above the median."""
    t_all, chans, floors = _speed_channels(tmp_path, None, 2)
    dt_med = float(np.median(np.diff(t_all)))
    for c in ("omega_r", "omega_l"):
        ch, f = chans[c], floors[c]
        assert np.max(np.abs(ch.resid)) / f > 4.0
        assert np.max(np.abs(ch.deflated(f))) / f < 3.0
        i = np.searchsorted(t_all, ch.t)
        dt = t_all[i] - t_all[i - 1]
        assert ch.band is not None and np.all(ch.band[dt >= dt_med] == 0)
        assert np.all(ch.band[dt < 0.01] > 0)


@needs_native(truth=True)
def test_a_back_emf_two_percent_high_still_shows_under_frame_jitter(tmp_path):
    """Back-EMF 2 % above nominal on the same recorder and seed: its strongest window of the
    wheel speeds stays above 3 floors with the band (3.6; 4.0 without)."""
    _, chans, floors = _speed_channels(tmp_path, {"motor_back_emf": {"ke_ratio": 1.02}}, 2)
    ch, f = chans["omega_r"], floors["omega_r"]
    wins, _ = sg.significant_windows(ch.t, ch.deflated(f), f)
    assert max(w.rms for w in wins) / f > 3.0
