"""The straight-line fill of unreported ticks with the reported ticks' count quantization taken
out, for a single wheel-speed loop (replay.unseen.fill_count_level; docs/analyzer.md "Ticks no
frame reported"): a PI loop's proportional term on the speed counted over one tick puts the
command on one of two levels, the frames see one level for blocks of them, and the line
through the reported commands runs off the unreported ticks' mean by a fraction of a level."""
from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace
from typing import Callable

import numpy as np

from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay import unseen as UN

PPR = 1000          # counts a revolution (a round test value)
TICK = 0.002        # s, the loop's period
FRAME = 10          # ticks a frame
G = 0.03            # the command's drop per rad/s of counted speed (the P term)



def _pi_prep(t: np.ndarray, u: np.ndarray, counts: np.ndarray, w_cnt: np.ndarray,
             frames: np.ndarray, tick: float, **extra: object) -> tuple[PreparedRun, np.ndarray]:
    """A `pi` loop's run whose ``frames`` report the tick (both sides alike), the unreported
    ticks filled by the line through the reported commands: (the prepared run, reported)."""
    n = t.size
    seen = np.zeros(n, bool)
    seen[frames] = True
    fill = np.interp(t, t[seen], u[seen])
    tel = {"t_s": t[frames], "enc_r": counts[frames], "enc_l": counts[frames],
           "omega_r": w_cnt[frames], "omega_l": w_cnt[frames],
           "pwm_r": u[frames], "pwm_l": u[frames]}
    run = SimpleNamespace(meta={"controller": "pi"}, telemetry=tel)
    prep = PreparedRun(run=run, t_in=t, t_in_tau=t, duty=(fill, fill.copy()),  # type: ignore[arg-type]
                       torque=(fill, fill.copy()), t_grid=t, robot={}, motor={},
                       start_pose=(0.0, 0.0, 0.0), ppr=PPR, inner_period=tick, tick_phase=0.0,
                       seen_ticks=seen, **extra)  # type: ignore[arg-type]
    return prep, seen

def _pi_run(controller: str | None = "pi", drop: tuple[int, ...] = (7, 8, 30, 31, 32),
            ppr: int = PPR, accel: float = 9.0, top: float = 6.1
            ) -> tuple[PreparedRun, np.ndarray, np.ndarray]:
    """A wheel accelerating then cruising under a PI loop on the counted speed, seen every
    FRAME ticks with some frames lost: (the prepared run with the line fill, the true command of
    every tick, the reported mask)."""
    n = 1200
    t = TICK * np.arange(n)
    q = 2.0 * math.pi / ppr
    omega = np.minimum(accel * t, top)                    # rad/s
    theta = np.cumsum(omega) * TICK
    counts = np.floor(theta / q)
    w_cnt = np.concatenate([[0.0], np.diff(counts)]) * q / TICK
    smooth = 0.05 + 0.04 * np.minimum(t, 0.7)
    u = smooth - G * (w_cnt - omega)                     # on the level of the counted speed
    frames = np.arange(0, n, FRAME)
    frames = np.delete(frames, list(drop))
    seen = np.zeros(n, bool)
    seen[frames] = True
    fill = np.interp(t, t[seen], u[seen])                # prepare's straight line
    fill[seen] = u[seen]
    tel = {"t_s": t[frames], "enc_r": counts[frames], "enc_l": counts[frames],
           "omega_r": w_cnt[frames], "omega_l": w_cnt[frames],
           "pwm_r": u[frames], "pwm_l": u[frames]}
    meta = {} if controller is None else {"controller": controller}
    run = SimpleNamespace(meta=meta, telemetry=tel)
    prep = PreparedRun(run=run, t_in=t, t_in_tau=t, duty=(fill, fill.copy()),  # type: ignore[arg-type]
                       torque=(fill, fill.copy()), t_grid=t, robot={}, motor={},
                       start_pose=(0.0, 0.0, 0.0), ppr=ppr, inner_period=TICK, tick_phase=0.0,
                       seen_ticks=seen)
    return prep, u, seen


def _interval_mean_error(duty: np.ndarray, u: np.ndarray, seen: np.ndarray) -> float:
    """RMS over the frame intervals of the mean error of their unreported ticks (what a wheel's
    speed integrates)."""
    i_seen = np.flatnonzero(seen)
    errs = [float(np.mean(duty[a + 1:b] - u[a + 1:b]))
            for a, b in zip(i_seen[:-1], i_seen[1:]) if b > a + 1]
    return math.sqrt(float(np.mean(np.square(errs))))


def test_the_count_levels_taken_out_of_the_fill() -> None:
    prep, u, seen = _pi_run()
    line = _interval_mean_error(np.asarray(prep.duty[0]), u, seen)
    out, n = UN.fill_count_level(prep)
    assert n == int((~seen).sum())
    refined = _interval_mean_error(np.asarray(out.duty[0]), u, seen)
    # the line runs a fraction of a level (G x 2 pi / PPR / TICK = 0.094) off the mean
    assert line > 0.01
    assert refined < 0.25 * line
    # the reported ticks stay as recorded; the run given is left as it is
    assert np.array_equal(np.asarray(out.duty[1])[seen], u[seen])
    assert np.array_equal(np.asarray(prep.duty[0])[~seen],
                          np.interp(prep.t_in[~seen], prep.t_in[seen], u[seen]))


def test_not_a_single_wheel_speed_loop_or_every_tick_reported_changes_nothing() -> None:
    for ctl in (None, "cascade"):
        prep, _, _ = _pi_run(controller=ctl)
        out, n = UN.fill_count_level(prep)
        assert n == 0 and out is prep
    prep, _, _ = _pi_run()
    full = PreparedRun(**{**prep.__dict__, "seen_ticks": None})
    out, n = UN.fill_count_level(full)
    assert n == 0 and out is full


def test_the_fill_spread_is_that_of_the_fill_with_the_count_levels_taken_out() -> None:
    # the reported commands jump by a level wherever the frames' aliasing of the count beat
    # changes; measured on them, the bend that input_uncertainty draws takes each jump for a
    # trend that may go on into the gap, carried over the lost frames' gaps as well
    rms = {}
    for ctl in ("pi", None):
        prep, _, _ = _pi_run(controller=ctl)
        spread = UN.fill_spread(prep)
        assert spread is not None
        rms[ctl] = math.sqrt(float(np.mean(np.square(spread[3][0]))))
    level = G * 2.0 * math.pi / PPR / TICK
    assert rms[None] > 0.25 * level
    # the PI loop's fill is the line with the count level taken out: so is its spread
    assert rms["pi"] < 0.25 * rms[None]


def test_a_slow_loop_on_a_ramp_is_not_moved_by_its_counted_speed_lag() -> None:
    # a 25 ms loop seen every 2.16 ticks (54 ms frames) on ramps of 30 rad/s^2: a tick's counted
    # speed is the mean over the tick before it, half a period (0.375 rad/s here, several
    # counts) behind the speed at the tick; the counts' mean speed taken at the tick instead of
    # at its counting interval's mid-time moves every unreported tick by G x that, one sign
    # for the whole ramp
    tick, accel = 0.025, 30.0
    n = 480
    t = tick * np.arange(n)
    q = 2.0 * math.pi / PPR
    phase = np.mod(t, 4.0)
    omega = np.where(phase < 1.0, accel * phase,
                     np.where(phase < 2.0, accel, np.where(phase < 3.0, accel * (3.0 - phase), 0.0)))
    theta = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1])) * tick])
    counts = np.floor(theta / q)
    w_cnt = np.concatenate([[0.0], np.diff(counts)]) * q / tick
    u = 0.05 + 0.01 * t - G * w_cnt
    frames = np.unique(np.round(np.arange(0.0, n / 2.16) * 2.16).astype(int))
    frames = frames[frames < n]
    prep, seen = _pi_prep(t, u, counts, w_cnt, frames, tick)
    fill = np.asarray(prep.duty[0])  # the line through the reported commands
    out, n_moved = UN.fill_count_level(prep)
    assert n_moved == int((~seen).sum())
    speeding_up = ~seen & (phase > 0.2) & (phase < 0.95)
    err = np.asarray(out.duty[0])[speeding_up] - u[speeding_up]
    lag_move = G * accel * tick / 2.0
    # the fill's error while speeding up keeps no one-signed share of the lag's move
    assert abs(float(np.mean(err))) < 0.2 * lag_move
    assert _interval_mean_error(np.asarray(out.duty[0]), u, seen) \
        <= _interval_mean_error(fill, u, seen)


def test_the_gain_holds_with_a_third_of_the_frames_lost() -> None:
    # 30 % of the frames lost at random: the reported ticks are 1, 2 or 3 frames apart, and the
    # plain mean of a tick's two neighbours is not the trend at its time.  On a 60 rad/s^2 ramp
    # with a count a tick of 1.05 rad/s (as hb28_tr_null_slip's 3.4 ms loop: 1.0 rad/s) the
    # counted speed's trend then leaks into its second differences, which the command does not
    # follow by -G: the fitted gain, and the level taken out, shrank (0.44 of the line's error
    # left with the plain mean, 0.20 with the line at the tick's time)
    rng = np.random.default_rng(3)
    n_frames = 1200 // FRAME
    drop = tuple(int(i) for i in np.flatnonzero(rng.random(n_frames) < 0.3)
                 if 0 < i < n_frames - 1)
    prep, u, seen = _pi_run(drop=drop, ppr=3000, accel=60.0, top=20.0)
    line = _interval_mean_error(np.asarray(prep.duty[0]), u, seen)
    out, _ = UN.fill_count_level(prep)
    refined = _interval_mean_error(np.asarray(out.duty[0]), u, seen)
    assert line > 0.005
    assert refined < 0.3 * line


def _cruise_run(u_of: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray], seed: int = 5
                ) -> tuple[PreparedRun, np.ndarray, np.ndarray]:
    """A wheel near 4.7 rad/s (1.5 counts a tick: the counted speed beats between two levels),
    its command u_of(t, counted speed, speed), seen every FRAME ticks with 30 % of the frames
    lost at random: (the prepared run with the line fill, the true commands, the reported mask)."""
    n = 2000
    t = TICK * np.arange(n)
    q = 2.0 * math.pi / PPR
    omega = 4.5 + 0.3 * t
    theta = np.cumsum(omega) * TICK
    counts = np.floor(theta / q)
    w_cnt = np.concatenate([[0.0], np.diff(counts)]) * q / TICK
    u = u_of(t, w_cnt, omega)
    rng = np.random.default_rng(seed)
    n_frames = n // FRAME
    keep = np.ones(n_frames, bool)
    keep[1:-1] = rng.random(n_frames - 2) >= 0.3
    frames = np.arange(0, n, FRAME)[keep]
    prep, seen = _pi_prep(t, u, counts, w_cnt, frames, TICK)
    return prep, u, seen


def test_the_gain_is_fitted_where_the_command_is_inside_its_limits() -> None:
    # a loop at full duty for three quarters of the run (as hb29_mj_null_slip's fast line near
    # the motors' no-load speed), then off the limit: the clamped commands do not
    # follow the count, and taken into the fit they pulled g to a fraction of the loop's (or
    # below 0, with lost frames)
    def u_of(t: np.ndarray, w_cnt: np.ndarray, omega: np.ndarray) -> np.ndarray:
        return np.clip(np.where(t < 3.0, 1.2, 0.9) - G * (w_cnt - omega), -1.0, 1.0)
    prep, u, seen = _cruise_run(u_of)
    out, n = UN.fill_count_level(prep)
    assert n == int((~seen).sum())
    late = seen & (prep.t_in > 3.1)
    line = _interval_mean_error(np.asarray(prep.duty[0]), u, late)
    refined = _interval_mean_error(np.asarray(out.duty[0]), u, late)
    assert line > 0.01
    assert refined < 0.3 * line
    # moved commands stay inside the duty's limits
    assert float(np.max(np.abs(np.asarray(out.duty[0])))) <= 1.0


def test_a_command_that_does_not_fall_with_the_count_is_not_moved() -> None:
    # the reported commands must establish the proportional response: a command that does not
    # follow the count (noise only), or rises with it, leaves the line fill as it is
    rng = np.random.default_rng(11)
    noise = 0.01 * rng.standard_normal(2000)
    for k in (0.0, -G):
        prep, _, _ = _cruise_run(lambda t, w_cnt, omega, k=k: 0.5 + noise - k * (w_cnt - omega))
        out, n = UN.fill_count_level(prep)
        assert n == 0 and out is prep


def test_ticks_between_commands_held_at_the_limit_are_not_moved() -> None:
    # a loop at full duty for three quarters of the run: there its count response is not seen,
    # and the unreported ticks between two reported commands at the limit stay on it (moved by
    # the gain of the run's last quarter, a third of them went below it)
    def u_of(t: np.ndarray, w_cnt: np.ndarray, omega: np.ndarray) -> np.ndarray:
        return np.clip(np.where(t < 3.0, 1.2, 0.9) - G * (w_cnt - omega), -1.0, 1.0)
    prep, u, seen = _cruise_run(u_of)
    out, n = UN.fill_count_level(prep)
    assert n == int((~seen).sum())
    held = ~seen & (prep.t_in < 2.9)
    assert np.all(u[held] == 1.0)
    assert np.all(np.asarray(out.duty[0])[held] == 1.0)


def test_a_run_whose_own_ticks_do_not_establish_the_gain_takes_the_cases() -> None:
    # the same loop in two runs: one off the limit throughout, one at full duty but for its
    # last 0.1 s (two triples inside the limits: no gain of its own); the case's gain, fitted
    # over both, takes the count level out of the second run's last frames as well
    def free(t: np.ndarray, w_cnt: np.ndarray, omega: np.ndarray) -> np.ndarray:
        return 0.6 - G * (w_cnt - omega)

    def late(t: np.ndarray, w_cnt: np.ndarray, omega: np.ndarray) -> np.ndarray:
        return np.clip(np.where(t < 3.9, 1.2, 0.9) - G * (w_cnt - omega), -1.0, 1.0)
    a, _, _ = _cruise_run(free, seed=6)
    b, u_b, seen_b = _cruise_run(late, seed=5)
    series = UN._gain_series(b)
    assert series is not None and UN.count_gain([series[0]]) is None
    own, n_own = UN.fill_count_level(b)
    assert n_own == 0
    gains = UN.count_gains([a, b])
    g_b = gains[1]
    assert g_b is not None and g_b[0] is not None and abs(g_b[0] - G) < 0.1 * G
    out, n = UN.fill_count_level(dataclasses.replace(b, count_gains=g_b))
    assert n == int((~seen_b).sum())
    tail = seen_b & (b.t_in > 3.9)
    assert _interval_mean_error(np.asarray(out.duty[0]), u_b, tail) \
        < 0.5 * _interval_mean_error(np.asarray(b.duty[0]), u_b, tail)
    # a run of another loop (other gains in meta.json) is fitted apart
    other = dataclasses.replace(a, run=SimpleNamespace(meta={"controller": "pi", "pi": {"kp": 1}},
                                                       telemetry=a.run.telemetry))
    assert UN.count_gains([other, b])[1] == (None, None)


def test_a_swinging_speed_moves_a_tick_by_no_more_than_a_count_level() -> None:
    # a 25 ms loop (a count a tick: 0.25 rad/s) tracking a reference that swings the wheel by
    # 6 rad/s at 2 Hz, seen every 2.56 ticks (64 ms frames): the command is G x the tracking
    # error, the reference minus the counted speed, the speed following the reference, so
    # only the count's quantization is in it.  The line through the reported counted speeds
    # departs from the counts' mean speed by the swing's curvature as well, which the command
    # does not follow; the count level a tick can carry is less than a count a tick (the
    # reported speeds' residues) plus a count over the interval (the counts' mean speed's).
    # Moved by more, with the loop's gain (the case's, as count_gains gives it), the fill
    # landed farther from the commands than the line (0.0046 against 0.0042, interval means)
    tick = 0.025
    n = 480
    t = tick * np.arange(n)
    q = 2.0 * math.pi / PPR
    omega = 10.0 + 6.0 * np.sin(2.0 * math.pi * 2.0 * t)
    theta = np.cumsum(omega) * tick
    counts = np.floor(theta / q)
    w_cnt = np.concatenate([[omega[0] * tick / q], np.diff(counts)]) * q / tick
    u = -G * (w_cnt - omega)
    frames = np.unique(np.round(np.arange(0.0, n / 2.56) * 2.56).astype(int))
    frames = frames[frames < n]
    prep, seen = _pi_prep(t, u, counts, w_cnt, frames, tick, count_gains=(G, G))
    fill = np.asarray(prep.duty[0])  # the line through the reported commands
    out, n_moved = UN.fill_count_level(prep)
    assert n_moved == int((~seen).sum())
    moved = np.abs(np.asarray(out.duty[0]) - fill)
    assert float(np.max(moved)) <= G * (q / tick + q / (2.0 * tick)) + 1e-12
    assert _interval_mean_error(np.asarray(out.duty[0]), u, seen) \
        < _interval_mean_error(fill, u, seen)
