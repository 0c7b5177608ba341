"""ctypes loader for the project's native library ``.build/host/libddrobot.so``.

The library is built from every ``host_tools/native/*.cpp`` together with every
``lib/*/src/**/*.cpp`` by :mod:`host_tools._build` (target ``ddrobot``), and rebuilt when any
source or header changes. The ctypes signatures come from the C ABI headers
``host_tools/native/*_capi.h`` (:mod:`host_tools._cabi`). Python does not implement any
physics: everything here calls ``lib/slipmodel`` through its C ABI
(``host_tools/native/slipmodel_capi.h``).

Public API
----------
``library_path()``, ``build(force=False)``, ``library()``, ``effect_vocabulary()``,
``output_columns()``, ``param_keys()`` and ``class Plant``.
"""
from __future__ import annotations

import ctypes
import functools
import math
import threading
import weakref
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from host_tools import _build, _cabi
from host_tools._build import NativeBuildError as NativeBuildError  # noqa: F401  (re-exported)

_lock = threading.Lock()
_lib: ctypes.CDLL | None = None


def library_path() -> Path:
    """Where the shared library lives (it may not exist yet)."""
    return _build.TARGETS["ddrobot"].output_path()


def build(force: bool = False) -> Path:
    """Compile the shared library if it is missing or stale (or always, with ``force``), by
    the project's one host build recipe (:mod:`host_tools._build`, target ``ddrobot``).

    Safe when several processes build at once: a file lock serialises them and the library is
    replaced atomically. Raises :class:`NativeBuildError` with the compiler's message on failure.
    """
    return _build.build("ddrobot", force=force)


def _is_stale() -> bool:
    return _build.is_stale(_build.TARGETS["ddrobot"])


def _load() -> ctypes.CDLL:
    global _lib
    with _lock:
        if _lib is not None:
            return _lib
        _lib = _cabi.bind(ctypes.CDLL(str(build())), "ddrobot")
        return _lib


def library() -> ctypes.CDLL:
    """The loaded shared library (built first if missing or stale), for other bindings of the
    same ``libddrobot.so`` (e.g. the lib/control C ABI). Every function of its headers
    (:data:`host_tools._cabi.HEADERS`) has its ``argtypes``/``restype`` set."""
    return _load()


def effect_vocabulary() -> dict[str, dict[str, float]]:
    """Effect name -> {parameter name -> default}, as the native library defines them."""
    return {k: dict(v) for k, v in _vocabulary().items()}


@functools.lru_cache(maxsize=None)
def _vocabulary() -> dict[str, dict[str, float]]:
    lib = _load()
    vocab: dict[str, dict[str, float]] = {}
    for i in range(lib.sm_effect_count()):
        name = lib.sm_effect_name(i).decode()
        vocab[name] = {lib.sm_effect_param_name(i, k).decode(): lib.sm_effect_param_default(i, k)
                       for k in range(lib.sm_effect_param_count(i))}
    return vocab


def output_columns() -> list[str]:
    """Names of the columns ``Plant.simulate`` returns, in the native order."""
    return list(_columns())


@functools.lru_cache(maxsize=None)
def _columns() -> tuple[str, ...]:
    lib = _load()
    return tuple(lib.sm_out_col_name(i).decode() for i in range(lib.sm_out_cols()))


def param_keys() -> list[str]:
    """The plant's parameter keys: ``robot.<name>`` (Table II.2) and ``motor.<name>``."""
    return list(_param_keys())


@functools.lru_cache(maxsize=None)
def _param_keys() -> tuple[str, ...]:
    lib = _load()
    return tuple(lib.sm_param_name(i).decode() for i in range(lib.sm_param_count()))


_MODES = {"torque": 0, "duty": 1}


def _as_1d(name: str, x, n: int | None = None) -> np.ndarray:
    try:
        a = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not numeric ({exc})") from None
    if a.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array, got shape {a.shape}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name}: length {a.shape[0]} differs from t_s length {n}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is {a[bad[0]]}: inputs must be finite")
    return a


class Plant:
    """The lib/slipmodel Euler plant.

    ``robot`` and ``motor`` take the keys of ``meta.json`` (``mu_s`` ... ``m_w``; ``supply_v``,
    ``no_load_rad_s``, ``stall_nm``); missing keys keep the Table II.2 / datasheet defaults and
    an unknown key raises ``ValueError`` (use :meth:`from_meta` to ignore unknown keys as the
    run format requires).
    """

    def __init__(self, robot: Mapping[str, float] | None = None,
                 motor: Mapping[str, float] | None = None):
        self._lib = _load()
        self._h = self._lib.sm_plant_new()
        if not self._h:
            raise MemoryError("sm_plant_new failed")
        self._finalizer = weakref.finalize(self, self._lib.sm_plant_free, self._h)
        for k, v in (robot or {}).items():
            self.set(f"robot.{k}", v)
        for k, v in (motor or {}).items():
            self.set(f"motor.{k}", v)

    @classmethod
    def from_meta(cls, meta: Mapping) -> "Plant":
        """A plant with the ``robot`` and ``motor`` parameters of a run's meta.json dict.
        Unknown keys are ignored (run-format.md); bad values raise ``ValueError``."""
        keys = set(param_keys())
        robot = {k: v for k, v in (meta.get("robot") or {}).items() if f"robot.{k}" in keys}
        motor = {k: v for k, v in (meta.get("motor") or {}).items() if f"motor.{k}" in keys}
        return cls(robot, motor)

    def _err(self) -> str:
        msg = self._lib.sm_last_error(self._h)
        return msg.decode() if msg else ""

    def set(self, key: str, value: float) -> None:
        """Set ``robot.<p>``, ``motor.<p>``, ``<effect>.<param>``, ``<effect>.enabled`` or the
        model setting ``plant.spin_share`` (lib/slipmodel/src/slipmodel/keys.h)."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{key}: value {value!r} is not a number") from None
        rc = self._lib.sm_plant_set(self._h, str(key).encode(), v)
        if rc == -1:
            raise ValueError(f"unknown plant key '{key}'")
        if rc != 0:
            raise ValueError(f"{key}: bad value {value!r} ({self._err()})")

    def get(self, key: str) -> float:
        out = ctypes.c_double()
        rc = self._lib.sm_plant_get(self._h, str(key).encode(), ctypes.byref(out))
        if rc != 0:
            raise ValueError(f"unknown plant key '{key}'")
        return out.value

    def params(self) -> dict[str, float]:
        """All ``robot.*`` and ``motor.*`` parameters."""
        return {k: self.get(k) for k in param_keys()}

    def set_effect(self, name: str, **params: float) -> None:
        """Switch effect ``name`` on; parameters not given take their defaults."""
        vocab = _vocabulary()
        if name not in vocab:
            raise ValueError(f"unknown effect '{name}'; known: {', '.join(vocab)}")
        unknown = set(params) - set(vocab[name])
        if unknown:
            raise ValueError(f"effect '{name}' has no parameter(s) {sorted(unknown)}; "
                             f"it has {list(vocab[name])}")
        values = dict(vocab[name])
        values.update(params)
        old = {p: self.get(f"{name}.{p}") for p in values}
        try:
            for p, v in values.items():
                self.set(f"{name}.{p}", v)
        except ValueError:
            for p, v in old.items():  # all or nothing: a bad value changes no setting
                self.set(f"{name}.{p}", v)
            raise
        self.set(f"{name}.enabled", 1.0)

    def disable_effect(self, name: str) -> None:
        if name not in effect_vocabulary():
            raise ValueError(f"unknown effect '{name}'")
        self.set(f"{name}.enabled", 0.0)

    def clear_effects(self) -> None:
        """All effects off, their parameters back to the defaults."""
        self._lib.sm_plant_clear_effects(self._h)

    def enabled_effects(self) -> dict[str, dict[str, float]]:
        out = {}
        for name, params in effect_vocabulary().items():
            if self.get(f"{name}.enabled"):
                out[name] = {p: self.get(f"{name}.{p}") for p in params}
        return out

    def simulate(self, t_s: Iterable[float], in_r: Iterable[float], in_l: Iterable[float],
                 mode: str = "torque", dt_s: float = 5e-4,
                 start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 start_velocity: tuple[float, float, float, float, float] | None = None
                 ) -> dict[str, np.ndarray]:
        """Reset to ``start_pose`` at rest (or moving with ``start_velocity`` = (v, w, omega,
        dtheta_r, dtheta_l), see ``Plant::set_velocity``) and simulate.

        Inputs are held over ``[t_s[k], t_s[k+1])`` (N m in ``mode="torque"``, duty in [-1, 1] in
        ``mode="duty"``); the plant integrates with an internal step <= ``dt_s``. Returns the
        columns of :func:`output_columns`, row k being the state at ``t_s[k]`` (torques, normal
        and contact forces of row k are those applied just after ``t_s[k]``).
        """
        if mode not in _MODES:
            raise ValueError(f"mode must be 'torque' or 'duty', got {mode!r}")
        try:
            dt = float(dt_s)
        except (TypeError, ValueError):
            raise ValueError(f"dt_s: {dt_s!r} is not a number") from None
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt_s must be a positive finite number, got {dt_s!r}")
        t = _as_1d("t_s", t_s)
        n = t.shape[0]
        if n < 1:
            raise ValueError("t_s is empty")
        r = _as_1d("in_r", in_r, n)
        l = _as_1d("in_l", in_l, n)
        nonincr = np.flatnonzero(np.diff(t) <= 0.0)
        if nonincr.size:
            k = int(nonincr[0]) + 1
            raise ValueError(f"t_s must increase strictly: t_s[{k}] = {t[k]} <= t_s[{k-1}] = {t[k-1]}")
        if len(start_pose) != 3 or not all(math.isfinite(float(v)) for v in start_pose):
            raise ValueError(f"start_pose must be three finite numbers, got {start_pose!r}")
        rc = self._lib.sm_plant_reset(self._h, *(float(v) for v in start_pose))
        if rc != 0:
            raise ValueError(self._err())
        if start_velocity is not None:
            if len(start_velocity) != 5:
                raise ValueError(f"start_velocity must be five numbers, got {start_velocity!r}")
            rc = self._lib.sm_plant_set_velocity(self._h, *(float(v) for v in start_velocity))
            if rc != 0:
                raise ValueError(self._err())
        cols = _columns()
        out = np.empty((n, len(cols)), dtype=np.float64)
        dp = ctypes.POINTER(ctypes.c_double)
        rc = self._lib.sm_simulate(self._h, _MODES[mode], n, t.ctypes.data_as(dp),
                                   r.ctypes.data_as(dp), l.ctypes.data_as(dp), dt,
                                   out.ctypes.data_as(dp))
        if rc != 0:
            raise ValueError(f"simulate failed ({rc}): {self._err()}")
        return {c: out[:, i].copy() for i, c in enumerate(cols)}

    def tau_max(self) -> tuple[float, float]:
        """II.51 per wheel (right, left) for the plant's parameters and static normal forces."""
        return (self._lib.sm_tau_max(self._h, 0), self._lib.sm_tau_max(self._h, 1))

    def normal_forces(self) -> tuple[float, float, float]:
        """Static normal forces (N_r, N_l, N_c) in N, II.27-II.29."""
        a, b, c = ctypes.c_double(), ctypes.c_double(), ctypes.c_double()
        self._lib.sm_normal_forces(self._h, ctypes.byref(a), ctypes.byref(b), ctypes.byref(c))
        return (a.value, b.value, c.value)
