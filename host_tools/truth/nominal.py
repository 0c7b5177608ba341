"""lib/control in closed loop with the nominal plant (lib/slipmodel), run tick by tick by
lib/closedloop's driver (:class:`host_tools.control.ClosedLoop`). No physics in Python."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from host_tools import _native
from host_tools.control import INNER_S, ClosedLoop, Controller


def nominal_closed_loop(kind: str, accel_m_s2: float, cruise_m_s: float, radius_m: float = 1.0,
                        clamp: bool = True, T_s: float = 3.0, plant: _native.Plant | None = None,
                        fixed_point: bool = True, dt_s: float = 5e-4,
                        actuator: str = "duty",
                        params: Mapping[str, float] | None = None) -> dict[str, np.ndarray]:
    """The firmware's controller in closed loop with the *nominal* ``lib/slipmodel`` plant (or
    ``plant``'s parameters and effects), on the 25 ms / 50 ms schedule with quantised encoders,
    run by ``lib/closedloop``'s driver (:class:`host_tools.control.ClosedLoop`).
    ``actuator="duty"`` (default) applies the controller's PWM duty through the datasheet motor
    (torque-speed line, saturation), as the robot does; ``actuator="torque"`` applies its torque
    command after the clamp directly, an ideal torque source, as the thesis's Simulink model
    does (II.6). Returns per-tick arrays: ``t_s``, true pose ``x_m, y_m, phi_rad``, reference
    ``x_ref, y_ref``, controller columns (``pwm_r`` ... ``odo_status``), and plant columns at
    the tick (``slip_r``, ``slip_l``, ``dtheta_r_rad_s`` ...), plus ``slip_any`` (a wheel
    slipping at any of the tick's plant rows) and ``slip_fine``/``t_fine`` (per row).
    ``params``: controller keys (``ctl_describe``), e.g. ``{"controller": 1}`` for the thesis's
    velocity loop, or gains ``k_x`` ... The duty of a clamped wheel is ramped every millisecond
    as the firmware's 1 kHz tick does (``pwm_slope_r/l``), with 1 ms plant rows."""
    if actuator not in ("duty", "torque"):
        raise ValueError(f"actuator must be 'duty' or 'torque', got {actuator!r}")
    n = int(round(T_s / INNER_S))
    sub = 25 if actuator == "duty" else 5  # plant rows per tick, so that slip inside one is seen
    plant_robot, plant_motor, effects = {}, {}, {}
    if plant is not None:
        for key, v in plant.params().items():
            part, name = key.split(".", 1)
            (plant_robot if part == "robot" else plant_motor)[name] = v
        effects = plant.enabled_effects()
    loop = ClosedLoop(kind, accel_m_s2, cruise_m_s, radius_m, fixed_point=fixed_point,
                      clamp=clamp, plant_robot=plant_robot, plant_motor=plant_motor,
                      effects=effects, plant_dt_s=dt_s, rows_per_tick=sub, actuator=actuator,
                      ctl_params=params)
    ticks, rows = loop.run(n, rows=True)
    last = loop.state()
    res: dict[str, np.ndarray] = {"t_s": np.arange(n + 1) * INNER_S}
    for c in Controller().columns:
        res[c] = np.append(ticks[c], np.nan)
    for c in ("x_m", "y_m", "phi_rad", "slip_r", "slip_l", "dtheta_r_rad_s", "dtheta_l_rad_s",
              "tau_r_nm", "tau_l_nm", "v_m_s"):
        res[c] = np.append(ticks[c], last[c])
    slip = np.append((rows["slip_r"] != 0) | (rows["slip_l"] != 0),
                     last["slip_r"] != 0 or last["slip_l"] != 0)
    res["slip_any"] = np.append(slip[:n * sub].reshape(n, sub).any(axis=1), False)
    res["slip_fine"] = slip
    res["t_fine"] = np.append(rows["t_s"], last["t_s"])
    ref = Controller(fixed_point=fixed_point, clamp=clamp, params=params)
    ref.set_reference(kind, accel_m_s2, cruise_m_s, radius_m)
    refs = np.array([ref.reference(t) for t in res["t_s"]])
    res["x_ref"], res["y_ref"] = refs[:, 0], refs[:, 1]
    return res
