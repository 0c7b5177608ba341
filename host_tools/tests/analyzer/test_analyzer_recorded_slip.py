"""The recording's own test of rolling (camera against counts) and a slip episode of the nominal
replay carried on while the recording goes on slipping after it (``replay.anchors``)."""
from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from host_tools import params as P
from host_tools.analyzer.prepare import run as PR
from host_tools.analyzer.prepare.odometry import encoder_odometry
from host_tools.analyzer.replay import anchors as AN
from host_tools.analyzer.replay import edges as ED

ROBOT = {name: p.value for p in P.TABLE.params if p.group == "robot" for name in [p.name]}
PPR = 2000
SPIN = (4.0, 6.5)   # the recorded body spins on its slipping wheels over this span


def _recording(seed: int = 1, spin: tuple[float, float] | None = SPIN,
               r_ratio: float = 1.0, b_ratio: float = 1.0,
               lost: tuple[float, float] | None = None):
    """A 16 s recording (50 Hz telemetry, 30 Hz camera with 1 mm and 0.01 rad of noise) of a
    robot that drives, turns and reverses, rolling with its wheels, except over ``spin``: its
    wheels turn backwards at 30 rad/s, and its body stands and spins at -6 rad/s.  Its wheel
    radius and track width are ``r_ratio`` and ``b_ratio`` times the nominal ones.  The frames
    strictly inside ``lost`` are lost (a gap of the telemetry, which ends a window)."""
    rng = np.random.default_rng(seed)
    r, b = float(ROBOT["r"]), float(ROBOT["b"])
    t = np.round(np.arange(0.0, 16.0 + 1e-9, 0.02), 6)
    w_r = 20 * np.sin(2 * np.pi * t / 5.0) + 6 * np.sin(2 * np.pi * t / 1.7)
    w_l = 20 * np.sin(2 * np.pi * t / 5.0) - 6 * np.sin(2 * np.pi * t / 2.3)
    in_spin = np.zeros(t.size, bool) if spin is None else (t >= spin[0]) & (t < spin[1])
    w_r[in_spin] = w_l[in_spin] = -30.0
    dt = np.diff(t, prepend=t[0])
    th_r, th_l = np.cumsum(w_r * dt), np.cumsum(w_l * dt)
    k = 2 * np.pi / PPR
    enc_r, enc_l = np.floor(th_r / k), np.floor(th_l / k)
    # the body: rolling with the wheels, except in the spin
    v = np.where(in_spin, 0.0, r_ratio * r * (w_r + w_l) / 2)
    om = np.where(in_spin, -6.0, r_ratio * r * (w_r - w_l) / (2 * b_ratio * b))
    phi = np.cumsum(om * dt)
    x, y = np.cumsum(v * np.cos(phi) * dt), np.cumsum(v * np.sin(phi) * dt)
    xo, yo, po = encoder_odometry(enc_r, enc_l, t, r, b, PPR, (0.0, 0.0, 0.0))
    tg = np.round(np.arange(0.0, 16.0, 1 / 30), 6)
    gt = {"t_s": tg, "x_m": np.interp(tg, t, x) + rng.normal(0, 1e-3, tg.size),
          "y_m": np.interp(tg, t, y) + rng.normal(0, 1e-3, tg.size),
          "phi_rad": np.angle(np.exp(1j * (np.interp(tg, t, phi)
                                           + rng.normal(0, 0.01, tg.size))))}
    tel = {"t_s": t, "enc_r": enc_r, "enc_l": enc_l, "x_odo_m": np.asarray(xo),
           "y_odo_m": np.asarray(yo), "phi_odo_rad": np.asarray(po)}
    if lost is not None:
        keep = (t <= lost[0]) | (t >= lost[1])
        tel = {k: v[keep] for k, v in tel.items()}
        t = tel["t_s"]
    nothing = (np.zeros(0), np.zeros(0))
    edges = [int(np.searchsorted(t, s)) for s in (4.0, 8.0, 12.0)]
    if lost is not None:
        edges = sorted(edges + [int(np.searchsorted(t, lost[1]))])
    bounds = [0] + edges + [t.size]
    return PR.PreparedRun(SimpleNamespace(telemetry=tel, groundtruth=gt, name="run-0"), t, t,
                          nothing, nothing, t, dict(ROBOT), {}, (0.0, 0.0, 0.0), PPR,
                          windows=list(zip(bounds[:-1], bounds[1:])), odo_schedule="frames")


def test_a_rolling_recording_passes_the_rolling_test():
    """Turns, reversals and the camera's noise: every block rolls (seeds 1-5, 64 blocks each,
    a false alarm of 1 % per run)."""
    for seed in range(1, 6):
        rt = AN.rolling_test(_recording(seed, spin=None))
        assert rt is not None and rt.t0.size == 64
        assert all(rt.rolling(i) for i in range(rt.t0.size)), (
            seed, np.nanmax(rt.z_heading), np.nanmax(rt.z_speed), rt.z_limit)


def test_a_robot_off_the_nominal_geometry_rolls():
    """A wheel radius 4 % and a track width 8 % off the nominal ones (effects of the vocabulary,
    well beyond their tolerance) are no slip: the test scales the counts' rates by the
    camera's median ratio to them."""
    for r_ratio, b_ratio in ((1.04, 1.0), (1.0, 0.92), (0.96, 1.08)):
        rt = AN.rolling_test(_recording(2, spin=None, r_ratio=r_ratio, b_ratio=b_ratio))
        assert rt is not None
        assert all(rt.rolling(i) for i in range(rt.t0.size)), (
            r_ratio, b_ratio, np.nanmax(rt.z_heading), np.nanmax(rt.z_speed))
    # and the spin is found on such a robot too
    rt = AN.rolling_test(_recording(2, r_ratio=1.04, b_ratio=0.92))
    inside = (rt.t0 >= SPIN[0]) & (rt.t1 <= SPIN[1])
    assert all(rt.rolling(i) is False for i in np.flatnonzero(inside))


def test_the_rolling_test_finds_the_spin():
    """The blocks inside the spin fail the test (its edges' blocks may go either way)."""
    rt = AN.rolling_test(_recording())
    assert rt is not None
    inside = (rt.t0 >= SPIN[0]) & (rt.t1 <= SPIN[1])
    assert all(rt.rolling(i) is False for i in np.flatnonzero(inside))
    outside = (rt.t1 <= SPIN[0]) | (rt.t0 >= SPIN[1])
    assert all(rt.rolling(i) for i in np.flatnonzero(outside))


def test_a_replay_episode_is_carried_on_while_the_recording_slips():
    """An episode of the nominal replay that ends while the recording still spins is carried on
    to where the recording rolls again; one after which the recording rolls is left as it is,
    and a slip that only the recording shows is not made an episode."""
    prep = _recording()
    got = AN.with_recorded_slip(prep, [(1.0, 1.2), (3.8, 4.4), (9.0, 9.3)])
    assert got[0] == (1.0, 1.2) and got[2] == (9.0, 9.3)
    assert got[1][0] == 3.8 and SPIN[1] <= got[1][1] <= SPIN[1] + AN.ROLL_BLOCK_S
    assert AN.with_recorded_slip(prep, [(1.0, 1.2)]) == [(1.0, 1.2)]
    assert AN.with_recorded_slip(prep, []) == []


def test_a_window_after_a_gap_that_starts_in_the_recordings_slip_starts_in_an_episode():
    """Frames lost over 4.9-5.6 s (a gap: the window before ends at it, and no command is known
    in it), inside the recording's spin: the window after the gap starts where the recording
    does not roll, and no replay saw that slip begin, so it is the recording's episode, from the
    last frame before the gap to where the recording rolls again; the window then starts as the
    camera shows it (``window_start``).  A gap where the recording rolls adds none."""
    prep = _recording(lost=(4.9, 5.6))
    t = prep.run.telemetry["t_s"]
    j = int(np.searchsorted(t, 5.6))
    got = AN.with_recorded_slip(prep, [])
    assert len(got) == 1 and got[0][0] == t[j - 1]
    assert SPIN[1] <= got[0][1] <= SPIN[1] + AN.ROLL_BLOCK_S
    assert AN.slip_containing(dataclasses.replace(prep, slip_episodes=got), float(t[j]))
    # with the replay's own episode before it, the two are both kept (the rules take the longer)
    assert AN.with_recorded_slip(prep, [(3.8, 4.4)])[1] == got[0]
    assert AN.with_recorded_slip(_recording(lost=(9.9, 10.6)), []) == []


def test_no_window_starts_in_the_recordings_slip_after_a_replay_episode():
    """The nominal replay grips again at 4.4 s while the recording spins until 6.5 s: the
    window edge at 8 s is where it was, the one at 4 s (its early start after the replay's
    episode, inside the recording's spin) is moved to 0.5 s after the recording rolls again,
    and the run's slip episode is the recording's (what ``locate`` takes as no evidence)."""
    prep = _recording()
    t = prep.run.telemetry["t_s"]

    class Replay:
        def simulate_windows(self, prep, effects):
            out = []
            for i_a, i_b in prep.windows:
                g = t[max(i_a - 25, 0):i_b]
                slip = (g >= 3.8) & (g < 4.4)
                out.append((None, {"t_s": g, "slip_r": slip.astype(float),
                                   "slip_l": slip.astype(float)}))
            return out

    out, moved = ED.edges_outside_slip(prep, Replay())
    starts = [round(float(t[a]), 2) for a, _ in out.windows]
    end = max(b for a, b in out.slip_episodes if a < 4.4)
    assert SPIN[1] <= end <= SPIN[1] + AN.ROLL_BLOCK_S
    assert moved >= 1
    assert 8.0 in starts and 12.0 in starts
    assert not any(3.8 < s - PR.BURN_IN_S < end for s in starts), starts
    assert any(abs(s - (end + PR.BURN_IN_S)) < 0.03 for s in starts), (starts, end)
