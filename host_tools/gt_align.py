"""Ground truth for a recorded run: an external tracker's CSV aligned to the board clock.

``python -m host_tools log --out RUN_DIR --attach-groundtruth TRACKER.csv`` adds the tracker's
track (columns t_s, x_m, y_m, optional phi_rad, on the tracker's own clock) to a recorded run
as groundtruth.csv, its time shifted by one of:

* an offset estimated with its standard error from the start from rest, which the wheels and
  the body make at one instant even when the wheels slip (:func:`estimate_onset_offset`; the
  speed correlation, :func:`correlate`, only finds the start in the tracker's file).  Refused
  (exit 2, nothing written) when the data cannot pin it within one tracker frame: a robot that
  never moves, a telemetry that does not start at rest, a repeated motion that leaves the
  correlation ambiguous, or a 95 % interval wider than one frame;
* ``--gt-unix-time``: the exact path, one clock for both: a tracker stamped with the logging
  PC's Unix time is mapped through the logger's host clock (meta.json logger.host_t0_unix_s
  and the host_t_s column), within the link's latency;
* ``--gt-offset S``: given (forces an offset the estimate refused).

meta.json gets a "groundtruth" section saying how, with ``offset_s`` and ``offset_se_s`` (the
run format keeps keys it does not name).  The workflow: README, "Ground truth from a tracker".
"""
from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np
from scipy.interpolate import PchipInterpolator

from host_tools import protocol as P
from host_tools import runfmt


MAX_OFFSET_S = 86_400.0   # --gt-max-offset bound: a tracker clock a day off is not "unsynchronised"
GRID_DT_S = 0.01          # speed grid of the cross-correlation
MAX_GRID = 20_000_000     # samples of one speed grid (55 h at 10 ms, 160 MB): longer is a glitch


class GroundTruthError(Exception):
    """The tracker's file cannot be aligned; ``code`` is the exit code (1 failed, 2 bad input)."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


def correlate(t_tel: np.ndarray, x_odo: np.ndarray, y_odo: np.ndarray,
              t_trk: np.ndarray, x_trk: np.ndarray, y_trk: np.ndarray,
              max_offset_s: float = 10.0, dt: float = GRID_DT_S,
              labels: tuple[str, str] = ("telemetry", "tracker")) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation of the speed along the path from odometry with that from
    the tracker, at lags (s, t_board = t_tracker + lag) on a ``dt`` grid: (lags, scores), NaN
    where the two overlap too little."""
    def speed(t: np.ndarray, x: np.ndarray, y: np.ndarray, what: str
              ) -> tuple[np.ndarray, np.ndarray]:
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
    return lags, scores


START_PRE_S = 0.5      # tracker samples fitted before the start from rest ...
START_POST_S = 0.3     # ... and after it (before the wheels can have slipped far)
START_STEP_S = 0.0005  # grid of candidate offsets
MOVED_M = 0.0005       # the wheels have left their first position (4 encoder counts)
UNIX_WINDOW_S = 1.0    # --gt-unix-time: the board-host clock difference per this much host time
Z95 = 1.96             # 95 % of a normal distribution within +- Z95 standard errors
AMBIGUOUS = 0.9        # a second correlation peak this high (of the first) leaves the lag ambiguous


def fit_start(t_tel: np.ndarray, wheel_m: np.ndarray, t_trk: np.ndarray, x_trk: np.ndarray,
              y_trk: np.ndarray, t_move: float, guess: float, span_s: float = 0.3,
              post_s: float = START_POST_S) -> tuple[float, float, int] | None:
    """Offset (t_board = t_tracker + offset) near ``guess`` at which the tracker's start from
    rest matches the wheels': the tracker's position along the direction the robot leaves in,
    START_PRE_S before to ``post_s`` after the start, fitted as c + k wheel_m(t + offset)
    (wheel_m: distance rolled, at rest before the first frame; k absorbs a wheel-radius
    error).  Before the wheels slip the body moves as they roll, so both see one start.
    Returns (offset, standard error, samples): the standard error is the half width of the
    offsets where the residual sum of squares rises by one noise variance (profile likelihood,
    noise from the residuals); None when the tracker has too few samples there."""
    # the wheels' distance between frames: a shape-preserving cubic (a straight line between
    # frames lies above an accelerating start: ms of bias at a 100 Hz tracker), at rest before
    # the first frame
    template = PchipInterpolator(t_tel, wheel_m, extrapolate=False)

    def wheels(tb: np.ndarray) -> np.ndarray:
        at: np.ndarray = np.nan_to_num(template(np.clip(tb, t_tel[0], t_tel[-1])))
        return at

    off = guess
    for _ in range(3):
        a, b = t_move - off - START_PRE_S, t_move - off + post_s
        k = (t_trk >= a) & (t_trk <= b)
        tw, xw, yw = t_trk[k], x_trk[k], y_trk[k]
        pre, post = tw < t_move - off, tw > b - 0.1
        if pre.sum() < 1 or post.sum() < 2 or tw.size < 8:
            return None
        dx, dy = xw[post].mean() - xw[pre].mean(), yw[post].mean() - yw[pre].mean()
        norm = math.hypot(dx, dy)
        if norm <= 0:
            return None
        d = (xw * dx + yw * dy) / norm
        cand = np.arange(off - span_s, off + span_s + START_STEP_S / 2, START_STEP_S)
        rss = np.full(cand.size, np.inf)
        for i, c in enumerate(cand):
            w = wheels(tw + c)
            A = np.column_stack([np.ones_like(w), w])
            coef, *_ = np.linalg.lstsq(A, d, rcond=None)
            if coef[1] > 0:
                r = d - A @ coef
                rss[i] = float(r @ r)
        i = int(np.argmin(rss))
        if not np.isfinite(rss[i]):
            return None
        done = abs(float(cand[i]) - off) < 0.001
        off = float(cand[i])
        span_s = 0.1
        if done:
            break
    # residuals of the best fit that follow each other (a start that is not quite the wheels'
    # shape: slip, tracker filtering) carry fewer independent samples: the noise variance is
    # scaled by (1 + rho) / (1 - rho), rho their lag-1 autocorrelation
    w = wheels(tw + off)
    A = np.column_stack([np.ones_like(w), w])
    res = d - A @ np.linalg.lstsq(A, d, rcond=None)[0]
    rho = float(np.clip(np.corrcoef(res[:-1], res[1:])[0, 1], 0.0, 0.9)) if res.std() > 0 else 0.0
    var = max(rss[i], 1e-18) / max(1, tw.size - 2) * (1 + rho) / (1 - rho)
    inside = np.flatnonzero(rss <= rss[i] + var)
    lo, hi = int(inside[0]), int(inside[-1])
    if lo == 0 or hi == cand.size - 1:
        return off, math.inf, int(tw.size)  # the interval reaches the searched span's edge

    def cross(j_in: int, j_out: int) -> float:  # where the RSS crosses rss_min + var
        f = (rss[i] + var - rss[j_in]) / (rss[j_out] - rss[j_in])
        return float(cand[j_in] + f * (cand[j_out] - cand[j_in]))
    return off, 0.5 * (cross(hi, hi + 1) - cross(lo, lo - 1)), int(tw.size)


def estimate_onset_offset(t_tel: np.ndarray, x_odo: np.ndarray, y_odo: np.ndarray,
                          t_trk: np.ndarray, x_trk: np.ndarray, y_trk: np.ndarray,
                          max_offset_s: float = 10.0,
                          labels: tuple[str, str] = ("telemetry", "tracker"),
                          wheel_m: np.ndarray | None = None) -> dict[str, Any]:
    """Offset (t_board = t_tracker + offset) with its standard error, from the instant the robot
    starts to move from rest, seen by the wheels and by the tracker (:func:`fit_start`); the speed
    correlation (:func:`correlate`) only says where in the tracker's file to look.  The start
    is one instant on both clocks even when the wheels slip.  GroundTruthError (2) when the
    data cannot give it: a robot that never moves, an ambiguous correlation (periodic motion),
    no start seen by the tracker (a telemetry that does not start at rest:
    :func:`estimate_run_offset`).  ``wheel_m``: the
    distance the wheels rolled per frame (mean of both, from the encoder counts), used for the
    start instead of the odometry columns, which a recorder may update less often than it
    sends frames (this project's firmware: every other frame)."""
    path = float(np.sum(np.hypot(np.diff(x_odo), np.diff(y_odo))))
    if wheel_m is not None and not np.any(np.abs(wheel_m - wheel_m[0]) > MOVED_M):
        wheel_m = None  # counts that never change (a recorder without encoders): the odometry
    sx, sy = (x_odo, y_odo) if wheel_m is None else (wheel_m, np.zeros_like(wheel_m))
    moved = np.flatnonzero(np.hypot(sx - sx[0], sy - sy[0]) > MOVED_M)
    if moved.size == 0:
        raise GroundTruthError(f"{labels[0]}: the robot never moves (odometry path {path * 1000:.1f} mm): "
                               "no motion to align the tracker by; pass --gt-offset, or record a "
                               "start from rest (README, \"Ground truth from a tracker\")", 2)
    t_move = float(t_tel[moved[0]])
    lags, scores = correlate(t_tel, x_odo, y_odo, t_trk, x_trk, y_trk, max_offset_s, labels=labels)
    if not np.isfinite(scores).any():
        raise GroundTruthError("the tracker and the telemetry do not overlap in time within "
                               f"+-{max_offset_s:g} s; pass --gt-offset", 1)
    i = int(np.nanargmax(scores))
    coarse, peak = float(lags[i]), float(scores[i])
    # the highest other local maximum at least 0.5 s away
    sc = np.where(np.isfinite(scores), scores, -np.inf)
    is_max = np.r_[False, (sc[1:-1] >= sc[:-2]) & (sc[1:-1] >= sc[2:]), False]
    far = np.abs(lags - coarse) >= 0.5
    other = sc[is_max & far]
    second = float(other.max()) if other.size else -1.0
    if peak > 0 and second >= AMBIGUOUS * peak:
        j = int(np.flatnonzero(is_max & far & (sc == second))[0])
        raise GroundTruthError(
            f"the clock offset is ambiguous: the speed correlation peaks at {coarse:.3f} s ({peak:.2f}) "
            f"and nearly as high at {float(lags[j]):.3f} s ({second:.2f}) (a repeated motion?); "
            "pass --gt-offset, or stamp the tracker with the logging PC's clock (--gt-unix-time; README, "
            "\"Ground truth from a tracker\")", 2)
    dist = sx if wheel_m is not None else np.hypot(sx - sx[0], sy - sy[0])
    fit = fit_start(t_tel, dist, t_trk, x_trk, y_trk, t_move, coarse)
    # how far the shape after the start differs from the wheels' (slip): the estimate with
    # 0.1 s shorter and longer fits; half their range is added to the standard error
    others = []
    for post in (START_POST_S - 0.1, START_POST_S + 0.1):
        o = fit_start(t_tel, dist, t_trk, x_trk, y_trk, t_move, coarse, post_s=post)
        others.append(o[0] if o is not None else math.nan)
    if fit is not None:
        offs = [fit[0]] + [o for o in others if math.isfinite(o)]
        fit = (fit[0], math.hypot(fit[1], 0.5 * (max(offs) - min(offs))), fit[2])
    if fit is None:
        raise GroundTruthError(f"{labels[1]}: too few tracker samples around the start from rest "
                               f"(board time {t_move:.3f} s, tracker time about {t_move - coarse:.3f} s); "
                               "pass --gt-offset", 2)
    return {"offset_s": fit[0], "offset_se_s": fit[1], "start_board_s": t_move, "samples": fit[2],
            "correlation_offset_s": coarse, "peak_correlation": peak,
            "second_peak_correlation": second}


def estimate_run_offset(run: runfmt.Run, trk: dict[str, np.ndarray], max_offset_s: float = 10.0,
                        csv_path: str = "tracker") -> dict[str, Any]:
    """:func:`estimate_onset_offset` for a loaded run and a tracker's columns (t_s, x_m, y_m):
    the wheels' distance from the encoder counts, the robot's wheel radius and encoder_ppr."""
    tel = run.telemetry
    tel_name = runfmt.display(os.path.join(run.path, "telemetry.csv"))
    if "omega_r" in tel and "omega_l" in tel and (tel["omega_r"][0] != 0 or tel["omega_l"][0] != 0):
        raise GroundTruthError(f"{tel_name}: the wheels already turn in the first frame (data row 1): "
                               "the alignment needs the start from rest in the recording; pass "
                               "--gt-offset or --gt-unix-time", 2)
    wheel_m = None
    if "enc_r" in tel and "enc_l" in tel:
        r = float((run.meta.get("robot") or {}).get("r", runfmt.DEFAULT_META["robot"]["r"]))
        ppr = float(run.meta.get("encoder_ppr") or runfmt.DEFAULT_META["encoder_ppr"])
        wheel_m = (tel["enc_r"] + tel["enc_l"]) / 2 * (2 * math.pi * r / ppr)
    return estimate_onset_offset(tel["t_s"], tel["x_odo_m"], tel["y_odo_m"],
                                 trk["t_s"], trk["x_m"], trk["y_m"], max_offset_s,
                                 labels=(tel_name, runfmt.display(csv_path)), wheel_m=wheel_m)


def describe(info: dict[str, Any]) -> str:
    """The line ``log --attach-groundtruth`` prints: the offset with its standard error."""
    se = info.get("offset_se_s")
    pm = "" if se is None else f" +- {se * 1000:.1f} ms (1 standard error)"
    extra = f", tracker frame {info['tracker_frame_s'] * 1000:.1f} ms" if "tracker_frame_s" in info else ""
    return f"groundtruth.csv written: offset {info['offset_s']} s{pm} ({info['method']}{extra})"


def attach_groundtruth(run_dir: str, csv_path: str, offset_s: float | None = None,
                       max_offset_s: float = 10.0, min_correlation: float = 0.5,
                       overwrite: bool = False, set_start_pose: bool = False, unix_time: bool = False
                       ) -> dict[str, Any]:
    try:
        run = runfmt.load_run(run_dir, check_units=False)
        trk = runfmt.read_groundtruth(csv_path)
    except runfmt.RunFormatError as exc:
        raise GroundTruthError(str(exc), 2) from None
    if offset_s is not None and not (math.isfinite(offset_s) and abs(offset_s) <= 1e10):
        raise GroundTruthError(f"--gt-offset {offset_s:g} must be a finite number of seconds "
                               "within +-1e10 (Unix time is about 1.8e9)", 2)
    info: dict[str, Any] = {"file": os.path.basename(csv_path), "rows": int(trk["t_s"].size)}
    shift: np.ndarray | float = 0.0  # board time - tracker time, per tracker sample or for all
    if unix_time:
        # tracker stamped by a PC clock (Unix seconds): map through the logger's host clock
        t0 = (run.meta.get("logger") or {}).get("host_t0_unix_s")
        if not t0 or "host_t_s" not in run.telemetry:
            raise GroundTruthError(f"{run_dir}: --gt-unix-time needs a run recorded by this logger "
                              "(meta.json logger.host_t0_unix_s and the host_t_s column)", 2)
        tel = run.telemetry
        # board time - host reception time: reception latency only lowers it, so take a high
        # percentile (the least delayed frames) rather than the maximum (robust to outliers),
        # per UNIX_WINDOW_S of host time (a board clock that drifts against the PC's, or a
        # simulated one that falls behind it, is followed), interpolated at each tracker sample.
        # The firmware stamps a frame before its first byte leaves; the host has it after the
        # last: even the least delayed frames spent their transmission time on the wire
        # (protocol.json's frame size and baud), added back.  Standard error: the scatter of
        # the least delayed quarter of each window (median over windows) and half the wire time.
        lag = tel["t_s"] - (t0 + tel["host_t_s"])
        d = P.definition()
        wire_s = d.wire_size("Telemetry") * d.bits_per_byte / d.baud
        h = tel["host_t_s"]
        centres, env, scatter = [], [], []
        for a in np.arange(h[0], max(h[-1] - UNIX_WINDOW_S, h[0]) + UNIX_WINDOW_S / 4, UNIX_WINDOW_S / 4):
            k = (h >= a) & (h < a + UNIX_WINDOW_S)
            if k.sum() < 8:
                continue
            centres.append(float(np.median(h[k])))
            env.append(float(np.percentile(lag[k], 95)) + wire_s)
            least = np.sort(lag[k])[-max(2, int(k.sum()) // 4):]
            scatter.append(float(np.std(least, ddof=1)))
        if not centres:
            centres, env, scatter = [float(np.median(h))], [float(np.percentile(lag, 95)) + wire_s], [0.0]
        shift = np.interp(trk["t_s"] - t0, centres, env)
        offset_s = float(np.median(env))
        se = math.hypot(float(np.median(scatter)), wire_s / 2)
        info.update(method="unix time via the logger's host clock (host_t0_unix_s + host_t_s)",
                    offset_s=round(offset_s, 4), offset_se_s=round(se, 4), wire_s=round(wire_s, 5),
                    offset_range_s=[round(min(env), 4), round(max(env), 4)],
                    host_board_spread_s=round(float(lag.max() - lag.min()), 4))
    elif offset_s is None:
        est = estimate_run_offset(run, trk, max_offset_s, csv_path)
        frame = float(np.median(np.diff(trk["t_s"])))
        lag, se, peak = est["offset_s"], est["offset_se_s"], est["peak_correlation"]
        info.update(method="start from rest: tracker fitted to the wheels' distance (speed correlation "
                           "to find it)", offset_s=round(lag, 4), offset_se_s=round(se, 4) if math.isfinite(se) else None,
                    tracker_frame_s=round(frame, 4), start_board_s=round(est["start_board_s"], 4),
                    correlation_offset_s=round(est["correlation_offset_s"], 4),
                    peak_correlation=round(peak, 4),
                    second_peak_correlation=round(est["second_peak_correlation"], 4))
        if not Z95 * se <= frame:
            raise GroundTruthError(
                f"the data cannot pin the clock offset within one tracker frame ({frame * 1000:.1f} ms): "
                f"{lag:.4f} s +- {se * 1000:.1f} ms (standard error; 95 %: +- {Z95 * se * 1000:.1f} ms) "
                f"from {est['samples']} tracker samples around the start from rest; nothing written. "
                "Pass --gt-offset S to use an offset anyway, or align exactly (--gt-unix-time; "
                "README, \"Ground truth from a tracker\")", 2)
        if peak < min_correlation:
            raise GroundTruthError(f"clock offset estimate is unreliable (peak correlation {peak:.2f} < "
                              f"{min_correlation}); pass --gt-offset", 1)
        offset_s = lag
    else:
        info.update(method="given", offset_s=offset_s)
    if not isinstance(shift, np.ndarray):
        shift = float(offset_s)
    phi = trk.get("phi_rad")
    start_pose = None
    if set_start_pose:
        # the tracker's pose at the first telemetry frame, on the board clock
        t0 = float(run.telemetry["t_s"][0])
        tb = trk["t_s"] + shift
        if not tb[0] <= t0 <= tb[-1]:
            raise GroundTruthError(f"{csv_path}: the tracker does not cover the run start (board time {t0:.3f} s)", 1)
        if phi is None or np.isfinite(phi).sum() < 2:
            raise GroundTruthError(f"{csv_path}: --gt-start-pose needs the phi_rad column", 2)
        ok = np.isfinite(phi)
        ph = np.unwrap(phi[ok])
        start_pose = [float(np.interp(t0, tb, trk["x_m"])), float(np.interp(t0, tb, trk["y_m"])),
                      float(np.interp(t0, tb[ok], ph))]
        info["start_pose_from"] = "tracker pose at the first telemetry frame"
    try:
        runfmt.write_groundtruth(run_dir, trk["t_s"] + shift, trk["x_m"], trk["y_m"], phi,
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
