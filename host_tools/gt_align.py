"""Ground truth for a recorded run: an external tracker's CSV aligned to the board clock.

``python -m host_tools log --out RUN_DIR --attach-groundtruth TRACKER.csv`` adds the tracker's
track (columns t_s, x_m, y_m, optional phi_rad, on the tracker's own clock) to a recorded run
as groundtruth.csv, shifting its time by ``--gt-offset``, by an offset estimated by
cross-correlating the speed from odometry with the speed from the tracker, or
(``--gt-unix-time``, a tracker stamped by a PC clock) through the logger's own host clock
recorded in meta.json; meta.json gets a "groundtruth" section saying how.
"""
from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from host_tools import runfmt


MAX_OFFSET_S = 86_400.0   # --gt-max-offset bound: a tracker clock a day off is not "unsynchronised"
GRID_DT_S = 0.01          # speed grid of the cross-correlation
MAX_GRID = 20_000_000     # samples of one speed grid (55 h at 10 ms, 160 MB): longer is a glitch


class GroundTruthError(Exception):
    """The tracker's file cannot be aligned; ``code`` is the exit code (1 failed, 2 bad input)."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


def estimate_offset(t_tel: np.ndarray, x_odo: np.ndarray, y_odo: np.ndarray,
                    t_trk: np.ndarray, x_trk: np.ndarray, y_trk: np.ndarray,
                    max_offset_s: float = 10.0, dt: float = GRID_DT_S,
                    labels: tuple[str, str] = ("telemetry", "tracker")) -> tuple[float, float]:
    """Offset (s) such that t_board = t_tracker + offset, by cross-correlating the speed along
    the path from odometry with that from the tracker.  Returns (offset, peak correlation)."""
    def speed(t, x, y, what):
        n = (t[-1] - t[0]) / dt
        if not n <= MAX_GRID:  # a clock glitch (one stamp years off) must not allocate TiB
            k = int(np.argmax(np.diff(t)))
            raise GroundTruthError(
                f"{what}: spans {t[-1] - t[0]:.6g} s, more than the {MAX_GRID * dt:.6g} s this "
                f"alignment takes; the largest step is {t[k + 1] - t[k]:.6g} s, before data row "
                f"{k + 2} (a clock glitch?); fix the times or pass --gt-offset", 2)
        g = np.arange(t[0], t[-1], dt)
        if g.size < 4:
            raise GroundTruthError("too few samples to estimate the clock offset; pass --gt-offset", 2)
        xi, yi = np.interp(g, t, x), np.interp(g, t, y)
        s = np.hypot(np.gradient(xi, dt), np.gradient(yi, dt))
        k = max(1, int(round(0.05 / dt)))  # 50 ms moving average against tracker noise
        s = np.convolve(s, np.ones(k) / k, mode="same")
        # tracker dropouts: no speed where the original samples are further apart than 0.25 s
        idx = np.searchsorted(t, g)
        idx = np.clip(idx, 1, len(t) - 1)
        gap = (t[idx] - t[idx - 1]) > 0.25
        s[gap] = np.nan
        return g, s

    if not (math.isfinite(max_offset_s) and 0 < max_offset_s <= MAX_OFFSET_S):
        raise GroundTruthError(f"--gt-max-offset {max_offset_s:g} must be in (0, {MAX_OFFSET_S:g}] s", 2)
    g_a, s_a = speed(t_tel, x_odo, y_odo, labels[0])
    g_b, s_b = speed(t_trk, x_trk, y_trk, labels[1])
    # beyond these lags the two recordings cannot overlap at all: never searched
    lo = max(-max_offset_s, g_a[0] - g_b[-1])
    hi = min(max_offset_s, g_a[-1] - g_b[0])
    lags = np.arange(lo, hi + dt / 2, dt) if lo <= hi else np.empty(0)
    best = (-2.0, 0.0)
    scores = np.full(lags.size, np.nan)
    for i, lag in enumerate(lags):
        # tracker sample at tracker time tt is board time tt + lag
        b = np.interp(g_a - lag, g_b, s_b, left=np.nan, right=np.nan)
        ok = np.isfinite(b) & np.isfinite(s_a)
        if ok.sum() < max(20, 0.2 * s_a.size):
            continue
        a_, b_ = s_a[ok] - s_a[ok].mean(), b[ok] - b[ok].mean()
        den = math.sqrt(float(a_ @ a_) * float(b_ @ b_))
        if den <= 0:
            continue
        scores[i] = float(a_ @ b_) / den
        if scores[i] > best[0]:
            best = (scores[i], lag)
    peak, lag = best
    if peak <= -2.0:
        raise GroundTruthError("the tracker and the telemetry do not overlap in time within "
                          f"+-{max_offset_s:g} s; pass --gt-offset", 1)
    i = int(np.nanargmax(scores))
    if 0 < i < lags.size - 1 and np.isfinite(scores[i - 1]) and np.isfinite(scores[i + 1]):
        y0, y1, y2 = scores[i - 1], scores[i], scores[i + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            lag = lags[i] + 0.5 * (y0 - y2) / den * dt
    return float(lag), float(peak)


def attach_groundtruth(run_dir: str, csv_path: str, offset_s: float | None = None,
                       max_offset_s: float = 10.0, min_correlation: float = 0.5,
                       overwrite: bool = False, set_start_pose: bool = False, unix_time: bool = False) -> dict:
    try:
        run = runfmt.load_run(run_dir, check_units=False)
        trk = runfmt._read_csv(csv_path, runfmt.GROUNDTRUTH_REQUIRED, may_be_empty=("phi_rad",))
        runfmt._check_time(trk["t_s"], csv_path)
    except runfmt.RunFormatError as exc:
        raise GroundTruthError(str(exc), 2) from None
    if offset_s is not None and not (math.isfinite(offset_s) and abs(offset_s) <= 1e10):
        raise GroundTruthError(f"--gt-offset {offset_s:g} must be a finite number of seconds "
                               "within +-1e10 (Unix time is about 1.8e9)", 2)
    info: dict[str, Any] = {"file": os.path.basename(csv_path), "rows": int(trk["t_s"].size)}
    if unix_time:
        # tracker stamped by a PC clock (Unix seconds): map through the logger's host clock
        t0 = (run.meta.get("logger") or {}).get("host_t0_unix_s")
        if not t0 or "host_t_s" not in run.telemetry:
            raise GroundTruthError(f"{run_dir}: --gt-unix-time needs a run recorded by this logger "
                              "(meta.json logger.host_t0_unix_s and the host_t_s column)", 2)
        tel = run.telemetry
        # board time - host reception time: reception latency only lowers it, so take a high
        # percentile (the least delayed frames) rather than the maximum (robust to outliers)
        lag = tel["t_s"] - (t0 + tel["host_t_s"])
        offset_s = float(np.percentile(lag, 95))
        info.update(method="unix time via the logger's host clock (host_t0_unix_s + host_t_s)",
                    offset_s=round(offset_s, 4), host_board_spread_s=round(float(lag.max() - lag.min()), 4))
    elif offset_s is None:
        tel = run.telemetry
        lag, peak = estimate_offset(tel["t_s"], tel["x_odo_m"], tel["y_odo_m"],
                                    trk["t_s"], trk["x_m"], trk["y_m"], max_offset_s,
                                    labels=(runfmt.display(os.path.join(run_dir, "telemetry.csv")),
                                            runfmt.display(csv_path)))
        info.update(method="speed cross-correlation (odometry vs tracker)",
                    offset_s=round(lag, 4), peak_correlation=round(peak, 4))
        if peak < min_correlation:
            raise GroundTruthError(f"clock offset estimate is unreliable (peak correlation {peak:.2f} < "
                              f"{min_correlation}); pass --gt-offset", 1)
        offset_s = lag
    else:
        info.update(method="given", offset_s=offset_s)
    phi = trk.get("phi_rad")
    start_pose = None
    if set_start_pose:
        # the tracker's pose at the first telemetry frame, on the board clock
        t0 = float(run.telemetry["t_s"][0])
        tb = trk["t_s"] + offset_s
        if not tb[0] <= t0 <= tb[-1]:
            raise GroundTruthError(f"{csv_path}: the tracker does not cover the run start (board time {t0:.3f} s)", 1)
        ok = np.isfinite(phi) if phi is not None else np.zeros(tb.shape, bool)
        if ok.sum() < 2:
            raise GroundTruthError(f"{csv_path}: --gt-start-pose needs the phi_rad column", 2)
        ph = np.unwrap(phi[ok])
        start_pose = [float(np.interp(t0, tb, trk["x_m"])), float(np.interp(t0, tb, trk["y_m"])),
                      float(np.interp(t0, tb[ok], ph))]
        info["start_pose_from"] = "tracker pose at the first telemetry frame"
    try:
        runfmt.write_groundtruth(run_dir, trk["t_s"] + offset_s, trk["x_m"], trk["y_m"], phi,
                                 overwrite=overwrite)
    except runfmt.RunFormatError as exc:
        raise GroundTruthError(str(exc), 2) from None
    mpath = os.path.join(run_dir, "meta.json")
    with open(mpath) as fh:
        meta = json.load(fh)
    meta["groundtruth"] = info
    if start_pose is not None:
        meta["start_pose"] = [round(v, 6) for v in start_pose]
    runfmt.write_atomic(mpath, json.dumps(meta, indent=2) + "\n")
    return info
