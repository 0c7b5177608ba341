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

from host_tools import _native, runfmt

ROOT = Path(__file__).resolve().parent.parent
PPR = runfmt.DEFAULT_META["encoder_ppr"]  # encoder counts per wheel turn
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
                        fixed_point: bool = True, dt_s: float = 5e-4,
                        actuator: str = "duty",
                        params: Mapping[str, float] | None = None) -> dict[str, np.ndarray]:
    """The firmware's controller in closed loop with the nominal ``lib/slipmodel`` plant, on the
    25 ms / 50 ms schedule with quantised encoders. ``actuator="duty"`` (default) applies the
    controller's PWM duty through the datasheet motor (torque-speed line, saturation), as the
    robot does; ``actuator="torque"`` applies its torque command after the clamp directly, an
    ideal torque source, as the thesis's Simulink model does (II.6). Returns per-tick arrays:
    ``t_s``, true pose ``x_m, y_m, phi_rad``, reference ``x_ref, y_ref``, controller columns
    (``pwm_r`` ... ``odo_status``), and plant columns at the tick (``slip_r``, ``slip_l``,
    ``dtheta_r_rad_s`` ...), plus ``slip_any`` (any slipping internal step in the tick).
    ``params``: controller keys (``ctl_describe``), e.g. ``{"controller": 1}`` for the thesis's
    velocity loop."""
    if actuator not in ("duty", "torque"):
        raise ValueError(f"actuator must be 'duty' or 'torque', got {actuator!r}")
    plant = plant or _native.Plant()
    ctl = Controller(fixed_point=fixed_point, clamp=clamp, params=params)
    ctl.set_reference(kind, accel_m_s2, cruise_m_s, radius_m)
    ctl.reset(0, 0, (0.0, 0.0, 0.0))
    n = int(round(T_s / INNER_S))
    # plant rows per tick, so that slip inside a tick is seen; with the motor one per millisecond,
    # as the firmware ramps the duty by pwm_slope every millisecond
    sub = 25 if actuator == "duty" else 5
    t_ticks = np.arange(n + 1) * INNER_S
    duty_r = np.zeros(n + 1)
    duty_l = np.zeros(n + 1)
    ramp = np.minimum(np.arange(sub) * (INNER_S * 1e3 / sub), INNER_S * 1e3 - 1.0)  # ms since the tick
    slope_r = np.zeros(n + 1)
    slope_l = np.zeros(n + 1)
    rows: list[dict[str, float]] = []
    state = None
    for k in range(n + 1):
        if k == 0:
            th_r = th_l = 0.0
        else:
            tg = np.round(np.arange(k * sub + 1) * (INNER_S / sub), 12)
            ur = np.clip(np.repeat(duty_r[:k], sub) + np.outer(slope_r[:k], ramp).ravel(), -1.0, 1.0)
            ul = np.clip(np.repeat(duty_l[:k], sub) + np.outer(slope_l[:k], ramp).ravel(), -1.0, 1.0)
            state = plant.simulate(tg, np.append(ur, 0.0), np.append(ul, 0.0), actuator, dt_s)
            th_r, th_l = state["theta_r_rad"][-1], state["theta_l_rad"][-1]
        if k == n:
            break
        o = ctl.inner(int(counts(th_r)), int(counts(th_l)))
        if k % 2 == 0:
            ctl.outer(k * INNER_S)
        if actuator == "duty":
            duty_r[k], duty_l[k] = o["pwm_r"], o["pwm_l"]
            slope_r[k], slope_l[k] = o["pwm_slope_r"], o["pwm_slope_l"]
        else:
            duty_r[k], duty_l[k] = o["tau_cmd_r"], o["tau_cmd_l"]
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


# ------------------------------------------------------------- the truth simulator (sim/truth)


TRUTH_BUILD = ROOT / ".build" / "truth"
TRUTH_LIB = TRUTH_BUILD / "libtruth.so"
_truth_lib: ctypes.CDLL | None = None

#: vocabulary effects whose parameters are plain true-robot values in the truth simulator
_PARAM_EFFECTS = {("friction_coefficient", "mu_s"): "robot.mu_s",
                  ("friction_coefficient", "mu_k"): "robot.mu_k",
                  ("wheel_radius", "r_eff"): "robot.r",
                  ("track_width", "b_eff"): "robot.b"}
#: effects the truth simulator has that run-format.md's vocabulary does not
EXTRA_EFFECTS = {"eccentric_wheel": ("eps", "phase_r", "phase_l"),
                 "battery_sag": ("r_int", "v_per_as"),
                 "friction_patch": ("x0", "x1", "factor")}


def _truth_sources() -> list[Path]:
    srcs = sorted((ROOT / "sim" / "truth").glob("*.cpp"))
    srcs += sorted((ROOT / "lib" / "control" / "src").rglob("*.cpp"))
    srcs += sorted((ROOT / "lib" / "slipmodel" / "src").rglob("*.cpp"))
    return srcs


def build_truth(force: bool = False) -> Path:
    """Compile ``sim/truth`` with the firmware's lib/control (and the lib/slipmodel parameter
    code it uses) into ``.build/truth/libtruth.so`` when missing or stale."""
    TRUTH_BUILD.mkdir(parents=True, exist_ok=True)
    inputs = _truth_sources() + sorted((ROOT / "sim" / "truth").glob("*.h"))
    for sub in ("control", "slipmodel"):
        inputs += sorted((ROOT / "lib" / sub / "src").rglob("*.h"))
    with open(TRUTH_BUILD / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (not force and TRUTH_LIB.exists()
                and all(f.stat().st_mtime <= TRUTH_LIB.stat().st_mtime for f in inputs)):
            return TRUTH_LIB
        tmp = TRUTH_BUILD / f".libtruth.{os.getpid()}.tmp"
        cmd = ["g++", "-std=c++14", "-O2", "-shared", "-fPIC", "-Wall", "-Wextra",
               f"-I{ROOT / 'lib' / 'control' / 'src'}", f"-I{ROOT / 'lib' / 'slipmodel' / 'src'}"]
        cmd += [str(s) for s in _truth_sources()] + ["-o", str(tmp)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            tmp.unlink(missing_ok=True)
            raise _native.NativeBuildError(f"building {TRUTH_LIB} failed:\n{' '.join(cmd)}\n"
                                           f"{proc.stderr}")
        os.replace(tmp, TRUTH_LIB)
    return TRUTH_LIB


def _tlib() -> ctypes.CDLL:
    global _truth_lib
    if _truth_lib is None:
        lib = ctypes.CDLL(str(build_truth()))
        dp = ctypes.POINTER(ctypes.c_double)
        ip = ctypes.POINTER(ctypes.c_int)
        for name, res, args in (
                ("tr_new", ctypes.c_void_p, []), ("tr_free", None, [ctypes.c_void_p]),
                ("tr_last_error", ctypes.c_char_p, [ctypes.c_void_p]),
                ("tr_key_count", ctypes.c_int, []), ("tr_key_name", ctypes.c_char_p, [ctypes.c_int]),
                ("tr_set", ctypes.c_int, [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_double]),
                ("tr_get", ctypes.c_int, [ctypes.c_void_p, ctypes.c_char_p, dp]),
                ("tr_tel_cols", ctypes.c_int, []), ("tr_tel_col_name", ctypes.c_char_p, [ctypes.c_int]),
                ("tr_cam_cols", ctypes.c_int, []), ("tr_cam_col_name", ctypes.c_char_p, [ctypes.c_int]),
                ("tr_run", ctypes.c_int, [ctypes.c_void_p, ctypes.c_int, dp, ip, ctypes.c_int, dp, ip])):
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
        _truth_lib = lib
    return _truth_lib


class TruthSim:
    """One configured truth simulator. Keys: :meth:`keys` (``robot.*``/``motor.*`` = the TRUE
    robot, ``ctl.*`` = the controller's nominal configuration, ``ref.*``, ``sim.*``, effects)."""

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

    def set_effect(self, name: str, **params: float) -> None:
        """Switch on a vocabulary effect (run-format.md names) or one of :data:`EXTRA_EFFECTS`."""
        vocab = _native.effect_vocabulary()
        if name in vocab:
            allowed = set(vocab[name])
        elif name in EXTRA_EFFECTS:
            allowed = set(EXTRA_EFFECTS[name])
        else:
            raise ValueError(f"unknown effect '{name}'; known: {sorted(vocab) + sorted(EXTRA_EFFECTS)}")
        bad = set(params) - allowed
        if bad:
            raise ValueError(f"effect '{name}' has no parameter(s) {sorted(bad)}; it has {sorted(allowed)}")
        if name == "stribeck":
            params = {"mu_k0": params.get("mu_k0", self.get("robot.mu_k")),
                      "v_s": params.get("v_s", 0.01)}
        for p, v in params.items():
            self.set(_PARAM_EFFECTS.get((name, p), f"{name}.{p}"), v)

    def run(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Simulate; returns (telemetry columns incl. hidden ``true_*``, camera true poses)."""
        T = self.get("sim.duration")
        n_tel = int(T / self.get("sim.tel_period")) + 3
        n_cam = int(T / self.get("sim.cam_period")) + 3
        tc, cc = self._lib.tr_tel_cols(), self._lib.tr_cam_cols()
        tel = np.zeros((n_tel, tc))
        cam = np.zeros((n_cam, cc))
        nt, nc = ctypes.c_int(), ctypes.c_int()
        dp = ctypes.POINTER(ctypes.c_double)
        rc = self._lib.tr_run(self._h, n_tel, tel.ctypes.data_as(dp), ctypes.byref(nt), n_cam,
                              cam.ctypes.data_as(dp), ctypes.byref(nc))
        if rc != 0:
            raise ValueError(f"truth simulator: {self._lib.tr_last_error(self._h).decode()}")
        tnames = [self._lib.tr_tel_col_name(i).decode() for i in range(tc)]
        cnames = [self._lib.tr_cam_col_name(i).decode() for i in range(cc)]
        nt, nc = nt.value, nc.value
        return ({c: tel[:nt, i].copy() for i, c in enumerate(tnames)},
                {c: cam[:nc, i].copy() for i, c in enumerate(cnames)})


# The run format's defaults (Table II.2 and the datasheet motor); runfmt keeps them, and
# host_tools/tests/test_native.py checks them against lib/slipmodel's own defaults.
NOMINAL_META_ROBOT = dict(runfmt.DEFAULT_META["robot"])
NOMINAL_META_MOTOR = dict(runfmt.DEFAULT_META["motor"])
TELEMETRY_SPEC_COLUMNS = ("t_s", "enc_r", "enc_l", "omega_r", "omega_l", "tau_cmd_r", "tau_cmd_l",
                          "pwm_r", "pwm_l", "x_odo_m", "y_odo_m", "phi_odo_rad")


def simulate_run(path: str | os.PathLike, reference: Mapping, effects: Mapping | None = None,
                 clamp: bool = True, duration_s: float = 2.0, seed: int = 0,
                 cam_noise_m: float = 1e-3, cam_noise_rad: float = 0.01, cam_dropout: float = 0.05,
                 experiment: str | None = None, hidden_dir: str | os.PathLike | None = None,
                 overwrite: bool = False) -> str:
    """Simulate one closed-loop run with the truth simulator and write it as a ``ddrun/1`` run
    folder at ``path`` (meta.json with the NOMINAL parameters, telemetry.csv with the spec
    columns, groundtruth.csv from a noisy camera with dropouts). The true state (``true_*``
    columns) goes to ``hidden_dir/<run name>.truth.csv`` when ``hidden_dir`` is given — never
    into the run folder.

    ``reference``: ``{"kind": "line"|"arc"|"figure_eight", "accel": m/s², "cruise": m/s,
    "radius": m}``; ``effects``: ``{name: {param: value}}`` (vocabulary or EXTRA_EFFECTS)."""
    from host_tools import runfmt
    rng = np.random.default_rng(seed)
    sim = TruthSim()
    kind = reference.get("kind", "line")
    if kind not in _REF_KINDS:
        raise ValueError(f"reference kind must be one of {list(_REF_KINDS)}, got {kind!r}")
    sim.set("ref.kind", _REF_KINDS[kind])
    sim.set("ref.accel", reference.get("accel", 0.5))
    sim.set("ref.cruise", reference.get("cruise", 0.5))
    sim.set("ref.radius", reference.get("radius", 1.0))
    sim.set("ctl.clamp", 1.0 if clamp else 0.0)
    sim.set("sim.duration", duration_s)
    # the board's telemetry phase against its 25 ms tick, and the camera's own clock
    sim.set("sim.tel_phase", float(rng.choice([0.002, 0.004, 0.006, 0.008, 0.012])))
    sim.set("sim.cam_phase", float(rng.uniform(0.0, 1.0 / 30.0)))
    for name, params in (effects or {}).items():
        sim.set_effect(name, **dict(params))
    tel, cam = sim.run()
    # camera: noise and dropouts (independent drops plus one short burst)
    keep = rng.random(cam["t_s"].size) > cam_dropout
    if cam["t_s"].size > 20:
        b0 = int(rng.integers(5, cam["t_s"].size - 10))
        keep[b0:b0 + int(rng.integers(2, 6))] = False
    gt = {"t_s": np.round(cam["t_s"][keep], 6),
          "x_m": cam["x_m"][keep] + rng.normal(0, cam_noise_m, keep.sum()),
          "y_m": cam["y_m"][keep] + rng.normal(0, cam_noise_m, keep.sum()),
          "phi_rad": cam["phi_rad"][keep] + rng.normal(0, cam_noise_rad, keep.sum())}
    ref_desc = (f"{kind}, accel {reference.get('accel', 0.5)} m/s^2, cruise "
                f"{reference.get('cruise', 0.5)} m/s" +
                (f", radius {reference.get('radius')} m" if kind != "line" else ""))
    meta = {"format": "ddrun/1", "experiment": experiment or f"closed loop: {ref_desc}",
            "source": "simulator", "torque_clamp": bool(clamp),
            "robot": dict(NOMINAL_META_ROBOT), "motor": dict(NOMINAL_META_MOTOR),
            "encoder_ppr": PPR, "periods_s": {"inner": INNER_S, "outer": 0.05, "telemetry": 0.02},
            "reference": {"kind": kind, **{k: float(v) for k, v in reference.items() if k != "kind"}},
            "duration_s": duration_s}
    telemetry = {c: tel[c] for c in TELEMETRY_SPEC_COLUMNS}
    telemetry["t_s"] = np.round(telemetry["t_s"], 6)
    for c in ("enc_r", "enc_l"):
        telemetry[c] = telemetry[c].astype(np.int64)
    runfmt.write_run(path, meta, telemetry, gt, overwrite=overwrite)
    if hidden_dir is not None:
        os.makedirs(hidden_dir, exist_ok=True)
        name = Path(path).name
        cols = ["t_s"] + [c for c in tel if c.startswith("true_") or c == "clamped"]
        np.savetxt(os.path.join(hidden_dir, f"{name}.truth.csv"),
                   np.column_stack([tel[c] for c in cols]), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.9g")
    return os.fspath(path)


def _parse_effect(text: str) -> tuple[str, dict[str, float]]:
    """``name:param=value,param=value`` -> (name, params)."""
    name, _, rest = text.partition(":")
    params: dict[str, float] = {}
    for item in filter(None, rest.split(",")):
        k, eq, v = item.partition("=")
        if not eq:
            raise ValueError(f"--effect {text!r}: expected name:param=value[,param=value]")
        try:
            params[k.strip()] = float(v)
        except ValueError:
            raise ValueError(f"--effect {text!r}: {v!r} is not a number") from None
    return name.strip(), params


def main(argv=None) -> int:
    """``python -m host_tools.truth RUN_DIR [--ref line|arc|figure_eight] [--accel A]
    [--cruise V] [--radius R] [--no-clamp] [--duration T] [--seed N]
    [--effect name:p=v,...]... [--hidden DIR]``: one closed-loop run of the truth simulator
    written as a run folder (true state to --hidden, never into the run)."""
    import argparse
    import sys
    ap = argparse.ArgumentParser(prog="python -m host_tools.truth", description=main.__doc__)
    ap.add_argument("run_dir")
    ap.add_argument("--ref", default="line", choices=list(_REF_KINDS))
    ap.add_argument("--accel", type=float, default=1.0, help="m/s^2")
    ap.add_argument("--cruise", type=float, default=0.6, help="m/s")
    ap.add_argument("--radius", type=float, default=0.5, help="m (arc: > 0 turns left)")
    ap.add_argument("--no-clamp", action="store_true", help="tau_max clamp off")
    ap.add_argument("--duration", type=float, default=2.0, help="s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--effect", action="append", default=[], metavar="NAME:P=V,...")
    ap.add_argument("--hidden", default=None, help="folder for the true state (csv)")
    ap.add_argument("--overwrite", action="store_true")
    a = ap.parse_args(argv)
    try:
        effects = dict(_parse_effect(e) for e in a.effect)
        path = simulate_run(a.run_dir, {"kind": a.ref, "accel": a.accel, "cruise": a.cruise,
                                        "radius": a.radius}, effects, clamp=not a.no_clamp,
                            duration_s=a.duration, seed=a.seed, hidden_dir=a.hidden,
                            overwrite=a.overwrite)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"run written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
