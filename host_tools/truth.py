"""Bindings for the firmware's control laws and the independent truth simulator.

* :class:`Controller` — ``lib/control`` (the firmware's cascade, fixed or float point) through
  its C ABI ``ctl_*`` (``host_tools/native/control_capi.cpp``) in ``libddrobot.so``. Driven like
  the firmware: cumulative encoder counts in, duties out, inner step every 25 ms, outer step
  every 50 ms after the inner step of the same tick.
* :func:`nominal_closed_loop` — that controller in closed loop with the *nominal* plant
  (``lib/slipmodel`` through :class:`host_tools._native.Plant`). ``Plant.simulate`` restarts
  from rest on every call, so each tick re-simulates the whole duty history (deterministic,
  O(ticks²) plant steps; 3 s cost about 0.2 s). No physics in Python.
* :func:`build_truth`, :class:`TruthSim`, :func:`simulate_run` — the independent truth simulator
  of ``sim/truth`` (the one deliberate second implementation of the physics, see
  ``sim/truth/truth.h``), compiled with the firmware's ``lib/control`` into
  ``.build/truth/libtruth.so``.
"""
from __future__ import annotations

import ctypes
import fcntl
import json
import math
import os
import subprocess
from pathlib import Path
from typing import Mapping

import numpy as np

from host_tools import _native

ROOT = Path(__file__).resolve().parent.parent
PPR = 1856
INNER_S = 0.025
_REF_KINDS = {"line": 0, "arc": 1, "figure_eight": 2}


# ------------------------------------------------------------------ lib/control (ctl_* ABI)

def _ctl_lib() -> ctypes.CDLL:
    lib = _native.library()
    if getattr(lib, "_ctl_declared", False):
        return lib
    d = ctypes.c_double
    dp = ctypes.POINTER(ctypes.c_double)
    sig = {
        "ctl_describe": (ctypes.c_char_p, []),
        "ctl_new": (ctypes.c_void_p, [ctypes.c_int, ctypes.c_int]),
        "ctl_free": (None, [ctypes.c_void_p]),
        "ctl_last_error": (ctypes.c_char_p, [ctypes.c_void_p]),
        "ctl_set": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_char_p, d]),
        "ctl_get": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_char_p, dp]),
        "ctl_set_reference": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_int, d, d, d]),
        "ctl_reference": (ctypes.c_int, [ctypes.c_void_p, d, dp, ctypes.c_int]),
        "ctl_reset": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_int32, ctypes.c_int32, d, d, d]),
        "ctl_outer": (ctypes.c_int, [ctypes.c_void_p, d]),
        "ctl_inner": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_int32, ctypes.c_int32, d, dp,
                                     ctypes.c_int]),
        "ctl_column_count": (ctypes.c_int, []),
        "ctl_column_name": (ctypes.c_char_p, [ctypes.c_int]),
    }
    for name, (res, args) in sig.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    lib._ctl_declared = True
    return lib


class Controller:
    """The firmware's cascade (``lib/control``) through the ``ctl_*`` C ABI."""

    def __init__(self, fixed_point: bool = True, clamp: bool = True,
                 params: Mapping[str, float] | None = None):
        self._lib = _ctl_lib()
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
        if kind not in _REF_KINDS:
            raise ValueError(f"reference kind must be one of {list(_REF_KINDS)}, got {kind!r}")
        self._check(self._lib.ctl_set_reference(self._h, _REF_KINDS[kind], accel_m_s2,
                                                cruise_m_s, radius_m), "ctl_set_reference")

    def reference(self, t_s: float) -> tuple[float, ...]:
        """(x, y, phi, v, omega, dv, domega) of the reference at ``t_s``."""
        out = (ctypes.c_double * 7)()
        self._check(self._lib.ctl_reference(self._h, float(t_s), out, 7), "ctl_reference")
        return tuple(out)

    def reset(self, enc_r: int = 0, enc_l: int = 0, pose=(0.0, 0.0, 0.0)) -> None:
        self._check(self._lib.ctl_reset(self._h, int(enc_r), int(enc_l), *map(float, pose)),
                    "ctl_reset")

    def inner(self, enc_r: int, enc_l: int, dt_s: float = INNER_S) -> dict[str, float]:
        rc = self._lib.ctl_inner(self._h, int(enc_r), int(enc_l), float(dt_s), self._row,
                                 len(self.columns))
        self._check(rc, "ctl_inner")
        return dict(zip(self.columns, self._row))

    def outer(self, t_s: float) -> None:
        self._check(self._lib.ctl_outer(self._h, float(t_s)), "ctl_outer")


def counts(theta_rad) -> np.ndarray:
    """Encoder counts of a wheel angle, as the quadrature decoder gives them (floor)."""
    return np.floor(np.asarray(theta_rad) * PPR / (2.0 * math.pi)).astype(np.int64)


def nominal_closed_loop(kind: str, accel_m_s2: float, cruise_m_s: float, radius_m: float = 1.0,
                        clamp: bool = True, T_s: float = 3.0, plant: _native.Plant | None = None,
                        fixed_point: bool = True, dt_s: float = 5e-4) -> dict[str, np.ndarray]:
    """The firmware's controller in closed loop with the nominal ``lib/slipmodel`` plant (duty
    mode), on the 25 ms / 50 ms schedule with quantised encoders. Returns per-tick arrays:
    ``t_s``, true pose ``x_m, y_m, phi_rad``, reference ``x_ref, y_ref``, controller columns
    (``pwm_r`` ... ``odo_status``), and plant columns at the tick (``slip_r``, ``slip_l``,
    ``dtheta_r_rad_s`` ...), plus ``slip_any`` (any slipping internal step in the tick)."""
    plant = plant or _native.Plant()
    ctl = Controller(fixed_point=fixed_point, clamp=clamp)
    ctl.set_reference(kind, accel_m_s2, cruise_m_s, radius_m)
    ctl.reset(0, 0, (0.0, 0.0, 0.0))
    n = int(round(T_s / INNER_S))
    sub = 5  # plant rows per tick, so that slip inside a tick is seen
    t_ticks = np.arange(n + 1) * INNER_S
    duty_r = np.zeros(n + 1)
    duty_l = np.zeros(n + 1)
    rows: list[dict[str, float]] = []
    state = None
    for k in range(n + 1):
        if k == 0:
            th_r = th_l = 0.0
        else:
            tg = np.round(np.arange(k * sub + 1) * (INNER_S / sub), 12)
            ur = np.repeat(duty_r[:k], sub)
            ul = np.repeat(duty_l[:k], sub)
            state = plant.simulate(tg, np.append(ur, 0.0), np.append(ul, 0.0), "duty", dt_s)
            th_r, th_l = state["theta_r_rad"][-1], state["theta_l_rad"][-1]
        if k == n:
            break
        o = ctl.inner(int(counts(th_r)), int(counts(th_l)))
        if k % 2 == 0:
            ctl.outer(k * INNER_S)
        duty_r[k], duty_l[k] = o["pwm_r"], o["pwm_l"]
        rows.append(o)
    res: dict[str, np.ndarray] = {"t_s": t_ticks}
    for c in ctl.columns:
        res[c] = np.array([r[c] for r in rows] + [np.nan])
    idx = np.arange(n + 1) * sub
    for c in ("x_m", "y_m", "phi_rad", "slip_r", "slip_l", "dtheta_r_rad_s", "dtheta_l_rad_s",
              "tau_r_nm", "tau_l_nm", "v_m_s"):
        res[c] = state[c][idx]
    slip = (state["slip_r"] != 0) | (state["slip_l"] != 0)
    res["slip_any"] = np.array([slip[i * sub:(i + 1) * sub].any() for i in range(n)] + [False])
    res["slip_fine"] = slip
    res["t_fine"] = state["t_s"]
    refs = np.array([ctl.reference(t) for t in t_ticks])
    res["x_ref"], res["y_ref"] = refs[:, 0], refs[:, 1]
    return res
