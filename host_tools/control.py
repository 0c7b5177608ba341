"""Bindings of the firmware's controller and of the closed-loop driver (no physics, no control
law in Python; both live in C++ behind the C ABI of ``libddrobot.so``).

* :class:`Controller` — ``lib/control`` (the firmware's cascade, fixed or float point) through
  its C ABI ``ctl_*`` (``host_tools/native/control_capi.cpp``). Driven like the firmware:
  cumulative encoder counts in, duties out, inner step every 25 ms, outer step every 50 ms
  after the inner step of the same tick.
* :class:`ClosedLoop` — ``lib/closedloop``'s driver through ``cl_*``
  (``host_tools/native/closedloop_capi.cpp``): that controller in closed loop with the
  ``lib/slipmodel`` plant, stepped forward tick by tick (cost linear in the run length).
"""
from __future__ import annotations

import ctypes
import math
from typing import Mapping

import numpy as np

from host_tools import _native, protocol
from host_tools.params import ENCODER_PPR
from host_tools.runfmt import DEFAULT_META

INNER_S = DEFAULT_META["periods_s"]["inner"]  # the firmware's inner period (protocol task table)
#: the scheduler tick (protocol.json timing.sched_tick_us): the firmware's duty ramp steps once a tick
SCHED_TICK_S: float = protocol.definition().timing["sched_tick_us"] / 1e6
#: reference kinds, name -> lib/control's code: protocol.json's ``profile`` enum, whose
#: ``straight`` the run format (meta.json reference.kind) calls ``line``
REF_KINDS: dict[str, int] = {("line" if k == "straight" else k): v
                             for k, v in protocol.definition().enums["profile"].items()}
ACTUATORS = {"duty": 0, "torque": 1}


def _kind(kind: str) -> int:
    if kind not in REF_KINDS:
        raise ValueError(f"reference kind must be one of {list(REF_KINDS)}, got {kind!r}")
    return REF_KINDS[kind]


class Controller:
    """The firmware's cascade (``lib/control``) through the ``ctl_*`` C ABI."""

    def __init__(self, fixed_point: bool = True, clamp: bool = True,
                 params: Mapping[str, float] | None = None):
        self._lib = _native.library()  # ctl_*: host_tools/native/control_capi.h
        self._h = self._lib.ctl_new(int(bool(fixed_point)), int(bool(clamp)))
        if not self._h:
            raise MemoryError("ctl_new failed")
        self.columns = [self._lib.ctl_column_name(i).decode()
                        for i in range(self._lib.ctl_column_count())]
        self._row = (ctypes.c_double * len(self.columns))()
        for k, v in (params or {}).items():
            self.set(k, v)

    def __del__(self):
        h = getattr(self, "_h", None)
        if h:
            self._lib.ctl_free(h)
            self._h = None

    def _check(self, rc: int, what: str) -> None:
        if rc < 0:
            raise ValueError(f"{what}: {self._lib.ctl_last_error(self._h).decode()} (code {rc})")

    def set(self, key: str, value: float) -> None:
        self._check(self._lib.ctl_set(self._h, key.encode(), float(value)), f"ctl_set({key})")

    def get(self, key: str) -> float:
        out = ctypes.c_double()
        self._check(self._lib.ctl_get(self._h, key.encode(), ctypes.byref(out)), f"ctl_get({key})")
        return out.value

    def set_reference(self, kind: str, accel_m_s2: float, cruise_m_s: float,
                      radius_m: float = 1.0) -> None:
        self._check(self._lib.ctl_set_reference(self._h, _kind(kind), accel_m_s2,
                                                cruise_m_s, radius_m), "ctl_set_reference")

    def reference(self, t_s: float) -> tuple[float, ...]:
        """(x, y, phi, v, omega, dv, domega) of the reference at ``t_s``."""
        out = (ctypes.c_double * 7)()
        self._check(self._lib.ctl_reference(self._h, float(t_s), out, 7), "ctl_reference")
        return tuple(out)

    def reset(self, enc_r: int = 0, enc_l: int = 0, pose=(0.0, 0.0, 0.0)) -> None:
        self._check(self._lib.ctl_reset(self._h, int(enc_r), int(enc_l), *map(float, pose)),
                    "ctl_reset")

    def start(self, enc_r: int = 0, enc_l: int = 0, pose=(0.0, 0.0, 0.0)) -> dict[str, float]:
        """The start tick of an experiment: reset to ``pose``, the outer step with the
        reference at t = 0, and the first command from rest (the columns of :meth:`inner`)."""
        rc = self._lib.ctl_start(self._h, int(enc_r), int(enc_l), *map(float, pose), self._row,
                                 len(self.columns))
        self._check(rc, "ctl_start")
        return dict(zip(self.columns, self._row))

    def inner(self, enc_r: int, enc_l: int, dt_s: float = INNER_S) -> dict[str, float]:
        rc = self._lib.ctl_inner(self._h, int(enc_r), int(enc_l), float(dt_s), self._row,
                                 len(self.columns))
        self._check(rc, "ctl_inner")
        return dict(zip(self.columns, self._row))

    def outer(self, t_s: float) -> None:
        self._check(self._lib.ctl_outer(self._h, float(t_s)), "ctl_outer")


class ClosedLoop:
    """The firmware's controller in closed loop with the ``lib/slipmodel`` plant
    (``lib/closedloop``'s ``cl::Driver`` through ``cl_*``), stepped forward tick by tick.

    Tick k (board time ``t0_s + k * inner_s``): the inner step on the plant's encoder counts
    (floor of angle x ppr / 2 pi), the outer step every ``outer_every`` ticks after it (reference
    time ``k * inner_s``; tick 0 is the start tick: reset, the outer step at t = 0, the first
    command from rest), then the plant advanced for one inner period with the duty
    (``actuator="duty"``) or the torque command after the clamp (``"torque"``, an ideal torque
    source), in ``rows_per_tick`` rows of Euler steps <= ``plant_dt_s``.

    ``ctl_robot``/``ctl_motor``: the controller's nominal parameters (meta.json names);
    ``ctl_params``: ``controller`` (0 improved, 1 thesis) and gains (``k_x`` ... ``k_ia``);
    ``duty_ramp``: the firmware's 1 kHz ramp of a clamped wheel's duty (off: held per tick);
    ``plant_robot``/``plant_motor`` and ``effects`` ({name: {param: value}}): the plant's.

    ``kind="drive"``: drive mode (the Drive command's reference, lib/control drive.h) instead of
    a profile: ``drive = {"accel": m/s^2, "alpha": rad/s^2, "commands": [{"t_s", "v", "omega"},
    ...]}``, the targets the firmware latched at outer ticks (board time, m/s, rad/s; what
    meta.json ``reference`` holds for a drive); accel_m_s2/cruise_m_s/radius_m are unused."""

    def __init__(self, kind: str, accel_m_s2: float, cruise_m_s: float, radius_m: float = 1.0, *,
                 fixed_point: bool = True, clamp: bool = True,
                 ctl_robot: Mapping[str, float] | None = None,
                 ctl_motor: Mapping[str, float] | None = None,
                 plant_robot: Mapping[str, float] | None = None,
                 plant_motor: Mapping[str, float] | None = None,
                 effects: Mapping[str, Mapping[str, float]] | None = None,
                 t0_s: float = 0.0, inner_s: float = INNER_S, outer_every: int = 2,
                 ppr: int = ENCODER_PPR, plant_dt_s: float = 5e-4, rows_per_tick: int = 1,
                 actuator: str = "duty", start_pose=(0.0, 0.0, 0.0),
                 ctl_params: Mapping[str, float] | None = None, duty_ramp: bool = True,
                 drive: Mapping | None = None):
        if actuator not in ACTUATORS:
            raise ValueError(f"actuator must be 'duty' or 'torque', got {actuator!r}")
        self._lib = _native.library()  # cl_*: host_tools/native/closedloop_capi.h
        self._h = self._lib.cl_new(int(bool(fixed_point)), int(bool(clamp)))
        if not self._h:
            raise MemoryError("cl_new failed")
        lib = self._lib
        self.tick_columns = [lib.cl_tick_col_name(i).decode() for i in range(lib.cl_tick_col_count())]
        self.row_columns = [lib.cl_row_col_name(i).decode() for i in range(lib.cl_row_col_count())]
        self.rows_per_tick = int(rows_per_tick)
        for k, v in {"t0_s": t0_s, "inner_s": inner_s, "outer_every": outer_every, "ppr": ppr,
                     "plant_dt_s": plant_dt_s, "rows_per_tick": rows_per_tick,
                     "actuator": ACTUATORS[actuator], "duty_ramp": float(bool(duty_ramp))}.items():
            self.set(f"loop.{k}", v)
        # the velocity loop first (it sets the variant's default gains), then gains, parameters
        ctl_params = dict(ctl_params or {})
        if "controller" in ctl_params:
            self.set("ctl.controller", ctl_params.pop("controller"))
        for k, v in ctl_params.items():
            if k.startswith("k_"):
                self.set(f"ctl.gain.{k}", v)
            elif f"robot.{k}" in _native.param_keys():
                self.set(f"ctl.robot.{k}", v)
            elif f"motor.{k}" in _native.param_keys():
                self.set(f"ctl.motor.{k}", v)
            else:
                self.set(f"ctl.{k}", v)
        for part, values in (("robot", ctl_robot), ("motor", ctl_motor)):
            for k, v in (values or {}).items():
                self.set(f"ctl.{part}.{k}", v)
        for part, values in (("robot", plant_robot), ("motor", plant_motor)):
            for k, v in (values or {}).items():
                self.set(f"{part}.{k}", v)
        vocab = _native.effect_vocabulary()
        for name, params in (effects or {}).items():
            if name not in vocab:
                raise ValueError(f"unknown effect '{name}'; known: {', '.join(vocab)}")
            bad = set(params) - set(vocab[name])
            if bad:
                raise ValueError(f"effect '{name}' has no parameter(s) {sorted(bad)}")
            for p, v in {**vocab[name], **params}.items():
                self.set(f"{name}.{p}", v)
            self.set(f"{name}.enabled", 1.0)
        if kind == "drive":
            if not isinstance(drive, Mapping):
                raise ValueError("kind 'drive' needs drive={'accel', 'alpha', 'commands'}")
            cmds = list(drive.get("commands") or [])
            arr = [np.ascontiguousarray([float(c[k]) for c in cmds], dtype=float)
                   for k in ("t_s", "v", "omega")]
            dp = ctypes.POINTER(ctypes.c_double)
            self._check(lib.cl_set_drive(self._h, float(drive["accel"]), float(drive["alpha"]), len(cmds),
                                         *(a.ctypes.data_as(dp) for a in arr)), "drive reference")
        else:
            self._check(lib.cl_set_reference(self._h, _kind(kind), float(accel_m_s2),
                                             float(cruise_m_s), float(radius_m)), "reference")
        self.reset(start_pose)

    def __del__(self):
        h = getattr(self, "_h", None)
        if h:
            self._lib.cl_free(h)
            self._h = None

    def _check(self, rc: int, what: str) -> None:
        if rc < 0:
            raise ValueError(f"closed loop {what}: {self._lib.cl_last_error(self._h).decode()} "
                             f"(code {rc})")

    def set(self, key: str, value: float) -> None:
        """A ``cl_set`` key (plant keys, ``ctl.*``, ``loop.*``); a ``ctl.*``/``loop.*`` key
        starts over: call :meth:`reset`."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{key}: {value!r} is not a number") from None
        self._check(self._lib.cl_set(self._h, key.encode(), v), f"key {key}")

    def reset(self, pose=(0.0, 0.0, 0.0)) -> None:
        """Plant at rest at ``pose`` at ``t0_s``, controller reset; the next tick is tick 0."""
        self._check(self._lib.cl_reset(self._h, *(float(v) for v in pose)), "reset")

    def run(self, n_ticks: int, rows: bool = False):
        """Runs ``n_ticks`` more ticks; returns {tick column: array} (see ``tick_columns``), and
        with ``rows`` also {row column: array} of the plant at every row (``rows_per_tick`` per
        tick)."""
        n = int(n_ticks)
        if n < 0:
            raise ValueError(f"n_ticks must be >= 0, got {n_ticks}")
        dp = ctypes.POINTER(ctypes.c_double)
        tk = np.empty((n, len(self.tick_columns)))
        rw = np.empty((n * self.rows_per_tick, len(self.row_columns))) if rows else None
        self._check(self._lib.cl_run(self._h, n, tk.ctypes.data_as(dp), tk.shape[1],
                                     rw.ctypes.data_as(dp) if rows else None,
                                     len(self.row_columns)), "run")
        ticks = {c: tk[:, i].copy() for i, c in enumerate(self.tick_columns)}
        if not rows:
            return ticks
        return ticks, {c: rw[:, i].copy() for i, c in enumerate(self.row_columns)}

    def state(self) -> dict[str, float]:
        """The plant now, in the row columns (torques of the last Euler step)."""
        out = (ctypes.c_double * len(self.row_columns))()
        self._check(self._lib.cl_state(self._h, out, len(out)), "state")
        return dict(zip(self.row_columns, out))


def resimulate_from_rest(kind, accel, cruise, radius, *, fixed_point, clamp, t0, n, ppr=ENCODER_PPR,
                         start_pose=(0.0, 0.0, 0.0), effects=None, actuator="duty", sub=1,
                         T=INNER_S, dt_s=5e-4, ctl_params=None, outer_every=2):
    """The closed loop without the driver, kept as the reference that :class:`ClosedLoop` is
    tested and benchmarked against: at tick k the plant is re-simulated from rest
    (``Plant.simulate``) over ticks 0..k with the inputs so far (``sub`` rows per tick), its wheel
    angles give the counts, then the controller's inner and (every ``outer_every`` ticks) outer
    step run through ``ctl_*`` (tick 0 is the start tick, ``ctl_start``).  O(ticks^2) plant steps.  Returns (per-tick controller columns
    and wheel angles, the last re-simulation's plant rows)."""
    plant = _native.Plant()
    for name, ps in (effects or {}).items():
        plant.set_effect(name, **ps)
    ctl = Controller(fixed_point=fixed_point, clamp=clamp, params=ctl_params)
    ctl.set_reference(kind, accel, cruise, radius)
    ctl.reset(0, 0, start_pose)
    # the duty of a clamped wheel grows by pwm_slope every millisecond after the tick, at most
    # T/1 ms - 1 times (the firmware's 1 kHz ramp): simulated on 1 ms rows, read at ``sub`` rows
    n_ms = int(round(T * 1e3))
    fine = n_ms if actuator == "duty" else sub
    if fine % sub:
        raise ValueError(f"sub must divide {fine}")
    ramp = np.minimum(np.arange(fine), n_ms - 1) if actuator == "duty" else np.zeros(fine)
    u_r, u_l = np.zeros(n), np.zeros(n)
    s_r, s_l = np.zeros(n), np.zeros(n)
    rows, th, st = [], np.zeros((n, 2)), None
    for k in range(n):
        if k > 0:
            tg = t0 + (T / fine) * np.arange(k * fine + 1)
            ur = np.clip(np.repeat(u_r[:k], fine) + np.outer(s_r[:k], ramp).ravel(), -1, 1)
            ul = np.clip(np.repeat(u_l[:k], fine) + np.outer(s_l[:k], ramp).ravel(), -1, 1)
            st = plant.simulate(tg, np.append(ur, 0.0), np.append(ul, 0.0), mode=actuator,
                                dt_s=dt_s, start_pose=start_pose)
            st = {c: v[::fine // sub] for c, v in st.items()}
            th[k] = st["theta_r_rad"][-1], st["theta_l_rad"][-1]
        counts = [int(math.floor(a * ppr / (2 * math.pi))) for a in th[k]]
        if k == 0:  # the start tick: reset, outer step at t = 0, first command from rest
            o = ctl.start(*counts, start_pose)
        else:
            o = ctl.inner(*counts, T)
            if k % outer_every == 0:
                ctl.outer(k * T)
        u_r[k], u_l[k] = ((o["pwm_r"], o["pwm_l"]) if actuator == "duty"
                          else (o["tau_cmd_r"], o["tau_cmd_l"]))
        if actuator == "duty":
            s_r[k], s_l[k] = o["pwm_slope_r"], o["pwm_slope_l"]
        rows.append(o)
    out = {c: np.array([r[c] for r in rows]) for c in rows[0]}
    out["theta_r_rad"], out["theta_l_rad"] = th[:, 0], th[:, 1]
    return out, st


def odometry_series(counts_r, counts_l, t, r: float, b: float, ppr: int,
                    pose0: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """lib/control's odometry (the firmware's formula, III.1-III.4) over a series of cumulative
    counts at times ``t``, from ``pose0``: (x, y, phi) after each sample (C ABI
    ``ctl_odometry_series``)."""
    fn = _native.library().ctl_odometry_series  # signature: host_tools/native/control_capi.h
    i32p = ctypes.POINTER(ctypes.c_int32)
    dp = ctypes.POINTER(ctypes.c_double)
    n = len(t)
    cr = np.ascontiguousarray(counts_r, dtype=np.int32)
    cl = np.ascontiguousarray(counts_l, dtype=np.int32)
    tt = np.ascontiguousarray(t, dtype=np.float64)
    x, y, phi = (np.empty(n) for _ in range(3))
    rc = fn(r, b, int(ppr), n, cr.ctypes.data_as(i32p), cl.ctypes.data_as(i32p), tt.ctypes.data_as(dp),
            float(pose0[0]), float(pose0[1]), float(pose0[2]),
            x.ctypes.data_as(dp), y.ctypes.data_as(dp), phi.ctypes.data_as(dp))
    if rc < 0:
        raise ValueError(f"ctl_odometry_series failed ({rc}): r={r}, b={b}, ppr={ppr}")
    return x, y, phi
