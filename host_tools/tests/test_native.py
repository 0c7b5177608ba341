"""Tests of host_tools._native: the ctypes binding of lib/slipmodel (no physics in Python)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from host_tools import _build, _native, params

P, MOTOR = params.ROBOT, params.MOTOR  # the table's values
M_T = P["m_r"] + 2 * P["m_w"]      # total mass, kg

# shared/spec/run-format.md, "Names of left-out physics"
RUN_FORMAT_EFFECTS = {
    "friction_coefficient": ["mu_s", "mu_k"], "wheel_radius": ["r_eff"],
    "track_width": ["b_eff"], "motor_back_emf": ["ke_ratio"], "driver_voltage_drop": ["volts"],
    "actuation_delay": ["delay_s"], "motor_lag": ["tau_s"], "axle_viscous": ["c"],
    "axle_coulomb": ["torque"], "caster_drag": ["mu"], "load_transfer": ["h"],
    "stribeck": ["mu_k0", "v_s"], "deadband": ["volts"], "motor_gain_asymmetry": ["ratio"],
    "floor_slope": ["rad"],
}
REQUIRED_COLUMNS = ["t_s", "x_m", "y_m", "phi_rad", "v_m_s", "omega_rad_s", "theta_r_rad",
                    "theta_l_rad", "dtheta_r_rad_s", "dtheta_l_rad_s", "tau_r_nm", "tau_l_nm",
                    "slip_r", "slip_l", "N_r", "N_l"]


@pytest.fixture(scope="module")
def plant():
    return _native.Plant()


def _const(t_end=2.0, dt=0.01, r=0.0, l=0.0):
    t = np.arange(0.0, t_end + dt / 2, dt)
    return t, np.full_like(t, r), np.full_like(t, l)


def test_library_builds_and_loads():
    path = _native.build()
    assert path == _native.library_path() and path.exists()
    assert _native.library().sm_effect_count() == len(RUN_FORMAT_EFFECTS)
    assert path.parent.name == "host" and path.parent.parent.name == ".build"


def test_effect_vocabulary_is_the_run_format_table():
    vocab = _native.effect_vocabulary()
    assert {k: list(v) for k, v in vocab.items()} == RUN_FORMAT_EFFECTS
    assert all(isinstance(x, float) and math.isfinite(x) for p in vocab.values() for x in p.values())


def test_columns():
    cols = _native.output_columns()
    assert cols[:len(REQUIRED_COLUMNS)] == REQUIRED_COLUMNS


def test_tau_max_and_normal_forces(plant):
    tr, tl = plant.tau_max()
    assert tr == pytest.approx(0.0924, abs=1e-4) and tl == tr
    nr, nl, nc = plant.normal_forces()
    assert nr + nl + nc == pytest.approx(M_T * P["g"], rel=1e-12)
    assert nc == pytest.approx(M_T * P["g"] * P["d"] / (P["d"] + P["e"]), rel=1e-12)


def test_simulate_rows_are_states_at_t(plant):
    t, r, l = _const(0.5, 0.02, 0.05, 0.05)
    out = plant.simulate(t, r, l, start_pose=(1.0, 2.0, 0.5))
    assert set(REQUIRED_COLUMNS) <= set(out)
    assert all(len(v) == len(t) for v in out.values())
    np.testing.assert_array_equal(out["t_s"], t)
    assert (out["x_m"][0], out["y_m"][0], out["phi_rad"][0]) == (1.0, 2.0, 0.5)
    assert out["v_m_s"][0] == 0.0
    assert out["tau_r_nm"][0] == pytest.approx(0.05)
    # rolled straight along the heading
    assert np.allclose(out["y_m"] - 2.0, np.tan(0.5) * (out["x_m"] - 1.0), atol=1e-12)


def test_ii61_through_python(plant):
    x = {}
    for tau in (0.09, 0.1, 0.3):
        out = plant.simulate(*_const(2.0, 0.01, tau, tau))
        x[tau] = out["x_m"][-1]
        assert (out["slip_r"].max() > 0) == (tau > 0.0924)
    a_roll = 2 * 0.09 / (P["r"] * (M_T + 2 * P["I_wy"] / P["r"] ** 2))
    assert x[0.09] == pytest.approx(0.5 * a_roll * 4.0, abs=1e-3)
    assert x[0.3] == pytest.approx(x[0.1], rel=0.01)


def test_inputs_are_held_and_dt_is_an_upper_bound(plant):
    # coarse output grid, fine internal step: same trajectory as a fine output grid
    t1, r1, l1 = _const(1.0, 0.1, 0.06, 0.02)
    t2, r2, l2 = _const(1.0, 0.001, 0.06, 0.02)
    a = plant.simulate(t1, r1, l1, dt_s=1e-3)
    b = plant.simulate(t2, r2, l2, dt_s=1e-3)
    assert a["phi_rad"][-1] == pytest.approx(b["phi_rad"][-1], rel=1e-9)
    # a step in the input at t = 0.5 s: no motion change before
    t = np.linspace(0, 1, 11)
    r = np.where(t < 0.5, 0.0, 0.05)
    out = plant.simulate(t, r, r)
    assert np.all(out["x_m"][:6] == 0.0) and out["x_m"][-1] > 0.0


def test_rows_at_one_instant_are_not_stepped(plant):
    """A row a sub-nanosecond before the next (a telemetry time and a tick time that two clocks
    rounded apart): the plant is not stepped over it. Stepped, the stick constraint's impulse
    over 1e-17 s gave the row after it a traction 0.09 N off, and every later row drifted."""
    t = np.round(np.arange(0.0, 0.6, 0.02), 12)
    duty = np.clip(t / 0.3, 0.0, 1.0) * 0.9          # a ramp: the wheels grip, then pull hard
    t2 = np.sort(np.r_[t, t[1:-1] + np.spacing(t[1:-1])])
    d2 = duty[np.searchsorted(t, t2, side="right") - 1]   # each input held from its row
    a = plant.simulate(t, duty, duty, mode="duty")
    b = plant.simulate(t2, d2, d2, mode="duty")
    rows = np.searchsorted(t2, t)
    for c in ("x_m", "dtheta_r_rad_s", "dtheta_l_rad_s", "slip_r", "slip_l"):
        assert np.max(np.abs(a[c] - b[c][rows])) < 1e-9, c
    # the forces applied just after t[k] are those of the row at the same instant that steps
    for c in ("F_r_n", "F_l_n", "N_r", "tau_r_nm"):
        assert np.max(np.abs(a[c][1:-1] - b[c][rows[1:-1] + 1])) < 1e-9, c


def test_duty_mode(plant):
    out = plant.simulate(*_const(4.0, 0.01, 0.3, 0.3), mode="duty")
    assert out["dtheta_r_rad_s"][-1] == pytest.approx(0.3 * MOTOR["no_load_rad_s"], rel=1e-3)


def test_effects_switch_and_clear():
    p = _native.Plant()
    base = p.simulate(*_const(0.5, 0.01, 0.3, 0.3), mode="duty")
    p.set_effect("motor_lag", tau_s=0.1)
    assert p.enabled_effects() == {"motor_lag": {"tau_s": 0.1}}
    lag = p.simulate(*_const(0.5, 0.01, 0.05, 0.05), dt_s=5e-4)
    # the torque builds up through the lag: row 10 is the step ending at 0.1 s + 0.5 ms
    assert lag["tau_r_nm"][10] == pytest.approx(0.05 * (1 - np.exp(-0.1005 / 0.1)), rel=1e-9)
    p.set_effect("stribeck")  # defaults
    assert p.get("stribeck.v_s") == 0.01
    p.clear_effects()
    assert p.enabled_effects() == {}
    again = p.simulate(*_const(0.5, 0.01, 0.3, 0.3), mode="duty")
    np.testing.assert_array_equal(again["x_m"], base["x_m"])


def test_parameters_from_dicts_and_meta():
    p = _native.Plant(robot={"mu_s": 0.5}, motor={"stall_nm": 1.0})
    assert p.get("robot.mu_s") == 0.5 and p.get("motor.stall_nm") == 1.0
    assert p.tau_max()[0] == pytest.approx(0.0924 * 0.5 / P["mu_s"], rel=1e-3)
    q = _native.Plant.from_meta({"robot": {"m_r": 2.0, "colour": "red"}, "motor": {}})
    assert q.get("robot.m_r") == 2.0
    assert set(_native.param_keys()) >= {"robot.I_wy", "motor.no_load_rad_s"}


@pytest.mark.parametrize("call, needle", [
    (lambda: _native.Plant(robot={"mass": 1.0}), "robot.mass"),
    (lambda: _native.Plant(robot={"m_r": -1.0}), "robot.m_r"),
    (lambda: _native.Plant(robot={"r": float("nan")}), "robot.r"),
    (lambda: _native.Plant(motor={"stall_nm": "x"}), "motor.stall_nm"),
    (lambda: _native.Plant().set_effect("wind"), "wind"),
    (lambda: _native.Plant().set_effect("stribeck", vs=1.0), "vs"),
    (lambda: _native.Plant().get("robot.nope"), "robot.nope"),
    (lambda: _native.Plant().set_effect("wheel_radius", r_eff=0.0), "wheel_radius.r_eff"),
    (lambda: _native.Plant().set_effect("motor_lag", tau_s=-1.0), "motor_lag.tau_s"),
])
def test_bad_keys_and_values_raise_clear_errors(call, needle):
    with pytest.raises(ValueError, match=needle):
        call()


def test_bad_simulate_inputs_raise_and_lose_nothing(plant):
    t, r, l = _const(0.2, 0.01, 0.05, 0.05)
    good = plant.simulate(t, r, l)
    bad_r = r.copy()
    bad_r[7] = np.nan
    with pytest.raises(ValueError, match=r"in_r\[7\]"):
        plant.simulate(t, bad_r, l)
    bad_t = t.copy()
    bad_t[5] = bad_t[4]
    with pytest.raises(ValueError, match=r"t_s\[5\]"):
        plant.simulate(bad_t, r, l)
    with pytest.raises(ValueError, match="length"):
        plant.simulate(t, r[:-1], l)
    with pytest.raises(ValueError, match="mode"):
        plant.simulate(t, r, l, mode="voltage")
    with pytest.raises(ValueError, match="dt_s"):
        plant.simulate(t, r, l, dt_s=0.0)
    with pytest.raises(ValueError, match="start_pose"):
        plant.simulate(t, r, l, start_pose=(0.0, float("inf"), 0.0))
    again = plant.simulate(t, r, l)
    np.testing.assert_array_equal(again["x_m"], good["x_m"])


def test_c_abi_rejects_bad_input_without_crashing():
    lib = _native._load()
    h = lib.sm_plant_new()
    try:
        assert lib.sm_plant_set(h, b"robot.unknown", 1.0) < 0
        assert lib.sm_plant_set(h, b"nodot", 1.0) < 0
        assert lib.sm_plant_set(h, b"stribeck.v_s", float("nan")) < 0
        assert lib.sm_plant_set(h, None, 1.0) < 0
        assert lib.sm_simulate(h, 0, 0, None, None, None, 1e-3, None) < 0
        assert lib.sm_simulate(None, 0, 1, None, None, None, 1e-3, None) < 0
        assert math.isnan(lib.sm_tau_max(h, 2))
        assert lib.sm_effect_name(99) is None and lib.sm_out_col_name(-1) is None
    finally:
        lib.sm_plant_free(h)


def test_bad_effect_value_changes_nothing():
    p = _native.Plant()
    p.set_effect("stribeck", mu_k0=0.24, v_s=0.02)
    with pytest.raises(ValueError, match="stribeck.v_s"):
        p.set_effect("stribeck", mu_k0=0.2, v_s=-1.0)
    assert p.enabled_effects() == {"stribeck": {"mu_k0": 0.24, "v_s": 0.02}}


def test_staleness_follows_sources():
    _native.build()
    assert not _native._is_stale()
    inputs = set(_build.TARGETS["ddrobot"].inputs())
    for rel in ("host_tools/native/slipmodel_capi.cpp", "host_tools/native/slipmodel_capi.h",
                "host_tools/native/ctl_columns.h", "lib/slipmodel/src/slipmodel/params.h",
                "lib/control/src/control/cascade.h", "lib/closedloop/src/closedloop/driver.h"):
        assert _build.ROOT / rel in inputs, rel


def test_vocabulary_copy_is_safe_to_modify():
    v = _native.effect_vocabulary()
    v["stribeck"]["v_s"] = 99.0
    assert _native.effect_vocabulary()["stribeck"]["v_s"] == 0.01


def test_run_format_defaults_are_the_library_defaults():
    """The Python side's defaults (runfmt, from run-format.md) must equal lib/slipmodel's
    Table II.2 and datasheet motor: one set of numbers, checked rather than trusted."""
    from host_tools import runfmt

    plant = _native.Plant()
    for group in ("robot", "motor"):
        for key, value in runfmt.DEFAULT_META[group].items():
            assert plant.get(f"{group}.{key}") == pytest.approx(value, rel=1e-6), f"{group}.{key}"
