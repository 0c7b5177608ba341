"""The test for a consistent bias of the nominal replay's residual: per fit channel and for each
wheel pair's difference, a t-test over block means pooled over the runs, with the bias the
model's tolerance allows."""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from host_tools.analyzer.locate.episodes import SLIP_UNC, UNPINNED_UNC
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import Channel


# A consistent bias: many samples that agree, each below STRONG_WINDOW.  The residual of each
# fit channel (in noise floors, deflated by the replay's uncertainty) is cut into blocks of
# BIAS_BLOCK_S within its replay windows; the block means are the effective samples (noise and
# the replay's own short-lived errors decorrelate within a block, so the autocorrelation of the
# samples inside a block does not count them many times) and a t-test over them, pooled over the
# runs, asks whether their mean differs from zero.  The threshold comes from the false-alarm
# rate BIAS_ALPHA per analysis, two-sided, shared by the fit channels (Bonferroni).  A bias below
# BIAS_MIN_FLOORS counts for nothing however many samples agree: it is the smallest output
# change an update may make to be adopted (``judge``'s min_output), so a smaller one could never
# be named.
BIAS_BLOCK_S = 1.0
BIAS_ALPHA = 0.01
BIAS_MIN_FLOORS = 0.5

# The two wheels' difference.  A per-wheel effect (a motor-gain asymmetry) moves the two wheels'
# residuals in opposite directions while the body's motion, and most of the replay's own error,
# moves them alike: the difference (r - l)/sqrt(2) of a wheel pair's residuals in floors (speeds,
# currents) holds the one without the other (heldback6's MuJoCo 10 % asymmetry: currents -0.64
# and +0.48 floors, t -2.5 and +1.5 per wheel; their difference -0.79 floors, and its block means
# decorrelate within half a second).  It is tested as one more channel (Bonferroni over the fit
# channels and these), in blocks of PAIR_BLOCK_S: on the tuning and heldback6 nulls the lag-1
# autocorrelation of the difference's 0.5 s block means is at most 0.2, so they are independent
# samples.  The tolerance's allowed bias of the difference is that of the draws' differences
# (``tolerance_draw_means``): the drawn parameters are the robot's, common to both wheels, so
# it is small where the per-wheel one is not.
WHEEL_PAIRS = (("omega_r", "omega_l"), ("current_r_a", "current_l_a"))
PAIR_BLOCK_S = 0.5


def pair_name(a: str, b: str) -> str:
    return f"{a}-{b}"


def _block_means(ch: Channel, floor: float, block_s: float = BIAS_BLOCK_S,
                 no_evidence: float | None = None) -> list[float]:
    """Means of the channel's residual (in floors) over blocks of ``block_s`` within each
    replay window; a block with fewer than 3 samples is left out, and so are the samples whose
    replay uncertainty is ``no_evidence`` or more (default SLIP_UNC: ``unpinned_episodes``)."""
    z = ch.resid / floor
    t = np.asarray(ch.t, float)
    seg = ch.seg if ch.seg is not None else np.zeros(t.size, int)
    ok = np.isfinite(z)
    if ch.unc is not None:
        ok &= ch.unc < (SLIP_UNC if no_evidence is None else no_evidence)
    out: list[float] = []
    for s in np.unique(seg):
        m = (seg == s) & ok
        if m.sum() < 3:
            continue
        ts, zs = t[m], z[m]
        k = np.floor((ts - ts[0]) / block_s).astype(int)
        # a short last block joins the one before it
        if k.size and k[-1] > 0 and ts[-1] - (ts[0] + k[-1] * block_s) < 0.5 * block_s:
            k[k == k[-1]] = k[-1] - 1
        for b in np.unique(k):
            zb = zs[k == b]
            if zb.size >= 3:
                out.append(float(np.mean(zb)))
    return out


def bias_test(nominal: Sequence[Mapping[str, Channel]], floors: Mapping[str, float],
              channels_: Sequence[str], alpha: float = BIAS_ALPHA,
              min_floors: float = BIAS_MIN_FLOORS,
              allowed: Sequence[Mapping[str, float] | None] | None = None,
              extra_tests: int = 0) -> dict[str, dict[str, Any]]:
    """Per fit channel: the mean residual over all runs (in noise floors), the number of
    blocks (effective samples), the t statistic of the block means, the threshold for the
    false-alarm rate ``alpha`` per analysis (two-sided, Bonferroni over ``channels_``) and
    whether the bias is significant and at least ``min_floors``; and the same for each wheel
    pair's difference (``WHEEL_PAIRS``, keyed ``pair_name``, in blocks of PAIR_BLOCK_S; the
    Bonferroni count includes them).  ``allowed`` (per run,
    channel -> std of the whole-run bias the model's tolerance allows, ``tolerance_bias``)
    joins the standard error: the tolerance is one set of parameters for all runs, so its
    error does not average out over blocks; it is taken as fully shared by the runs.
    ``extra_tests``: further tests of the analysis in the same Bonferroni share (the wheels'
    torque imbalance, ``wheels.imbalance_test``); each entry gives the share's count
    (``tests``)."""
    from scipy import stats
    from host_tools.analyzer.replay.channels import Channel
    out: dict[str, dict[str, Any]] = {}
    tests: list[tuple[str, list[tuple[list[float], float]], float, float]] = []
    for c in channels_:
        f = floors.get(c, 0.0)
        if not f > 0:
            continue
        tests.append((c, [(_block_means(chans[c], f),
                           (allowed[i] or {}).get(c, 0.0) / f if allowed else 0.0)
                          for i, chans in enumerate(nominal) if c in chans], f, BIAS_BLOCK_S))
    for a, b in WHEEL_PAIRS:
        fa, fb = floors.get(a, 0.0), floors.get(b, 0.0)
        if a not in channels_ or b not in channels_ or not (fa > 0 and fb > 0):
            continue
        name = pair_name(a, b)
        per_run = []
        for i, chans in enumerate(nominal):
            ca, cb = chans.get(a), chans.get(b)
            if ca is None or cb is None or ca.t.size != cb.t.size or np.any(ca.t != cb.t):
                continue
            d = Channel(name, ca.t, (ca.resid / fa - cb.resid / fb) / math.sqrt(2),
                        np.zeros(ca.t.size), "floors", ca.seg,
                        None if ca.unc is None and cb.unc is None else
                        np.maximum(ca.unc if ca.unc is not None else 0.0,
                                   cb.unc if cb.unc is not None else 0.0))
            per_run.append((_block_means(d, 1.0, PAIR_BLOCK_S, UNPINNED_UNC),
                            (allowed[i] or {}).get(name, 0.0) if allowed else 0.0))
        tests.append((name, per_run, 1.0, PAIR_BLOCK_S))
    m = max(len(tests) + extra_tests, 1)
    for c, per_run, f, block_s in tests:
        means = [v for bm, _ in per_run for v in bm]
        n = len(means)
        if n < 3:
            continue
        sys_ = sum(len(bm) * a for bm, a in per_run) / n
        mu = float(np.mean(means))
        sd = float(np.std(means, ddof=1))
        se = math.sqrt(sd ** 2 / n + sys_ ** 2)
        tstat = mu / se if se > 0 else (math.inf if mu != 0 else 0.0)
        thr = float(stats.t.ppf(1 - alpha / (2 * m), n - 1))
        out[c] = {"bias_floors": mu, "blocks": n, "block_s": block_s, "t": tstat,
                  "t_threshold": thr, "tolerance_floors": sys_, "tests": m,
                  "significant": bool(abs(tstat) > thr and abs(mu) >= min_floors)}
    return out


def allowed_bias(prep: PreparedRun, floors: Mapping[str, float]) -> dict[str, float]:
    """The whole-run bias the model's tolerance allows (``prep.tolerance_bias``, channel units)
    and, for each wheel pair, that of the pair's difference in floors: the std over the
    tolerance draws of (mean_r / floor_r - mean_l / floor_l) / sqrt(2)."""
    out = dict(prep.tolerance_bias or {})
    draws = prep.tolerance_draw_means or {}
    for a, b in WHEEL_PAIRS:
        fa, fb = floors.get(a, 0.0), floors.get(b, 0.0)
        if a in draws and b in draws and fa > 0 and fb > 0 and len(draws[a]) == len(draws[b]):
            d = (np.asarray(draws[a]) / fa - np.asarray(draws[b]) / fb) / math.sqrt(2)
            out[pair_name(a, b)] = float(np.std(d))
    return out
