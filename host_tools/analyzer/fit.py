"""Output-error fitting of vocabulary effects across all runs at once.

A :class:`Problem` holds the prepared runs, the replayer and the per-channel noise
floors.  Its residual is the recording minus the simulation of every fit channel of
every run, divided by that channel's noise floor.  Parameters are fitted by
``scipy.optimize.least_squares`` on the simulated trajectories (bounded, after a
coarse multi-start grid), never on differentiated data."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from host_tools.analyzer import effects as fx
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import DERIVED, FIT_CHANNELS, channels
from host_tools.analyzer.replay.openloop import OpenLoopReplay

# Recording time per run that the fit replays (see Problem.select_windows).
FIT_BUDGET_S = 16.0


@dataclass
class Param:
    effect: str
    name: str
    neutral: float
    lo: float
    hi: float
    floor: float

    def to_x(self, v: float) -> float:
        return (v - self.lo) / (self.hi - self.lo)

    def from_x(self, x: float) -> float:
        return self.lo + float(x) * (self.hi - self.lo)


def params_for(names: Sequence[str], meta: Mapping, vocab: Mapping[str, Mapping[str, float]]
               ) -> list[Param]:
    out = []
    for n in names:
        spec = fx.spec_for(n, vocab.get(n, {}))
        for ps in spec.params:
            if n in vocab and (ps.sets[0] if ps.sets else ps.name) not in vocab[n]:
                continue
            out.append(Param(n, ps.name, ps.neutral(meta), ps.lo(meta), ps.hi(meta),
                             ps.floor(meta)))
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
    fixed: dict = field(default_factory=dict)       # coordinate index -> pinned value in [0, 1]
    unidentified: list[str] = field(default_factory=list)   # "effect.coordinate" pinned

    @property
    def n_free(self) -> int:
        return len(self.values) - len(self.fixed)


class Problem:
    """The fitting problem over a set of runs; picklable (plants are made lazily)."""

    def __init__(self, preps: list[PreparedRun], floors: Mapping[str, float],
                 vocab: Mapping[str, Mapping[str, float]], dt_s: float = 5e-4,
                 fit_channels: Sequence[str] = FIT_CHANNELS, split_frac: float = 0.6):
        self.preps = preps
        self.floors = dict(floors)
        self.vocab = {k: dict(v) for k, v in vocab.items()}
        self.dt_s = dt_s
        self.fit_channels = [c for c in fit_channels if c in self.floors]
        self.split_frac = split_frac
        self._replay: OpenLoopReplay | None = None
        self.meta = preps[0].run.meta
        self.fit_windows: dict[int, list[int]] | None = None

    @property
    def replay(self) -> OpenLoopReplay:
        if self._replay is None:
            self._replay = OpenLoopReplay("duty", dt_s=self.dt_s)
        return self._replay

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_replay"] = None
        return d

    # ------------------------------------------------------------------ residuals

    def _split_t(self, prep: PreparedRun) -> float:
        t = prep.run.telemetry["t_s"]
        return float(t[0] + self.split_frac * (t[-1] - t[0]))

    def sim_channels(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int],
                     full: bool = False):
        """Channels of ``runs`` replayed with ``effects``: on the fitting windows
        (:meth:`select_windows`) unless ``full``."""
        out = []
        for i in runs:
            prep = self.preps[i]
            which = None if (full or self.fit_windows is None) else self.fit_windows.get(i)
            sim = self.replay.simulate_windows(prep, effects, which)
            out.append(channels(prep, sim, "duty"))
        return out

    def select_windows(self, nominal: Sequence[Mapping[str, object]],
                       budget_s: float = FIT_BUDGET_S) -> dict[int, list[int]] | None:
        """Fit on the windows that carry information, so that the cost of a fit grows with the
        budget and not with the run's length: per run, the replay windows whose nominal
        normalized residual over the fit channels is largest (where a mismatch is), half of the
        budget, and windows spread evenly over the rest of the run (what the update must not
        spoil), the other half.  None (all windows) when every run fits in the budget."""
        sel: dict[int, list[int]] = {}
        any_cut = False
        for i, (prep, chans) in enumerate(zip(self.preps, nominal)):
            nw = len(prep.windows)
            dur = [max(b - a, 1e-9) for a, b in (prep.window_times(w) for w in range(nw))]
            if sum(dur) <= budget_s or nw <= 2:
                sel[i] = list(range(nw))
                continue
            any_cut = True
            energy = np.zeros(nw)
            for c in self.fit_channels:
                ch = chans.get(c)
                if ch is None or ch.seg is None:
                    continue
                np.add.at(energy, ch.seg, (ch.deflated(self.floors[c]) / self.floors[c]) ** 2)
            per = energy / np.maximum(np.bincount(np.concatenate(
                [chans[c].seg for c in self.fit_channels if c in chans and chans[c].seg is not None]
                or [np.zeros(0, int)]), minlength=nw), 1)
            mean_d = float(np.mean(dur))
            k = max(2, int(budget_s / mean_d))
            top = [int(w) for w in np.argsort(-per)[:max(1, k // 2)]]
            rest = [w for w in range(nw) if w not in top]
            spread = [rest[int(j)] for j in np.linspace(0, len(rest) - 1, k - len(top)).round()
                      ] if rest else []
            sel[i] = sorted(set(top) | set(spread))
        self.fit_windows = sel if any_cut else None
        return self.fit_windows

    def residual(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int],
                 part: str = "all", full: bool = False) -> np.ndarray:
        """Stacked normalized residual of the fit channels.  ``part``: "all", "early" (before
        the time split) or "late" (after it)."""
        parts = []
        for i, chans in zip(runs, self.sim_channels(effects, runs, full)):
            ts = self._split_t(self.preps[i])
            for c in self.fit_channels:
                ch = chans.get(c)
                if ch is None:
                    continue
                r = ch.deflated(self.floors[c]) / self.floors[c]
                if part == "early":
                    r = r[ch.t <= ts]
                elif part == "late":
                    r = r[ch.t > ts]
                parts.append(r)
        if not parts:
            return np.zeros(0)
        r = np.concatenate(parts)
        return np.where(np.isfinite(r), r, 1e6)

    def channel_resids(self, effects, runs: Sequence[int], part: str = "all",
                       full: bool = False) -> dict[str, np.ndarray]:
        """Residual per channel in the channel's unit, concatenated over ``runs``."""
        acc: dict[str, list[np.ndarray]] = {}
        for i, chans in zip(runs, self.sim_channels(effects, runs, full)):
            ts = self._split_t(self.preps[i])
            for c, ch in chans.items():
                r = ch.resid
                if part == "early":
                    r = r[ch.t <= ts]
                elif part == "late":
                    r = r[ch.t > ts]
                acc.setdefault(c, []).append(r)
        return {c: np.concatenate(v) for c, v in acc.items() if sum(a.size for a in v)}

    def channel_rmse(self, effects, runs: Sequence[int], part: str = "all",
                     full: bool = False) -> dict[str, float]:
        """RMSE per channel in the channel's unit, pooled over ``runs``."""
        return {c: float(np.sqrt(np.mean(v ** 2)))
                for c, v in self.channel_resids(effects, runs, part, full).items()}

    # ----------------------------------------------------------------------- fit

    def fit(self, names: Sequence[str], runs: Sequence[int], part: str = "all",
            x0: np.ndarray | None = None, max_nfev: int = 60, grid: int = 7,
            fixed: Mapping[int, float] | None = None) -> FitResult:
        """Fit the coordinates of ``names`` (bounded, after a coarse grid).  ``fixed`` pins
        coordinates (index -> value in [0, 1]).  Without ``fixed``, a coordinate that the data
        do not identify (1-sigma uncertainty above UNIDENTIFIED of its search range) while
        another one is identified is pinned at its neutral value and the rest refitted; the
        result names it in ``unidentified``."""
        params = params_for(names, self.meta, self.vocab)
        k_all = len(params)
        fixed = dict(fixed or {})
        free = [i for i in range(k_all) if i not in fixed]
        k = len(free)
        full0 = np.array([np.clip(p.to_x(p.neutral), 0, 1) for p in params])
        for i, v in fixed.items():
            full0[i] = v

        def expand(xf):
            x = full0.copy()
            x[free] = xf
            return x

        def fun(xf):
            x = expand(xf)
            return self.residual(effects_dict(params, [p.from_x(v) for p, v in zip(params, x)]),
                                 runs, part)

        nfev = 0
        if x0 is not None:
            x0 = np.asarray(x0, float)
            x0 = x0[free] if x0.size == k_all else x0
        else:
            # coarse multi-start: the neutral point and a grid along each parameter
            starts = [full0[free].copy()]
            base = starts[0]
            levels = np.linspace(0.0, 1.0, grid)
            for j in range(k):
                for lv in levels:
                    s_ = base.copy()
                    s_[j] = lv
                    starts.append(s_)
            best, best_c = None, math.inf
            for s_ in starts:
                c = float(np.sum(fun(s_) ** 2))
                nfev += 1
                if c < best_c:
                    best, best_c = s_, c
            x0 = best
            # for 2-parameter effects refine the second coordinate around the best first one
            if k == 2:
                for lv in levels:
                    s_ = x0.copy()
                    s_[1] = lv
                    c = float(np.sum(fun(s_) ** 2))
                    nfev += 1
                    if c < best_c:
                        best, best_c = s_, c
                x0 = best
        x0 = np.clip(np.asarray(x0, float), 1e-6, 1 - 1e-6)
        try:
            if k == 1:
                # one parameter: bounded Brent search around the best grid point.  Robust to
                # the cost being piecewise constant at the plant's step (delays), unlike a
                # finite-difference gradient.
                half = 1.0 / max(grid - 1, 1)
                lo, hi = max(0.0, x0[0] - half), min(1.0, x0[0] + half)
                cost = lambda v: float(np.sum(fun(np.array([v])) ** 2))  # noqa: E731
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
        xfull = expand(x)
        values = [p.from_x(v) for p, v in zip(params, xfull)]
        std = [math.nan] * k_all
        for i in free:
            std[i] = math.inf
        if J is not None and r.size > k:
            # parameter covariance, inflated for correlated residuals
            n_eff = effective_n(r)
            s2 = float(np.sum(r ** 2)) / max(r.size - k, 1)
            try:
                cov = np.linalg.pinv(J.T @ J) * s2 * (r.size / max(n_eff, 1.0))
                for jj, i in enumerate(free):
                    std[i] = float(np.sqrt(max(cov[jj, jj], 0.0))) * (params[i].hi - params[i].lo)
            except np.linalg.LinAlgError:
                pass
        out = FitResult(list(names), effects_dict(params, values), values, np.asarray(xfull),
                        float(np.sum(r ** 2)), int(r.size), std, nfev, ok, msg,
                        [(p.effect, p.name) for p in params], fixed=fixed)
        out.unidentified = [f"{params[i].effect}.{params[i].name}" for i in fixed]
        if not fixed and k >= 2 and ok:
            unid = [i for i in free if not (std[i] <= UNIDENTIFIED * (params[i].hi - params[i].lo))]
            if unid and len(unid) < k:
                re = self.fit(names, runs, part, x0=None, max_nfev=max_nfev, grid=grid,
                              fixed={i: float(full0[i]) for i in unid})
                re.nfev += out.nfev
                return re
        return out


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


def delta_bic(rss1: float, rss0: float, n_eff: float, k: int) -> float:
    """BIC(model) - BIC(nominal) with Gaussian errors of unknown variance over n_eff samples."""
    if rss0 <= 0 or rss1 <= 0:
        return 0.0
    return float(n_eff * math.log(rss1 / rss0) + k * math.log(max(n_eff, 2.0)))


# --------------------------------------------------------------- candidate evaluation


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
    heldout_per_channel: dict = field(default_factory=dict)
    # per channel: held-out residuals (unit of the channel) before and after, sample by sample
    heldout_pairs: dict = field(default_factory=dict)
    recorder_notes: list[str] = field(default_factory=list)

    @property
    def accepted(self) -> bool:
        return bool(self.checks) and all(self.checks.values())

    @property
    def name(self) -> str:
        return "+".join(self.effects)


def evaluate_candidate(problem: Problem, names: Sequence[str], base: Mapping | None = None,
                       x0: np.ndarray | None = None, ref_rss: float | None = None,
                       ref_effects: Mapping | None = None) -> Candidate:
    """Fit ``names`` on all runs, then held-out: leave one run out (several runs) or a time
    split (one run).  Comparisons are against ``ref_effects`` (default: nominal)."""
    runs = list(range(len(problem.preps)))
    ref_effects = dict(ref_effects or {})
    full = problem.fit(names, runs, x0=x0)
    r_ref = problem.residual(ref_effects, runs)
    rss_ref = float(np.sum(r_ref ** 2)) if ref_rss is None else ref_rss
    n_eff = effective_n(r_ref)
    k = full.n_free
    dbic = delta_bic(full.rss, rss_ref, n_eff, k)
    # held-out
    folds: list[tuple[list[int], list[int], str, str]] = []
    if len(runs) >= 2:
        for i in runs:
            folds.append(([j for j in runs if j != i], [i], "all", "all"))
    else:
        folds.append((runs, runs, "early", "late"))
    sq_b = sq_a = 0.0
    cnt = 0
    ch_b: dict[str, list[float]] = {}
    ch_a: dict[str, list[float]] = {}
    pairs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    fold_values = []
    res_b: dict[str, list[np.ndarray]] = {}
    res_a: dict[str, list[np.ndarray]] = {}
    for train, test, ptrain, ptest in folds:
        f = problem.fit(names, train, part=ptrain, x0=full.x, max_nfev=25, fixed=full.fixed)
        fold_values.append(f.values)
        rb = problem.residual(ref_effects, test, ptest)
        ra = problem.residual(f.params, test, ptest)
        sq_b += float(np.sum(rb ** 2))
        sq_a += float(np.sum(ra ** 2))
        cnt += rb.size
        cb = problem.channel_resids(ref_effects, test, ptest)
        ca = problem.channel_resids(f.params, test, ptest)
        for c in cb:
            if c in ca and ca[c].size == cb[c].size:
                res_b.setdefault(c, []).append(cb[c])
                res_a.setdefault(c, []).append(ca[c])
    for c in res_b:
        vb, va = np.concatenate(res_b[c]), np.concatenate(res_a[c])
        ch_b[c] = [float(np.sqrt(np.mean(vb ** 2)))]
        ch_a[c] = [float(np.sqrt(np.mean(va ** 2)))]
        pairs[c] = (vb, va)
    hb = math.sqrt(sq_b / max(cnt, 1))
    ha = math.sqrt(sq_a / max(cnt, 1))
    rfit = problem.residual(full.params, runs)
    size = float(np.sqrt(np.mean((rfit - r_ref) ** 2))) if r_ref.size == rfit.size else 0.0
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    return Candidate(list(names), full, dbic, hb, ha,
                     {c: rms(v) for c, v in ch_b.items()}, {c: rms(v) for c, v in ch_a.items()},
                     fold_values, size, heldout_pairs=pairs)


# The per-channel held-out rule (docs/analyzer.md, "The held-out rule"): an update is adopted
# only if no channel that measures physics gets worse on the held-out data, judged against that
# channel's noise: a channel is worse when its held-out RMS error grows by more than
# HELDOUT_TOL noise floors AND the growth is significant in a paired test over the held-out
# samples (mean of after^2 - before^2 above HELDOUT_Z standard errors, with the sample count
# corrected for autocorrelation).  Differences far below the noise floor, or within what the
# noise makes of a held-out RMS, are no evidence.  Derived channels (the recorder's odometry,
# computed from the counts) are reported but veto nothing: recorders integrate odometry
# differently (schedule, integration rule, geometry), and a physics update cannot be judged by
# how well it reproduces another program's arithmetic.  The held-out data only accept or
# reject an update; they fit nothing.
HELDOUT_TOL = 0.1     # noise floors
HELDOUT_Z = 2.33      # one-sided 1 %
HELDOUT_RULE = (f"a channel that measures physics is worse after the update when its held-out "
                f"RMS error grows by more than {HELDOUT_TOL} noise floors and the growth is "
                f"significant (paired test over the held-out samples, z > {HELDOUT_Z}, "
                f"autocorrelation-corrected); an update that makes any such channel worse is "
                f"not adopted. Derived channels ({', '.join(DERIVED)}) are reported, not used "
                f"to veto. Held-out data only accept or reject an update, they fit nothing")
BIC_MARGIN = -10.0


def paired_worse(before: np.ndarray, after: np.ndarray, floor: float,
                 tol: float = HELDOUT_TOL, z: float = HELDOUT_Z) -> tuple[bool, float, float]:
    """(worse, increase in noise floors, z statistic) of held-out residuals ``before`` and
    ``after`` of one channel, sample by sample (see HELDOUT_RULE)."""
    b, a = np.asarray(before, float), np.asarray(after, float)
    if b.size == 0 or a.size != b.size or not floor > 0:
        return False, 0.0, 0.0
    incr = (math.sqrt(float(np.mean(a ** 2))) - math.sqrt(float(np.mean(b ** 2)))) / floor
    d = (a ** 2 - b ** 2) / floor ** 2
    if d.size < 3:
        return incr > tol, incr, math.inf if incr > 0 else 0.0
    sd = float(np.std(d, ddof=1))
    se = sd / math.sqrt(effective_n(d)) if sd > 0 else 0.0
    mean = float(np.mean(d))
    zstat = mean / se if se > 0 else (math.inf if mean > 0 else 0.0)
    return bool(incr > tol and zstat > z), incr, zstat


def heldout_channel_check(before: Mapping[str, float], after: Mapping[str, float],
                          floors: Mapping[str, float], pairs: Mapping | None = None
                          ) -> dict[str, dict]:
    """Per channel: held-out RMSE before and after the update, the increase in noise floors,
    the paired test's z, whether the channel is derived, and whether it holds.  Channels
    without a noise floor or without both values are left out."""
    out = {}
    for ch, b in before.items():
        a = after.get(ch)
        f = floors.get(ch)
        if a is None or f is None or not (math.isfinite(b) and math.isfinite(a)):
            continue
        if pairs is not None and ch in pairs:
            worse, incr, zs = paired_worse(pairs[ch][0], pairs[ch][1], f)
        else:
            incr = (a - b) / f if f > 0 else 0.0
            worse, zs = incr > HELDOUT_TOL, math.nan
        derived = ch in DERIVED
        out[ch] = {"before": b, "after": a, "noise_floor": f,
                   "increase_noise_floors": incr, "z": zs, "derived": derived,
                   "worse": bool(worse), "ok": bool(derived or not worse)}
    return out


def judge(problem: Problem, cand: Candidate, ref_effects: Mapping | None = None,
          only: Sequence[str] | None = None, bic_margin: float = BIC_MARGIN,
          heldout_gain: float = 0.05, stability: float = 0.5, min_output: float = 0.5) -> None:
    """Fill ``cand.checks`` with the acceptance tests (and why they failed): ``bic``,
    ``heldout`` (pooled gain), ``heldout_channels`` (no channel worse), ``size``, ``stable``.
    ``only`` restricts the size/stability tests to these effects (the added one of a pair)."""
    params = params_for(cand.effects, problem.meta, problem.vocab)
    ref_effects = ref_effects or {}
    c = cand.checks
    c["bic"] = cand.delta_bic < bic_margin
    if not c["bic"]:
        cand.reasons.append(f"BIC does not improve enough ({cand.delta_bic:.1f} >= {bic_margin})")
    # pooled over the fit channels (normalized): the update must predict held-out data better
    c["heldout"] = cand.heldout_after < (1 - heldout_gain) * cand.heldout_before
    if not c["heldout"]:
        cand.reasons.append(f"held-out error does not improve by {heldout_gain:.0%} "
                            f"({cand.heldout_before:.3g} -> {cand.heldout_after:.3g})")
    # channel by channel: no physics channel worse beyond its noise (HELDOUT_RULE)
    cand.heldout_per_channel = heldout_channel_check(cand.heldout_channels_before,
                                                     cand.heldout_channels_after, problem.floors,
                                                     cand.heldout_pairs)
    worse = [ch for ch, v in cand.heldout_per_channel.items() if not v["ok"]]
    c["heldout_channels"] = not worse
    if worse:
        cand.reasons.append("held-out error larger after the update, beyond the noise, on " +
                            ", ".join(f"{ch} ({cand.heldout_per_channel[ch]['before']:.4g} -> "
                                      f"{cand.heldout_per_channel[ch]['after']:.4g}, "
                                      f"+{cand.heldout_per_channel[ch]['increase_noise_floors']:.2f}"
                                      f" floors)" for ch in worse))
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
        dev = cand.fit.values[j] - p.neutral
        if p.floor > 0 and abs(dev) >= p.floor:
            size_ok = True
        if p.floor <= 0:
            continue  # shape parameter (e.g. v_s): stability judged through its partner
        folds = [fv[j] for fv in cand.fold_values]
        if abs(dev) >= p.floor:
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
    if not size_ok:
        cand.reasons.append("fitted size below the floor")
    if cand.output_size < min_output:
        size_ok = False
        cand.reasons.append(f"changes the outputs by only {cand.output_size:.2f} noise floors")
    c["size"] = size_ok
    c["stable"] = stable and cand.fit.ok
