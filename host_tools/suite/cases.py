"""Case definitions of the concealed-effect suite.

A case is a hidden truth (effects switched on in the truth simulator) plus the experiments
(closed-loop references) recorded from it. The label (:meth:`Case.label`) is what the scorer
knows and the analyzer never sees: it is written under ``labels/``, apart from ``runs/``.

Concealment kinds (issue 9):
- ``compensation``: the closed loop hides the effect in tracking; it shows only in the duty or
  torque the controller needed;
- ``regime``: the effect acts only at high speed, only while accelerating/slipping, only at small
  duty or only in turns;
- ``hidden_channel``: below the noise in the robot's own channels, visible only in the camera
  (or the other way round);
- ``confounded``: two effects with overlapping signatures.
"""
from __future__ import annotations

from dataclasses import dataclass, field

R = 0.0365  # nominal wheel radius, only to write the thesis's wheel accelerations as m/s^2

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

NEUTRAL = {"friction_coefficient": {"mu_s": 0.241, "mu_k": 0.239},
           "wheel_radius": {"r_eff": 0.0365}, "track_width": {"b_eff": 0.105},
           "motor_back_emf": {"ke_ratio": 1.0}, "driver_voltage_drop": {"volts": 0.0},
           "actuation_delay": {"delay_s": 0.0}, "motor_lag": {"tau_s": 0.0},
           "axle_viscous": {"c": 0.0}, "axle_coulomb": {"torque": 0.0},
           "caster_drag": {"mu": 0.0}, "load_transfer": {"h": 0.0},
           "stribeck": {"mu_k0": 0.239, "v_s": 0.01}, "deadband": {"volts": 0.0},
           "motor_gain_asymmetry": {"ratio": 1.0}, "floor_slope": {"rad": 0.0}}
#: the parameter scored for each effect
MAIN_PARAM = {"friction_coefficient": "mu_s", "wheel_radius": "r_eff", "track_width": "b_eff",
              "motor_back_emf": "ke_ratio", "driver_voltage_drop": "volts",
              "actuation_delay": "delay_s", "motor_lag": "tau_s", "axle_viscous": "c",
              "axle_coulomb": "torque", "caster_drag": "mu", "load_transfer": "h",
              "stribeck": "mu_k0", "deadband": "volts", "motor_gain_asymmetry": "ratio",
              "floor_slope": "rad"}
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
                "note": self.note,
                "experiments": [{"reference": r, "clamp": c, "duration_s": d}
                                for r, c, d in self.experiments]}


# effect -> (strong params, weak params, experiments, concealment, note)
_SINGLE = {
    "friction_coefficient": ({"mu_s": 0.17, "mu_k": 0.16}, {"mu_s": 0.205, "mu_k": 0.2}, SLIP,
                             ["regime"], "acts only when a wheel slips (hard acceleration); the "
                             "clamp uses the nominal mu, so it does not prevent the slip"),
    "wheel_radius": ({"r_eff": 0.0385}, {"r_eff": 0.0376}, STD, ["hidden_channel"],
                     "encoders and odometry agree with the controller; only the camera sees "
                     "the distance differ"),
    "track_width": ({"b_eff": 0.116}, {"b_eff": 0.110}, EIGHT, ["hidden_channel", "regime"],
                    "only in turns, and only the camera heading sees it"),
    "motor_back_emf": ({"ke_ratio": 1.15}, {"ke_ratio": 1.06}, STD, ["compensation", "confounded"],
                       "the velocity loop compensates; shows in the duty, grows with speed; "
                       "overlaps axle_viscous"),
    "driver_voltage_drop": ({"volts": 1.2}, {"volts": 0.5}, STD, ["compensation"],
                            "compensated by the loop; duty higher than needed"),
    "actuation_delay": ({"delay_s": 0.03}, {"delay_s": 0.012}, STD, ["regime", "confounded"],
                        "only during speed changes; overlaps motor_lag"),
    "motor_lag": ({"tau_s": 0.05}, {"tau_s": 0.02}, STD, ["regime", "confounded"],
                  "only during speed changes; overlaps actuation_delay"),
    "axle_viscous": ({"c": 0.0025}, {"c": 0.001}, STD, ["compensation", "confounded"],
                     "compensated; overlaps motor_back_emf"),
    "axle_coulomb": ({"torque": 0.03}, {"torque": 0.012}, SLOW, ["compensation", "regime"],
                     "compensated; matters most at small duty"),
    "caster_drag": ({"mu": 0.1}, {"mu": 0.05}, EIGHT, ["compensation"],
                    "compensated; a drag force at the caster"),
    "load_transfer": ({"h": 0.06}, {"h": 0.035}, SLIP, ["regime"],
                      "changes the wheel loads only while accelerating; visible only when "
                      "slipping"),
    "stribeck": ({"mu_k0": 0.12, "v_s": 0.2}, {"mu_k0": 0.18, "v_s": 0.1}, SLIP, ["regime"],
                 "kinetic friction at small slip speed differs; only while slipping"),
    "deadband": ({"volts": 0.8}, {"volts": 0.4}, SLOW, ["compensation", "regime"],
                 "only at small duty; the integrators hide it in tracking"),
    "motor_gain_asymmetry": ({"ratio": 1.15}, {"ratio": 1.05}, STD, ["compensation"],
                             "the yaw loop hides it; the duties differ between the wheels"),
    "floor_slope": ({"rad": 0.04}, {"rad": 0.015}, STD, ["compensation", "confounded"],
                    "compensated by the integrators; overlaps a torque shortfall"),
}


def all_cases() -> list[Case]:
    cases: list[Case] = []
    # nulls: the nominal physics in four experiment sets (one with slip, clamp off)
    for name, exps in (("null_std", STD), ("null_slip", SLIP), ("null_slow", SLOW),
                       ("null_eight", EIGHT)):
        cases.append(Case(name, {}, exps, "no_mismatch", [], "no effect: the truth simulator's "
                          "nominal physics", fast=(name == "null_std")))
    for eff, (strong, weak, exps, conc, note) in _SINGLE.items():
        cases.append(Case(f"{eff}_strong", {eff: strong}, exps, "explained", conc, note,
                          fast=(eff == "motor_back_emf")))
        cases.append(Case(f"{eff}_weak", {eff: weak}, exps, "explained", conc, note))
    # pairs and confounds
    cases.append(Case("pair_emf_viscous", {"motor_back_emf": {"ke_ratio": 1.08},
                                           "axle_viscous": {"c": 0.0012}}, STD, "explained",
                      ["confounded", "compensation"], "both lower the torque in proportion to speed"))
    cases.append(Case("pair_delay_lag", {"actuation_delay": {"delay_s": 0.02},
                                         "motor_lag": {"tau_s": 0.03}}, STD, "explained",
                      ["confounded", "regime"], "both retard the torque"))
    cases.append(Case("pair_radius_friction", {"wheel_radius": {"r_eff": 0.0378},
                                               "friction_coefficient": {"mu_s": 0.19, "mu_k": 0.18}},
                      SLIP, "explained", ["confounded", "hidden_channel"],
                      "both make the camera distance differ from the encoders'"))
    cases.append(Case("pair_asym_slope", {"motor_gain_asymmetry": {"ratio": 1.1},
                                          "floor_slope": {"rad": 0.03}}, STD, "explained",
                      ["confounded", "compensation"], "both need extra duty"))
    cases.append(Case("emf_fast_run_only", {"motor_back_emf": {"ke_ratio": 1.12}}, FAST_ONE,
                      "explained", ["regime", "compensation"],
                      "two slow runs show little; the effect lives in the one fast run"))
    # outside the vocabulary
    cases.append(Case("oov_eccentric_strong", {"eccentric_wheel": {"eps": 0.05}}, STD,
                      "unexplained", ["regime"], "rolling radius varies with the wheel angle",
                      fast=True))
    cases.append(Case("oov_eccentric_weak", {"eccentric_wheel": {"eps": 0.025}}, STD,
                      "unexplained", ["regime"], "rolling radius varies with the wheel angle"))
    cases.append(Case("oov_battery_sag", {"battery_sag": {"r_int": 1.5, "v_per_as": 0.8}}, STD,
                      "unexplained", ["compensation"], "supply falls with current and charge"))
    cases.append(Case("oov_battery_sag_weak", {"battery_sag": {"r_int": 1.0, "v_per_as": 0.5}},
                      STD, "unexplained", ["compensation"], "supply falls with current and charge"))
    cases.append(Case("oov_friction_patch", {"friction_patch": {"x0": 0.3, "x1": 0.9,
                                                                "factor": 0.5}},
                      SLIP, "unexplained", ["regime"], "a slippery patch of floor"))
    for i, c in enumerate(cases):
        c.seed = 1000 + 17 * i
    return cases


def get(names: list[str] | None = None, fast: bool = False) -> list[Case]:
    cases = all_cases()
    if fast:
        cases = [c for c in cases if c.fast]
    if names:
        known = {c.name: c for c in all_cases()}
        bad = [n for n in names if n not in known]
        if bad:
            raise ValueError(f"unknown case(s) {bad}; known: {sorted(known)}")
        cases = [known[n] for n in names]
    return cases


def demo_case() -> Case:
    """The built-in concealed-effect case of ``python -m host_tools demo``."""
    return next(c for c in all_cases() if c.name == "motor_back_emf_weak")
