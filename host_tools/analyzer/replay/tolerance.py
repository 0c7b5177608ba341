"""The replay's uncertainty from the nominal model's own tolerance: the robot's parameters are
known only within params.json's ``tol`` (Table II.2 to its last printed digit, μ to a
spring-scale division), and where the replay is sensitive to them (a slip onset, a saturating
stop or reversal, an arc over seconds) the recording may depart from the nominal replay by that
much without any physics missing.

Beside the parameters, the normal forces' physics that the nominal model carries only at a guess
(replay/normal_forces.py) is drawn over its possible range (:func:`left_out_normal_forces`):
where the wheels' mass sits, the height of the centre of mass, and the share of the wheels'
spin-up that reacts on the body.  The nominal model lies inside each range."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Mapping

import numpy as np

from host_tools import params as P
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.normal_forces import (SPIN_SHARE, NormalForces, spin_height,
                                                      spin_range, wheels_on_axle)

__all__ = ["EnsembleDraw", "LeftOut", "ToleranceUncertainty", "ensemble_draws",
           "left_out_normal_forces", "tolerance_draws", "tolerance_uncertainty",
           "wheels_on_axle"]

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
    """The normal forces' physics that the nominal model (:data:`normal_forces.NOMINAL`: the
    wheels' mass on the axle, the centre of mass at Table II.2's ``h``, the spin-up's share
    ``k^``) can only carry at a guess, at its derived size (:func:`left_out_normal_forces`);
    each part is drawn uniformly and independently over its possible range, the nominal model
    inside it.

    ``wheel_shift_m``: how far the robot's centre of mass lies behind the platform's c when
    the wheels' mass sits on the axle (``2 m_w d / m_t``).  Table II.1 gives ``d`` only as the
    "distance from wheel's axis to center of mass" and II.29 puts the total mass m_t at c;
    params.json reads ``m_r``, ``d`` and ``I_rz`` as the platform's, so the nominal model has
    the wheels on the axle and the caster carrying ``m_r g d / (d + e)``.  The planar reading
    (``m_t g d / (d + e)``) is still possible; the draws take a share in [0, 1].

    ``h_max_m``: the highest centre of mass, Table II.2's ``h`` plus its tolerance;
    ``com_h_m``: the nominal one (``h``); the draws take one in [0, ``h_max_m``].

    ``spin_h_m``: the reaction of the wheels' spin-up as a load-transfer height.  The motors
    spinning up the wheels pitch the body and unload the caster by ``k I_wy (theta''_r +
    theta''_l) / (d + e)`` (moments about the centre of mass: the wheels' spin momentum changes
    at that rate; lib/slipmodel/README.md, "Load transfer and spin-up"); while the wheels roll
    ``theta'' = a / r``, which is ``m_t a k h_s / (d + e)`` with ``h_s = 2 I_wy / (m_t r)``
    (39 mm at the table's values).  ``spin_share``: the nominal model's ``k^``
    (params.json ``model.spin_share``); the draws take k in ``k^ +- tol``, i.e. [0, 1].

    ``mu_ranges``: relative ranges (lo <= 0 <= hi), one per part, by which a robot inside these
    ranges moves a wheel's normal force at its slip onset from the nominal model's.  The
    traction limit is ``mu N``, so such a recording replays as one whose friction coefficient
    is that much off the nominal one, either way:

    * the wheels' mass: the nominal wheels carry ``N0 = N_p (1 + x)``, ``x = 2 m_w d /
      (m_t e)`` over the planar ``N_p = m_t g e / (2 (d + e))``; a robot with its wheels' mass
      at c carries ``N_p``: ``[-x / (1 + x), 0]``;
    * the height: at the acceleration where both wheels reach ``mu N`` (``a = 2 mu N /
      m_t``) a transfer at H moves ``m_t a H / (2 (d + e)) = mu N H / (d + e)``, so a centre of
      mass at H against the nominal h moves N by ``mu (H - h) / (d + e)`` of it: ``[-mu h /
      (d + e), mu (h_max - h) / (d + e)]``;
    * the spin-up: the same with the rolling height ``(k - k^) h_s``: ``[-mu k^ h_s / (d + e),
      mu (1 - k^) h_s / (d + e)]``."""
    wheel_shift_m: float
    h_max_m: float
    com_h_m: float
    spin_h_m: float
    spin_share: float
    mu_ranges: tuple[tuple[float, float], ...]

    @property
    def mu_range(self) -> tuple[float, float]:
        """(lowest, highest) relative departure of the fitted friction coefficient, all parts
        together."""
        return (float(sum(lo for lo, _ in self.mu_ranges)),
                float(sum(hi for _, hi in self.mu_ranges)))


def left_out_normal_forces(robot: Mapping[str, float], mu: float | None = None) -> LeftOut:
    """The derived size of the normal forces' physics that the nominal model carries at a guess
    (:class:`LeftOut`) for the robot parameters ``robot`` (meta.json's); ``mu`` the friction
    coefficient of ``mu_ranges`` (default the robot's μs)."""
    m_r, m_w = float(robot["m_r"]), float(robot["m_w"])
    d, e = float(robot["d"]), float(robot["e"])
    h = max(float(robot["h"]), 0.0)
    h_max = max(h + P.TOLERANCES.get(("robot", "h"), 0.0), 0.0)
    m_t = m_r + 2.0 * m_w
    mu_v = float(robot["mu_s"]) if mu is None else float(mu)
    spin = spin_height(robot)
    k_lo, k_hi = spin_range()
    k = SPIN_SHARE
    if not (m_t > 0 and d + e > 0 and e > 0):
        return LeftOut(0.0, h_max, h, spin, k, ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0)))
    shift = max(d - wheels_on_axle(robot, 1.0)["d"], 0.0)   # c's move toward the axle
    x = shift / e
    c = mu_v / (d + e)
    return LeftOut(shift, h_max, h, spin, k,
                   ((-x / (1.0 + x), 0.0), (-c * h, c * (h_max - h)),
                    (c * (k_lo - k) * spin, c * (k_hi - k) * spin)))


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
    """One replay of the tolerance ensemble: the robot parameters drawn within their tolerance
    (``params``, over the run's own) and the normal forces' physics drawn over its range
    (``forces``)."""
    params: dict[str, float]
    forces: NormalForces


def ensemble_draws(robot: Mapping[str, float], n: int, rng: np.random.Generator
                   ) -> list[EnsembleDraw]:
    """``n`` replays of the tolerance ensemble: the parameters within their tolerance
    (:func:`tolerance_draws`), then the normal forces' physics (:func:`left_out_normal_forces`),
    each part uniform over its range: the share of the wheels' mass on the axle in [0, 1]
    (:func:`wheels_on_axle`, from the drawn d, e, I_rz), a centre of mass in [0,
    ``h_max_m``], and a share k of the spin-up in ``k^ +- tol`` ([0, 1]) as the rolling height
    ``k h_s``, with the plant's own spin term off (``normal_forces.plant_config``).  While the
    wheels roll (θ̈ = a/r, where a slip onset is decided) that is exactly the pitch balance with
    a share k of ``I_wy`` reacting; inside a slip the balance's spin term follows the slipping
    wheel's θ̈, which the motor's whole torque drives (its stall torque is some twenty times
    what the contact passes), and drawn there it would spread every slip episode of the
    ensemble by normal forces that no slip onset decides; a 7 % larger wheel in a braking run
    then hid inside that spread (``test_analyzer_e2e``).  The nominal model (share 1, the
    table's h, k^) lies inside every range, so the draws fall on both sides of it."""
    params = tolerance_draws(robot, n, rng)
    k_lo, k_hi = spin_range()
    out = []
    for d in params:
        lo = left_out_normal_forces({**robot, **d})
        share = float(rng.uniform(0.0, 1.0))
        h = float(rng.uniform(0.0, 1.0)) * lo.h_max_m
        k = k_lo + float(rng.uniform(0.0, 1.0)) * (k_hi - k_lo)
        out.append(EnsembleDraw(d, NormalForces(share, h, k)))
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
        rep = OpenLoopReplay(replay.mode, dt_s=replay.dt_s, forces=draw.forces,
                             params=draw.params)
        for name, ch in channels(prep, rep.simulate_windows(prep, {}),
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
