"""Firmware in the loop: the real megaatmega2560 firmware.elf in simavr against
lib/slipmodel's plant, recorded through the simulated XBee pty by the telemetry logger.

Skips (with the reason) only when the firmware cannot be built here; a simulator that does not
build or run is a failure.  Figures (ISR cycles per edge, task cycles, speed) are printed
(pytest -s) and stored in each run's fil.json; nothing here is timed.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from host_tools import fil
from host_tools import firmware_id
from host_tools import params
from host_tools import protocol as P
from host_tools import runfmt

D = P.definition()
BUDGET = {t["name"]: t["budget_cycles"] for t in D.tasks()}
ENC_BUDGET = next(i["budget_cycles_per_event"] for i in json.loads(Path(D.path).read_text())["timing"]["isr"]
                  if i["name"] == "encoder")
RUNNING = 1 << D.flags["status"]["running"]
FAILSAFE = D.enums["failsafe"]


def straight(accel: float, duration: float) -> dict:
    return {"profile": "straight", "wheel_accel": accel, "accel_time": 0.5, "duration": duration, "radius": 0.0}


def csv(path: Path) -> dict[str, np.ndarray]:
    a = np.genfromtxt(path, delimiter=",", names=True)
    return {n: a[n] for n in a.dtype.names}


@pytest.fixture(scope="module")
def run48(elf, sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("fil") / "straight48"
    code, lg, s = fil.record(out, elf, straight(48.0, 1.5), clamp=False)
    assert code == 0, lg.end_reason
    return out, lg, s


@pytest.fixture(scope="module")
def run72_clamped(elf, sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("fil") / "straight72_clamp"
    code, lg, s = fil.record(out, elf, straight(72.0, 1.5), clamp=True)
    assert code == 0, lg.end_reason
    return out, lg, s


def test_recording_is_a_run_with_groundtruth_on_the_board_clock(run48):
    out, lg, s = run48
    run = runfmt.load_run(out)
    tel, gt = run.telemetry, run.groundtruth
    assert run.meta["source"] == "fil" and run.meta["torque_clamp"] is False
    assert lg.end_reason == "experiment finished"
    assert tel["t_s"].size > 60 and gt is not None and gt["t_s"].size > 100
    assert set(runfmt.GROUNDTRUTH_COLUMNS) <= set(gt)


def test_groundtruth_and_telemetry_share_the_board_clock(run72_clamped):
    # no slip (clamp on): the odometry of each frame is the true position at most one inner
    # period (25 ms, its last update) before the frame's time stamp
    out, _, _ = run72_clamped
    run = runfmt.load_run(out)
    tel, gt = run.telemetry, run.groundtruth
    running = (tel["status"].astype(int) & RUNNING) != 0
    moving = running & (tel["x_odo_m"] > 0.01)
    t, x = tel["t_s"][moving], tel["x_odo_m"][moving]
    assert t.size > 30
    tol = 0.001
    early = np.interp(t - 0.026, gt["t_s"], gt["x_m"]) - tol
    late = np.interp(t, gt["t_s"], gt["x_m"]) + tol
    assert np.all((x >= early) & (x <= late)), float(np.max(np.maximum(early - x, x - late)))


def test_encoder_counts_equal_plant_wheel_angles(run48):
    out, _, s = run48
    tel = csv(out / "telemetry.csv")
    smp = csv(out / "encoder_samples.csv")
    smp_t = smp["t_s"][smp["boot"] == 1]
    n_checked = 0
    worst = 0.0
    for w in ("r", "l"):
        true = smp[f"counts_true_{w}"][smp["boot"] == 1]
        # each frame's counts were sampled by the frame's own enc_snapshot() call: the last one
        # before its time stamp (t_us is read right after it)
        i = np.searchsorted(smp_t, tel["t_s"] + 1e-6) - 1
        ok = (i >= 0) & (tel["t_s"] - smp_t[np.clip(i, 0, None)] < 0.005)
        err = tel[f"enc_{w}"][ok] - true[i[ok]]
        worst = max(worst, float(np.abs(err).max()))
        assert np.all(np.abs(err) <= 1.0), f"{w}: max |counts - plant angle| = {np.abs(err).max():.3f} counts"
        n_checked += int(ok.sum())
        assert tel[f"enc_{w}"].max() > 5000  # the wheels really turned (> 2.7 turns)
    assert n_checked >= 120
    assert s["encoder_check"]["frames"] >= 60 and max(s["encoder_check"]["max_abs_err_counts_r"],
                                                     s["encoder_check"]["max_abs_err_counts_l"]) <= 1.0
    assert s["encoder_check"]["illegal_max_r"] == 0 and s["encoder_check"]["illegal_max_l"] == 0
    print(f"\nencoder: {n_checked} frame counts vs plant angle, worst {worst:.3f} counts")


def test_motor_outputs_read_back_as_the_commanded_duty(run48):
    # the duty the simulator reads from OCR3C/OCR1A, COM bits and DIR/BRAKE pins equals the duty
    # the firmware reports (pwm_r/l, its Q15 command) within one PWM count: fast PWM gives
    # (OCR + 1) / (TOP + 1), the firmware writes OCR = round(800 |d|) - 1 (median difference 0)
    out, _, _ = run48
    tel = csv(out / "telemetry.csv")
    pl = csv(out / "plant.csv")
    run = ((tel["status"].astype(int) & RUNNING) != 0) & (np.abs(tel["pwm_r"]) > 0.05) & (np.abs(tel["pwm_r"]) < 0.95)
    assert run.sum() > 30
    k = np.searchsorted(pl["t_s"], tel["t_s"][run])  # the plant step after the frame
    for w in ("r", "l"):
        d = pl[f"duty_{w}"][k] - tel[f"pwm_{w}"][run]
        # a duty set just before the frame reaches the plant at the next step: skip those
        d = d[np.abs(d) < 0.01]
        assert d.size > 0.8 * run.sum()
        # bound: OCR is a whole count (+-0.5/800), the +1 count, the telemetry's 1e-4 resolution
        assert np.all(np.abs(d) <= 1.5 / 800 + 1e-4), np.abs(d).max()
        print(f"\nduty read from the timers - duty reported by the firmware ({w}): median {np.median(d) * 800:+.2f}"
              " PWM counts", end="")


def test_current_sense_reads_the_plant_armature_current(run48):
    # the firmware's own ADC code (A0/A1, AVcc reference) measures the plant's armature current
    # through the shield's volts per ampere (protocol.json current_sense): each frame reports the
    # latest conversion pair the 1 kHz tick started (adc_samples.csv: the sample instants), at
    # most a tick and a pair before the frame, so the analyzer may compare it with the plant at
    # the frame's time
    out, _, s = run48
    tel, adc, pl = csv(out / "telemetry.csv"), csv(out / "adc_samples.csv"), csv(out / "plant.csv")
    cs = D.current_sense
    lsb_a = cs["adc_vref_v"] / 2 ** cs["adc_bits"] / cs["volts_per_amp"]
    csv_a = 0.5e-4  # telemetry.csv's current columns have 4 decimals
    for w, name in ((0, "r"), (1, "l")):
        t_sh, i_sh = adc["t_s"][adc["wheel"] == w], adc["current_a"][adc["wheel"] == w]
        # the frame is built right after its time stamp; it reads the channel's latest completed
        # conversion, sampled at most a tick (1 ms) and a pair (208 us) before: of the samples
        # in [t - 1.25 ms, t + 0.25 ms] the one it reports (within the ADC's half count)
        meas_all = tel[f"current_{name}_a"]
        ks, ms = [], []
        for t_f, m in zip(tel["t_s"], meas_all):
            cand = np.nonzero((t_sh >= t_f - 1.25e-3) & (t_sh <= t_f + 0.25e-3))[0]
            if cand.size:
                ks.append(cand[int(np.argmin(np.abs(m - np.abs(i_sh[cand]))))])
                ms.append(m)
        k, meas = np.asarray(ks), np.asarray(ms)
        assert k.size >= 70
        # the ADC rounds: half a count of the current it sampled
        err = meas - np.abs(i_sh[k])
        assert np.all(np.abs(err) <= 0.5 * lsb_a + csv_a), np.abs(err).max() / lsb_a
        # the plant's own record: the step that holds the sample instant, within one count plus
        # the model's ripple (the change to the steps either side)
        j = np.clip(np.searchsorted(pl["t_s"], t_sh[k]), 1, pl["t_s"].size - 2)
        i_pl = np.abs(pl[f"current_{name}_a"])
        ripple = np.maximum(np.abs(i_pl[j - 1] - i_pl[j]), np.abs(i_pl[j + 1] - i_pl[j]))
        err_pl = np.abs(meas - i_pl[j])
        assert np.all(err_pl <= lsb_a + ripple + csv_a), float(np.max(err_pl - ripple) / lsb_a)
        assert meas.max() > 0.2, meas.max()  # currents well above the resolution were measured
        print(f"\ncurrent sense ({name}): {meas.size} frames, max {meas.max():.3f} A, "
              f"|frame - sampled| <= {np.abs(err).max() / lsb_a:.3f} counts, "
              f"|frame - plant| - ripple <= {np.max(err_pl - ripple) / lsb_a:.3f} counts", end="")
    assert s["current_sense"]["samples"] >= 2 * 70


def test_meta_carries_the_builds_firmware_id(run48):
    out, _, _ = run48
    meta = json.loads((out / "meta.json").read_text())
    assert meta["logger"]["firmware_id"] == firmware_id.revision(fil.ROOT)[1] != "unknown"


def test_no_task_overran_and_cycles_reported(run48):
    out, _, s = run48
    tel = csv(out / "telemetry.csv")
    run = (tel["status"].astype(int) & RUNNING) != 0
    assert run.sum() > 50
    for task in ("inner", "outer", "telemetry"):
        over = tel[f"{task}_overruns"][run]
        mx = tel[f"{task}_max_cyc"][run]
        assert over.max() == 0, f"{task} overran its budget during the experiment"
        assert 0 < mx.max() <= BUDGET[task], f"{task}: {mx.max()} cycles, budget {BUDGET[task]}"
        print(f"\n{task}: max {mx.max():.0f} cycles during the experiment (budget {BUDGET[task]})"
              f"; whole run incl. boot: max {s['tasks'][task]['max_cycles']}, overruns {s['tasks'][task]['overruns']}",
              end="")
    e = s["encoder_isr"]
    assert e["calls"] > 10000 and e["max_cycles"] <= ENC_BUDGET
    # One ISR per edge. The hardware merges two edges on one INT pin only when the second comes
    # before the first one's ISR has started (its flag still set); here the edges on one pin are
    # two counts apart, over 4000 cycles at this run's top wheel speed, against an ISR latency
    # of tens of cycles, so none merge. At the stop, at most one edge per INT pin (4) can still
    # be pending or in service.
    assert 0 <= e["edges_driven"] - e["calls"] <= 4
    print(f"\nencoder ISR: {e['mean_cycles']:.2f} cycles per edge mean, {e['max_cycles']} max "
          f"({e['calls']} calls, budget {ENC_BUDGET}); simulator speed {s['sim_s_per_wall_s']:.3f} simulated s per wall s")


def test_clamp_off_48_slips_clamp_on_72_does_not(run48, run72_clamped):
    _, _, s48 = run48
    out, lg, s72 = run72_clamped
    # without the clamp, 48 rad/s^2 exceeds what friction allows: the plant reports slip
    assert s48["slip"]["steps_slipping_r"] > 100 and s48["slip"]["steps_slipping_l"] > 100
    assert s48["slip"]["max_slip_speed_m_s"] > 0.1
    # with the clamp, 72 rad/s^2 is commanded, the robot moves, and no wheel slips while the
    # controller drives (from the release of the brake to the end of the experiment, when the
    # firmware brakes: see the braking figure printed below)
    pl = csv(out / "plant.csv")
    assert lg.end_reason == "experiment finished"
    t_on, t_off = s72["brake_off_t_s"][0], s72["brake_on_t_s"][-1]
    assert t_off - t_on > 1.4
    drive = (pl["t_s"] >= t_on) & (pl["t_s"] <= t_off)
    assert pl["x_m"][drive][-1] > 0.5
    r, b = run_r(out), params.ROBOT["b"]
    slip_r = pl["dtheta_r_rad_s"] * r - (pl["v_m_s"] + b * pl["omega_rad_s"])
    slip_l = pl["dtheta_l_rad_s"] * r - (pl["v_m_s"] - b * pl["omega_rad_s"])
    dt = float(np.median(np.diff(pl["t_s"])))
    v_slip = np.maximum(np.abs(slip_r), np.abs(slip_l))[drive]
    slid_m = float(np.sum(v_slip) * dt)
    # The clamp holds the torque exactly at the nominal tau_max (zero margin): from rest the
    # plant's contact sits on the friction limit and flags "slipping" for a few steps at
    # micrometre-per-second slip speeds. Not slipping = the contact points do not move
    # measurably (clamp off at 48 rad/s^2 they slide at ~0.5 m/s, checked above).
    assert v_slip.max() < 1e-3, f"slip speed {v_slip.max():.4f} m/s while driving"
    assert slid_m < 1e-4, f"wheels slid {slid_m * 1000:.3f} mm while driving"
    assert abs(pl["w_m_s"][drive]).max() < 1e-6
    flagged = int(((pl["slipping_r"] > 0) | (pl["slipping_l"] > 0))[drive].sum())
    after = pl["t_s"] > t_off
    print(f"\nclamp on, 72 rad/s^2, while driving ({drive.sum()} plant steps, x {pl['x_m'][drive][-1]:.3f} m): "
          f"max slip speed {v_slip.max() * 1000:.4f} mm/s, slid {slid_m * 1e6:.2f} um, {flagged} steps flagged at the "
          f"friction limit; clamp off at 48: max slip speed {s48['slip']['max_slip_speed_m_s']:.3f} m/s. "
          f"After the firmware brakes at {t_off:.3f} s: {(pl['slipping_r'][after] > 0).sum()} of {after.sum()} "
          f"plant steps slipping")
    meta = json.loads((out / "meta.json").read_text())
    assert meta["torque_clamp"] is True


def test_record_s_is_simulated_time_on_a_simulator_slower_than_real_time(elf, sim, tmp_path):
    """The length of a recording is simulated time: a simulator slower than real time (held to
    half of it here, as a loaded machine slows it) still records it whole; the wall clock,
    which would have cut it at half, is only the backstop."""
    out = tmp_path / "slow"
    code, lg, _ = fil.record(out, elf, None, record_s=1.0, args=["--realtime", "0.5"])
    assert code == 0, lg.end_reason
    assert lg.end_reason == "recorded 1 s"
    t = csv(out / "telemetry.csv")["t_s"]
    assert t[-1] - t[0] >= 1.0


def test_plant_effects_reach_the_plant_slippery_floor_defeats_the_nominal_clamp(elf, sim, tmp_path):
    # the firmware clamps at the nominal mu_s (Table II.2); on a floor with mu_s = 0.12 the same
    # clamp allows twice the torque the floor can take: the wheels slip although the clamp is on
    out = tmp_path / "slippery"
    keys = {"friction_coefficient.enabled": 1, "friction_coefficient.mu_s": 0.12, "friction_coefficient.mu_k": 0.11}
    code, lg, s = fil.record(out, elf, straight(48.0, 1.0), clamp=True, args=fil.sim_args(keys))
    assert code == 0, lg.end_reason
    # the caller's keys over the nominal model's normal forces (the simulator's default plant)
    assert s["plant_keys"] == {**fil.nominal_plant_keys(), **{k: float(v) for k, v in keys.items()}}
    meta = json.loads((out / "meta.json").read_text())
    assert meta["torque_clamp"] is True and "--set" in meta["fil"]["command"]
    assert s["slip"]["steps_slipping_r"] > 100 and s["slip"]["max_slip_speed_m_s"] > 0.05


def test_encoder_noise_counted_exactly_or_detected(elf, sim, tmp_path):
    # 3 us edge jitter and a 2 us bounce (one channel forth and back) on 2 % of the edges.
    # A bounce that lands before the ISR of the previous edge has read the pins shows both
    # channels changed: an illegal transition, which the firmware must flag and then stop the
    # motors (failsafe encoder_fault). Invariant: while no illegal transition is reported the
    # counts are within +-1 of the plant angle; after one, the motors stop.
    out = tmp_path / "noisy"
    code, lg, s = fil.record(out, elf, straight(48.0, 1.0), clamp=True,
                             args=["--enc-jitter-us", "3", "--enc-glitch", "0.02", "--seed", "11"])
    assert code == 0, lg.end_reason
    tel = csv(out / "telemetry.csv")
    smp = csv(out / "encoder_samples.csv")
    i = np.searchsorted(smp["t_s"], tel["t_s"] + 1e-6) - 1
    clean = (tel["illegal_r"] == 0) & (tel["illegal_l"] == 0) & (i >= 0)
    for w in ("r", "l"):
        err = tel[f"enc_{w}"][clean] - smp[f"counts_true_{w}"][i[clean]]
        assert np.all(np.abs(err) <= 1.0), f"{w}: {np.abs(err).max():.3f} counts without an illegal transition"
    assert tel["enc_r"][clean].max() > 20  # the wheels turned before any detection
    assert s["encoder_isr"]["edges_driven"] > 2 * abs(tel["enc_r"][clean]).max()
    detected = not clean[i >= 0].all()
    if detected:
        t_ill = tel["t_s"][~clean & (i >= 0)][0]
        assert any(e["code"] == FAILSAFE["encoder_fault"] for e in s["failsafe_events"])
        assert any(t_ill - 0.05 < t <= t_ill + 0.03 for t in s["brake_on_t_s"]), (t_ill, s["brake_on_t_s"])
    print(f"\nencoder noise: {s['encoder_isr']['edges_driven']} edges driven; "
          + (f"illegal transition reported at {t_ill:.3f} s -> encoder_fault, motors braked"
             if detected else "all counted, within +-1 count"))


def run_r(out: Path) -> float:
    return float(json.loads((out / "meta.json").read_text())["robot"]["r"])


def test_arc_left_turns_left_wiring_and_signs(elf, sim, tmp_path):
    # a straight line cannot tell the wheels apart: a left arc (radius +0.5 m) must turn the
    # plant counter-clockwise, with the right wheel (OCR3C/PB6, encoder on PD2/PD3) faster, and
    # the firmware's odometry heading must follow the true heading
    out = tmp_path / "arc"
    exp = {"profile": "arc", "wheel_accel": 20.0, "accel_time": 0.5, "duration": 1.5, "radius": 0.5}
    code, lg, s = fil.record(out, elf, exp, clamp=True)
    assert code == 0, lg.end_reason
    run = runfmt.load_run(out)
    tel, gt = run.telemetry, run.groundtruth
    running = ((tel["status"].astype(int) & RUNNING) != 0) & (tel["t_s"] > tel["t_s"][0] + 0.1)
    t, phi = tel["t_s"][running], tel["phi_odo_rad"][running]
    assert gt["phi_rad"][-1] > 0.6 and np.all(np.diff(gt["phi_rad"][gt["t_s"] < t[-1]]) > -1e-6)
    assert tel["enc_r"][running][-1] > 1.4 * tel["enc_l"][running][-1] > 0
    early = np.interp(t - 0.03, gt["t_s"], gt["phi_rad"]) - 0.005
    late = np.interp(t, gt["t_s"], gt["phi_rad"]) + 0.005
    assert np.all((phi >= early) & (phi <= late)), float(np.max(np.maximum(early - phi, phi - late)))


# ---------------------------------------------------------------- the two velocity loops

THESIS = 1 << D.flags["status"]["thesis_controller"]
CONTROLLER = D.enums["controller"]


@pytest.fixture(scope="module")
def runs_by_controller(elf, sim, tmp_path_factory):
    """48 rad/s^2 for 0.5 s, clamp off, once with each velocity loop set by the logger."""
    runs = {}
    for variant in ("thesis", "improved"):
        out = tmp_path_factory.mktemp("fil") / f"controller_{variant}"
        code, lg, _ = fil.record(out, elf, straight(48.0, 1.0), clamp=False, controller=variant)
        assert code == 0, lg.end_reason
        runs[variant] = (runfmt.load_run(out), lg)
    return runs


@pytest.mark.parametrize("variant", ["thesis", "improved"])
def test_controller_set_by_the_logger_is_what_the_firmware_reports(runs_by_controller, variant):
    run, lg = runs_by_controller[variant]
    assert run.meta["controller_variant"] == variant
    set_ctl = [c for c in run.meta["commands"] if c["command"] == "SetController"]
    assert set_ctl == [{"command": "SetController", "values": {"variant": variant}, "result": "ok"}]
    # the firmware's Params after the command carry it (the last report is the one after it)
    assert lg.params["controller"] == CONTROLLER[variant]
    # ... and so does the telemetry status of every frame of the experiment
    st = run.telemetry["status"].astype(int)
    running = (st & RUNNING) != 0
    assert running.sum() > 40
    assert np.all(((st[running] & THESIS) != 0) == (variant == "thesis"))


def _start_command_and_peak(run) -> tuple[np.ndarray, float, float]:
    """(first commanded torques r, l; peak command and wheel speed over the 0.5 s ramp)."""
    tel = run.telemetry
    running = (tel["status"].astype(int) & RUNNING) != 0
    i0 = int(np.flatnonzero(running)[0])
    ramp = running & (tel["t_s"] < tel["t_s"][i0] + 0.5)
    peak = float(max(tel["tau_cmd_r"][ramp].max(), tel["tau_cmd_l"][ramp].max()))
    omega_end = float(tel["omega_r"][np.flatnonzero(ramp)[-1]] + tel["omega_l"][np.flatnonzero(ramp)[-1]]) / 2
    return np.array([tel["tau_cmd_r"][i0], tel["tau_cmd_l"][i0]]), peak, omega_end


def test_thesis_and_improved_loops_command_what_their_feed_forward_says(runs_by_controller):
    """At the start tick the robot is at rest on its reference (no speed or pose error, no
    integral, no coupling terms at w = 0), so each wheel is commanded the feed-forward alone:
    tau = (r/2) m_ff (alpha r) = m_ff r^2 alpha / 2, with m_ff = m_t for the thesis's II.47
    and m_t + 2 I_wy / r^2 (the wheels' spin inertia too) for the improved loop. The first
    running frame reports that command (telemetry every 20 ms, the next tick 25 ms later).
    Tolerance 2e-4 N m: the telemetry's 1e-4 N m step plus the fixed-point feed-forward's
    rounding (dv in Q12, the gain (r/2) m_ff in Q18, the torque in Q16: < 1e-4 N m here)."""
    robot = runs_by_controller["thesis"][0].meta["robot"]
    alpha, r = 48.0, robot["r"]
    m_t = robot["m_r"] + 2 * robot["m_w"]
    m_ff = {"thesis": m_t, "improved": m_t + 2 * robot["I_wy"] / r**2}
    got = {}
    for variant, (run, _) in runs_by_controller.items():
        first, peak, omega_end = _start_command_and_peak(run)
        want = m_ff[variant] * r**2 * alpha / 2
        assert np.all(np.abs(first - want) <= 2e-4), (variant, first, want)
        got[variant] = (first.mean(), peak, omega_end)
        print(f"\n{variant}: start command {first.mean():.4f} N m (feed-forward {want:.4f}), peak over "
              f"the ramp {peak:.4f} N m, wheel speed at its end {omega_end:.2f} rad/s", end="")
    # over the ramp (clamp off, the motor): the improved loop follows the profile (about 45 of
    # 48 rad/s^2 in lib/control/README.md's plant, peak 0.142 N m), the thesis's lags it (28,
    # peak 0.109): its peak command is lower and its wheels are slower at the ramp's end
    assert got["thesis"][1] < got["improved"][1] - 0.02
    assert got["thesis"][2] < 0.75 * got["improved"][2]


def test_set_controller_refuses_a_bad_variant_and_while_running(elf, sim, tmp_path):
    """protocol.json: SetController.variant in [0, 1] (out_of_range, detail = the field's index
    otherwise), busy while an experiment runs; a refused command changes nothing."""
    typ = D.by_name["SetController"].type
    steps = [  # (board time s, frames to send)
        (0.10, D.frame(typ, 10, bytes([2])) + D.encode("RequestParams", 11)),
        (0.20, D.encode("SetController", 12, {"variant": "thesis"}) + D.encode("RequestParams", 13)),
        (0.30, D.encode("Start", 14, straight(20.0, 0.5))),
        (0.40, D.encode("SetController", 15, {"variant": "improved"}) + D.encode("RequestParams", 16)),
    ]
    host = HostScript(elf, tmp_path / "setcontroller", ["--t-end", "1.0"])

    def step(now, t):
        while steps and now >= steps[0][0]:
            host.port.write(steps.pop(0)[1])
        return None if now < 0.6 else False

    host.run(step)
    acks = {q: (D.result_names.get(r), typ_) for q, typ_, r in host.acks}
    assert acks[10] == ("out_of_range", typ)
    assert acks[12] == ("ok", typ) and acks[14][0] == "ok"
    assert acks[15] == ("busy", typ)
    # the last three Params answer RequestParams 11, 13 and 16 (those before: the boot's and the
    # answer to the host's first frame): after the refused value, after thesis, after the
    # refused change while running
    assert [p["controller"] for p in host.params[-3:]] == [CONTROLLER["improved"], CONTROLLER["thesis"],
                                                          CONTROLLER["thesis"]]
    assert [q for q, typ_, _ in host.acks if typ_ == D.by_name["RequestParams"].type][-3:] == [11, 13, 16]
    running = [t for t in host.telem if int(t["status"]) & RUNNING]
    assert running and all(int(t["status"]) & THESIS for t in running)


def test_host_silent_motors_stop_within_500ms(elf, sim, tmp_path):
    out = tmp_path / "silent"
    code, lg, s = fil.record(out, elf, straight(48.0, 3.0), clamp=True, args=["--host-silent-after-start", "0.4"])
    link = s["link"]
    assert link["down_silenced"] > 0  # the logger kept sending; nothing reached the robot
    last, t0 = link["last_down_frame_t_s"], s["experiment_start_t_s"]
    assert t0 > 0 and t0 < last <= t0 + 0.4  # heartbeats arrived while running, then silence
    stops = [t for t in s["brake_on_t_s"] if t > last]
    assert stops, "motors never stopped after the host went silent"
    dt = stops[0] - last
    print(f"\nhost silent: last host frame at {last:.4f} s, brake at {stops[0]:.4f} s: {dt * 1000:.1f} ms")
    assert dt <= 0.5
    assert any(e["code"] == FAILSAFE["host_timeout"] for e in s["failsafe_events"])
    pl = csv(out / "plant.csv")
    after = pl["t_s"] > stops[0] + 0.001
    assert np.all(pl["duty_r"][after] == 0) and np.all(pl["duty_l"][after] == 0)


def test_hang_in_main_loop_triggers_watchdog(elf, sim, tmp_path):
    out = tmp_path / "hang"
    code, lg, s = fil.record(out, elf, straight(48.0, 3.0), clamp=True, args=["--hang-after-start", "0.4"])
    hang = s["hang"]["set_t_s"]
    assert s["experiment_start_t_s"] > 0 and hang >= s["experiment_start_t_s"] + 0.4
    assert s["reset_t_s"], "no reset after the hang"
    dt = s["reset_t_s"][0] - hang
    print(f"\nhang at {hang:.4f} s, watchdog reset {dt * 1000:.1f} ms later")
    assert 0.1 < dt < 0.5  # WDTO_250MS: nominally 250 ms (the oscillator's tolerance aside)
    assert len(s["boot_t_s"]) == 2
    causes = s["reset_causes"]
    assert len(causes) == 2 and causes[1]["mcusr"] & (1 << D.flags["reset_cause"]["watchdog"])
    assert any(e["code"] == FAILSAFE["watchdog_reset"] and e["boot"] == 2 for e in s["failsafe_events"])
    assert lg.stats["robot_resets"] == 1
    # the reset is recognised from the boot counter (EEPROM, +1 per boot), which the firmware
    # reports in every frame: one step, at the reset
    boots = csv(out / "telemetry.csv")["boot_count"].astype(int)
    assert np.count_nonzero(np.diff(boots)) == 1 and (boots[-1] - boots[0]) % 65536 == 1
    # motors off from the reset on (boot code makes the pins safe before main)
    pl = csv(out / "plant.csv")
    after = pl["t_s"] > s["reset_t_s"][0] + 0.001
    assert after.sum() > 10 and np.all(pl["duty_r"][after] == 0) and np.all(pl["duty_l"][after] == 0)


class HostScript:
    """A host on the simulator's pty, paced by the robot's board time (telemetry t_us):
    ``step(t_board, telemetry)`` is called for every telemetry frame and may write."""

    def __init__(self, elf, out, args):
        import serial
        self.sm = fil.Sim(elf, out, args)
        self.port = serial.serial_for_url(self.sm.pty, baudrate=D.baud, timeout=0.02)
        self.dec = P.StreamDecoder(D.version, D.max_payload)
        self.acks: list[tuple[int, int, int]] = []  # (cmd seq, cmd type, result)
        # per Ack: the time stamp of the last telemetry frame before it in the stream (-1: none).
        # The firmware handled the command after it queued that frame (an Ack may only overtake
        # telemetry), so this bounds its receipt on the board clock, whatever the host's latency
        self.ack_after_t: list[float] = []
        self.telem: list[dict] = []
        self.params: list[dict] = []  # Params frames, raw field values

    def run(self, step, wall_s=60.0):
        import serial
        t0 = time.monotonic()
        try:
            # the simulator holds the board after boot until the host's first byte arrives
            self.port.write(D.encode("RequestParams", 0))
            while time.monotonic() - t0 < wall_s:
                try:
                    data = self.port.read(4096)
                except serial.SerialException:
                    break  # the simulator ended (t_end)
                for f in self.dec.feed(data):
                    msg, raws = D.unpack(f)
                    if msg.name == "Ack":
                        self.acks.append((raws[0], raws[1], raws[2]))
                        self.ack_after_t.append(self.telem[-1]["t_us"] if self.telem else -1.0)
                    elif msg.name == "Params":
                        self.params.append(dict(zip(msg.field_names(), raws)))
                    elif msg.name == "Telemetry":
                        t = D.physical(msg, raws)
                        self.telem.append(t)
                        if step(t["t_us"], t) is False:
                            return
        finally:
            self.port.close()
            self.sm.wait(60)


def test_only_known_host_messages_feed_the_host_timeout(elf, sim, tmp_path):
    """Only known host messages keep the robot driving: after 0.3 s of heartbeats the host sends
    only valid frames (CRC right) of an unknown type and Heartbeats one byte too long, every
    20 ms: the robot must brake on the host timeout as if the host were silent."""
    unknown = next(t for t in range(1, 256) if t not in D.by_type)
    hb_type = D.by_name["Heartbeat"].type
    running = 1 << D.flags["status"]["running"]
    st = {"seq": 3, "last_start": -1.0, "t_run": None, "last_hb": None, "last_junk": -1.0,
          "stop": None, "junk": 0}
    start = D.encode("Start", 2, {"profile": "straight", "wheel_accel": 48.0, "accel_time": 0.5,
                                  "duration": 3.0, "radius": 0.0})
    host = HostScript(elf, tmp_path / "junk", ["--t-end", "4"])

    def step(now, t):
        run = bool(int(t["status"]) & running)
        if st["t_run"] is None:
            if run:
                st["t_run"] = now
            elif now - st["last_start"] >= 0.1:  # bytes sent before the USART is up are lost
                host.port.write(D.encode("SetClamp", 1, {"on": 1}) + start)
                st["last_start"] = now
            return None
        if not run:
            st["stop"] = now
            return False
        if now - st["t_run"] < 0.3:
            if st["last_hb"] is None or now - st["last_hb"] >= 0.1:
                host.port.write(D.encode("Heartbeat", st["seq"] & 0xFFFF))
                st["seq"] += 1
                st["last_hb"] = now
        elif now - st["last_junk"] >= 0.02:
            host.port.write(D.frame(unknown, st["seq"], b"\x01\x02\x03")
                            + D.frame(hb_type, st["seq"] + 1, b"\x00"))
            st["seq"] += 2
            st["junk"] += 2
            st["last_junk"] = now
        return None

    host.run(step)
    assert st["t_run"] is not None, "the experiment never started"
    assert st["stop"] is not None, "the robot kept driving while only junk frames arrived"
    codes = {int(t["failsafe"]) for t in host.telem if t["t_us"] >= st["stop"]}
    assert FAILSAFE["host_timeout"] in codes
    # the last Heartbeat the firmware took (its Ack ok) came after the telemetry frame of time
    # stamp rx_t: the host timeout runs from there on the board clock, however late the host
    # (paced by telemetry it reads behind the board under load) wrote it
    rx_t = max(t_prev for (_, typ, r), t_prev in zip(host.acks, host.ack_after_t)
               if typ == hb_type and D.result_names.get(r) == "ok" and t_prev < st["stop"])
    dt = st["stop"] - rx_t
    print(f"\njunk frames only: {st['junk']} sent; last Heartbeat sent at {st['last_hb']:.3f} s, "
          f"taken after the frame of {rx_t:.3f} s, stopped (host_timeout) {dt * 1000:.0f} ms "
          "later by telemetry")
    assert 0.45 <= dt <= 0.7  # 498.5 ms + a telemetry period + the frames' transmission
    # the junk reached the firmware as verified frames: it answered them
    results = {D.result_names.get(r) for _, typ, r in host.acks if typ in (unknown, hb_type)}
    assert {"unknown_type", "bad_length"} <= results


BURST = 50  # back-to-back host frames the firmware takes whole at 115200 baud (docs/firmware.md)


@pytest.mark.parametrize("name", ["Heartbeat", "SetMu"])
def test_a_burst_of_50_back_to_back_host_frames_is_received_whole(elf, sim, tmp_path, name):
    """A burst of 50 host frames back to back at the link's baud rate is received whole: every
    frame is decoded (no CRC, framing or overflow error), handled and answered ok. The 14-byte
    Acks outrun the uplink: those the transmit ring has no room for wait in the firmware's reply
    store and go before telemetry, which is what is dropped (counted in tx_drops). The failure
    modes this guards: UBRR written before U2X (simavr then receives at half the baud rate), a
    controller rebuild per SetMu frame (16.6 ms each) overflowing the receive ring, and Acks
    dropped for the room telemetry took."""
    values = {"mu_s": 0.30, "mu_k": 0.28} if name == "SetMu" else None
    burst = b"".join(D.encode(name, 100 + i, values) for i in range(BURST))
    counters = ("rx_crc_errors", "rx_bad_frames", "rx_overflows", "tx_drops", "telemetry_overruns")
    st = {"before": None}
    host = HostScript(elf, tmp_path / "burst", ["--t-end", "1.2"])

    def step(now, t):
        if st["before"] is None and now >= 0.3:
            st["before"] = {k: int(t[k]) for k in counters}
            host.port.write(burst)  # 50 frames at once: back to back on the simulated wire

    host.run(step)
    after = {k: int(host.telem[-1][k]) for k in counters}
    d = {k: after[k] - st["before"][k] for k in counters}
    acks = [r for q, _, r in host.acks if 100 <= q < 100 + BURST]
    frames = [t for t in host.telem if t["t_us"] >= 0.3]
    print(f"\nburst of {BURST} {name}: {len(acks)} Acks, tx_drops +{d['tx_drops']}, "
          f"receive errors {d['rx_crc_errors']} CRC, {d['rx_bad_frames']} framing, "
          f"{d['rx_overflows']} ring overflows; {len(frames)} telemetry frames from 0.3 s, "
          f"telemetry overruns +{d['telemetry_overruns']}")
    assert d["rx_crc_errors"] == d["rx_bad_frames"] == d["rx_overflows"] == 0
    assert all(D.result_names.get(r) == "ok" for r in acks)
    assert sorted(q for q, _, _ in host.acks if 100 <= q < 100 + BURST) == list(range(100, 100 + BURST))
    # what was dropped is telemetry: each drop is a frame missing from the 50 Hz, and each
    # missing frame was dropped or not built (a release missed during the controller rebuild)
    due = round((host.telem[-1]["t_us"] - frames[0]["t_us"]) / 0.02) + 1
    assert len(frames) + d["tx_drops"] <= due <= len(frames) + d["tx_drops"] + d["telemetry_overruns"]


def test_request_params_behind_a_burst_of_acks_gets_its_params_at_the_first_ask(elf, sim, tmp_path):
    """A RequestParams that arrives while Acks and telemetry fill the transmit ring gets its Ack
    and its Params (105 bytes on the wire) at the first ask: the Params wait for room instead of
    being dropped, and go before the next telemetry frame. Three rounds, each 20 Heartbeats and
    a RequestParams back to back (280 bytes of Acks for 189 bytes received) right after a
    telemetry frame."""
    rounds = (0.3, 0.5, 0.7)
    n_hb = 20
    st = {"sent": [], "params_before": []}
    host = HostScript(elf, tmp_path / "rp", ["--t-end", "1.0"])

    def step(now, t):
        i = len(st["sent"])
        if i < len(rounds) and now >= rounds[i]:
            base = 1000 * (i + 1)
            st["params_before"].append(len(host.params))
            st["sent"].append((base, now))
            host.port.write(b"".join(D.encode("Heartbeat", base + k) for k in range(n_hb))
                            + D.encode("RequestParams", base + n_hb))

    host.run(step)
    assert len(st["sent"]) == len(rounds)
    # one Params per RequestParams (the boot's and the first-byte RequestParams' come before)
    n0 = st["params_before"][0]
    print(f"\nRequestParams behind {n_hb} Heartbeats, {len(rounds)} rounds: "
          f"{len(host.params) - n0} Params received, tx_drops {int(host.telem[-1]['tx_drops'])}")
    assert len(host.params) - n0 == len(rounds)
    rp = D.by_name["RequestParams"].type
    for base, _ in st["sent"]:
        got = sorted(q for q, _, r in host.acks if base <= q <= base + n_hb and D.result_names.get(r) == "ok")
        assert got == list(range(base, base + n_hb + 1)), f"round {base}: Acks {got}"
        assert any(q == base + n_hb and typ == rp for q, typ, _ in host.acks)


def test_corrupted_command_bytes_are_rejected(elf, sim, tmp_path):
    import serial
    out = tmp_path / "corrupt"
    sm = fil.Sim(elf, out, ["--link-dir", "down", "--link-ber", "0.06", "--seed", "7", "--t-end", "5"])
    port = serial.serial_for_url(sm.pty, baudrate=D.baud, timeout=0.05)
    dec = P.StreamDecoder(D.version, D.max_payload)
    acks: dict[int, int] = {}
    telem = []
    sent = []
    try:
        for seq in range(1, 61):
            port.write(D.encode("SetMu", seq, {"mu_s": 0.30, "mu_k": 0.28}))
            sent.append(seq)
            t_end = time.monotonic() + 0.03
            while time.monotonic() < t_end:
                for f in dec.feed(port.read(256)):
                    msg, raws = D.unpack(f)
                    if msg.name == "Ack":
                        acks[raws[0]] = raws[2]
                    elif msg.name == "Telemetry":
                        telem.append(D.physical(msg, raws))
        t_end = time.monotonic() + 0.5
        while time.monotonic() < t_end:
            for f in dec.feed(port.read(256)):
                msg, raws = D.unpack(f)
                if msg.name == "Ack":
                    acks[raws[0]] = raws[2]
                elif msg.name == "Telemetry":
                    telem.append(D.physical(msg, raws))
    finally:
        port.close()
        sm.wait(30)
    s = sm.summary()
    bad = set(s["link"]["down_corrupted_seqs"])
    ok = {q for q, r in acks.items() if D.result_names.get(r) == "ok"}
    assert s["link"]["down_frames"] == len(sent)
    assert len(bad) >= 10 and len(bad) <= len(sent) - 10, "want both corrupted and intact frames"
    assert not (ok & bad), f"corrupted frames accepted: {sorted(ok & bad)}"
    assert ok, "no intact command was accepted"
    rejected = {q for q, r in acks.items() if D.result_names.get(r) != "ok"}
    assert rejected & bad, "no corrupted frame was answered with a rejection"
    assert telem and telem[-1]["rx_crc_errors"] + telem[-1]["rx_bad_frames"] > 0
    print(f"\ncorruption: {len(sent)} SetMu sent, {len(bad)} corrupted on the link, {len(ok)} accepted (all intact), "
          f"{len(rejected & bad)} corrupted answered with a rejection, the rest dropped silently")


def test_corrupted_telemetry_is_rejected_by_the_logger(elf, sim, tmp_path):
    # bit errors on the robot->host link: the logger drops the damaged frames (CRC) and every row
    # it records is still exact (counts within +-1 of the plant angle at the frame's sample time)
    out = tmp_path / "uplink"
    code, lg, s = fil.record(out, elf, straight(48.0, 1.0), clamp=True,
                             args=["--link-dir", "up", "--link-ber", "0.002", "--seed", "5"])
    assert code == 0, lg.end_reason
    assert s["link"]["up_flipped"] > 5 and s["link"]["down_flipped"] == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta["logger"]["crc_errors"] + sum(meta["logger"]["rejected_blocks"].values()) > 0
    tel = csv(out / "telemetry.csv")
    smp = csv(out / "encoder_samples.csv")
    assert 0.6 * s["frames_from_robot"]["telemetry"] < tel["t_s"].size < s["frames_from_robot"]["telemetry"]
    i = np.searchsorted(smp["t_s"], tel["t_s"] + 1e-6) - 1
    ok = i >= 0
    for w in ("r", "l"):
        assert np.all(np.abs(tel[f"enc_{w}"][ok] - smp[f"counts_true_{w}"][i[ok]]) <= 1.0)


def test_camera_rate_noise_and_dropout(elf, sim, tmp_path):
    import subprocess
    out = tmp_path / "cam"
    r = subprocess.run([str(sim), str(elf), "--run-dir", str(out), "--no-wait-host", "--realtime", "0",
                        "--t-end", "0.5", "--cam-rate", "50", "--cam-noise-xy", "0.002", "--cam-noise-phi", "0.01",
                        "--cam-dropout", "0.2", "--seed", "5"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    gt = csv(out / "groundtruth.csv")
    s = json.loads((out / "fil.json").read_text())
    n = gt["t_s"].size + s["groundtruth"]["missing"]
    assert n == 25  # 50 Hz over 0.5 s
    assert 0 < s["groundtruth"]["missing"] < 12 and gt["t_s"].size == s["groundtruth"]["rows"]
    k = gt["t_s"] / 0.02
    assert np.allclose(k, np.round(k), atol=1e-4)  # samples on the 50 Hz grid of the board clock
    # the robot stands still at the origin: what is there is the noise
    assert 0.0005 < np.std(gt["x_m"]) < 0.005 and 0.002 < np.std(gt["phi_rad"]) < 0.03


@pytest.mark.parametrize("bad, message", [
    (["--set", "robot.mu_s=-1"], "bad value for 'robot.mu_s'"),
    (["--set", "effect.nope=1"], "unknown plant key 'effect.nope'"),
    (["--link-ber", "1.5"], "not a probability"),
    (["--plant-dt", "0.00000001"], "--plant-dt"),
    (["--frobnicate"], "unknown option --frobnicate"),
])
def test_bad_options_are_refused_clearly(elf, sim, tmp_path, bad, message):
    import subprocess
    r = subprocess.run([str(sim), str(elf), "--run-dir", str(tmp_path / "x")] + bad, capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 2 and message in r.stderr, r.stderr


def test_missing_elf_is_refused_clearly(sim, tmp_path):
    import subprocess
    r = subprocess.run([str(sim), str(tmp_path / "none.elf"), "--run-dir", str(tmp_path / "x")],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "cannot read" in r.stderr


def test_a_model_sent_to_the_simulator_is_the_plant_the_analyzer_replayed():
    """``fil record --model``: the model's keys with the nominal normal forces on top
    (``plant_config``), every robot key given so that none of the nominal's stays behind: a
    fitted load transfer's h is a centre-of-mass height (k^ h_s added), the wheels' mass sits on
    the axle of the model's robot (its payload included)."""
    from host_tools.analyzer.replay.normal_forces import plant_config
    from host_tools.params import ROBOT
    model = {"format": "ddmodel/1", "robot": {"m_r": ROBOT["m_r"] + 0.4},
             "effects": {"load_transfer": {"h": 0.09}, "payload": {"mass_kg": 0.4}}}
    keys = fil.model_plant_keys(model)
    want = plant_config({**ROBOT, "m_r": ROBOT["m_r"] + 0.4}, {"load_transfer": {"h": 0.09}})
    assert keys["load_transfer.h"] == pytest.approx(want.effects["load_transfer"]["h"])
    assert keys["load_transfer.h"] > 0.09                      # k^ h_s added
    assert keys["robot.d"] == pytest.approx(want.robot["d"]) and keys["robot.d"] < ROBOT["d"]
    assert keys["robot.m_r"] == pytest.approx(ROBOT["m_r"] + 0.4)
    assert keys["plant.spin_share"] == 0.0
    assert not any(k.startswith("payload.") for k in keys)   # folded into robot.m_r once
    # every key the nominal sets is overridden by the model's
    assert set(fil.nominal_plant_keys()) <= set(keys)


def test_lockstep_holds_the_board_clock_and_delivers_host_bytes_at_the_hold(elf, sim, tmp_path):
    """--lockstep: the simulator starts held at 50 ms of board time (no host byte read before;
    the AT line counts every byte the robot sent until then), "run T N" runs to board time T
    once the host's N bytes are read, and those bytes reach USART2 from the hold's board time
    on, however long the host took to write them (here 0.3 s of wall time, while a
    free-running simulator would have run on); "free" runs on; "hold G" stops the free-running
    clock at its next multiple of G. A bad control line ends the run with a reason."""
    import serial
    sm = fil.Sim(elf, tmp_path / "ls", ["--lockstep", "--realtime", "0", "--t-end", "5"])
    port = sm.wrap_port(serial.serial_for_url(sm.pty, baudrate=D.baud, timeout=0.02))
    try:
        port.write(D.encode("Heartbeat", 1))  # the simulator waits for the host's first byte
        assert sm.stepping and sm.start_hold() == pytest.approx(0.05, abs=1e-4)
        assert sm.up_at_hold > 0  # the boot's frames, in the pty before the hold
        while not sm.caught_up():
            port.read(1)
        assert port.read(64) == b""  # nothing more until the next grant
        t_at = sm.run_to(0.3)
        assert t_at == pytest.approx(0.3, abs=1e-4)
        time.sleep(0.3)
        frame = D.encode("Heartbeat", 2)
        port.write(frame)
        assert sm.run_to(0.5) == pytest.approx(0.5, abs=1e-4)
        sm.release()
        t_hold = sm.hold(0.1)
        assert t_hold >= 0.5 and abs(t_hold / 0.1 - round(t_hold / 0.1)) < 1e-2
        assert t_hold < round(t_hold, 1) + 1e-3
        sm.release()
        time.sleep(0.1)
    finally:
        port.close()
        sm.wait(30)
    s = sm.summary()
    assert s["lockstep"] is True and s["lockstep_holds"] == 4
    assert s["link"]["down_frames"] == 2
    # the second frame: written during the hold at 0.3 s, received whole its bytes later
    byte_s = 10 / s["link"]["baud"]  # 10 bits per byte at the USART's actual rate
    assert s["link"]["last_down_frame_t_s"] == pytest.approx(t_at + len(frame) * byte_s, abs=2e-6)

    bad = fil.Sim(elf, tmp_path / "bad", ["--lockstep", "--realtime", "0", "--t-end", "5"])
    p2 = serial.serial_for_url(bad.pty, baudrate=D.baud, timeout=0.02)
    try:
        p2.write(D.encode("Heartbeat", 1))
        bad.start_hold()
        with pytest.raises(fil.FilError):
            bad._control("run soon")  # not "run T N": the simulator ends, no further hold
    finally:
        p2.close()
        bad.wait(30)
    assert "bad control line" in bad.summary()["stop_reason"]
