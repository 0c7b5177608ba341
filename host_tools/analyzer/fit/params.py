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
    return out


def effects_dict(params: Sequence[Param], values: Sequence[float]) -> dict[str, dict[str, float]]:
    """Vocabulary parameters (what the plant and the report take) of fitted coordinates."""
    raw: dict[str, dict[str, float]] = {}
    for p, v in zip(params, values):
        raw.setdefault(p.effect, {})[p.name] = float(v)
    return {e: fx.vocabulary_params(e, d) for e, d in raw.items()}


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

    @property
    def n_free(self) -> int:
        return len(self.values) - len(self.fixed)


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
