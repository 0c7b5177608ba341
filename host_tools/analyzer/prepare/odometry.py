"""How the recorder's odometry columns relate to its own encoder counts."""
from __future__ import annotations

from typing import Any, cast

import numpy as np

from host_tools.analyzer.prepare.run import GAP_S, PreparedRun


def _tick_of_frame(prep: PreparedRun, t: np.ndarray) -> np.ndarray | None:
    """Time of the latest inner tick at or before each time in ``t`` (None: phase unknown)."""
    phase = prep.tick_phase
    period = float(prep.inner_period or 0.0)
    if phase is None or period <= 0:
        return None
    return phase + np.floor((t - phase) / period + 1e-9) * period


def odometry_times(prep: PreparedRun) -> np.ndarray:
    """When the pose that each telemetry frame reports was computed: the latest inner tick for
    a recorder that integrates at its ticks (this project's firmware), the frame itself for one
    that integrates at the frames (see :func:`recorder_odometry`)."""
    t = prep.run.telemetry["t_s"]
    if prep.odo_schedule == "frames":
        return t
    tk = _tick_of_frame(prep, t)
    return t if tk is None else np.maximum(tk, t[0])


def recorder_odometry(prep: PreparedRun) -> dict[str, Any]:
    """How the recorder's odometry columns relate to its own encoder counts, from the recording
    alone: lib/control's odometry (exact arc, III.2-III.4) of the recorded counts is computed
    at the inner ticks (counts interpolated there; a frame reports the latest tick's pose, as
    this project's firmware does) and at the frames, each window by window from the recorded
    pose, and compared with the recorded odometry.  The better schedule is taken; if even it
    differs by more than a few counts of wheel travel, the recorder computes odometry
    differently (integration rule, wheel geometry, schedule) and that is a finding about the
    recorder, not about the physics."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    r, b, ppr = float(prep.robot["r"]), float(prep.robot["b"]), prep.ppr
    k = 2 * np.pi / ppr
    tol_m, tol_rad = 10 * r * k, 10 * r * k / (2 * b)   # ten counts of wheel travel
    wins = prep.windows or [(0, t.size)]
    ticks_all = _tick_of_frame(prep, t)
    errs: dict[str, list[np.ndarray]] = {"frames": [], "ticks": []}
    for i_a, i_b in wins:
        tw = t[i_a:i_b]
        if tw.size < 2:
            continue
        pose0 = (tel["x_odo_m"][i_a], tel["y_odo_m"][i_a], tel["phi_odo_rad"][i_a])
        rec = np.column_stack([tel["x_odo_m"][i_a:i_b], tel["y_odo_m"][i_a:i_b],
                               tel["phi_odo_rad"][i_a:i_b]])
        cand = {"frames": encoder_odometry(tel["enc_r"][i_a:i_b], tel["enc_l"][i_a:i_b], tw, r, b, ppr,
                                    pose0)}
        if ticks_all is not None:
            tk = ticks_all[i_a:i_b]
            uniq, idx = np.unique(tk, return_inverse=True)
            # counts at the ticks, interpolated over the whole run (the first tick of a window
            # lies before its first frame)
            # (not across a gap: after one, a tick before the window's first frame gets its
            # counts on the line through the window's first two frames)
            after_gap = i_a > 0 and t[i_a] - t[i_a - 1] > GAP_S and i_b - i_a >= 2
            at_t = np.maximum(uniq, t[0])

            def counts_at(n: np.ndarray) -> np.ndarray:
                c = np.interp(at_t, t, n)
                if after_gap:
                    early = at_t < t[i_a]
                    slope = (n[i_a + 1] - n[i_a]) / (t[i_a + 1] - t[i_a])
                    c[early] = n[i_a] + slope * (at_t[early] - t[i_a])
                return cast(np.ndarray, np.floor(c + 1e-9))
            cr, cl = counts_at(tel["enc_r"]), counts_at(tel["enc_l"])
            if uniq.size >= 2:
                xo, yo, po = encoder_odometry(cr, cl, at_t + 1e-9 * np.arange(at_t.size), r, b, ppr,
                                       pose0)
                cand["ticks"] = (xo[idx], yo[idx], po[idx])
        for name, (xo, yo, po) in cand.items():
            errs[name].append(np.column_stack([rec[:, 0] - xo, rec[:, 1] - yo,
                                               wrap_angle(rec[:, 2] - po)]))
    out: dict[str, dict[str, float]] = {}
    for name, es in errs.items():
        if not es:
            continue
        e = np.vstack(es)
        out[name] = {"rms_m": float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))),
                     "rms_rad": float(np.sqrt(np.mean(e[:, 2] ** 2)))}
    if not out:
        return {}
    best = min(out, key=lambda n: out[n]["rms_m"] / tol_m + out[n]["rms_rad"] / tol_rad)
    res: dict[str, Any] = {"schedule": best, "tolerance_m": tol_m, "tolerance_rad": tol_rad, "by_schedule": out}
    res["agrees"] = bool(out[best]["rms_m"] <= tol_m and out[best]["rms_rad"] <= tol_rad)
    return res


def wrap_angle(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def encoder_odometry(counts_r: np.ndarray, counts_l: np.ndarray, t: np.ndarray, r: float,
                     b: float, ppr: int, pose0: tuple[float, float, float]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Encoder odometry of cumulative counts, computed by lib/control's own odometry (the
    firmware's formula, III.1-III.4; :func:`host_tools.control.odometry_series`)."""
    from host_tools import control  # lib/control through its C ABI (built on first use)
    return control.odometry_series(counts_r, counts_l, t, r, b, ppr, pose0)
