"""A cascade's acceleration feed-forward pulse that no reported command shows: a reference segment
shorter than an outer period (a ramp the outer ticks see one sample of) makes the torque step by
(r/2) m_ff dv for one outer period, and when the frames that would report those two ticks are
lost the straight-line fill of the unreported ticks misses all of it.  The reference (a
``segments`` list in meta.json, which the closed-loop replay does not replay) says where and by
how much: replay.unseen.feedforward_term, drawn in the replay's uncertainty from unreported
commands (docs/analyzer.md, "The replay's uncertainty from unreported commands")."""
from __future__ import annotations

import csv

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

INNER_S = 0.025   # outer 50 ms: outer ticks at 0, 0.05, ... s
# at rest, then a 30 ms segment toward 0.3 m/s (1.0106-1.0406 s: between the outer ticks at 1.0
# and 1.05, which see none of its ramp up) and a stop: the outer tick at 1.05 s samples the ramp
# down (-0.6 m/s^2), the one at 1.1 s rest again: a feed-forward pulse on the ticks at 1.075 and
# 1.1 s
TOUR = {"kind": "segments", "accel": 0.6, "alpha": 2.0,
        "segments": [{"duration_s": 1.0106, "v": 0.0, "omega": 0.0},
                     {"duration_s": 0.03, "v": 0.3, "omega": 0.0},
                     {"duration_s": 1.5, "v": 0.0, "omega": 0.0}]}
PULSE_TICKS = (43, 44)      # 1.075 and 1.1 s
LOST_S = (1.08, 1.12)       # the frames reporting them (1.087, 1.112 s) lost


@pytest.fixture(scope="module")
def pulse(tmp_path_factory):
    """(prepared run with the pulse's frames lost, the commands the controller gave at its
    ticks): a frame at every tick, two of them removed from telemetry.csv."""
    d = tmp_path_factory.mktemp("ffpulse")
    path = truth.simulate_run(d / "run", TOUR, None, duration_s=2.5, seed=7,
                              recorder={"inner_s": INNER_S, "tel_s": INNER_S})
    full = load_run(path)
    tel = d / "run" / "telemetry.csv"
    with open(tel) as fh:
        rows = list(csv.reader(fh))
    keep = [rows[0]] + [r for r in rows[1:] if not LOST_S[0] <= float(r[0]) <= LOST_S[1]]
    assert len(keep) == len(rows) - 2
    with open(tel, "w", newline="") as fh:
        csv.writer(fh).writerows(keep)
    prep = PI.prepare_timed(load_run(path))
    tf = np.asarray(full.telemetry["t_s"], float)
    kf = np.floor(tf / INNER_S + 1e-9).astype(np.int64)
    k = np.round(prep.t_in / INNER_S).astype(np.int64)
    idx = np.searchsorted(kf, k)
    assert np.array_equal(kf[idx], k)
    given = (np.asarray(full.telemetry["pwm_r"], float)[idx],
             np.asarray(full.telemetry["pwm_l"], float)[idx])
    return prep, k, given


def test_the_pulse_is_unreported_and_not_replayed(pulse):
    prep, k, given = pulse
    assert CL.ClosedLoopReplay().setup(prep)[0] is None   # a segments tour: no closed-loop fill
    seen = np.asarray(prep.seen_ticks, bool)
    for kk in PULSE_TICKS:
        assert not seen[k == kk].any()
    # the controller's command there: the pulse, over 0.02 of duty below its reported neighbours
    i = np.flatnonzero(np.isin(k, PULSE_TICKS))
    for side in (0, 1):
        u = given[side]
        assert np.all(u[i] < min(u[i[0] - 1], u[i[-1] + 1]) - 0.02)


def test_feedforward_term_finds_the_pulse(pulse):
    prep, k, _ = pulse
    ff = UN.feedforward_term(prep)
    assert ff is not None
    unseen, _, dep = ff
    r = prep.robot
    m_ff = r["m_r"] + 2 * r["m_w"] + 2 * r["I_wy"] / r["r"] ** 2
    expect = -0.5 * r["r"] * m_ff * 0.6 / prep.motor["stall_nm"]
    on = np.isin(k[unseen], PULSE_TICKS)
    assert on.sum() == 2
    for side in (0, 1):
        assert np.allclose(dep[side][on], expect, rtol=1e-9)
        assert np.all(dep[side][~on] == 0.0)


def _worst_in_floors(prep, given, floor: float) -> dict[str, float]:
    """Per wheel speed, within 0.3 s after the pulse: the largest error of the duty replay from
    the fill (filled against given commands) over sqrt(floor^2 + the replay's uncertainty^2),
    the deflation the decisions use (Channel.deflated)."""
    filled, true = filled_and_given(prep, given)
    out = {}
    for c in ("omega_r", "omega_l"):
        near = (filled[c].t > 1.075) & (filled[c].t < 1.4)
        err = (filled[c].sim - true[c].sim)[near]
        u = np.nan_to_num(filled[c].unc[near]) if filled[c].unc is not None else 0.0 * err
        out[c] = float(np.max(np.abs(err) / np.sqrt(floor ** 2 + u ** 2)))
    return out


def test_the_replay_uncertainty_covers_the_hidden_pulse(pulse, monkeypatch):
    """The straight-line fill keeps none of the pulse, so the duty replay's wheel speeds run off
    by several wheel-speed quantization floors after it; the feed-forward's draw (std
    |departure| / sqrt 3 per gap) takes it within 3 (fails before: no feed-forward term)."""
    prep, _, given = pulse
    floor = 2 * np.pi / prep.run.meta["encoder_ppr"] / (INNER_S * np.sqrt(6.0))
    with_term = _worst_in_floors(prep, given, floor)
    assert all(v < 3.0 for v in with_term.values()), with_term
    monkeypatch.setattr(UN, "feedforward_term", lambda p: None)
    without = _worst_in_floors(prep, given, floor)
    assert all(v > 3.0 for v in without.values()), without


def test_the_phase_term_still_sees_the_line_fill(pulse):
    prep, _, _ = pulse
    assert UN.phase_term(prep) is not None


def test_the_feedforward_gains_are_the_recording_controllers(pulse):
    """m_ff and I_ff come from lib/control for the recording's velocity loop: the improved loop's
    rolling mass (the chassis, the wheels and their spin inertia), the thesis loop's m_t."""
    prep, _, _ = pulse
    r = prep.run.meta["robot"]
    _, _, m_ff, i_ff, _ = UN.feedforward_gains(prep.run.meta)
    assert m_ff == pytest.approx(r["m_r"] + 2 * r["m_w"] + 2 * r["I_wy"] / r["r"] ** 2, rel=1e-6)
    thesis = dict(prep.run.meta, controller_variant="thesis")
    _, _, m_t, i_t, _ = UN.feedforward_gains(thesis)
    assert m_t == pytest.approx(r["m_r"] + 2 * r["m_w"], rel=1e-6)
    assert i_t < i_ff
