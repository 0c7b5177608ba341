"""A ``segments`` reference (meta.json ``{"kind": "segments", "accel", "alpha", "segments":
[{"duration_s", "v", "omega"}, ...]}``, docs/suite.md), read back from a recording: from rest,
segment i (starting at the sum of the earlier durations) ramps v toward its ``v`` at +-accel and
omega toward its ``omega`` at +-alpha, then holds; after the last segment its targets hold.

The simulator's own definition is sim/truth/truth.cpp's ``SpeedRef``; this is the readers' one
(the suite's concealment evidence, the analyzer's fill of unreported ticks), held to it by
``test_truth.test_segment_reference_is_tracked_and_written``."""
from __future__ import annotations

import math
from typing import Mapping, cast

import numpy as np


def segments_speeds(ref: Mapping[str, object], t: np.ndarray, eps_s: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(v, omega, dv/dt, domega/dt) of the reference at times ``t`` (reference time 0 at the
    experiment's start); a segment's start or a ramp's end within ``eps_s`` after an instant
    counts as reached at it.  None when ``ref`` is not such a list."""
    try:
        accel, alpha = float(cast(float, ref["accel"])), float(cast(float, ref["alpha"]))
        segs = [(float(g["duration_s"]), float(g["v"]), float(g["omega"]))
                for g in cast("list[Mapping[str, float]]", ref["segments"])]
    except (KeyError, TypeError, ValueError):
        return None
    if not segs or not (accel > 0 and alpha > 0) or any(d < 0 for d, _, _ in segs):
        return None
    t = np.asarray(t, float)
    v, w, dv, dw = (np.zeros(t.size) for _ in range(4))
    t0, v0, w0 = 0.0, 0.0, 0.0
    for k, (dur, vt, wt) in enumerate(segs):
        end = t0 + dur if k + 1 < len(segs) else math.inf
        m = (t >= t0 - eps_s) & (t < end - eps_s)
        tau = t[m] - t0
        for tgt, cur, rate, val, der in ((vt, v0, accel, v, dv), (wt, w0, alpha, w, dw)):
            step = abs(tgt - cur)
            val[m] = cur + math.copysign(1.0, tgt - cur) * np.minimum(rate * tau, step) if step else cur
            der[m] = np.where(t[m] < t0 + step / rate - eps_s, math.copysign(rate, tgt - cur), 0.0) \
                if step else 0.0
        v0 = vt if dur * accel >= abs(vt - v0) else v0 + math.copysign(dur * accel, vt - v0)
        w0 = wt if dur * alpha >= abs(wt - w0) else w0 + math.copysign(dur * alpha, wt - w0)
        t0 = end
    return v, w, dv, dw
