"""Long references of the truth simulator, drawn from a seed: the tour (speed ramps, cruises,
arcs, stops and turns on the spot) and the reversals (fast cruises, direct reversals, stops from
speed, spins that reverse); both are ``segments`` references."""
from __future__ import annotations

import numpy as np


def tour_reference(duration_s: float, seed: int = 0, accel: float = 0.6,
                   alpha: float = 2.0) -> dict:
    """A long reference: a seeded sequence of speed ramps, cruises, arcs, stops and turns on
    the spot that fills ``duration_s`` and ends at rest (a ``segments`` reference)."""
    rng = np.random.default_rng(seed)
    segs: list[dict] = []
    t = 0.0
    end = max(duration_s - 2.0, 1.0)
    while t < end:
        kind = "cruise" if not segs else str(rng.choice(["cruise", "arc", "stop", "spin"],
                                                         p=[0.35, 0.3, 0.15, 0.2]))
        if kind == "cruise":
            sg = {"duration_s": float(rng.uniform(2.0, 6.0)), "v": float(rng.uniform(0.15, 0.6)),
                  "omega": 0.0}
        elif kind == "arc":
            v = float(rng.uniform(0.15, 0.5))
            R = float(rng.uniform(0.4, 1.5)) * (1 if rng.random() < 0.5 else -1)
            sg = {"duration_s": float(rng.uniform(2.0, 5.0)), "v": v, "omega": v / R}
        elif kind == "stop":
            sg = {"duration_s": float(rng.uniform(1.0, 2.0)), "v": 0.0, "omega": 0.0}
        else:
            sg = {"duration_s": float(rng.uniform(1.0, 3.0)), "v": 0.0,
                  "omega": float(rng.uniform(0.8, 1.5)) * (1 if rng.random() < 0.5 else -1)}
        sg = {k: round(v, 4) for k, v in sg.items()}
        sg["duration_s"] = min(sg["duration_s"], round(end - t, 4)) or 0.1
        segs.append(sg)
        t += sg["duration_s"]
    segs.append({"duration_s": round(max(duration_s - t, 0.1), 4), "v": 0.0, "omega": 0.0})
    return {"kind": "segments", "accel": accel, "alpha": alpha, "segments": segs}


def reversal_reference(duration_s: float, seed: int = 0, accel: float = 1.2,
                       alpha: float = 6.0) -> dict:
    """A long, hard reference: a seeded sequence of fast cruises forward and backward (up to
    1.3 m/s, where the duty saturates), direct reversals, stops from speed, arcs and spins
    that reverse, with ramps at ``accel`` and ``alpha`` (wheel-speed changes of about 30 rad/s
    within a second), filling ``duration_s`` and ending at rest (a ``segments`` reference)."""
    rng = np.random.default_rng([seed, 60])
    segs: list[dict] = []
    t, v_last, w_last = 0.0, 0.0, 0.0
    end = max(duration_s - 2.0, 1.0)
    while t < end:
        kind = str(rng.choice(["cruise", "reverse", "stop", "arc", "spin"],
                              p=[0.3, 0.25, 0.15, 0.15, 0.15]))
        sign = -1.0 if rng.random() < 0.35 else 1.0
        if kind == "cruise":
            sg = {"duration_s": rng.uniform(1.0, 3.0), "v": sign * rng.uniform(0.6, 1.3), "omega": 0.0}
        elif kind == "reverse":  # straight to the opposite speed
            v = -np.sign(v_last or 1.0) * rng.uniform(0.5, 0.9)
            sg = {"duration_s": rng.uniform(1.2, 2.5), "v": v, "omega": 0.0}
        elif kind == "stop":
            sg = {"duration_s": rng.uniform(0.6, 1.5), "v": 0.0, "omega": 0.0}
        elif kind == "arc":
            v = sign * rng.uniform(0.3, 0.8)
            R = rng.uniform(0.4, 1.2) * (1 if rng.random() < 0.5 else -1)
            sg = {"duration_s": rng.uniform(1.0, 2.5), "v": v, "omega": v / R}
        else:  # spin, the other way than the last turn
            sg = {"duration_s": rng.uniform(0.8, 1.8), "v": 0.0,
                  "omega": -np.sign(w_last or 1.0) * rng.uniform(2.0, 4.0)}
        sg = {k: round(float(x), 4) for k, x in sg.items()}
        sg["duration_s"] = min(sg["duration_s"], round(end - t, 4)) or 0.1
        segs.append(sg)
        t += sg["duration_s"]
        v_last, w_last = sg["v"], sg["omega"] or w_last
    segs.append({"duration_s": round(max(duration_s - t, 0.1), 4), "v": 0.0, "omega": 0.0})
    return {"kind": "segments", "accel": accel, "alpha": alpha, "segments": segs}
