"""Each replay window's camera anchor at its first frame against the true pose (a case's labels
truth files), and what tying the window to its first camera sample at the first frame would cost
(the truth's motion between the two).  Usage:
    PYTHONPATH=. .venv/bin/python bench/analyzer/window_anchor_truth.py RUNS/CASE LABELS/CASE"""
import glob
import os
import sys

import numpy as np
from host_tools.analyzer.pipeline import front
from host_tools.analyzer.replay.anchors import _gt_anchor
from host_tools.analyzer.prepare.odometry import wrap_angle

case_runs, labels = sys.argv[1], sys.argv[2]
dirs = sorted(glob.glob(os.path.join(case_runs, "run-*")))
fr = front(dirs)
for prep, d in zip(fr.preps, dirs):
    name = os.path.basename(d)
    tr = np.genfromtxt(os.path.join(labels, name + ".truth.csv"), delimiter=",", names=True)
    tp = np.unwrap(tr["true_phi_rad"])

    def T(c, x, tr=tr, tp=tp):
        return np.interp(x, tr["t_s"], tp if c == "phi" else tr["true_" + c + "_m"])
    t = prep.run.telemetry["t_s"]
    tg = prep.run.groundtruth["t_s"]
    print(f"== {name}")
    print(" w   t_a    anchor  tg0    lag_s  anchor_err(x,y mm; phi)   fallback_err(x,y mm; phi)")
    for w, (i_a, i_b) in enumerate(prep.windows):
        if i_a == 0:
            continue
        at = float(t[i_a])
        an = _gt_anchor(prep, at)
        hi = t[i_b] if i_b < t.size else t[-1]
        ins = tg[(tg >= at) & (tg < hi)]
        tg0 = ins[0] if ins.size else np.nan
        fb = (1e3 * (T("x", tg0) - T("x", at)), 1e3 * (T("y", tg0) - T("y", at)), T("phi", tg0) - T("phi", at))
        if an is None:
            ae = "            None          "
        else:
            ae = f"{1e3*(an['x_m']-T('x',at)):7.1f} {1e3*(an['y_m']-T('y',at)):7.1f} {float(wrap_angle(np.array(an['phi_rad']-T('phi',at)))):7.3f}"
        print(f"{w:2d} {at:6.2f} {'ok  ' if an else 'NONE'} {tg0:6.2f} {tg0-at:5.2f}  {ae}   "
              f"{fb[0]:7.1f} {fb[1]:7.1f} {fb[2]:7.3f}")
