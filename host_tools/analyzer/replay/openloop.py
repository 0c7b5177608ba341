"""Open-loop replay: the plant driven with the recorded duty or torque command."""
from __future__ import annotations

from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay import anchors
from host_tools.analyzer.replay.normal_forces import NOMINAL, NormalForces, plant_config

_NEEDED = {"x_m", "y_m", "phi_rad", "theta_r_rad", "theta_l_rad", "dtheta_r_rad_s",
           "dtheta_l_rad_s", "tau_r_nm", "tau_l_nm", "v_m_s", "omega_rad_s", "slip_r", "slip_l",
           "i_r_a", "i_l_a"}


def _zoh(t_in: np.ndarray, v: np.ndarray, grid: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(t_in, grid, side="right") - 1
    idx = np.clip(idx, 0, v.size - 1)
    out = v[idx].astype(float)
    out[grid < t_in[0]] = 0.0
    return out


class OpenLoopReplay:
    """Drive the plant with the recorded duty ("duty") or torque command ("torque").  The
    plant is the nominal model's (``normal_forces.plant_config``): the normal-force physics
    ``forces`` (default the nominal model's) and the run's robot parameters with ``params``
    over them (the tolerance ensemble's draws)."""

    def __init__(self, mode: str = "duty", dt_s: float = 5e-4, plant_factory: Any = None,
                 forces: NormalForces = NOMINAL, params: Mapping[str, float] | None = None):
        if mode not in ("duty", "torque"):
            raise ValueError(f"mode must be 'duty' or 'torque', not {mode!r}")
        self.mode = mode
        self.name = f"open-loop {mode}"
        self.dt_s = dt_s
        self.forces = forces
        self.params = dict(params or {})
        self._factory = plant_factory
        self._plants: dict[tuple[tuple[tuple[str, Any], ...], tuple[tuple[str, Any], ...]], Any] = {}

    def _plant(self, robot: dict[str, Any], motor: dict[str, Any]) -> Any:
        key = (tuple(sorted(robot.items())), tuple(sorted(motor.items())))
        p = self._plants.get(key)
        if p is None:
            factory = self._factory
            if factory is None:
                from host_tools import _native  # the one physics, via the C ABI
                factory = _native.Plant
            p = factory(robot=robot, motor=motor)
            self._plants[key] = p
        return p

    def _ready(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]]
               ) -> tuple[Any, tuple[np.ndarray, np.ndarray], np.ndarray]:
        """(plant with ``effects`` switched on, the replayed inputs, their times)."""
        cfg = plant_config({**prep.robot, **self.params}, effects, self.forces)
        plant = self._plant(cfg.robot, prep.motor)
        for key, value in cfg.keys.items():
            plant.set(key, value)
        plant.clear_effects()
        for name, params in cfg.effects.items():
            plant.set_effect(name, **{k: float(v) for k, v in params.items()})
        if self.mode == "duty":
            return plant, prep.duty, prep.t_in
        return plant, prep.torque, prep.t_in_tau

    def simulate(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]]
                 ) -> dict[str, np.ndarray]:
        plant, src, t_in = self._ready(prep, effects)
        grid = prep.t_grid
        # The plant is stepped on the replay grid itself (telemetry times and reconstructed
        # input times), each input held from its row to the next.  lib/slipmodel's
        # Plant::set_time keeps the actuation-delay line across the clock re-alignment at every
        # row, so no special time grid is needed.
        in_r = _zoh(t_in, src[0], grid)
        in_l = _zoh(t_in, src[1], grid)
        out = plant.simulate(grid, in_r, in_l, mode=self.mode, dt_s=self.dt_s,
                             start_pose=prep.start_pose)
        res = {k: np.asarray(v, float) for k, v in out.items() if k in _NEEDED}
        res["t_s"] = grid.copy()
        return res

    def simulate_windows(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]],
                         which: Sequence[int] | None = None) -> "WindowSims":
        """Per replay window (``which``, default all): the plant outputs on the window's part of
        the replay grid, started as :func:`window_start` says.  A one-window run gives the same
        simulation as :meth:`simulate`."""
        if len(prep.windows) <= 1 and (which is None or list(which) == [0]):
            return WindowSims([(0, self.simulate(prep, effects))], effects)
        plant, src, t_in = self._ready(prep, effects)
        out = []
        for w in (range(len(prep.windows)) if which is None else which):
            t0, pose, vel = anchors.window_start(prep, w, effects)
            t_end = prep.window_times(w)[1]
            grid = prep.t_grid[(prep.t_grid >= t0 - 1e-12) & (prep.t_grid <= t_end + 1e-12)]
            if grid.size < 2:
                continue
            in_r = _zoh(t_in, src[0], grid)
            in_l = _zoh(t_in, src[1], grid)
            o = plant.simulate(grid, in_r, in_l, mode=self.mode, dt_s=self.dt_s,
                               start_pose=pose, start_velocity=vel)
            res = {k: np.asarray(v, float) for k, v in o.items() if k in _NEEDED}
            res["t_s"] = grid.copy()
            out.append((w, res))
        return WindowSims(out, effects)


class WindowSims(list[tuple[int, dict[str, np.ndarray]]]):
    """[(window index, plant outputs)] of a windowed replay, with the ``effects`` the plant
    ran with (the candidate's geometry, which the count-anchored camera channels need)."""

    def __init__(self, items: Iterable[tuple[int, dict[str, np.ndarray]]] = (),
                 effects: Mapping[str, Mapping[str, float]] | None = None):
        super().__init__(items)
        self.effects = dict(effects or {})
