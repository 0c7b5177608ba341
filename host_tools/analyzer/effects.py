"""What the analyzer needs to know about each vocabulary effect in order to *fit* it:
the neutral value (effect off) for a run's nominal parameters, search bounds, the
nominal model's own tolerance of that neutral value (params.json ``tol``: a fitted deviation
within it is not evidence of the effect), and which measurement separates confusable effects.

The physics of the effects is not here: it lives in lib/slipmodel and is reached
through host_tools._native.  Effects the plant knows but this table does not get
generic bounds around their default (see :func:`spec_for`)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from host_tools import params as _params


@dataclass(frozen=True)
class ParamSpec:
    name: str
    neutral: Callable[[Mapping[str, Any]], float]  # meta -> neutral value
    lo: Callable[[Mapping[str, Any]], float]
    hi: Callable[[Mapping[str, Any]], float]
    # the tolerance of the neutral value: where the neutral value is a nominal robot parameter,
    # its params.json ``tol`` (the parameters the replay's tolerance ensemble draws, group
    # ``robot``); 0 where params.json gives none (effect off = 0 or 1: the size is then judged by
    # the fit's own uncertainty and the output change alone); None for a shape parameter, whose
    # size and stability are judged through its partner
    tol: Callable[[Mapping[str, Any]], float] | None
    unit: str = ""
    # A fitted coordinate that is not itself a vocabulary parameter: (vocabulary parameter it
    # sets, function of the effect's fitted coordinates).  Used to fit inside the physically
    # possible region, e.g. mu_k as a fraction of mu_s so that mu_k <= mu_s always.
    sets: tuple[str, Callable[[Mapping[str, float]], float]] | None = None
    # A coordinate whose identification is judged with another quantity held at its fitted
    # value: (held vocabulary parameter, coordinate that keeps it, its value as a function of
    # this coordinate's value and the held one, this coordinate's possible range given the held
    # one).  mu_s with mu_k held: wheels that slip all run pin mu_k and say nothing about mu_s,
    # while in the (mu_s, mu_k/mu_s) coordinates both move mu_k and look identified.
    given: tuple[str, str, Callable[[float, float], float],
                 Callable[[float, Mapping[str, Any]], tuple[float, float]]] | None = None
    # The ranges (lower, upper offset from the neutral value; lower <= 0 <= upper), one per
    # independent part, by which the normal forces' physics that the nominal model carries only
    # at a guess moves this parameter's fitted value (replay/tolerance.py,
    # ``left_out_normal_forces``: where the wheels' mass sits, the centre of mass's height, the
    # share of the wheels' spin-up); the replay's tolerance ensemble draws each uniformly, and a
    # fitted deviation within them is not evidence of the effect.  None: no such physics.
    left_out: Callable[[Mapping[str, Any]], tuple[tuple[float, float], ...]] | None = None
    # The vocabulary parameter this coordinate ``sets`` is itself a nominal robot parameter that
    # the size test judges (mu_k, set by mu_k/mu_s with mu_s): (its neutral value, its
    # tolerance, its left-out ranges as ``left_out``), all functions of meta.
    sets_judged: tuple[Callable[[Mapping[str, Any]], float], Callable[[Mapping[str, Any]], float],
                       Callable[[Mapping[str, Any]], tuple[tuple[float, float], ...]]] | None = None
    # Fitted in the logarithm of its value (``fit.params.Param``): a positive scale that the
    # plant uses only as a ratio (Stribeck's v_s: mu depends on |s| / v_s alone) and whose search
    # range spans decades.  A step of the coordinate is then one relative change of the scale
    # wherever it lies, as the physics sees it; on a linear map of [0.001, 1] m/s the grid start's
    # levels jump from 0.001 to 0.17 m/s and a finite-difference step (1 % of the range,
    # 0.01 m/s) is a fifth of a v_s of 0.05 m/s.
    log: bool = False


@dataclass(frozen=True)
class EffectSpec:
    name: str
    params: tuple[ParamSpec, ...]
    signature: str  # what it does to the recordings, for the human report

    @property
    def main(self) -> str:
        return self.params[0].name


def _c(v: float) -> Callable[[Mapping[str, Any]], float]:
    return lambda meta: v


def _robot(key: str, scale: float = 1.0) -> Callable[[Mapping[str, Any]], float]:
    return lambda meta: scale * float(meta["robot"][key])


def _motor(key: str, scale: float = 1.0) -> Callable[[Mapping[str, Any]], float]:
    return lambda meta: scale * float(meta["motor"][key])


def _tol(key: str) -> Callable[[Mapping[str, Any]], float]:
    """params.json's tolerance of the robot parameter ``key``."""
    return lambda meta: float(_params.TOLERANCES[("robot", key)])


def _ratio_tol(meta: Mapping[str, Any]) -> float:
    """Tolerance of mu_k / mu_s from those of mu_k and mu_s (first-order propagation)."""
    mu_s, mu_k = float(meta["robot"]["mu_s"]), float(meta["robot"]["mu_k"])
    return (mu_k / mu_s) * math.hypot(_tol("mu_k")(meta) / mu_k, _tol("mu_s")(meta) / mu_s)


_NO_TOL = _c(0.0)


def _friction_left_out(key: str
                       ) -> Callable[[Mapping[str, Any]], tuple[tuple[float, float], ...]]:
    """The normal forces' physics that the nominal model carries at a guess, as a friction
    coefficient: wheels that carry more (less) than the nominal model gives at their slip onset
    reach ``mu N`` where the nominal model needs a larger (smaller) ``mu``; the nominal model
    lies inside each part's range, so either way (``LeftOut.mu_ranges``, one range per
    part)."""
    def f(meta: Mapping[str, Any]) -> tuple[tuple[float, float], ...]:
        from host_tools.analyzer.replay.tolerance import left_out_normal_forces
        mu = float(meta["robot"][key])
        return tuple((mu * lo, mu * hi)
                     for lo, hi in left_out_normal_forces(meta["robot"], mu).mu_ranges)
    return f


def _height_left_out(meta: Mapping[str, Any]) -> tuple[tuple[float, float], ...]:
    """The normal forces' physics that the nominal model carries at a guess, as the
    ``load_transfer`` effect's centre-of-mass ``h`` (about its neutral value, Table II.2's
    ``h``): a centre of mass between the ground and ``h`` plus its tolerance, and a share k of
    the spin-up other than the nominal k^, which rolls like a height ``(k - k^) h_s``
    (``LeftOut``)."""
    from host_tools.analyzer.replay.normal_forces import spin_range
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    lo = left_out_normal_forces(meta["robot"])
    k_lo, k_hi = spin_range()
    return ((-lo.com_h_m, lo.h_max_m - lo.com_h_m),
            ((k_lo - lo.spin_share) * lo.spin_h_m, (k_hi - lo.spin_share) * lo.spin_h_m))


def left_out_ranges(effect: str, name: str, meta: Mapping[str, Any],
                    fitted: Mapping[str, Mapping[str, float]] | None = None
                    ) -> tuple[tuple[float, float], ...]:
    """:attr:`ParamSpec.left_out` of ``effect``'s parameter ``name`` (none: ``()``).  Where
    the fit's effects ``fitted`` carry the load transfer's spin share k as a kept nuisance
    (``fit.params.spin_param``), h's range from k's tolerance is no longer left out: the fit has
    k, and its sigma of h holds what k leaves open (their correlation)."""
    from host_tools.analyzer.replay.normal_forces import SPIN_KEY
    spec = SPECS.get(effect)
    for ps in spec.params if spec is not None else ():
        if ps.name == name and ps.left_out is not None:
            ranges = ps.left_out(meta)
            if (effect == "load_transfer" and name == "h"
                    and SPIN_KEY in (fitted or {}).get(effect, {})):
                return ranges[:1]   # _height_left_out: (centre of mass, spin share)
            return ranges
    return ()


@dataclass(frozen=True)
class Judged:
    """A vocabulary parameter that a fitted coordinate sets (``ParamSpec.sets_judged``), as the
    size test judges it: its fitted value, deviation from its neutral value, 1-sigma, tolerance
    and left-out ranges, and its value in each held-out fold."""
    effect: str
    name: str
    value: float
    dev: float
    std: float
    tol: float
    left_out: tuple[tuple[float, float], ...]
    folds: tuple[float, ...]


def judged_sets(params: Sequence[Any], values: Sequence[float], std: Sequence[float],
                fold_values: Sequence[Sequence[float]], meta: Mapping[str, Any]) -> list[Judged]:
    """The set vocabulary parameters of the fitted coordinates ``params`` (fit.params.Param) at
    ``values`` with 1-sigma ``std`` (one per coordinate) and the held-out folds' values.  The
    sigma is the setting coordinate's times the set parameter's change with it, the effect's
    other coordinates held: the fit's solve holds a profiled coordinate (mu_s) while it fits
    the others (mu_k/mu_s), so that is mu_k's own uncertainty at the fitted mu_s."""
    out: list[Judged] = []
    for j, p in enumerate(params):
        spec = next((ps for ps in SPECS[p.effect].params if ps.name == p.name), None) \
            if p.effect in SPECS else None
        if spec is None or spec.sets is None or spec.sets_judged is None:
            continue
        if j >= len(std) or not math.isfinite(std[j]):
            continue   # pinned (unidentified) or not seen by the data: the set value is no estimate
        # the effect's vocabulary coordinates (a nuisance, e.g. the friction's creep, sets none)
        idx = [i for i, q in enumerate(params) if q.effect == p.effect and q.nuisance is None]
        name, fn = spec.sets

        def at(vals: Sequence[float], dx: float = 0.0) -> float:
            d = {params[i].name: float(vals[i]) + (dx if i == j else 0.0) for i in idx}
            return float(fn(d))
        v = at(values)
        h = 1e-6 * max(abs(float(values[j])), 1e-6)
        slope = (at(values, h) - v) / h
        sd = abs(slope) * float(std[j])
        neutral, tol, left = spec.sets_judged
        out.append(Judged(p.effect, name, v, v - float(neutral(meta)), sd,
                          float(tol(meta)), tuple(left(meta)),
                          tuple(at(fv) for fv in fold_values if len(fv) == len(values))))
    return out


P = ParamSpec
SPECS: dict[str, EffectSpec] = {s.name: s for s in [
    # mu_k is fitted as a fraction of mu_s in [0.5, 1]: kinetic friction never exceeds static
    EffectSpec("friction_coefficient", (
        P("mu_s", _robot("mu_s"), _c(0.03), _c(1.2), _tol("mu_s"),
          given=("mu_k", "mu_k_over_mu_s", lambda mu_s, mu_k: mu_k / mu_s,
                 lambda mu_k, meta: (mu_k, min(mu_k / 0.5, 1.2))),
          left_out=_friction_left_out("mu_s")),
        P("mu_k_over_mu_s", lambda m: float(m["robot"]["mu_k"]) / float(m["robot"]["mu_s"]),
          _c(0.5), _c(1.0), _ratio_tol,
          sets=("mu_k", lambda d: d["mu_k_over_mu_s"] * d["mu_s"]),
          sets_judged=(_robot("mu_k"), _tol("mu_k"), _friction_left_out("mu_k")))),
        "wheels spin up (slip) at a different torque; distance lost in slip changes"),
    EffectSpec("wheel_radius", (
        P("r_eff", _robot("r"), _robot("r", 0.7), _robot("r", 1.3), _tol("r"), "m"),),
        "ground-truth distance scales against encoder distance"),
    EffectSpec("track_width", (
        P("b_eff", _robot("b"), _robot("b", 0.7), _robot("b", 1.4), _tol("b"), "m"),),
        "ground-truth heading change scales against the encoder difference"),
    EffectSpec("motor_back_emf", (
        P("ke_ratio", _c(1.0), _c(0.5), _c(2.0), _NO_TOL),),
        "torque shortfall growing with wheel speed"),
    EffectSpec("driver_voltage_drop", (
        P("volts", _c(0.0), _c(0.0), _motor("supply_v", 0.4), _NO_TOL, "V"),),
        "constant fraction of drive voltage missing"),
    EffectSpec("actuation_delay", (
        P("delay_s", _c(0.0), _c(0.0), _c(0.1), _NO_TOL, "s"),),
        "response shifted later in time"),
    EffectSpec("motor_lag", (
        P("tau_s", _c(0.0), _c(0.0), _c(0.2), _NO_TOL, "s"),),
        "torque rises slowly after a step of the command"),
    EffectSpec("axle_viscous", (
        # at most half the motor's own speed-torque slope stall_nm / no_load_rad_s
        P("c", _c(0.0), _c(0.0),
          lambda meta: 0.5 / float(meta["motor"]["no_load_rad_s"]) * float(meta["motor"]["stall_nm"]),
          _NO_TOL, "N m s/rad"),),
        "drag torque proportional to wheel speed"),
    EffectSpec("axle_coulomb", (
        P("torque", _c(0.0), _c(0.0), _motor("stall_nm", 0.3), _NO_TOL, "N m"),),
        "constant drag torque while the wheel turns"),
    EffectSpec("caster_drag", (
        P("mu", _c(0.0), _c(0.0), _c(0.5), _NO_TOL),),
        "constant drag force on the body while it moves"),
    # h: the centre-of-mass height, Table II.2's in the nominal model (replay/normal_forces.py,
    # which adds the spin-up's rolling height k^ h_s to it); its tolerance is in the left-out range
    EffectSpec("load_transfer", (
        P("h", _robot("h"), _c(0.0), _c(0.25), _NO_TOL, "m", left_out=_height_left_out),),
        "normal forces shift during acceleration; slip threshold moves"),
    EffectSpec("stribeck", (
        # friction at zero slip speed is capped at mu_s by the plant: above it is unidentifiable
        P("mu_k0", _robot("mu_k"), _c(0.03), _robot("mu_s"), _tol("mu_k"),
          left_out=_friction_left_out("mu_k")),
        P("v_s", _c(0.01), _c(0.001), _c(1.0), None, log=True)),
        "kinetic friction depends on slip speed"),
    EffectSpec("deadband", (
        P("volts", _c(0.0), _c(0.0), _motor("supply_v", 0.3), _NO_TOL, "V"),),
        "small duties give no torque"),
    EffectSpec("motor_gain_asymmetry", (
        P("ratio", _c(1.0), _c(0.6), _c(1.6), _NO_TOL),),
        "one wheel stronger than the other: the robot curves"),
    EffectSpec("floor_slope", (
        P("rad", _c(0.0), _c(-0.2), _c(0.2), _NO_TOL, "rad"),),
        "constant along-track gravity force"),
    # up to the platform's own mass again; extra mass within the tolerance of the platform's own
    # mass m_r is not told apart from it
    EffectSpec("payload", (
        P("mass_kg", _c(0.0), _c(0.0), _robot("m_r"), _tol("m_r"), "kg"),),
        "extra mass on the chassis: slower accelerations, more normal force and tau_max"),
]}

# The measurement that tells two confusable effects apart.
SEPARATORS: dict[frozenset[str], str] = {
    frozenset({"motor_back_emf", "axle_viscous"}):
        "hold the wheels at one speed with two different supply voltages (or log motor current): "
        "back-EMF scales with the voltage, axle friction does not",
    frozenset({"motor_back_emf", "driver_voltage_drop"}):
        "a run at low speed and high duty (stall-like): a voltage drop costs torque at zero "
        "speed, back-EMF does not",
    frozenset({"driver_voltage_drop", "deadband"}):
        "a slow duty ramp from zero: a deadband gives no motion below its threshold, a drop "
        "scales all duties",
    frozenset({"driver_voltage_drop", "axle_coulomb"}):
        "a run at two duty levels: a voltage drop scales with duty, Coulomb friction is constant",
    frozenset({"axle_viscous", "axle_coulomb"}):
        "coast-down from two speeds: viscous drag falls with speed, Coulomb drag does not",
    frozenset({"axle_coulomb", "caster_drag"}):
        "a spin in place: axle friction acts on the wheels, caster drag on the body",
    frozenset({"axle_coulomb", "floor_slope"}):
        "the same run driven in the opposite direction: a slope helps one way, friction never",
    frozenset({"caster_drag", "floor_slope"}):
        "the same run driven in the opposite direction: a slope helps one way, drag never",
    frozenset({"actuation_delay", "motor_lag"}):
        "a sharp torque step logged at a high rate: a delay shifts it, a lag rounds it",
    frozenset({"wheel_radius", "friction_coefficient"}):
        "ground truth during a gentle (no-slip) run: radius scales distance, slip does not",
    frozenset({"friction_coefficient", "stribeck"}):
        "steps to several torques above tau_max: Stribeck friction changes with slip speed",
    frozenset({"friction_coefficient", "load_transfer"}):
        "slip onset at several accelerations: load transfer moves tau_max with acceleration",
    frozenset({"track_width", "motor_gain_asymmetry"}):
        "a straight run: gain asymmetry curves it, a track-width error does not",
}


# Effects that are plain values of the nominal robot's parameters: effect -> {effect parameter:
# meta.json robot key}.  The plant applies them as such; the analyzer folds them into the robot
# parameters (model.json) and uses them wherever it needs the candidate's geometry outside the
# plant (the count-anchored camera channels).
PARAMETER_EFFECTS: dict[str, dict[str, str]] = {
    "friction_coefficient": {"mu_s": "mu_s", "mu_k": "mu_k"},
    "wheel_radius": {"r_eff": "r"},
    "track_width": {"b_eff": "b"},
}


# Effects that lib/slipmodel's plant does not have because they are changes of the nominal
# plant's parameters: effect -> {effect parameter: (meta.json robot key it adds to, neutral)}.
# payload: extra mass at the platform's centre of mass c (m_r + mass_kg, I_rz unchanged), the
# convention of the truth and MuJoCo engines; the plant derives inertia, normal forces and
# tau_max from m_r.
ADDED_PARAMETER_EFFECTS: dict[str, dict[str, tuple[str, float]]] = {
    "payload": {"mass_kg": ("m_r", 0.0)},
}


def parameter_effect_vocabulary() -> dict[str, dict[str, float]]:
    """{effect: {parameter: neutral}} of :data:`ADDED_PARAMETER_EFFECTS` (the analyzer's
    vocabulary beyond the plant's own effects)."""
    return {n: {p: v[1] for p, v in ps.items()} for n, ps in ADDED_PARAMETER_EFFECTS.items()}


def folded_robot(robot: Mapping[str, float],
                 effects: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """The robot parameters ``robot`` with the parameter effects of ``effects`` folded in (the
    plain values replace, the added ones add)."""
    out = dict(robot)
    for name, params in effects.items():
        for p, key in PARAMETER_EFFECTS.get(name, {}).items():
            if p in params:
                out[key] = float(params[p])
        for p, (key, _) in ADDED_PARAMETER_EFFECTS.get(name, {}).items():
            if p in params:
                out[key] = float(robot[key]) + float(params[p])
    return out


#: The friction fit's nuisance key (``fit.params.creep_param``): the slip speed over which a
#: sliding wheel's coefficient falls from mu_s to mu_k.  The plant carries it as its Stribeck law
#: tied to mu_s (:func:`creep_form`); the nominal model's Coulomb switch is its limit v -> 0.
CREEP_KEY = "v_creep"


def creep_form(effects: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """``effects`` with a ``friction_coefficient`` that carries the creep speed
    (:data:`CREEP_KEY`) in the plant's own form: the friction's two coefficients and the
    plant's ``stribeck`` law tied to its mu_s, mu(|s|) = mu_k + (mu_s - mu_k) exp(-(|s|/v)^2)
    (lib/slipmodel's Stribeck law with mu_k0 = mu_s): a wheel that breaks away at mu_s N keeps
    about mu_s while it creeps at slip speeds well under v and slides at mu_k well above it.
    Other effects as given; an effect set without the key unchanged."""
    fc = effects.get("friction_coefficient", {})
    if CREEP_KEY not in fc:
        return {e: dict(p) for e, p in effects.items()}
    out = {e: dict(p) for e, p in effects.items()}
    fric = {k: float(v) for k, v in fc.items() if k != CREEP_KEY}
    out["friction_coefficient"] = fric
    out["stribeck"] = {"mu_k0": float(fric["mu_s"]), "v_s": float(fc[CREEP_KEY])}
    return out


def plant_setup(robot: Mapping[str, float], effects: Mapping[str, Mapping[str, float]]
                ) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """(robot parameters, plant effects) of ``effects`` on the robot ``robot``: the effects the
    plant does not have (:data:`ADDED_PARAMETER_EFFECTS`) as changed parameters, the others as
    its effects, a friction's creep speed as the plant's Stribeck law tied to its mu_s
    (:func:`creep_form`).  The nominal model's normal-force physics comes on top
    (``replay.normal_forces.plant_config``, which every replay's plant is built with)."""
    added = {n: p for n, p in effects.items() if n in ADDED_PARAMETER_EFFECTS}
    rest = {n: dict(p) for n, p in creep_form(effects).items()
            if n not in ADDED_PARAMETER_EFFECTS}
    r = dict(robot)
    for name, params in added.items():
        for p, (key, _) in ADDED_PARAMETER_EFFECTS[name].items():
            if p in params:
                r[key] = float(robot[key]) + float(params[p])
    return r, rest


def vocabulary_params(effect: str, fitted: Mapping[str, float]) -> dict[str, float]:
    """The vocabulary parameters of ``effect`` from its fitted coordinates."""
    spec = SPECS.get(effect)
    if spec is None:
        return dict(fitted)
    out = {}
    for ps in spec.params:
        if ps.name not in fitted:
            continue
        if ps.sets is None:
            out[ps.name] = float(fitted[ps.name])
        else:
            out[ps.sets[0]] = float(ps.sets[1](fitted))
    return out


#: The physical range of each vocabulary parameter, the one place that says it (the analyzer's
#: judge refuses a candidate outside it; the suite's scorer counts a reported fit outside it as
#: impossible): ">0" positive, ">=0" non-negative, "|x|<pi/2" an angle below 90 degrees.
PHYSICAL_RANGE: dict[str, dict[str, str]] = {
    "friction_coefficient": {"mu_s": ">0", "mu_k": ">0"},
    "wheel_radius": {"r_eff": ">0"}, "track_width": {"b_eff": ">0"},
    "motor_back_emf": {"ke_ratio": ">0"}, "driver_voltage_drop": {"volts": ">=0"},
    "actuation_delay": {"delay_s": ">=0"}, "motor_lag": {"tau_s": ">=0"},
    "axle_viscous": {"c": ">=0"}, "axle_coulomb": {"torque": ">=0"},
    "caster_drag": {"mu": ">=0"}, "load_transfer": {"h": ">=0"},
    "stribeck": {"mu_k0": ">=0", "v_s": ">0"}, "deadband": {"volts": ">=0"},
    "motor_gain_asymmetry": {"ratio": ">0"}, "floor_slope": {"rad": "|x|<pi/2"},
    "payload": {"mass_kg": ">=0"},
}
#: (effect, lower, upper): within one effect's parameters, ``lower`` never exceeds ``upper``
#: (kinetic friction never exceeds static friction)
PHYSICAL_ORDER: tuple[tuple[str, str, str], ...] = (
    ("friction_coefficient", "mu_k", "mu_s"), ("stribeck", "mu_k0", "mu_s"))


def physically_possible(effect: str, params: Mapping[str, Any]) -> list[str]:
    """Why a fitted parameter set of ``effect`` is physically impossible (empty list:
    possible): a value that is not a finite number, one outside :data:`PHYSICAL_RANGE`, an
    order of :data:`PHYSICAL_ORDER` broken, a mass or inertia (``m_*``, ``I_*``) not positive."""
    why = []
    ranges = PHYSICAL_RANGE.get(effect, {})
    for k, v in params.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            why.append(f"{k} = {v!r} is not a finite number")
            continue
        kind = ranges.get(k, ">0" if k.startswith(("m_", "I_")) else "")
        if kind == ">0" and v <= 0:
            why.append(f"{k} = {v:.4g} <= 0")
        elif kind == ">=0" and v < 0:
            why.append(f"{k} = {v:.4g} < 0")
        elif kind == "|x|<pi/2" and abs(v) >= math.pi / 2:
            why.append(f"{k} = {v:.4g}: |{k}| >= pi/2")
    for eff, lower, upper in PHYSICAL_ORDER:
        lo, hi = params.get(lower), params.get(upper)
        if eff == effect and isinstance(lo, (int, float)) and isinstance(hi, (int, float)) \
                and lo > hi + 1e-12:
            why.append(f"{lower} {lo:.4g} > {upper} {hi:.4g}")
    return why


def separator(a: str, b: str) -> str:
    return SEPARATORS.get(frozenset({a, b}),
                          f"a run that excites {a} and {b} differently, with ground truth")


def spec_for(name: str, defaults: Mapping[str, float]) -> EffectSpec:
    """The fitting spec of ``name``; an effect the table does not know gets bounds of
    0.5x..1.5x around a non-zero default (or 0..1 around zero) and no tolerance (params.json
    gives none for an effect it does not know)."""
    if name in SPECS:
        return SPECS[name]
    params = []
    for p, d in defaults.items():
        d = float(d)
        if d != 0:
            lo, hi = sorted((0.5 * d, 1.5 * d))
            params.append(P(p, _c(d), _c(lo), _c(hi), _NO_TOL))
        else:
            params.append(P(p, _c(0.0), _c(0.0), _c(1.0), _NO_TOL))
    return EffectSpec(name, tuple(params), "effect unknown to the analyzer's table")
