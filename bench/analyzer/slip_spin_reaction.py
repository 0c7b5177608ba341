"""Measurement: a truth slip null's current windows against the spin-up reaction inside a slip.

The truth simulator carries the wheels' spin-up in the pitch balance through the slipping
wheel's own theta'' at k = 1 (sim/truth/truth.cpp, ``sim.spin_share``); the nominal model
carries it as the rolling height k^ h_s (k^ = 0.5, replay/normal_forces.py) and the tolerance
ensemble draws k in [0, 1] in that rolling form only (replay/tolerance.py, ``ensemble_draws``).
In a run that slips from rest (SLIP's run-0: 72 rad/s^2 asked, the duty short of saturation)
the slipping wheel's theta'' is some 1.5 times a/r, so the truth's wheels carry more load than
any draw, the wheels spin up slower (the wheel current higher) and the slip ends earlier; near
the saturated cruise that end is a step of the current.

For one case's runs it prints:

* the nominal replay's significant windows as the detection sees them (``front``), in floors,
  and whether a mismatch is seen;
* per run that slips, for the duty replay of the nominal model, of the nominal model with the
  spin-up in the theta'' form at k^ and at k = 1 (the truth's form: ``load_transfer`` at the
  table's h with the fit's nuisance spin share): the mean and RMS current residual over the
  reference's ramp (0.1 s to its end) and over the 45 ms after the truth-form replay's slip
  end, and the end of the replay's first slip episode; the same end for each of the
  tolerance ensemble's draws;
* with ``--theta-ensemble``, the windows again with the ensemble's k drawn in the theta''
  form (an experiment: 9dcba9e drew it so and went back, since in a braking run it spread
  every slip episode).

Usage (nice it; a 4-run SLIP case takes some 10 s):
  PYTHONPATH=. .venv/bin/python bench/analyzer/slip_spin_reaction.py RUNS/hb30_tr_null_slip \\
      [--theta-ensemble]

Re-recording with one recorder knob changed (see the report of this measurement):
  python -m host_tools.suite generate --set heldback30 --cases hb30_tr_null_slip --out DIR \\
      --recorder tel_s=0.02 [--seed-offset N]
"""
from __future__ import annotations

import argparse
import dataclasses
import glob
from typing import Any, Mapping

import numpy as np

import host_tools.analyzer.replay.openloop as _ol
import host_tools.analyzer.replay.tolerance as _tol
from host_tools.analyzer.replay import normal_forces as nf


@dataclasses.dataclass(frozen=True)
class ThetaForces(nf.NormalForces):
    """A draw whose spin share k acts through the plant's own theta'' term."""


_plant_config = nf.plant_config


def _theta_plant_config(robot: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
                        forces: nf.NormalForces = nf.NOMINAL) -> nf.PlantConfig:
    if isinstance(forces, ThetaForces) and "load_transfer" not in effects:
        h = forces.com_h_m if forces.com_h_m is not None else float(robot["h"])
        eff = {**effects, "load_transfer": {"h": h, nf.SPIN_KEY: forces.spin_share}}
        return _plant_config(robot, eff, nf.NormalForces(forces.share, None, forces.spin_share))
    return _plant_config(robot, effects, forces)


def _use_theta_ensemble() -> None:
    draws = _tol.ensemble_draws

    def theta_draws(robot: Any, n: int, rng: Any) -> list[_tol.EnsembleDraw]:
        return [_tol.EnsembleDraw(d.params, ThetaForces(d.forces.share, d.forces.com_h_m,
                                                        d.forces.spin_share))
                for d in draws(robot, n, rng)]
    vars(_ol)["plant_config"] = _theta_plant_config  # the name the replay calls
    vars(_tol)["ensemble_draws"] = theta_draws


def first_slip_end(sim: Mapping[str, np.ndarray], side: str = "r", min_s: float = 0.05
                   ) -> float | None:
    """End of the replay's first slip episode of at least ``min_s`` on wheel ``side``."""
    t, s = sim["t_s"], np.asarray(sim[f"slip_{side}"]) > 0.5
    i = 0
    while i < s.size:
        if s[i]:
            j = i
            while j < s.size and s[j]:
                j += 1
            if t[min(j, t.size - 1)] - t[i] >= min_s:
                return float(t[min(j, t.size - 1)])
            i = j
        i += 1
    return None


def windows_report(runs: list[str]) -> None:
    from host_tools.analyzer.pipeline import front
    fr = front(runs)
    loc, det = fr.loc, fr.det
    print(f"  mismatch seen: {det.mismatch_seen} (strong window {det.strong_k:.2f} floors, "
          f"normalized RMS {det.nrms0:.3f}); current floors "
          + ", ".join(f"{c} {v * 1e3:.2f} mA" for c, v in loc.floors.items()
                      if c.startswith("current")))
    for (i, c), ws in sorted(loc.windows.items()):
        for w in ws:
            print(f"    {fr.preps[i].name} {c} {w.t_start_s:.3f}-{w.t_end_s:.3f} s "
                  f"{w.rms / loc.floors[c]:.2f} floors")


def spin_report(runs: list[str]) -> None:
    from host_tools.analyzer.pipeline import front
    from host_tools.analyzer.replay.channels import channels
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    fr = front(runs)
    rep = OpenLoopReplay("duty")
    for prep in fr.preps:
        h = float(prep.robot["h"])
        variants = {"nominal (rolling k^)": {},
                    "theta'' k^": {"load_transfer": {"h": h, nf.SPIN_KEY: nf.SPIN_SHARE}},
                    "theta'' k=1 (truth)": {"load_transfer": {"h": h, nf.SPIN_KEY: 1.0}}}
        sims = {n: rep.simulate(prep, e) for n, e in variants.items()}
        end_nom = first_slip_end(sims["nominal (rolling k^)"])
        if end_nom is None or end_nom < 0.2:
            continue
        end_truth = first_slip_end(sims["theta'' k=1 (truth)"]) or end_nom
        ref = prep.run.meta.get("reference") or {}
        t_acc = (min(float(ref["cruise"]) / float(ref["accel"]), end_nom)
                 if ref.get("accel") and ref.get("cruise") else end_nom)
        print(f"  {prep.name}: slips from rest; current residual mean/RMS (mA) over 0.1-"
              f"{t_acc:.3f} s (the reference's ramp) and over {end_truth:.3f}-"
              f"{end_truth + 0.045:.3f} s (the truth-form replay's slip end)")
        for n, e in variants.items():
            ch = channels(prep, rep.simulate_windows(prep, e), "duty")
            parts = []
            for c in ("current_r_a", "current_l_a"):
                x = ch[c]
                for a, b in ((0.1, t_acc), (end_truth, end_truth + 0.045)):
                    m = (x.t >= a) & (x.t <= b)
                    r = x.resid[m] * 1e3
                    parts.append(f"{c[-3]} {np.mean(r):+6.2f}/{np.sqrt(np.mean(r ** 2)):5.2f}")
            print(f"    {n:20s} " + "  ".join(parts)
                  + f"  slip end {first_slip_end(sims[n]):.4f} s")
        seed = int(np.uint32(int(np.sum(np.asarray(prep.run.telemetry["t_s"], float) * 1e3))
                             & 0xFFFFFFFF))
        draws = _tol.ensemble_draws(prep.robot, _tol.TOLERANCE_ENSEMBLE,
                                    np.random.default_rng([seed, 22]))
        ends = [first_slip_end(OpenLoopReplay("duty", forces=d.forces, params=d.params)
                               .simulate(prep, {})) for d in draws]
        print("    ensemble draws' slip ends (s): "
              + ", ".join("-" if v is None else f"{v:.4f}" for v in ends))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("case_runs", help="a case's runs folder (run-*/ inside)")
    ap.add_argument("--theta-ensemble", action="store_true",
                    help="also the windows with the ensemble's k drawn in the theta'' form")
    a = ap.parse_args()
    runs = sorted(glob.glob(a.case_runs.rstrip("/") + "/run-*"))
    print(f"{a.case_runs}: {len(runs)} runs")
    print(" the detection at this analyzer:")
    windows_report(runs)
    spin_report(runs)
    if a.theta_ensemble:
        _use_theta_ensemble()
        print(" the detection with the ensemble's spin share drawn in the theta'' form:")
        windows_report(runs)


if __name__ == "__main__":
    main()
