"""Benchmark of the analyzer on synthetic cases: ``python bench/analyzer/bench.py``.

Each case is four 1.5 s runs (ramp, turn, slow, brake) from the NOMINAL plant with one
effect switched on (or none).  This measures speed and catches regressions; it is not the
proof of the analyzer (the data come from the same model that is fitted -- the
independent truth simulator's suite, host_tools.suite, is the proof).  Prints one line per case, a summary and the
wall time per case."""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

CASES: dict[str, dict] = {
    "null": {},
    "friction_coefficient": {"mu_s": 0.17, "mu_k": 0.16},
    "wheel_radius": {"r_eff": 0.038},
    "track_width": {"b_eff": 0.115},
    "motor_back_emf": {"ke_ratio": 1.25},
    "driver_voltage_drop": {"volts": 1.5},
    "actuation_delay": {"delay_s": 0.03},
    "motor_lag": {"tau_s": 0.04},
    "axle_viscous": {"c": 0.004},
    "axle_coulomb": {"torque": 0.03},
    "caster_drag": {"mu": 0.1},
    "load_transfer": {"h": 0.05},
    "stribeck": {"mu_k0": 0.15, "v_s": 0.05},
    "deadband": {"volts": 1.0},
    "motor_gain_asymmetry": {"ratio": 0.9},
    "floor_slope": {"rad": 0.03},
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/bench.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated case names")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--keep", default=None, help="keep the generated runs and reports here")
    args = ap.parse_args(argv)
    from host_tools.analyzer import synth
    from host_tools.analyzer.pipeline import analyze

    root = args.keep or tempfile.mkdtemp(prefix="analyzer-bench-")
    rows = []
    quiet = lambda msg: None  # noqa: E731
    for k, name in enumerate(args.cases.split(",")):
        eff = {name: CASES[name]} if CASES[name] else {}
        paths = synth.make_case(os.path.join(root, name), eff, seed=k + 1)
        t0 = time.time()
        an = analyze(paths, jobs=args.jobs, log=quiet)
        dt = time.time() - t0
        sel = [s["effect"] for s in an.selected]
        eq = [q for s in an.selected for q in s["equivalent"]]
        if name == "null":
            ok = an.verdict == "no_mismatch"
            perr = ""
        else:
            ok = name in sel or name in eq
            main_p = next(iter(CASES[name]))
            perr = ""
            for s in an.selected:
                if s["effect"] == name and main_p in s["params"]:
                    true = CASES[name][main_p]
                    perr = f"{100 * (s['params'][main_p] - true) / true:+.1f}%"
        rows.append((name, an.verdict, ok, dt))
        print(f"{name:22s} verdict={an.verdict:12s} selected={'+'.join(sel) or '-':28s} "
              f"equiv={','.join(eq) or '-':40s} ok={'yes' if ok else 'NO '} "
              f"param_err={perr or '-':8s} {dt:5.1f} s", flush=True)
    n_ok = sum(r[2] for r in rows)
    tot = sum(r[3] for r in rows)
    print(f"\n{n_ok}/{len(rows)} cases right; analyzer wall time {tot:.1f} s total, "
          f"{tot / len(rows):.1f} s per case of four 1.5 s runs with every candidate "
          f"({args.jobs} processes, {os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
