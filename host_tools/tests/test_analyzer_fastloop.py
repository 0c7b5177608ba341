"""Recordings whose inner loop is faster than the telemetry (a 10 ms loop seen at 50 Hz): half
the commands are never recorded. The analyzer finds the tick phase from the board's wheel
speeds (a cubic through the counts), fills the unreported ticks with the closed-loop replay's
pattern, and compares the camera against the count-anchored pose (docs/analyzer.md)."""
from __future__ import annotations

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import truth  # noqa: E402

from host_tools import params  # noqa: E402
from host_tools.analyzer import replay as R  # noqa: E402
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
    phase = R.board_rate_phase(tel, 0.010, int(arc_run.meta["encoder_ppr"]))
    assert phase is not None
    err = min(phase % 0.010, 0.010 - phase % 0.010)
    assert err <= 0.0025, phase


def test_unreported_ticks_filled_closer_to_the_commands_given(arc_run):
    prep = R.prepare(arc_run, 0.5, 0.0)
    seen = prep.extras["seen_ticks"]
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
    cl = R.ClosedLoopReplay().simulate(prep, {})
    n = R.fill_unseen_from_controller(prep, cl)
    in_cl = (prep.t_in >= cl["t_s"][0] - 1e-9) & (prep.t_in <= cl["t_s"][-1] + 1e-9)
    assert n == int((~seen & in_cl).sum()) > 0.4 * seen.size
    assert np.array_equal(prep.duty[0][seen], given[0][seen])
    assert bias() < 0.5 * line, (line, bias())


def test_count_anchored_pose_only_for_unreported_inputs(tmp_path, arc_run):
    prep = R.prepare_timed(arc_run)
    assert prep.extras["count_anchored_pose"]
    normal = load_run(truth.simulate_run(tmp_path / "fw", ARC, None, clamp=True, duration_s=2.0,
                                         seed=31))
    assert not R.prepare_timed(normal).extras["count_anchored_pose"]
    duty = R.OpenLoopReplay("duty")
    R.fill_unseen_from_controller(prep, R.ClosedLoopReplay().simulate(prep, {}))
    sim = duty.simulate_windows(prep, {})
    anchored = R.channels(prep, sim, "duty")
    prep.extras["count_anchored_pose"] = False
    plain = R.channels(prep, sim, "duty")
    # the wheels' channels are the same; the camera channels lose the replay's wheel drift
    assert np.array_equal(anchored["omega_r"].resid, plain["omega_r"].resid)
    cam = sum(_rms(anchored[c].resid) for c in ("x_m", "y_m"))
    assert cam < sum(_rms(plain[c].resid) for c in ("x_m", "y_m"))
    assert cam < 2 * 1.5e-3   # the camera's 1 mm noise, per channel, with margin


def test_a_geometry_effect_stays_visible_in_the_anchored_pose(tmp_path):
    """The anchoring removes what the counts show, not what they cannot: a 3 % larger wheel
    moves the body further for the same counts."""
    run = load_run(truth.simulate_run(tmp_path / "r", ARC, {"wheel_radius": {"r_eff": 0.0376}},
                                      clamp=True, duration_s=2.0, seed=32, recorder=LOOP10))
    prep = R.prepare_timed(run)
    R.fill_unseen_from_controller(prep, R.ClosedLoopReplay().simulate(prep, {}))
    duty = R.OpenLoopReplay("duty")
    nom = R.channels(prep, duty.simulate_windows(prep, {}), "duty")
    eff = R.channels(prep, duty.simulate_windows(prep, {"wheel_radius": {"r_eff": 0.0376}}),
                     "duty")
    nom_cam = _rms(nom["x_m"].resid) + _rms(nom["y_m"].resid)
    eff_cam = _rms(eff["x_m"].resid) + _rms(eff["y_m"].resid)
    assert nom_cam > 3e-3 and eff_cam < 0.5 * nom_cam, (nom_cam, eff_cam)
