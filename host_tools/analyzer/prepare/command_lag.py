"""How much later the duty in force (``pwm_*``) follows the controller's torque command
(``tau_cmd_*``): the command-to-duty delay that a duty-driven replay cannot see.

Model.  The controller sets a torque command and the duty it maps to at each inner tick; a
frame at time t reports the latest tick's command, and a recorder whose ``pwm_*`` is the duty
in force reports the duty of the latest tick at or before t - d (d the actuation delay).  The
torque-to-duty map of a DC-motor drive is linear in the command and the wheel speed at the
tick (lib/control: u = tau/stall + omega/no_load, saturated), so

    pwm(t) = a tau_cmd(k(t - d)) + b omega(k(t - d)) + c,    k(s) = the latest tick <= s,

with a, b, c fitted per run and wheel by least squares (the same form holds for a recorder
whose map has other coefficients; a recorder without ``omega_*`` drops that term).  The tick
grid is the one the prepare stage found (``inner_period``, ``tick_phase``); a tick no frame
reported gets the line between its reported neighbours; without a tick phase the frames are
the grid.  Frames with a saturated duty are left out (the map is not linear there), and every
d is scored on the same frames (those whose t - D_MAX_S lies inside the run).

Decision.  The residual sum of squares RSS(d) is a step function of d (a frame changes source
tick only where t - d crosses a tick), so the estimate is the centre of the step of least
RSS.  Against d = 0 the test is the drop in RSS in units of the residual variance per
effective sample: F = (RSS(0) - RSS(d)) / (RSS(d) / n_eff), n_eff = n (1 - rho) / (1 + rho)
with rho the residuals' lag-1 autocorrelation (the residual of a frame repeats over the
frames of one tick).  A lag is significant when F >= F_SIGNIFICANT (chi-square with one
degree of freedom at 5 sigma, for the search over the steps of d) and the estimate exceeds
Z_ESTIMATE of its standard errors; the standard error is the
larger of the step's width over sqrt(12) (where inside the step d lies is not seen) and the
half-width of the d range within one residual variance of the minimum."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence, cast

import numpy as np

from host_tools.analyzer.prepare.timing import _feasible_arc

if TYPE_CHECKING:
    from host_tools.analyzer.prepare.run import PreparedRun

D_MAX_S = 0.15          # search range: above the vocabulary's actuation_delay bound (0.1 s)
D_STEP_S = 0.0005
SATURATED = 0.995       # |duty| at or above this is saturated (left out)
F_SIGNIFICANT = 25.0    # chi-square(1) at 5 sigma
Z_ESTIMATE = 2.33       # the estimate must exceed this many standard errors (one-sided 1 %)
JACKKNIFE_BLOCKS = 8    # per run, for the standard error
COLUMNS = ("tau_cmd_r", "tau_cmd_l", "pwm_r", "pwm_l")


def _tick_series(t: np.ndarray, x: np.ndarray, k: np.ndarray, k0: int, n_k: int) -> np.ndarray:
    """The value of ``x`` at each tick k0 .. k0 + n_k - 1: the first frame that reported the
    tick; a tick no frame reported gets the line between its reported neighbours."""
    ks, first = np.unique(k, return_index=True)
    return cast(np.ndarray, np.interp(np.arange(k0, k0 + n_k), ks, x[first]))


class _RunLag:
    """One run's data for the scan over d."""

    def __init__(self, prep: PreparedRun, d_max: float) -> None:
        tel = prep.run.telemetry
        self.t = np.asarray(tel["t_s"], float)
        T, phase = float(prep.inner_period or 0.0), prep.tick_phase
        # the ticks are where the torque commands change (the prepared phase comes from the
        # duty, whose changes a delay moves off the ticks): the centre of their feasible arc
        self.phase_sd = 0.0
        arc = _feasible_arc(self.t, [np.asarray(tel[c], float) for c in COLUMNS[:2]], T) \
            if T > 0 else None
        if arc is not None:
            phase, self.phase_sd = (arc[0] + 0.5 * arc[1]) % T, arc[1] / math.sqrt(12.0)
        if T > 0 and phase is not None:
            self.T, self.phase = T, float(phase)
            k = np.floor((self.t - self.phase) / T + 1e-9).astype(int)
        else:   # the frames are the grid: tick j at frame j
            self.T, self.phase = 0.0, 0.0
            k = np.arange(self.t.size)
        self.k0 = int(k.min())
        n_k = int(k.max()) - self.k0 + 1
        self.wheels = []
        tick_tau = None
        if self.T > 0 and getattr(prep, "torque", None) is not None and prep.t_in_tau.size:
            kt = np.round((np.asarray(prep.t_in_tau, float) - self.phase) / T).astype(int) - self.k0
            on_grid = np.abs(prep.t_in_tau - (self.phase + (kt + self.k0) * T)) < 1e-6
            if on_grid.all():
                tick_tau = (kt, [np.asarray(x, float) for x in prep.torque])
        use = self.t - d_max >= self.t[0]
        for s in ("r", "l"):
            pwm = np.asarray(tel[f"pwm_{s}"], float)
            cols = [np.asarray(tel[f"tau_cmd_{s}"], float)]
            if f"omega_{s}" in tel:
                cols.append(np.asarray(tel[f"omega_{s}"], float))
            keep = use & (np.abs(pwm) < SATURATED) & np.isfinite(pwm)
            if keep.sum() < 10 or np.ptp(cols[0]) <= 0:
                continue
            series = [_tick_series(self.t, c, k, self.k0, n_k) for c in cols]
            if tick_tau is not None:   # the prepared per-tick commands (unreported ticks filled)
                kt, tau_t = tick_tau[0], tick_tau[1][0 if s == "r" else 1]
                inside = (kt >= 0) & (kt < n_k)
                series[0][kt[inside]] = tau_t[inside]
            self.wheels.append((np.flatnonzero(keep), pwm, series))

    def source_tick(self, d: float) -> np.ndarray:
        if self.T > 0:
            k = np.floor((self.t - d - self.phase) / self.T + 1e-9).astype(int)
        else:   # latest frame at or before t - d
            k = np.searchsorted(self.t, self.t - d + 1e-9, side="right") - 1
        return cast(np.ndarray, np.maximum(k - self.k0, 0))

    def residuals(self, d: float) -> list[np.ndarray]:
        src = self.source_tick(d)
        out = []
        for idx, pwm, series in self.wheels:
            s = src[idx]
            A = np.column_stack([x[s] for x in series] + [np.ones(idx.size)])
            coef, *_ = np.linalg.lstsq(A, pwm[idx], rcond=None)
            out.append(pwm[idx] - A @ coef)
        return out

    def block_rss(self, d: float) -> np.ndarray:
        """The residual sum of squares of each of JACKKNIFE_BLOCKS contiguous time blocks."""
        out = np.zeros(JACKKNIFE_BLOCKS)
        span = max(float(self.t[-1] - self.t[0]), 1e-9)
        for (idx, _, _), r in zip(self.wheels, self.residuals(d)):
            b = np.minimum((JACKKNIFE_BLOCKS * (self.t[idx] - self.t[0]) / span).astype(int),
                           JACKKNIFE_BLOCKS - 1)
            out += np.bincount(b, weights=r * r, minlength=JACKKNIFE_BLOCKS)
        return out


def _best_step(rss: np.ndarray) -> tuple[int, int]:
    """(first, last) grid index of the step of least RSS."""
    j = int(np.argmin(rss))
    tie = rss[j] + 1e-9 * max(rss[j], 1e-30)
    lo = hi = j
    while lo > 0 and rss[lo - 1] <= tie:
        lo -= 1
    while hi < rss.size - 1 and rss[hi + 1] <= tie:
        hi += 1
    return lo, hi


def _rho(res: Sequence[np.ndarray]) -> float:
    num = den = 0.0
    for r in res:
        r = r - r.mean()
        num += float(r[1:] @ r[:-1])
        den += float(r @ r)
    return min(max(num / den, 0.0), 0.99) if den > 0 else 0.0


def command_lag(preps: Sequence[PreparedRun], d_max: float = D_MAX_S, d_step: float = D_STEP_S
                ) -> dict[str, Any] | None:
    """The lag of the duty in force behind the torque command over the runs (model above):
    ``delay_s`` (0 when not significant), ``estimate_s`` and ``std_s`` of the best step, ``F``,
    ``n``, ``n_eff``, ``significant``.  None when no run has both columns moving."""
    runs = []
    for p in preps:
        tel = p.run.telemetry
        if not all(c in tel for c in COLUMNS) or len(tel["t_s"]) < 20:
            continue
        rl = _RunLag(p, d_max)
        if rl.wheels:
            runs.append(rl)
    if not runs:
        return None
    grid = np.arange(0.0, d_max + 0.5 * d_step, d_step)
    blocks = np.array([np.concatenate([rl.block_rss(d) for rl in runs]) for d in grid])
    rss = blocks.sum(axis=1)
    lo, hi = _best_step(rss)
    j = lo
    best = rss[j]

    def centre(a: int, b: int) -> float:
        return 0.5 * (grid[a] + grid[b] + d_step) if a > 0 else 0.0

    # jackknife over the time blocks: how far the best step moves without each block (the
    # residual is not white where a tick's command is unreported, so the curvature of RSS(d)
    # alone understates the spread)
    used = np.flatnonzero(blocks.sum(axis=0) > 0)
    jk = np.array([centre(*_best_step(rss - blocks[:, b])) for b in used])
    jk_sd = math.sqrt((jk.size - 1) / jk.size * float(np.sum((jk - jk.mean()) ** 2))) \
        if jk.size > 1 else 0.0
    res = [r for rl in runs for r in rl.residuals(float(grid[j]))]
    n = sum(r.size for r in res)
    rho = _rho(res)
    n_eff = n * (1.0 - rho) / (1.0 + rho)
    var = best / n_eff if best > 0 else 0.0
    F = (rss[0] - best) / var if var > 0 else (math.inf if rss[0] > best else 0.0)
    d_hat = centre(lo, hi)
    within = np.flatnonzero(rss <= best + var)
    half = 0.5 * (grid[within.max()] - grid[within.min()] + d_step)
    phase_sd = max(rl.phase_sd for rl in runs)
    std = math.hypot(max((grid[hi] - grid[lo] + d_step) / math.sqrt(12.0), half, jk_sd), phase_sd)
    # and the estimate itself away from zero by its own standard error (one-sided 1 %, the
    # held-out rule's rate): a residual drop the step search finds at a delay within its error of
    # zero (this firmware's duty ramped every millisecond after a 0.64 ms computation: 2.7 +-
    # 2.8 ms on its nominal runs) is no lag
    significant = bool(F >= F_SIGNIFICANT and lo > 0 and d_hat > Z_ESTIMATE * std)
    return {"delay_s": float(d_hat) if significant else 0.0, "estimate_s": float(d_hat),
            "std_s": float(std), "F": float(F), "n": int(n), "n_eff": float(n_eff),
            "significant": significant,
            "grid": "ticks" if all(rl.T > 0 for rl in runs) else "frames"}


def select_command_delay(preps: Sequence[PreparedRun], selected: list[dict[str, Any]],
                         verdict: str, effects: Mapping[str, Mapping[str, float]],
                         notes: list[str], log: Callable[[str], None]
                         ) -> tuple[str, dict[str, Mapping[str, float]]]:
    """The command-to-duty delay (:func:`command_lag`): where the recorded duty (the duty in
    force) lags the torque command significantly, ``actuation_delay`` is selected with the lag
    as ``delay_s`` (and its standard error), the updated model gets it, and a note says so.
    The duty replay, driven by that duty in force, cannot see such a delay, so it is neither
    fitted there nor added to the replays' effects; a run without the delay's signature leaves
    the verdict as the replays decided it.  Returns (verdict, the updated model's effects)."""
    lag = command_lag(preps)
    if lag is None or not lag["significant"] or "actuation_delay" in effects:
        return verdict, dict(effects)
    d, sd = lag["delay_s"], lag["std_s"]
    log(f"command-to-duty lag: {1e3 * d:.1f} +- {1e3 * sd:.1f} ms (F = {lag['F']:.3g})")
    notes.append(f"the recorded duty lags the torque command by {1e3 * d:.1f} +- {1e3 * sd:.1f} ms "
                 f"(F = {lag['F']:.3g} against no lag, {lag['n_eff']:.0f} effective samples): "
                 "actuation_delay selected from the command-to-duty lag, which the duty replay "
                 "(driven by the duty in force) cannot see")
    selected.append({"effect": "actuation_delay", "params": {"delay_s": round(d, 4)},
                     "std": {"delay_s": round(sd, 4)}, "unidentified": [], "equivalent": [],
                     "separating_measurement": {}, "from": "command_lag"})
    return ("explained" if verdict == "no_mismatch" else verdict,
            {**effects, "actuation_delay": {"delay_s": d}})
