"""Signal-level pieces of the analyzer that need no physics: noise floors estimated
from the data, significant windows of a residual, and the operating regime that
best explains where a residual is significant."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np


def robust_std(x: np.ndarray) -> float:
    """1.4826 * median absolute deviation (a Gaussian's std), ignoring NaN."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def hf_noise_std(resid: np.ndarray) -> float:
    """Std of the white part of a residual, from its second differences.

    A smooth mismatch (drift, bias, slow dynamics) has small second differences;
    white noise of std s has second differences of std s*sqrt(6).  The MAD keeps
    a few steps (an edge of a mismatch) from inflating the estimate."""
    r = np.asarray(resid, dtype=float)
    r = r[np.isfinite(r)]
    if r.size < 5:
        return 0.0
    return cast(float, robust_std(np.diff(r, 2)) / np.sqrt(6.0))


def quantization_std(step: float) -> float:
    """Std of the difference of two independent uniform quantization errors of one step
    (e.g. a speed from two encoder readings)."""
    return cast(float, float(step) / np.sqrt(6.0))


def clipped_reading_mean(m: np.ndarray, sigma: float) -> np.ndarray:
    """The mean reading of a sense that reads the magnitude ``m`` >= 0 with Gaussian noise of
    std ``sigma`` and no negative values (an ADC clips at 0 counts): E[max(0, m + n)] =
    m Phi(m / sigma) + sigma phi(m / sigma).  At m = 0 it reads sigma / sqrt(2 pi) (0.40 sigma)
    on average, within 1 % of sigma of m from m = 2 sigma on.  The ADC's rounding to counts
    changes it by under 0.02 sigma for sigma of a count or more (the sum over the counts is the
    integral's midpoint rule; at half a count 0.08 sigma at nil).  ``sigma`` <= 0: ``m``
    itself."""
    m = np.asarray(m, float)
    if not sigma > 0:
        return m
    from scipy.special import ndtr
    u = m / sigma
    return cast(np.ndarray, m * ndtr(u) + sigma * np.exp(-0.5 * u * u) / math.sqrt(2 * math.pi))


def count_rate_band(dt: np.ndarray, dt_ref: float, count: float) -> np.ndarray:
    """Per sample of a rate from two cumulative counts ``dt`` apart (a wheel speed from the
    encoder counts of two frames, ``count`` its unit per count): how much its quantization
    spreads beyond that of a sample ``dt_ref`` apart, which the noise floor already holds
    (``quantization_std(count / dt_ref)``, ``dt_ref`` the median frame interval).  The count
    difference is off by up to a count whatever the interval, so in rate units its std is
    ``quantization_std(count / dt)``: a frame 4 ms after its neighbour (±9 ms jitter on
    20 ms frames) reads a speed five times as coarse as the floor's.  The excess
    ``sqrt(max(q(dt)^2 - q(dt_ref)^2, 0))`` is joined to the floor in quadrature like the
    replay's other spreads (``Channel.deflated``); nil at and beyond ``dt_ref``, so a
    recorder with regular frames is compared as before."""
    dt = np.asarray(dt, float)
    if dt_ref <= 0 or count <= 0:
        return np.zeros(dt.size)
    q = quantization_std(count) / np.where(dt > 0, dt, np.inf)
    q_ref = quantization_std(count / dt_ref)
    out: np.ndarray = np.sqrt(np.maximum(q ** 2 - q_ref ** 2, 0.0))
    # the same interval up to the round-off of a difference of two times
    out[dt >= dt_ref * (1.0 - 1e-9)] = 0.0
    return out


def quantization_step(x: np.ndarray, rel_tol: float = 0.1) -> float:
    """The quantization step of a recorded column: its smallest non-zero difference between
    samples, when the other differences are whole multiples of it (within ``rel_tol`` of a
    step, for the rounding of a CSV file); 0 for a column that is not quantized so."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return 0.0
    d = np.abs(np.diff(x))
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    d = d[d > 1e-9 * max(scale, 1e-300)]
    if d.size == 0:
        return 0.0
    step = float(np.min(d))
    m = d / step
    if np.median(np.abs(m - np.round(m))) > rel_tol:
        return 0.0
    # the mean of the differences that round to one step (less sensitive to the file's rounding)
    one = d[np.round(m) == 1]
    return float(np.mean(one)) if one.size else step


def smooth(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over n samples (n odd), edges shrunk."""
    x = np.asarray(x, dtype=float)
    if n <= 1 or x.size == 0:
        return cast(np.ndarray, x.copy())
    n = int(n) | 1
    k = np.ones(n)
    num = np.convolve(x, k, mode="same")
    den = np.convolve(np.ones_like(x), k, mode="same")
    return num / den


@dataclass
class Window:
    t_start_s: float
    t_end_s: float
    i0: int
    i1: int  # inclusive
    rms: float


def missing_sample_gap_s(t: np.ndarray) -> float:
    """The longest interval between two neighbouring samples of the series sampled at ``t``
    (sorted, at least two) that misses none: one and a half of its usual (median) interval,
    jitter included, short of a missing sample."""
    return 1.5 * float(np.median(np.diff(np.asarray(t, dtype=float))))


def significant_windows(t: np.ndarray, resid: np.ndarray, floor: float, k: float = 3.0,
                        smooth_n: int = 5, min_len: int = 3, merge_gap_s: float = 0.06
                        ) -> tuple[list[Window], np.ndarray]:
    """Windows where the smoothed |residual| exceeds k * floor / sqrt(smooth_n) and the raw
    RMS over the window exceeds k * floor... in short: sustained, not single spikes.
    Significant samples at most ``merge_gap_s`` apart are one window, and so are those no
    further apart than one and a half of the channel's usual (median) sampling interval: its
    neighbours, jitter included, short of a missing sample.  By ``merge_gap_s`` alone, each
    significant sample of a channel sampled slower than it (65 ms telemetry, a 10 Hz camera)
    would be a window of its own, too short to count, and nothing there could stand out.

    Returns the windows and the boolean significance mask (per sample)."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(resid, dtype=float)
    if r.size < max(min_len, smooth_n) or t.size != r.size or floor <= 0:
        return [], np.zeros(r.shape, bool)
    n = min(smooth_n, max(1, r.size))
    s = smooth(r, n)
    thr = k * floor / np.sqrt(n)
    # a smoothed residual of pure noise has std floor/sqrt(n); demand also a raw size
    mask = (np.abs(s) > max(thr, 1.0 * floor))
    idx = np.flatnonzero(mask)
    windows: list[Window] = []
    if idx.size:
        gap_s = max(merge_gap_s, missing_sample_gap_s(t))
        starts = [idx[0]]
        ends = []
        for a, b in zip(idx[:-1], idx[1:]):
            if t[b] - t[a] > gap_s:
                ends.append(a)
                starts.append(b)
        ends.append(idx[-1])
        for i0, i1 in zip(starts, ends):
            if i1 - i0 + 1 < min_len:
                mask[i0:i1 + 1] = False
                continue
            seg = r[i0:i1 + 1]
            rms = float(np.sqrt(np.mean(seg ** 2)))
            if rms < k * floor / np.sqrt(i1 - i0 + 1) or rms < floor:
                mask[i0:i1 + 1] = False
                continue
            mask[i0:i1 + 1] = True
            windows.append(Window(float(t[i0]), float(t[i1]), int(i0), int(i1), rms))
    return windows, mask


# --------------------------------------------------------------------------- regimes


@dataclass
class Regime:
    description: str
    score: float  # F1 of the predicate against the significance mask, 0..1
    mask: np.ndarray


def regime_candidates(state: dict[str, np.ndarray], tau_max: float | None
                      ) -> list[tuple[str, np.ndarray]]:
    """Named predicates over the operating state at each sample.

    ``state`` holds arrays on one time base: ``t``, ``w_r``, ``w_l`` (wheel speeds, rad/s),
    ``a_r``, ``a_l`` (wheel accelerations, rad/s^2), ``tau_r``, ``tau_l`` (torque command),
    ``u_r``, ``u_l`` (duty) and ``yaw`` (yaw rate, rad/s)."""
    t = state["t"]
    out: list[tuple[str, np.ndarray]] = []
    wmax = np.maximum(np.abs(state["w_r"]), np.abs(state["w_l"]))
    amax = np.maximum(np.abs(state["a_r"]), np.abs(state["a_l"]))
    top = float(np.max(wmax)) if wmax.size else 0.0
    for q in np.linspace(0.1, 0.9, 9):
        thr = round(q * top, 1)
        if thr > 0:
            out.append((f"wheel speed above {thr:g} rad/s", wmax > thr))
            out.append((f"wheel speed below {thr:g} rad/s", wmax < thr))
    atop = float(np.max(amax)) if amax.size else 0.0
    for q in (0.1, 0.2, 0.3, 0.5):
        thr = round(q * atop, 0)
        if thr > 0:
            out.append((f"during acceleration (|wheel acceleration| above {thr:g} rad/s^2)",
                        amax > thr))
    amean = 0.5 * (state["a_r"] + state["a_l"])
    wmean = 0.5 * (state["w_r"] + state["w_l"])
    if atop > 0:
        out.append(("while speeding up", amean * np.sign(wmean + 1e-12) > 0.1 * atop))
        out.append(("while slowing down", amean * np.sign(wmean + 1e-12) < -0.1 * atop))
        out.append(("at steady speed", amax < 0.1 * atop))
    if tau_max is not None and tau_max > 0:
        tmax = np.maximum(np.abs(state["tau_r"]), np.abs(state["tau_l"]))
        out.append((f"when the torque command exceeds tau_max ({tau_max:.3g} N m)",
                    tmax > 0.98 * tau_max))
        out.append(("when the torque command is near tau_max (above 80 %)",
                    tmax > 0.8 * tau_max))
    umax = np.maximum(np.abs(state["u_r"]), np.abs(state["u_l"]))
    for thr in (0.05, 0.1, 0.2):
        out.append((f"when the duty is small (|pwm| below {thr:g})", umax < thr))
    ytop = float(np.max(np.abs(state["yaw"]))) if state["yaw"].size else 0.0
    if ytop > 0.05:
        out.append(("only in turns", np.abs(state["yaw"]) > max(0.2 * ytop, 0.05)))
        out.append(("only on straight segments", np.abs(state["yaw"]) < max(0.2 * ytop, 0.05)))
    if t.size:
        for q in (0.25, 0.5, 0.75):
            thr = round(float(t[0] + q * (t[-1] - t[0])), 2)
            out.append((f"after t = {thr:g} s", t > thr))
        out.append(("everywhere the robot moves", wmax > 0.05 * max(top, 1e-9)))
    return out


def best_regime(mask: np.ndarray, candidates: list[tuple[str, np.ndarray]]) -> Regime | None:
    """The predicate whose samples best coincide with the significance mask (F1 score)."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return None
    best: Regime | None = None
    for desc, pred in candidates:
        pred = np.asarray(pred, bool)
        if pred.shape != mask.shape or not pred.any():
            continue
        tp = float(np.sum(pred & mask))
        prec = tp / float(np.sum(pred))
        rec = tp / float(np.sum(mask))
        f1 = 0.0 if tp == 0 else 2 * prec * rec / (prec + rec)
        if best is None or f1 > best.score + 1e-12:
            best = Regime(desc, f1, pred)
    return best


# ----------------------------------------------------------------- sparse regression


def stlsq(X: np.ndarray, y: np.ndarray, names: list[str], threshold: float = 0.1,
          iters: int = 10, max_terms: int = 4) -> dict[str, float]:
    """Sequentially thresholded least squares (the SINDy regression) on standardized
    features; returns {feature name: coefficient in original units} of the kept terms."""
    X = np.asarray(X, float)
    y = np.asarray(y, float)
    ok = np.all(np.isfinite(X), axis=1) & np.isfinite(y)
    X, y = X[ok], y[ok]
    if y.size < 5:
        return {}
    scale = np.std(X, axis=0)
    scale[scale == 0] = 1.0
    Z = X / scale
    ys = float(np.std(y)) or 1.0
    keep = np.ones(Z.shape[1], bool)
    coef = np.zeros(Z.shape[1])
    for _ in range(iters):
        if not keep.any():
            break
        c, *_ = np.linalg.lstsq(Z[:, keep], y / ys, rcond=None)
        coef[:] = 0
        coef[keep] = c
        small = np.abs(coef) < threshold
        if keep.sum() > max_terms:
            order = np.argsort(-np.abs(coef))
            small |= ~np.isin(np.arange(coef.size), order[:max_terms])
        new_keep = keep & ~small
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return {names[i]: float(coef[i] * ys / scale[i]) for i in np.flatnonzero(keep)
            if coef[i] != 0}


def r_squared(y: np.ndarray, yhat: np.ndarray) -> float:
    y = np.asarray(y, float)
    ss = float(np.sum((y - np.mean(y)) ** 2))
    return 0.0 if ss == 0 else 1.0 - float(np.sum((y - yhat) ** 2)) / ss


def round_sig(v: float, sig: int = 4) -> float:
    """``v`` to ``sig`` significant digits, as the report gives its figures (None for a value
    that is not finite, which JSON cannot carry)."""
    if v == 0 or not math.isfinite(v):
        return float(v) if math.isfinite(v) else None  # type: ignore[return-value]
    return float(f"{v:.{sig}g}")
