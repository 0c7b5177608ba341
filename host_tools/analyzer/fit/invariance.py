"""Time invariance of the selected model: a vocabulary effect's parameter is a constant of the
robot, so the model fitted on the early part of the recordings and on the late part must agree
within the fits' uncertainty.  A parameter that drifts (a supply sagging with the current and
the charge drawn, a motor warming up) is physics outside the vocabulary, however well the
drifting effect fits the whole: the verdict is then ``unexplained`` with the drift reported.

The test, paired over the runs: each run's first and second half are fitted apart
(``Problem.fit``, started at the whole fit), and each free fit coordinate's difference
d_i = early_i - late_i has the standard error s_i = sqrt(sigma_early_i^2 + sigma_late_i^2),
the fits' own (autocorrelation-corrected) 1-sigma uncertainties.  The runs are replicates of
one robot: their weighted mean difference d = sum(w_i d_i)/sum(w_i), w_i = 1/s_i^2, has the
standard error 1/sqrt(sum w_i), scaled up by the runs' scatter beyond their sigmas when there is
more (Birge ratio sqrt(chi^2/(m - 1)) over m runs): a fit's sigma knows the noise only, and a
model that is not exact (another engine, a recorder's details, a parameter that a half of a run
hardly constrains) lets a half's fit move with the run's regime by far more, differently from
run to run, while a drifting supply moves every run alike.  z = d / se is significant at a
false-alarm rate of INVARIANCE_ALPHA per analysis, two-sided, Bonferroni over the coordinates
compared: the rate of the detection's bias test (``locate.bias.BIAS_ALPHA``).  The nominal
model's tolerance is one offset common to both halves and cancels in the difference.

As every update, a drift must also change the outputs by at least INVARIANCE_MIN_OUTPUT noise
floors (the halves' own fits against the whole fit, RMS over the fit channels, as a candidate's
output change is measured): each run of the suites accelerates in its first half and cruises
in its second, so time and regime go together, and a vocabulary effect on another engine moves
alike in every run between the two regimes (heldback7's MuJoCo driver drop: 0.7175 V early,
0.7037 V late, z 4.4, the outputs 0.14 noise floors apart)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import stats

from host_tools.analyzer.fit.judge import Candidate
from host_tools.analyzer.fit.params import FitResult, params_for
from host_tools.analyzer.fit.problem import Problem, largest_rms
from host_tools.analyzer.locate.bias import BIAS_ALPHA, BIAS_MIN_FLOORS
from host_tools.analyzer.signals import round_sig

if TYPE_CHECKING:
    from host_tools.analyzer.fit.state_dependence import StateDependence

INVARIANCE_ALPHA = BIAS_ALPHA
INVARIANCE_SPLIT = 0.5        # the time split of each run: first and second half
INVARIANCE_NFEV = 30          # evaluations of each half's fit (started at the whole fit)
NUMERICAL_ZERO = 1e-9         # of a coordinate's range: a sigma below it is round-off
INVARIANCE_MIN_OUTPUT = BIAS_MIN_FLOORS   # judge's min_output: the smallest adoptable change


@dataclass
class Invariance:
    """The early and late fits of the selected effects and their comparison."""
    coords: list[dict[str, Any]] = field(default_factory=list)  # one per compared coordinate
    z_threshold: float = math.inf
    output_floors: float = 0.0    # the drifting model's output change (_split_output_change)
    drift: bool = False           # in time, or (with_state) with the drive's load
    state: StateDependence | None = None   # fit/state_dependence.py

    def with_state(self, state: StateDependence | None) -> Invariance:
        """This check with the state-dependence test's result joined: either finding makes
        the selected model one that is not constant."""
        self.state = state
        self.drift = self.drift or (state is not None and state.found)
        return self

    def time_drift(self) -> bool:
        """The halves' drift alone (significant and moving the outputs)."""
        return (any(abs(c["z"]) > self.z_threshold for c in self.coords)
                and self.output_floors >= INVARIANCE_MIN_OUTPUT)

    def report(self) -> dict[str, Any]:
        """report.json's ``fit.invariance`` (docs/analyzer.md)."""
        return {"split": "first and second half of each run", "alpha": INVARIANCE_ALPHA,
                "z_threshold": round(self.z_threshold, 3),
                "output_change_noise_floors": round_sig(self.output_floors, 3),
                "min_output_noise_floors": INVARIANCE_MIN_OUTPUT, "drift": self.drift,
                "params": self.coords,
                "state_dependence": None if self.state is None else self.state.report()}

    def note(self) -> str:
        if self.state is not None and self.state.found and not self.time_drift():
            return self.state.note()
        worst = max(self.coords, key=lambda c: abs(c["z"]))
        return (f"the selected model is not constant in time: {worst['effect']}.{worst['param']} "
                f"fitted {worst['early']:.4g} on the first half of the runs and "
                f"{worst['late']:.4g} on the second, a difference of {worst['drift']:.3g} +- "
                f"{worst['drift_std']:.2g} (z {worst['z']:+.2f} beyond {self.z_threshold:.2f}; "
                f"the outputs move by {self.output_floors:.2f} noise floors with it): "
                "a vocabulary effect's parameter is constant, so a drifting one stands for "
                "physics outside the vocabulary")


def _weighted(values: list[float], stds: list[float]) -> tuple[float, float, float]:
    """(weighted mean, its standard error, Birge ratio >= 1) of ``values`` with ``stds``."""
    w = np.array([1.0 / s ** 2 for s in stds])
    v = np.array(values)
    mean = float(np.sum(w * v) / np.sum(w))
    se = float(1.0 / math.sqrt(np.sum(w)))
    birge = 1.0
    if v.size > 1:
        birge = max(1.0, math.sqrt(float(np.sum(w * (v - mean) ** 2)) / (v.size - 1)))
    return mean, se, birge


def invariance_check(problem: Problem, chosen: Candidate,
                     split: float = INVARIANCE_SPLIT) -> Invariance:
    """Fit ``chosen``'s effects on the early and the late part of each run (before and after
    ``split`` of its duration) and compare each free coordinate, paired over the runs (module
    docstring).  Coordinates pinned in the whole fit stay pinned and no other is pinned: a
    half is the whole fit's model refitted, and a coordinate the half leaves open shows as its
    large sigma (a half that pinned Stribeck's v_s at its neutral 0.01 m/s and refitted from
    the grid ended at a worse cost than its start, and its mu_k0 at the bound stood for a model
    the whole fit is not); a run whose coordinate has no finite uncertainty above round-off in
    either half, or is pinned there, does not count for it."""
    old = problem.split_frac
    problem.split_frac = split
    try:
        per_run = [[problem.fit(chosen.effects, [i], part, x0=chosen.fit.x,
                                max_nfev=INVARIANCE_NFEV, fixed=chosen.fit.fixed or None,
                                pin_unidentified=False)
                    for part in ("early", "late")] for i in range(len(problem.preps))]
    finally:
        problem.split_frac = old
    coords: list[dict[str, Any]] = []
    params = params_for(chosen.effects, problem.meta, problem.vocab)
    for k, (effect, name) in enumerate(chosen.fit.coords):
        if k in chosen.fit.fixed or (k < len(params) and params[k].shape):
            continue   # a shape parameter (Stribeck's v_s) is judged through its partner
        # a sigma at the pseudo-inverse's round-off (a half that does not move the outputs
        # with this coordinate: a track width on a straight half) is no estimate
        tiny = NUMERICAL_ZERO * (params[k].hi - params[k].lo) if k < len(params) else 0.0
        d, s, e_v, e_s, l_v, l_s = [], [], [], [], [], []
        for early, late in per_run:
            se, sl = early.std[k], late.std[k]
            if (k in early.fixed or k in late.fixed or not (math.isfinite(se) and math.isfinite(sl))
                    or not (se > tiny and sl > tiny)):
                continue
            d.append(early.values[k] - late.values[k])
            s.append(math.sqrt(se ** 2 + sl ** 2))
            e_v.append(early.values[k])
            e_s.append(se)
            l_v.append(late.values[k])
            l_s.append(sl)
        if not d:
            continue
        mean, se_d, birge = _weighted(d, s)
        coords.append({"effect": effect, "param": name, "runs": len(d),
                       "early": round_sig(_weighted(e_v, e_s)[0], 5),
                       "late": round_sig(_weighted(l_v, l_s)[0], 5),
                       "drift": round_sig(mean, 4), "drift_std": round_sig(se_d * birge, 3),
                       "birge_ratio": round(birge, 3), "z": round(mean / (se_d * birge), 3),
                       "per_run": [round_sig(x, 4) for x in d],
                       "per_run_std": [round_sig(x, 3) for x in s]})
    if not coords:
        return Invariance()
    zt = float(stats.norm.ppf(1.0 - INVARIANCE_ALPHA / (2 * len(coords))))
    size = _split_output_change(problem, chosen, per_run, split)
    return Invariance(coords, zt, size,
                      any(abs(c["z"]) > zt for c in coords) and size >= INVARIANCE_MIN_OUTPUT)


def _split_output_change(problem: Problem, chosen: Candidate, per_run: list[list[FitResult]],
                         split: float) -> float:
    """In noise floors, what the halves' own fits change in the residual against the whole
    fit, each half with its own, measured as a candidate's output change is
    (``Problem.output_change``: per fit channel, the largest): the output change of a model
    whose parameters drift."""
    old = problem.split_frac
    problem.split_frac = split
    sums: dict[str, list[float]] = {}
    try:
        for i, halves in enumerate(per_run):
            for part, own in zip(("early", "late"), halves):
                problem.change_sums(chosen.fit.params, own.params, [i], part, into=sums)
    finally:
        problem.split_frac = old
    return largest_rms(sums)
