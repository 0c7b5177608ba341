"""A fitted candidate effect and its judgement: BIC, held-out error, size, physical
possibility, per-channel veto."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from host_tools.analyzer import effects as fx
from host_tools.analyzer.fit.params import FitResult, params_for
from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.fit.solver import effective_n, lag1_correlation
from host_tools.analyzer.replay.channels import DERIVED


def delta_bic(rss1: float, rss0: float, n_eff: float, k: int) -> float:
    """BIC(model) - BIC(nominal) with Gaussian errors of unknown variance over n_eff samples."""
    if rss0 <= 0 or rss1 <= 0:
        return 0.0
    return float(n_eff * math.log(rss1 / rss0) + k * math.log(max(n_eff, 2.0)))


@dataclass
class Candidate:
    effects: list[str]
    fit: FitResult
    delta_bic: float
    heldout_before: float        # normalized held-out RMSE, nominal
    heldout_after: float
    heldout_channels_before: dict[str, float]
    heldout_channels_after: dict[str, float]
    fold_values: list[list[float]]
    output_size: float           # RMS change of the fit channels, in noise floors
    checks: dict[str, bool] = field(default_factory=dict)
    reasons: list[str] = field(default_factory=list)
    heldout_per_channel: dict[str, dict[str, Any]] = field(default_factory=dict)
    # per channel: held-out residuals (unit of the channel) before and after, sample by sample
    heldout_pairs: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    # per channel: the reference replay's uncertainty (input spread and tolerance ensemble,
    # ``Channel.unc``; unit of the channel) at the same held-out samples (HELDOUT_RULE)
    heldout_spread: dict[str, np.ndarray] = field(default_factory=dict)
    recorder_notes: list[str] = field(default_factory=list)
    # all fit channels pooled, in noise floors: held-out residuals before and after, sample by
    # sample (the paired adoption test); None when not kept
    heldout_pooled: tuple[np.ndarray, np.ndarray] | None = None
    # the pooled samples' segments (one fit channel, or one slip difference, of one held-out
    # run), their lengths in order; None when the segments of before and after differ
    heldout_segments: np.ndarray | None = None
    heldout_z: float = math.nan   # the paired test's z of the held-out improvement

    @property
    def accepted(self) -> bool:
        return bool(self.checks) and all(self.checks.values())

    @property
    def name(self) -> str:
        return "+".join(self.effects)


# Held-out folds: each run is held out once.  Up to HELDOUT_FOLDS runs, one run at a time (leave
# one run out); with more runs, HELDOUT_FOLDS folds of consecutive runs (k-fold), so that the
# refits of the folds cost about HELDOUT_FOLDS full fits however many runs there are (leaving
# out each of N runs costs N fits of N - 1 runs: quadratic in N).  A fold then leaves out the
# same share of the data as one run of HELDOUT_FOLDS does, so the folds' spread (``judge``'s
# stability test) is that of the run counts the rules were settled on, not narrower.
HELDOUT_FOLDS = 8


def heldout_folds(n_runs: int) -> list[tuple[list[int], list[int], str, str]]:
    """(training runs, held-out runs, training part, held-out part) of each fold: leave one run
    out up to HELDOUT_FOLDS runs, HELDOUT_FOLDS folds of consecutive runs beyond, a time split
    of a single run (fitted on its early part, held out on its late part)."""
    runs = list(range(n_runs))
    if n_runs < 2:
        return [(runs, runs, "early", "late")]
    groups = [[int(i) for i in g] for g in np.array_split(runs, min(n_runs, HELDOUT_FOLDS))]
    return [([j for j in runs if j not in held], g, "all", "all")
            for g, held in ((g, set(g)) for g in groups)]


def heldout_method(n_runs: int, split_frac: float) -> str:
    """The report's words for :func:`heldout_folds`."""
    if n_runs < 2:
        return f"time split at {split_frac:.0%} of the run"
    if n_runs <= HELDOUT_FOLDS:
        return "leave one run out"
    return f"{HELDOUT_FOLDS} folds of consecutive runs, each held out once"


def evaluate_candidate(problem: Problem, names: Sequence[str],
                       base: Mapping[str, Mapping[str, float]] | None = None,
                       x0: np.ndarray | None = None, ref_rss: float | None = None,
                       ref_effects: Mapping[str, Mapping[str, float]] | None = None) -> Candidate:
    """Fit ``names`` on all runs, then held out (:func:`heldout_folds`): leave one run out (up
    to HELDOUT_FOLDS runs), HELDOUT_FOLDS folds of runs (more), or a time split (one run).
    Comparisons are against ``ref_effects`` (default: nominal)."""
    runs = list(range(len(problem.preps)))
    ref_effects = dict(ref_effects or {})
    full = problem.fit(names, runs, x0=x0)
    r_ref = problem.residual(ref_effects, runs)
    rss_ref = float(np.sum(r_ref ** 2)) if ref_rss is None else ref_rss
    n_eff = effective_n(r_ref)
    k = full.n_free
    dbic = delta_bic(full.rss, rss_ref, n_eff, k)
    folds = heldout_folds(len(runs))
    sq_b = sq_a = 0.0
    cnt = 0
    ch_b: dict[str, list[float]] = {}
    ch_a: dict[str, list[float]] = {}
    pairs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    fold_values = []
    pool_b: list[np.ndarray] = []
    pool_a: list[np.ndarray] = []
    seg_len: list[int] | None = []
    res_b: dict[str, list[np.ndarray]] = {}
    res_a: dict[str, list[np.ndarray]] = {}
    res_u: dict[str, list[np.ndarray]] = {}
    for train, test, ptrain, ptest in folds:
        f = problem.fit(names, train, part=ptrain, x0=full.x, max_nfev=25, fixed=full.fixed)
        fold_values.append(f.values)
        sb = problem.residual_segments(ref_effects, test, ptest)
        sa = problem.residual_segments(f.params, test, ptest)
        rb = np.concatenate(sb) if sb else np.zeros(0)
        ra = np.concatenate(sa) if sa else np.zeros(0)
        if seg_len is not None and [x.size for x in sb] == [x.size for x in sa]:
            seg_len += [x.size for x in sb]
        else:
            seg_len = None
        sq_b += float(np.sum(rb ** 2))
        sq_a += float(np.sum(ra ** 2))
        cnt += rb.size
        if rb.size == ra.size:
            pool_b.append(rb)
            pool_a.append(ra)
        cb = problem.channel_resids(ref_effects, test, ptest)
        ca = problem.channel_resids(f.params, test, ptest)
        cu = problem.channel_resids(ref_effects, test, ptest, spread=True)
        for c in cb:
            if c in ca and ca[c].size == cb[c].size:
                res_b.setdefault(c, []).append(cb[c])
                res_a.setdefault(c, []).append(ca[c])
                res_u.setdefault(c, []).append(cu[c] if c in cu and cu[c].size == cb[c].size
                                               else np.zeros(cb[c].size))
    spreads: dict[str, np.ndarray] = {}
    for c in res_b:
        vb, va = np.concatenate(res_b[c]), np.concatenate(res_a[c])
        ch_b[c] = [float(np.sqrt(np.mean(vb ** 2)))]
        ch_a[c] = [float(np.sqrt(np.mean(va ** 2)))]
        pairs[c] = (vb, va)
        spreads[c] = np.concatenate(res_u[c])
    hb = math.sqrt(sq_b / max(cnt, 1))
    ha = math.sqrt(sq_a / max(cnt, 1))
    size = problem.output_change(ref_effects, full.params, runs)
    rms: Callable[[Any], float] = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    pooled = ((np.concatenate(pool_b), np.concatenate(pool_a))
              if pool_b and len(pool_b) == len(folds) else None)
    segs = (np.asarray(seg_len, dtype=np.int64) if pooled is not None and seg_len is not None
            else None)
    return Candidate(list(names), full, dbic, hb, ha,
                     {c: rms(v) for c, v in ch_b.items()}, {c: rms(v) for c, v in ch_a.items()},
                     fold_values, size, heldout_pairs=pairs, heldout_spread=spreads,
                     heldout_pooled=pooled, heldout_segments=segs)


# The per-channel held-out rule (docs/analyzer.md, "The held-out rule"): an update is adopted
# only if no channel that measures physics gets worse on the held-out data, judged against that
# channel's noise and against the nominal model's own tolerance on it: a channel is worse when
# its held-out RMS error grows by more than HELDOUT_TOL of sqrt(floor^2 + spread^2) (spread: the
# RMS over the held-out samples of the reference replay's uncertainty, ``Channel.unc``: the input
# spread and the tolerance ensemble's spread in quadrature; not the current's sampling band,
# which is a reading's own, sample by sample, as the noise is) AND the growth is
# significant in a paired test over the held-out samples: the mean of after^2 - before^2 above
# HELDOUT_Z standard errors.  The standard error has two independent parts.  The noise's: the
# spread of the differences over the sample count corrected for autocorrelation.  The
# tolerance's: the robot the recording was made with is one draw within the tolerance, and the
# replay's departure e_i that it causes (RMS u_i at sample i) enters every sample's difference
# as 2 D_i e_i (D_i = after_i - before_i, the update's change, the same whichever robot it is):
# it moves the samples of a replay together (a slip onset the ensemble cannot pin shifts the
# whole pose after it), so it does not average out over the samples; by Minkowski's inequality
# the RMS of mean(2 D e) is at most mean(2 |D_i| u_i) whatever the correlation, and that bound
# is its share.  A growth that a robot within the tolerance would give the nominal model is no
# evidence that the update is worse; where the replay is pinned (spread 0) the rule is the noise
# test alone.  Derived channels (the recorder's odometry, computed from the counts) are reported
# but veto nothing: recorders integrate odometry differently (schedule, integration rule,
# geometry), and a physics update cannot be judged by how well it reproduces another program's
# arithmetic.  The held-out data only accept or reject an update; they fit nothing.
HELDOUT_TOL = 0.1     # of sqrt(noise floor^2 + replay spread^2)

HELDOUT_Z = 2.33      # one-sided 1 %

HELDOUT_RULE = (f"a channel that measures physics is worse after the update when its held-out "
                f"RMS error grows by more than {HELDOUT_TOL} of sqrt(noise floor^2 + replay "
                f"spread^2) (the spread: the nominal model's tolerance ensemble and input spread "
                f"on that channel) and the growth is significant (paired test over the held-out "
                f"samples, z > {HELDOUT_Z}; its standard error the noise's, "
                f"autocorrelation-corrected, and the tolerance's, bounded by mean(2 |change| x "
                f"spread), which does not shrink with the sample count); an update that makes "
                f"any such channel worse is not adopted. Derived channels "
                f"({', '.join(DERIVED)}) are reported, not used to veto. Held-out data only "
                f"accept or reject an update, they fit nothing")


BIC_MARGIN = -10.0

# A fitted parameter is off its neutral value (SIZE_RULE) when the deviation lies beyond what the
# nominal model allows by more than the one-sided 1 % point (the rate of SIZE_Z under a normal)
# of the combined error of the fit (its 1-sigma, autocorrelation-corrected, normal) and of the
# nominal parameter: params.json's ``tol`` of the neutral value (ParamSpec.tol) is a half-width,
# the true value lies within value +- tol, uniformly as the replay's tolerance ensemble draws it
# (standard uncertainty tol / sqrt(3)).  The point is that of the normal convolved with that
# uniform (``size_threshold``), not SIZE_Z times their combined standard uncertainty: where the
# tolerance dominates, SIZE_Z x tol / sqrt(3) = 1.35 tol lies beyond anything the uniform can
# give (its 1 % point is 0.98 tol) and would refuse a precise fit 1.2 tol beyond the allowance,
# which no robot within the tolerance replays; where the fit's sigma dominates the point is
# SIZE_Z sigma, and without a tolerance exactly that.  What the nominal model allows is the
# neutral value itself, widened by the ranges
# [lo, hi] by which the parts of the normal forces' physics that the nominal model carries only at
# a guess move the fitted value (ParamSpec.left_out, replay/tolerance.py: where the wheels' mass
# sits, the centre of mass's height, the share of the wheels' spin-up; the nominal model lies
# inside each part's range, so they move a friction coefficient either way, by LeftOut.mu_ranges
# of it, and a load-transfer height from the ground up to Table II.2's h plus its tolerance, and
# by the spin share's range times h_s): any
# value between sum(lo) and sum(hi) is a robot the ensemble draws, the nominal one included, so
# none of them is evidence.  SIZE_Z is the one-sided 1 % of the other tests (HELDOUT_Z).  Without
# a tolerance or a left-out range (an effect whose neutral value is no nominal parameter) the
# deviation must be significant against the fit's uncertainty, and the output change
# (``min_output``) decides.
SIZE_Z = HELDOUT_Z
SIZE_RULE = (f"value - nominal outside [sum lo, sum hi] by more than the one-sided 1 % point "
             f"(z {SIZE_Z}) of the fit's normal error (sigma_fit) plus the nominal parameter's "
             f"uniform one (+- tol, tol its params.json tolerance, 0 where it has none; without "
             f"it {SIZE_Z} x sigma_fit), [lo, hi] each range by which a part of the nominal "
             f"model's left-out physics of the normal forces moves it (none where it does not)")


def _normal_tail(x: float) -> float:
    """P(X > x) for a standard normal X."""
    return 0.5 * math.erfc(x / math.sqrt(2.0))


def size_threshold(sigma_fit: float, tol: float, z: float = SIZE_Z) -> float:
    """The point that the sum of a normal error (1-sigma ``sigma_fit``) and a uniform one on
    [-tol, tol] exceeds with the probability a normal exceeds ``z`` sigma (one-sided): z x
    sigma_fit without a tolerance, (1 - 2 p) tol without a fit error, between them the
    convolution's own quantile (its tail in closed form, solved by bisection)."""
    s = max(float(sigma_fit), 0.0) if math.isfinite(sigma_fit) else 0.0
    a = max(float(tol), 0.0)
    if a == 0.0:
        return z * s
    p = _normal_tail(z)
    if s == 0.0:
        return (1.0 - 2.0 * p) * a

    def antider(v: float) -> float:   # d/dv = P(normal error > v)
        return v * _normal_tail(v / s) - s * math.exp(-0.5 * (v / s) ** 2) / math.sqrt(2 * math.pi)

    def tail(t: float) -> float:      # P(normal + uniform > t)
        return (antider(t + a) - antider(t - a)) / (2.0 * a)

    lo, hi = 0.0, z * s + a
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if tail(mid) > p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def significant_deviation(dev: float, sigma_fit: float, tol: float, z: float = SIZE_Z,
                          left_out: Sequence[tuple[float, float]] = ()) -> bool:
    """Is a fitted deviation ``dev`` from the neutral value outside the range the nominal
    model's left-out physics allows (``left_out``: the ranges (lo, hi) of its parts, summed;
    none: the neutral value alone) by more than the one-sided point, at the rate of ``z``, of
    the fit's normal error (``sigma_fit``; a non-finite one counts as 0: a coordinate whose
    uncertainty is unknown is judged on the tolerance and the output change) plus the nominal
    parameter's uniform one (``tol``, the half-width of the range), :func:`size_threshold`?"""
    sd = sigma_fit if math.isfinite(sigma_fit) else 0.0
    lo = sum(min(float(a), float(b)) for a, b in left_out)
    hi = sum(max(float(a), float(b)) for a, b in left_out)
    beyond = dev - hi if dev > hi else (lo - dev if dev < lo else 0.0)
    return beyond > size_threshold(sd, tol, z) and dev != 0.0

# Adoption asks the held-out data whether the update predicts them better: a paired test of the
# held-out errors, sample by sample over the fit channels in noise floors, d = after^2 - before^2,
# whose mean must lie below zero by more than HELDOUT_Z (one-sided 1 %, the rate of the
# per-channel veto) of its standard error under the test's own null.  Each fold's update is
# fitted on the other runs, so its change D = after - before on the held-out run is fixed with
# respect to that run's noise e: with before = s + e (s the nominal model's systematic misfit),
# d = 2 D s + D^2 + 2 D e, and only 2 D e is random.  Its variance, 4 sum_ij D_i D_j cov(e_i, e_j)
# / n^2, is taken per segment (one channel, or one slip difference, of one held-out run) as
# sigma^2 sum D_i^2 (1 + rho) / (1 - rho): sigma^2 the segment's mean after^2 (what the update
# leaves, a misfit included, counted as noise: the noise's variance where the update explains
# the segment, 1 floor^2 or less where the replay's uncertainty deflates the residual, more
# where the update leaves a misfit), rho the lag-1 correlation of the
# segment's after residual (0 to 0.995).  The sample spread of d instead holds the effect's own
# variation along the run (a gain that grows with the distance driven): its mean and spread
# grow together and z stays bounded however large the effect (docs/analyzer.md, "The adoption
# test's error").  A pair must beat each of its singles on the same held-out samples; that
# comparison keeps the sample spread of d, the sample count corrected for the autocorrelation of
# the pair's residual: there the reference is the single's fit, not a nominal model fixed
# before the data, and a fixed-design error counting the single's misfit as noise was the
# stricter where it was measured (docs/analyzer.md).


def paired_better(before: np.ndarray, after: np.ndarray, z: float = HELDOUT_Z,
                  segments: Sequence[int] | np.ndarray | None = None) -> tuple[bool, float]:
    """(better, z statistic): are the held-out residuals ``after`` (in noise floors) smaller
    than ``before``, sample by sample, beyond what the noise does to them?  With ``segments``
    (the lengths, in order, of the pooled segments: one channel of one held-out run) the
    error is the fixed-design one under the test's null; without, the sample spread of the
    differences."""
    b, a = np.asarray(before, float), np.asarray(after, float)
    if b.size < 3 or a.size != b.size:
        return False, 0.0
    d = a ** 2 - b ** 2
    mean = float(np.mean(d))
    if segments is not None and int(np.sum(segments)) == b.size:
        var = 0.0
        start = 0
        for m in (int(x) for x in segments):
            if m:
                seg_a = a[start:start + m]
                ch = seg_a - b[start:start + m]
                rho = lag1_correlation(seg_a)
                var += (float(np.mean(seg_a ** 2)) * float(np.sum(ch ** 2))
                        * (1.0 + rho) / (1.0 - rho))
            start += m
        if var == 0:
            return mean < 0, (math.inf if mean < 0 else 0.0)
        zstat = -mean / (2.0 * math.sqrt(var) / b.size)
        return bool(zstat > z), zstat
    sd = float(np.std(d, ddof=1))
    if sd == 0:
        return mean < 0, (math.inf if mean < 0 else 0.0)
    # the samples count as independent as the residual left after the update (its noise and
    # what the update does not explain): the structure of ``before``, the very mismatch the
    # update removes, would otherwise count as correlation and hide a large gain
    zstat = -mean / (sd / math.sqrt(effective_n(a)))
    return bool(zstat > z), zstat


def paired_worse(before: np.ndarray, after: np.ndarray, floor: float,
                 spread: np.ndarray | None = None, tol: float = HELDOUT_TOL,
                 z: float = HELDOUT_Z) -> tuple[bool, float, float]:
    """(worse, increase in noise floors, z statistic) of held-out residuals ``before`` and
    ``after`` of one channel, sample by sample, with ``spread`` the reference replay's own
    uncertainty at the same samples (None: none; see HELDOUT_RULE)."""
    b, a = np.asarray(before, float), np.asarray(after, float)
    if b.size == 0 or a.size != b.size or not floor > 0:
        return False, 0.0, 0.0
    u = (np.zeros(b.size) if spread is None or np.size(spread) != b.size
         else np.abs(np.asarray(spread, float)) / floor)
    # a sample whose replay is not pinned at all (no finite spread) is no evidence either way
    keep = np.isfinite(u)
    if not keep.all():
        a, b, u = a[keep], b[keep], u[keep]
        if b.size == 0:
            return False, 0.0, 0.0
    incr = (math.sqrt(float(np.mean(a ** 2))) - math.sqrt(float(np.mean(b ** 2)))) / floor
    big = incr > tol * math.sqrt(1.0 + float(np.mean(u ** 2)))
    d = (a ** 2 - b ** 2) / floor ** 2
    if d.size < 3:
        return big, incr, math.inf if incr > 0 else 0.0
    sd = float(np.std(d, ddof=1))
    se_noise = sd / math.sqrt(effective_n(d)) if sd > 0 else 0.0
    se_tol = 2.0 * float(np.mean(np.abs(a - b) / floor * u))
    se = math.hypot(se_noise, se_tol)
    mean = float(np.mean(d))
    zstat = mean / se if se > 0 else (math.inf if mean > 0 else 0.0)
    return bool(big and zstat > z), incr, zstat


def heldout_channel_check(before: Mapping[str, float], after: Mapping[str, float],
                          floors: Mapping[str, float],
                          pairs: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                          spreads: Mapping[str, np.ndarray] | None = None
                          ) -> dict[str, dict[str, Any]]:
    """Per channel: held-out RMSE before and after the update, the increase in noise floors,
    the replay's spread (RMS over the held-out samples of ``spreads[ch]``, the reference
    replay's own uncertainty; 0 without it), the paired test's z, whether the channel is
    derived, and whether it holds.  Channels without a noise floor or without both values are
    left out."""
    out = {}
    for ch, b in before.items():
        a = after.get(ch)
        f = floors.get(ch)
        if a is None or f is None or not (math.isfinite(b) and math.isfinite(a)):
            continue
        u = None if spreads is None else spreads.get(ch)
        fin = None if u is None else np.asarray(u, float)[np.isfinite(u)]
        spread = float(np.sqrt(np.mean(np.square(fin)))) if fin is not None and fin.size else 0.0
        if pairs is not None and ch in pairs:
            worse, incr, zs = paired_worse(pairs[ch][0], pairs[ch][1], f, u)
        else:
            incr = (a - b) / f if f > 0 else 0.0
            worse, zs = incr > HELDOUT_TOL * math.hypot(1.0, spread / f if f > 0 else 0.0), math.nan
        derived = ch in DERIVED
        out[ch] = {"before": b, "after": a, "noise_floor": f, "replay_spread": spread,
                   "increase_noise_floors": incr, "z": zs, "derived": derived,
                   "worse": bool(worse), "ok": bool(derived or not worse)}
    return out


def judge(problem: Problem, cand: Candidate, ref_effects: Mapping[str, Mapping[str, float]] | None = None,
          only: Sequence[str] | None = None, bic_margin: float = BIC_MARGIN,
          stability: float = 0.5, min_output: float = 0.5) -> None:
    """Fill ``cand.checks`` with the acceptance tests (and why they failed): ``bic``,
    ``heldout`` (paired test of the pooled held-out errors, ``paired_better``; without the
    samples, the pooled RMS must fall), ``heldout_channels`` (no channel worse), ``size``,
    ``stable``.
    ``only`` restricts the size/stability tests to these effects (the added one of a pair)."""
    params = params_for(cand.effects, problem.meta, problem.vocab)
    ref_effects = ref_effects or {}
    c = cand.checks
    c["bic"] = cand.delta_bic < bic_margin
    if not c["bic"]:
        cand.reasons.append(f"BIC does not improve enough ({cand.delta_bic:.1f} >= {bic_margin})")
    # pooled over the fit channels (normalized): the update must predict held-out data better
    if cand.heldout_pooled is not None:
        c["heldout"], cand.heldout_z = paired_better(*cand.heldout_pooled,
                                                     segments=cand.heldout_segments)
    else:
        c["heldout"] = cand.heldout_after < cand.heldout_before
    if not c["heldout"]:
        cand.reasons.append(f"held-out error does not improve significantly "
                            f"({cand.heldout_before:.3g} -> {cand.heldout_after:.3g}, paired "
                            f"z {cand.heldout_z:.2f} <= {HELDOUT_Z})")
    # channel by channel: no physics channel worse beyond its noise (HELDOUT_RULE)
    cand.heldout_per_channel = heldout_channel_check(cand.heldout_channels_before,
                                                     cand.heldout_channels_after, problem.floors,
                                                     cand.heldout_pairs, cand.heldout_spread)
    worse = [ch for ch, v in cand.heldout_per_channel.items() if not v["ok"]]
    c["heldout_channels"] = not worse
    if worse:
        cand.reasons.append("held-out error larger after the update, beyond the noise, on " +
                            ", ".join(f"{ch} ({cand.heldout_per_channel[ch]['before']:.4g} -> "
                                      f"{cand.heldout_per_channel[ch]['after']:.4g}, "
                                      f"+{cand.heldout_per_channel[ch]['increase_noise_floors']:.2f}"
                                      f" floors, z {cand.heldout_per_channel[ch]['z']:.2f})"
                                      for ch in worse))
    dworse = [ch for ch, v in cand.heldout_per_channel.items() if v["derived"] and v["worse"]]
    if dworse:
        cand.recorder_notes.append("derived channel(s) " + ", ".join(dworse) + " worse after the "
                                   "update (not a veto: the recorder's own odometry)")
    # physically possible parameters only
    impossible = [w for e, ps in cand.fit.params.items() for w in fx.physically_possible(e, ps)]
    c["physical"] = not impossible
    if impossible:
        cand.reasons.append("physically impossible fit: " + "; ".join(impossible))
    size_ok = False
    stable = True
    for j, p in enumerate(params):
        if only is not None and p.effect not in only:
            continue
        if p.shape:
            continue  # shape parameter (e.g. v_s): size and stability judged through its partner
        dev = cand.fit.values[j] - p.neutral
        sd = cand.fit.std[j] if j < len(cand.fit.std) else math.nan
        counts = significant_deviation(dev, sd, p.tol,
                                       left_out=fx.left_out_ranges(p.effect, p.name, problem.meta,
                                                                   cand.fit.params))
        size_ok = size_ok or counts
        folds = [fv[j] for fv in cand.fold_values]
        if counts:
            if any(np.sign(f - p.neutral) != np.sign(dev) for f in folds):
                stable = False
                cand.reasons.append(f"{p.effect}.{p.name}: held-out folds disagree in sign")
            spread = (max(folds + [cand.fit.values[j]]) - min(folds + [cand.fit.values[j]]))
            if spread > stability * abs(dev):
                stable = False
                cand.reasons.append(f"{p.effect}.{p.name}: spread over folds {spread:.3g} "
                                    f"> {stability:.0%} of its size {abs(dev):.3g}")
            if math.isfinite(cand.fit.std[j]) and cand.fit.std[j] > abs(dev) / 2:
                stable = False
                cand.reasons.append(f"{p.effect}.{p.name}: uncertainty {cand.fit.std[j]:.3g} "
                                    f"> half its size")
    # a vocabulary parameter a coordinate sets (mu_k = mu_k/mu_s x mu_s) is a nominal robot
    # parameter too, judged alike: the best-identified of the coefficients where mu_s is known
    # only to its profile set
    for jd in fx.judged_sets(params, cand.fit.values, cand.fit.std, cand.fold_values,
                             problem.meta):
        if only is not None and jd.effect not in only:
            continue
        counts = significant_deviation(jd.dev, jd.std, jd.tol, left_out=jd.left_out)
        size_ok = size_ok or counts
        if counts:
            neutral = jd.value - jd.dev
            if any(np.sign(f - neutral) != np.sign(jd.dev) for f in jd.folds):
                stable = False
                cand.reasons.append(f"{jd.effect}.{jd.name}: held-out folds disagree in sign")
            spread = max(jd.folds + (jd.value,)) - min(jd.folds + (jd.value,))
            if spread > stability * abs(jd.dev):
                stable = False
                cand.reasons.append(f"{jd.effect}.{jd.name}: spread over folds {spread:.3g} "
                                    f"> {stability:.0%} of its size {abs(jd.dev):.3g}")
    if not size_ok:
        cand.reasons.append(f"fitted deviation from nominal within what the nominal model allows "
                            f"({SIZE_RULE})")
    if cand.output_size < min_output:
        size_ok = False
        cand.reasons.append(f"changes the outputs by only {cand.output_size:.2f} noise floors")
    c["size"] = size_ok
    c["stable"] = stable and cand.fit.ok
