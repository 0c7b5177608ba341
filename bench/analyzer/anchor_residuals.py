"""Measurement: how well the camera anchor's straight-line offset fits, window by window
(docs/analyzer.md, "Long runs"; ``replay/anchors._gt_anchor_of``).

The anchor of a replay window after the first is the recorder's odometry corrected by
camera = R(delta) odometry + c, c a straight line in time fitted over +-1.5 s.  For each window
of a run this prints, at its early start and at its first frame, and for x and y: the number of
samples of the fit, the RMS of the offset's residual about its line, the residual's lag-1
correlation r1 and the standard error of the line's value the analyzer gives the window's camera
positions (``anchors._line_se_at``).  A residual far above the camera's own noise with r1 near 1
is the offset bending within the span (the odometry drifting other than linearly), which the
window's pose then carries from its start.

    PYTHONPATH=. nice .venv/bin/python bench/analyzer/anchor_residuals.py RUN_DIR

(one run folder, e.g. a suite ``runs/<case>/run-1``; the analysis's front end runs first, ~30 s
for a 60 s run).
"""
from __future__ import annotations

import argparse

import numpy as np

from host_tools.analyzer.pipeline import front
from host_tools.analyzer.replay import anchors as AN


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a run folder")
    a = ap.parse_args(argv)
    p = front([a.run]).preps[0]
    t = p.run.telemetry["t_s"]
    rec: list[tuple[float, int, float, float, float]] = []
    line_at = AN._line_at

    def spy(tt: np.ndarray, v: np.ndarray, at: float) -> float:
        x = tt - at
        if x.size >= 4 and np.ptp(x) > 0:
            A = np.column_stack([np.ones_like(x), x])
            res = v - A @ np.linalg.lstsq(A, v, rcond=None)[0]
            r1 = float(np.corrcoef(res[:-1], res[1:])[0, 1])
            rms = float(np.sqrt(np.mean(res ** 2)))
            rec.append((at, res.size, rms, r1, AN._line_se_at(tt, v, at)))
        return line_at(tt, v, at)
    AN._line_at = spy
    try:
        for w, (i_a, _) in enumerate(p.windows):
            if w == 0 or i_a == 0:
                continue
            for i in (AN._early_start(t, i_a), i_a):
                rec.clear()
                AN._gt_anchor_of(p, float(t[i]))
                for (at, n, rms, r1, se), c in zip(rec, ("x", "y")):
                    print(f"window {w:2d} at {at:8.3f} s {c}: n {n:3d}  residual RMS "
                          f"{rms * 1e3:7.3f} mm  r1 {r1:5.2f}  standard error {se * 1e3:7.3f} mm")
    finally:
        AN._line_at = line_at
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
