"""A cascade whose outer period spans two inner ticks, seen by frames that report one tick of
each pair for blocks of frames (a 29 ms loop seen every 55 ms), on a reference the closed-loop
replay does not replay (a ``segments`` tour): the unreported ticks keep the straight-line fill,
which misses the outer loop's two-tick staircase with one sign per block.  The replay's
uncertainty from unreported commands carries a phase term for it (replay.unseen.phase_term,
docs/analyzer.md "The replay's uncertainty from unreported commands")."""
from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from _native_skip import needs_native
from _unseen_replay import filled_and_given

pytestmark = needs_native(truth=True)

from host_tools import truth  # noqa: E402
from host_tools.analyzer.prepare import inputs as PI  # noqa: E402
from host_tools.analyzer.replay import closedloop as CL  # noqa: E402
from host_tools.analyzer.replay import unseen as UN  # noqa: E402
from host_tools.runfmt import load_run  # noqa: E402

# a start to 0.5 m/s and a stop: the staircase while the wheels accelerate and brake
TOUR = {"kind": "segments", "accel": 0.6, "alpha": 2.0,
        "segments": [{"duration_s": 2.0, "v": 0.5, "omega": 0.0},
                     {"duration_s": 1.5, "v": 0.0, "omega": 0.0}]}
INNER_S = 0.029
TEL_S = 2 * INNER_S - 0.003   # 55 ms: the reported tick slides 3 ms a frame against the outer period
ACC_REGIME = 12.0   # rad/s^2: the report's "during acceleration"


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def given_commands(prep, full, inner_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The duties the controller gave at ``prep``'s ticks, from ``full``: the same run recorded
    with a frame at every tick.  About half of ``prep``'s ticks are unreported."""
    tf = np.asarray(full.telemetry["t_s"], float)
    kf = np.floor(tf / inner_s + 1e-9).astype(np.int64)
    k = np.round(prep.t_in / inner_s).astype(np.int64)
    idx = np.searchsorted(kf, k)
    assert np.array_equal(kf[idx], k)
    assert 0.4 < np.mean(np.asarray(prep.seen_ticks, bool)) < 0.6
    return (np.asarray(full.telemetry["pwm_r"], float)[idx],
            np.asarray(full.telemetry["pwm_l"], float)[idx])


@pytest.fixture(scope="module")
def staircase(tmp_path_factory):
    """(prepared run, the commands the controller gave at its ticks): the same run recorded
    with a frame at every tick (the truth simulator's controller and physics do not depend on
    the telemetry period) gives the unreported ticks' commands."""
    d = tmp_path_factory.mktemp("phase")
    rec = {"inner_s": INNER_S, "tel_s": TEL_S}
    run = load_run(truth.simulate_run(d / "run", TOUR, None, duration_s=3.5, seed=41,
                                      recorder=rec))
    full = load_run(truth.simulate_run(d / "full", TOUR, None, duration_s=3.5, seed=41,
                                       recorder=dict(rec, tel_s=INNER_S)))
    prep = PI.prepare_timed(run)
    given = given_commands(prep, full, INNER_S)
    seen = np.asarray(prep.seen_ticks, bool)
    for side in (0, 1):   # the reported ticks are the recorded commands, exactly
        assert np.array_equal(prep.duty[side][seen], given[side][seen])
    return prep, given


def test_the_closed_loop_replay_refuses_the_tour(staircase):
    """The case the term is for: no controller pattern refines the straight-line fill."""
    prep, _ = staircase
    assert CL.ClosedLoopReplay().setup(prep)[0] is None


def test_phase_term_blocks_follow_the_reported_phase(staircase):
    """One block per stretch of frames that report the same tick of each pair: the reported
    tick slides by 2 x 29 - 55 = 3 ms a frame, a block lasts about 29 / 3 frames (0.53 s);
    within a block the fill's error keeps the sign that the term's offset has for one draw."""
    prep, given = staircase
    pt = UN.phase_term(prep)
    assert pt is not None
    block, off = pt
    seen = np.asarray(prep.seen_ticks, bool)
    t_un = prep.t_in[~seen]
    n_blocks = int(block[-1]) + 1
    span = float(t_un[-1] - t_un[0])
    block_s = INNER_S / (2 * INNER_S - TEL_S) * TEL_S
    assert abs(n_blocks - span / block_s) <= 2, (n_blocks, span / block_s)
    # where the command moves, the fill misses by a fraction of one tick's change, of one
    # sign relative to the term's offset per block: the ratio error / offset keeps its sign
    for side in (0, 1):
        err = prep.duty[side][~seen] - given[side][~seen]
        signs = []
        for b in range(n_blocks):
            m = (block == b) & (np.abs(off[side]) > 0.5 * np.abs(off[side]).max())
            if m.sum() >= 4:
                r = err[m] / off[side][m]
                signs.append(np.sign(np.median(r)))
                assert np.mean(np.sign(r) == np.sign(np.median(r))) >= 0.75, (side, b, r)
                assert np.all(np.abs(err[m]) <= np.abs(off[side][m]) * 1.5 + 2e-3), (side, b)
        assert len(signs) >= 3


def _coverage(prep, given) -> dict[str, float]:
    """Per wheel speed: the RMS of the replay uncertainty over the RMS of the replay's error
    from the fill (filled against given commands), where |wheel acceleration| > 12 rad/s^2."""
    filled, true = filled_and_given(prep, given)
    out = {}
    for c in ("omega_r", "omega_l"):
        acc = np.abs(np.gradient(true[c].sim, true[c].t)) > ACC_REGIME
        assert acc.sum() >= 10
        err = filled[c].sim - true[c].sim
        out[c] = _rms(filled[c].unc[acc]) / _rms(err[acc])
    return out


def test_replay_uncertainty_covers_the_staircase_fill_error(staircase, monkeypatch):
    """During acceleration the replay's uncertainty is the size of the error the fill causes
    (within a factor of 3 either way; the bend and tick-level terms alone covered 0.3-0.4 of
    it)."""
    prep, given = staircase
    with_term = _coverage(prep, given)
    for c, ratio in with_term.items():
        assert 0.6 < ratio < 3.0, (c, with_term)
    monkeypatch.setattr(UN, "phase_term", lambda p: None)
    without = _coverage(prep, given)
    assert all(r < 0.5 for r in without.values()), without


def test_no_phase_term_for_a_single_tick_outer_loop_or_a_refined_fill(staircase):
    prep, _ = staircase
    run = copy.deepcopy(prep.run)
    run.meta["periods_s"] = dict(run.meta["periods_s"], outer=INNER_S)
    assert UN.phase_term(dataclasses.replace(prep, run=run)) is None
    # a fill the controller's pattern refined (what fill_unseen_from_controller does where
    # the closed-loop replay runs) is no longer the line: its staircase is the controller's
    seen = np.asarray(prep.seen_ticks, bool)
    bent = tuple(np.where(seen, u, u + 1e-3) for u in prep.duty)
    assert UN.phase_term(dataclasses.replace(prep, duty=bent)) is None
    every = dataclasses.replace(prep, seen_ticks=np.ones(seen.size, bool))
    assert UN.phase_term(every) is None


def test_a_mujoco_tour_null_seen_in_blocks_is_no_mismatch(tmp_path):
    """End to end: a 20 s tour made by the MuJoCo engine under this recorder (heldback14's
    hb14_mj_null_tour_20s: 29 ms loop, 55 ms frames, odometry at the frames, a 15 Hz camera)
    is a null; without the phase term this run's wheel speeds during acceleration were taken
    for a mismatch (``unexplained``)."""
    pytest.importorskip("mujoco")
    from host_tools.analyzer import pipeline
    rec = {"inner_s": INNER_S, "tel_s": TEL_S, "odometry": "frames", "integration": "midpoint",
           "heading_gt": "wrapped", "cam_hz": 15.0}
    path = truth.simulate_run(tmp_path / "tour", {"kind": "tour"}, None, duration_s=20.0,
                              seed=1, recorder=rec, engine="mujoco")
    an = pipeline.analyze([str(path)], jobs=1, log=lambda m: None)
    assert an.verdict == "no_mismatch", (an.verdict, an.selected)


def test_no_phase_term_for_a_single_wheel_speed_loop(staircase):
    """A recorder whose controller is one wheel-speed loop (meta.json ``controller: pi``) has
    no outer staircase, whatever outer period its meta.json gives."""
    prep, _ = staircase
    run = copy.deepcopy(prep.run)
    run.meta["controller"] = "pi"
    assert UN.phase_term(dataclasses.replace(prep, run=run)) is None
    run.meta["controller"] = "cascade"
    assert UN.phase_term(dataclasses.replace(prep, run=run)) is not None
