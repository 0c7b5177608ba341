"""The fit problem: the replayed residual of every fit channel in noise floors, kept per
replay, and the least-squares fit of a set of effects (its numerics: :mod:`.solver`)."""
from __future__ import annotations

import math
from collections import OrderedDict
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.stats import chi2

from host_tools.analyzer.fit.params import (CREEP_GRID_M_S, CREEP_LEVEL, CREEP_PASSES,
                                            FitResult, Param,
                                            ProfileInterval, effects_dict, params_for)
from host_tools.analyzer.fit.solver import (PROFILE_LEVEL, UNIDENTIFIED, residual_variance,
                                            flat_minimum, given_line, given_neutral, grid_start, param_std,
                                            profile_interval, profile_scan, profile_steps,
                                            profile_walk, solve, unidentified_given)
from host_tools.analyzer.locate.bias import WHEEL_PAIRS, pair_name
from host_tools.analyzer.locate.episodes import SLIP_UNC, UNPINNED_UNC
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import FIT_CHANNELS, Channel, channels
from host_tools.analyzer.replay.openloop import OpenLoopReplay


# Recording time per run that the fit replays (see Problem.select_windows).
FIT_BUDGET_S = 16.0

# Bytes of replayed channels each process keeps (Problem.sim_channels): the replays a fit asks
# for again (the nominal one, the fitted point, the start and first steps every held-out fold
# shares) are looked up instead of simulated again.
CACHE_BYTES = 128 * 2 ** 20



def largest_rms(sums: Mapping[str, Sequence[float]]) -> float:
    """The largest per-channel RMS of :meth:`Problem.change_sums`' [sum of squares, count]
    (0 without samples): an update's output change in noise floors."""
    return max((math.sqrt(sq / n) for sq, n in sums.values() if n), default=0.0)

class Problem:
    """The fitting problem over a set of runs; picklable (plants are made lazily)."""

    def __init__(self, preps: Sequence[PreparedRun], floors: Mapping[str, float],
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
        self._cache: OrderedDict[tuple[object, ...], tuple[dict[str, Channel], bool, int]] = \
            OrderedDict()
        self._cache_bytes = 0
        self.n_simulated = 0     # runs replayed (not found in the cache), for the benchmarks

    @property
    def replay(self) -> OpenLoopReplay:
        if self._replay is None:
            self._replay = OpenLoopReplay("duty", dt_s=self.dt_s)
        return self._replay

    def __getstate__(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["_replay"] = None
        d["_cache"] = OrderedDict()
        d["_cache_bytes"] = 0
        return d

    # ------------------------------------------------------------------ residuals

    def _split_t(self, prep: PreparedRun) -> float:
        t = prep.run.telemetry["t_s"]
        return float(t[0] + self.split_frac * (t[-1] - t[0]))

    def sim_channels(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int],
                     full: bool = False, fit_only: bool = False
                     ) -> list[dict[str, Channel]]:
        """Channels of ``runs`` replayed with ``effects``: on the fitting windows
        (:meth:`select_windows`) unless ``full``; only the fit channels when ``fit_only``.
        A replay is a function of the run, the windows and the effects alone (the prepared
        runs do not change once the problem is built; whatever changes one must call
        :meth:`forget`), so each one is kept (up to CACHE_BYTES, least recently used first
        out) and a second request for it returns the same channels without simulating again.
        The channels are shared: callers must not change them."""
        out: list[dict[str, Channel]] = []
        for i in runs:
            which = None if (full or self.fit_windows is None) else self.fit_windows.get(i)
            key = (i, None if which is None else tuple(which), _effects_key(effects))
            hit = self._cache.get(key)
            if hit is not None and (fit_only or not hit[1]):
                self._cache.move_to_end(key)
                out.append(hit[0])
                continue
            prep = self.preps[i]
            sim = self.replay.simulate_windows(prep, effects, which)
            chans = channels(prep, sim, "duty", only=self.fit_channels if fit_only else None)
            self.n_simulated += 1
            self._remember(key, chans, fit_only)
            out.append(chans)
        return out

    def forget(self) -> None:
        """Drop the kept replays (after a prepared run changed)."""
        self._cache.clear()
        self._cache_bytes = 0

    def _remember(self, key: tuple[object, ...], chans: dict[str, Channel], partial: bool
                  ) -> None:
        size = sum(a.nbytes for ch in chans.values()
                   for a in (ch.t, ch.rec, ch.sim, ch.seg, ch.unc) if a is not None)
        old = self._cache.pop(key, None)
        if old is not None:
            self._cache_bytes -= old[2]
        if size > CACHE_BYTES:
            return
        self._cache[key] = (chans, partial, size)
        self._cache_bytes += size
        while self._cache_bytes > CACHE_BYTES:
            _, (_, _, n) = self._cache.popitem(last=False)
            self._cache_bytes -= n

    def select_windows(self, nominal: Sequence[Mapping[str, Channel]],
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
        parts = self.residual_segments(effects, runs, part, full)
        return np.concatenate(parts) if parts else np.zeros(0)

    def residual_segments(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int],
                          part: str = "all", full: bool = False) -> list[np.ndarray]:
        """:meth:`residual` in its segments (one fit channel, or one wheel pair's slip
        difference, of one run), in its order; non-finite samples as there."""
        parts = []
        for i, chans in zip(runs, self.sim_channels(effects, runs, full, fit_only=True)):
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
            for d, t in self.slip_differences(chans):
                parts.append(d if part == "all" else d[t <= ts] if part == "early" else d[t > ts])
        return [np.where(np.isfinite(r), r, 1e6) for r in parts]

    def output_change(self, before: Mapping[str, Mapping[str, float]],
                      after: Mapping[str, Mapping[str, float]], runs: Sequence[int]) -> float:
        """How far an update moves the model's outputs, in noise floors: per fit channel, the
        RMS over ``runs`` of the change of its normalized residual (the residual as the fit
        weighs it: deflated by the replay's own uncertainty, over the floor) from the effects
        ``before`` to ``after``; the largest over the channels.  Per channel, not pooled: an
        effect moves the channels that measure it (a torque imbalance the wheels' speeds and
        currents, a radius the camera), and pooling would dilute it by however many other
        channels a recorder happens to log."""
        return largest_rms(self.change_sums(before, after, runs))

    def change_sums(self, before: Mapping[str, Mapping[str, float]],
                    after: Mapping[str, Mapping[str, float]], runs: Sequence[int],
                    part: str = "all", into: dict[str, list[float]] | None = None
                    ) -> dict[str, list[float]]:
        """Per fit channel [sum of squares, count] of the change of the normalized residual
        from ``before`` to ``after`` over ``runs`` (``part`` as :meth:`residual`), added to
        ``into`` when given (:meth:`output_change` and the invariance check's halves)."""
        acc = {} if into is None else into
        for i, ca, cb in zip(runs, self.sim_channels(before, runs, fit_only=True),
                             self.sim_channels(after, runs, fit_only=True)):
            ts = self._split_t(self.preps[i]) if part != "all" else 0.0
            for c in self.fit_channels:
                x, y = ca.get(c), cb.get(c)
                if x is None or y is None or x.t.size != y.t.size or not x.t.size:
                    continue
                f = self.floors[c]
                d = (y.deflated(f) - x.deflated(f)) / f
                if part == "early":
                    d = d[x.t <= ts]
                elif part == "late":
                    d = d[x.t > ts]
                d = d[np.isfinite(d)]
                s = acc.setdefault(c, [0.0, 0.0])
                s[0] += float(np.sum(d ** 2))
                s[1] += d.size
            # a wheel pair's difference where each wheel alone is no evidence (a slip), as
            # the residual holds it
            for (name, da, t), (_, db, _) in zip(self.named_slip_differences(ca),
                                                 self.named_slip_differences(cb)):
                if da.size != db.size:
                    continue
                d = db - da
                if part == "early":
                    d = d[t <= ts]
                elif part == "late":
                    d = d[t > ts]
                d = d[np.isfinite(d)]
                s = acc.setdefault(name, [0.0, 0.0])
                s[0] += float(np.sum(d ** 2))
                s[1] += d.size
        return acc

    def slip_differences(self, chans: Mapping[str, Channel]
                         ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per wheel pair (``locate.bias.WHEEL_PAIRS``) of the fit channels: the pair's
        difference (r - l)/sqrt(2) of the residuals in floors, and its times, on the samples
        where a wheel on its own is no evidence but the pair's difference is (a slip of a
        windowed replay: replay uncertainty at least ``SLIP_UNC`` and below ``UNPINNED_UNC``,
        ``locate.episodes.unpinned_episodes``).  Elsewhere the two wheels' residuals are in the
        fit, and r^2 + l^2 already holds the difference's square; in such a slip the common
        part is dropped and the difference kept, as the detection's bias test keeps it
        (``locate.bias.bias_test``)."""
        return [(d, t) for _, d, t in self.named_slip_differences(chans)]

    def named_slip_differences(self, chans: Mapping[str, Channel]
                               ) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """:meth:`slip_differences` with each pair's name (``locate.bias.pair_name``)."""
        out: list[tuple[str, np.ndarray, np.ndarray]] = []
        for a, b in WHEEL_PAIRS:
            ca, cb = chans.get(a), chans.get(b)
            if (ca is None or cb is None or a not in self.fit_channels
                    or b not in self.fit_channels or ca.t.size != cb.t.size
                    or (ca.unc is None and cb.unc is None)):
                continue
            ua = ca.unc if ca.unc is not None else np.zeros(ca.t.size)
            ub = cb.unc if cb.unc is not None else np.zeros(cb.t.size)
            m = ((np.maximum(ua, ub) >= SLIP_UNC) & (np.maximum(ua, ub) < UNPINNED_UNC)
                 & (ca.t == cb.t))
            if not m.any():
                continue
            d = (ca.resid[m] / self.floors[a] - cb.resid[m] / self.floors[b]) / math.sqrt(2)
            out.append((pair_name(a, b), d, ca.t[m]))
        return out

    def channel_resids(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int], part: str = "all",
                       full: bool = False, spread: bool = False) -> dict[str, np.ndarray]:
        """Residual per channel in the channel's unit, concatenated over ``runs``; with
        ``spread``, the replay's uncertainty at the same samples instead (``Channel.unc``: the
        input spread and the tolerance ensemble's spread; zeros where it has none)."""
        acc: dict[str, list[np.ndarray]] = {}
        for i, chans in zip(runs, self.sim_channels(effects, runs, full)):
            ts = self._split_t(self.preps[i])
            for c, ch in chans.items():
                r = ch.resid
                if spread:
                    r = np.zeros(r.size) if ch.unc is None else np.asarray(ch.unc, float)
                if part == "early":
                    r = r[ch.t <= ts]
                elif part == "late":
                    r = r[ch.t > ts]
                acc.setdefault(c, []).append(r)
        return {c: np.concatenate(v) for c, v in acc.items() if sum(a.size for a in v)}

    def channel_rmse(self, effects: Mapping[str, Mapping[str, float]], runs: Sequence[int], part: str = "all",
                     full: bool = False) -> dict[str, float]:
        """RMSE per channel in the channel's unit, pooled over ``runs``."""
        return {c: float(np.sqrt(np.mean(v ** 2)))
                for c, v in self.channel_resids(effects, runs, part, full).items()}

    # ----------------------------------------------------------------------- fit

    def fit(self, names: Sequence[str], runs: Sequence[int], part: str = "all",
            x0: np.ndarray | None = None, max_nfev: int = 60, grid: int = 7,
            fixed: Mapping[int, float] | None = None, pin_unidentified: bool = True,
            decide_nuisance: bool = True, hold: Mapping[int, float] | None = None,
            rescan: bool = False) -> FitResult:
        """Fit the coordinates of ``names`` (bounded, after a coarse grid).  ``fixed`` pins
        coordinates (index -> value in [0, 1]).  Without ``fixed``, a coordinate that the data
        do not identify (1-sigma uncertainty above UNIDENTIFIED of its search range in its fit coordinate) while
        another one is identified is pinned at its neutral value and the rest refitted; the
        result names it in ``unidentified``.  ``pin_unidentified=False`` keeps every coordinate
        free: a refit that must stay the model it is compared with, its sigmas saying what the
        data leave open.

        A coordinate with a ``given`` spec (mu_s with mu_k held) is profiled, since its cost
        is a staircase that neither a gradient nor a finite difference sees: on a fit of every
        run (the analysis' fit of a candidate set) its scan's minimum is the gradient solve's
        start when no start is given (:meth:`_profile_start`), and its profile set at the
        solution (:meth:`_profile_set`) gives its 1-sigma and ``FitResult.intervals``; the
        held-out folds' and halves' refits, which start from such a fit, hold it at its
        start (its uncertainty is the set) and refit the rest; a kept nuisance coordinate
        (:meth:`_fit_nuisance`) is held alike.  ``hold`` holds coordinates (index -> value in
        [0, 1]) that the fit carries but does not move (a nuisance at a grid value);
        ``rescan`` scans the profiled coordinates' profiles from the given start ``x0`` as from
        a grid start (a start whose other coordinates hold, at a changed nuisance)."""
        params = params_for(names, self.meta, self.vocab)
        k_all = len(params)
        fixed = dict(fixed or {})
        whole = part == "all" and sorted(set(runs)) == list(range(len(self.preps)))
        nuisance = [i for i in range(k_all) if params[i].nuisance is not None and i not in fixed]
        if nuisance and decide_nuisance and (whole or x0 is None):
            return self._fit_nuisance(names, runs, part, x0, max_nfev, grid, fixed,
                                      pin_unidentified, params, nuisance)
        # the pins the fit was asked for, apart from a pinned nuisance coordinate: that one is
        # the fit without it (effects_dict), which pins what it pins as it would alone
        asked = {i: v for i, v in fixed.items() if params[i].nuisance is None}
        profiled = [i for i in range(k_all) if i not in fixed and params[i].given is not None]
        held: dict[int, float] = {}
        if not whole and x0 is not None and (profiled or nuisance):
            # a kept nuisance (k) is held at the whole fit's value too: a fold or half has fewer
            # slips, and k free there would send h anywhere along their valley (correlation
            # about -0.99), a spread of the valley, not of h
            xa = np.asarray(x0, float)
            if xa.size == k_all:
                held = {i: float(np.clip(xa[i], 0, 1)) for i in [*profiled, *nuisance]}
        held.update({i: float(v) for i, v in (hold or {}).items() if i not in fixed})
        free = [i for i in range(k_all) if i not in fixed and i not in held]
        full0 = np.array([np.clip(p.to_x(p.neutral), 0, 1) for p in params])
        for i, v in {**fixed, **held}.items():
            full0[i] = v

        def expand(xf: np.ndarray) -> np.ndarray:
            x: np.ndarray = full0.copy()
            x[free] = xf
            return x

        def fun(xf: np.ndarray) -> np.ndarray:
            x = expand(xf)
            return self.residual(effects_dict(params, [p.from_x(v) for p, v in zip(params, x)],
                                              fixed), runs, part)

        profiled = [i for i in profiled if whole and i in free]
        nfev = 0
        if x0 is not None:
            x0 = np.asarray(x0, float)
            x0 = x0[free] if x0.size == k_all else x0
            for i in profiled if rescan else ():
                x0, n_p = self._profile_start(params, free, i, x0, expand, fun)
                nfev += n_p
        else:
            # the grid start keeps its levels of mu_s (at mu_k ~ mu_s: the only start with
            # mu_k above the nominal mu_s); the profile then scans mu_s at its mu_k
            x0, nfev = grid_start(fun, full0[free].copy(), grid)
            for i in profiled:   # the solve starts on the profile's minimum
                x0, n_p = self._profile_start(params, free, i, x0, expand, fun)
                nfev += n_p
        x0 = np.clip(np.asarray(x0, float), 1e-6, 1 - 1e-6)
        rest = [fi for fi, i in enumerate(free) if i not in profiled]
        if profiled and rest:
            # the gradient solve fits the other coordinates with the profiled ones held: it
            # cannot see a staircase, and its finite differences would move them across steps
            x_start = x0

            def fun_rest(xs: np.ndarray) -> np.ndarray:
                y = x_start.copy()
                y[rest] = xs
                return fun(y)
            xs, r, Js, ok, msg, n_solve = solve(fun_rest, x0[rest], grid, max_nfev)
            x = x0.copy()
            x[rest] = xs
            J = None
            if Js is not None:
                J = np.zeros((Js.shape[0], len(free)))
                J[:, rest] = Js
        else:
            x, r, J, ok, msg, n_solve = solve(fun, x0, grid, max_nfev)
        nfev += n_solve
        intervals: dict[int, ProfileInterval] = {}
        for i in profiled:   # the profile set at the solution, and its minimum if lower
            prof, x1, n_p = self._profile_set(params, free, i, x, r, expand, fun)
            nfev += n_p
            if prof is None:
                continue
            intervals[i] = prof
            if not np.array_equal(x1, x):
                r1 = fun(x1)
                nfev += 1
                if float(np.sum(r1 ** 2)) < float(np.sum(r ** 2)):
                    x, r = x1, r1
        xfull = expand(x)
        values = [p.from_x(v) for p, v in zip(params, xfull)]
        std = param_std(J, r, params, free, values)
        for i, prof in intervals.items():
            std[i] = prof.sigma
        out = FitResult(list(names), effects_dict(params, values, fixed), values,
                        np.asarray(xfull),
                        float(np.sum(r ** 2)), int(r.size), std, nfev, ok, msg,
                        [(p.effect, p.name) for p in params], fixed=fixed,
                        intervals={f"{params[i].effect}.{params[i].name}": v
                                   for i, v in intervals.items()})
        out.unidentified = [f"{params[i].effect}.{params[i].name}" for i in fixed
                            if params[i].nuisance is None]
        k_voc = len([i for i in free if params[i].nuisance is None])
        if pin_unidentified and not asked and k_voc >= 2 and ok:
            unid = [i for i in free if params[i].nuisance is None
                    and not (std[i] <= UNIDENTIFIED * params[i].span(values[i]))]
            # a profiled coordinate is pinned at the nominal model's point on its line
            # (solver.given_neutral) where the data allow it, else at the nearest value they
            # allow (its profile set)
            allowed = {i: (p.lo, p.hi) for i, p in intervals.items()}
            pins = {i: float(np.clip(params[i].to_x(min(max(self._line_neutral(
                        params, free, i, values), allowed[i][0]), allowed[i][1])), 0, 1))
                    if i in allowed else float(full0[i]) for i in unid}
            if len(unid) < k_voc:
                for i, pin in unidentified_given(params, free, xfull, values, r, expand, fun,
                                                 self.meta, allowed).items():
                    if i not in pins:
                        unid.append(i)
                        pins[i] = pin
            if unid and len(unid) < k_voc:
                re = self.fit(names, runs, part, x0=None, max_nfev=max_nfev, grid=grid,
                              fixed={**fixed, **pins}, decide_nuisance=decide_nuisance,
                              hold=hold)
                re.nfev += out.nfev
                re.intervals = {**out.intervals, **re.intervals}
                return re
        return out

    def _fit_nuisance(self, names: Sequence[str], runs: Sequence[int], part: str,
                      x0: np.ndarray | None, max_nfev: int, grid: int, fixed: Mapping[int, float],
                      pin_unidentified: bool, params: Sequence[Param], nuisance: Sequence[int]
                      ) -> FitResult:
        """A fit whose effects carry nuisance coordinates (``Param.nuisance``: the
        ``load_transfer`` fit's spin share k): first the fit without them (each pinned at its
        neutral value, where the effect does not carry it: exactly the fit of the nominal
        model's form), then from its point the fit with them free; the latter is kept only
        where it fits at least as well and every nuisance coordinate's 1-sigma is below its
        ``Param.nuisance`` (the data identify it beyond the nominal model's own knowledge),
        else the former.  A kept nuisance coordinate is fitted, so it counts in the fit's free
        parameters (``FitResult.n_free``: BIC); the held-out folds and the invariance halves hold
        it at this fit's value (:meth:`fit`)."""
        pins = {i: float(np.clip(params[i].to_x(params[i].neutral), 0, 1)) for i in nuisance}
        base = self.fit(names, runs, part, x0=x0, max_nfev=max_nfev, grid=grid,
                        fixed={**fixed, **pins}, pin_unidentified=pin_unidentified)
        if not base.ok:
            return base
        by_sigma = [i for i in nuisance if params[i].keep == "sigma"]
        by_ratio = [i for i in nuisance if params[i].keep == "ratio"]
        out = base
        if by_sigma:
            start = np.asarray(base.x, float).copy()
            for i in nuisance:
                start[i] = pins[i]
            free = self.fit(names, runs, part, x0=start, max_nfev=max_nfev, grid=grid,
                            fixed={**fixed, **{i: v for i, v in base.fixed.items()
                                               if i not in pins or i in by_ratio}},
                            pin_unidentified=False, decide_nuisance=False)
            free.nfev += base.nfev
            kept = (free.ok and free.rss <= base.rss
                    and all(free.std[i] < float(params[i].nuisance or 0.0) for i in by_sigma))
            out = free if kept else base
        for i in by_ratio:
            out = self._fit_creep(names, runs, part, max_nfev, grid, fixed, pin_unidentified,
                                  params, i, out, pins)
        return out

    def _fit_creep(self, names: Sequence[str], runs: Sequence[int], part: str, max_nfev: int,
                   grid: int, fixed: Mapping[int, float], pin_unidentified: bool,
                   params: Sequence[Param], i: int, base: FitResult, pins: Mapping[int, float]
                   ) -> FitResult:
        """The friction fit with its creep speed (``fit.params.creep_param``, coordinate ``i``):
        refitted from ``base``'s point with the creep held at each value of ``CREEP_GRID_M_S``
        (its cost is a staircase in it as in mu_s: a gradient does not see it) — mu_s's profile
        scanned afresh at the held mu_k and mu_k solved at the held mu_s, then further passes
        from the last point, mu_s's profile walked, while a pass lowers the cost by half a unit
        of s^2 n/n_eff (at most ``CREEP_PASSES``) —, the other nuisance coordinates as in
        ``base`` (kept: held there; else pinned); not tried where mu_s's profile set in ``base``
        is unbounded or the widest creep changes no residual (no wheel slides); the
        lowest of them is kept only where the fit without creep costs more by the
        ``CREEP_LEVEL`` point of chi-square with one degree of freedom on its residual scale
        s^2 n/n_eff (``solver.residual_variance``) — the fit without creep being the lower of
        ``base`` and the same fit started from the best creep fit's point (mu_s's profile
        scanned again there), so that the two are compared from the same start —; else
        ``base`` as it is.
        A kept creep counts in the fit's free parameters (BIC), is held at its value in the
        held-out folds and invariance halves (as a kept spin share), and carries its set over
        the grid (the values within the two-sided 95 % point of the lowest cost) in
        ``FitResult.nuisance_sets``."""
        others = {j: float(base.x[j]) for j in pins if j != i and j not in base.fixed}
        pinned = {j: v for j, v in pins.items() if j != i and j in base.fixed}
        fits = []
        nfev = base.nfev
        if any(iv.kind == "unbounded" for k, iv in base.intervals.items()
               if k.startswith(params[i].effect + ".")):
            # the creep shapes a breakaway; where mu_s's profile set has no edge (every wheel
            # slides from the first tick), the data hold no breakaway to shape, and a creep there
            # would stand in for whatever else differs at the start of a slide
            return base
        r_base = self.residual(base.params, runs, part)
        # the creep acts only while a wheel slides: where the fit without it slides nowhere, the
        # widest creep leaves every residual as it is and the data say nothing of it
        probe = {e: dict(p) for e, p in base.params.items()}
        probe.setdefault(params[i].effect, {})[params[i].name] = CREEP_GRID_M_S[-1]
        nfev += 2
        if np.array_equal(self.residual(probe, runs, part), r_base):
            base.nfev = nfev
            return base
        unit = residual_variance(r_base, base.n_free)
        for v in CREEP_GRID_M_S:
            x0 = np.asarray(base.x, float).copy()
            x0[i] = float(np.clip(params[i].to_x(v), 0, 1))
            f = None
            for k in range(CREEP_PASSES):
                # the first pass scans mu_s's profile afresh; the later ones walk it from the
                # last point (Problem._profile_set, at the end of every fit of all runs)
                g = self.fit(names, runs, part, x0=x0, max_nfev=max_nfev, grid=grid,
                             fixed={**fixed, **pinned}, pin_unidentified=pin_unidentified,
                             decide_nuisance=False, rescan=k == 0,
                             hold={i: x0[i], **others})
                nfev += g.nfev
                if not g.ok or (f is not None and g.rss >= f.rss):
                    break
                gain = math.inf if f is None else f.rss - g.rss
                f, x0 = g, np.asarray(g.x, float).copy()
                if gain < 0.5 * unit:   # under half a unit of chi-square: settled
                    break
            if f is not None:
                fits.append((v, f))
        if not fits:
            return base
        best = min(fits, key=lambda t: t[1].rss)[1]
        # the fit without creep gets the same start: from the best creep fit's point, mu_s's
        # profile scanned again (mu_s's and mu_k's staircases leave a fit where it started)
        x0 = np.asarray(best.x, float).copy()
        x0[i] = pins[i]
        again = self.fit(names, runs, part, x0=x0, max_nfev=max_nfev, grid=grid,
                         fixed={**fixed, **pinned, i: pins[i]}, pin_unidentified=pin_unidentified,
                         decide_nuisance=False, rescan=True, hold=others)
        nfev += again.nfev
        null = again if again.ok and again.rss < base.rss else base
        scale = residual_variance(self.residual(null.params, runs, part), null.n_free)
        if null.rss - best.rss <= float(chi2.ppf(CREEP_LEVEL, 1)) * scale:
            # not kept: the fit as it was (the refit from the creep's start is the test's
            # reference only; where mu_s's cost is flat it moves mu_s along the flat)
            base.nfev = nfev
            return base
        within = [v for v, f in fits
                  if f.rss - best.rss <= float(chi2.ppf(PROFILE_LEVEL, 1)) * scale]
        best.nuisance_sets = {params[i].name: (min(within), max(within))}
        best.nfev = nfev
        return best

    def _line_neutral(self, params: Sequence[Param], free: Sequence[int], i: int,
                      values: Sequence[float]) -> float:
        """The nominal model's point on coordinate ``i``'s given line through ``values``
        (solver.given_neutral); its neutral value without such a line."""
        line = given_line(params, free, i, values, self.meta)
        if line is None:
            return float(params[i].neutral)
        j, held_v, lo, hi, _ = line
        return given_neutral(params, i, j, held_v, lo, hi)

    def _given_cost(self, params: Sequence[Param], free: Sequence[int], i: int,
                    xf: np.ndarray, expand: Callable[[np.ndarray], np.ndarray],
                    fun: Callable[[np.ndarray], np.ndarray]
                    ) -> tuple[Callable[[float], np.ndarray], Callable[[float], float], float,
                               float, float, float] | None:
        """Along the line through ``xf`` that holds coordinate ``i``'s given quantity
        (``solver.given_line``; the other coordinates held: mu_k barely moves along mu_s's
        profile): (value -> free coordinates, value -> cost, the possible range's ends, the
        current value, the nominal model's point on the line: ``solver.given_neutral``); None
        without such a line."""
        x = expand(xf)
        values = [p.from_x(v) for p, v in zip(params, x)]
        line = given_line(params, free, i, values, self.meta)
        if line is None:
            return None
        j, held_v, lo, hi, coords = line
        fi, fj = list(free).index(i), list(free).index(j)

        def at(v: float) -> np.ndarray:
            y = np.array(xf, float)
            y[fi], y[fj] = coords(v)
            out: np.ndarray = np.clip(y, 0.0, 1.0)
            return out

        def cost(v: float) -> float:
            return float(np.sum(fun(at(v)) ** 2))

        return (at, cost, lo, hi, min(max(values[i], lo), hi),
                given_neutral(params, i, j, held_v, lo, hi))

    def _profile_start(self, params: Sequence[Param], free: Sequence[int], i: int,
                       xf: np.ndarray, expand: Callable[[np.ndarray], np.ndarray],
                       fun: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, int]:
        """(``xf`` moved to the minimum of coordinate ``i``'s profile scan over its possible
        range (``solver.profile_scan``) — on a flat minimum, where the likelihood prefers no
        point, its point nearest the nominal model's point on the line —, evaluations)."""
        g = self._given_cost(params, free, i, xf, expand, fun)
        if g is None:
            return xf, 0
        at, cost, lo, hi, _, v_nom = g
        coarse, fine = profile_steps(params[i].tol, lo, hi)
        pts = profile_scan(cost, lo, hi, coarse, fine)
        a, b = flat_minimum(pts)
        return at(min(max(v_nom, a), b)), len(pts)

    def _profile_set(self, params: Sequence[Param], free: Sequence[int], i: int,
                     xf: np.ndarray, r: np.ndarray, expand: Callable[[np.ndarray], np.ndarray],
                     fun: Callable[[np.ndarray], np.ndarray]
                     ) -> tuple[ProfileInterval | None, np.ndarray, int]:
        """Coordinate ``i``'s profile set around the solution ``xf`` (residual ``r``): the cost
        walked outwards from it in coarse steps until it leaves the two-sided threshold
        (``solver.profile_walk``), the edges then located to the fine step
        (``solver.profile_interval``; the threshold's scale s^2 n/n_eff from ``r``).  Returns
        (the set, ``xf`` moved to the lowest point seen — on a flat minimum, its point nearest
        the nominal model's point on the line —, evaluations)."""
        g = self._given_cost(params, free, i, xf, expand, fun)
        if g is None:
            return None, xf, 0
        at, cost, lo, hi, v0, v_nom = g
        coarse, fine = profile_steps(params[i].tol, lo, hi)
        c0 = float(np.sum(r ** 2))
        scale = residual_variance(r, len(free))
        pts = profile_walk(cost, v0, c0, lo, hi, coarse, float(chi2.ppf(PROFILE_LEVEL, 1)) * scale)
        n0 = len(pts) - 1
        e_lo, e_hi, kind, sigma = profile_interval(cost, pts, lo, hi, fine, scale)
        a, b = flat_minimum(pts)
        flat_best = min(max(v_nom, a), b)
        prof = ProfileInterval(e_lo, e_hi, kind, PROFILE_LEVEL, sigma, flat_best, (a, b),
                               (lo, hi), fine, len(pts) - 1)
        best = v0 if pts[v0] <= min(pts.values()) else flat_best
        return prof, at(best), max(n0, len(pts) - 1)


def _effects_key(effects: Mapping[str, Mapping[str, float]]
                 ) -> tuple[tuple[str, tuple[tuple[str, str], ...]], ...]:
    """A hashable key of ``effects`` that tells apart any two that differ in a bit of a
    parameter (float.hex), so that a cached replay is only ever reused for the same input."""
    return tuple(sorted((str(e), tuple(sorted((str(k), float(v).hex()) for k, v in ps.items())))
                        for e, ps in effects.items()))
