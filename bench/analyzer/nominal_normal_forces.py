"""Experiment: the friction fitted when the analyzer's nominal replay plant carries the normal
forces' physics that the planar II.27-II.29 leave out (docs/analyzer.md, the tolerance
paragraph; lib/slipmodel/README.md, "Load transfer and spin-up").

Variants of the nominal plant (every duty/torque replay the analyzer builds itself: the nominal
replay, the fits' replays; the closed-loop replay and the tolerance ensemble's draws keep their
own plants):

  base   the planar nominal plant (the analyzer as it is)
  a      the wheels' mass on the axle (``replay.tolerance.wheels_on_axle``, share 1)
  b05    the ``load_transfer`` effect at the table's h, spin share k = 0.5
  b1     the same with k = 1
  c05    a and b05 together
  c1     a and b1 together
  c0     a and the transfer at h with the effect's own spin term off (k = 0)
  r05    a and the transfer at h + 0.5 h_s with the effect's own spin term off (spin share 0):
         the spin-up as a rolling height, as the tolerance ensemble draws it (h_s = 2 I_wy /
         (m_t r), ``left_out_normal_forces``); inside a slip it differs from c05

The tolerance ensemble is left as it is: its draws span the same physics (share in [0, 1],
transfer heights [0, h + tol_h] + k h_s), so with a variant's nominal inside that range its
spread is the RMS about the variant's nominal replay, which ``tolerance_uncertainty`` takes
from the (patched) replay itself.  ``--ensemble live`` instead draws the spin-up with the
effect's own spin term (``plant.spin_share`` k uniform in [0, 1], the transfer's height a
centre of mass in [0, h + tol_h]), as a nominal plant with the live spin term (b, c) carries
it.  A candidate effect of the analyzer's own that is ``load_transfer`` replaces the
variant's (the fitted h is then the whole transfer).  The judge's allowance for the left-out
physics (``effects._friction_left_out``: up to ``mu_excess`` above the nominal, never below)
is not patched: it decides acceptance, not the fitted values.

Usage (nice it; one process; a friction-only case takes seconds, a case that fits the whole
vocabulary up to half a minute):

  nice .venv/bin/python bench/analyzer/nominal_normal_forces.py --variants base,a,c05 \
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

VARIANTS: dict[str, tuple[float, float | None, float]] = {
    # name: (share of the wheels' mass on the axle, spin share k of load_transfer or None: off,
    #        share of the spin-up's rolling height h_s added to the transfer's h)
    "base": (0.0, None, 0.0),
    "a": (1.0, None, 0.0),
    "b05": (0.0, 0.5, 0.0),
    "b1": (0.0, 1.0, 0.0),
    "c05": (1.0, 0.5, 0.0),
    "c1": (1.0, 1.0, 0.0),
    "c0": (1.0, 0.0, 0.0),
    "r05": (1.0, 0.0, 0.5),
}


@contextlib.contextmanager
def nominal_plant(share: float, spin: float | None, rolling: float = 0.0) -> Iterator[None]:
    """Patch ``OpenLoopReplay._ready`` so that the replays the analyzer builds without a plant
    factory (the nominal model's) carry the variant's physics."""
    from host_tools.analyzer.effects import plant_setup
    from host_tools.analyzer.replay import openloop
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces, wheels_on_axle
    orig = openloop.OpenLoopReplay._ready

    def _ready(self: Any, prep: Any, effects: Mapping[str, Mapping[str, float]]) -> Any:
        if self._factory is not None:          # the tolerance ensemble's draws
            return orig(self, prep, effects)
        robot, plant_effects = plant_setup(prep.robot, effects)
        h = float(robot["h"]) + rolling * left_out_normal_forces(robot).spin_h_m
        if share > 0:
            robot = {**robot, **wheels_on_axle(robot, share)}
        if spin is not None and "load_transfer" not in plant_effects:
            plant_effects = {**plant_effects, "load_transfer": {"h": h}}
        plant = self._plant(robot, prep.motor)
        plant.clear_effects()
        plant.set("plant.spin_share", 1.0 if spin is None else float(spin))
        for name, params in plant_effects.items():
            plant.set_effect(name, **{k: float(v) for k, v in params.items()})
        if self.mode == "duty":
            return plant, prep.duty, prep.t_in
        return plant, prep.torque, prep.t_in_tau

    openloop.OpenLoopReplay._ready = _ready  # type: ignore[method-assign]
    try:
        yield
    finally:
        openloop.OpenLoopReplay._ready = orig  # type: ignore[method-assign]


@contextlib.contextmanager
def live_spin_ensemble() -> Iterator[None]:
    """Patch ``tolerance.ensemble_draws``: the draws' spin-up through the plant's own spin term
    (``spin_share`` k in [0, 1]) instead of as a rolling height."""
    from host_tools.analyzer.replay import tolerance as tol
    orig = tol.ensemble_draws

    def draws(robot: Mapping[str, float], n: int, rng: Any) -> list[Any]:
        out = []
        for d in tol.tolerance_draws(robot, n, rng):
            lo = tol.left_out_normal_forces({**robot, **d})
            share = float(rng.uniform(0.0, 1.0))
            h = float(rng.uniform(0.0, 1.0)) * lo.h_max_m
            k = float(rng.uniform(0.0, 1.0))
            r = {**d, **tol.wheels_on_axle({**robot, **d}, share)}
            out.append(tol.EnsembleDraw(r, {"load_transfer": {"h": h}}, spin_share=k))
        return out

    tol.ensemble_draws = draws
    try:
        yield
    finally:
        tol.ensemble_draws = orig


def analyze_case(case_dir: Path, variant: str, effects: str | None, out: Path,
                 ensemble: str = "asis") -> dict[str, Any]:
    from host_tools.analyzer import cli
    runs = sorted(str(p) for p in case_dir.iterdir() if (p / "meta.json").is_file())
    if not runs:
        raise SystemExit(f"{case_dir}: no run folders (meta.json) in it")
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    argv = [*runs, "--out", str(out), "--jobs", "1", "--no-plots"]
    if effects:
        argv += ["--effects", effects]
    share, spin, rolling = VARIANTS[variant]
    t0 = time.time()
    ens = live_spin_ensemble() if ensemble == "live" else contextlib.nullcontext()
    with nominal_plant(share, spin, rolling), ens, contextlib.redirect_stderr(io.StringIO()):
        rc = cli.main(parser.parse_args(argv))
    rep = json.loads((out / "report.json").read_text())
    fc = next((c for c in rep.get("candidates", []) if c.get("effect") == "friction_coefficient"),
              None)
    return {"case": case_dir.name, "variant": variant, "ensemble": ensemble, "rc": rc, "verdict": rep.get("verdict"),
            "selected": [s["effect"] for s in rep.get("selected", [])],
            "friction": None if fc is None else fc.get("params"),
            "friction_accepted": None if fc is None else fc.get("accepted"),
            "elapsed_s": round(time.time() - t0, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", type=Path, metavar="CASE_DIR")
    ap.add_argument("--variants", default="base,a,b05,b1,c05,c1,c0,r05")
    ap.add_argument("--effects", default="friction_coefficient")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--ensemble", choices=("asis", "live"), default="asis",
                    help="the tolerance ensemble's draws: as the analyzer draws them (asis) or "
                         "with the plant's own spin term (live)")
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
            row = analyze_case(case, v, a.effects, a.out / case.name / v, a.ensemble)
            rows.append(row)
            f = row["friction"] or {}
            print(f"{row['case']:34s} {v:5s} {a.ensemble:4s} {row['verdict']:14s} "
                  f"mu_s={f.get('mu_s', float('nan')):.4f} mu_k={f.get('mu_k', float('nan')):.4f} "
                  f"accepted={row['friction_accepted']} selected={','.join(row['selected'])} "
                  f"({row['elapsed_s']} s)", flush=True)
            if a.json:
                a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
