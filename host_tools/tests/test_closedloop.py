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
