"""The numerics of one fit: the coarse multi-start, the bounded least-squares solve, each fitted
coordinate's uncertainty from the correlated residual, and which coordinates the data do not
identify."""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from host_tools.analyzer.fit.params import Param


# A fitted coordinate is unidentified when its 1-sigma uncertainty exceeds this fraction of its
# search range: the data say nothing about it.
UNIDENTIFIED = 0.5


def lag1_correlation(r: np.ndarray) -> float:
    """Lag-1 correlation of ``r`` about its mean, clipped to [0, 0.995] (0 below 3 samples)."""
    r = np.asarray(r, float)
    if r.size < 3:
        return 0.0
    a, b = r[:-1] - r.mean(), r[1:] - r.mean()
    den = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    rho = 0.0 if den == 0 else float(np.sum(a * b) / den)
    return min(max(rho, 0.0), 0.995)


def effective_n(r: np.ndarray) -> float:
    """Number of independent samples in a residual with AR(1)-like correlation."""
    r = np.asarray(r, float)
    if r.size < 3:
        return float(r.size)
    rho = lag1_correlation(r)
    return max(r.size * (1 - rho) / (1 + rho), 2.0)



def residual_variance(r: np.ndarray, k: int) -> float:
    """The scale of a least-squares covariance, (J'J)^+ times this: the residual's mean square
    over its n - k degrees of freedom (k fitted coordinates), inflated by n / n_eff for its
    correlation (:func:`effective_n`)."""
    r = np.asarray(r, float)
    return float(np.sum(r ** 2)) / max(r.size - k, 1) * (r.size / max(effective_n(r), 1.0))

def given_line(params: Sequence[Param], free: Sequence[int], i: int, values: Sequence[float],
               meta: Mapping[str, Any]
               ) -> tuple[int, float, float, float, Callable[[float], tuple[float, float]]] | None:
    """The line through the fitted point along which coordinate ``i`` (with a ``given`` spec,
    ``effects.ParamSpec.given``) moves while the held quantity keeps its value: (index of the
    keeper coordinate, the held value, the lowest and highest possible value of ``i`` there,
    value -> (x_i, x_keeper) in [0, 1] coordinates).  None when ``i`` has no such line among
    the free coordinates (no spec, the keeper pinned or absent, an empty possible range)."""
    g = params[i].given
    if g is None or i not in free:
        return None
    held, keeper, keeper_value, possible = g
    names = [(p.effect, p.name) for p in params]
    try:
        j = names.index((params[i].effect, keeper))
    except ValueError:
        return None
    if j not in free or keeper != f"{held}_over_{params[i].name}":
        return None
    held_v = float(values[i]) * float(values[j])
    lo, hi = possible(held_v, meta)
    lo, hi = max(lo, params[i].lo), min(hi, params[i].hi)
    if not hi > lo:
        return None
    pi, pj = params[i], params[j]
    return j, held_v, float(lo), float(hi), \
        lambda v: (pi.to_x(v), pj.to_x(keeper_value(v, held_v)))


def given_neutral(params: Sequence[Param], i: int, j: int, held_v: float, lo: float,
                  hi: float) -> float:
    """The nominal model's point on coordinate ``i``'s given line (:func:`given_line`: the held
    quantity at ``held_v``, keeper ``j``, possible range [lo, hi]): the value of ``i`` at which
    the keeper takes its own neutral value, or the end of [lo, hi] nearest to it.  For mu_s
    with mu_k held, mu_s = mu_k / (the nominal mu_k/mu_s): where the data pin mu_k and say
    nothing of mu_s, the nominal's knowledge of mu_s is its relation to mu_k (the table's two
    coefficients measured on one floor by one method), not its absolute value on a floor the
    data have shown to be another; at the nominal mu_k it is the nominal mu_s."""
    g = params[i].given
    assert g is not None
    keeper_value = g[2]
    target = float(params[j].neutral)

    def f(v: float) -> float:
        return float(keeper_value(v, held_v)) - target
    f_lo, f_hi = f(lo), f(hi)
    if f_lo == 0.0:
        return float(lo)
    if f_lo * f_hi > 0 or f_hi == 0.0:
        return float(lo if abs(f_lo) < abs(f_hi) else hi)
    a, b = float(lo), float(hi)
    for _ in range(60):            # bisection: the keeper is monotonic along the line
        m = 0.5 * (a + b)
        if f(m) * f_lo > 0:
            a = m
        else:
            b = m
    return 0.5 * (a + b)


def unidentified_given(params: Sequence[Param], free: Sequence[int], x: np.ndarray,
                       values: Sequence[float], r: np.ndarray,
                       expand: Callable[[np.ndarray], np.ndarray],
                       fun: Callable[[np.ndarray], np.ndarray], meta: Mapping[str, Any],
                       allowed: Mapping[int, tuple[float, float]] | None = None
                       ) -> dict[int, float]:
    """Coordinates with a ``given`` spec (effects.ParamSpec.given) that the data do not
    identify with the held quantity at its fitted value: their 1-sigma uncertainty along the
    line that keeps it (:func:`given_line`; from the residual's change over a tenth of the
    possible range, with the same autocorrelation inflation as :func:`param_std`) above
    UNIDENTIFIED of their possible range there.  Returns index -> the coordinate to pin it at:
    the nominal model's point on the line (:func:`given_neutral`), or the nearest value the
    data allow (``allowed``: index -> its profile set, :func:`profile_interval`) or, without
    one, the nearest possible value given the held one."""
    out: dict[int, float] = {}
    for i in free:
        line = given_line(params, free, i, values, meta)
        if line is None:
            continue
        j, held_v, lo, hi, coords = line
        v_i = float(values[i])
        width = hi - lo
        h = 0.1 * width
        v2 = v_i + h if v_i + h <= hi else v_i - h
        x2 = x.copy()
        x2[i], x2[j] = coords(v2)
        if not (0 <= x2[j] <= 1):
            continue
        d = (fun(x2[list(free)]) - r) / (v2 - v_i)
        dd = float(d @ d)
        std = math.sqrt(residual_variance(r, len(free)) / dd) if dd > 0 else math.inf
        if std > UNIDENTIFIED * width:
            a, b = (allowed or {}).get(i, (lo, hi))
            pin = min(max(given_neutral(params, i, j, held_v, lo, hi), a), b)
            out[i] = float(np.clip(params[i].to_x(pin), 0, 1))
    return out


# The profile of a coordinate with a ``given`` spec (mu_s with mu_k held).  With the plant's
# stick/slip its cost is a staircase: exactly flat between steps, each step a breakaway moving
# by one plant time step, so neither a gradient nor a finite difference sees it.  It is scanned
# on a grid over the coordinate's possible range at the nominal parameter's full tolerance
# width 2 tol (one point in every range of values the nominal model's own knowledge does not
# tell apart), the best point then refined by halving the step down to a fine step of a tenth of
# that, tol/5, where the grid's own quantization (standard deviation step/sqrt(12)) is a tenth
# of the tolerance's standard uncertainty tol/sqrt(3) (for mu_s, 0.0012: about the one-tick
# quantum of a breakaway under a 0.1 s torque ramp to the slip limit); the set's edges are
# located to the fine step too.
PROFILE_FINE = 10
# Confidence level of the reported profile set: two-sided where the set has two edges inside
# the possible range, one-sided where it reaches an end of it.
PROFILE_LEVEL = 0.95


def profile_steps(tol: float, lo: float, hi: float) -> tuple[float, float]:
    """(coarse, fine) grid steps of a profile over [lo, hi] (PROFILE_FINE): 2 tol and tol/5;
    without a tolerance, a twelfth of the range (the grid start's resolution, twice over)."""
    coarse = 2.0 * tol if tol > 0 else (hi - lo) / 12.0
    coarse = min(coarse, hi - lo)
    return coarse, coarse / PROFILE_FINE


def profile_scan(cost: Callable[[float], float], lo: float, hi: float, coarse: float,
                 fine: float, pts: dict[float, float] | None = None) -> dict[float, float]:
    """The cost at every point of a coarse grid over [lo, hi], then at the midpoints either
    side of the best point so far with the step halved each time, down to ``fine`` (value ->
    cost; ``pts`` already evaluated)."""
    pts = {} if pts is None else pts

    def ev(v: float) -> None:
        v = float(min(max(v, lo), hi))
        if v not in pts:
            pts[v] = cost(v)
    n = max(2, int(math.ceil((hi - lo) / coarse - 1e-9)) + 1)
    for v in np.linspace(lo, hi, n):
        ev(float(v))
    step = (hi - lo) / (n - 1)
    while step > fine:
        step *= 0.5
        best = min(pts, key=lambda v: pts[v])
        ev(best - step)
        ev(best + step)
    return pts


def profile_walk(cost: Callable[[float], float], v0: float, c0: float, lo: float, hi: float,
                 coarse: float, limit: float) -> dict[float, float]:
    """The cost from ``v0`` (cost ``c0``, a fit's solution) outwards in coarse steps on each
    side until it exceeds the lowest cost seen by ``limit`` or the range [lo, hi] ends (value
    -> cost): the profile set around a solution that a scan already placed on its minimum."""
    pts = {float(v0): float(c0)}
    for sign in (-1.0, 1.0):
        v = float(v0)
        while (v > lo) if sign < 0 else (v < hi):
            v = min(max(v + sign * coarse, lo), hi)
            pts[v] = cost(v)
            if pts[v] - min(pts.values()) > limit:
                break
    return pts


def flat_minimum(pts: Mapping[float, float]) -> tuple[float, float]:
    """The stretch of scanned values, around the lowest cost, whose cost equals it (to
    rounding): the flat step of a staircase that holds the minimum."""
    xs = sorted(pts)
    cs = np.array([pts[v] for v in xs])
    k = int(np.argmin(cs))
    eps = 1e-9 * max(1.0, abs(float(cs[k])))
    a = b = k
    while a > 0 and cs[a - 1] - cs[k] <= eps:
        a -= 1
    while b < len(xs) - 1 and cs[b + 1] - cs[k] <= eps:
        b += 1
    return xs[a], xs[b]


def profile_interval(cost: Callable[[float], float], pts: dict[float, float], lo: float,
                     hi: float, fine: float, scale: float, level: float = PROFILE_LEVEL
                     ) -> tuple[float, float, str, float]:
    """(lower edge, upper edge, kind, sigma) of the profile set {v : cost(v) - min <= q scale}
    of scanned points ``pts`` over the possible range [lo, hi], each edge located to ``fine``
    by bisection (evaluations added to ``pts``) and put midway between the last point inside
    and the first outside.  ``scale``: the residual variance times
    n/n_eff at the minimum (:func:`param_std`'s inflation), so q is chi-square with one degree
    of freedom: two-sided ``level`` (3.84 at 95 %) where the set has two edges inside the
    range; where it reaches an end of the range the data bound the value on one side only,
    and that edge is the one-sided ``level`` bound (2.71): kind ``upper_bound`` (the set
    starts at ``lo``), ``lower_bound`` (it ends at ``hi``), ``unbounded`` (both; sigma inf).
    Sigma: the set's half-width over the normal quantile of its level, at least the fine
    grid's quantization fine/sqrt(12)."""
    from scipy.stats import chi2, norm
    q2 = float(chi2.ppf(level, 1))
    q1 = float(chi2.ppf(2 * level - 1, 1))
    cmin = min(pts.values())

    def hull(q: float) -> tuple[float, float]:
        ins = [v for v, c in pts.items() if c - cmin <= q * scale]
        return min(ins), max(ins)

    def edge(q: float, upper: bool) -> float:
        a, b = hull(q)
        inner = b if upper else a
        outer_c = [v for v in pts if (v > inner if upper else v < inner)]
        if not outer_c:
            return inner
        outer = min(outer_c) if upper else max(outer_c)
        while abs(outer - inner) > fine:
            m = 0.5 * (inner + outer)
            pts[m] = cost(m)
            if pts[m] - cmin <= q * scale:
                inner = m
            else:
                outer = m
        return 0.5 * (inner + outer)   # the crossing is somewhere between: its middle

    a, b = hull(q2)
    at_lo, at_hi = a <= lo + 1e-12, b >= hi - 1e-12
    if at_lo and at_hi:
        return lo, hi, "unbounded", math.inf
    if at_lo:
        e_lo, e_hi, kind, z = lo, edge(q1, True), "upper_bound", float(norm.ppf(level))
    elif at_hi:
        e_lo, e_hi, kind, z = edge(q1, False), hi, "lower_bound", float(norm.ppf(level))
    else:
        e_lo, e_hi, kind, z = edge(q2, False), edge(q2, True), "two_sided", math.sqrt(q2)
    sigma = max((e_hi - e_lo) / (2 * z), fine / math.sqrt(12.0))
    return e_lo, e_hi, kind, sigma


def grid_start(fun: Callable[[np.ndarray], np.ndarray], base: np.ndarray, grid: int
               ) -> tuple[np.ndarray, int]:
    """Coarse multi-start: the neutral point ``base`` and a grid along each parameter; for
    2-parameter effects the second coordinate refined around the best first one.  Returns the
    best start and the number of residual evaluations."""
    k = base.size
    nfev = 0
    starts = [base]
    levels = np.linspace(0.0, 1.0, grid)
    for j in range(k):
        for lv in levels:
            s_ = base.copy()
            s_[j] = lv
            starts.append(s_)
    best, best_c = base, math.inf   # the neutral point when every start costs inf
    for s_ in starts:
        c = float(np.sum(fun(s_) ** 2))
        nfev += 1
        if c < best_c:
            best, best_c = s_, c
    x0 = best
    if k == 2:
        for lv in levels:
            s_ = x0.copy()
            s_[1] = lv
            c = float(np.sum(fun(s_) ** 2))
            nfev += 1
            if c < best_c:
                best, best_c = s_, c
        x0 = best
    return x0, nfev


def solve(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, grid: int, max_nfev: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, bool, str, int]:
    """The bounded fit from ``x0``: (x, residual, Jacobian or None, ok, message, evaluations)."""
    k = x0.size
    nfev = 0
    try:
        if k == 1:
            # one parameter: bounded Brent search around the best grid point.  Robust to
            # the cost being piecewise constant at the plant's step (delays), unlike a
            # finite-difference gradient.
            half = 1.0 / max(grid - 1, 1)
            lo, hi = max(0.0, x0[0] - half), min(1.0, x0[0] + half)
            cost: Callable[[float], float] = lambda v: float(np.sum(fun(np.array([v])) ** 2))  # noqa: E731
            sol = minimize_scalar(cost, bounds=(lo, hi), method="bounded",
                                  options={"xatol": 2e-4, "maxiter": max_nfev})
            x = np.array([sol.x if sol.fun <= cost(x0[0]) else x0[0]])
            nfev += int(sol.nfev) + 1
            r = fun(x)
            # Jacobian for the uncertainty, with a step well above the plant's time step
            hstep = 1e-2 if x[0] + 1e-2 <= 1 else -1e-2
            J = ((fun(x + hstep) - r) / hstep).reshape(-1, 1)
            nfev += 1
            ok, msg = True, "bounded scalar search"
        else:
            res = least_squares(fun, x0, bounds=(np.zeros(k), np.ones(k)), method="trf",
                                diff_step=1e-2, max_nfev=max_nfev, x_scale=1.0)
            x = res.x
            r = res.fun
            nfev += res.nfev
            J = res.jac
            ok, msg = bool(res.status >= 0), str(res.message)
    except Exception as exc:  # a simulation blew up: keep the best start, mark it
        x, r, J, ok, msg = x0, fun(x0), None, False, f"{type(exc).__name__}: {exc}"
    return x, r, J, ok, msg, nfev


# A direction of J^T J with an eigenvalue at or below NULL_RCOND of the largest (numpy's pinv
# cut-off) is one the data do not see; a coordinate with more than NULL_SHARE of its unit vector
# in such a direction has no estimate.
NULL_RCOND = 1e-15
NULL_SHARE = 1e-6


def param_std(J: np.ndarray | None, r: np.ndarray, params: Sequence[Param], free: Sequence[int],
              values: Sequence[float] | None = None) -> list[float]:
    """1-sigma uncertainty of each parameter (nan: pinned; inf: not estimated), from the
    parameter covariance inflated for correlated residuals; a coordinate's sigma times
    ``Param.span`` at its fitted value (``values``; needed for a logarithmic coordinate)."""
    k = len(free)
    std = [math.nan] * len(params)
    for i in free:
        std[i] = math.inf
    if J is not None and r.size > k:
        try:
            jtj = J.T @ J
            cov = np.linalg.pinv(jtj) * residual_variance(r, k)
            # the pseudo-inverse gives a direction the data do not see (a coordinate whose
            # replay does not change at all, e.g. a delay below the replay's time step) zero
            # variance; the data say nothing there: not estimated (inf), as without J
            lam, vec = np.linalg.eigh(jtj)
            top = max(float(lam.max()), 0.0) if lam.size else 0.0
            blind = np.abs(vec[:, lam <= NULL_RCOND * top])
            for jj, i in enumerate(free):
                if blind.size and float(blind[jj].max()) > NULL_SHARE:
                    continue
                v = params[i].neutral if values is None else values[i]
                std[i] = float(np.sqrt(max(cov[jj, jj], 0.0))) * params[i].span(v)
        except np.linalg.LinAlgError:
            pass
    return std
