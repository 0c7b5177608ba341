"""Experiment: the friction fitted when the analyzer's nominal replay plant carries other normal
forces than the nominal model's (replay/normal_forces.py: the wheels' mass on the axle, the
transfer at Table II.2's h plus the spin-up's rolling height k^ h_s; docs/analyzer.md, the
tolerance paragraph; lib/slipmodel/README.md, "Load transfer and spin-up").

Variants of the nominal plant (every duty/torque replay the analyzer builds with the nominal
model's normal forces: the nominal replay, the fits' replays; the closed-loop replay and the
tolerance ensemble's draws keep their own plants):

  base    the nominal model as the analyzer has it (share 1, the table's h, k^ = 0.5 as a
          rolling height)
  planar  the planar II.27-II.29 plant (the whole mass at c, no longitudinal transfer)
  a       the wheels' mass on the axle, no transfer
  r0      the wheels on the axle and the transfer at h, no spin-up (k = 0)
  r1      the same with the whole spin-up as a rolling height (k = 1)
  c05     the wheels on the axle and the transfer at h with the plant's own spin term at k = 0.5
          (theta'' of the wheels, also inside a slip)
  c1      the same with k = 1

The tolerance ensemble is left as it is: its draws span the physics about the nominal model
(share in [0, 1], a centre of mass in [0, h + tol_h], k in [0, 1]); its spread is the RMS about
the variant's nominal replay, which ``tolerance_uncertainty`` takes from the (patched) replay
itself.  A candidate ``load_transfer`` effect of the analyzer's own replaces the variant's
centre-of-mass height (plant_config).  The judge's allowance for the physics the nominal model
can only guess (``effects._friction_left_out``: ``LeftOut.mu_ranges``, either way about the
nominal model) is not patched: it decides acceptance, not the fitted values.

Usage (nice it; one process; a friction-only case takes seconds, a case that fits the whole
vocabulary up to half a minute):

  nice .venv/bin/python bench/analyzer/nominal_normal_forces.py --variants base,planar,c1 \
      --effects friction_coefficient --out /tmp/X CASE_DIR [CASE_DIR ...]

A CASE_DIR holds the run folders of one case (a suite ``runs/<case>``).  Prints one line per
case and variant: verdict, selected effects and the fitted friction_coefficient candidate's
μs/μk (its fit is reported whether it was adopted or not); ``--json`` writes them too.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, Iterator, Mapping

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

VARIANTS: dict[str, tuple[float, float | None, float | None, bool] | None] = {
    # name: (share of the wheels' mass on the axle, centre-of-mass height: None the robot's h,
    #        spin share k: None the nominal k^, k through the plant's own spin term (True) or as
    #        a rolling height k h_s (False)); None: the nominal model unpatched
    "base": None,
    "planar": (0.0, 0.0, 0.0, False),
    "a": (1.0, 0.0, 0.0, False),
    "r0": (1.0, None, 0.0, False),
    "r1": (1.0, None, 1.0, False),
    "c05": (1.0, None, 0.5, True),
    "c1": (1.0, None, 1.0, True),
}


@contextlib.contextmanager
def nominal_plant(variant: tuple[float, float | None, float | None, bool] | None
                  ) -> Iterator[None]:
    """Patch ``OpenLoopReplay._ready`` so that the replays the analyzer builds with the nominal
    model's normal forces carry the variant's instead (None: no patch)."""
    if variant is None:
        yield
        return
    from host_tools.analyzer.replay import openloop
    from host_tools.analyzer.replay.normal_forces import (NOMINAL, SPIN_SHARE, NormalForces,
                                                          plant_config)
    share, com_h, spin, live = variant
    k = SPIN_SHARE if spin is None else float(spin)
    orig = openloop.OpenLoopReplay._ready

    def _ready(self: Any, prep: Any, effects: Mapping[str, Mapping[str, float]]) -> Any:
        if self.forces is not NOMINAL:          # the tolerance ensemble's draws
            return orig(self, prep, effects)
        cfg = plant_config({**prep.robot, **self.params}, effects,
                           NormalForces(share, com_h, 0.0 if live else k))
        plant = self._plant(cfg.robot, prep.motor)
        plant.set("plant.spin_share", k if live else 0.0)
        plant.clear_effects()
        for name, params in cfg.effects.items():
            plant.set_effect(name, **{p: float(v) for p, v in params.items()})
        if self.mode == "duty":
            return plant, prep.duty, prep.t_in
        return plant, prep.torque, prep.t_in_tau

    openloop.OpenLoopReplay._ready = _ready  # type: ignore[method-assign]
    try:
        yield
    finally:
        openloop.OpenLoopReplay._ready = orig  # type: ignore[method-assign]


def analyze_case(case_dir: Path, variant: str, effects: str | None, out: Path) -> dict[str, Any]:
    from host_tools.analyzer import cli
    runs = sorted(str(p) for p in case_dir.iterdir() if (p / "meta.json").is_file())
    if not runs:
        raise SystemExit(f"{case_dir}: no run folders (meta.json) in it")
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    argv = [*runs, "--out", str(out), "--jobs", "1", "--no-plots"]
    if effects:
        argv += ["--effects", effects]
    t0 = time.time()
    with nominal_plant(VARIANTS[variant]), contextlib.redirect_stderr(io.StringIO()):
        rc = cli.main(parser.parse_args(argv))
    rep = json.loads((out / "report.json").read_text())
    fc = next((c for c in rep.get("candidates", []) if c.get("effect") == "friction_coefficient"),
              None)
    return {"case": case_dir.name, "variant": variant, "rc": rc, "verdict": rep.get("verdict"),
            "selected": [s["effect"] for s in rep.get("selected", [])],
            "friction": None if fc is None else fc.get("params"),
            "friction_accepted": None if fc is None else fc.get("accepted"),
            "elapsed_s": round(time.time() - t0, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", type=Path, metavar="CASE_DIR")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--effects", default="friction_coefficient")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    variants = [v for v in a.variants.split(",") if v]
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        print(f"unknown variant(s) {bad}; known: {sorted(VARIANTS)}", file=sys.stderr)
        return 2
    rows = []
    for case in a.cases:
        for v in variants:
            row = analyze_case(case, v, a.effects, a.out / case.name / v)
            rows.append(row)
            f = row["friction"] or {}
            print(f"{row['case']:34s} {v:6s} {row['verdict']:14s} "
                  f"mu_s={f.get('mu_s', float('nan')):.4f} mu_k={f.get('mu_k', float('nan')):.4f} "
                  f"accepted={row['friction_accepted']} selected={','.join(row['selected'])} "
                  f"({row['elapsed_s']} s)", flush=True)
            if a.json:
                a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
