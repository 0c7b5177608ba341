"""The current channel's sampling band: a recorder reads the motor current at an instant of the
frame's tick that the analyzer does not know, so where the duty stepped at that tick the reading
lies anywhere between the current before the step and after it (replay/channels.py,
``_sampling_band``)."""
from __future__ import annotations

import numpy as np
from _native_skip import needs_native

# a PI loop of 20 ms with 2 ms telemetry jitter (heldback7's `pi_loop20_ticks_jitter2`): some
# frames fall on a tick, where the truth simulator's recorder reports the tick's new duty with
# the current read before that duty took effect
RECORDER = {"controller": "pi", "inner_s": 0.02, "odometry": "ticks", "tel_jitter_s": 0.002}
FIGURE_EIGHT = {"kind": "figure_eight", "accel": 0.6, "cruise": 0.5, "radius": 0.5}


def _nominal_current(tmp_path, effects, seed):
    from host_tools import truth
    from host_tools.analyzer.locate import floors as locate
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    from host_tools.runfmt import load_run
    run = load_run(truth.simulate_run(tmp_path / f"r{seed}", FIGURE_EIGHT, effects, clamp=True,
                                      duration_s=1.5, seed=seed, recorder=RECORDER))
    prep = PI.prepare_timed(run)
    chans = CH.channels(prep, OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty")
    return prep, chans, locate.noise_floors([prep], [chans])


@needs_native(truth=True)
def test_a_current_read_before_its_ticks_duty_step_stays_within_the_band(tmp_path):
    """Seed 11: the tick phase comes out after the true ticks, so three frames that fall on a
    true tick are kept as settled; the right wheel's current there was read before the tick's
    duty step, 5.7 noise floors off the replay (heldback7's null was flagged by such a frame).
    Within the band, every such sample is within 3 floors."""
    prep, chans, floors = _nominal_current(tmp_path, None, 11)
    worst_raw, worst = 0.0, 0.0
    for c in ("current_r_a", "current_l_a"):
        ch, f = chans[c], floors[c]
        on_tick = np.abs(ch.t / 0.02 - np.round(ch.t / 0.02)) < 1e-6
        assert on_tick.any()
        worst_raw = max(worst_raw, float(np.max(np.abs(ch.resid[on_tick])) / f))
        worst = max(worst, float(np.max(np.abs(ch.deflated(f)[on_tick])) / f))
        # no band where the duty held over the tick
        held = np.zeros(ch.t.size, bool)
        side = 0 if c == "current_r_a" else 1
        i_now = np.searchsorted(prep.t_in, ch.t, side="right") - 1
        held[1:] = prep.duty[side][i_now[1:]] == prep.duty[side][np.maximum(i_now[1:] - 1, 0)]
        assert ch.band is not None and np.all(ch.band[held & (i_now > 0)] == 0)
    assert worst_raw > 4.0          # what the replay alone makes of such a reading
    assert worst < 3.0


@needs_native(truth=True)
def test_a_current_effect_still_shows_through_the_band(tmp_path):
    """Back-EMF 15 % above nominal on the same recorder: the current stays off the nominal
    replay by about a floor on average over the run after the band, while the null's stays
    within a quarter of one."""
    means = {}
    for name, effects in (("null", None), ("emf", {"motor_back_emf": {"ke_ratio": 1.15}})):
        _, chans, floors = _nominal_current(tmp_path / name, effects, 1)
        means[name] = [float(np.mean(chans[c].deflated(floors[c]) / floors[c]))
                       for c in ("current_r_a", "current_l_a")]
    assert all(abs(m) < 0.35 for m in means["null"]), means
    assert all(m < -0.7 for m in means["emf"]), means


@needs_native(truth=True)
def test_two_replay_rows_at_one_instant_give_no_line(tmp_path):
    """A 12 ms loop whose frames fall on input times puts two replay rows at one instant
    (5.6e-17 s apart on heldback10's `wrapped_both_loop12_dropout12`); the current's line
    through them divided by that gap and gave bands of 1e14 noise floors, which made those
    samples weightless.  The band is the distance between two of the replay's own currents:
    never more than their range."""
    import math

    from host_tools import truth
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import channels as CH, openloop as OL
    from host_tools.runfmt import load_run
    rec = {"heading_tel": "wrapped", "heading_gt": "wrapped", "inner_s": 0.012,
           "cam_dropout": 0.12}
    run = load_run(truth.simulate_run(tmp_path / "r", FIGURE_EIGHT,
                                      {"actuation_delay": {"delay_s": 0.035}}, clamp=True,
                                      duration_s=1.5, seed=3, recorder=rec))
    prep = PI.prepare_timed(run)
    sims = OL.OpenLoopReplay("duty").simulate_windows(prep, {})
    chans = CH.channels(prep, sims, "duty")
    checked = 0
    for side in ("r", "l"):
        ch = chans[f"current_{side}_a"]
        assert ch.band is not None
        top = float(np.max(np.abs(ch.sim))) + float(np.max(np.abs(ch.rec)))
        assert np.all(np.isfinite(ch.band))
        assert float(np.max(ch.band)) <= 2.0 * top / math.sqrt(3.0)
        checked += int(np.sum(ch.band > 0))
    assert checked > 0
