"""The replay's uncertainty from the nominal model's own tolerance: the robot's parameters are
known only within params.json's ``tol`` (Table II.2 to its last printed digit, μ to a
spring-scale division), and where the replay is sensitive to them (a slip onset, a saturating
stop or reversal, an arc over seconds) the recording may depart from the nominal replay by that
much without any physics missing."""
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
class ToleranceUncertainty:
    """What :func:`tolerance_uncertainty` finds for one run (the PreparedRun fields of the
    same names)."""
    replay_unc: dict[str, tuple[np.ndarray, np.ndarray]]  # channel -> (t, std), in quadrature
    tolerance_bias: dict[str, float]               # channel -> whole-run bias allowed
    tolerance_draw_means: dict[str, list[float]]   # channel -> each draw's mean residual


def tolerance_uncertainty(prep: PreparedRun, replay: OpenLoopReplay, n: int = TOLERANCE_ENSEMBLE
                          ) -> ToleranceUncertainty | None:
    """Per channel and sample, the spread (std) of ``n`` duty replays whose robot parameters are
    drawn within their tolerance (:func:`tolerance_draws`), added in quadrature to the run's
    replay uncertainty (``prep.replay_unc``, which :func:`input_uncertainty` may already hold):
    decisions compare each residual with its noise floor, the input spread and this spread
    together (``Channel.deflated``), and the fits weigh samples by the same.  The recorded
    odometry is compared with the nominal geometry (the recorder's own arithmetic); only the
    plant's parameters are drawn.  Draws are seeded by the run's content, so an analysis is
    repeatable.  Returns (None: nothing drawn, ``n`` < 2) that replay uncertainty, the
    ``tolerance_bias`` (channel -> std over the draws of the mean residual: the whole-run bias
    the tolerance allows) and the ``tolerance_draw_means`` (channel -> each draw's mean
    residual, from which ``locate.allowed_bias`` gets the bias allowed in the wheels'
    difference); the pipeline puts them in the prepared run.  ``prep`` is left as it is."""
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
    for draw in tolerance_draws(prep.robot, n, rng):
        def factory(robot: dict[str, Any], motor: dict[str, Any], _d: dict[str, float] = draw
                    ) -> Any:
            return _native.Plant(robot={**robot, **_d}, motor=motor)
        rep = OpenLoopReplay(replay.mode, dt_s=replay.dt_s, plant_factory=factory)
        for name, ch in channels(prep, rep.simulate_windows(prep, {}), replay.mode).items():
            acc.setdefault(name, []).append(ch.resid)
            t_of[name] = ch.t
    old = prep.replay_unc or {}
    new = {}
    for name, v in acc.items():
        if len({a.size for a in v}) != 1 or not t_of[name].size:
            continue
        t = t_of[name]
        spread = np.std(np.array(v), axis=0)
        if name in old:
            spread = np.sqrt(spread ** 2 + np.interp(t, *old[name]) ** 2)
        new[name] = (t, spread)
    # the parameters are one set for the whole robot, so the error they cause is systematic: the
    # spread of each draw's mean residual is a bias the nominal model allows (``bias_test``)
    draw_means = {name: [float(np.mean(a)) for a in v]
                  for name, v in acc.items() if all(a.size for a in v)}
    return ToleranceUncertainty({**old, **new},
                                {name: float(np.std(m)) for name, m in draw_means.items()},
                                draw_means)
