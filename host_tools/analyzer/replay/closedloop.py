"""Closed-loop replay through lib/control, and what it needs from a run."""
from __future__ import annotations

import math
from typing import Any, Mapping, cast

import numpy as np

from host_tools import params as param_table
from host_tools import protocol as P
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import Channel
from host_tools.analyzer.replay.normal_forces import plant_config
from host_tools.control import REF_KINDS as PROFILE_KINDS


# meta.json reference.kind: the firmware's profiles and its drive mode (the Drive commands)
REF_KINDS = (*PROFILE_KINDS, "drive")
# meta.json "controller" values that mean lib/control's cascade (absent: assumed)
REPLAYABLE_CONTROLLERS = ("improved", "cascade")
# meta.json "controller_variant": the cascade's velocity loop (absent: the firmware's default,
# improved), the protocol's names and codes (the C ABI's "controller" key takes the same codes)
VELOCITY_LOOPS = dict(P.definition().enums["controller"])
CLOSED_LOOP_CHANNELS = ("tau_cmd_r", "tau_cmd_l", "pwm_r", "pwm_l")


def closed_loop_setup(meta: Mapping[str, Any], t: np.ndarray, tau_r: np.ndarray, tau_l: np.ndarray
                      ) -> tuple[dict[str, Any] | None, list[str], list[str]]:
    """What the closed-loop replay needs from a run, or why it cannot run.

    Returns (setup, problems, assumptions).  ``setup`` is None when a problem makes the replay
    impossible.  Needed: ``meta["reference"]`` = ``{"kind": line|arc|figure_eight, "accel":
    m/s^2, "cruise": m/s, "radius": m (arc, figure eight)}`` (the free-text ``experiment`` is
    not parsed: that would be guessing), or for a drive ``{"kind": "drive", "accel", "alpha",
    "commands": [{"t_s", "v", "omega"}, ...]}`` (the Drive targets as the firmware latched them,
    host_tools/logger/reference.py), ``torque_clamp``, ``periods_s.inner``/``outer``.
    ``reference.t0_s`` is the board time of the controller's first tick (reference time 0);
    when absent it is taken as 0 (the board clock starts with the experiment, as the truth
    simulator writes) and that assumption is checked against the recording: every change of
    the recorded torque command must fall in a telemetry interval that contains a tick."""
    problems: list[str] = []
    assumptions: list[str] = []
    ctl = meta.get("controller")
    if ctl is not None and ctl not in REPLAYABLE_CONTROLLERS:
        return None, [f"meta.json controller {ctl!r} is not one that lib/control replays "
                      f"({', '.join(REPLAYABLE_CONTROLLERS)})"], []
    variant = meta.get("controller_variant", "improved")
    if not isinstance(variant, str) or variant not in VELOCITY_LOOPS:
        return None, [f"meta.json controller_variant {variant!r} is not a velocity loop of "
                      f"lib/control ({', '.join(VELOCITY_LOOPS)})"], []
    ref = meta.get("reference")
    if not isinstance(ref, Mapping):
        msg = ("meta.json has no structured 'reference' ({kind, accel, cruise, radius}); "
               "the free-text 'experiment' is not parsed, so the reference the firmware "
               "tracked is unknown")
        cmds = meta.get("commands")
        if isinstance(cmds, list) and any(isinstance(c, Mapping) and c.get("command") == "Start"
                                          for c in cmds):
            msg += ("; the logged Start command gives the profile but not the board time at "
                    "which the experiment started, which the replay would need (reference.t0_s)")
        return None, [msg], []
    kind = ref.get("kind")
    if kind not in REF_KINDS:
        return None, [f"meta.json reference.kind {kind!r} is not one of {list(REF_KINDS)}"], []
    vals = {}
    need = (["accel", "alpha"] if kind == "drive" else
            ["accel", "cruise"] + (["radius"] if kind != "line" else []))
    drive = None
    if kind == "drive":  # the Drive targets as the firmware latched them (host_tools/logger/reference.py)
        cmds = ref.get("commands")
        if (not isinstance(cmds, list) or not all(
                isinstance(c, Mapping) and all(isinstance(c.get(k), (int, float)) and not isinstance(c.get(k), bool)
                                               and math.isfinite(c[k]) for k in ("t_s", "v", "omega"))
                for c in cmds)):
            problems.append("meta.json reference.commands must be a list of {t_s, v, omega} numbers")
        else:
            drive = {"accel": ref.get("accel"), "alpha": ref.get("alpha"),
                     "commands": [{k: float(c[k]) for k in ("t_s", "v", "omega")} for c in cmds]}
    for k in need:
        v = ref.get(k)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            problems.append(f"meta.json reference.{k} is missing or not a number")
        else:
            vals[k] = float(v)
    if "torque_clamp" not in meta:
        problems.append("meta.json has no 'torque_clamp': the clamp setting the firmware ran "
                        "with is unknown")
    periods = meta.get("periods_s", {})
    inner, outer = float(periods.get("inner", 0.0)), float(periods.get("outer", 0.0))
    ratio = round(outer / inner) if inner > 0 else 0
    if inner <= 0 or ratio < 1 or abs(ratio * inner - outer) > 1e-9:
        problems.append(f"periods_s inner {inner} / outer {outer}: the outer loop is not a whole "
                        "number of inner ticks")
    if problems:
        return None, problems, []
    t0 = ref.get("t0_s")
    if t0 is None:
        t0 = 0.0
        assumptions.append("reference.t0_s not in meta.json: the controller's first tick (reference "
                           "time 0) is taken at board time 0")
        if float(t[0]) - t0 > 10.0 * inner * max(ratio, 1):
            problems.append(f"reference.t0_s not in meta.json and the first telemetry frame is at "
                            f"board time {float(t[0]):g} s, not near 0: the board clock does not "
                            f"start with the experiment, so the controller's first tick is unknown")
            return None, problems, assumptions
    t0 = float(t0)
    if t0 > float(t[0]) + inner:
        # a recording that starts before the run (the logger's, idle until Start or Drive): the
        # frames before t0 must command nothing; they are not replayed
        before = np.asarray(t) < t0 - 1e-9
        if np.any(np.asarray(tau_r)[before] != 0) or np.any(np.asarray(tau_l)[before] != 0):
            problems.append(f"reference.t0_s = {t0} s is after the first telemetry frame's tick "
                            "and the frames before it command torque")
            return None, problems, assumptions
        assumptions.append(f"the recording starts {t0 - float(t[0]):.3g} s before the run's first tick "
                           "(reference.t0_s); the idle frames before it are not replayed")
    # the recorded torque command must change only in intervals that contain a tick
    ch = np.flatnonzero((np.diff(tau_r) != 0) | (np.diff(tau_l) != 0)) + 1
    ch = ch[t[ch - 1] >= t0]
    if ch.size:
        tick = t0 + np.floor((t[ch] - t0) / inner + 1e-9) * inner
        bad = int(np.sum(~(tick > t[ch - 1] + 1e-9)))
        if bad > max(1, int(0.05 * ch.size)):
            problems.append(f"{bad} of {ch.size} changes of the recorded torque command fall "
                            f"between ticks of a {inner * 1e3:g} ms schedule starting at "
                            f"t0 = {t0:g} s: the tick times are not known")
            return None, problems, assumptions
    return ({"kind": kind, "accel": vals["accel"], "cruise": vals.get("cruise", 0.0),
             "radius": vals.get("radius", 1.0), "clamp": bool(meta["torque_clamp"]), "drive": drive,
             "t0_s": t0, "inner_s": inner, "outer_every": int(ratio),
             "controller": VELOCITY_LOOPS[variant]}, [], assumptions)


CTL_KEYS = (*param_table.ROBOT, *param_table.MOTOR)  # the controller's nominal keys in meta.json


class ClosedLoopReplay:
    """Closed-loop replay through lib/control: the firmware's fixed-point cascade, configured
    with the run's nominal parameters, reference and clamp setting, drives the lib/slipmodel
    plant (with or without candidate effects) on the firmware's schedule: an inner step every
    ``periods_s.inner`` on the plant's encoder counts (floor of angle x ppr / 2 pi), an outer
    step every ``periods_s.outer`` after the inner step of the same tick.  It reproduces the
    torque and duty the firmware should have commanded.

    The loop is lib/closedloop's driver (C ABI ``cl_*``, bound by
    :class:`host_tools.control.ClosedLoop`), which steps plant and controller forward tick by
    tick: cost linear in the run length."""

    name = "closed-loop"

    def __init__(self, dt_s: float = 5e-4):
        self.dt_s = dt_s

    @staticmethod
    def available() -> tuple[bool, str]:
        try:
            from host_tools.control import ClosedLoop  # noqa: F401  (lib/closedloop C ABI)
        except Exception as exc:  # pragma: no cover - depends on the build
            return False, f"the lib/control C ABI could not be loaded: {exc}"
        return True, ""

    def setup(self, prep: "PreparedRun") -> tuple[dict[str, Any] | None, list[str], list[str]]:
        tel = prep.run.telemetry
        setup, problems, assumptions = closed_loop_setup(prep.run.meta, tel["t_s"],
                                                         tel["tau_cmd_r"], tel["tau_cmd_l"])
        # the loader fills missing meta keys with the run format's defaults: say when the
        # clamp setting is such a default rather than recorded
        try:
            import json
            import os
            with open(os.path.join(prep.run.path, "meta.json")) as fh:
                raw = json.load(fh)
        except (OSError, ValueError):
            raw = None
        if isinstance(raw, Mapping) and "torque_clamp" not in raw and setup is not None:
            assumptions.append("torque_clamp not in meta.json: the run format's default "
                               f"({str(setup['clamp']).lower()}) is used")
        return setup, problems, assumptions

    def simulate(self, prep: "PreparedRun", effects: Mapping[str, Mapping[str, float]],
                 setup: dict[str, Any] | None = None) -> dict[str, np.ndarray]:
        """Per tick: ``t_s`` (board time), the controller's columns (``tau_cmd_r`` ... ``pwm_l``)
        and the plant's state at the tick (wheel angles ``theta_r_rad``, ``theta_l_rad``, ...).
        Raises ValueError when the run lacks what the replay needs (see
        :func:`closed_loop_setup`)."""
        from host_tools.control import ClosedLoop  # lib/closedloop through its C ABI
        if setup is None:
            setup, problems, _ = self.setup(prep)
            if setup is None:
                raise ValueError("closed-loop replay impossible: " + "; ".join(problems))
        meta = prep.run.meta
        ctl = {part: {k: float(v) for k, v in meta[part].items() if k in CTL_KEYS}
               for part in ("robot", "motor")}
        T, t0 = setup["inner_s"], setup["t0_s"]
        t_end = float(prep.run.telemetry["t_s"][-1])
        n = int(math.floor((t_end - t0) / T + 1e-9)) + 1
        cfg = plant_config(prep.robot, effects)  # the nominal model's normal forces
        loop = ClosedLoop(setup["kind"], setup["accel"], setup["cruise"], setup["radius"],
                          fixed_point=True, clamp=setup["clamp"], ctl_robot=ctl["robot"],
                          ctl_motor=ctl["motor"], plant_robot=cfg.robot, plant_motor=prep.motor,
                          effects=cfg.effects, t0_s=t0, inner_s=T, outer_every=setup["outer_every"],
                          ppr=prep.ppr, plant_dt_s=self.dt_s, start_pose=prep.start_pose,
                          ctl_params={"controller": setup["controller"]},
                          # the firmware's 1 kHz duty ramp, where the recorder says it ramps
                          duty_ramp=bool(prep.run.meta.get("duty_ramp", False)),
                          drive=setup.get("drive"))
        for key, value in cfg.keys.items():
            loop.set(key, value)
        return cast("dict[str, np.ndarray]", loop.run(n))


def closed_loop_channels(prep: "PreparedRun", sim: Mapping[str, np.ndarray]) -> dict[str, Channel]:
    """Recorded against replayed controller outputs at the telemetry frames: a frame reports
    the output of the latest tick at or before it."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    ts = np.asarray(sim["t_s"], float)
    T = float(ts[1] - ts[0]) if ts.size > 1 else 1.0
    idx = np.floor((t - ts[0]) / T + 1e-6).astype(int)
    ok = (idx >= 0) & (idx < ts.size)
    out = {}
    for c in CLOSED_LOOP_CHANNELS:
        unit = "N m" if c.startswith("tau") else "1"
        out[c] = Channel(c, t[ok], np.asarray(tel[c], float)[ok],
                         np.asarray(sim[c], float)[idx[ok]], unit)
    return out
