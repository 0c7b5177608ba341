"""Time invariance of the selected model: a vocabulary effect's parameter is a constant of the
robot, so the model fitted on the early part of the recordings and on the late part must agree
within the two fits' uncertainty.  A parameter that drifts (a supply sagging with the charge
drawn, a motor warming up, a wearing tyre) is physics outside the vocabulary, however well the
drifting effect fits the whole: the verdict is then ``unexplained`` with the drift reported.

The test: the selected effects are refitted (``Problem.fit``, started at the whole fit) on the
first and on the second half of each run, and each free fit coordinate's difference is compared
with its standard error, z = (early - late) / sqrt(sigma_early^2 + sigma_late^2), the sigmas the
fits' own (autocorrelation-corrected) 1-sigma uncertainties.  A drift is significant at a
false-alarm rate of INVARIANCE_ALPHA per analysis, two-sided, Bonferroni over the coordinates
compared: the rate of the detection's bias test (``locate.BIAS_ALPHA``).  The nominal model's
tolerance is one offset common to both halves and cancels in the difference.

A drift must also matter: the replays with the early and with the late parameters must differ
by at least INVARIANCE_MIN_FLOORS (RMS over the fit channels, in noise floors, as a
candidate's output change is measured), the smallest output change an update may make to be
adopted.  The halves' sigmas are those of the fit's noise alone; a model that is not exact
(another engine, a recorder's details) lets a parameter move with the regime by more than
that, and a difference the outputs cannot show is no evidence of a drift (the tuning case
``deadband_weak``: 0.4046 +- 0.0011 V early, 0.4003 +- 0.0006 V late, z 3.4, outputs
0.0x floors apart)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from host_tools.analyzer.fit.judge import Candidate
from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.locate import BIAS_ALPHA, BIAS_MIN_FLOORS
from host_tools.analyzer.signals import round_sig

INVARIANCE_ALPHA = BIAS_ALPHA
INVARIANCE_MIN_FLOORS = BIAS_MIN_FLOORS   # = judge's min_output: the smallest adoptable change
INVARIANCE_SPLIT = 0.5        # the time split of each run: first and second half
INVARIANCE_NFEV = 30          # evaluations of each half's fit (started at the whole fit)


@dataclass
class Invariance:
    """The early and late fits of the selected effects and their comparison."""
    coords: list[dict[str, Any]] = field(default_factory=list)  # one per compared coordinate
    z_threshold: float = math.inf
    output_floors: float = 0.0    # RMS change of the fit channels from early to late parameters
    drift: bool = False

    def report(self) -> dict[str, Any]:
        """report.json's ``fit.invariance`` (docs/analyzer.md)."""
        return {"split": "first and second half of each run", "alpha": INVARIANCE_ALPHA,
                "z_threshold": round(self.z_threshold, 3),
                "output_change_noise_floors": round_sig(self.output_floors, 3),
                "min_output_noise_floors": INVARIANCE_MIN_FLOORS, "drift": self.drift,
                "params": self.coords}

    def note(self) -> str:
        worst = max(self.coords, key=lambda c: abs(c["z"]))
        return (f"the selected model is not constant in time: {worst['effect']}.{worst['param']} "
                f"fitted {worst['early']:.4g} +- {worst['early_std']:.2g} on the first half of "
                f"each run and {worst['late']:.4g} +- {worst['late_std']:.2g} on the second "
                f"(z {worst['z']:+.2f}, beyond {self.z_threshold:.2f}; the outputs "
                f"{self.output_floors:.2f} noise floors apart): a vocabulary effect's "
                "parameter is constant, so a drifting one stands for physics outside the "
                "vocabulary")


def invariance_check(problem: Problem, chosen: Candidate,
                     split: float = INVARIANCE_SPLIT) -> Invariance:
    """Fit ``chosen``'s effects on the early and the late part of every run (before and after
    ``split`` of each run's duration) and compare each free coordinate (module docstring).
    Coordinates pinned in the whole fit stay pinned; one without a finite uncertainty in
    either half is not compared."""
    runs = list(range(len(problem.preps)))
    old = problem.split_frac
    problem.split_frac = split
    try:
        halves = [problem.fit(chosen.effects, runs, part, x0=chosen.fit.x,
                              max_nfev=INVARIANCE_NFEV, fixed=chosen.fit.fixed or None)
                  for part in ("early", "late")]
    finally:
        problem.split_frac = old
    early, late = halves
    coords = []
    for i, (effect, name) in enumerate(chosen.fit.coords):
        if i in chosen.fit.fixed or i in early.fixed or i in late.fixed:
            continue
        se, sl = early.std[i], late.std[i]
        if not (math.isfinite(se) and math.isfinite(sl)) or se + sl <= 0:
            continue
        z = (early.values[i] - late.values[i]) / math.sqrt(se ** 2 + sl ** 2)
        coords.append({"effect": effect, "param": name,
                       "early": round_sig(early.values[i], 5), "early_std": round_sig(se, 3),
                       "late": round_sig(late.values[i], 5), "late_std": round_sig(sl, 3),
                       "z": round(z, 3)})
    if not coords:
        return Invariance()
    zt = float(stats.norm.ppf(1.0 - INVARIANCE_ALPHA / (2 * len(coords))))
    r_early = problem.residual(early.params, runs)
    r_late = problem.residual(late.params, runs)
    size = (float(np.sqrt(np.mean((r_early - r_late) ** 2)))
            if r_early.size == r_late.size and r_early.size else 0.0)
    return Invariance(coords, zt, size,
                      any(abs(c["z"]) > zt for c in coords) and size >= INVARIANCE_MIN_FLOORS)
