"""The recorder: what the robot's board runs and logs (:data:`RECORDER_DEFAULTS`: this
project's firmware pipeline; the variants: the truth's own PI loop and odometry, other periods,
jitter, lost frames, camera rate and noise, wrapped headings), checked options, their
command-line form, and the motor current logged as the Motor Shield R3 does."""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from host_tools import protocol, runfmt

PPR = runfmt.DEFAULT_META["encoder_ppr"]  # encoder counts per wheel turn
_PERIODS_S = runfmt.DEFAULT_META["periods_s"]  # the firmware's task periods (protocol.json)


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
#: pipeline (lib/control's cascade and odometry on protocol.json's periods, a 30 Hz camera).
RECORDER_DEFAULTS = {
    "controller": "cascade",    # cascade (lib/control) | pi (the truth's own PI wheel-speed loop)
    "odometry": "firmware",     # firmware (lib/control, at the ticks) | ticks | frames (own code)
    "integration": "arc",       # own odometry: arc (exact arc) | midpoint
    "inner_s": _PERIODS_S["inner"],  # inner period (protocol.json's task table); the outer is twice it
    "tel_s": _PERIODS_S["telemetry"],  # telemetry period (the firmware's, protocol.json's)
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
