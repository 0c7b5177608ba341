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


def effective_n(r: np.ndarray) -> float:
    """Number of independent samples in a residual with AR(1)-like correlation."""
    r = np.asarray(r, float)
    if r.size < 3:
        return float(r.size)
    a, b = r[:-1] - r.mean(), r[1:] - r.mean()
    den = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    rho = 0.0 if den == 0 else float(np.sum(a * b) / den)
    rho = min(max(rho, 0.0), 0.995)
    return max(r.size * (1 - rho) / (1 + rho), 2.0)


def unidentified_given(params: Sequence[Param], free: Sequence[int], x: np.ndarray,
                       values: Sequence[float], r: np.ndarray,
                       expand: Callable[[np.ndarray], np.ndarray],
                       fun: Callable[[np.ndarray], np.ndarray], meta: Mapping[str, Any]
                       ) -> dict[int, float]:
    """Coordinates with a ``given`` spec (effects.ParamSpec.given) that the data do not
    identify with the held quantity at its fitted value: their 1-sigma uncertainty along the
    line that keeps it (from the residual's change over a tenth of the possible range, with the
    same autocorrelation inflation as :func:`param_std`) above UNIDENTIFIED of their possible
    range there.  Returns index -> the coordinate to pin it at: its neutral value, or the
    nearest possible value given the held one."""
    out: dict[int, float] = {}
    names = [(p.effect, p.name) for p in params]
    for i in free:
        g = params[i].given
        if g is None:
            continue
        held, keeper, keeper_value, possible = g
        try:
            j = names.index((params[i].effect, keeper))
        except ValueError:
            continue
        if j not in free:
            continue
        v_i, v_j = float(values[i]), float(values[j])
        held_v = v_i * v_j if keeper == f"{held}_over_{params[i].name}" else None
        if held_v is None:
            continue
        lo, hi = possible(held_v, meta)
        width = hi - lo
        if not width > 0:
            continue
        h = 0.1 * width
        v2 = v_i + h if v_i + h <= hi else v_i - h
        x2 = x.copy()
        x2[i] = params[i].to_x(v2)
        x2[j] = params[j].to_x(keeper_value(v2, held_v))
        if not (0 <= x2[j] <= 1):
            continue
        d = (fun(x2[list(free)]) - r) / (v2 - v_i)
        dd = float(d @ d)
        s2 = float(np.sum(r ** 2)) / max(r.size - len(free), 1)
        infl = r.size / max(effective_n(r), 1.0)
        std = math.sqrt(s2 * infl / dd) if dd > 0 else math.inf
        if std > UNIDENTIFIED * width:
            pin = min(max(params[i].neutral, lo), hi)
            out[i] = float(np.clip(params[i].to_x(pin), 0, 1))
    return out


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


def param_std(J: np.ndarray | None, r: np.ndarray, params: Sequence[Param], free: Sequence[int]) -> list[float]:
    """1-sigma uncertainty of each parameter (nan: pinned; inf: not estimated), from the
    parameter covariance inflated for correlated residuals."""
    k = len(free)
    std = [math.nan] * len(params)
    for i in free:
        std[i] = math.inf
    if J is not None and r.size > k:
        n_eff = effective_n(r)
        s2 = float(np.sum(r ** 2)) / max(r.size - k, 1)
        try:
            cov = np.linalg.pinv(J.T @ J) * s2 * (r.size / max(n_eff, 1.0))
            for jj, i in enumerate(free):
                std[i] = float(np.sqrt(max(cov[jj, jj], 0.0))) * (params[i].hi - params[i].lo)
        except np.linalg.LinAlgError:
            pass
    return std
