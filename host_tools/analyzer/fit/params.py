"""The effects' parameters as fit coordinates (each mapped onto [0, 1] over its search range)
and the result of a fit."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from host_tools.analyzer import effects as fx


@dataclass
class Param:
    effect: str
    name: str
    neutral: float
    lo: float
    hi: float
    tol: float                  # tolerance of ``neutral`` (ParamSpec.tol); 0 for a shape parameter
    shape: bool = False         # a shape parameter (ParamSpec.tol None): judged through its partner
    given: tuple[Any, ...] | None = None   # ParamSpec.given
    log: bool = False           # ParamSpec.log: the coordinate is log(value), lo > 0
    # a nuisance coordinate (not a vocabulary parameter: the load_transfer fit's spin share k,
    # the friction fit's creep speed): kept only where its test passes (``keep``), else pinned
    # at ``neutral``, where the effect carries it not at all (Problem.fit); None for every
    # vocabulary parameter.  keep "sigma": kept where its 1-sigma is below ``nuisance``; keep
    # "ratio": fitted over a grid of values and kept where the likelihood ratio against the
    # fit without it passes (Problem._fit_creep; ``nuisance`` unused, 0)
    nuisance: float | None = None
    keep: str = "sigma"

    def to_x(self, v: float) -> float:
        if self.log:
            return math.log(v / self.lo) / math.log(self.hi / self.lo)
        return (v - self.lo) / (self.hi - self.lo)

    def from_x(self, x: float) -> float:
        if self.log:
            return float(self.lo * (self.hi / self.lo) ** float(x))
        return self.lo + float(x) * (self.hi - self.lo)

    def span(self, v: float) -> float:
        """d value / d coordinate at value ``v``: the search range's width on a linear map,
        v ln(hi/lo) on a logarithmic one (a coordinate's sigma times it is the value's)."""
        if self.log:
            return float(v) * math.log(self.hi / self.lo)
        return self.hi - self.lo


def params_for(names: Sequence[str], meta: Mapping[str, Any], vocab: Mapping[str, Mapping[str, float]]
               ) -> list[Param]:
    out = []
    for n in names:
        spec = fx.spec_for(n, vocab.get(n, {}))
        for ps in spec.params:
            if n in vocab and (ps.sets[0] if ps.sets else ps.name) not in vocab[n]:
                continue
            out.append(Param(n, ps.name, ps.neutral(meta), ps.lo(meta), ps.hi(meta),
                             ps.tol(meta) if ps.tol is not None else 0.0,
                             shape=ps.tol is None, given=ps.given, log=ps.log))
        if n == "load_transfer" and any(p.effect == n and p.name == "h" for p in out):
            out.append(spin_param())
        if (n == "friction_coefficient" and len(names) == 1
                and any(p.effect == n and p.given is not None for p in out)):
            out.append(creep_param())   # the friction single's (a pair carries none)
    return out


#: The friction fit's creep speeds (m/s, ``creep_param``): a grid a factor of two apart from
#: 2.5 to 40 mm/s, i.e. from under the slip speeds the 1 ms replay resolves in a spin-up (a
#: wheel at the 72 rad/s^2 straight's slip acceleration passes 2.5 mm/s within 1 ms) to well
#: above the 5 mm/s at which a contact like MuJoCo's switches to sliding (docs/suite.md).  The
#: fit holds the creep at each grid value (its cost is a staircase in it, as in mu_s).
CREEP_GRID_M_S = (0.0025, 0.005, 0.01, 0.02, 0.04)
#: The likelihood-ratio test that keeps a creep: chi-square with one degree of freedom on the
#: fit's residual scale at the analyzer's other tests' 1 %, shared among the grid's values
#: (Bonferroni: the lowest of five fits is kept only where one of them would pass at 0.2 %;
#: the creep has no value under the null, so the ratio's supremum over the grid is the test)
CREEP_LEVEL = 1.0 - 0.01 / len(CREEP_GRID_M_S)
#: passes of the creep fit at each grid value (mu_s's profile scanned at the held mu_k, then
#: mu_k solved at the held mu_s), each from the last while it lowers the cost: with creep the
#: cost is a narrow valley in (mu_s, mu_k), which one pass leaves where it started in mu_k
CREEP_PASSES = 4


def creep_param() -> Param:
    """The ``friction_coefficient`` fit's nuisance coordinate: the creep speed v over which a
    wheel's coefficient falls from mu_s to mu_k once it breaks away (``effects.creep_form``:
    the plant's Stribeck law tied to mu_s).  The nominal model has no creep (its Coulomb switch,
    v -> 0, the thesis'); a tyre and a soft contact hold about mu_s while they creep before they
    slide, and a nominal model that slides at once matches such a later slide only with a higher
    mu_s (docs/analyzer.md).  The friction single's only (a pair's fit carries none: five
    refits per grid value for each pair would multiply the pairs' cost; a pair is judged
    against the single as it is).  Fitted over :data:`CREEP_GRID_M_S` with mu_s profiled at
    each and kept only where the likelihood ratio against the fit without it passes (``keep``
    "ratio", ``Problem._fit_creep``): otherwise the friction fit is the nominal model's form.
    A shape coordinate: no size or stability test of its own (it is no effect's evidence)."""
    return Param("friction_coefficient", fx.CREEP_KEY, CREEP_GRID_M_S[0], CREEP_GRID_M_S[0],
                 CREEP_GRID_M_S[-1], 0.0, shape=True, log=True, nuisance=0.0, keep="ratio")


def spin_param() -> Param:
    """The ``load_transfer`` fit's nuisance coordinate: the share k of the wheels' spin-up that
    reacts on the body, in [0, 1] (``replay.normal_forces``: carried through the plant's own
    theta'' term where fitted).  Its neutral value is the nominal model's k^ (params.json
    ``model.spin_share``), its tolerance k^'s, and it is kept only where its 1-sigma is below
    the tolerance's standard uncertainty tol/sqrt(3) (the nominal model's own knowledge of k,
    a uniform draw over k^ +- tol): otherwise the data tell k no better than the nominal model
    does and the fit is the one without it (k^ as the rolling height k^ h_s), as an
    unidentified coordinate is pinned at its neutral value.  A shape coordinate: no size or
    stability test of its own (it is no effect's evidence)."""
    from host_tools.analyzer.replay import normal_forces as nf
    return Param("load_transfer", nf.SPIN_KEY, nf.SPIN_SHARE, 0.0, 1.0, nf.SPIN_SHARE_TOL,
                 shape=True, nuisance=nf.SPIN_SHARE_SIGMA)


def effects_dict(params: Sequence[Param], values: Sequence[float],
                 fixed: Mapping[int, float] | None = None) -> dict[str, dict[str, float]]:
    """Vocabulary parameters (what the plant and the report take) of fitted coordinates, with
    each nuisance coordinate (``Param.nuisance``) that is not pinned (``fixed``) beside them
    under its own name: a pinned nuisance is not carried at all (the nominal model's form)."""
    raw: dict[str, dict[str, float]] = {}
    extra: dict[str, dict[str, float]] = {}
    for i, (p, v) in enumerate(zip(params, values)):
        if p.nuisance is not None:
            if fixed is None or i not in fixed:
                extra.setdefault(p.effect, {})[p.name] = float(v)
            continue
        raw.setdefault(p.effect, {})[p.name] = float(v)
    out = {e: fx.vocabulary_params(e, d) for e, d in raw.items()}
    for e, d in extra.items():
        out.setdefault(e, {}).update(d)
    return out


def vocabulary_only(effects: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """``effects`` without the fits' nuisance parameters (the report's and model.json's
    vocabulary parameters)."""
    return {e: {k: float(v) for k, v in ps.items() if not is_nuisance(e, k)}
            for e, ps in effects.items()}


def is_nuisance(effect: str, name: str) -> bool:
    """A fit coordinate that is no vocabulary parameter: the load transfer's spin share, the
    friction's creep speed."""
    from host_tools.analyzer.replay.normal_forces import SPIN_KEY
    return ((effect == "load_transfer" and name == SPIN_KEY)
            or (effect == "friction_coefficient" and name == fx.CREEP_KEY))


@dataclass
class FitResult:
    effects: list[str]
    params: dict[str, dict[str, float]]
    values: list[float]
    x: np.ndarray
    rss: float
    n: int
    std: list[float]          # 1-sigma parameter uncertainty (autocorrelation-corrected)
    nfev: int
    ok: bool = True
    message: str = ""
    coords: list[tuple[str, str]] = field(default_factory=list)  # (effect, fitted coordinate)
    fixed: dict[int, float] = field(default_factory=dict)  # coordinate index -> pinned value in [0, 1]
    unidentified: list[str] = field(default_factory=list)   # "effect.coordinate" pinned
    # "effect.coordinate" -> its profile set (coordinates with a ``given`` spec, on fits of
    # every run: Problem.fit)
    intervals: dict[str, "ProfileInterval"] = field(default_factory=dict)
    # nuisance key -> (lowest, highest) grid value within the 95 % chi-square of the grid's
    # lowest cost, for a nuisance fitted over a grid (the creep speed: Problem._fit_creep)
    nuisance_sets: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def n_free(self) -> int:
        return len(self.values) - len(self.fixed)


def fitted_nuisance(fit: "FitResult", effect: str) -> dict[str, dict[str, float]]:
    """The nuisance coordinates ``fit`` carries for ``effect`` (kept, not pinned: the effect's
    fitted parameters hold them beside the vocabulary's), name -> {"value", "std"} (the
    report's extra field ``nuisance``; empty when none is kept)."""
    ps = fit.params.get(effect, {})
    out: dict[str, dict[str, float]] = {}
    for k, v in ps.items():
        if not is_nuisance(effect, k):
            continue
        if k in fit.nuisance_sets:   # held at a grid value: its set over the grid, not a sigma
            lo, hi = fit.nuisance_sets[k]
            out[k] = {"value": float(v), "lo": float(lo), "hi": float(hi)}
            continue
        sd = next((s for (e, q), s in zip(fit.coords, fit.std) if e == effect and q == k),
                  math.nan)
        out[k] = {"value": float(v), "std": float(sd)}
    return out


@dataclass
class ProfileInterval:
    """The profile-likelihood set of a coordinate with a ``given`` spec (mu_s with mu_k held):
    the values whose cost is within the chi-square threshold of the profile's minimum
    (:func:`host_tools.analyzer.fit.solver.profile_interval`)."""
    lo: float                  # lower edge (the possible range's bottom for an upper bound)
    hi: float                  # upper edge (the possible range's top for a lower bound)
    kind: str                  # "two_sided", "upper_bound" (lo is the bound's floor, e.g. mu_k),
                               # "lower_bound" (hi is the range's top) or "unbounded"
    level: float               # confidence level of the set (0.95)
    sigma: float               # the standard deviation it implies (half the 95 % width / 1.96)
    best: float                # the profile's minimum (on a flat minimum, its point nearest
                               # the nominal model's point on the line: solver.given_neutral)
    flat: tuple[float, float]  # the stretch over which the cost equals its minimum
    possible: tuple[float, float]   # the range scanned: the coordinate's possible range
    step: float                # the finest grid step of the scan
    evaluations: int           # residual evaluations the scan took
