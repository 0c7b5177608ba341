"""Recordings whose inner loop is faster than the telemetry (a 10 ms loop seen at 50 Hz): half
the commands are never recorded. The analyzer finds the tick phase from the board's wheel
speeds (a cubic through the counts), fills the unreported ticks with the closed-loop replay's
pattern, and compares the camera against the count-anchored pose (docs/analyzer.md)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import truth  # noqa: E402

from host_tools import params  # noqa: E402
from host_tools.analyzer.prepare import inputs as PI  # noqa: E402
from host_tools.analyzer.prepare import timing as PT  # noqa: E402
from host_tools.analyzer.replay import anchors as AN  # noqa: E402
from host_tools.analyzer.replay import channels as CH  # noqa: E402
from host_tools.analyzer.replay import closedloop as CL  # noqa: E402
from host_tools.analyzer.replay import openloop as OL  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402
from host_tools.runfmt import load_run  # noqa: E402

ARC = {"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": 0.6}
WHEEL_R_M = params.ROBOT["r"]
SLIP = {"kind": "line", "accel": 72 * WHEEL_R_M, "cruise": 36 * WHEEL_R_M}
LOOP10 = {"inner_s": 0.010}


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _dense_truth(meta: dict) -> dict:
    """The same run's commands at every 10 ms tick: the truth simulator's controller is
    deterministic, so a telemetry period of one tick shows every command it gave."""
    ref = meta["reference"]
    sim = truth.TruthSim()
    sim.set("ref.kind", truth._REF_KINDS[ref["kind"]])
    for k in ("accel", "cruise", "radius"):
        if k in ref:
            sim.set(f"ref.{k}", ref[k])
    sim.set("ctl.clamp", 1.0 if meta["torque_clamp"] else 0.0)
    sim.set("sim.duration", meta["duration_s"])
    sim.set("sim.inner_period", 0.010)
    sim.set("sim.tel_period", 0.010)
    sim.set("sim.tel_phase", 0.0)
    tel, _ = sim.run()
    return tel


@pytest.fixture(scope="module")
def arc_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("fastloop")
    return load_run(truth.simulate_run(d / "run", ARC, None, clamp=True, duration_s=2.0,
                                       seed=31, recorder=LOOP10))


def test_phase_of_a_fast_loop_from_the_board_speeds(arc_run):
    """The truth simulator's ticks lie at board time 0, 10 ms, ...; with a straight line
    through the counts every phase would fit equally (the estimate was None)."""
    tel = arc_run.telemetry
    phase = PT.board_rate_phase(tel, 0.010, int(arc_run.meta["encoder_ppr"]))
    assert phase is not None
    err = min(phase % 0.010, 0.010 - phase % 0.010)
    assert err <= 0.0025, phase


def test_unreported_ticks_filled_closer_to_the_commands_given(arc_run):
    prep = PI.prepare(arc_run, 0.5, 0.0)
    seen = prep.seen_ticks
    assert seen is not None and 0.4 < seen.mean() < 0.6   # every other tick reported
    dense = _dense_truth(arc_run.meta)
    idx = np.searchsorted(dense["t_s"], prep.t_in + 1e-9) - 1
    given = [dense["pwm_r"][idx], dense["pwm_l"][idx]]
    # the reported ticks are the recorded values, exactly
    assert np.array_equal(prep.duty[0][seen], given[0][seen])
    t_un = prep.t_in[~seen]

    def bias():
        """Mean error of the filled ticks over 0.25 s blocks (what drifts an open-loop
        replay; single ticks' scatter averages out), RMS over the blocks and the wheels."""
        out = []
        for i in (0, 1):
            e = (prep.duty[i] - given[i])[~seen]
            out += [e[(t_un >= a) & (t_un < a + 0.25)].mean() for a in np.arange(0, 2.0, 0.25)]
        return _rms(out)
    line = bias()
    cl = CL.ClosedLoopReplay().simulate(prep, {})
    line_fill = prep
    prep, n = UN.fill_unseen_from_controller(prep, cl)
    # a new prepared run: the given one keeps the line's fill
    assert prep is not line_fill and not np.array_equal(line_fill.duty[0], prep.duty[0])
    in_cl = (prep.t_in >= cl["t_s"][0] - 1e-9) & (prep.t_in <= cl["t_s"][-1] + 1e-9)
    assert n == int((~seen & in_cl).sum()) > 0.4 * seen.size
    assert np.array_equal(prep.duty[0][seen], given[0][seen])
    assert bias() < 0.5 * line, (line, bias())


def test_count_anchored_pose_only_for_unreported_inputs(tmp_path, arc_run):
    prep = PI.prepare_timed(arc_run)
    assert prep.count_anchored_pose
    normal = load_run(truth.simulate_run(tmp_path / "fw", ARC, None, clamp=True, duration_s=2.0,
                                         seed=31))
    assert not PI.prepare_timed(normal).count_anchored_pose
    duty = OL.OpenLoopReplay("duty")
    prep, _ = UN.fill_unseen_from_controller(prep, CL.ClosedLoopReplay().simulate(prep, {}))
    # a fill biased by 0.01 of duty on one wheel (what a wrong guess of the unreported
    # commands does): the replayed wheels drift, and with them the open-loop pose
    seen = prep.seen_ticks
    prep.duty = (np.where(seen, prep.duty[0], prep.duty[0] + 0.01), prep.duty[1])
    sim = duty.simulate_windows(prep, {})
    anchored = CH.channels(prep, sim, "duty")
    prep.count_anchored_pose = False
    plain = CH.channels(prep, sim, "duty")
    # the wheels' channels are the same; the camera channels lose the replay's wheel drift
    assert np.array_equal(anchored["omega_r"].resid, plain["omega_r"].resid)
    cam = sum(_rms(anchored[c].resid) for c in ("x_m", "y_m"))
    assert sum(_rms(plain[c].resid) for c in ("x_m", "y_m")) > 2 * cam
    assert cam < 2 * 1.5e-3   # the camera's 1 mm noise, per channel, with margin


def test_a_geometry_effect_stays_visible_in_the_anchored_pose(tmp_path):
    """The anchoring removes what the counts show, not what they cannot: a 3 % larger wheel
    moves the body further for the same counts."""
    run = load_run(truth.simulate_run(tmp_path / "r", ARC, {"wheel_radius": {"r_eff": 0.0376}},
                                      clamp=True, duration_s=2.0, seed=32, recorder=LOOP10))
    prep = PI.prepare_timed(run)
    prep, _ = UN.fill_unseen_from_controller(prep, CL.ClosedLoopReplay().simulate(prep, {}))
    duty = OL.OpenLoopReplay("duty")
    nom = CH.channels(prep, duty.simulate_windows(prep, {}), "duty")
    eff = CH.channels(prep, duty.simulate_windows(prep, {"wheel_radius": {"r_eff": 0.0376}}),
                     "duty")
    nom_cam = _rms(nom["x_m"].resid) + _rms(nom["y_m"].resid)
    eff_cam = _rms(eff["x_m"].resid) + _rms(eff["y_m"].resid)
    assert nom_cam > 3e-3 and eff_cam < 0.5 * nom_cam, (nom_cam, eff_cam)


def _true_commands(prep, run) -> tuple:
    """The commands the truth simulator gave at the prepared run's ticks."""
    dense = _dense_truth(run.meta)
    idx = np.searchsorted(dense["t_s"], prep.t_in + 1e-9) - 1
    return dense["pwm_r"][idx], dense["pwm_l"][idx]


def _fill_error_and_uncertainty(run, channels=("omega_r", "omega_l")):
    """Per channel: (sample times, the replay's error from the filled commands against the
    true ones, the replay uncertainty input_uncertainty gives for it)."""
    prep = PI.prepare_timed(run)
    prep, _ = UN.fill_unseen_from_controller(prep, CL.ClosedLoopReplay().simulate(prep, {}))
    duty = OL.OpenLoopReplay("duty")
    unc = UN.input_uncertainty(prep, duty)
    assert unc and prep.replay_unc is None   # returned, the prepared run left as it is
    prep = dataclasses.replace(prep, replay_unc=unc)
    filled = CH.channels(prep, duty.simulate_windows(prep, {}), "duty")
    base = prep.duty
    prep.duty = _true_commands(prep, run)
    true = CH.channels(prep, duty.simulate_windows(prep, {}), "duty")
    prep.duty = base
    return {c: (filled[c].t, filled[c].sim - true[c].sim, filled[c].unc) for c in channels}


def test_replay_uncertainty_is_the_size_of_the_fill_error(arc_run):
    """Every other tick unreported: the ensemble's spread is the size of what the fill gets
    wrong (RMS within a factor of three either way), neither an order of magnitude below it
    (independent per-tick errors without the bends were) nor far above it."""
    for c, (_, err, unc) in _fill_error_and_uncertainty(arc_run).items():
        ratio = _rms(unc) / _rms(err)
        assert 1 / 3 < ratio < 3, (c, _rms(err), _rms(unc))


def test_replay_uncertainty_grows_in_a_gap_of_lost_frames(arc_run):
    """Frames lost over the end of the acceleration (0.5 s): the commands bent where no
    frame saw it, and the replay's error after the gap is covered by its uncertainty."""
    import copy
    run = copy.deepcopy(arc_run)
    t = run.telemetry["t_s"]
    keep = (t < 0.40) | (t > 0.56)
    run.telemetry = {k: v[keep] for k, v in run.telemetry.items()}
    out = _fill_error_and_uncertainty(run)
    for c, (ts, err, unc) in out.items():
        after = (ts > 0.56) & (ts < 0.8)
        calm = ts > 1.2
        assert _rms(err[after]) > 3 * _rms(err[calm])                # the gap's error is real
        assert _rms(unc[after]) > 0.5 * _rms(err[after]), (c, _rms(err[after]), _rms(unc[after]))
        assert _rms(unc[after]) > 3 * _rms(unc[calm])


def test_no_replay_uncertainty_when_every_tick_is_reported(tmp_path):
    run = load_run(truth.simulate_run(tmp_path / "fw", ARC, None, clamp=True, duration_s=1.5,
                                      seed=33))
    prep = PI.prepare_timed(run)
    assert UN.input_uncertainty(prep, OL.OpenLoopReplay("duty")) is None
    chans = CH.channels(prep, OL.OpenLoopReplay("duty").simulate_windows(prep, {}), "duty")
    assert all(ch.unc is None for ch in chans.values())
    ch = chans["omega_r"]
    assert np.array_equal(ch.deflated(0.1), ch.resid)
    ch.unc = np.full(ch.t.size, 0.1)
    assert np.allclose(ch.deflated(0.1), ch.resid / np.sqrt(2.0))


def test_unreported_commands_stay_within_their_bracket(arc_run):
    """A closed-loop replay whose step falls on an unreported tick the recording does not
    show does not push the fill beyond the reported commands around it by more than the
    tick-level scatter."""
    prep = PI.prepare_timed(arc_run)
    cl = CL.ClosedLoopReplay().simulate(prep, {})
    seen = prep.seen_ticks
    k = int(np.flatnonzero(~seen & (prep.t_in > 1.0))[0])
    j = int(np.argmin(np.abs(cl["t_s"] - prep.t_in[k])))
    cl = dict(cl)
    cl["pwm_r"] = np.asarray(cl["pwm_r"], float).copy()
    cl["pwm_r"][j] += 0.1
    prep, _ = UN.fill_unseen_from_controller(prep, cl)
    lo = min(prep.duty[0][k - 1], prep.duty[0][k + 1])
    hi = max(prep.duty[0][k - 1], prep.duty[0][k + 1])
    assert lo - 0.02 <= prep.duty[0][k] <= hi + 0.02, (lo, prep.duty[0][k], hi)


def test_a_slipping_replayed_wheel_does_not_move_the_anchored_pose(arc_run):
    """The count anchoring carries the replay's extra wheel turning into the pose only where
    the replayed wheel rolls: with the replay slipping throughout, nothing is carried."""
    prep = PI.prepare_timed(arc_run)
    sims = OL.OpenLoopReplay("duty").simulate_windows(prep, {})
    _, sim = next(iter(sims))
    n = arc_run.telemetry["t_s"].size
    t = arc_run.telemetry["t_s"]
    th_r = np.interp(t, sim["t_s"], sim["theta_r_rad"]) * 1.01   # a replay that over-turns
    th_l = np.interp(t, sim["t_s"], sim["theta_l_rad"]) * 1.01
    tg = arc_run.groundtruth["t_s"][arc_run.groundtruth["t_s"] < t[-1]]
    rolling = AN._count_anchor_shift(prep, sim, t, th_r, th_l, 0, n, tg)
    assert _rms(rolling["x_m"]) > 1e-3
    slipping = dict(sim, slip_r=np.ones(np.asarray(sim["t_s"]).size))
    shift = AN._count_anchor_shift(prep, slipping, t, th_r, th_l, 0, n, tg)
    assert all(np.abs(v).max() == 0.0 for v in shift.values())


def test_closed_loop_replay_matched_a_tick_early_or_late(tmp_path):
    """The closed-loop replay's ticks are matched to the recording's where its duties bend
    as the reported ones do (the outer loop's staircase, seen where consecutive ticks are
    reported): a replay moved by one tick is moved back, an aligned one is left alone."""
    run = load_run(truth.simulate_run(tmp_path / "r", ARC, None, clamp=True, duration_s=2.0,
                                      seed=34, recorder={"tel_drop": 0.05}))
    prep = PI.prepare_timed(run)
    cl = CL.ClosedLoopReplay().simulate(prep, {})
    seen = np.asarray(prep.seen_ticks, bool)
    k = np.round((prep.t_in - cl["t_s"][0]) / (cl["t_s"][1] - cl["t_s"][0])).astype(np.int64)
    assert UN._replay_tick_shift(prep, cl, k, seen) == 0
    for lag in (1, -1):
        moved = dict(cl)
        for c in ("pwm_r", "pwm_l"):
            moved[c] = np.roll(np.asarray(cl[c], float), lag)
        assert UN._replay_tick_shift(prep, moved, k, seen) == lag


def test_anchored_heading_has_no_wrap_spikes_across_pi(tmp_path):
    """A run that turns past +-pi: lib/control's odometry of the replayed and of the recorded
    counts wraps its heading at different frames, and a difference of wrapped headings
    interpolated to the camera times had put 1-3 rad spikes into phi_rad (a wheel that the
    replay turns otherwise than the recording, here axle viscous friction the nominal replay
    lacks)."""
    arc = {"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": 0.4}   # about 5.9 rad in 5 s
    run = load_run(truth.simulate_run(
        tmp_path / "r", arc, {"axle_viscous": {"c": 1.5e-3}}, clamp=True, duration_s=5.0,
        seed=31, recorder=dict(LOOP10, heading_gt="wrapped", heading_tel="wrapped")))
    prep = PI.prepare_timed(run)
    assert prep.count_anchored_pose and len(prep.windows) == 1
    prep, _ = UN.fill_unseen_from_controller(prep, CL.ClosedLoopReplay().simulate(prep, {}))
    sims = OL.OpenLoopReplay("duty").simulate_windows(prep, {})
    _, sim = next(iter(sims))
    assert np.ptp(sim["phi_rad"]) > 1.5 * np.pi
    ch = CH.channels(prep, sims, "duty")
    # the camera's 0.01 rad noise and the small heading effect of the missing friction
    assert np.abs(ch["phi_rad"].resid).max() < 0.1
    # the shift itself: a replay that over-turns both wheels by 1 % moves the heading smoothly
    # (the camera samples are 33 ms apart), never by a jump towards 2 pi
    t = run.telemetry["t_s"]
    th = [np.interp(t, sim["t_s"], sim[f"theta_{s}_rad"]) * 1.01 for s in ("r", "l")]
    tg = run.groundtruth["t_s"][run.groundtruth["t_s"] < t[-1]]
    shift = AN._count_anchor_shift(prep, sim, t, th[0], th[1], 0, t.size, tg)
    assert np.abs(np.diff(shift["phi_rad"])).max() < 0.05


def test_count_anchor_moves_the_pose_on_the_candidate_geometry(arc_run):
    """The replay's extra wheel turning moves the body by the replayed plant's radius and track
    width: with a candidate r_eff / b_eff the anchor shift is that of the candidate's geometry
    (it had used meta.json's nominal r and b, which left a right radius fit off by the
    nominal-to-fitted ratio of the shift)."""
    prep = PI.prepare_timed(arc_run)
    sims = OL.OpenLoopReplay("duty").simulate_windows(prep, {})
    _, sim = next(iter(sims))
    t = arc_run.telemetry["t_s"]
    th_r = np.interp(t, sim["t_s"], sim["theta_r_rad"]) * 1.05   # a replay that over-turns
    th_l = np.interp(t, sim["t_s"], sim["theta_l_rad"]) * 1.05
    tg = arc_run.groundtruth["t_s"][arc_run.groundtruth["t_s"] < t[-1]]
    r, b = params.ROBOT["r"], params.ROBOT["b"]
    nom = AN._count_anchor_shift(prep, sim, t, th_r, th_l, 0, t.size, tg)
    big_r = AN._count_anchor_shift(prep, sim, t, th_r, th_l, 0, t.size, tg,
                                   {"wheel_radius": {"r_eff": 1.03 * r}})
    assert _rms(nom["x_m"]) > 5e-3
    # the heading follows r/b exactly; the positions move with it
    assert np.allclose(big_r["phi_rad"], 1.03 * nom["phi_rad"], rtol=1e-3, atol=1e-9)
    assert _rms(big_r["x_m"] - nom["x_m"]) > 0.02 * _rms(nom["x_m"])
    wide = AN._count_anchor_shift(prep, sim, t, th_r, th_l, 0, t.size, tg,
                                  {"track_width": {"b_eff": 1.1 * b}})
    assert np.allclose(wide["phi_rad"], nom["phi_rad"] / 1.1, rtol=1e-3, atol=1e-9)
    # the windows' replay carries the effects it ran with to the channels
    eff = {"wheel_radius": {"r_eff": 1.03 * r}}
    assert OL.OpenLoopReplay("duty").simulate_windows(prep, eff).effects == eff


def test_a_channel_whose_samples_differ_between_draws_keeps_its_spread(arc_run, monkeypatch):
    """The current is compared only at samples away from a change of the duty, and a drawn
    unseen tick may change it where the fill did not (a stop's reported duties all equal, a
    draw's not): a draw's replay may keep fewer current samples.  The draws are matched by
    time, so the channel keeps its spread at the samples that at least half of the draws have
    (a run's current had none at all for two samples at its end: heldback16's truth 60 s null
    recorded at 65 ms, 19 current floors after a lost frame at a braking step against no input
    spread).  Here every other draw loses the current's last sample."""
    prep = PI.prepare_timed(arc_run)
    prep, _ = UN.fill_unseen_from_controller(prep, CL.ClosedLoopReplay().simulate(prep, {}))
    duty = OL.OpenLoopReplay("duty")
    full = UN.input_uncertainty(prep, duty)
    assert full and "current_r_a" in full
    real, calls = UN.channels, []

    def fewer(*a, **k):
        out = real(*a, **k)
        calls.append(1)
        if len(calls) % 2:
            out = {c: (dataclasses.replace(ch, t=ch.t[:-1], rec=ch.rec[:-1], sim=ch.sim[:-1],
                                           seg=None if ch.seg is None else ch.seg[:-1],
                                           band=None if ch.band is None else ch.band[:-1])
                       if c.startswith("current") else ch) for c, ch in out.items()}
        return out
    monkeypatch.setattr(UN, "channels", fewer)
    part = UN.input_uncertainty(prep, duty)
    assert part and all(c in part for c in ("current_r_a", "current_l_a"))
    for c in ("current_r_a", "current_l_a"):
        t, s = part[c]
        assert np.array_equal(t, full[c][0])    # the last sample: in half of the draws
        assert np.allclose(s[:-1], full[c][1][:-1])
    assert np.array_equal(part["omega_r"][1], full["omega_r"][1])
