"""Case definitions of the concealed-effect suite.

A case is a hidden truth (effects switched on in the truth simulator) plus the experiments
(closed-loop references) recorded from it, and the recorder that recorded them. The label
(:meth:`Case.label`) is what the scorer knows and the analyzer never sees: it is written under
``labels/``, apart from ``runs/``.

The sets are data (``sets.json`` beside this file, :data:`SET_DATA`; docs/suite.md; the protocol and
each held-back set's record in docs/validation.md): each with what it is for, its provenance (the commit that defined it and the one
since which its cases are unchanged, checked by host_tools/tests/suite/test_suite.py), its seeds, its
engine, its recorders and its cases. ``tuning`` (:func:`all_cases`) and ``mujoco``: analyzer rules
may be settled on them; ``heldback`` to ``heldback42``: other seeds, effect sizes and recorders
(the truth simulator's recorder variants), long runs; only scored.

Concealment kinds:
- ``compensation``: the closed loop hides the effect in tracking; it shows only in the duty or
  torque the controller needed;
- ``regime``: the effect acts only at high speed, only while accelerating/slipping, only at small
  duty or only in turns;
- ``hidden_channel``: below the noise in the robot's own channels, visible only in the camera
  (or the other way round);
- ``confounded``: two effects with overlapping signatures.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

from host_tools.params import ROBOT

R = ROBOT["r"]  # nominal wheel radius, only to write the thesis's wheel accelerations as m/s^2

# ---- experiment sets: (reference, clamp, duration_s)
LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}
STD = [(LINE, True, 3.0),
       ({"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.5}, True, 3.0),
       ({"kind": "arc", "accel": 1.2, "cruise": 0.6, "radius": -0.7}, True, 3.0)]
SLIP = [({"kind": "line", "accel": 72 * R, "cruise": 36 * R}, False, 2.0),
        ({"kind": "line", "accel": 48 * R, "cruise": 24 * R}, False, 2.0),
        ({"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": 0.6}, True, 2.0),
        ({"kind": "line", "accel": 1.0, "cruise": 0.6}, True, 2.0)]
SLOW = [({"kind": "line", "accel": 0.3, "cruise": 0.15}, True, 2.5),
        ({"kind": "arc", "accel": 0.3, "cruise": 0.2, "radius": 0.4}, True, 2.5),
        ({"kind": "line", "accel": 0.6, "cruise": 0.5}, True, 2.0)]
EIGHT = [({"kind": "figure_eight", "accel": 1.0, "cruise": 0.5, "radius": 0.5}, True, 3.0),
         (LINE, True, 2.0),
         ({"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": -0.5}, True, 2.0)]
# one fast run among slow ones: a speed-dependent effect shows in one run only
FAST_ONE = [SLOW[0][:2] + (2.0,), SLOW[1], ({"kind": "line", "accel": 1.2, "cruise": 0.9}, True, 2.0)]

NEUTRAL = {"friction_coefficient": {"mu_s": ROBOT["mu_s"], "mu_k": ROBOT["mu_k"]},
           "wheel_radius": {"r_eff": ROBOT["r"]}, "track_width": {"b_eff": ROBOT["b"]},
           "motor_back_emf": {"ke_ratio": 1.0}, "driver_voltage_drop": {"volts": 0.0},
           "actuation_delay": {"delay_s": 0.0}, "motor_lag": {"tau_s": 0.0},
           "axle_viscous": {"c": 0.0}, "axle_coulomb": {"torque": 0.0},
           "caster_drag": {"mu": 0.0}, "load_transfer": {"h": 0.0},
           "stribeck": {"mu_k0": ROBOT["mu_k"], "v_s": 0.01}, "deadband": {"volts": 0.0},
           "motor_gain_asymmetry": {"ratio": 1.0}, "floor_slope": {"rad": 0.0},
           "payload": {"mass_kg": 0.0}}
#: the parameter scored for each effect
MAIN_PARAM = {"friction_coefficient": "mu_s", "wheel_radius": "r_eff", "track_width": "b_eff",
              "motor_back_emf": "ke_ratio", "driver_voltage_drop": "volts",
              "actuation_delay": "delay_s", "motor_lag": "tau_s", "axle_viscous": "c",
              "axle_coulomb": "torque", "caster_drag": "mu", "load_transfer": "h",
              "stribeck": "mu_k0", "deadband": "volts", "motor_gain_asymmetry": "ratio",
              "floor_slope": "rad", "payload": "mass_kg"}
OUT_OF_VOCABULARY = ("eccentric_wheel", "battery_sag", "friction_patch")


@dataclass
class Case:
    name: str
    effects: dict
    experiments: list
    expect: str                       # no_mismatch | explained | unexplained
    concealment: list = field(default_factory=list)
    note: str = ""
    fast: bool = False
    seed: int = 0
    recorder: dict = field(default_factory=dict)  # host_tools.truth.RECORDER_DEFAULTS overrides
    recorder_name: str = "firmware"
    long: bool = False                # 10-minute case (bench --no-long skips it)
    set: str = "tuning"
    engine: str = "truth"             # the physics the recorder drives: truth | mujoco
    engine_options: dict = field(default_factory=dict)  # e.g. {"inductance_h": 0.002} (mujoco)

    @property
    def length(self) -> str:
        """Run-length class: 'short' (<= 3 s runs), '20 s', '1 min', '2 min' or '10 min'
        (total)."""
        total = sum(d for _, _, d in self.experiments)
        longest = max(d for _, _, d in self.experiments)
        if longest <= 5.0:
            return "short"
        return ("10 min" if total >= 590 else "2 min" if longest >= 100 else
                "1 min" if longest >= 30 else "20 s")

    @property
    def true_effects(self) -> list[str]:
        return [e for e in self.effects if e not in OUT_OF_VOCABULARY]

    def label(self) -> dict:
        return {"case": self.name, "effects": self.effects, "expect": self.expect,
                "true_effects": self.true_effects, "concealment": self.concealment,
                "main_param": ({"effect": self.true_effects[0],
                                "param": MAIN_PARAM[self.true_effects[0]],
                                "value": self.effects[self.true_effects[0]][MAIN_PARAM[self.true_effects[0]]],
                                "nominal": NEUTRAL[self.true_effects[0]][MAIN_PARAM[self.true_effects[0]]]}
                               if self.true_effects else None),
                "note": self.note, "set": self.set, "length": self.length, "long": self.long,
                "recorder_name": self.recorder_name, "recorder": self.recorder,
                "engine": self.engine, "engine_options": self.engine_options,
                "experiments": [{"reference": r, "clamp": c, "duration_s": d}
                                for r, c, d in self.experiments]}


TOUR = {"kind": "tour", "accel": 0.6, "alpha": 2.0}  # host_tools.truth.tour_reference, per run seed
LONG_20S = [(TOUR, True, 20.0), (TOUR, True, 20.0)]
LONG_2MIN = [(TOUR, True, 120.0), (TOUR, True, 120.0)]
# host_tools.truth.reversal_reference, per run seed: fast cruises forward and backward where the
# duty saturates, direct reversals, stops from speed, arcs and spins that reverse; 'hard' with
# the clamp off and steeper ramps, so the hardest transitions slip.
REV = {"kind": "reversals", "accel": 1.2, "alpha": 6.0}
REV_HARD = {"kind": "reversals", "accel": 1.6, "alpha": 8.0}
LONG_60S = [(REV, True, 60.0), (REV, True, 60.0)]
LONG_60S_HARD = [(REV_HARD, False, 60.0)]
#: experiment sets and references a set's data (sets.json) names
RUNS = {"STD": STD, "SLIP": SLIP, "SLOW": SLOW, "EIGHT": EIGHT, "FAST_ONE": FAST_ONE,
        "LONG_20S": LONG_20S, "LONG_2MIN": LONG_2MIN, "LONG_60S": LONG_60S,
        "LONG_60S_HARD": LONG_60S_HARD}
REFS = {"TOUR": TOUR, "REV": REV, "REV_HARD": REV_HARD}


def _short(exps: list, extra: dict | None = None) -> list:
    """The same experiments as runs of 1.5 s, and one more run of ``extra`` (clamped)."""
    out = [(r, c, 1.5) for r, c, _ in exps]
    return out + ([(extra, True, 1.5)] if extra else [])


def _runs(spec) -> list:
    """A case's experiments from its data: a name of :data:`RUNS`, ``{"short": name, "extra":
    reference}`` (:func:`_short`) or a list of ``[reference or a name of REFS, clamp, s]``."""
    if isinstance(spec, str):
        return RUNS[spec]
    if isinstance(spec, dict):
        return _short(RUNS[spec["short"]], spec.get("extra"))
    return [(REFS[r] if isinstance(r, str) else r, c, d) for r, c, d in spec]


with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "sets.json")) as _fh:
    _DATA = json.load(_fh)
#: each effect's note (what conceals it), shared by the sets' cases of that effect
EFFECT_NOTES: dict[str, str] = _DATA["effect_notes"]
#: the sets' data: about, provenance (the commit that defined the set and the one since which its
#: cases are unchanged), seeds (first, step), engine, recorders (host_tools.truth.RECORDER_DEFAULTS
#: overrides, by name) and cases
SET_DATA: dict[str, dict] = _DATA["sets"]
SETS = tuple(SET_DATA)
#: recorder variants of the held-back sets (none of them is the firmware pipeline)
RECORDERS = SET_DATA["heldback"]["recorders"]
RECORDERS_2 = SET_DATA["heldback2"]["recorders"]


def set_cases(which: str) -> list[Case]:
    """The cases of a set, built from its data: the ``k``-th case has the seed
    ``first + step * k``; a case's recorder is ``firmware`` (no overrides) unless it names one of
    the set's recorders."""
    d = SET_DATA[which]
    cases = []
    for k, row in enumerate(d["cases"]):
        rec = row.get("recorder", "firmware")
        note = EFFECT_NOTES[row["note_of"]] if "note_of" in row else row.get("note", "")
        cases.append(Case(row["name"], row["effects"], _runs(row["runs"]), row["expect"],
                          list(row.get("concealment", [])), note, fast=row.get("fast", False),
                          seed=d["seeds"]["first"] + d["seeds"]["step"] * k,
                          recorder=dict(d["recorders"][rec]) if rec != "firmware" else {},
                          recorder_name=rec, long=row.get("long", False), set=which,
                          engine=row.get("engine", d["engine"]),
                          engine_options=dict(row.get("engine_options", {}))))
    return cases


def all_cases() -> list[Case]:
    """The tuning set."""
    return set_cases("tuning")


def get(names: list[str] | None = None, fast: bool = False, which: str = "tuning",
        long: bool = True) -> list[Case]:
    """Cases of a set (one of :data:`SETS`); ``fast``: its CI subset; ``long=False``:
    without the 10-minute cases; ``names``: those cases of the set."""
    if which not in SETS:
        raise ValueError(f"set must be one of {', '.join(SETS)}, got '{which}'")
    pool = set_cases(which)
    cases = pool
    if fast:
        cases = [c for c in cases if c.fast]
    if names:
        known = {c.name: c for c in pool}
        bad = [n for n in names if n not in known]
        if bad:
            raise ValueError(f"unknown case(s) {', '.join(bad)} in the {which} set; known: "
                             f"{', '.join(sorted(known))}")
        cases = [known[n] for n in names]
    if not long:
        cases = [c for c in cases if not c.long]
    return cases


def demo_case() -> Case:
    """The built-in concealed-effect case of ``python -m host_tools demo``."""
    return next(c for c in all_cases() if c.name == "motor_back_emf_weak")
