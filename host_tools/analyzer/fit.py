"""Output-error fitting of vocabulary effects across all runs at once.

A :class:`Problem` holds the prepared runs, the replayer and the per-channel noise
floors.  Its residual is the recording minus the simulation of every fit channel of
every run, divided by that channel's noise floor.  Parameters are fitted by
``scipy.optimize.least_squares`` on the simulated trajectories (bounded, after a
coarse multi-start grid), never on differentiated data."""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from host_tools.analyzer import effects as fx
from host_tools.analyzer.replay import CHANNELS, FIT_CHANNELS, OpenLoopReplay, PreparedRun, channels


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
            if n in vocab and ps.name not in vocab[n]:
                continue
            out.append(Param(n, ps.name, ps.neutral(meta), ps.lo(meta), ps.hi(meta),
                             ps.floor(meta)))
    return out


def effects_dict(params: Sequence[Param], values: Sequence[float]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for p, v in zip(params, values):
        out.setdefault(p.effect, {})[p.name] = float(v)
    return out


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

    def sim_channels(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int]):
        out = []
        for i in runs:
            prep = self.preps[i]
            sim = self.replay.simulate(prep, effects)
            out.append(channels(prep, sim, "duty"))
        return out

    def residual(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int],
                 part: str = "all") -> np.ndarray:
        """Stacked normalized residual of the fit channels.  ``part``: "all", "early" (before
        the time split) or "late" (after it)."""
        parts = []
        for i, chans in zip(runs, self.sim_channels(effects, runs)):
            ts = self._split_t(self.preps[i])
            for c in self.fit_channels:
                ch = chans.get(c)
                if ch is None:
                    continue
                r = ch.resid / self.floors[c]
                if part == "early":
                    r = r[ch.t <= ts]
                elif part == "late":
                    r = r[ch.t > ts]
                parts.append(r)
        if not parts:
            return np.zeros(0)
        r = np.concatenate(parts)
        return np.where(np.isfinite(r), r, 1e6)

    def channel_rmse(self, effects, runs: Sequence[int], part: str = "all") -> dict[str, float]:
        """RMSE per channel in the channel's unit, pooled over ``runs``."""
        acc: dict[str, list[np.ndarray]] = {}
        for i, chans in zip(runs, self.sim_channels(effects, runs)):
            ts = self._split_t(self.preps[i])
            for c, ch in chans.items():
                r = ch.resid
                if part == "early":
                    r = r[ch.t <= ts]
                elif part == "late":
                    r = r[ch.t > ts]
                acc.setdefault(c, []).append(r)
        return {c: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for c, v in acc.items()
                if sum(a.size for a in v)}

    # ----------------------------------------------------------------------- fit

    def fit(self, names: Sequence[str], runs: Sequence[int], part: str = "all",
            x0: np.ndarray | None = None, max_nfev: int = 60, grid: int = 7) -> FitResult:
        params = params_for(names, self.meta, self.vocab)
        k = len(params)

        def fun(x):
            return self.residual(effects_dict(params, [p.from_x(v) for p, v in zip(params, x)]),
                                 runs, part)

        nfev = 0
        if x0 is None:
            # coarse multi-start: the neutral point and a grid along each parameter
            starts = [np.array([np.clip(p.to_x(p.neutral), 0, 1) for p in params])]
            base = starts[0]
            levels = np.linspace(0.0, 1.0, grid)
            for j in range(k):
                for lv in levels:
                    s = base.copy()
                    s[j] = lv
                    starts.append(s)
            best, best_c = None, math.inf
            for s in starts:
                c = float(np.sum(fun(s) ** 2))
                nfev += 1
                if c < best_c:
                    best, best_c = s, c
            x0 = best
            # for 2-parameter effects refine the second coordinate around the best first one
            if k == 2:
                for lv in levels:
                    s = x0.copy()
                    s[1] = lv
                    c = float(np.sum(fun(s) ** 2))
                    nfev += 1
                    if c < best_c:
                        best, best_c = s, c
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
        values = [p.from_x(v) for p, v in zip(params, x)]
        std = [math.inf] * k
        if J is not None and r.size > k:
            # parameter covariance, inflated for correlated residuals
            n_eff = effective_n(r)
            s2 = float(np.sum(r ** 2)) / max(r.size - k, 1)
            try:
                cov = np.linalg.pinv(J.T @ J) * s2 * (r.size / max(n_eff, 1.0))
                std = [float(np.sqrt(max(cov[i, i], 0.0))) * (p.hi - p.lo)
                       for i, p in enumerate(params)]
            except np.linalg.LinAlgError:
                pass
        return FitResult(list(names), effects_dict(params, values), values, np.asarray(x),
                         float(np.sum(r ** 2)), int(r.size), std, nfev, ok, msg)


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
    k = len(full.values)
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
    fold_values = []
    for train, test, ptrain, ptest in folds:
        f = problem.fit(names, train, part=ptrain, x0=full.x, max_nfev=25)
        fold_values.append(f.values)
        rb = problem.residual(ref_effects, test, ptest)
        ra = problem.residual(f.params, test, ptest)
        sq_b += float(np.sum(rb ** 2))
        sq_a += float(np.sum(ra ** 2))
        cnt += rb.size
        for c, v in problem.channel_rmse(ref_effects, test, ptest).items():
            ch_b.setdefault(c, []).append(v)
        for c, v in problem.channel_rmse(f.params, test, ptest).items():
            ch_a.setdefault(c, []).append(v)
    hb = math.sqrt(sq_b / max(cnt, 1))
    ha = math.sqrt(sq_a / max(cnt, 1))
    rfit = problem.residual(full.params, runs)
    size = float(np.sqrt(np.mean((rfit - r_ref) ** 2))) if r_ref.size == rfit.size else 0.0
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    return Candidate(list(names), full, dbic, hb, ha,
                     {c: rms(v) for c, v in ch_b.items()}, {c: rms(v) for c, v in ch_a.items()},
                     fold_values, size)


# The per-channel held-out rule (docs/analyzer.md, "The held-out rule"; issue 9: "the held-out
# error is never worse after the update"): an update is adopted only if, on the held-out data,
# every compared channel's RMS error is at most the nominal model's on the same data.  No
# tolerance.  The held-out data are never used to fit a parameter, only to accept or reject.
HELDOUT_RULE = ("no channel's held-out RMS error may be larger after the update than before "
                "it, compared as this report states them (4 significant digits); no tolerance. "
                "Held-out data only accept or reject an update, they fit nothing")


# Held-out errors are compared at the resolution the report states them with (report.json
# gives 4 significant digits): a difference the report cannot show is no difference.
REPORT_SIG = 4
BIC_MARGIN = -10.0


def reported(v: float, sig: int = REPORT_SIG) -> float:
    return float(f"{v:.{sig}g}") if math.isfinite(v) else v


def no_worse(after: float, before: float) -> bool:
    """``after`` is not larger than ``before`` as the report states them."""
    return reported(after) <= reported(before)


def heldout_channel_check(before: Mapping[str, float], after: Mapping[str, float],
                          floors: Mapping[str, float]) -> dict[str, dict]:
    """Per channel: held-out RMSE before and after the update, the limit (= before) and whether
    it holds.  Channels without a noise floor or without both values are left out."""
    out = {}
    for ch, b in before.items():
        a = after.get(ch)
        f = floors.get(ch)
        if a is None or f is None or not (math.isfinite(b) and math.isfinite(a)):
            continue
        out[ch] = {"before": b, "after": a, "noise_floor": f, "limit": b,
                   "increase_noise_floors": (a - b) / f if f > 0 else 0.0,
                   "ok": no_worse(a, b)}
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
    # channel by channel (every compared channel): never worse
    cand.heldout_per_channel = heldout_channel_check(cand.heldout_channels_before,
                                                     cand.heldout_channels_after, problem.floors)
    worse = [ch for ch, v in cand.heldout_per_channel.items() if not v["ok"]]
    c["heldout_channels"] = not worse
    if worse:
        cand.reasons.append("held-out error larger after the update on " + ", ".join(
            f"{ch} ({cand.heldout_per_channel[ch]['before']:.4g} -> "
            f"{cand.heldout_per_channel[ch]['after']:.4g})" for ch in worse))
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


def pairs_to_try(ranked: Sequence[str], top: int = 4) -> list[tuple[str, str]]:
    return list(itertools.combinations(list(ranked)[:top], 2))
