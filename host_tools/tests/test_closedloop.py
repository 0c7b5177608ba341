"""lib/closedloop's driver (C ABI ``cl_*``, bound by host_tools.control.ClosedLoop) against
host_tools.control.resimulate_from_rest, the way the closed loop was run before it (the
lib/control binding stepped from Python, the plant re-simulated from rest at every tick).  Both
use the same C++ (lib/control, lib/slipmodel), so they must agree to rounding."""
from __future__ import annotations

import numpy as np
import pytest

from host_tools import params

WHEEL_R_M = params.ROBOT["r"]  # Table II.2

from _native_skip import needs_native  # noqa: E402

pytestmark = needs_native()

from host_tools.control import ClosedLoop, resimulate_from_rest  # noqa: E402

CTL_COLS = ("pwm_r", "pwm_l", "tau_cmd_r", "tau_cmd_l", "tau_max_r", "tau_max_l", "clamped_r",
            "sat_r", "omega_r", "omega_l", "x_odo_m", "y_odo_m", "phi_odo_rad", "v_d_m_s",
            "omega_d_rad_s", "e_x_m", "e_y_m", "e_phi_rad")


@pytest.mark.parametrize("case", [
    dict(kind="line", accel=72 * WHEEL_R_M, cruise=36 * WHEEL_R_M, radius=1.0, fixed_point=True,
         clamp=False, t0=0.0),
    dict(kind="arc", accel=0.8, cruise=0.5, radius=0.5, fixed_point=True, clamp=True, t0=12.3,
         start_pose=(0.2, -0.1, 0.3), effects={"motor_back_emf": {"ke_ratio": 1.2}}),
    dict(kind="figure_eight", accel=0.5, cruise=0.4, radius=0.6, fixed_point=False, clamp=True,
         t0=0.0, effects={"actuation_delay": {"delay_s": 0.03}}, ctl_params={"r": 0.037}),
    dict(kind="line", accel=72 * WHEEL_R_M, cruise=36 * WHEEL_R_M, radius=1.0, fixed_point=True,
         clamp=True, t0=0.0, actuator="torque", sub=5),
])
def test_driver_matches_the_resimulation_from_rest(case):
    n = 60  # 1.5 s
    old, st = resimulate_from_rest(n=n, **case)
    ctl_params = case.get("ctl_params") or {}
    loop = ClosedLoop(case["kind"], case["accel"], case["cruise"], case["radius"],
                      fixed_point=case["fixed_point"], clamp=case["clamp"],
                      ctl_robot=ctl_params, effects=case.get("effects"), t0_s=case["t0"],
                      start_pose=case.get("start_pose", (0.0, 0.0, 0.0)),
                      actuator=case.get("actuator", "duty"), rows_per_tick=case.get("sub", 1))
    new, rows = loop.run(n // 2, rows=True)
    more, rows2 = loop.run(n - n // 2, rows=True)      # continues where it stopped
    new = {c: np.concatenate([new[c], more[c]]) for c in new}
    rows = {c: np.concatenate([rows[c], rows2[c]]) for c in rows}
    assert np.allclose(new["t_s"], case["t0"] + 0.025 * np.arange(n), rtol=0, atol=1e-12)
    for c in ("theta_r_rad", "theta_l_rad"):
        np.testing.assert_allclose(new[c], old[c], rtol=0, atol=1e-9, err_msg=c)
    for c in CTL_COLS:
        np.testing.assert_allclose(new[c], old[c], rtol=0, atol=1e-9, err_msg=c)
    assert np.abs(old["tau_cmd_r"]).max() > 0.02  # the loop really drove the plant
    # the plant rows of the last re-simulation (every row but the one still to be stepped)
    m = n * case.get("sub", 1) - case.get("sub", 1)
    for c in ("x_m", "y_m", "phi_rad", "dtheta_r_rad_s", "tau_r_nm", "slip_r", "t_s"):
        np.testing.assert_allclose(rows[c][:m], st[c][:m], rtol=0, atol=1e-9, err_msg=c)


def test_slip_is_counted_per_euler_step_and_the_clamp_prevents_it():
    a = 72 * WHEEL_R_M
    off = ClosedLoop("line", a, a / 2, clamp=False).run(120)
    on = ClosedLoop("line", a, a / 2, clamp=True).run(120)
    assert off["slip_steps"].sum() > 0 and on["slip_steps"].sum() == 0
    first = int(np.argmax(off["slip_steps"] > 0))
    assert off["t_s"][first] < off["first_slip_t_s"][first] <= off["t_s"][first] + 0.025
    assert np.all(off["first_slip_t_s"][off["slip_steps"] == 0] == -1)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="reference"):
        ClosedLoop("line", 0.0, 0.5)
    with pytest.raises(ValueError, match="unknown key"):
        ClosedLoop("line", 1.0, 0.5, ctl_robot={"nonsense": 1.0})
    with pytest.raises(ValueError, match="bad value"):
        ClosedLoop("line", 1.0, 0.5, plant_robot={"r": -1.0})
    with pytest.raises(ValueError, match="inner period"):
        ClosedLoop("line", 1.0, 0.5, inner_s=0.0)
    with pytest.raises(ValueError, match="rows per tick"):
        ClosedLoop("line", 1.0, 0.5, rows_per_tick=0)
    with pytest.raises(ValueError, match="unknown effect"):
        ClosedLoop("line", 1.0, 0.5, effects={"gremlins": {}})
    with pytest.raises(ValueError, match="fixed-point"):
        ClosedLoop("line", 1.0, 0.5, ctl_robot={"r": 0.5})  # in range, beyond Q44 odometry


def test_drive_mode_tracks_the_velocity_commands_as_the_firmware_latches_them():
    """kind 'drive': the targets apply from the outer tick of their board time, ramp within the
    limits (lib/control drive.h) and the cascade tracks them: 0.3 m/s from t0 to t0 + 2 s is
    0.6 m (symmetric ramps), then a quarter turn on the spot (1 rad/s for pi/2 s)."""
    t0 = 0.5
    cmds = [{"t_s": t0, "v": 0.3, "omega": 0.0}, {"t_s": t0 + 2.0, "v": 0.0, "omega": 0.0},
            {"t_s": t0 + 3.0, "v": 0.0, "omega": 1.0}, {"t_s": t0 + 3.0 + np.pi / 2, "v": 0.0, "omega": 0.0}]
    # the firmware latches at outer ticks: a command between two ticks applies from the next one
    cmds[3]["t_s"] = t0 + 0.05 * np.ceil((cmds[3]["t_s"] - t0) / 0.05)
    for fixed in (True, False):
        loop = ClosedLoop("drive", 0.0, 0.0, 0.0, fixed_point=fixed, t0_s=t0,
                          drive={"accel": 1.0, "alpha": 4.0, "commands": cmds})
        out = loop.run(int(7.0 / 0.025))
        k2 = int(round(3.3 / 0.025))  # 2.8 s after t0: at rest after the first leg
        assert out["x_m"][k2] == pytest.approx(0.6, abs=0.01)
        assert abs(out["y_m"][k2]) < 2e-3
        turned = out["phi_rad"][-1]
        moved = np.hypot(out["x_m"][-1] - out["x_m"][k2], out["y_m"][-1] - out["y_m"][k2])
        assert turned == pytest.approx(0.05 * np.ceil(np.pi / 2 / 0.05), abs=0.03)
        assert moved < 0.01
        assert abs(out["v_m_s"][-1]) < 1e-3 and abs(out["omega_rad_s"][-1]) < 0.03  # settling


def test_drive_mode_refuses_bad_commands():
    with pytest.raises(ValueError, match="not sorted"):
        ClosedLoop("drive", 0, 0, 0, drive={"accel": 1.0, "alpha": 4.0, "commands": [
            {"t_s": 1.0, "v": 0.1, "omega": 0.0}, {"t_s": 0.5, "v": 0.0, "omega": 0.0}]})
    with pytest.raises(ValueError, match="out of range"):
        ClosedLoop("drive", 0, 0, 0, drive={"accel": 1.0, "alpha": 4.0, "commands": [
            {"t_s": 0.0, "v": 9.0, "omega": 0.0}]})
    with pytest.raises(ValueError, match="drive limits"):
        ClosedLoop("drive", 0, 0, 0, drive={"accel": 0.0, "alpha": 4.0, "commands": []})
