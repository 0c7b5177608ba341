"""The replay's uncertainty from the nominal model's own tolerance: the robot's parameters are
known only within params.json's ``tol`` (Table II.2 to its last printed digit, μ to a
spring-scale division), and where the replay is sensitive to them (a slip onset, a saturating
stop or reversal, an arc over seconds) the recording may depart from the nominal replay by that
much without any physics missing.

Beside the parameters, the nominal model's own left-out physics of the normal forces is drawn at
its derived size (:func:`left_out_normal_forces`): where the wheels' mass sits, the
longitudinal load transfer of a centre of mass above the ground, and the reaction of the
wheels' spin-up.  A real robot and any 3-D engine have them; lib/slipmodel's II.27–II.29 leave
them out."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from host_tools import params as P
from host_tools.analyzer.prepare.run import PreparedRun

if TYPE_CHECKING:
    from host_tools.analyzer.replay.openloop import OpenLoopReplay

TOLERANCE_ENSEMBLE = 8     # replays with the robot's parameters drawn within their tolerance

# The robot group (Table II.2 and μ) is drawn.  The motor's datasheet constants are not: their
# ±10 % is the very deviation the vocabulary's motor effects name and fit (back-EMF, gain
# asymmetry, driver voltage drop), so absorbing it into the noise would hide what the analyzer
# is there to find; a motor inside its datasheet tolerance is reported as the effect it is.
TOLERANCE_GROUPS = ("robot",)


@dataclass(frozen=True)
class LeftOut:
    """The nominal model's left-out physics of the normal forces, at its derived size
    (:func:`left_out_normal_forces`); each part is drawn uniformly and independently between
    none of it and all of it.

    ``wheel_shift_m``: how far the robot's centre of mass moves back towards the axle when the
    wheels' mass sits on the axle instead of at c (``2 m_w d / m_t``).  Table II.1 gives ``d``
    only as the "distance from wheel's axis to center of mass" and II.29 puts the total mass
    m_t at c; with the platform's mass m_r at c and each wheel's m_w on the axle, the robot's
    centre of mass is at ``m_r d / m_t`` and the caster, still ``d + e`` ahead of o, carries
    ``m_r g d / (d + e)`` instead of ``m_t g d / (d + e)``: the wheels carry more.  Both
    readings are possible; the draws take one between them.

    ``h_max_m``: the height of the centre of mass whose longitudinal load transfer the nominal
    model leaves out (the plant's ``load_transfer`` effect, ``N_c`` falls by ``m a h / (d +
    e)`` while accelerating): Table II.2's ``h`` (plus its tolerance), which II.28 uses only
    laterally.

    ``spin_h_m``: the reaction of the wheels' spin-up as a load-transfer height.  The motors
    spinning up the wheels pitch the body and unload the caster by ``I_wy (theta''_r +
    theta''_l) / (d + e)`` (moments about the centre of mass: the wheels' spin momentum changes
    at that rate); while the wheels roll ``theta'' = a / r``, which is ``m_t a h_s / (d + e)``
    with ``h_s = 2 I_wy / (m_t r)`` (39 mm at the table's values).  The plant's
    ``load_transfer`` effect carries this term itself (lib/slipmodel/README.md, "Load transfer
    and spin-up"), with the share ``k`` of ``I_wy`` whose spin reacts (``plant.spin_share``;
    the effect's own is 1, the table's wheel: ``I_wy = 2 I_wz`` is a thin disc's).  How much
    of a real robot's ``I_wy`` spins with the wheel is not known: a gear-motor's rotor, which
    the table's ``I_wy`` may count in, reacts with 1/gear of its share, and MuJoCo's wheel body
    carries ``I_wz`` of it (k = 1/2, measured); the draws take k in [0, 1].  As a height of the
    effect at its own k = 1, a robot with its centre of mass at ``H`` and the share ``k``
    rolls like ``h = H - (1 - k) h_s``: between ``-h_s`` and ``h_max_m``.

    ``excess``: relative excess of a wheel's normal force at its slip onset over the nominal
    model's, from each part at its full size: ``2 m_w d / (m_t e)`` from the wheels' mass on the
    axle (the caster's load falls by ``2 m_w g d / (d + e)``, shared by the two wheels against
    their ``m_t g e / (2 (d + e))``), ``mu h / (d + e)`` from the transfer at the acceleration
    where both wheels reach ``mu N`` (``a = 2 mu N / m_t``, so ``m_t a h / (2 (d + e) N) = mu h
    / (d + e)``) and ``mu h_s / (d + e)`` from the spin-up.  The traction limit is ``mu N``, so
    a recording with these normal forces replays as one whose friction coefficient is up to
    ``(1 + mu_excess)`` times the nominal one (``mu_excess`` their sum); never less."""
    wheel_shift_m: float
    h_max_m: float
    spin_h_m: float
    excess: tuple[float, float, float]

    @property
    def mu_excess(self) -> float:
        return float(sum(self.excess))


def left_out_normal_forces(robot: Mapping[str, float], mu: float | None = None) -> LeftOut:
    """The derived size of the left-out normal-force physics (:class:`LeftOut`) for the robot
    parameters ``robot`` (meta.json's); ``mu`` the friction coefficient of ``excess``
    (default the robot's μs)."""
    m_r, m_w = float(robot["m_r"]), float(robot["m_w"])
    d, e = float(robot["d"]), float(robot["e"])
    h = max(float(robot["h"]) + P.TOLERANCES.get(("robot", "h"), 0.0), 0.0)
    m_t = m_r + 2.0 * m_w
    r = float(robot["r"])
    mu_v = float(robot["mu_s"]) if mu is None else float(mu)
    spin = 2.0 * float(robot["I_wy"]) / (m_t * r) if m_t > 0 and r > 0 else 0.0
    if not (m_t > 0 and d + e > 0 and e > 0):
        return LeftOut(0.0, h, spin, (0.0, 0.0, 0.0))
    return LeftOut(2.0 * m_w * max(d, 0.0) / m_t, h, spin,
                   (2.0 * m_w * max(d, 0.0) / (m_t * e), mu_v * h / (d + e),
                    mu_v * spin / (d + e)))


def wheels_on_axle(robot: Mapping[str, float], share: float) -> dict[str, float]:
    """The lumped plant's ``d``, ``e`` and ``I_rz`` for a robot whose wheels' mass sits the
    fraction ``share`` (0: at c, the nominal II.29; 1: on the axle) on the axle: the robot's
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


def tolerance_draws(robot: Mapping[str, float], n: int, rng: np.random.Generator
                    ) -> list[dict[str, float]]:
    """``n`` parameter sets, each value uniform within value ± tol (params.json) around the
    run's own value; μk is kept at or below μs, as the plant requires."""
    toler = [(name, tol) for (group, name), tol in P.TOLERANCES.items()
             if group in TOLERANCE_GROUPS and tol > 0 and name in robot]
    out = []
    for _ in range(n):
        d = {name: float(robot[name]) + float(tol) * float(rng.uniform(-1.0, 1.0))
             for name, tol in toler}
        if "mu_s" in d and "mu_k" in d:
            d["mu_k"] = min(d["mu_k"], d["mu_s"])
        lo_hi = P.RANGES
        for k in d:
            lo, hi = lo_hi.get(("robot", k), (-math.inf, math.inf))
            d[k] = min(max(d[k], lo), hi)
        out.append(d)
    return out


@dataclass(frozen=True)
class EnsembleDraw:
    """One replay of the tolerance ensemble: the plant's robot parameters, its effects and the
    share of ``I_wy`` whose spin-up reacts in the ``load_transfer`` effect (the plant's
    ``plant.spin_share``)."""
    robot: dict[str, float]
    effects: dict[str, dict[str, float]]
    spin_share: float = 1.0


def ensemble_draws(robot: Mapping[str, float], n: int, rng: np.random.Generator
                   ) -> list[EnsembleDraw]:
    """``n`` replays of the tolerance ensemble: the parameters within their tolerance
    (:func:`tolerance_draws`), then the left-out physics of the normal forces
    (:func:`left_out_normal_forces`), each part uniform over its range: the share of the wheels'
    mass on the axle in [0, 1] (:func:`wheels_on_axle`, from the drawn d, e, I_rz), and the
    plant's ``load_transfer`` effect at a height that is a centre of mass in [0, ``h_max_m``]
    plus a share k in [0, 1] of the spin-up's rolling height ``spin_h_m``, with the effect's own
    spin-up off (``spin_share`` 0).  While the wheels roll (θ̈ = a/r, where a slip onset is
    decided) that is exactly the pitch balance with a share k of ``I_wy`` reacting; inside a
    slip the balance's spin term follows the slipping wheel's θ̈, which the motor's whole
    torque drives (its stall torque is some twenty times what the contact passes), and drawn
    there it would spread every slip episode of the ensemble by normal forces that no slip
    onset decides; a 7 % larger wheel in a braking run then hid inside that spread
    (``test_analyzer_e2e``).  A draw with neither part is the planar nominal model."""
    params = tolerance_draws(robot, n, rng)
    out = []
    for d in params:
        lo = left_out_normal_forces({**robot, **d})
        share = float(rng.uniform(0.0, 1.0))
        h = float(rng.uniform(0.0, 1.0)) * lo.h_max_m + float(rng.uniform(0.0, 1.0)) * lo.spin_h_m
        r = {**d, **wheels_on_axle({**robot, **d}, share)}
        out.append(EnsembleDraw(r, {"load_transfer": {"h": h}}, spin_share=0.0))
    return out


@dataclass(frozen=True)
class ToleranceUncertainty:
    """What :func:`tolerance_uncertainty` finds for one run (the PreparedRun fields of the
    same names)."""
    replay_unc: dict[str, tuple[np.ndarray, np.ndarray]]  # channel -> (t, std), in quadrature
    tolerance_bias: dict[str, float]               # channel -> whole-run bias allowed
    tolerance_draw_means: dict[str, list[float]]   # channel -> each draw's mean residual


def tolerance_uncertainty(prep: PreparedRun, replay: OpenLoopReplay, n: int = TOLERANCE_ENSEMBLE
                          ) -> ToleranceUncertainty | None:
    """Per channel and sample, the spread of ``n`` duty replays of the tolerance ensemble
    (:func:`ensemble_draws`: robot parameters within their tolerance, and the nominal model's
    left-out physics of the normal forces) about the nominal replay (the RMS over the draws of
    their difference from it: the left-out physics moves every draw the same way, so their
    spread about their own mean would miss a recording at the far end of the range), added in
    quadrature to the run's replay uncertainty (``prep.replay_unc``, which
    :func:`input_uncertainty` may already hold): decisions compare each residual with its noise
    floor, the input spread and this spread together (``Channel.deflated``), and the fits weigh
    samples by the same.  The recorded odometry is compared with the nominal geometry (the
    recorder's own arithmetic); only the plant is drawn.  Draws are seeded by the run's content,
    so an analysis is repeatable.  Returns (None: nothing drawn, ``n`` < 2) that replay
    uncertainty, the ``tolerance_bias`` (channel -> RMS over the draws of the mean residual's
    departure from the nominal replay's: the whole-run bias the tolerance allows) and the
    ``tolerance_draw_means`` (channel -> each draw's mean residual, from which
    ``locate.allowed_bias`` gets the bias allowed in the wheels' difference); the pipeline puts
    them in the prepared run.  ``prep`` is left as it is."""
    from host_tools import _native
    from host_tools.analyzer.replay.channels import channels
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    if n < 2:
        return None
    seed = int(np.uint32(int(np.sum(np.asarray(prep.run.telemetry["t_s"], float) * 1e3))
                         & 0xFFFFFFFF))
    rng = np.random.default_rng([seed, 22])
    acc: dict[str, list[np.ndarray]] = {}
    t_of: dict[str, np.ndarray] = {}
    nominal = channels(prep, replay.simulate_windows(prep, {}), replay.mode)
    for draw in ensemble_draws(prep.robot, n, rng):
        def factory(robot: dict[str, Any], motor: dict[str, Any], _d: dict[str, float] = draw.robot,
                    _k: float = draw.spin_share) -> Any:
            plant = _native.Plant(robot={**robot, **_d}, motor=motor)
            plant.set("plant.spin_share", _k)
            return plant
        rep = OpenLoopReplay(replay.mode, dt_s=replay.dt_s, plant_factory=factory)
        for name, ch in channels(prep, rep.simulate_windows(prep, draw.effects),
                                 replay.mode).items():
            acc.setdefault(name, []).append(ch.resid)
            t_of[name] = ch.t
    old = prep.replay_unc or {}
    new = {}
    for name, v in acc.items():
        if len({a.size for a in v}) != 1 or not t_of[name].size:
            continue
        t = t_of[name]
        # about the nominal replay, not about the draws' mean: the left-out physics moves every
        # draw one way, and the recording may sit at the far end of that range
        ref = nominal[name].resid if name in nominal else None
        if ref is not None and ref.size == v[0].size:
            spread = np.sqrt(np.mean((np.array(v) - ref) ** 2, axis=0))
        else:
            spread = np.std(np.array(v), axis=0)
        if name in old:
            spread = np.sqrt(spread ** 2 + np.interp(t, *old[name]) ** 2)
        new[name] = (t, spread)
    # the parameters are one set for the whole robot, so the error they cause is systematic: the
    # RMS over the draws of each draw's mean residual about the nominal replay's is a bias the
    # nominal model allows (``bias_test``)
    draw_means = {name: [float(np.mean(a)) for a in v]
                  for name, v in acc.items() if all(a.size for a in v)}
    bias = {}
    for name, m in draw_means.items():
        nom_ch = nominal.get(name)
        if nom_ch is not None and nom_ch.resid.size:
            bias[name] = float(np.sqrt(np.mean((np.array(m) - float(np.mean(nom_ch.resid))) ** 2)))
        else:
            bias[name] = float(np.std(m))
    return ToleranceUncertainty({**old, **new}, bias, draw_means)
