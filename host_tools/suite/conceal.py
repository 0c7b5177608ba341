"""Evidence of concealment: how each case differs from the nominal truth (the null of the same
experiments) in what a casual look would check — the tracking the camera sees, the wheel
speeds and odometry the robot logs — against what the controller had to do (duty).

Uses the hidden truth files (labels/<case>/run-k.truth.csv) and the runs' telemetry; the
null's runs are simulated afresh with the same experiments. Printed by
``python -m host_tools.suite conceal``."""
from __future__ import annotations

import os
import tempfile

import numpy as np

from host_tools import runfmt, truth
from host_tools.control import REF_KINDS
from host_tools.segments import segments_speeds
from host_tools.suite.cases import Case


def _null_runs(case: Case, tmp: str) -> list[tuple[dict, dict]]:
    out = []
    for k, (ref, clamp, dur) in enumerate(case.experiments):
        p = os.path.join(tmp, f"null-{k}")
        truth.simulate_run(p, ref, {}, clamp=clamp, duration_s=dur, seed=case.seed + k,
                           hidden_dir=tmp, recorder=case.recorder, engine=case.engine,
                           engine_options=case.engine_options or None)
        out.append((runfmt.load_run(p).telemetry,
                    np.genfromtxt(os.path.join(tmp, f"null-{k}.truth.csv"), delimiter=",", names=True)))
    return out


def _segments_position(meta: dict, t: np.ndarray, dt: float = 2e-4) -> np.ndarray:
    """Reference position of a 'segments' reference (meta.json's reference or speed_reference)
    at times t: the integral of its v and omega (:func:`host_tools.segments.segments_speeds`;
    trapezoid on fine steps)."""
    ref = meta.get("reference") or meta.get("speed_reference")
    tg = np.arange(0.0, float(t[-1]) + 2 * dt, dt)
    speeds = segments_speeds(ref, tg)
    if speeds is None:
        raise ValueError("meta.json's reference is not a segments reference")
    v, w = speeds[0], speeds[1]
    phi = np.concatenate([[0.0], np.cumsum(0.5 * dt * (w[1:] + w[:-1]))])
    phm = phi[:-1] + 0.25 * dt * (w[1:] + w[:-1])
    vm = 0.5 * (v[1:] + v[:-1])
    x = np.concatenate([[0.0], np.cumsum(dt * vm * np.cos(phm))])
    y = np.concatenate([[0.0], np.cumsum(dt * vm * np.sin(phm))])
    return np.column_stack([np.interp(t, tg, x), np.interp(t, tg, y)])


def evidence(case: Case, data_dir: str) -> dict:
    """Max over runs of: tracking error |p_true - p_ref| of the case and of the null (m), |Δ odometry| (m), |Δ board wheel speed| (rad/s),
    |Δ duty|, against the nominal truth with the same experiments."""
    res = {"track_m": 0.0, "track_null_m": 0.0, "late_m": 0.0, "late_null_m": 0.0, "odo_m": 0.0, "omega": 0.0, "duty": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        nulls = _null_runs(case, tmp)
        for k, (ntel, ntr) in enumerate(nulls):
            run = os.path.join(data_dir, "runs", case.name, f"run-{k}")
            tel = runfmt.load_run(run).telemetry
            tr = np.genfromtxt(os.path.join(data_dir, "labels", case.name, f"run-{k}.truth.csv"),
                               delimiter=",", names=True)
            t = tel["t_s"]

            def d(a_t, a, b_t, b):
                return float(np.max(np.abs(np.interp(t, a_t, a) - np.interp(t, b_t, b))))
            ref, clamp, dur = case.experiments[k]
            if ref["kind"] not in REF_KINDS:
                pr = _segments_position(runfmt.load_meta(run), tr["t_s"])
                pn = _segments_position(runfmt.load_meta(run), ntr["t_s"])
            else:
                ctl = truth.Controller()
                ctl.set_reference(ref["kind"], ref["accel"], ref["cruise"], ref.get("radius", 1.0))
                pr = np.array([ctl.reference(tt)[:2] for tt in tr["t_s"]])
                pn = np.array([ctl.reference(tt)[:2] for tt in ntr["t_s"]])
            res["track_m"] = max(res["track_m"], float(np.max(np.hypot(
                tr["true_x_m"] - pr[:, 0], tr["true_y_m"] - pr[:, 1]))))
            res["track_null_m"] = max(res["track_null_m"], float(np.max(np.hypot(
                ntr["true_x_m"] - pn[:, 0], ntr["true_y_m"] - pn[:, 1]))))
            ec = np.hypot(tr["true_x_m"] - pr[:, 0], tr["true_y_m"] - pr[:, 1])
            en = np.hypot(ntr["true_x_m"] - pn[:, 0], ntr["true_y_m"] - pn[:, 1])
            late = tr["t_s"] >= 0.6 * tr["t_s"][-1]
            late_n = ntr["t_s"] >= 0.6 * ntr["t_s"][-1]
            res["late_m"] = max(res["late_m"], float(ec[late].max()))
            res["late_null_m"] = max(res["late_null_m"], float(en[late_n].max()))
            res["odo_m"] = max(res["odo_m"], d(t, tel["x_odo_m"], ntel["t_s"], ntel["x_odo_m"]),
                               d(t, tel["y_odo_m"], ntel["t_s"], ntel["y_odo_m"]))
            res["omega"] = max(res["omega"], d(t, tel["omega_r"], ntel["t_s"], ntel["omega_r"]),
                               d(t, tel["omega_l"], ntel["t_s"], ntel["omega_l"]))
            res["duty"] = max(res["duty"], d(t, tel["pwm_r"], ntel["t_s"], ntel["pwm_r"]),
                              d(t, tel["pwm_l"], ntel["t_s"], ntel["pwm_l"]))
    return res
