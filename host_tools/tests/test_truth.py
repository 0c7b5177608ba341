"""The independent truth simulator (sim/truth): it agrees with lib/slipmodel where both model
the same physics, every effect changes the recording, and its runs are valid run folders with
the true state kept out of them."""
import numpy as np
import pytest

from host_tools import _native, runfmt, truth


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
    o = _native.Plant().simulate(t, np.full(t.size, u_r), np.full(t.size, u_l), "duty")
    assert np.abs(o["x_m"] - tel["true_x_m"]).max() < 1e-3
    assert np.abs(o["y_m"] - tel["true_y_m"]).max() < 1e-3
    assert np.abs(o["dtheta_r_rad_s"] - tel["true_dtheta_r"]).max() < 0.05
    assert (o["slip_r"].sum() > 0) == (tel["true_slip_r"].sum() > 0)


def test_closed_loop_matches_nominal_closed_loop_at_72():
    a = 72 * 0.0365
    s = truth.TruthSim()
    for k, v in {"ref.accel": a, "ref.cruise": a / 2, "ctl.clamp": 0, "sim.duration": 3.0,
                 "sim.tel_phase": 0.0, "sim.tel_period": 0.025}.items():
        s.set(k, v)
    tel, _ = s.run()
    n = truth.nominal_closed_loop("line", a, a / 2, clamp=False, T_s=3.0)
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
    from host_tools.suite.cases import _SINGLE
    params = _SINGLE[name][0]
    for u_r, u_l in ((0.6, 0.4), (1.0, 0.9)):
        tel, _ = _open_loop(u_r, u_l, T=1.5, **{})
        s = truth.TruthSim()
        for k, v in {"sim.open_loop": 1, "sim.u_r": u_r, "sim.u_l": u_l, "sim.duration": 1.5,
                     "sim.tel_phase": 0.0}.items():
            s.set(k, v)
        s.set_effect(name, **params)
        eff, _ = s.run()
        t = np.arange(0, 97) / 64.0
        p = _native.Plant()
        p.set_effect(name, **params)
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
