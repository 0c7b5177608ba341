"""The once-per-revolution test: whether a wheel speed's residual follows its own wheel's angle.

A wheel whose rolling radius, mass or contact changes around its circumference (an eccentric
wheel, a flat spot, a bent rim) modulates its speed once per revolution.  The modulation has no
mean, so the test of a consistent bias (``bias.bias_test``) averages it away, and under timing
jitter and ADC noise no window stands out of the noise floors; but it keeps its phase to the
wheel's angle, which the encoder counts give sample by sample.  So each wheel speed's residual
z (recording minus nominal replay, in noise floors deflated by the replay's uncertainty,
``Channel.deflated``: the input spread and the tolerance's per-sample spread) is regressed on
cos and sin of that wheel's angle from its counts (at the middle of each speed's count
difference), with an intercept per replay window (a window's bias belongs to the bias test) and
a phase of its own per run (the counts start at zero at each run's power-up, wherever the wheel
stands).  The null is that all the runs' cosine and sine coefficients are zero, tested by a
Wald statistic:

- the residual is serially correlated (the replay's own slowly varying errors, the encoder's
  quantization); its variance at the regressors is estimated from the data, block by block
  (blocks of ``REV_BLOCK_S`` within each replay window: the block's score, the regressors times
  the residual left after the fit, against the regressors' own sum of squares, pooled over the
  runs: a block-robust, HAC-like scale), and the blocks' scores' lag-1 autocorrelation inflates
  it and cuts the effective number of blocks, as the other tests of the stage do;
- the nominal model's tolerance: the replay ensemble (``replay.tolerance.ensemble_draws``, the
  robot's parameters within their tolerance and the left-out normal-force physics) is replayed
  and each draw's departure from the nominal replay is put on the same regressors; the
  covariance of those coefficients over the draws (about the nominal's, one parameter set for
  every run, so it is shared by the runs) joins the coefficients' covariance.  A wheel whose
  nominal replay could show a once-per-revolution term within the tolerance is not called.
  These replays are only run when the test would fire without them (the tolerance only
  lowers the statistic);
- the false-alarm rate is the consistent-bias test's ``BIAS_ALPHA`` per analysis, in its
  Bonferroni share (one test per wheel);
- a term whose RMS is below ``BIAS_MIN_FLOORS`` floors counts for nothing however significant:
  a smaller output change is never adopted, and a change that small is no mismatch to report.

When it fires the recordings disagree with the nominal model (``detect_mismatch``); no
vocabulary effect depends on the wheel's angle, so the fits that follow cannot take it up."""
from __future__ import annotations

import dataclasses
import math
import zlib
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from host_tools.analyzer.locate.bias import BIAS_ALPHA, BIAS_MIN_FLOORS
from host_tools.analyzer.locate.episodes import SLIP_UNC
from host_tools.analyzer.replay.channels import Channel

# speed channel -> the telemetry's count column of the same wheel
REV_CHANNELS = (("omega_r", "enc_r"), ("omega_l", "enc_l"))
REV_BLOCK_S = 0.5
REV_NAME = "once_per_revolution"


def wheel_angle(prep: Any, ch: Channel, enc_col: str) -> np.ndarray:
    """The wheel's angle (rad, from the recorded counts) at the middle of each speed sample's
    count difference: the mean of the angles at the sample's frame and the frame before it."""
    tel = prep.run.telemetry
    t_tel = np.asarray(tel["t_s"], float)
    th = np.asarray(tel[enc_col], float) * 2 * math.pi / float(prep.ppr)
    i = np.clip(np.searchsorted(t_tel, np.asarray(ch.t, float)), 1, t_tel.size - 1)
    return np.asarray(0.5 * (th[i] + th[i - 1]), float)


def _design(ch: Channel, theta: np.ndarray, floor: float, delta: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(the regressors cos/sin of ``theta`` with each replay window's mean taken out, samples x
    2; the residual in deflated floors likewise; the samples' times; their windows) over the
    usable samples (finite, replay uncertainty below SLIP_UNC, as the bias test's).  ``delta``
    (channel units, on the same samples): that in place of the residual, deflated alike (a
    tolerance draw's departure from the nominal replay)."""
    src = ch if delta is None else dataclasses.replace(ch, rec=ch.sim + np.asarray(delta, float))
    z = src.deflated(floor) / floor
    seg = ch.seg if ch.seg is not None else np.zeros(ch.t.size, int)
    ok = np.isfinite(ch.resid) & np.isfinite(theta)
    if ch.unc is not None:
        ok &= ch.unc < SLIP_UNC
    X = np.column_stack([np.cos(theta), np.sin(theta)])[ok]
    z, t, seg = np.where(np.isfinite(z), z, 0.0)[ok], np.asarray(ch.t, float)[ok], seg[ok]
    for s in np.unique(seg):
        m = seg == s
        X[m] -= X[m].mean(axis=0)
        z[m] -= z[m].mean()
    return X, z, t, seg


def _block_index(t: np.ndarray, seg: np.ndarray, block_s: float) -> np.ndarray:
    """Each sample's block: consecutive blocks of ``block_s`` within each replay window, numbered
    over the run in time order; a short last block joins the one before it (as
    ``bias._block_means``)."""
    out = np.zeros(t.size, int)
    nxt = 0
    for s in np.unique(seg):
        idx = np.nonzero(seg == s)[0]
        ts = t[idx]
        k = np.floor((ts - ts[0]) / block_s + 1e-9).astype(int)
        if k.size and k[-1] > 0 and ts[-1] - (ts[0] + k[-1] * block_s) < 0.5 * block_s:
            k[k == k[-1]] = k[-1] - 1
        out[idx] = nxt + k
        nxt += int(k.max()) + 2 if k.size else 0   # a gap in the numbering between windows
    return out


def revolution_test(terms: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
                    n_tests: int, alpha: float = BIAS_ALPHA, min_floors: float = BIAS_MIN_FLOORS,
                    tolerance: Callable[[], Sequence[Sequence[np.ndarray | None]]] | None = None,
                    block_s: float = REV_BLOCK_S) -> dict[str, Any] | None:
    """The test of one wheel (module docstring).  ``terms``: per run, ``_design``'s (X, z, t,
    seg); ``n_tests``: the tests sharing ``alpha`` per analysis (Bonferroni), this one
    included; ``tolerance``: called only when the test fires without it, returns per draw and
    run the draw's departure from the nominal on the run's regressors (``_design``'s z of
    the departure; None where that run has none).  Returns None without a run whose wheel
    turns or without more blocks than coefficients, else the figures: ``amplitude_floors``
    (RMS over the runs of each run's fitted amplitude), ``rms_floors`` (RMS of the fitted term
    over the samples), ``F`` and ``F_threshold`` (the Wald statistic over its degrees of
    freedom ``df``), ``blocks``, ``n_eff``, ``lag1``, ``tolerance_amplitude_floors`` (RMS over
    the draws and runs of the amplitude a draw puts on the regressors; None when the
    tolerance was not replayed), ``runs`` and ``significant``."""
    from scipy import stats
    used: list[int] = []
    betas: list[np.ndarray] = []
    Ms: list[np.ndarray] = []
    ss_fit = 0.0
    n_samp = 0
    scores: list[list[tuple[np.ndarray, int]]] = []   # per run, (block score, block number)
    mtr: list[float] = []
    dof_b: list[float] = []
    for i, (X, z, t, seg) in enumerate(terms):
        if z.size < 3:
            continue
        M = X.T @ X
        ev = np.linalg.eigvalsh(M)
        if not (ev[0] > 1e-9 * max(ev[-1], 1e-300) and ev[-1] > 0):
            continue        # the wheel barely turns in this run: cos and sin are one regressor
        beta = np.linalg.solve(M, X.T @ z)
        e = z - X @ beta
        used.append(i)
        betas.append(beta)
        Ms.append(M)
        ss_fit += float(beta @ M @ beta)
        n_samp += z.size
        blk = _block_index(t, seg, block_s)
        run_scores = []
        for b in np.unique(blk):
            m = blk == b
            if m.sum() < 3:
                continue
            run_scores.append((X[m].T @ e[m], b))
            Mb = X[m].T @ X[m]
            mtr.append(float(np.trace(Mb)))
            # the block's degrees of freedom: 2 where the wheel turns through it, 1 where
            # cos and sin are one regressor (Satterthwaite: tr(M)^2 / tr(M^2))
            dof_b.append(float(np.trace(Mb)) ** 2 / max(float(np.sum(Mb * Mb)), 1e-300))
        scores.append(run_scores)
    q = 2 * len(used)
    nb = sum(len(s) for s in scores)
    if not used or nb <= q:
        return None
    dof = sum(dof_b)
    if dof <= q:
        return None
    s2 = sum(float(s @ s) for run in scores for s, _ in run) / sum(mtr) * dof / (dof - q)
    # lag-1 autocorrelation of consecutive blocks' scores (neighbours within a window)
    num = den = 0.0
    for run in scores:
        for (a, ka), (b, kb) in zip(run[:-1], run[1:]):
            if kb == ka + 1:
                num += float(a @ b)
        den += sum(float(s @ s) for s, _ in run)
    rho = min(max(num / den if den > 0 else 0.0, 0.0), 0.995)
    inflate = (1 + rho) / (1 - rho)
    n_eff = nb / inflate
    df2 = max(dof / inflate - q, 1.0)
    thr = float(stats.f.ppf(1 - alpha / max(n_tests, 1), q, df2))
    beta_all = np.concatenate(betas)
    V0 = np.zeros((q, q))
    for j, M in enumerate(Ms):
        V0[2 * j:2 * j + 2, 2 * j:2 * j + 2] = inflate * s2 * np.linalg.inv(M)
    W = float(beta_all @ np.linalg.solve(V0, beta_all))
    amp = math.sqrt(float(np.mean([b @ b for b in betas])))
    rms = math.sqrt(ss_fit / n_samp) if n_samp else 0.0
    tol_amp: float | None = None
    if tolerance is not None and W / q > thr and rms >= min_floors:
        draws = tolerance()
        B = []
        for d in draws:
            bd = np.zeros(q)
            for j, i in enumerate(used):
                dz = d[i] if i < len(d) else None
                if dz is None or dz.size != terms[i][1].size:
                    continue
                bd[2 * j:2 * j + 2] = np.linalg.solve(Ms[j], terms[i][0].T @ dz)
            B.append(bd)
        if B:
            Bm = np.array(B)
            T = Bm.T @ Bm / len(B)
            tol_amp = math.sqrt(float(np.mean(np.sum(Bm.reshape(len(B), -1, 2) ** 2, axis=2))))
            W = float(beta_all @ np.linalg.solve(V0 + T, beta_all))
    F = W / q
    return {"amplitude_floors": amp, "rms_floors": rms, "F": F, "F_threshold": thr,
            "df": [q, df2], "blocks": nb, "n_eff": n_eff, "lag1": rho, "block_s": block_s,
            "tolerance_amplitude_floors": tol_amp, "runs": len(used), "tests": n_tests,
            "significant": bool(F > thr and rms >= min_floors)}


def _run_seed(preps: Sequence[Any]) -> int:
    """A seed from the runs' content (their counts), so an analysis is repeatable."""
    h = 0
    for p in preps:
        for c in ("enc_r", "enc_l"):
            h = zlib.crc32(np.ascontiguousarray(p.run.telemetry[c], float).tobytes(), h)
    return h


def tolerance_departures(preps: Sequence[Any], nominal: Sequence[Mapping[str, Channel]],
                         dt_s: float, names: Sequence[str]
                         ) -> dict[str, list[list[np.ndarray | None]]]:
    """Per channel in ``names``, per draw of the tolerance ensemble (``TOLERANCE_ENSEMBLE``
    replays, ``ensemble_draws``; one parameter set for all the runs, as the robot is one), per
    run: the draw's departure from the nominal duty replay (nominal minus draw, the change of
    the residual, channel units) on the nominal channel's samples (None where they differ)."""
    from host_tools.analyzer.replay.channels import channels
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    from host_tools.analyzer.replay.tolerance import TOLERANCE_ENSEMBLE, ensemble_draws
    rng = np.random.default_rng([_run_seed(preps), 1])
    out: dict[str, list[list[np.ndarray | None]]] = {c: [] for c in names}
    for draw in ensemble_draws(preps[0].robot, TOLERANCE_ENSEMBLE, rng):
        rep = OpenLoopReplay("duty", dt_s=dt_s, forces=draw.forces, params=draw.params)
        per: dict[str, list[np.ndarray | None]] = {c: [] for c in names}
        for p, nom in zip(preps, nominal):
            got = channels(p, rep.simulate_windows(p, {}), "duty", only=names)
            for c in names:
                a, b = nom.get(c), got.get(c)
                ok = a is not None and b is not None and a.t.size == b.t.size
                per[c].append(a.sim - b.sim if ok and a is not None and b is not None
                              else None)
        for c in names:
            out[c].append(per[c])
    return out


def revolution_of(preps: Sequence[Any], nominal: Sequence[Mapping[str, Channel]],
                  floors: Mapping[str, float], dt_s: float, n_tests: int,
                  cache: dict[str, Any] | None = None,
                  reference: Sequence[Mapping[str, Channel]] | None = None
                  ) -> dict[str, dict[str, Any]]:
    """:func:`revolution_test` of each wheel speed in ``REV_CHANNELS`` that has a noise floor,
    keyed by the speed channel, on the residuals of ``nominal`` (per run, channel -> Channel);
    the tolerance ensemble is replayed (once for both wheels, about the nominal replay
    ``reference``, default ``nominal``) only when a wheel's test would fire without it, and
    kept in ``cache`` (a dict) for a later call on the same runs."""
    cache = {} if cache is None else cache
    ref = nominal if reference is None else reference
    names = [c for c, _ in REV_CHANNELS if floors.get(c, 0.0) > 0]
    out: dict[str, dict[str, Any]] = {}
    for c, enc in REV_CHANNELS:
        if c not in names:
            continue
        f = floors[c]
        terms = []
        idx = []
        for i, (p, chans) in enumerate(zip(preps, nominal)):
            ch = chans.get(c)
            if ch is None or ch.t.size < 3:
                continue
            idx.append(i)
            terms.append(_design(ch, wheel_angle(p, ch, enc), f))

        def tolerance(c: str = c, idx: list[int] = idx, f: float = f
                      ) -> list[list[np.ndarray | None]]:
            if "d" not in cache:
                cache["d"] = tolerance_departures(preps, ref, dt_s, names)
            res: list[list[np.ndarray | None]] = []
            for draw in cache["d"].get(c, []):
                row: list[np.ndarray | None] = []
                for i in idx:
                    dz = draw[i]
                    ch = nominal[i][c]
                    row.append(None if dz is None else
                               _design(ch, wheel_angle(preps[i], ch, dict(REV_CHANNELS)[c]),
                                       f, dz)[1])
                res.append(row)
            return res
        r = revolution_test(terms, n_tests, tolerance=tolerance)
        if r is not None:
            out[c] = r
    return out


def revolution_remains(det: Any, preps: Sequence[Any], duty: Any,
                       effects: Mapping[str, Mapping[str, float]]) -> list[str]:
    """The wheel speeds whose once-per-revolution test fired on the nominal replay
    (``det.revolution``) and fires again on the replay with ``effects`` (the model an
    explanation would adopt; same floors, Bonferroni share and tolerance as detection): no
    vocabulary effect depends on the wheel's angle, but one whose replay legitimately moves
    with it would take the term away, and then the effects explain it.  Empty when detection
    saw no such term."""
    from host_tools.analyzer.replay.channels import channels
    fired = [c for c, v in (det.revolution or {}).items() if v["significant"]]
    if not fired:
        return []
    after = [channels(p, duty.simulate_windows(p, effects), "duty") for p in preps]
    n_tests = next(iter(det.revolution.values()))["tests"]
    floors = {c: det.problem.floors[c] for c in fired}
    again = revolution_of(preps, after, floors, duty.dt_s, n_tests,
                          cache=det.revolution_cache, reference=det.nominal)
    return [c for c in fired if again.get(c, {}).get("significant")]
