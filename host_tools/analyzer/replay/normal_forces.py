"""The nominal robot's normal forces: the one definition of the physics of the wheel and caster
loads that every plant the analyzer builds for the nominal model and its candidates carries
(the open-loop duty and torque replays, the closed-loop replay, the fits' replays, the
tolerance ensemble's draws, the synthetic runs of :mod:`host_tools.analyzer.synth`).

lib/slipmodel's II.27-II.29 put the whole mass m_t at the centre of mass c and have no
longitudinal load transfer; a real robot (and any 3-D engine) has its wheels' mass on the
axle, its centre of mass above the ground and the reaction of its wheels' spin-up.  The nominal
model carries each at its table value:

* **the wheels' mass on the axle** (:func:`wheels_on_axle`, share 1): params.json gives ``m_r``
  as the "platform mass (without the two driven wheels)", and ``d``, ``I_rz`` as the
  platform's; the wheels sit on the axle.  The robot's centre of mass is ``d_c = m_r d / m_t``
  ahead of o, the caster where it was (``d_c + e_c = d + e``), so at rest the caster carries
  ``m_r g d / (d + e)`` instead of II.29's ``m_t g d / (d + e)``.  A ``payload`` is extra mass
  at the platform's c (``m_r + mass_kg``), so it enters before the split.
* **the longitudinal transfer of a centre of mass at Table II.2's h** (the plant's
  ``load_transfer`` effect: ``N_c`` falls by ``m_t a h / (d + e)`` while accelerating).
* **the wheels' spin-up** as a rolling height ``k h_s`` added to h, ``h_s = 2 I_wy / (m_t r)``:
  while the wheels roll (theta'' = a / r, where a slip onset is decided) the pitch balance's
  ``k I_wy (theta''_r + theta''_l)`` is exactly ``m_t a k h_s``.  ``k`` is the share of
  ``I_wy`` whose spin reacts on the body, params.json's ``model.spin_share`` (k^ = 0.5 with
  tolerance 0.5: the table's ``I_wy = 2 I_wz`` reads as a thin disc, k = 1, while a 64 g wheel
  of 36.5 mm holds at most 1/14 of that I_wy, the rest likely a geared rotor whose reaction is
  1/G of its share, k near 0; nothing tells which, so the middle of [0, 1], whose largest error
  over the possible range is the smallest).  The plant's own theta'' spin term is off
  (``plant.spin_share`` 0): inside a slip the slipping wheel's theta'' follows the motor's
  whole torque, and a spin term drawn there spreads every slip episode by normal forces that no
  slip onset decides (a 7 % larger wheel in a braking run hid inside that spread,
  ``test_analyzer_e2e``).

A candidate ``load_transfer`` effect's ``h`` is the centre-of-mass height: it replaces the
table's h, and ``k^ h_s`` stays added.  Where the fit carries the spin share k as its nuisance
parameter (the key :data:`SPIN_KEY` beside ``h``, ``fit.params``: kept only where the slips
identify it), the plant carries the spin-up through its own theta'' term at that k instead
(``plant.spin_share`` k, no rolling height): the form the data identify k in, since while the
wheels roll k h_s and h are one parameter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

from host_tools import params as P

#: k^: the share of I_wy whose spin-up reacts on the body, as the nominal model carries it
SPIN_SHARE = float(P.MODEL["spin_share"])
#: its tolerance: the possible k lie within SPIN_SHARE +- SPIN_SHARE_TOL (clipped to [0, 1])
SPIN_SHARE_TOL = float(P.TOLERANCES[("model", "spin_share")])
#: the standard uncertainty of that tolerance (a uniform draw over k^ +- tol): a fit's nuisance k
#: is kept only where its 1-sigma is below it (``fit.params.params_for``)
SPIN_SHARE_SIGMA = SPIN_SHARE_TOL / math.sqrt(3.0)
#: the key of the ``load_transfer`` effect's nuisance spin share k in a fit's effects (not a
#: vocabulary parameter: the reports carry it apart from ``h``)
SPIN_KEY = "spin_share"
#: the share of the wheels' mass on the axle in the nominal model (the table's reading)
WHEELS_ON_AXLE = 1.0


def spin_range() -> tuple[float, float]:
    """The possible spin shares k: k^ +- its tolerance, within [0, 1]."""
    return max(SPIN_SHARE - SPIN_SHARE_TOL, 0.0), min(SPIN_SHARE + SPIN_SHARE_TOL, 1.0)


def spin_height(robot: Mapping[str, float], r: float | None = None) -> float:
    """``h_s = 2 I_wy / (m_t r)``: the wheels' spin-up as a load-transfer height while they roll
    (``r`` the rolling radius, default the robot's)."""
    m_t = float(robot["m_r"]) + 2.0 * float(robot["m_w"])
    rr = float(robot["r"]) if r is None else float(r)
    return 2.0 * float(robot["I_wy"]) / (m_t * rr) if m_t > 0 and rr > 0 else 0.0


def wheels_on_axle(robot: Mapping[str, float], share: float) -> dict[str, float]:
    """The lumped plant's ``d``, ``e`` and ``I_rz`` for a robot whose wheels' mass sits the
    fraction ``share`` (0: at c, the planar II.29; 1: on the axle) on the axle: the robot's
    centre of mass ``d_c = d - share 2 m_w d / m_t`` ahead of o, the caster where it was
    (``d_c + e_c = d + e``), and ``I_rz`` such that the plant's yaw inertia about the new centre
    of mass, ``I_rz + 2 (I_wz + m_w b^2)``, is that of the masses where they now sit."""
    m_r, m_w = float(robot["m_r"]), float(robot["m_w"])
    d, e = float(robot["d"]), float(robot["e"])
    m_t = m_r + 2.0 * m_w
    s = min(max(float(share), 0.0), 1.0)
    d_c = d - s * 2.0 * m_w * d / m_t
    i_rz = (float(robot["I_rz"]) + (m_r + (1.0 - s) * 2.0 * m_w) * (d - d_c) ** 2
            + s * 2.0 * m_w * d_c ** 2)
    return {"d": d_c, "e": e + (d - d_c), "I_rz": i_rz}


@dataclass(frozen=True)
class NormalForces:
    """The normal-force physics of one plant: the share of the wheels' mass on the axle, the
    centre-of-mass height (None: the robot's ``h``) and the share k of the spin-up, carried as
    the rolling height ``k h_s``.  :data:`NOMINAL` is the nominal model's; the tolerance
    ensemble draws others."""
    share: float = WHEELS_ON_AXLE
    com_h_m: float | None = None
    spin_share: float = SPIN_SHARE


NOMINAL = NormalForces()


@dataclass(frozen=True)
class PlantConfig:
    """What a lib/slipmodel plant is built with: robot parameters, effects and model settings
    (``plant.spin_share``)."""
    robot: dict[str, float]
    effects: dict[str, dict[str, float]]
    keys: dict[str, float] = field(default_factory=dict)


def plant_config(robot: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
                 forces: NormalForces = NOMINAL) -> PlantConfig:
    """The plant of the robot ``robot`` (meta.json's parameters) with the analyzer's
    ``effects`` and the normal-force physics ``forces``: the added-parameter effects folded in
    first (a payload is mass at the platform's c), then the wheels' mass moved to the axle, and
    the ``load_transfer`` effect at the centre-of-mass height (a candidate's ``h``, else
    ``forces.com_h_m``, else the robot's ``h``) plus ``forces.spin_share`` h_s, with the
    plant's own spin term off; or, where the effect carries the fit's nuisance spin share
    (:data:`SPIN_KEY`), at the centre-of-mass height alone with the plant's own spin term at
    that share."""
    from host_tools.analyzer.effects import plant_setup
    r, fx = plant_setup(robot, effects)
    lt = dict(fx.pop("load_transfer", {}))
    spin = lt.pop(SPIN_KEY, None)
    if "h" in lt:
        h_com = float(lt["h"])
    elif forces.com_h_m is not None:
        h_com = float(forces.com_h_m)
    else:
        h_com = float(r["h"])
    r_eff = fx.get("wheel_radius", {}).get("r_eff", r["r"])
    h_s = spin_height(r, r_eff)
    r.update(wheels_on_axle(r, forces.share))
    if spin is not None:
        fx["load_transfer"] = {**lt, "h": max(h_com, 0.0)}
        return PlantConfig(r, fx, {"plant.spin_share": min(max(float(spin), 0.0), 1.0)})
    fx["load_transfer"] = {**lt, "h": max(h_com + float(forces.spin_share) * h_s, 0.0)}
    return PlantConfig(r, fx, {"plant.spin_share": 0.0})


def rolling_form(robot: Mapping[str, float], effects: Mapping[str, Mapping[str, float]]
                 ) -> dict[str, dict[str, float]]:
    """``effects`` in the nominal model's form: a ``load_transfer`` that carries the fit's kept
    spin share k (:data:`SPIN_KEY`) becomes the height :func:`plant_config` replays the same
    while the wheels roll, ``h + (k - k^) h_s`` (it adds ``k^ h_s`` to a height), without k.
    For what takes a model in that form (model.json, ``fil.model_plant_keys``); other effects
    as given."""
    from host_tools.analyzer.effects import plant_setup
    lt = effects.get("load_transfer", {})
    if SPIN_KEY not in lt:
        return {e: dict(p) for e, p in effects.items()}
    rest = {e: dict(p) for e, p in effects.items() if e != "load_transfer"}
    r, _ = plant_setup(robot, rest)
    h_s = spin_height(r, rest.get("wheel_radius", {}).get("r_eff", r["r"]))
    h = float(lt["h"]) + (float(lt[SPIN_KEY]) - float(NOMINAL.spin_share)) * h_s
    return {**rest, "load_transfer": {**{k: float(v) for k, v in lt.items() if k != SPIN_KEY},
                                      "h": max(h, 0.0)}}
