"""The nominal closed loop and the independent truth simulator.

* :class:`Controller` — ``lib/control`` through its C ABI, re-exported from
  :mod:`host_tools.control` (where the binding lives).
* :func:`nominal_closed_loop` — that controller in closed loop with the *nominal* plant
  (``lib/slipmodel``), run forward tick by tick by ``lib/closedloop``'s driver
  (:class:`host_tools.control.ClosedLoop`). No physics in Python.
* :func:`build_truth`, :class:`TruthSim`, :func:`simulate_run` — the independent truth simulator
  of ``sim/truth`` (the one deliberate second implementation of the physics, see
  ``sim/truth/truth.h``), compiled with the firmware's ``lib/control`` into
  ``.build/truth/libtruth.so``; :data:`RECORDER_DEFAULTS` are the recorder variants (the
  firmware pipeline by default; the truth's own PI loop and odometry, other periods, jitter,
  lost frames, camera rate and noise, wrapped headings), :func:`tour_reference` a long
  reference, and the motor current is logged like the Motor Shield R3 does.
"""
from __future__ import annotations

import ctypes
import math
import json
import os
from pathlib import Path
from typing import Mapping

import numpy as np

from host_tools import _build, _cabi, _native, protocol, runfmt
from host_tools.control import INNER_S, ClosedLoop, Controller  # noqa: F401  (re-exported)
from host_tools.control import REF_KINDS as _REF_KINDS

PPR = runfmt.DEFAULT_META["encoder_ppr"]  # encoder counts per wheel turn


# ------------------------------------------------- lib/control in closed loop (lib/closedloop)


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


# ------------------------------------------------------------- the truth simulator (sim/truth)


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


# The run format's defaults (Table II.2 and the datasheet motor): the parameter table's
# (params/params.json), which also generates lib/slipmodel's and the truth simulator's defaults.
NOMINAL_META_ROBOT = dict(runfmt.DEFAULT_META["robot"])
NOMINAL_META_MOTOR = dict(runfmt.DEFAULT_META["motor"])
TELEMETRY_SPEC_COLUMNS = ("t_s", "enc_r", "enc_l", "omega_r", "omega_l", "tau_cmd_r", "tau_cmd_l",
                          "pwm_r", "pwm_l", "x_odo_m", "y_odo_m", "phi_odo_rad")

#: the Motor Shield R3's current sense (protocol/protocol.json "current_sense", the scale of
#: Telemetry current_r/current_l): volts_per_amp, magnitude only, read by the adc_bits ADC
#: against AVcc = adc_vref_v: A = raw * adc_vref_v / 2^adc_bits / volts_per_amp.
#: meta.json's "current_sense" holds these and the nominal motor's stall current "stall_a" (not
#: under "motor", whose keys readers hand to the nominal plant, which has no stall current).
CURRENT_SENSE = dict(protocol.definition().current_sense, magnitude_only=True)

#: The recorder: what the robot's board runs and logs. The defaults are this project's firmware
#: pipeline (lib/control's cascade and odometry, 25/50 ms, 50 Hz telemetry, 30 Hz camera).
RECORDER_DEFAULTS = {
    "controller": "cascade",    # cascade (lib/control) | pi (the truth's own PI wheel-speed loop)
    "odometry": "firmware",     # firmware (lib/control, at the ticks) | ticks | frames (own code)
    "integration": "arc",       # own odometry: arc (exact arc) | midpoint
    "inner_s": 0.025,           # inner period; the outer period is twice it
    "tel_s": 0.020,             # telemetry period (the firmware's 50 Hz)
    "tel_jitter_s": 0.0,        # telemetry frame times jitter uniformly by +- this
    "tel_drop": 0.0,            # fraction of telemetry frames dropped (plus one burst when > 0)
    "cam_hz": 30.0,             # camera rate
    "cam_noise_m": 1e-3,        # camera position noise (standard deviation)
    "cam_noise_rad": 0.01,      # camera heading noise
    "cam_dropout": 0.05,        # fraction of camera frames lost (plus one burst)
    "heading_tel": "unwrapped",  # phi_odo_rad: unwrapped | wrapped (to (-pi, pi])
    "heading_gt": "unwrapped",   # groundtruth phi_rad: unwrapped | wrapped
    "current": True,            # log current_r_a, current_l_a like the Motor Shield R3
    "adc_noise_lsb": 1.0,       # current ADC noise (standard deviation, LSB)
    "pwm": "commanded",         # pwm_r/l: commanded (at the tick) | in_force (after actuation_delay)
}
_RECORDER_CHOICES = {"controller": ("cascade", "pi"), "odometry": ("firmware", "ticks", "frames"),
                     "integration": ("arc", "midpoint"), "heading_tel": ("unwrapped", "wrapped"),
                     "heading_gt": ("unwrapped", "wrapped"), "pwm": ("commanded", "in_force")}
_RECORDER_RANGES = {"inner_s": (0.001, 0.5), "tel_s": (0.002, 0.5), "tel_jitter_s": (0.0, 0.5), "tel_drop": (0.0, 0.5),
                    "cam_hz": (1.0, 1000.0), "cam_noise_m": (0.0, 1.0),
                    "cam_noise_rad": (0.0, 1.0), "cam_dropout": (0.0, 0.9),
                    "adc_noise_lsb": (0.0, 100.0)}


def recorder_config(recorder: Mapping | None = None, **overrides) -> dict:
    """:data:`RECORDER_DEFAULTS` updated by ``recorder`` and ``overrides`` and checked (the PI
    loop's odometry defaults to the recorder's own at the ticks)."""
    rec = dict(RECORDER_DEFAULTS)
    for src in (recorder or {}), overrides:
        for k, v in src.items():
            if k not in rec:
                raise ValueError(f"unknown recorder option '{k}'; known: {', '.join(sorted(rec))}")
            rec[k] = v
    if rec["controller"] == "pi" and "odometry" not in {**(recorder or {}), **overrides}:
        rec["odometry"] = "ticks"  # the PI recorder has no lib/control odometry
    for k, choices in _RECORDER_CHOICES.items():
        if rec[k] not in choices:
            raise ValueError(f"recorder {k} must be one of {', '.join(map(str, choices))}, "
                             f"got {rec[k]}")
    for k, (lo, hi) in _RECORDER_RANGES.items():
        try:
            rec[k] = float(rec[k])
        except (TypeError, ValueError):
            raise ValueError(f"recorder {k}: {rec[k]!r} is not a number") from None
        if not lo <= rec[k] <= hi:
            raise ValueError(f"recorder {k} = {rec[k]:g} is outside [{lo:g}, {hi:g}]")
    rec["current"] = bool(rec["current"])
    if rec["controller"] == "pi" and rec["odometry"] == "firmware":
        raise ValueError("the PI recorder has no lib/control odometry: odometry must be "
                         "'ticks' or 'frames'")
    return rec


def tour_reference(duration_s: float, seed: int = 0, accel: float = 0.6,
                   alpha: float = 2.0) -> dict:
    """A long reference: a seeded sequence of speed ramps, cruises, arcs, stops and turns on
    the spot that fills ``duration_s`` and ends at rest (a ``segments`` reference)."""
    rng = np.random.default_rng(seed)
    segs: list[dict] = []
    t = 0.0
    end = max(duration_s - 2.0, 1.0)
    while t < end:
        kind = "cruise" if not segs else str(rng.choice(["cruise", "arc", "stop", "spin"],
                                                         p=[0.35, 0.3, 0.15, 0.2]))
        if kind == "cruise":
            sg = {"duration_s": float(rng.uniform(2.0, 6.0)), "v": float(rng.uniform(0.15, 0.6)),
                  "omega": 0.0}
        elif kind == "arc":
            v = float(rng.uniform(0.15, 0.5))
            R = float(rng.uniform(0.4, 1.5)) * (1 if rng.random() < 0.5 else -1)
            sg = {"duration_s": float(rng.uniform(2.0, 5.0)), "v": v, "omega": v / R}
        elif kind == "stop":
            sg = {"duration_s": float(rng.uniform(1.0, 2.0)), "v": 0.0, "omega": 0.0}
        else:
            sg = {"duration_s": float(rng.uniform(1.0, 3.0)), "v": 0.0,
                  "omega": float(rng.uniform(0.8, 1.5)) * (1 if rng.random() < 0.5 else -1)}
        sg = {k: round(v, 4) for k, v in sg.items()}
        sg["duration_s"] = min(sg["duration_s"], round(end - t, 4)) or 0.1
        segs.append(sg)
        t += sg["duration_s"]
    segs.append({"duration_s": round(max(duration_s - t, 0.1), 4), "v": 0.0, "omega": 0.0})
    return {"kind": "segments", "accel": accel, "alpha": alpha, "segments": segs}


def reversal_reference(duration_s: float, seed: int = 0, accel: float = 1.2,
                       alpha: float = 6.0) -> dict:
    """A long, hard reference: a seeded sequence of fast cruises forward and backward (up to
    1.3 m/s, where the duty saturates), direct reversals, stops from speed, arcs and spins
    that reverse, with ramps at ``accel`` and ``alpha`` (wheel-speed changes of about 30 rad/s
    within a second), filling ``duration_s`` and ending at rest (a ``segments`` reference)."""
    rng = np.random.default_rng([seed, 60])
    segs: list[dict] = []
    t, v_last, w_last = 0.0, 0.0, 0.0
    end = max(duration_s - 2.0, 1.0)
    while t < end:
        kind = str(rng.choice(["cruise", "reverse", "stop", "arc", "spin"],
                              p=[0.3, 0.25, 0.15, 0.15, 0.15]))
        sign = -1.0 if rng.random() < 0.35 else 1.0
        if kind == "cruise":
            sg = {"duration_s": rng.uniform(1.0, 3.0), "v": sign * rng.uniform(0.6, 1.3), "omega": 0.0}
        elif kind == "reverse":  # straight to the opposite speed
            v = -np.sign(v_last or 1.0) * rng.uniform(0.5, 0.9)
            sg = {"duration_s": rng.uniform(1.2, 2.5), "v": v, "omega": 0.0}
        elif kind == "stop":
            sg = {"duration_s": rng.uniform(0.6, 1.5), "v": 0.0, "omega": 0.0}
        elif kind == "arc":
            v = sign * rng.uniform(0.3, 0.8)
            R = rng.uniform(0.4, 1.2) * (1 if rng.random() < 0.5 else -1)
            sg = {"duration_s": rng.uniform(1.0, 2.5), "v": v, "omega": v / R}
        else:  # spin, the other way than the last turn
            sg = {"duration_s": rng.uniform(0.8, 1.8), "v": 0.0,
                  "omega": -np.sign(w_last or 1.0) * rng.uniform(2.0, 4.0)}
        sg = {k: round(float(x), 4) for k, x in sg.items()}
        sg["duration_s"] = min(sg["duration_s"], round(end - t, 4)) or 0.1
        segs.append(sg)
        t += sg["duration_s"]
        v_last, w_last = sg["v"], sg["omega"] or w_last
    segs.append({"duration_s": round(max(duration_s - t, 0.1), 4), "v": 0.0, "omega": 0.0})
    return {"kind": "segments", "accel": accel, "alpha": alpha, "segments": segs}


def wrap_heading(phi) -> np.ndarray:
    """Headings wrapped to (-pi, pi]."""
    return math.pi - np.mod(math.pi - np.asarray(phi, dtype=float), 2 * math.pi)


def _shield_current(i_a: np.ndarray, rng: np.random.Generator, noise_lsb: float) -> np.ndarray:
    """What the firmware logs of an armature current: |I| through the shield's sense output,
    read by the ADC (CURRENT_SENSE) with Gaussian noise of ``noise_lsb``."""
    cs = CURRENT_SENSE
    lsb_v = cs["adc_vref_v"] / 2 ** cs["adc_bits"]
    raw = np.abs(i_a) * cs["volts_per_amp"] / lsb_v + rng.normal(0.0, noise_lsb, i_a.size)
    raw = np.clip(np.round(raw), 0, 2 ** cs["adc_bits"] - 1)
    return raw * lsb_v / cs["volts_per_amp"]


def configure(reference: Mapping, effects: Mapping | None, clamp: bool, duration_s: float,
              seed: int, rec: Mapping, rng: np.random.Generator, rng_rec: np.random.Generator,
              engine: str = "truth", engine_options: Mapping | None = None
              ) -> tuple[TruthSim, dict, str]:
    """A :class:`TruthSim` set up for one run (reference, recorder ``rec`` of
    :func:`recorder_config`, clock phases drawn from ``rng`` and ``rng_rec``, effects on the
    chosen engine's physics): returns (simulator, reference as written to meta.json, kind).
    :func:`simulate_run` and the engines' validation use it."""
    from host_tools.engines import ENGINES
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    if engine_options and engine != "mujoco":
        raise ValueError("engine options are the mujoco engine's")
    sim = TruthSim()
    reference = dict(reference)
    kind = reference.get("kind", "line")
    if kind in ("tour", "reversals"):
        make = tour_reference if kind == "tour" else reversal_reference
        reference = make(duration_s, seed, **{k: reference[k] for k in ("accel", "alpha")
                                              if k in reference})
        kind = "segments"
    if kind == "segments":
        sim.set("ref.kind", 3)
        sim.set("ref.accel", reference.get("accel", 0.6))
        sim.set("ref.alpha", reference.get("alpha", 2.0))
        sim.set_segments(reference.get("segments") or [])
        reference = {"kind": "segments", "accel": float(reference.get("accel", 0.6)),
                     "alpha": float(reference.get("alpha", 2.0)),
                     "segments": [{"duration_s": float(sg["duration_s"]), "v": float(sg.get("v", 0.0)),
                                   "omega": float(sg.get("omega", 0.0))}
                                  for sg in reference["segments"]]}
    elif kind in _REF_KINDS:
        sim.set("ref.kind", _REF_KINDS[kind])
        sim.set("ref.accel", reference.get("accel", 0.5))
        sim.set("ref.cruise", reference.get("cruise", 0.5))
        sim.set("ref.radius", reference.get("radius", 1.0))
    else:
        raise ValueError(f"reference kind must be one of {list(_REF_KINDS) + ['segments', 'tour']}, "
                         f"got {kind!r}")
    pi = rec["controller"] == "pi"
    sim.set("ctl.clamp", 1.0 if clamp and not pi else 0.0)
    sim.set("sim.duration", duration_s)
    inner = rec["inner_s"]
    sim.set("sim.inner_period", inner)
    sim.set("rec.controller", 1.0 if pi else 0.0)
    sim.set("rec.odometry", {"firmware": 0, "ticks": 1, "frames": 2}[rec["odometry"]])
    sim.set("rec.midpoint", 1.0 if rec["integration"] == "midpoint" else 0.0)
    sim.set("sim.tel_period", rec["tel_s"])
    sim.set("rec.tel_jitter", rec["tel_jitter_s"])
    sim.set("rec.pwm_in_force", 1.0 if rec["pwm"] == "in_force" else 0.0)
    # the delay of the duty in force: the plant's actuation delay, wherever the plant applies it
    sim.set("rec.pwm_delay", float(dict((effects or {}).get("actuation_delay", {})).get("delay_s", 0.0)))
    sim.set("rec.seed", float(rng_rec.integers(0, 2 ** 32)))
    # the board's telemetry phase against its tick, and the camera's own clock
    sim.set("sim.tel_phase", float(rng.choice([0.002, 0.004, 0.006, 0.008, 0.012])) % rec["tel_s"])
    sim.set("sim.cam_period", 1.0 / rec["cam_hz"])
    sim.set("sim.cam_phase", float(rng.uniform(0.0, 1.0 / rec["cam_hz"])))
    if engine == "mujoco":
        from host_tools.engines.mujoco_robot import MujocoRobot  # lazy: needs the mujoco package
        plant = MujocoRobot(effects, **dict(engine_options or {}))
        sim.set("sim.dt", plant.dt)
        sim.set_plant(plant)
    else:
        for name, params in (effects or {}).items():
            sim.set_effect(name, **dict(params))
    return sim, reference, kind


def simulate_run(path: str | os.PathLike, reference: Mapping, effects: Mapping | None = None,
                 clamp: bool = True, duration_s: float = 2.0, seed: int = 0,
                 cam_noise_m: float | None = None, cam_noise_rad: float | None = None,
                 cam_dropout: float | None = None,
                 experiment: str | None = None, hidden_dir: str | os.PathLike | None = None,
                 overwrite: bool = False, recorder: Mapping | None = None,
                 engine: str = "truth", engine_options: Mapping | None = None) -> str:
    """Simulate one closed-loop run with the truth simulator and write it as a ``ddrun/1`` run
    folder at ``path`` (meta.json with the NOMINAL parameters, telemetry.csv with the spec
    columns and the shield's motor current, groundtruth.csv from a noisy camera with dropouts).
    The true state (``true_*`` columns) goes to ``hidden_dir/<run name>.truth.csv`` when
    ``hidden_dir`` is given — never into the run folder.

    ``reference``: ``{"kind": "line"|"arc"|"figure_eight", "accel": m/s², "cruise": m/s,
    "radius": m}`` or ``{"kind": "segments", "accel": m/s², "alpha": rad/s², "segments":
    [{"duration_s", "v", "omega"}, ...]}`` or ``{"kind": "tour"}`` (:func:`tour_reference` for
    ``duration_s`` and ``seed``) or ``{"kind": "reversals"}`` (:func:`reversal_reference`);
    ``effects``: ``{name: {param: value}}`` (vocabulary or
    EXTRA_EFFECTS); ``recorder``: options of :data:`RECORDER_DEFAULTS` (the camera arguments
    override the recorder's camera noise and dropout when given). ``engine``: the physics the
    recorder drives, ``"truth"`` (``sim/truth``'s own) or ``"mujoco"``
    (:class:`host_tools.engines.mujoco_robot.MujocoRobot` with ``effects`` and
    ``engine_options``, e.g. ``{"inductance_h": 0.002}``); the run folder does not say which."""
    rec = recorder_config(recorder, **{k: v for k, v in (("cam_noise_m", cam_noise_m),
                                                         ("cam_noise_rad", cam_noise_rad),
                                                         ("cam_dropout", cam_dropout))
                                       if v is not None})
    rng = np.random.default_rng(seed)
    rng_rec = np.random.default_rng([seed, 16])  # the recorder's variants draw from their own stream
    sim, reference, kind = configure(reference, effects, clamp, duration_s, seed, rec, rng,
                                     rng_rec, engine, engine_options)
    pi = rec["controller"] == "pi"
    inner = rec["inner_s"]
    tel, cam = sim.run()
    # camera: noise and dropouts (independent drops plus one short burst)
    keep = rng.random(cam["t_s"].size) > rec["cam_dropout"]
    if cam["t_s"].size > 20:
        b0 = int(rng.integers(5, cam["t_s"].size - 10))
        keep[b0:b0 + int(rng.integers(2, 6))] = False
    gt = {"t_s": np.round(cam["t_s"][keep], 6),
          "x_m": cam["x_m"][keep] + rng.normal(0, rec["cam_noise_m"], keep.sum()),
          "y_m": cam["y_m"][keep] + rng.normal(0, rec["cam_noise_m"], keep.sum()),
          "phi_rad": cam["phi_rad"][keep] + rng.normal(0, rec["cam_noise_rad"], keep.sum())}
    if rec["heading_gt"] == "wrapped":
        gt["phi_rad"] = wrap_heading(gt["phi_rad"])
    if kind == "segments":
        ref_desc = (f"segments: {len(reference['segments'])} speed ramps, cruises, arcs, stops "
                    f"and turns over {sum(s['duration_s'] for s in reference['segments']):g} s")
    else:
        ref_desc = (f"{kind}, accel {reference.get('accel', 0.5)} m/s^2, cruise "
                    f"{reference.get('cruise', 0.5)} m/s" +
                    (f", radius {reference.get('radius')} m" if kind != "line" else ""))
    ref_meta = ({"kind": kind, **{k: float(v) for k, v in reference.items() if k != "kind"}}
                if kind != "segments" else reference)
    motor = dict(NOMINAL_META_MOTOR)
    meta = {"format": "ddrun/1",
            "experiment": experiment or f"{'PI wheel-speed loop' if pi else 'closed loop'}: {ref_desc}",
            "source": "simulator", "torque_clamp": bool(clamp) and not pi,
            "robot": dict(NOMINAL_META_ROBOT), "motor": motor,
            "encoder_ppr": PPR, "periods_s": {"inner": inner, "outer": 2 * inner,
                          "telemetry": rec["tel_s"]},
            "controller": "pi" if pi else "cascade"}
    if pi:
        # no lib/control reference: the closed loop is not lib/control's and cannot be replayed
        # with it; the PI loop's own reference and gains are written instead
        meta["speed_reference"] = ref_meta
        meta["pi"] = {k: sim.get(f"pi.{k}") for k in ("kp", "ki", "j_ff", "tau_limit")}
    else:
        meta["reference"] = ref_meta
    meta["duration_s"] = duration_s
    if rec["current"]:  # with the nominal stall current (the truth's default)
        meta["current_sense"] = dict(CURRENT_SENSE, stall_a=TruthSim().get("motor.stall_a"))
    telemetry = {c: tel[c] for c in TELEMETRY_SPEC_COLUMNS}
    telemetry["t_s"] = np.round(telemetry["t_s"], 6)
    for c in ("enc_r", "enc_l"):
        telemetry[c] = telemetry[c].astype(np.int64)
    if rec["current"]:
        telemetry["current_r_a"] = _shield_current(tel["true_i_r_a"], rng_rec, rec["adc_noise_lsb"])
        telemetry["current_l_a"] = _shield_current(tel["true_i_l_a"], rng_rec, rec["adc_noise_lsb"])
    if rec["heading_tel"] == "wrapped":
        telemetry["phi_odo_rad"] = wrap_heading(telemetry["phi_odo_rad"])
    if rec["tel_drop"] > 0:  # lost frames: independent drops plus one burst; first and last kept
        n = telemetry["t_s"].size
        keep_t = rng_rec.random(n) > rec["tel_drop"]
        if n > 40:
            b0 = int(rng_rec.integers(10, n - 20))
            keep_t[b0:b0 + int(rng_rec.integers(3, 11))] = False
        keep_t[0] = keep_t[-1] = True
        telemetry = {c: v[keep_t] for c, v in telemetry.items()}
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


def add_recorder_arguments(ap) -> None:
    """The recorder variants as command-line options (shared with the suite's generator)."""
    d = RECORDER_DEFAULTS
    g = ap.add_argument_group("recorder variants (defaults: this project's firmware pipeline)")
    g.add_argument("--controller", choices=_RECORDER_CHOICES["controller"], default=d["controller"],
                   help="cascade: lib/control's cascade; pi: the truth's own PI wheel-speed loop "
                        "(meta says 'controller': 'pi' and has no lib/control reference)")
    g.add_argument("--odometry", choices=_RECORDER_CHOICES["odometry"], default=None,
                   help="firmware: lib/control's odometry at the inner ticks; ticks / frames: the "
                        "recorder's own odometry updated at the inner ticks / at the telemetry "
                        "frames (default: firmware, or ticks with --controller pi)")
    g.add_argument("--integration", choices=_RECORDER_CHOICES["integration"], default=d["integration"],
                   help="own odometry's rule: exact arc or midpoint")
    g.add_argument("--inner-ms", type=float, default=1e3 * d["inner_s"],
                   help="inner period in ms (e.g. 10, 20, 25); the outer period is twice it")
    g.add_argument("--tel-ms", type=float, default=1e3 * d["tel_s"],
                   help="telemetry period in ms (default 20: the firmware's 50 Hz)")
    g.add_argument("--tel-jitter-ms", type=float, default=0.0,
                   help="telemetry frame times jitter uniformly by +- this (ms)")
    g.add_argument("--tel-drop", type=float, default=0.0,
                   help="fraction of telemetry frames dropped (plus one burst of 3-10)")
    g.add_argument("--cam-hz", type=float, default=d["cam_hz"], help="camera rate (e.g. 30, 100)")
    g.add_argument("--cam-noise-mm", type=float, default=1e3 * d["cam_noise_m"],
                   help="camera position noise, mm (standard deviation)")
    g.add_argument("--cam-noise-mrad", type=float, default=1e3 * d["cam_noise_rad"],
                   help="camera heading noise, mrad")
    g.add_argument("--cam-dropout", type=float, default=d["cam_dropout"],
                   help="fraction of camera frames lost (plus one burst)")
    g.add_argument("--heading-tel", choices=_RECORDER_CHOICES["heading_tel"], default=d["heading_tel"],
                   help="phi_odo_rad unwrapped or wrapped to (-pi, pi]")
    g.add_argument("--heading-gt", choices=_RECORDER_CHOICES["heading_gt"], default=d["heading_gt"],
                   help="groundtruth phi_rad unwrapped or wrapped to (-pi, pi]")
    g.add_argument("--no-current", action="store_true", help="do not log the motor current")
    g.add_argument("--adc-noise-lsb", type=float, default=d["adc_noise_lsb"],
                   help="current ADC noise, LSB (standard deviation)")


def recorder_from_args(a) -> dict:
    """The recorder options of :func:`add_recorder_arguments`'s parsed arguments."""
    odo = a.odometry or ("ticks" if a.controller == "pi" else "firmware")
    return recorder_config(controller=a.controller, odometry=odo, integration=a.integration,
                           inner_s=a.inner_ms / 1e3, tel_s=a.tel_ms / 1e3, tel_jitter_s=a.tel_jitter_ms / 1e3,
                           tel_drop=a.tel_drop, cam_hz=a.cam_hz, cam_noise_m=a.cam_noise_mm / 1e3,
                           cam_noise_rad=a.cam_noise_mrad / 1e3, cam_dropout=a.cam_dropout,
                           heading_tel=a.heading_tel, heading_gt=a.heading_gt,
                           current=not a.no_current, adc_noise_lsb=a.adc_noise_lsb)


def main(argv=None) -> int:
    """``python -m host_tools.truth RUN_DIR [--ref line|arc|figure_eight|tour|segments]
    [--accel A] [--cruise V] [--radius R] [--segments FILE] [--no-clamp] [--duration T]
    [--seed N] [--effect name:p=v,...]... [--hidden DIR] [recorder variants]``: one closed-loop
    run of the truth simulator written as a run folder (true state to --hidden, never into the
    run). ``--ref tour``: a seeded sequence of speed ramps, stops and turns filling --duration;
    ``--ref segments --segments FILE``: a JSON list of {duration_s, v, omega} (ramps at --accel
    and --alpha)."""
    import argparse
    import sys
    ap = argparse.ArgumentParser(prog="python -m host_tools.truth", description=main.__doc__)
    ap.add_argument("run_dir")
    ap.add_argument("--ref", default="line",
                    choices=list(_REF_KINDS) + ["tour", "reversals", "segments"])
    ap.add_argument("--accel", type=float, default=None,
                    help="m/s^2 (default 1.0; 0.6 for tour and segments, 1.2 for reversals)")
    ap.add_argument("--cruise", type=float, default=0.6, help="m/s")
    ap.add_argument("--radius", type=float, default=0.5, help="m (arc: > 0 turns left)")
    ap.add_argument("--alpha", type=float, default=None,
                    help="rad/s^2 (tour, segments: default 2; reversals: 6)")
    ap.add_argument("--segments", default=None, metavar="FILE",
                    help="JSON list of {duration_s, v, omega} for --ref segments")
    ap.add_argument("--no-clamp", action="store_true", help="tau_max clamp off")
    ap.add_argument("--duration", type=float, default=2.0, help="s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--effect", action="append", default=[], metavar="NAME:P=V,...")
    ap.add_argument("--hidden", default=None, help="folder for the true state (csv)")
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--engine", choices=("truth", "mujoco"), default="truth",
                    help="the physics the recorder drives: the truth simulator's own or the "
                         "MuJoCo model (host_tools.engines.mujoco_robot; needs the mujoco package)")
    ap.add_argument("--inductance-mh", type=float, default=0.0,
                    help="mujoco engine: the motors' armature inductance, mH")
    add_recorder_arguments(ap)
    a = ap.parse_args(argv)
    try:
        effects = dict(_parse_effect(e) for e in a.effect)
        if a.ref in ("tour", "reversals", "segments"):
            hard = a.ref == "reversals"
            ref = {"kind": a.ref, "accel": (1.2 if hard else 0.6) if a.accel is None else a.accel,
                   "alpha": (6.0 if hard else 2.0) if a.alpha is None else a.alpha}
            if a.ref == "segments":
                if not a.segments:
                    raise ValueError("--ref segments needs --segments FILE")
                with open(a.segments) as fh:
                    ref["segments"] = json.load(fh)
        else:
            ref = {"kind": a.ref, "accel": 1.0 if a.accel is None else a.accel,
                   "cruise": a.cruise, "radius": a.radius}
        path = simulate_run(a.run_dir, ref, effects, clamp=not a.no_clamp,
                            duration_s=a.duration, seed=a.seed, hidden_dir=a.hidden,
                            overwrite=a.overwrite, recorder=recorder_from_args(a),
                            engine=a.engine,
                            engine_options=({"inductance_h": a.inductance_mh / 1e3}
                                            if a.engine == "mujoco" else None))
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"run written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
