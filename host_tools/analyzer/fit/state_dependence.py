"""State dependence of the selected model: a vocabulary effect's parameter is a constant of the
robot, so after the update the residual must not follow the selected parameters' own output
sensitivities scaled by how hard the drive is loaded or by how much charge it has drawn.  A
parameter that moves with the load (a supply whose voltage falls with the total armature
current through an internal resistance and with the charge drawn, standing in as a driver
drop, a deadband or a back-EMF constant) is physics outside the vocabulary however well the
constant stand-in fits the whole: the verdict is then ``unexplained``.

The test is the linearized form of "fit the parameter on loaded and on unloaded samples apart"
(a Chow test on the fit's Jacobian), which the split of each run into halves
(:mod:`.invariance`) hardly makes: a half holds loaded (accelerating) and unloaded (cruising)
samples alike.  At the whole fit's coordinates x the normalized residual
r of every fit channel (the fit's windows) and its sensitivity J_k = dr/dx_k to each free
coordinate (a forward difference of STEP_X of the coordinate's range: one more replay each)
are regressed per run as

    r = J a + (J * z_load) b + (J * z_charge) c + e,

z_load the drive's total measured current |i_r| + |i_l| (A), z_charge its integral over the run
(A s), each centred on the run; a parameter of the selected model that varies as
p + b z_load + c z_charge leaves exactly this residual.  Each coefficient's standard error is
Newey-West (the residual of a windowed replay is smooth: lags up to HAC_S seconds, per fit
channel series).  The runs are replicates of one robot: per coefficient their weighted mean
against its standard error, scaled up by the runs' scatter beyond their errors (Birge ratio,
as the invariance check pairs its halves): an inexact model (another engine) lets the
coefficient move with each run's regime, differently from run to run, while a sagging supply
moves every run alike.  |z| is significant at STATE_ALPHA per analysis, two-sided,
Bonferroni over the coefficients tested.  Each run is regressed on the coordinates its own
data resolve (:func:`resolved`, the fit's identification rule) and a coordinate's slopes are
paired over the runs that resolve it; two coordinates the outputs do not tell apart would
otherwise leave their difference to the noise (:func:`regress`).  As every update, the
state-dependent model must also change the outputs by at least STATE_MIN_OUTPUT noise floors
(the pooled regression's b, c terms, RMS per fit channel, the largest).

Only the recorded currents say how hard the supply is loaded: without ``current_r_a`` and
``current_l_a`` in every run the check is not made (None)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from scipy import stats

from host_tools.analyzer.fit.invariance import INVARIANCE_ALPHA, INVARIANCE_MIN_OUTPUT
from host_tools.analyzer.fit.invariance import _weighted as weighted
from host_tools.analyzer.fit.params import effects_dict, params_for
from host_tools.analyzer.fit.solver import NULL_SHARE, UNIDENTIFIED, residual_variance
from host_tools.analyzer.signals import round_sig

if TYPE_CHECKING:
    from host_tools.analyzer.fit.judge import Candidate
    from host_tools.analyzer.fit.problem import Problem

STEP_X = 1e-3            # forward-difference step of a fit coordinate (of its range)
HAC_S = 0.5              # Newey-West lags, in seconds of each channel's samples
COVARIATES = ("load_a", "charge_as")
STATE_ALPHA = INVARIANCE_ALPHA            # the invariance check's rate
STATE_MIN_OUTPUT = INVARIANCE_MIN_OUTPUT  # and its smallest output change of an update


@dataclass
class StateDependence:
    """The selected parameters' dependence on the drive's load and charge drawn."""
    coefs: list[dict[str, Any]] = field(default_factory=list)
    z_threshold: float = math.inf
    output_floors: float = 0.0
    found: bool = False

    def report(self) -> dict[str, Any]:
        return {"covariates": "load_a: total measured current |i_r|+|i_l| (A); charge_as: its "
                              "integral over the run (A s); each centred per run; slope: the "
                              "parameter's change per unit of the covariate",
                "z_threshold": round(self.z_threshold, 3),
                "output_change_noise_floors": round_sig(self.output_floors, 3),
                "found": self.found, "coefficients": self.coefs}

    def note(self) -> str:
        worst = max(self.coefs, key=lambda c: abs(c["z"]))
        return (f"the selected model's {worst['effect']}.{worst['param']} varies with the "
                f"drive's {'total current' if worst['covariate'] == 'load_a' else 'charge drawn'}"
                f" (z {worst['z']:+.2f} beyond {self.z_threshold:.2f} over "
                f"{worst['runs']} runs; the outputs move by {self.output_floors:.2f} noise "
                "floors with it): a vocabulary effect's parameter is constant, so one that "
                "follows the load stands for physics outside the vocabulary")


def _covariates(prep: Any) -> np.ndarray | None:
    """(t, load, charge) of a run from its recorded currents; None without them."""
    tel = prep.run.telemetry
    if "current_r_a" not in tel or "current_l_a" not in tel:
        return None
    t = np.asarray(tel["t_s"], float)
    load = np.abs(np.asarray(tel["current_r_a"], float)) + np.abs(np.asarray(tel["current_l_a"],
                                                                             float))
    ok = np.isfinite(load)
    if ok.sum() < 3:
        return None
    t, load = t[ok], load[ok]
    charge = np.concatenate([[0.0], np.cumsum(0.5 * (load[1:] + load[:-1]) * np.diff(t))])
    return np.vstack([t, load, charge])


def _series(problem: Problem, effects: Any, runs: Sequence[int]
            ) -> list[tuple[int, str, np.ndarray, np.ndarray]]:
    """(run, channel, t, normalized residual) of every fit channel on the fit's windows."""
    out = []
    for i, chans in zip(runs, problem.sim_channels(effects, runs, fit_only=True)):
        for c in problem.fit_channels:
            ch = chans.get(c)
            if ch is not None and ch.t.size:
                out.append((i, c, ch.t, ch.deflated(problem.floors[c]) / problem.floors[c]))
    return out


def newey_west(X: np.ndarray, e: np.ndarray, groups: np.ndarray, lags: dict[int, int],
               bread: np.ndarray) -> np.ndarray:
    """Covariance of the OLS coefficients of ``X`` with residual ``e``: Newey-West (Bartlett
    weights) within each group (a channel's series) up to ``lags[group]`` samples, groups
    independent.  ``bread``: the (X'X)^+ of the solve, at the solve's own rank
    (:func:`ols_same_rank`)."""
    meat = np.zeros((X.shape[1], X.shape[1]))
    for g in np.unique(groups):
        s = X[groups == g] * e[groups == g][:, None]
        meat += s.T @ s
        L = min(lags.get(int(g), 0), s.shape[0] - 1)
        for lag in range(1, L + 1):
            G = s[lag:].T @ s[:-lag]
            meat += (1.0 - lag / (L + 1.0)) * (G + G.T)
    return np.asarray(bread @ meat @ bread)


def resolved(J: np.ndarray, r: np.ndarray) -> list[int]:
    """The columns (fit coordinates) of the sensitivity ``J`` that the residual ``r`` resolves
    one by one: each one's 1-sigma uncertainty (the fit's own, :func:`solver.param_std`: the
    residual's variance over its degrees of freedom, inflated for its autocorrelation, through
    (J'J)^+ of the columns kept) at most UNIDENTIFIED of its range (1 in a fit coordinate), as
    the fit calls a coordinate identified.  Backwards: the least resolved column is dropped and
    the rest judged again, until every one kept is resolved.  Two coordinates that move the
    outputs alike (mu_k/mu_s and Stribeck's mu_k0 both setting the kinetic level; a coordinate
    whose replay does not move at all under the step, on a stick/slip staircase) are not
    resolved apart: one of them stands for their common direction."""
    keep = list(range(J.shape[1]))
    while keep:
        _, S, Vt = np.linalg.svd(J[:, keep], full_matrices=False)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(S > 0, 1.0 / np.where(S > 0, S, 1.0) ** 2, math.inf)
            var = np.array([float(np.sum(np.where(Vt[:, j] != 0, Vt[:, j] ** 2 * inv, 0.0)))
                            for j in range(len(keep))])
        std = np.sqrt(var * residual_variance(r, len(keep)))
        worst = int(np.argmax(std))
        if std[worst] <= UNIDENTIFIED:
            break
        keep.pop(worst)
    return keep


def ols_same_rank(X: np.ndarray, y: np.ndarray, groups: np.ndarray, lags: dict[int, int]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(coefficients, Newey-West standard errors) of ``y`` on ``X``, the solve and the bread of
    the covariance from one SVD of X at one rank (numpy lstsq's cut: singular values above
    eps max(n, p) of the largest).  A coefficient with more than NULL_SHARE of its unit vector
    in a direction below the cut has no estimate (inf): the data do not see it."""
    U, S, Vt = np.linalg.svd(X, full_matrices=False)
    ok = S > (S[0] if S.size else 0.0) * np.finfo(float).eps * max(X.shape)
    Vk = Vt[ok].T
    beta = Vk @ ((U[:, ok].T @ y) / S[ok])
    V = newey_west(X, y - X @ beta, groups, lags, bread=(Vk / S[ok] ** 2) @ Vk.T)
    se = np.sqrt(np.maximum(np.diag(V), 0.0))
    if not np.all(ok):
        se[np.abs(Vt[~ok]).max(axis=0) > NULL_SHARE] = math.inf
    return beta, se


def regress(base: Sequence[tuple[int, str, np.ndarray, np.ndarray]],
            sens: Sequence[Sequence[np.ndarray]], cov: Sequence[np.ndarray | None],
            names: Sequence[tuple[str, str]], spans: Sequence[float]
            ) -> tuple[list[dict[str, Any]], float]:
    """The regressions of the module docstring: (one entry per coordinate and covariate with a
    run that resolves it, the pooled regression's load and charge terms' output change, RMS
    per fit channel, the largest).  ``base``: (run, channel, t, normalized residual) per fit
    series; ``sens[k][g]``: series g's sensitivity to coordinate k; ``cov[run]``: (t, load,
    charge); ``names``/``spans``: each coordinate's (effect, parameter) and parameter range.

    Each run is regressed on the coordinates its own data resolve (:func:`resolved`), the
    others held at the whole fit's values; a coordinate's load and charge slopes are then
    pooled over the runs that resolve it.  Where two coordinates are not resolved apart the
    kept one's slope is their common direction's: regressed on both, the solve finds the
    difference of two columns equal up to a 1e-8 of their size, which noise sets at will, and
    a covariance with another rank (X'X pseudo-inverted at 1e-15 of its largest eigenvalue
    drops the direction lstsq keeps) gave it a tiny error (hb25_mj_friction_coefficient: Birge
    ratios up to 5e10, |z| to 1.2e4)."""
    nk, nz = len(names), len(COVARIATES)
    rows: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, str, int]]] = {}
    for gi, (i, c, t, r) in enumerate(base):
        cv = cov[i]
        assert cv is not None
        z = np.column_stack([np.interp(t, cv[0], cv[1]), np.interp(t, cv[0], cv[2])])
        J = np.column_stack([s[gi] for s in sens])
        ok = np.isfinite(r) & np.all(np.isfinite(J), axis=1)
        if ok.sum() >= 3:
            rows.setdefault(i, []).append((r[ok], J[ok], z[ok], c, gi))
    est: list[tuple[dict[int, float], dict[int, float]]] = []
    pooled_y, pooled_j, pooled_z, pooled_c, pooled_g = [], [], [], [], []
    lags: dict[int, int] = {}
    for i, parts in rows.items():
        y = np.concatenate([p[0] for p in parts])
        J = np.vstack([p[1] for p in parts])
        z = np.vstack([p[2] for p in parts])
        z = z - z.mean(axis=0)
        groups = np.concatenate([np.full(p[0].size, p[4]) for p in parts])
        lags.update({p[4]: int(round(HAC_S / max(float(np.median(np.diff(base[p[4]][2]))), 1e-6)))
                     for p in parts})
        pooled_y.append(y)
        pooled_j.append(J)
        pooled_z.append(z)
        pooled_g.append(groups)
        pooled_c.append(np.concatenate([np.full(p[0].size, p[3]) for p in parts]))
        keep = resolved(J, y)
        X = _design(J[:, keep], z)
        if not keep or y.size <= 2 * X.shape[1]:
            continue
        beta, se = ols_same_rank(X, y, groups, lags)
        m = len(keep)
        b_run: dict[int, float] = {}
        s_run: dict[int, float] = {}
        for j in range(nz):
            for q, k in enumerate(keep):
                col = m * (1 + j) + q
                if math.isfinite(se[col]) and se[col] > 0:
                    b_run[j * nk + k], s_run[j * nk + k] = float(beta[col]), float(se[col])
        est.append((b_run, s_run))
    coefs: list[dict[str, Any]] = []
    for jk in range(nz * nk):
        have = [(b[jk], s[jk]) for b, s in est if jk in b]
        if not have:
            continue
        mean, se_m, birge = weighted([b for b, _ in have], [s for _, s in have])
        effect, name = names[jk % nk]
        span = spans[jk % nk]   # coordinate -> parameter
        coefs.append({"effect": effect, "param": name, "covariate": COVARIATES[jk // nk],
                      "runs": len(have), "unresolved_runs": len(rows) - len(have),
                      "slope": round_sig(mean * span, 4),
                      "slope_std": round_sig(se_m * birge * span, 3),
                      "birge_ratio": round(birge, 3), "z": round(mean / (se_m * birge), 3)})
    if not coefs:
        return coefs, 0.0
    # the output change: the pooled regression's load and charge terms, per channel, on the
    # coordinates the pooled data resolve
    y, J, ch = np.concatenate(pooled_y), np.vstack(pooled_j), np.concatenate(pooled_c)
    keep = resolved(J, y)
    X = _design(J[:, keep], np.vstack(pooled_z))
    beta, _ = ols_same_rank(X, y, np.concatenate(pooled_g), lags)
    part = X[:, len(keep):] @ beta[len(keep):]
    size = max(float(np.sqrt(np.mean(part[ch == c] ** 2))) for c in np.unique(ch))
    return coefs, size


def _design(J: np.ndarray, z: np.ndarray) -> np.ndarray:
    """[J, J z_load, J z_charge]."""
    return np.column_stack([J] + [J * z[:, j:j + 1] for j in range(z.shape[1])])


def state_dependence_check(problem: Problem, chosen: Candidate) -> StateDependence | None:
    """The test of the module docstring for the selected candidate ``chosen``; None when a run
    has no current channels or no coordinate is free."""
    runs = list(range(len(problem.preps)))
    cov = [_covariates(p) for p in problem.preps]
    if any(c is None for c in cov):
        return None
    fit = chosen.fit
    params = params_for(chosen.effects, problem.meta, problem.vocab)
    # the vocabulary's coordinates: a fit's nuisance (the load transfer's spin share) is held
    # where it was fitted, as the time-invariance check holds a shape coordinate
    free = [k for k in range(len(params)) if k not in fit.fixed and params[k].nuisance is None]
    if not free:
        return None
    x0 = np.asarray(fit.x, float)
    base = _series(problem, fit.params, runs)
    sens = []
    for k in free:
        x = x0.copy()
        x[k] = x[k] + STEP_X if x[k] + STEP_X <= 1.0 else x[k] - STEP_X
        moved = _series(problem, effects_dict(params, [p.from_x(v) for p, v in zip(params, x)],
                                              fit.fixed), runs)
        sens.append([(m[3] - b[3]) / (x[k] - x0[k]) for b, m in zip(base, moved)])
    coefs, size = regress(base, sens, cov, [fit.coords[k] for k in free],
                          [params[k].hi - params[k].lo for k in free])
    if not coefs:
        return None
    zt = float(stats.norm.ppf(1.0 - STATE_ALPHA / (2 * len(coefs))))
    found = any(abs(c["z"]) > zt for c in coefs) and size >= STATE_MIN_OUTPUT
    return StateDependence(coefs, zt, size, found)
