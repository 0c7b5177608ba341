"""Replay a recorded run through the plant and put recording and simulation side by side.

The plant is lib/slipmodel's, reached through host_tools._native (never re-implemented
here).  A *replayer* turns (prepared run, effects) into simulated plant outputs; the
open-loop ones drive the plant with the recorded duty or the recorded torque command.
A closed-loop replay through lib/control plugs in as another replayer once its C ABI
exists (see :class:`ClosedLoopReplay`).

:func:`channels` then maps a recording and a simulation onto common channels, each a
pair (recorded, simulated) on the recording's own time base."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np

from host_tools.runfmt import Run

# Channels compared (name -> kind).  "fit" channels enter the output-error fit.
CHANNELS = ("omega_r", "omega_l", "enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad",
            "x_m", "y_m", "phi_rad")
FIT_CHANNELS = ("omega_r", "omega_l", "x_m", "y_m", "phi_rad")
CUMULATIVE = ("enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad")


def reconstruct_input_times(t: np.ndarray, values: list[np.ndarray], period: float,
                            arc_position: float = 0.5) -> np.ndarray:
    """When the recorded inputs change between two telemetry frames, the change happened at a
    tick of the loop that sets them (period ``period``), somewhere in (t[k-1], t[k]].  Find the
    tick phase that puts one tick in every such interval and return, per frame, the time the
    value it reports took effect.  Falls back to the frame times when no phase fits (e.g. the
    loop is not periodic, or faster than telemetry).

    The data pin the phase down to an arc of feasible phases (5 ms wide for a 25 ms loop seen
    at 50 Hz); ``arc_position`` picks the phase along it (0 start, 0.5 centre, 1 end)."""
    t = np.asarray(t, float)
    n = t.size
    eff = t.copy()
    if n < 3 or period <= 0:
        return eff
    changed = np.zeros(n, bool)
    for v in values:
        changed[1:] |= np.diff(np.asarray(v, float)) != 0
    ks = np.flatnonzero(changed)
    if ks.size == 0:
        return eff
    dt_tel = float(np.median(np.diff(t)))
    if period < dt_tel * 0.999:  # loop faster than telemetry: several ticks per interval
        return eff
    phases = np.linspace(0.0, period, 400, endpoint=False)
    bad = np.zeros(phases.size, int)
    for j, phase in enumerate(phases):
        # latest tick <= t[k] must lie after t[k-1] (a tick on a frame counts as before it)
        tick = phase + np.floor((t[ks] - phase) / period + 1e-9) * period
        bad[j] = int(np.sum(~(tick > t[ks - 1] + 1e-9)))
    # tolerate a few changes that no phase explains (timing jitter at coincidences)
    if bad.min() > max(1, int(0.05 * ks.size)):  # not one periodic loop: keep frame times
        return eff
    feasible = bad == bad.min()
    # the data pin the phase down to an arc of feasible phases: take its centre
    if feasible.all():
        return eff
    start = int(np.flatnonzero(~feasible)[0])
    rolled = np.roll(feasible, -start)
    best_len, best_start, run_start = 0, 0, None
    for j, f in enumerate(np.append(rolled, False)):
        if f and run_start is None:
            run_start = j
        elif not f and run_start is not None:
            if j - run_start > best_len:
                best_len, best_start = j - run_start, run_start
            run_start = None
    pos = best_start + float(np.clip(arc_position, 0.0, 1.0)) * (best_len - 1)
    best_phase = ((pos + start) % phases.size) * period / phases.size
    tick = best_phase + np.floor((t[ks] - best_phase) / period + 1e-9) * period
    ok = tick > t[ks - 1] + 1e-9
    eff[ks[ok]] = tick[ok]
    return eff


@dataclass
class PreparedRun:
    """A run with its inputs reconstructed for replay."""

    run: Run
    t_in: np.ndarray          # time at which each duty sample takes effect
    t_in_tau: np.ndarray      # time at which each torque-command sample takes effect
    duty: tuple[np.ndarray, np.ndarray]
    torque: tuple[np.ndarray, np.ndarray]
    t_grid: np.ndarray        # times at which the simulation is sampled
    robot: dict
    motor: dict
    start_pose: tuple[float, float, float]
    ppr: int
    extras: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.run.name


def prepare(run: Run, arc_position: float = 0.5) -> PreparedRun:
    tel = run.telemetry
    t = tel["t_s"]
    period = float(run.meta["periods_s"]["inner"])
    t_in = reconstruct_input_times(t, [tel["pwm_r"], tel["pwm_l"]], period, arc_position)
    t_in_tau = reconstruct_input_times(t, [tel["tau_cmd_r"], tel["tau_cmd_l"]], period,
                                       arc_position)
    # the input takes effect at t_in[k] and holds until the next one; the simulation is sampled
    # at the union of input times and telemetry times, from the first frame on
    grid = np.unique(np.concatenate([t, t_in, t_in_tau]))
    return PreparedRun(run=run, t_in=t_in, t_in_tau=t_in_tau,
                       duty=(tel["pwm_r"], tel["pwm_l"]),
                       torque=(tel["tau_cmd_r"], tel["tau_cmd_l"]),
                       t_grid=grid, robot=dict(run.meta["robot"]), motor=dict(run.meta["motor"]),
                       start_pose=run.start_pose, ppr=int(run.meta["encoder_ppr"]),
                       extras={"arc_position": arc_position})


def prepare_best(run: Run, replay: "OpenLoopReplay", positions=(0.0, 0.25, 0.5, 0.75, 1.0)
                 ) -> PreparedRun:
    """:func:`prepare`, with the input-timing phase chosen along its feasible arc by the
    nominal duty replay's wheel-speed error (a nuisance parameter of the recording, fitted
    once per run before anything else)."""
    best, best_c = None, np.inf
    for pos in positions:
        prep = prepare(run, pos)
        ch = channels(prep, replay.simulate(prep, {}), "duty")
        c = float(sum(np.sum(ch[k].resid ** 2) for k in ("omega_r", "omega_l")))
        if c < best_c:
            best, best_c = prep, c
    return best


def _zoh(t_in: np.ndarray, v: np.ndarray, grid: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(t_in, grid, side="right") - 1
    idx = np.clip(idx, 0, v.size - 1)
    out = v[idx].astype(float)
    out[grid < t_in[0]] = 0.0
    return out


class Replayer(Protocol):
    name: str

    def simulate(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]]
                 ) -> dict[str, np.ndarray]:
        """Plant outputs (columns of _native.Plant.simulate) on ``prep.t_grid``."""


class OpenLoopReplay:
    """Drive the plant with the recorded duty ("duty") or torque command ("torque")."""

    def __init__(self, mode: str = "duty", dt_s: float = 5e-4, plant_factory: Any = None):
        if mode not in ("duty", "torque"):
            raise ValueError(f"mode must be 'duty' or 'torque', not {mode!r}")
        self.mode = mode
        self.name = f"open-loop {mode}"
        self.dt_s = dt_s
        self._factory = plant_factory
        self._plants: dict = {}

    def _plant(self, robot: dict, motor: dict):
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

    def simulate(self, prep: PreparedRun, effects: Mapping[str, Mapping[str, float]]
                 ) -> dict[str, np.ndarray]:
        plant = self._plant(prep.robot, prep.motor)
        plant.clear_effects()
        for name, params in effects.items():
            plant.set_effect(name, **{k: float(v) for k, v in params.items()})
        src = prep.duty if self.mode == "duty" else prep.torque
        t_in = prep.t_in if self.mode == "duty" else prep.t_in_tau
        grid = prep.t_grid
        # Simulate on a dyadic grid (multiples of 2^-n s, one plant step per row): sums of its
        # times are exact in binary floating point, so the plant's clock never appears to run
        # backwards between rows (which would clear the actuation-delay history), and input
        # changes land within one step of their reconstructed time.  Outputs are then
        # interpolated onto the recording's times.
        h = 2.0 ** math.floor(math.log2(self.dt_s))
        t0 = math.floor(grid[0] / h) * h
        n = int(math.ceil((grid[-1] - t0) / h)) + 1
        fine = t0 + h * np.arange(n)
        in_r = _zoh(t_in, src[0], fine)
        in_l = _zoh(t_in, src[1], fine)
        out = plant.simulate(fine, in_r, in_l, mode=self.mode, dt_s=h * 1.000001,
                             start_pose=prep.start_pose)
        ts = np.asarray(out["t_s"], float)
        res = {k: np.interp(grid, ts, np.asarray(v, float)) for k, v in out.items()
               if k in _NEEDED}
        res["t_s"] = grid.copy()
        return res


_NEEDED = {"x_m", "y_m", "phi_rad", "theta_r_rad", "theta_l_rad", "dtheta_r_rad_s",
           "dtheta_l_rad_s", "tau_r_nm", "tau_l_nm", "v_m_s", "omega_rad_s", "slip_r", "slip_l"}


class ClosedLoopReplay:
    """Closed-loop replay through lib/control: the plant driven by the firmware's own control
    laws, reproducing the torque the firmware should have commanded.  Needs the control C ABI
    (host_tools._native.Controller); until that exists :meth:`available` says why not."""

    name = "closed-loop"

    @staticmethod
    def available() -> tuple[bool, str]:
        try:
            from host_tools import _native
        except Exception as exc:  # pragma: no cover - depends on the build
            return False, f"host_tools._native unavailable: {exc}"
        if not hasattr(_native, "Controller"):
            return False, "the lib/control C ABI (host_tools._native.Controller) does not exist yet"
        return True, ""

    def simulate(self, prep: PreparedRun, effects):  # pragma: no cover - not yet available
        ok, why = self.available()
        raise NotImplementedError(why or "closed-loop replay is not implemented yet")


# -------------------------------------------------------------------------- channels


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _odometry(theta_r: np.ndarray, theta_l: np.ndarray, r: float, b: float,
              pose0: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dead reckoning from wheel angles (III.2-III.4), the same formula as the recorded
    odometry; used only to compare like with like.  The firmware's own odometry (lib/control)
    replaces this when the control C ABI exists."""
    ds = r * 0.5 * (np.diff(theta_r) + np.diff(theta_l))
    dphi = r * (np.diff(theta_r) - np.diff(theta_l)) / (2 * b)
    phi = pose0[2] + np.concatenate([[0.0], np.cumsum(dphi)])
    mid = phi[:-1] + 0.5 * dphi
    x = pose0[0] + np.concatenate([[0.0], np.cumsum(ds * np.cos(mid))])
    y = pose0[1] + np.concatenate([[0.0], np.cumsum(ds * np.sin(mid))])
    return x, y, phi


@dataclass
class Channel:
    name: str
    t: np.ndarray
    rec: np.ndarray
    sim: np.ndarray
    unit: str

    @property
    def resid(self) -> np.ndarray:
        d = self.rec - self.sim
        return _wrap(d) if self.name in ("phi_rad", "phi_odo_rad") else d


def channels(prep: PreparedRun, sim: Mapping[str, np.ndarray], mode: str = "duty"
             ) -> dict[str, Channel]:
    run = prep.run
    tel = run.telemetry
    t = tel["t_s"]
    g = np.asarray(sim["t_s"], float)

    def at(name: str, times: np.ndarray) -> np.ndarray:
        return np.interp(times, g, np.asarray(sim[name], float))

    k = 2 * np.pi / prep.ppr
    th_r, th_l = at("theta_r_rad", t), at("theta_l_rad", t)
    out: dict[str, Channel] = {}
    dt = np.diff(t)
    for side, th in (("r", th_r), ("l", th_l)):
        enc = tel[f"enc_{side}"]
        out[f"omega_{side}"] = Channel(f"omega_{side}", t[1:], np.diff(enc) * k / dt,
                                       np.diff(th) / dt, "rad/s")
        out[f"enc_{side}"] = Channel(f"enc_{side}", t, enc - enc[0], (th - th[0]) / k, "counts")
    # odometry of the simulated encoders (quantized like the real ones)
    q_r = np.floor((th_r - th_r[0]) / k) * k
    q_l = np.floor((th_l - th_l[0]) / k) * k
    pose0 = (tel["x_odo_m"][0], tel["y_odo_m"][0], tel["phi_odo_rad"][0])
    xo, yo, po = _odometry(q_r, q_l, float(prep.robot["r"]), float(prep.robot["b"]), pose0)
    out["x_odo_m"] = Channel("x_odo_m", t, tel["x_odo_m"], xo, "m")
    out["y_odo_m"] = Channel("y_odo_m", t, tel["y_odo_m"], yo, "m")
    out["phi_odo_rad"] = Channel("phi_odo_rad", t, tel["phi_odo_rad"], po, "rad")
    # The recorded torque command is what the controller wanted; an open-loop replay only knows
    # the torque the plant delivered, so tau_cmd is compared by the closed-loop replay only.
    gt = run.groundtruth
    if gt is not None:
        tg = gt["t_s"]
        inside = (tg >= g[0]) & (tg <= g[-1])
        tg = tg[inside]
        if tg.size >= 3:
            out["x_m"] = Channel("x_m", tg, gt["x_m"][inside], at("x_m", tg), "m")
            out["y_m"] = Channel("y_m", tg, gt["y_m"][inside], at("y_m", tg), "m")
            ph = gt["phi_rad"][inside]
            ok = np.isfinite(ph)
            if ok.sum() >= 3:
                # unwrap the simulated heading continuously, compare modulo 2 pi
                out["phi_rad"] = Channel("phi_rad", tg[ok], ph[ok], at("phi_rad", tg[ok]), "rad")
    return out


def state_table(prep: PreparedRun) -> dict[str, np.ndarray]:
    """Operating state at the telemetry frames (from the recording), for regime search."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    k = 2 * np.pi / prep.ppr
    w_r = np.gradient(tel["enc_r"] * k, t)
    w_l = np.gradient(tel["enc_l"] * k, t)
    from host_tools.analyzer.signals import smooth
    w_r, w_l = smooth(w_r, 3), smooth(w_l, 3)
    return {"t": t, "w_r": w_r, "w_l": w_l,
            "a_r": smooth(np.gradient(w_r, t), 3), "a_l": smooth(np.gradient(w_l, t), 3),
            "tau_r": tel["tau_cmd_r"], "tau_l": tel["tau_cmd_l"],
            "u_r": tel["pwm_r"], "u_l": tel["pwm_l"],
            "yaw": float(prep.robot["r"]) * (w_r - w_l) / (2 * float(prep.robot["b"]))}
