"""The wheels' torque imbalance: one test of the two wheels' difference that combines its
contrasts (speeds, currents) along the signature a per-wheel torque difference leaves in them.

Under the closed loop a motor that delivers more torque than its twin is compensated: the
controller gives it less duty, the recorded speeds stay on the reference, and the duty replay,
driven by that duty through the nominal (symmetric) plant, turns that wheel slower and draws
more current in it than the recording.  So the speeds' difference (r - l)/sqrt(2) and the
currents' difference of the residuals move with opposite signs, each by about 0.3-1 noise
floor on a 10 % imbalance, and by how much follows the torque the wheels carry: large while
they accelerate, small at cruise.  The block-mean test of a constant bias
(``bias.bias_test``) takes that variation for noise (the block means of a 10 % imbalance
correlate at lag 1 by 0.8-0.9, against at most 0.2 on the nulls), so each difference on its
own stays below its threshold.

The signature of the imbalance is the replay's own response to it: the nominal plant replayed
once more with the vocabulary's per-wheel torque effect (``IMBALANCE_EFFECT``, a gain ratio
``IMBALANCE_STEP``) gives, per contrast and sample, the change s that effect makes; the
residual's contrasts r are regressed on it, r = beta * s + e, by generalized least squares
over the contrasts' block means (blocks of ``bias.PAIR_BLOCK_S`` within each replay
window, the covariance of e between the contrasts estimated from the blocks and iterated with
beta), so the contrasts are combined with their correlation and weighted by what each carries.
The blocks that hold a pinned slip (a wheel's replay uncertainty ``episodes.SLIP_UNC``: each
wheel no evidence, their difference evidence) get a covariance of their own, estimated from
them and at least the other blocks': on a hard-reversal null with the clamp off they carry most
of the signature (the replay's slips respond to a gain ratio) and several times the other
blocks' error (heldback20's truth-engine 60 s null: 15 of 53 blocks, 92 % of the information,
the speeds' error 1.15 floors RMS against 0.14), which one covariance for all blocks counted
as that many ordinary blocks; the t threshold then takes the degrees of freedom of the two
groups' estimates (Welch-Satterthwaite, ``_dof``).
The standard error of beta counts the effective number of blocks (the lag-1 autocorrelation of
the blocks' score terms, as ``fit.problem.effective_n``) and adds the bias the model's
tolerance allows in the contrasts (the covariance over the tolerance draws of their whole-run
means, ``tolerance_cov``; one set of parameters for all runs, so it does not average out).
The test is two-sided at the consistent-bias test's false-alarm rate, counted in its
Bonferroni share, and also asks the fitted imbalance to change the outputs by at least
``bias.BIAS_MIN_FLOORS``, measured as the adoption measures an update's output change (RMS of
the change of the fit's residual, ``fit.judge``): a smaller one could never be named."""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from host_tools.analyzer.locate.bias import (BIAS_ALPHA, BIAS_MIN_FLOORS, PAIR_BLOCK_S, WHEEL_PAIRS,
                                             pair_name)
from host_tools.analyzer.locate.episodes import SLIP_UNC, UNPINNED_UNC
from host_tools.analyzer.replay.channels import Channel

IMBALANCE_EFFECT = "motor_gain_asymmetry"
# The signature's step: a 10 % gain ratio, within the range where the replay's response is
# linear (the fitted beta of the tuning cases 1.05-1.15 gives their ratios to 0.005).
IMBALANCE_STEP = 1.1
IMBALANCE_NAME = "wheels_imbalance"


def contrast(a: Channel, b: Channel, fa: float, fb: float, sim_a: np.ndarray | None = None,
             sim_b: np.ndarray | None = None) -> np.ndarray:
    """(r - l)/sqrt(2) in floors: of the residuals, or (with ``sim_a``/``sim_b``, another
    replay's values at the same samples) of that replay's change from ``a``/``b``'s."""
    if sim_a is None or sim_b is None:
        d = a.resid / fa - b.resid / fb
    else:
        d = (np.asarray(sim_a, float) - a.sim) / fa - (np.asarray(sim_b, float) - b.sim) / fb
    return np.asarray(d / math.sqrt(2), float)


def _blocks(t: np.ndarray, seg: np.ndarray, ok: np.ndarray, block_s: float
            ) -> dict[tuple[int, int], np.ndarray]:
    """Sample indices of each block of ``block_s`` within each replay window, keyed (window,
    block) from the window's first sample; a short last block joins the one before it, and a
    block with fewer than 3 usable samples is left out (``bias._block_means``' rule)."""
    out: dict[tuple[int, int], np.ndarray] = {}
    for s in np.unique(seg):
        idx = np.nonzero(seg == s)[0]
        if idx.size == 0:
            continue
        ts = t[idx]
        k = np.floor((ts - ts[0]) / block_s + 1e-9).astype(int)
        if k.size and k[-1] > 0 and ts[-1] - (ts[0] + k[-1] * block_s) < 0.5 * block_s:
            k[k == k[-1]] = k[-1] - 1
        for b in np.unique(k):
            sel = idx[(k == b) & ok[idx]]
            if sel.size >= 3:
                out[(int(s), int(b))] = sel
    return out


def block_contrasts(nominal: Mapping[str, Channel], stepped: Mapping[str, Channel],
                    floors: Mapping[str, float], pairs: Sequence[tuple[str, str]],
                    block_s: float, no_evidence: float
                    ) -> tuple[list[str], np.ndarray, np.ndarray, float, int, np.ndarray]:
    """One run's blocks: (the pairs' names, the residual contrasts' block means R and the
    signature's S, blocks x pairs, NaN where a pair has no such block; the sum of the
    signature's squares over the samples used and their number, for the output size; per
    block, whether it holds a sample of a pinned slip).  Samples whose replay
    uncertainty is ``no_evidence`` or more are left out (``episodes.unpinned_episodes``);
    within a slip (a wheel's uncertainty ``SLIP_UNC`` or more) the difference stays evidence,
    as in the bias test, and its block is marked."""
    names: list[str] = []
    per: dict[tuple[int, int], dict[int, tuple[float, float]]] = {}
    in_slip: dict[tuple[int, int], bool] = {}
    ss = 0.0
    cnt = 0
    for a, b in pairs:
        ca, cb, sa, sb = nominal.get(a), nominal.get(b), stepped.get(a), stepped.get(b)
        fa, fb = floors.get(a, 0.0), floors.get(b, 0.0)
        if ca is None or cb is None or sa is None or sb is None or not (fa > 0 and fb > 0):
            continue
        if not (ca.t.size == cb.t.size == sa.t.size == sb.t.size) or np.any(ca.t != cb.t):
            continue
        j = len(names)
        names.append(pair_name(a, b))
        r = contrast(ca, cb, fa, fb)
        s = contrast(ca, cb, fa, fb, sa.sim, sb.sim)
        ok = np.isfinite(r) & np.isfinite(s)
        slip = np.zeros(r.size, bool)
        for c in (ca, cb):
            if c.unc is not None:
                ok &= c.unc < no_evidence
                slip |= c.unc >= SLIP_UNC
        ss += float(np.sum(s[ok] ** 2))
        cnt += int(np.sum(ok))
        seg = ca.seg if ca.seg is not None else np.zeros(ca.t.size, int)
        for key, sel in _blocks(np.asarray(ca.t, float), seg, ok, block_s).items():
            per.setdefault(key, {})[j] = (float(np.mean(r[sel])), float(np.mean(s[sel])))
            in_slip[key] = in_slip.get(key, False) or bool(np.any(slip[sel]))
    R = np.full((len(per), len(names)), np.nan)
    S = np.full((len(per), len(names)), np.nan)
    keys = sorted(per)
    for i, key in enumerate(keys):
        for j, (rv, sv) in per[key].items():
            R[i, j], S[i, j] = rv, sv
    return names, R, S, ss, cnt, np.array([in_slip[k] for k in keys], bool)


def tolerance_cov(prep: Any, floors: Mapping[str, float], pairs: Sequence[tuple[str, str]]
                  ) -> dict[tuple[str, str], float]:
    """The covariance over the tolerance draws (``prep.tolerance_draw_means``) of the pairs'
    whole-run contrasts (mean_r/floor_r - mean_l/floor_l)/sqrt(2), keyed by pair names."""
    draws = getattr(prep, "tolerance_draw_means", None) or {}
    d: dict[str, np.ndarray] = {}
    for a, b in pairs:
        fa, fb = floors.get(a, 0.0), floors.get(b, 0.0)
        if a in draws and b in draws and fa > 0 and fb > 0 and len(draws[a]) == len(draws[b]) > 1:
            diff = np.asarray(draws[a]) / fa - np.asarray(draws[b]) / fb
            d[pair_name(a, b)] = diff / math.sqrt(2)
    out = {}
    for p in d:
        for q in d:
            if d[p].size == d[q].size:
                out[(p, q)] = float(np.mean((d[p] - d[p].mean()) * (d[q] - d[q].mean())))
    return out


def _lag1(x: Sequence[np.ndarray]) -> float:
    """Lag-1 autocorrelation of consecutive values, pooled over the given sequences (runs),
    clipped to [0, 0.995]."""
    num = den = 0.0
    allv = np.concatenate([np.asarray(v, float) for v in x]) if x else np.zeros(0)
    if allv.size < 3:
        return 0.0
    m = float(allv.mean())
    for v in x:
        v = np.asarray(v, float) - m
        num += float(np.sum(v[:-1] * v[1:]))
        den += float(np.sum(v * v))
    rho = num / den if den > 0 else 0.0
    return min(max(rho, 0.0), 0.995)


def _block_cov(e: np.ndarray, have: np.ndarray, rows: np.ndarray,
               floor: np.ndarray | None = None) -> np.ndarray:
    """The covariance between the columns of the errors ``e`` over the blocks ``rows`` (a
    column with fewer than two such blocks takes its variance over all blocks); each variance
    at least ``floor``'s diagonal when given."""
    p = e.shape[1]
    var = np.array([np.nanvar(e[rows, j], ddof=1) if np.sum(have[rows, j]) > 1 else
                    (np.nanvar(e[:, j], ddof=1) if np.sum(have[:, j]) > 1 else 1.0)
                    for j in range(p)])
    var = np.where(np.isfinite(var) & (var > 0), var, 1.0)
    if floor is not None:
        var = np.maximum(var, np.diag(floor))
    cov = np.diag(var)
    for j in range(p):
        for l in range(j + 1, p):
            m = have[:, j] & have[:, l] & rows
            if m.sum() > 3:
                with np.errstate(invalid="ignore", divide="ignore"):  # a constant column: 0
                    c = float(np.corrcoef(e[m, j], e[m, l])[0, 1])
                c = min(max(c if math.isfinite(c) else 0.0, -0.95), 0.95)
                cov[j, l] = cov[l, j] = c * math.sqrt(var[j] * var[l])
    return cov


def _gls(R: np.ndarray, S: np.ndarray, slip: np.ndarray | None = None, rounds: int = 4
         ) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """beta of R = beta * S + e by generalized least squares over the blocks (rows), the
    covariance of e between the columns estimated from the blocks and iterated with beta;
    a block uses the columns it has.  The blocks that hold a pinned slip (``slip``) have a
    covariance of their own, estimated from them, its variances at least the other blocks'
    (the slip's own error adds to theirs).  Returns (beta, the information sum s'W s, the
    covariance of the blocks without a slip, each block's score term s'W e and information
    term s'W s, the gradient sum of W s per column)."""
    n, p = R.shape
    have = np.isfinite(R) & np.isfinite(S)
    slip = np.zeros(n, bool) if slip is None else np.asarray(slip, bool)
    cov = cov_slip = np.eye(p)
    beta, info = 0.0, 0.0
    for _ in range(rounds):
        num = info = 0.0
        for i in range(n):
            k = have[i]
            if not k.any():
                continue
            w = np.linalg.inv((cov_slip if slip[i] else cov)[np.ix_(k, k)])
            num += float(S[i, k] @ w @ R[i, k])
            info += float(S[i, k] @ w @ S[i, k])
        if not info > 0:
            return 0.0, 0.0, cov, np.zeros(0), np.zeros(0), np.zeros(p)
        beta = num / info
        e = np.where(have, R - beta * S, np.nan)
        if slip.any() and not slip.all():
            cov = _block_cov(e, have, ~slip)
            cov_slip = _block_cov(e, have, slip, floor=cov)
        else:
            cov = cov_slip = _block_cov(e, have, np.ones(n, bool))
    score = np.zeros(n)
    infos = np.zeros(n)
    grad = np.zeros(p)
    e = R - beta * S
    for i in range(n):
        k = have[i]
        if not k.any():
            continue
        w = np.linalg.inv((cov_slip if slip[i] else cov)[np.ix_(k, k)])
        score[i] = float(S[i, k] @ w @ e[i, k])
        infos[i] = float(S[i, k] @ w @ S[i, k])
        grad[k] += w @ S[i, k]
    return beta, info, cov, score, infos, grad


def _dof(infos: np.ndarray, slip: np.ndarray, inflate: float) -> float:
    """The degrees of freedom of beta's standard error (Welch-Satterthwaite): beta is the
    information-weighted mean of each group's own (the blocks with and without a pinned slip,
    each group's covariance estimated from its n_g blocks, n_g (1 - rho)/(1 + rho) effective,
    with n_g,eff - 1 degrees of freedom), so the test's t counts I^2 / sum(I_g^2 / dof_g):
    n_eff - 1 with one group, and about the slips' own count where they carry the signature."""
    total = float(np.sum(infos))
    den = 0.0
    groups = [g for g in (False, True) if np.any(slip == g)]
    for g in groups:
        m = slip == g
        dof_g = max(float(np.sum(m)) / inflate, 2.0) - 1.0
        den += float(np.sum(infos[m])) ** 2 / dof_g
    return total ** 2 / den if den > 0 else max(len(infos) / inflate, 2.0) - 1.0


def imbalance_test(nominal: Sequence[Mapping[str, Channel]],
                   stepped: Sequence[Mapping[str, Channel] | None],
                   floors: Mapping[str, float], n_tests: int, alpha: float | None = None,
                   min_floors: float | None = None,
                   allowed: Sequence[Mapping[tuple[str, str], float] | None] | None = None,
                   pairs: Sequence[tuple[str, str]] | None = None,
                   step: float = IMBALANCE_STEP,
                   output_of: Callable[[float], float] | None = None
                   ) -> dict[str, Any] | None:
    """The wheels' torque imbalance test (module docstring).  ``nominal``: per run, the nominal
    replay's channels; ``stepped``: per run, the replay with ``IMBALANCE_EFFECT`` at ``step``
    (None: that run is left out); ``n_tests``: the tests sharing the false-alarm rate
    ``alpha`` (default ``BIAS_ALPHA``) per analysis, this one included; ``allowed``: per
    run, ``tolerance_cov``; ``output_of``: the output change (the adoption's output size,
    ``fit.judge``) of the imbalance at a given ratio, default |beta| times the contrasts' RMS
    change at the step.
    Returns None without two blocks to test, else the figures: ``ratio`` (the gain ratio the
    regression puts on the imbalance), ``t``, ``t_threshold``, ``blocks``, ``slip_blocks``
    (those holding a pinned slip), ``n_eff`` (blocks corrected for their autocorrelation), ``output_floors`` (the output change of the fitted
    imbalance, ``output_of``), ``tolerance_se`` (the standard error the
    tolerance adds to the ratio), ``correlation`` (of the
    contrasts' block errors), ``contrasts`` and ``significant``."""
    from scipy import stats
    alpha = BIAS_ALPHA if alpha is None else alpha
    min_floors = BIAS_MIN_FLOORS if min_floors is None else min_floors
    pairs = WHEEL_PAIRS if pairs is None else pairs
    names_all = [pair_name(a, b) for a, b in pairs]
    rows_R: list[np.ndarray] = []
    rows_S: list[np.ndarray] = []
    slip_of: list[np.ndarray] = []
    run_of: list[int] = []
    ss = 0.0
    n_samples = 0
    A = np.zeros((len(names_all), len(names_all)))
    for i, (nom, stp) in enumerate(zip(nominal, stepped)):
        if stp is None:
            continue
        names, R, S, s2, cnt, in_slip = block_contrasts(nom, stp, floors, pairs, PAIR_BLOCK_S,
                                                        UNPINNED_UNC)
        if not names or R.shape[0] == 0:
            continue
        cols = [names_all.index(n) for n in names]
        Rf = np.full((R.shape[0], len(names_all)), np.nan)
        Sf = np.full((R.shape[0], len(names_all)), np.nan)
        Rf[:, cols], Sf[:, cols] = R, S
        rows_R.append(Rf)
        rows_S.append(Sf)
        slip_of.append(in_slip)
        run_of += [i] * R.shape[0]
        ss += s2
        n_samples += cnt
        tol = (allowed[i] if allowed is not None and i < len(allowed) else None) or {}
        for (p, q), v in tol.items():
            if p in names_all and q in names_all:
                A[names_all.index(p), names_all.index(q)] += v * R.shape[0]
    if not rows_R:
        return None
    R = np.vstack(rows_R)
    S = np.vstack(rows_S)
    used = [j for j in range(len(names_all)) if np.any(np.isfinite(R[:, j]))]
    R, S = R[:, used], S[:, used]
    A = A[np.ix_(used, used)] / R.shape[0]
    n = int(np.sum(np.any(np.isfinite(R), axis=1)))
    if n < 3:
        return None
    slip = np.concatenate(slip_of)
    beta, info, cov, score, infos, grad = _gls(R, S, slip)
    if not info > 0:
        return None
    runs_arr = np.asarray(run_of)
    rho = _lag1([score[runs_arr == i] for i in np.unique(runs_arr)])
    inflate = (1 + rho) / (1 - rho)
    n_eff = max(n / inflate, 2.0)
    var_tol = float(grad @ A @ grad) / info ** 2
    se = math.sqrt(inflate / info + var_tol)
    tstat = beta / se if se > 0 else 0.0
    thr = float(stats.t.ppf(1 - alpha / (2 * max(n_tests, 1)), _dof(infos, slip, inflate)))
    # the output change at the fitted beta: by default the contrasts' RMS change over the
    # samples the blocks hold
    ratio = 1.0 + (step - 1.0) * beta
    if output_of is not None:
        out_rms = output_of(ratio)
    else:
        out_rms = abs(beta) * math.sqrt(ss / n_samples) if n_samples else 0.0
    corr = (float(cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1])) if cov.shape[0] > 1 else 0.0)
    return {"ratio": ratio, "t": tstat, "t_threshold": thr, "blocks": n,
            "slip_blocks": int(np.sum(np.concatenate(slip_of))), "n_eff": n_eff, "block_s": PAIR_BLOCK_S, "output_floors": out_rms,
            "tolerance_se": math.sqrt(var_tol) * (step - 1.0), "correlation": corr,
            "contrasts": [names_all[j] for j in used],
            "significant": bool(abs(tstat) > thr and out_rms >= min_floors)}


def imbalance_of(problem: Any, nominal: Sequence[Mapping[str, Channel]], n_tests: int
                 ) -> dict[str, Any] | None:
    """:func:`imbalance_test` on the fit problem's runs: the signature from one more replay of
    every run (all its windows) with ``IMBALANCE_EFFECT`` at ``IMBALANCE_STEP`` (kept in the
    problem's replay cache, where the fits may ask for it again), the tolerance from each
    prepared run's draws.  None when the vocabulary has no such effect."""
    spec = problem.vocab.get(IMBALANCE_EFFECT)
    if not spec:
        return None
    step = {next(iter(spec)): IMBALANCE_STEP}
    runs = list(range(len(problem.preps)))
    stepped = problem.sim_channels({IMBALANCE_EFFECT: step}, runs, full=True, fit_only=True)
    allowed = [tolerance_cov(p, problem.floors, WHEEL_PAIRS) for p in problem.preps]
    # the output change as the adoption measures it (``Problem.output_change``, ``fit.judge``),
    # at the ratio found, so that what is detected can be adopted
    name = next(iter(spec))

    def output_of(ratio: float) -> float:
        if not ratio > 0:
            return 0.0
        return float(problem.output_change({}, {IMBALANCE_EFFECT: {name: ratio}}, runs))
    return imbalance_test(nominal, stepped, problem.floors, n_tests, allowed=allowed,
                          output_of=output_of)
