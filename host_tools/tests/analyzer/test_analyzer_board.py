"""The analyzer on this project's own firmware: the duty takes effect when the inner task's
computation ends (the board reports that task's cycles with every frame), and a clamped wheel's
duty ramps every millisecond between ticks (meta ``duty_ramp``), reported at the frame's own
time.  A replay that held the reported duty from the tick called the firmware in the loop's
nominal runs a mismatch (docs/analyzer.md)."""
from __future__ import annotations

import numpy as np
import pytest

from host_tools.analyzer.prepare import timing as PT
from host_tools.params import ENCODER_PPR
from host_tools.runfmt import Run


def _run(tel: dict, meta: dict) -> Run:
    run = Run.__new__(Run)
    run.telemetry, run.meta = tel, meta
    return run


def test_ramped_duty_reconstructed_from_frames():
    """Ticks every 25 ms (phase 3 ms), the duty set 0.6 ms after a tick, then +slope every
    millisecond; frames every 20 ms report the duty in force at their own time."""
    period, phase, lat = 0.025, 0.003, 0.0006
    ticks = phase + period * np.arange(0, 40)
    slope = np.where(np.arange(40) < 20, 1e-3 + 2e-5 * np.arange(40), 0.0)  # clamped, then not
    base = 0.1 + np.cumsum(np.r_[0.0, slope[:-1] * 24])                      # continuous ramps

    def duty_at(x):
        k = np.floor((x - phase) / period + 1e-9).astype(int)
        m = np.clip(np.floor((x - ticks[k]) / 1e-3 + 1e-9), 0, 24)
        return base[k] + slope[k] * np.where(x - ticks[k] < lat, 0, m)
    t = 0.0045 + 0.02 * np.arange(48)
    d = duty_at(t)
    t_in, (u_r, u_l) = PT._ramped_duty(t, (d, d), phase, period, np.full(t.size, lat))
    assert np.array_equal(u_r, u_l)
    # against the true duty at every input time: the ramp steps and the tick steps
    inside = (t_in > t[0] + period) & (t_in < t[-1] - period)
    err = np.abs(u_r[inside] - duty_at(t_in[inside] + 1e-7))
    # within a third of one ramp step, but for the two ticks before the clamp lets go (one frame
    # per tick cannot tell where the ramp stops: the slope of the ticks around it is used)
    k_in = np.floor((t_in[inside] - phase) / period + 1e-9).astype(int)
    settled = (k_in < 18) | (k_in > 19)
    assert err[settled].max() < 0.3 * slope.max(), err[settled].max()
    # the frame's duty held from its tick (what the replay did before): off by up to a tick's
    # ramp, everywhere the wheel is clamped
    kf = np.floor((t - phase) / period + 1e-9).astype(int)
    first = {k: d[np.flatnonzero(kf == k)[0]] for k in np.unique(kf)}
    held = np.abs(np.array([first.get(k, np.nan) for k in k_in]) - duty_at(t_in[inside] + 1e-7))
    ok = settled & np.isfinite(held)
    assert np.sqrt(np.mean(held[ok] ** 2)) > 5 * np.sqrt(np.mean(err[ok] ** 2))


def test_compute_latency_from_the_boards_task_cycles():
    t = 0.02 * np.arange(5)
    meta = {"periods_s": {"inner": 0.025}}
    lat = PT.compute_latency_s(_run({"t_s": t, "inner_last_cyc": np.full(5, 10240.0)}, meta))
    assert lat == pytest.approx(np.full(5, 10240 / 16e6))
    assert PT.compute_latency_s(_run({"t_s": t}, meta)) is None          # another recorder
    # never more than a period (a saturated or corrupt count)
    assert PT.compute_latency_s(_run({"t_s": t, "inner_last_cyc": np.full(5, 1e7)}, meta)).max() \
        == pytest.approx(0.025)


def test_board_rate_phase_ignores_a_few_restarted_speed_estimates():
    """A speed estimate restarted at the end of an experiment (the board reports 0 while the
    wheels still turn) is no count difference at any phase; two such frames in 120 must not
    make the recorder look like one whose speeds are not count differences."""
    k = 2 * np.pi / ENCODER_PPR
    period, phase = 0.025, 0.0111
    t = 0.0123 + 0.02 * np.arange(120)
    theta = 3.0 * np.minimum(t, 1.0) ** 2 + 6.0 * np.maximum(t - 1.0, 0.0)   # accelerate, cruise
    n = np.floor(theta / k)
    tick = phase + np.floor((t - phase) / period) * period
    w = k * (np.floor(np.interp(tick, t, theta) / k)
             - np.floor(np.interp(tick - period, t, theta) / k)) / period
    w[110:112] = 0.0
    tel = {"t_s": t, "enc_r": n, "enc_l": n, "omega_r": w, "omega_l": w}
    est = PT.board_rate_phase(tel, period, ENCODER_PPR)
    assert est is not None and abs((est - phase + period / 2) % period - period / 2) < 0.002
    w2 = w.copy()
    w2[::4] = 0.0   # a quarter of the frames: not a count-difference recorder
    assert PT.board_rate_phase({**tel, "omega_r": w2, "omega_l": w2}, period, ENCODER_PPR) is None


@pytest.mark.parametrize("clamp", [False, True])
def test_firmware_in_the_loop_nominal_run_is_no_mismatch(elf, sim, tmp_path, clamp):
    """The real firmware in simavr against the nominal plant, a camera of 1 mm / 10 mrad
    noise like the truth simulator's: nothing to explain.  With a noiseless camera (floor
    0.2 mm) the latency and the ramp replayed, one clamp-off run of five still drifted 1 mm
    sideways while both wheels slipped (the replay's slip does not reproduce the plant's to
    a fraction of a millimetre); before the latency and the ramp were replayed the camera was
    3.3 and 12.5 floors off on the noiseless runs."""
    from host_tools import fil
    from host_tools.analyzer.pipeline import analyze
    out = tmp_path / "fil"
    code, lg, _ = fil.record(out, elf, {"profile": "straight", "wheel_accel": 48.0,
                                        "accel_time": 0.5, "duration": 2.0, "radius": 0.0},
                             clamp=clamp, args=["--cam-noise-xy", "0.001",
                                                "--cam-noise-phi", "0.01"])
    assert code == 0, lg.end_reason
    res = analyze([str(out)], jobs=1, log=lambda m: None)
    assert res.verdict == "no_mismatch", res.localization
