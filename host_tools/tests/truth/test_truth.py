"""The independent truth simulator (sim/truth): it agrees with lib/slipmodel where both model
the same physics, every effect changes the recording, and its runs are valid run folders with
the true state kept out of them."""
import math

import numpy as np
import pytest

from host_tools import _native, params, runfmt, truth

ROBOT, MOTOR, PPR = params.ROBOT, params.MOTOR, params.ENCODER_PPR  # the table's values


def _truth_like_plant(effects=None, spin_share=1.0):
    """lib/slipmodel's plant with the truth simulator's normal forces, derived here by hand: the
    wheels' mass on the axle (the robot's centre of mass d_c = m_r d / m_t ahead of o, the
    caster where it was, the yaw inertia of the masses where they sit: the plant adds
    2 (I_wz + m_w b^2) to I_rz) and the pitch balance at the centre of mass's height with the
    share ``spin_share`` of the wheels' spin-up (the plant's load_transfer effect)."""
    R, fx = dict(ROBOT), {k: dict(v) for k, v in (effects or {}).items()}
    m_t = R["m_r"] + 2 * R["m_w"]
    d_c = R["m_r"] * R["d"] / m_t
    h = fx.pop("load_transfer", {}).get("h", R["h"])
    robot = {**R, "d": d_c, "e": R["d"] + R["e"] - d_c, "h": h,
             "I_rz": R["I_rz"] + R["m_r"] * (R["d"] - d_c) ** 2 + 2 * R["m_w"] * d_c ** 2}
    p = _native.Plant(robot=robot)
    p.set("plant.spin_share", spin_share)
    p.set_effect("load_transfer", h=h)
    for name, q in fx.items():
        p.set_effect(name, **q)
    return p


def _open_loop(u_r, u_l, T=2.0, **keys):
    s = truth.TruthSim()
    for k, v in {"sim.open_loop": 1, "sim.u_r": u_r, "sim.u_l": u_l, "sim.duration": T,
                 "sim.tel_phase": 0.0, **keys}.items():
        s.set(k, v)
    return s.run()


@pytest.mark.parametrize("u_r,u_l", [(0.3, 0.3), (1.0, 1.0), (1.0, 0.7), (-0.8, 0.5)])
def test_agrees_with_nominal_plant_rolling_and_slipping(u_r, u_l):
    # Two formulations (world-frame impulses + PGS at 0.2 ms vs body-frame force law at 0.5 ms)
    # of the same Coulomb physics must agree to well below the camera noise.
    tel, _ = _open_loop(u_r, u_l)
    t = tel["t_s"]
    o = _truth_like_plant().simulate(t, np.full(t.size, u_r), np.full(t.size, u_l), "duty")
    assert np.abs(o["x_m"] - tel["true_x_m"]).max() < 1e-3
    assert np.abs(o["y_m"] - tel["true_y_m"]).max() < 1e-3
    assert np.abs(o["dtheta_r_rad_s"] - tel["true_dtheta_r"]).max() < 0.05
    assert (o["slip_r"].sum() > 0) == (tel["true_slip_r"].sum() > 0)


def test_closed_loop_matches_nominal_closed_loop_at_72():
    a = 72 * ROBOT["r"]
    s = truth.TruthSim()
    for k, v in {"ref.accel": a, "ref.cruise": a / 2, "ctl.clamp": 0, "sim.duration": 3.0,
                 "sim.tel_phase": 0.0, "sim.tel_period": 0.025}.items():
        s.set(k, v)
    tel, _ = s.run()
    n = truth.nominal_closed_loop("line", a, a / 2, clamp=False, T_s=3.0,
                                  plant=_truth_like_plant())
    assert tel["true_slip_r"].sum() > 0
    assert np.abs(n["x_m"] - tel["true_x_m"][: n["x_m"].size]).max() < 2e-3


EFFECTS = {
    "friction_coefficient": {"mu_s": 0.15, "mu_k": 0.14}, "wheel_radius": {"r_eff": 0.038},
    "track_width": {"b_eff": 0.115}, "motor_back_emf": {"ke_ratio": 1.3},
    "driver_voltage_drop": {"volts": 1.5}, "actuation_delay": {"delay_s": 0.03},
    "motor_lag": {"tau_s": 0.04}, "axle_viscous": {"c": 0.002}, "axle_coulomb": {"torque": 0.02},
    "caster_drag": {"mu": 0.1}, "load_transfer": {"h": 0.04},
    "stribeck": {"mu_k0": 0.2, "v_s": 0.05}, "deadband": {"volts": 1.0},
    "motor_gain_asymmetry": {"ratio": 1.15}, "floor_slope": {"rad": 0.03},
    "eccentric_wheel": {"eps": 0.03}, "battery_sag": {"r_int": 1.0, "v_per_as": 0.5},
    "friction_patch": {"x0": 0.3, "x1": 0.8, "factor": 0.4},
    "payload": {"mass_kg": 0.5},
}


def _closed(effects):
    s = truth.TruthSim()
    for k, v in {"ref.kind": 1, "ref.accel": 1.5, "ref.cruise": 0.7, "ref.radius": 0.5,
                 "ctl.clamp": 0, "sim.duration": 1.5}.items():
        s.set(k, v)
    for name, p in effects.items():
        s.set_effect(name, **p)
    return s.run()


def test_vocabulary_covered_and_every_effect_acts():
    assert set(_native.effect_vocabulary()) <= set(EFFECTS)
    assert len(set(EFFECTS) - set(_native.effect_vocabulary())) >= 2
    base, _ = _closed({})
    for name, p in EFFECTS.items():
        tel, _ = _closed({name: p})
        # the effect shows in what the robot or the camera sees
        diff = max(np.abs(tel["pwm_r"] - base["pwm_r"]).max(),
                   np.abs(tel["pwm_l"] - base["pwm_l"]).max(),
                   100 * np.abs(tel["true_x_m"] - base["true_x_m"]).max())
        assert diff > 0.01, name


def test_bad_input_is_refused():
    s = truth.TruthSim()
    with pytest.raises(ValueError, match="unknown key"):
        s.set("robot.nonsense", 1.0)
    with pytest.raises(ValueError, match="outside"):
        s.set("robot.r", -1.0)
    with pytest.raises(ValueError, match="unknown effect"):
        s.set_effect("gremlins", x=1)
    with pytest.raises(ValueError, match="no parameter"):
        s.set_effect("motor_lag", tau=0.1)


def test_run_folder_valid_and_truth_hidden(tmp_path):
    run = tmp_path / "runs" / "r1"
    truth.simulate_run(run, {"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": 0.6},
                       {"motor_back_emf": {"ke_ratio": 1.2}}, duration_s=1.5, seed=3,
                       hidden_dir=tmp_path / "hidden")
    r = runfmt.load_run(run)
    assert r.groundtruth is not None and 30 < r.groundtruth["t_s"].size < 46  # 30 Hz, dropouts
    assert np.all(np.diff(r.telemetry["t_s"]) > 0) and abs(np.diff(r.telemetry["t_s"]).mean() - 0.02) < 1e-6
    text = "".join(p.read_text() for p in run.iterdir())
    assert "true_" not in text and "ke_ratio" not in text and "back_emf" not in text
    assert (tmp_path / "hidden" / "r1.truth.csv").exists()
    # counts are whole and quantised; the camera is noisy around the true pose
    assert np.all(r.telemetry["enc_r"] == np.round(r.telemetry["enc_r"]))


@pytest.mark.parametrize("name", sorted(_native.effect_vocabulary()))
def test_each_vocabulary_effect_agrees_with_slipmodel(name):
    """Same effect, same open-loop duties: the truth simulator and lib/slipmodel's plant agree
    to well below the effect's own size. The plant is sampled on a binary time grid (k/64 s):
    on decimal grids its actuation-delay history is cleared by sm_simulate's clock re-sync
    (reported to lib/slipmodel's owner)."""
    from host_tools.suite.cases import get
    params = get([f"{name}_strong"])[0].effects[name]
    for u_r, u_l in ((0.6, 0.4), (1.0, 0.9)):
        tel, _ = _open_loop(u_r, u_l, T=1.5, **{})
        s = truth.TruthSim()
        for k, v in {"sim.open_loop": 1, "sim.u_r": u_r, "sim.u_l": u_l, "sim.duration": 1.5,
                     "sim.tel_phase": 0.0}.items():
            s.set(k, v)
        s.set_effect(name, **params)
        eff, _ = s.run()
        t = np.arange(0, 97) / 64.0
        p = _truth_like_plant({name: params})
        o = p.simulate(t, np.full(t.size, u_r), np.full(t.size, u_l), "duty", 1.0 / 2048)
        xt, yt = np.interp(t, eff["t_s"], eff["true_x_m"]), np.interp(t, eff["t_s"], eff["true_y_m"])
        x0, y0 = np.interp(t, tel["t_s"], tel["true_x_m"]), np.interp(t, tel["t_s"], tel["true_y_m"])
        size = np.hypot(xt - x0, yt - y0).max()
        err = np.hypot(o["x_m"] - xt, o["y_m"] - yt).max()
        assert size > 3e-3, (name, size)
        assert err < 1.5e-3 and err < 0.2 * size, (name, u_r, u_l, err, size)


def test_command_line(tmp_path, capsys):
    run = tmp_path / "r"
    assert truth.main([str(run), "--ref", "arc", "--duration", "1.0",
                       "--effect", "eccentric_wheel:eps=0.02", "--hidden", str(tmp_path / "h")]) == 0
    assert runfmt.load_run(run).telemetry["t_s"].size == 50
    assert truth.main([str(tmp_path / "x"), "--effect", "gremlin:x=1"]) == 2
    assert truth.main([str(tmp_path / "x"), "--effect", "motor_lag:tau_s=abc"]) == 2
    assert truth.main([str(tmp_path / "x"), "--accel", "50"]) == 2
    assert "outside" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


# ------------------------------------------------------------------ motor current

def _current_relation(effects, u=0.6):
    """Open loop at duty u: the truth's armature current against its own DC motor model,
    I = stall_a (V_eff/supply_v - ke_ratio omega/no_load), at the frames from 0.1 s (spin-up
    included)."""
    s = truth.TruthSim()
    for k, v in {"sim.open_loop": 1, "sim.u_r": u, "sim.u_l": u, "sim.duration": 1.5,
                 "sim.tel_phase": 0.0}.items():
        s.set(k, v)
    for name, p in effects.items():
        s.set_effect(name, **p)
    tel, _ = s.run()
    m = tel["t_s"] >= 0.1
    return tel["true_i_r_a"][m], tel["true_dtheta_r"][m], s


@pytest.mark.parametrize("effects,v_eff,ke", [
    ({}, 0.6 * 12.0, 1.0),
    ({"axle_viscous": {"c": 0.004}}, 0.6 * 12.0, 1.0),
    ({"axle_coulomb": {"torque": 0.03}}, 0.6 * 12.0, 1.0),
    ({"motor_back_emf": {"ke_ratio": 1.2}}, 0.6 * 12.0, 1.2),
    ({"driver_voltage_drop": {"volts": 1.5}}, 0.6 * 10.5, 1.0),
    ({"deadband": {"volts": 1.0}}, 0.6 * 12.0 - 1.0, 1.0),
])
def test_current_is_the_electrical_side(effects, v_eff, ke):
    i, w, s = _current_relation(effects)
    assert s.get("motor.stall_a") == 2.0  # thesis III.1: 12 V, 2 A maximum
    model = 2.0 * (v_eff / 12.0 - ke * w / MOTOR["no_load_rad_s"])
    # a third of an ADC LSB (2.96 mA): the logged current is the drive step's before the
    # frame, whose wheel speed is 0.2 ms older (< 0.6 mA from 0.1 s on, 3 mA at 0.02 s)
    assert np.abs(i - model).max() < 1e-3
    assert i.max() > 0.15  # a real current flows (not a trivially zero column)


def test_axle_friction_lowers_the_speed_not_the_current_law():
    i0, w0, _ = _current_relation({})
    i1, w1, _ = _current_relation({"axle_viscous": {"c": 0.004}})
    # at the same duty the wheel turns slower, so more current flows (less back-EMF) ...
    assert w1[-1] < w0[-1] - 1.0 and i1[-1] > i0[-1] + 0.05
    # ... and the back-EMF case at the same duty differs although the current law is the same
    i2, w2, _ = _current_relation({"motor_back_emf": {"ke_ratio": 1.2}})
    assert abs(i2 - i0).max() > 0.01


def test_logged_current_is_the_shields_adc(tmp_path):
    run = tmp_path / "r"
    truth.simulate_run(run, {"kind": "arc", "accel": 1.0, "cruise": 0.6, "radius": 0.5},
                       {"motor_back_emf": {"ke_ratio": 1.15}}, duration_s=2.0, seed=1,
                       hidden_dir=tmp_path / "h")
    r = runfmt.load_run(run)
    tr = np.genfromtxt(tmp_path / "h" / "r.truth.csv", delimiter=",", names=True)
    lsb = 5.0 / 1024 / 1.65
    for side in ("r", "l"):
        a = r.telemetry[f"current_{side}_a"]
        raw = a / lsb
        assert np.all(a >= 0) and np.allclose(raw, np.round(raw), atol=1e-9)
        err = a - np.abs(tr[f"true_i_{side}_a"])
        assert np.abs(err).max() < 6 * lsb and 0.3 * lsb < err.std() < 2 * lsb  # ~1 LSB noise
        assert a.max() > 0.1
    assert r.meta["current_sense"]["stall_a"] == 2.0 and "stall_a" not in r.meta["motor"]
    assert r.meta["current_sense"]["volts_per_amp"] == 1.65
    r2 = truth.simulate_run(tmp_path / "nc", {"kind": "line"}, duration_s=0.5,
                            recorder={"current": False})
    assert "current_r_a" not in runfmt.load_run(r2).telemetry


# ------------------------------------------------------------------ recorder variants

ARC = {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.5}


def _rec_run(tmp_path, name, rec, ref=ARC, T=3.0, seed=4, effects=None):
    p = truth.simulate_run(tmp_path / name, ref, effects, duration_s=T, seed=seed,
                           hidden_dir=tmp_path / "h", recorder=rec)
    tr = np.genfromtxt(tmp_path / "h" / f"{name}.truth.csv", delimiter=",", names=True)
    return runfmt.load_run(p), tr


def _odometry(enc_r, enc_l, midpoint):
    """Independent re-computation of odometry from counts (nominal r, b)."""
    k = 2 * np.pi / PPR * ROBOT["r"]
    x = y = phi = 0.0
    out = [(0.0, 0.0, 0.0)]
    for i in range(1, enc_r.size):
        dr, dl = (enc_r[i] - enc_r[i - 1]) * k, (enc_l[i] - enc_l[i - 1]) * k
        ds, dp = 0.5 * (dr + dl), (dr - dl) / (2 * ROBOT["b"])
        if midpoint or abs(dp) < 1e-9:
            x += ds * np.cos(phi + dp / 2)
            y += ds * np.sin(phi + dp / 2)
        else:
            x += ds / dp * (np.sin(phi + dp) - np.sin(phi))
            y -= ds / dp * (np.cos(phi + dp) - np.cos(phi))
        phi += dp
        out.append((x, y, phi))
    return np.array(out)


@pytest.mark.parametrize("midpoint", [False, True])
def test_frame_odometry_is_the_recorders_own(tmp_path, midpoint):
    rec = {"odometry": "frames", "integration": "midpoint" if midpoint else "arc"}
    r, _ = _rec_run(tmp_path, "f", rec)
    t = r.telemetry
    first = np.flatnonzero((t["enc_r"] != 0) | (t["enc_l"] != 0))[0] - 1
    mine = _odometry(t["enc_r"][first:], t["enc_l"][first:], midpoint)
    assert np.abs(mine[:, 0] - t["x_odo_m"][first:]).max() < 1e-9
    assert np.abs(mine[:, 2] - t["phi_odo_rad"][first:]).max() < 1e-9
    other = _odometry(t["enc_r"][first:], t["enc_l"][first:], not midpoint)
    assert np.abs(other[:, 1] - t["y_odo_m"][first:]).max() > 1e-7  # the rule matters
    # the firmware's odometry (at the ticks) reports a different, older pose
    fw, _ = _rec_run(tmp_path, "fw", {})
    assert np.abs(fw.telemetry["x_odo_m"] - t["x_odo_m"]).max() > 2e-3


def test_tick_odometry_and_inner_periods(tmp_path):
    for inner in (0.010, 0.020, 0.025):
        r, tr = _rec_run(tmp_path, f"i{int(inner * 1e3)}", {"inner_s": inner, "odometry": "ticks"})
        assert r.meta["periods_s"] == {"inner": inner, "outer": 2 * inner, "telemetry": 0.02}
        t = r.telemetry
        # the torque command changes only at ticks: between two frames that hold no tick it
        # stays; with 10 ms ticks every frame interval holds one
        changed = np.flatnonzero(np.diff(t["tau_cmd_r"]) != 0)
        assert changed.size > 10
        if inner == 0.025:
            ticks = np.floor(t["t_s"] / inner + 1e-9)
            assert np.all(ticks[changed + 1] > ticks[changed])
        # the own odometry at the ticks follows the true pose within what a tick's age explains
        xo = np.interp(t["t_s"], tr["t_s"], tr["true_x_m"])
        assert np.abs(t["x_odo_m"] - xo).max() < 0.6 * inner + 2e-3


def test_pi_recorder(tmp_path):
    r, tr = _rec_run(tmp_path, "pi", {"controller": "pi"}, T=3.0)
    m = r.meta
    assert m["controller"] == "pi" and "reference" not in m and m["speed_reference"]["kind"] == "arc"
    assert m["torque_clamp"] is False and m["pi"]["kp"] > 0
    t = r.telemetry
    # the duty logged is the one the PI's torque asked for through the datasheet motor
    u = np.clip(t["tau_cmd_r"] / MOTOR["stall_nm"] + t["omega_r"] / MOTOR["no_load_rad_s"], -1, 1)
    assert np.abs(u - t["pwm_r"]).max() < 1e-12
    # its speed estimate is a count difference over the 25 ms tick: a multiple of one count
    q = t["omega_r"] * 0.025 / (2 * np.pi / PPR)
    assert np.abs(t["omega_r"]).max() > 5 and np.allclose(q, np.round(q), atol=1e-6)
    # and the loop tracks: the wheel speed reaches the reference's (v + b omega)/r at cruise
    late = tr["t_s"] > 2.0
    w_ref = (0.5 + ROBOT["b"] * 0.5 / 0.5) / ROBOT["r"]
    assert abs(np.mean(tr["true_dtheta_r"][late]) - w_ref) < 0.3
    # it differs from the cascade's recording of the same experiment
    c, _ = _rec_run(tmp_path, "c", {}, T=3.0)
    assert np.abs(c.telemetry["pwm_r"] - t["pwm_r"]).max() > 0.01


def test_jitter_drops_camera_and_headings(tmp_path):
    spin = {"kind": "segments", "accel": 0.6, "alpha": 3.0,
            "segments": [{"duration_s": 4.0, "v": 0.1, "omega": 2.0},
                         {"duration_s": 1.0, "v": 0.0, "omega": 0.0}]}
    base, _ = _rec_run(tmp_path, "b", {}, ref=spin, T=5.0)
    r, _ = _rec_run(tmp_path, "j", {"tel_jitter_s": 0.004, "tel_drop": 0.05, "cam_hz": 100,
                                    "heading_tel": "wrapped", "heading_gt": "unwrapped"},
                    ref=spin, T=5.0)
    dt = np.diff(r.telemetry["t_s"])
    assert dt.min() < 0.0165 and dt.max() > 0.06  # jitter, and a burst of lost frames
    assert 0.85 * 250 < r.telemetry["t_s"].size < 0.99 * 250
    assert 0.9 * 500 < r.groundtruth["t_s"].size <= 500  # 100 Hz camera
    phi = r.telemetry["phi_odo_rad"]
    assert phi.max() <= np.pi and phi.min() > -np.pi and np.ptp(base.telemetry["phi_odo_rad"]) > 6
    assert np.ptp(r.groundtruth["phi_rad"]) > 6  # ground truth left unwrapped
    w, _ = _rec_run(tmp_path, "w", {"heading_gt": "wrapped"}, ref=spin, T=5.0)
    assert np.abs(np.unwrap(w.groundtruth["phi_rad"]) - base.groundtruth["phi_rad"]).max() < 1e-9
    assert np.array_equal(w.telemetry["phi_odo_rad"], base.telemetry["phi_odo_rad"])


def test_segment_reference_is_tracked_and_written(tmp_path):
    from host_tools.suite.conceal import _segments_position
    r, tr = _rec_run(tmp_path, "s", {}, ref={"kind": "tour"}, T=30.0, seed=7)
    ref = r.meta["reference"]
    assert ref["kind"] == "segments" and len(ref["segments"]) >= 5
    assert abs(sum(s["duration_s"] for s in ref["segments"]) - 30.0) < 1e-6
    assert {"accel", "alpha"} <= set(ref)
    kinds = {("stop" if s["v"] == 0 and s["omega"] == 0 else "spin" if s["v"] == 0 else
              "arc" if s["omega"] else "cruise") for s in ref["segments"]}
    assert len(kinds) >= 3
    p = _segments_position(r.meta, tr["t_s"])
    err = np.hypot(tr["true_x_m"] - p[:, 0], tr["true_y_m"] - p[:, 1])
    assert np.ptp(p[:, 0]) > 1.0 and err.max() < 0.05  # the cascade follows the truth's reference
    # the same tour under the PI loop (no pose feedback) ends elsewhere but moves as much
    pi, tr2 = _rec_run(tmp_path, "sp", {"controller": "pi"}, ref={"kind": "tour"}, T=30.0, seed=7)
    assert pi.meta["speed_reference"] == ref


def test_long_run_with_delay(tmp_path):
    # the actuation delay's command history is a ring: long runs at 10 ms ticks work
    r, tr = _rec_run(tmp_path, "long", {"inner_s": 0.01}, ref={"kind": "tour"}, T=120.0,
                     effects={"actuation_delay": {"delay_s": 0.05}})
    assert r.telemetry["t_s"].size == 6000 and abs(tr["t_s"][-1] - 119.992) < 0.02


def test_recorder_options_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown recorder option"):
        truth.recorder_config({"odometer": "frames"})
    with pytest.raises(ValueError, match="odometry must be one of"):
        truth.recorder_config({"odometry": "camera"})
    with pytest.raises(ValueError, match="no lib/control odometry"):
        truth.recorder_config({"controller": "pi", "odometry": "firmware"})
    assert truth.recorder_config({"controller": "pi"})["odometry"] == "ticks"
    with pytest.raises(ValueError, match="outside"):
        truth.recorder_config({"tel_drop": 0.9})
    s = truth.TruthSim()
    s.set("ref.kind", 3)
    with pytest.raises(ValueError, match="segment list"):
        s.run()
    with pytest.raises(ValueError, match="segment 0"):
        s.set_segments([{"duration_s": -1, "v": 0.2, "omega": 0}])


def test_command_line_variants(tmp_path):
    run = tmp_path / "v"
    assert truth.main([str(run), "--ref", "tour", "--duration", "6", "--controller", "pi",
                       "--odometry", "frames", "--integration", "midpoint", "--inner-ms", "20",
                       "--tel-jitter-ms", "2", "--tel-drop", "0.05", "--cam-hz", "100",
                       "--cam-noise-mm", "2", "--heading-tel", "wrapped"]) == 0
    r = runfmt.load_run(run)
    assert r.meta["controller"] == "pi" and r.meta["periods_s"]["inner"] == 0.02
    assert r.meta["speed_reference"]["kind"] == "segments"
    assert r.groundtruth["t_s"].size > 450
    assert truth.main([str(tmp_path / "x"), "--ref", "segments"]) == 2
    assert truth.main([str(tmp_path / "x"), "--controller", "pi", "--odometry", "firmware"]) == 2


def test_telemetry_period_option(tmp_path):
    """``tel_s`` sets the frame period (and meta's), the frames sample the same motion."""
    base, _ = _rec_run(tmp_path, "b", {}, T=2.0)
    for tel_s in (0.04, 0.01):
        r, _ = _rec_run(tmp_path, f"t{tel_s}", {"tel_s": tel_s}, T=2.0)
        assert r.meta["periods_s"]["telemetry"] == tel_s
        dt = np.diff(r.telemetry["t_s"])
        assert np.allclose(dt, tel_s, atol=1e-6)
        assert abs(r.telemetry["t_s"].size - 2.0 / tel_s) <= 2
        # the counts at a common time agree with the 50 Hz recording's within a few counts
        t = base.telemetry["t_s"][10:-10]
        for c in ("enc_r", "enc_l"):
            a = np.interp(t, r.telemetry["t_s"], r.telemetry[c])
            assert np.abs(a - base.telemetry[c][10:-10]).max() < 0.05 * np.ptp(base.telemetry[c])
    with pytest.raises(ValueError):
        truth.recorder_config(tel_s=0.0)


def test_payload_is_mass_at_c():
    """payload.mass_kg: m_r + mass_kg at the platform's c, I_rz unchanged; the wheels' mass on
    the axle: at rest the caster carries only the platform's share, (m_r + mass_kg) g d/(d+e)
    (II.29 with the whole mass at c would give m_t g d/(d+e)), and the same duties accelerate
    the robot less."""
    m0 = ROBOT["m_r"] + 2 * ROBOT["m_w"]
    for extra in (0.0, 0.6):
        tel, _ = _open_loop(0.0, 0.0, T=0.1, **{"payload.mass_kg": extra})
        W = (m0 + extra) * ROBOT["g"]
        n = tel["true_N_r"][-1] + tel["true_N_l"][-1] + tel["true_N_c"][-1]
        assert n == pytest.approx(W, rel=1e-9)
        assert tel["true_N_c"][-1] == pytest.approx(
            (ROBOT["m_r"] + extra) * ROBOT["g"] * ROBOT["d"] / (ROBOT["d"] + ROBOT["e"]), rel=1e-9)
    light, _ = _open_loop(0.2, 0.2, T=0.3)
    heavy, _ = _open_loop(0.2, 0.2, T=0.3, **{"payload.mass_kg": 0.6})
    k = np.searchsorted(light["t_s"], 0.1)  # still accelerating: 4.4 against 3.9 rad/s
    assert heavy["true_dtheta_r"][k] < light["true_dtheta_r"][k] - 0.3


def test_external_plant_drives_the_recorder():
    """tr_set_plant: the recorder (controller, encoders, telemetry, camera) runs on another
    engine's state. A kinematic stand-in: wheel speed = duty x no-load speed, rolling."""
    import ctypes
    r, b, w0 = ROBOT["r"], ROBOT["b"], MOTOR["no_load_rad_s"]

    class Kinematic:
        error = None

        def __init__(self):
            self.s = [0.0] * 17
            self.calls = 0

        def plant_callback(self):
            proto = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double,
                                     ctypes.c_double, ctypes.c_double, ctypes.c_double,
                                     ctypes.POINTER(ctypes.c_double))

            def step(_u, t, dt, u_r, u_l, out):
                s = self.s
                s[5], s[6] = u_r * w0, u_l * w0
                s[3] += dt * s[5]
                s[4] += dt * s[6]
                v, w = r * (s[5] + s[6]) / 2, r * (s[5] - s[6]) / (2 * b)
                s[0] += dt * v * math.cos(s[2])
                s[1] += dt * v * math.sin(s[2])
                s[2] += dt * w
                for i, x in enumerate(s):
                    out[i] = x
                self.calls += 1
                return 0
            return proto(step)

    sim = truth.TruthSim()
    assert len(sim.plant_state_names()) == 17 and sim.plant_state_names()[:3] == ["x_m", "y_m", "phi_rad"]
    k = Kinematic()
    sim.set_plant(k)
    for key, v in {"ref.kind": 1, "ref.accel": 0.8, "ref.cruise": 0.5, "ref.radius": 0.5,
                   "sim.duration": 2.0, "sim.tel_phase": 0.0}.items():
        sim.set(key, v)
    tel, cam = sim.run()
    assert k.calls == round(2.0 / sim.get("sim.dt"))
    # the encoders count the stand-in's wheel angles, the camera sees its pose
    th = np.array(k.s[3:5])
    assert tel["enc_r"][-1] == np.floor(th[0] * PPR / (2 * math.pi))
    assert cam["x_m"][-1] == pytest.approx(tel["true_x_m"][-1], abs=0.02)
    # the cascade drives the stand-in around the arc: the heading grows by v/R
    assert tel["true_phi_rad"][-1] > 1.0
    sim.set_plant(None)
    own, _ = sim.run()
    assert own["true_x_m"][-1] != tel["true_x_m"][-1]


def test_reversal_reference():
    ref = truth.reversal_reference(60.0, seed=3)
    segs = ref["segments"]
    assert ref["kind"] == "segments" and ref["accel"] == 1.2 and ref["alpha"] == 6.0
    assert sum(s["duration_s"] for s in segs) == pytest.approx(60.0)
    assert segs[-1]["v"] == 0 and segs[-1]["omega"] == 0
    v = [s["v"] for s in segs]
    assert max(v) > 1.1 and min(v) < -0.5  # fast cruises, both ways
    assert any(a * b < 0 for a, b in zip(v, v[1:]))  # a direct reversal
    w = [s["omega"] for s in segs if s["v"] == 0 and s["omega"]]
    assert w and min(w) < 0 < max(w)  # spins both ways
    assert truth.reversal_reference(60.0, seed=3) == ref != truth.reversal_reference(60.0, seed=4)


def test_pwm_in_force_reports_the_delayed_duty(tmp_path):
    """Recorder option pwm=in_force: the pwm columns report the duty in force, the commanded
    one actuation_delay earlier (the plant and the torque command are the same run's).  With
    frames every 5 ms, finer than the 25 ms ticks, every tick's duty is seen."""
    ref = {"kind": "figure_eight", "accel": 0.6, "cruise": 0.5, "radius": 0.5}
    fx = {"actuation_delay": {"delay_s": 0.03}}
    runs = {pwm: runfmt.load_run(truth.simulate_run(
        tmp_path / pwm, ref, fx, clamp=True, duration_s=2.0, seed=5,
        recorder={"pwm": pwm, "tel_s": 0.005, "current": False})).telemetry
        for pwm in ("commanded", "in_force")}
    cmd, force = runs["commanded"], runs["in_force"]
    assert np.array_equal(cmd["t_s"], force["t_s"])
    assert np.array_equal(cmd["tau_cmd_r"], force["tau_cmd_r"])
    lag = 6   # 30 ms in 5 ms frames
    assert np.array_equal(force["pwm_r"][lag:], cmd["pwm_r"][:-lag])
    assert np.array_equal(force["pwm_l"][lag:], cmd["pwm_l"][:-lag])
    assert not np.array_equal(force["pwm_r"], cmd["pwm_r"])


@pytest.mark.parametrize("k", [1.0, 0.5, 0.0])
def test_spin_up_with_the_body_at_rest_unloads_the_caster(k):
    """Wheels spinning up on a floor without grip (the body stays at rest, a_x = 0): each
    wheel's theta'' = tau / I_wy, so the pitch balance gives N_c (d + e) = m_r g d - k (tau_r +
    tau_l) (sim.spin_share k; the wheels on the axle; the centre of mass on the ground, so that
    the floor's 0.001 m g of drag has no moment)."""
    keys = {"robot.mu_s": 0.001, "robot.mu_k": 0.001, "sim.spin_share": k,
            "load_transfer.h": 0.0}
    tel, _ = _open_loop(0.3, 0.3, T=0.2, **keys)
    R = ROBOT
    # late enough that the torque changes slowly (the balance uses the previous step's theta'')
    i = np.searchsorted(tel["t_s"], 0.1)
    tau = tel["true_tau_r_nm"][i] + tel["true_tau_l_nm"][i]
    assert tau > 0.05 and tel["true_slip_r"][i] == 1
    want = (R["m_r"] * R["g"] * R["d"] - k * tau) / (R["d"] + R["e"])
    assert tel["true_N_c"][i] == pytest.approx(want, abs=3e-3)  # k tau/(d+e): 0.5 N at k = 1


@pytest.mark.parametrize("h,k", [(None, 1.0), (0.0, 1.0), (None, 0.0), (0.08, 0.5)])
def test_pure_rolling_transfer_is_the_height_plus_the_spin_share(h, k):
    """While the wheels roll (theta'' = a / r) the pitch balance is a transfer at the height
    h + k h_s, h_s = 2 I_wy / (m_t r): N_c (d + e) = m_t g d_c - m_t a (h + k h_s), d_c = m_r d
    / m_t (load_transfer.h, default robot.h; sim.spin_share k)."""
    R = ROBOT
    m_t = R["m_r"] + 2 * R["m_w"]
    keys = {"sim.spin_share": k, **({} if h is None else {"load_transfer.h": h})}
    tel, _ = _open_loop(0.1, 0.1, T=0.6, **keys)  # 0.077 N m per wheel, under tau_max
    assert not tel["true_slip_r"].any()
    t, w = tel["t_s"], tel["true_dtheta_r"]
    i = np.searchsorted(t, 0.1)
    a = R["r"] * (w[i + 1] - w[i - 1]) / (t[i + 1] - t[i - 1])
    assert a > 0.3
    height = (m_t * R["g"] * R["m_r"] * R["d"] / m_t - tel["true_N_c"][i] * (R["d"] + R["e"])) / (m_t * a)
    h_s = 2 * R["I_wy"] / (m_t * R["r"])
    want = (R["h"] if h is None else h) + k * h_s
    assert height == pytest.approx(want, rel=0.02, abs=5e-4)
