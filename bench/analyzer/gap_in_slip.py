"""Survey: replay windows that start right after a telemetry gap inside a slip episode
(docs/analyzer.md, "Slip and anchors"; heldback32's MuJoCo hard 60 s null).

A gap over ``GAP_S`` always ends a window, and the edge rules (``replay/edges``) move every
other window start out of the nominal replay's slip episodes; a window after a gap cannot be
moved.  For every run with such a gap this gives each window after a gap: its start, the slip
episode containing it (if any) after the edge rules, and, for one inside a slip, the state the
window starts from (``anchors.window_start``: the camera's, ``anchors.camera_state``) against
the rolling one from the counts and the camera-minus-odometry anchor fitted across the slip.

    PYTHONPATH=. python bench/analyzer/gap_in_slip.py CASE_DIR [CASE_DIR ...]

(a case directory holds ``run-*`` folders: a suite ``runs/<case>``).
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from host_tools.analyzer import pipeline as PL
from host_tools.analyzer.prepare.inputs import prepare_runs
from host_tools.analyzer.prepare.run import GAP_S
from host_tools.analyzer.replay import anchors as AN
from host_tools.analyzer.replay.edges import edges_outside_slip
from host_tools.analyzer.replay.nominal import replay_closed_loop
from host_tools.analyzer.replay.openloop import OpenLoopReplay


def _quiet(_msg: str) -> None:
    return None


def survey(case: Path, dt_s: float = 5e-4) -> None:
    dirs = sorted(str(p) for p in case.glob("run-*"))
    preps = prepare_runs(PL._load_runs(dirs, _quiet), _quiet)
    preps, _ = replay_closed_loop(preps, dt_s, [], _quiet)
    duty = OpenLoopReplay("duty", dt_s=dt_s)
    for d, p in zip(dirs, preps):
        t = p.run.telemetry["t_s"]
        if not np.any(np.diff(t) > GAP_S):
            continue
        if len(p.windows) > 1:
            p = edges_outside_slip(p, duty)[0]
        for w, (i_a, i_b) in enumerate(p.windows):
            if i_a == 0 or t[i_a] - t[i_a - 1] <= GAP_S:
                continue
            at = float(t[i_a])
            ep = AN.slip_containing(p, at)
            print(f"{case.name} {Path(d).name} window {w}: {at:.3f}-{float(t[i_b - 1]):.3f} s "
                  f"after a gap from {float(t[i_a - 1]):.3f} s; "
                  + (f"inside the slip episode {ep[0]:.3f}-{ep[1]:.3f} s" if ep else "no slip"))
            if ep is None:
                continue
            _, pose, vel = AN.window_start(p, w)
            assert vel is not None
            r, b = float(p.robot["r"]), float(p.robot["b"])
            roll = (r * (vel[3] + vel[4]) / 2, r * (vel[3] - vel[4]) / (2 * b))
            # the anchor as it was: the camera-minus-odometry offset fitted across the slip
            # (the episode containing the start and the replay's own ones starting there left out)
            old = dataclasses.replace(p, anchors={}, slip_episodes=[
                e for e in p.slip_episodes if e != ep and e[0] != at])
            an = AN._gt_anchor_of(old, at)
            print(f"  start: camera pose {pose[0]:.4f}, {pose[1]:.4f} m, {pose[2]:.4f} rad; "
                  f"forward {vel[0]:.3f} m/s, sideways {vel[1]:.3f} m/s, turn {vel[2]:.3f} rad/s; "
                  f"wheels {vel[3]:.2f}, {vel[4]:.2f} rad/s")
            print(f"  rolling with the counts: forward {roll[0]:.3f} m/s, turn {roll[1]:.3f} rad/s")
            if an is not None:
                dphi = float(np.angle(np.exp(1j * (an["phi_rad"] - pose[2]))))
                print(f"  offset anchor across the slip: {an['x_m'] - pose[0]:+.4f}, "
                      f"{an['y_m'] - pose[1]:+.4f} m, {dphi:+.4f} rad off the camera's")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", type=Path)
    for case in ap.parse_args().cases:
        survey(case)


if __name__ == "__main__":
    main()
