"""Measurement: slip nulls' false alarms against the form the spin-up reaction is carried in.

The truth simulator carries the wheels' spin-up in the pitch balance through the slipping
wheel's own theta'' at k = 1 (sim/truth/truth.cpp), MuJoCo's wheel body reacts with k = 0.5;
the nominal model carries it as the rolling height k^ h_s (k^ = 0.5, replay/normal_forces.py)
and the tolerance ensemble draws k in [0, 1] in that rolling form only (replay/tolerance.py).
While the wheels roll theta'' = a/r and both forms are the same; they differ inside a slip.
This script runs the analyzer's stages up to the detection (``pipeline.front``) on each case
given, under the analyzer as it is and under candidate forms, and prints whether a mismatch
is seen (on a null: a false alarm) and the largest window, in floors:

* ``0``: the analyzer as it is;
* ``a``: every ensemble draw's k in the theta'' form (``load_transfer`` at the draw's height
  with the plant's own spin term at k; the rolling form while the wheels roll);
* ``b``: the form itself uncertain: the even draws in the theta'' form, the odd ones rolling
  (the theta'' form only inside slip episodes with the rolling one outside is ``a`` itself,
  since a rolling wheel's theta'' is a/r);
* ``c``: the nominal replay (every plant built with the nominal normal forces, the fits' too)
  in the theta'' form at k^, the ensemble as it is.

Usage (nice it; a 4-run SLIP case takes some 2 s a form):
  PYTHONPATH=. .venv/bin/python bench/analyzer/slip_spin_forms.py [--forms 0,a,b,c] \\
      RUNS/case_a RUNS/case_b ...

Seed offsets of a null (the runs re-recorded with other noise, same physics):
  python -m host_tools.suite generate --set heldback30 --cases hb30_tr_null_slip --out DIR \\
      --seed-offset N

Measured at 3e85334 (no rule followed).  Slip nulls at seed offsets 1-10 (tuning ``null_slip``,
mujoco ``mj_null_slip``, hb28-31's ``_tr_``/``_mj_null_slip``; 50 recordings an engine),
mismatch seen 0 / a / b / c: truth 7 / 7 / 5 / 11, MuJoCo 1 / 1 / 1 / 1 (hb31_mj s3 at 3.81
floors in every form).  hb30_tr_null_slip 7 / 6 / 4 / 10 of 10; hb28_tr_null_slip at offset
8 seen under a (3.51) and b (3.01), not under 0 (1.70): at its slip end (run-0 current_r,
t = 0.762 s, residual -26.9 mA) the draws' per-sample spread is 6.8 mA rolling, 3.5 mA in the
theta'' form; the slip end is a step whose time the draws move, and their RMS about the nominal
covers a sample only where their ends straddle it.  Stored runs (``suite bench --reuse``, hb27-31
slip effects and slip nulls, 36 cases): every form turns the out-of-vocabulary
hb31_mj_oov_friction_patch from unexplained to explained (friction + load transfer) and moves
hb31_mj_stribeck (mu_k0 0.1529 for 0.161, floor slope and motor lag beside it: a 0.1731 with
three other effects, b 0.1347 alone, c unexplained); a makes hb30_tr_null_slip no_mismatch at
the set's seed; c also loses hb27_mj_friction_coefficient_2 and hb29_tr_friction_coefficient
(Stribeck alone) and leaves hb31_mj_friction_coefficient unexplained.  The detection of the 139
stored slip cases of hb13-31 (38 nulls, 101 effects and OOV): only hb30_tr_null_slip changes.
"""
from __future__ import annotations

import argparse
import dataclasses
import glob
import os
from typing import Any, Callable, Mapping

import host_tools.analyzer.replay.closedloop as _cl
import host_tools.analyzer.replay.openloop as _ol
import host_tools.analyzer.replay.tolerance as _tol
from host_tools.analyzer.replay import normal_forces as nf


@dataclasses.dataclass(frozen=True)
class ThetaForces(nf.NormalForces):
    """Normal forces whose spin share k acts through the plant's own theta'' term."""


_ORIG = {"ol": nf.plant_config, "cl": _cl.plant_config, "draws": _tol.ensemble_draws}


def _theta(robot: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
           forces: nf.NormalForces) -> nf.PlantConfig:
    """``plant_config`` with the spin share ``forces.spin_share`` in the theta'' form (the
    fit's nuisance-k form: ``load_transfer`` at the centre of mass with the plant's own spin
    term), where the effects carry no spin share of their own."""
    lt = effects.get("load_transfer", {})
    if nf.SPIN_KEY in lt:
        return nf.plant_config(robot, effects, forces)
    h = lt.get("h", forces.com_h_m if forces.com_h_m is not None else float(robot["h"]))
    eff = {**effects, "load_transfer": {**lt, "h": float(h), nf.SPIN_KEY: forces.spin_share}}
    return nf.plant_config(robot, eff, nf.NormalForces(forces.share, None, forces.spin_share))


def _config_for(form: str) -> Callable[..., nf.PlantConfig]:
    def config(robot: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
               forces: nf.NormalForces = nf.NOMINAL) -> nf.PlantConfig:
        if isinstance(forces, ThetaForces) or (form == "c" and forces is nf.NOMINAL):
            return _theta(robot, effects, forces)
        return nf.plant_config(robot, effects, forces)
    return config


def use_form(form: str) -> None:
    """Switch the analyzer (in this process) to ``form`` (see the module's text)."""
    draws = _ORIG["draws"]

    def form_draws(robot: Any, n: int, rng: Any) -> list[_tol.EnsembleDraw]:
        out = []
        for i, d in enumerate(draws(robot, n, rng)):
            if form == "a" or (form == "b" and i % 2 == 0):
                d = _tol.EnsembleDraw(d.params, ThetaForces(d.forces.share, d.forces.com_h_m,
                                                            d.forces.spin_share))
            out.append(d)
        return out
    cfg = _ORIG["ol"] if form == "0" else _config_for(form)
    vars(_ol)["plant_config"] = cfg   # the names the replays call
    vars(_cl)["plant_config"] = cfg if form == "c" else _ORIG["cl"]
    vars(_tol)["ensemble_draws"] = draws if form == "0" else form_draws


def detection(case_runs: str) -> tuple[bool, float, str]:
    """(mismatch seen, the largest window in floors, where) of one case's runs."""
    from host_tools.analyzer.pipeline import front
    runs = sorted(glob.glob(os.path.join(case_runs, "run-*")))
    fr = front(runs)
    loc = fr.loc
    top = max(((w.rms / loc.floors[c], f"{fr.preps[i].name} {c} {w.t_start_s:.3f} s")
               for (i, c), ws in loc.windows.items() for w in ws), default=(0.0, "-"))
    return bool(fr.det.mismatch_seen), float(top[0]), top[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+", help="case runs folders (run-*/ inside)")
    ap.add_argument("--forms", default="0,a,b,c")
    a = ap.parse_args()
    forms = a.forms.split(",")
    seen = {f: 0 for f in forms}
    for case in a.cases:
        parts = []
        for f in forms:
            use_form(f)
            s, k, where = detection(case)
            seen[f] += s
            parts.append(f"{f}: {'SEEN' if s else '-'} {k:5.2f} ({where})")
        print(f"{case}\n    " + "\n    ".join(parts), flush=True)
    use_form("0")
    print("mismatch seen: " + ", ".join(f"{f} {seen[f]}/{len(a.cases)}" for f in forms))


if __name__ == "__main__":
    main()
