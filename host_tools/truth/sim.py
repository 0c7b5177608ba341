"""The truth simulator's binding: ``sim/truth`` (the one deliberate second implementation of
the physics, see ``sim/truth/truth.h``) compiled with the firmware's ``lib/control`` into
``.build/truth/libtruth.so``, one configured simulator a :class:`TruthSim`, which can also drive
another engine's plant (:meth:`TruthSim.set_plant`)."""
from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from host_tools import _build, _cabi, _native


TRUTH_LIB = _build.TARGETS["truth"].output_path()
_truth_lib: ctypes.CDLL | None = None

#: vocabulary effects whose parameters are plain true-robot values in the truth simulator
_PARAM_EFFECTS = {("friction_coefficient", "mu_s"): "robot.mu_s",
                  ("friction_coefficient", "mu_k"): "robot.mu_k",
                  ("wheel_radius", "r_eff"): "robot.r",
                  ("track_width", "b_eff"): "robot.b"}
#: run-format.md's vocabulary effects that lib/slipmodel's plant need not have (the truth has them)
SPEC_EFFECTS = {"payload": ("mass_kg",)}
#: effects the truth simulator has that run-format.md's vocabulary does not
EXTRA_EFFECTS = {"eccentric_wheel": ("eps", "phase_r", "phase_l"),
                 "battery_sag": ("r_int", "v_per_as"),
                 "friction_patch": ("x0", "x1", "factor")}


def build_truth(force: bool = False) -> Path:
    """Compile ``sim/truth`` with the firmware's lib/control (and the lib/slipmodel parameter
    code it uses) into ``.build/truth/libtruth.so`` when missing or stale (the project's one
    host build recipe, :mod:`host_tools._build`, target ``truth``)."""
    return _build.build("truth", force=force)


def _tlib() -> ctypes.CDLL:
    global _truth_lib
    if _truth_lib is None:  # signatures: sim/truth/truth.h
        _truth_lib = _cabi.bind(ctypes.CDLL(str(build_truth())), "truth")
    return _truth_lib


class TruthSim:
    """One configured truth simulator. Keys: :meth:`keys` (``robot.*``/``motor.*`` = the TRUE
    robot, ``ctl.*`` = the controller's nominal configuration, ``ref.*``, ``sim.*``, ``rec.*``
    and ``pi.*`` = the recorder, effects)."""

    def __init__(self):
        self._lib = _tlib()
        self._h = self._lib.tr_new()

    def __del__(self):
        if getattr(self, "_h", None):
            self._lib.tr_free(self._h)
            self._h = None

    def keys(self) -> list[str]:
        return [self._lib.tr_key_name(i).decode() for i in range(self._lib.tr_key_count())]

    def set(self, key: str, value: float) -> None:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{key}: {value!r} is not a number") from None
        rc = self._lib.tr_set(self._h, key.encode(), v)
        if rc != 0:
            raise ValueError(f"truth simulator: {self._lib.tr_last_error(self._h).decode()}")

    def get(self, key: str) -> float:
        out = ctypes.c_double()
        if self._lib.tr_get(self._h, key.encode(), ctypes.byref(out)) != 0:
            raise ValueError(f"truth simulator: {self._lib.tr_last_error(self._h).decode()}")
        return out.value

    def set_segments(self, segments) -> None:
        """The segment list of ``ref.kind`` 3: ``[{"duration_s", "v", "omega"}, ...]``."""
        try:
            arr = np.array([[float(sg["duration_s"]), float(sg.get("v", 0.0)),
                             float(sg.get("omega", 0.0))] for sg in segments], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise ValueError("segments: a list of {duration_s, v, omega} objects") from None
        arr = np.ascontiguousarray(arr.reshape(-1, 3).T)
        dp = ctypes.POINTER(ctypes.c_double)
        rc = self._lib.tr_set_segments(self._h, arr.shape[1], arr[0].ctypes.data_as(dp),
                                       arr[1].ctypes.data_as(dp), arr[2].ctypes.data_as(dp))
        if rc != 0:
            raise ValueError(f"truth simulator: {self._lib.tr_last_error(self._h).decode()}")

    def set_effect(self, name: str, **params: float) -> None:
        """Switch on a vocabulary effect (run-format.md names) or one of :data:`EXTRA_EFFECTS`."""
        vocab = {**{k: dict.fromkeys(v, 0.0) for k, v in SPEC_EFFECTS.items()},
                 **_native.effect_vocabulary()}
        if name in vocab:
            allowed = set(vocab[name])
        elif name in EXTRA_EFFECTS:
            allowed = set(EXTRA_EFFECTS[name])
        else:
            raise ValueError(f"unknown effect '{name}'; known: "
                             f"{', '.join(sorted(vocab) + sorted(EXTRA_EFFECTS))}")
        bad = set(params) - allowed
        if bad:
            raise ValueError(f"effect '{name}' has no parameter(s) {', '.join(sorted(bad))}; "
                             f"it has {', '.join(sorted(allowed))}")
        if name == "stribeck":
            params = {"mu_k0": params.get("mu_k0", self.get("robot.mu_k")),
                      "v_s": params.get("v_s", 0.01)}
        for p, v in params.items():
            self.set(_PARAM_EFFECTS.get((name, p), f"{name}.{p}"), v)

    def set_plant(self, plant) -> None:
        """Drive another engine's plant (``tr_set_plant``): ``plant`` has ``plant_callback()``,
        a ctypes function of the signature in ``sim/truth/truth.h``, and ``error``, the
        exception that stopped a run (e.g. :class:`host_tools.engines.mujoco_robot.MujocoRobot`);
        ``None``: the truth's own physics. Both are kept alive by this object."""
        self._plant = plant
        self._plant_cb = plant.plant_callback() if plant is not None else None
        ptr = ctypes.cast(self._plant_cb, ctypes.c_void_p) if plant is not None else None
        self._lib.tr_set_plant(self._h, ptr, None)

    def plant_state_names(self) -> list[str]:
        return [self._lib.tr_plant_state_name(i).decode()
                for i in range(self._lib.tr_plant_state_count())]

    def run(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Simulate; returns (telemetry columns incl. hidden ``true_*``, camera true poses)."""
        T = self.get("sim.duration")
        n_tel = int(T / self.get("sim.tel_period")) + 8
        n_cam = int(T / self.get("sim.cam_period")) + 3
        tc, cc = self._lib.tr_tel_cols(), self._lib.tr_cam_cols()
        tel = np.zeros((n_tel, tc))
        cam = np.zeros((n_cam, cc))
        nt, nc = ctypes.c_int(), ctypes.c_int()
        dp = ctypes.POINTER(ctypes.c_double)
        rc = self._lib.tr_run(self._h, n_tel, tel.ctypes.data_as(dp), ctypes.byref(nt), n_cam,
                              cam.ctypes.data_as(dp), ctypes.byref(nc))
        if rc != 0:
            cause = getattr(getattr(self, "_plant", None), "error", None)
            raise ValueError(f"truth simulator: {self._lib.tr_last_error(self._h).decode()}"
                             + (f": {cause}" if cause else "")) from cause
        tnames = [self._lib.tr_tel_col_name(i).decode() for i in range(tc)]
        cnames = [self._lib.tr_cam_col_name(i).decode() for i in range(cc)]
        nt, nc = nt.value, nc.value
        return ({c: tel[:nt, i].copy() for i, c in enumerate(tnames)},
                {c: cam[:nc, i].copy() for i, c in enumerate(cnames)})
