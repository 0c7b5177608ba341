"""``python -m host_tools.suite {list,generate,bench}`` — the concealed-effect suite."""
from __future__ import annotations

import argparse
import os
import sys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m host_tools.suite", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name, help_ in (("list", "list the cases"), ("generate", "write the runs and hidden labels"),
                        ("bench", "generate, run the analyzer on every case, score"),
                        ("conceal", "how much each case differs from the nominal truth, per channel"),
                        ("score", "summarize the scores of earlier bench runs (no analysis)")):
        p = sub.add_parser(name, help=help_)
        p.add_argument("--fast", action="store_true", help="only the fast subset (CI)")
        p.add_argument("--cases", default=None, help="comma-separated case names")
        if name != "list":
            p.add_argument("--out", default="out/suite", help="data folder (default out/suite)")
            p.add_argument("--seed-offset", type=int, default=0,
                           help="add to every case's seed (other noise, phases; same physics)")
        if name == "score":
            p.add_argument("--rescore", action="store_true",
                           help="score again from the stored reports and labels")
        if name == "bench":
            p.add_argument("--jobs", type=int, default=2, help="analyzer processes (default 2)")
            p.add_argument("--reuse", action="store_true", help="reuse runs already generated")
    a = ap.parse_args(argv)
    from host_tools.suite import cases as C
    try:
        sel = C.get(a.cases.split(",") if a.cases else None, fast=a.fast)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for c in sel:
        c.seed += getattr(a, "seed_offset", 0)
    if a.cmd == "list":
        for c in sel:
            print(f"{c.name:<28} expect {c.expect:<12} {len(c.experiments)} runs  "
                  f"{','.join(c.concealment) or '-':<28} {c.effects}")
        print(f"{len(sel)} cases")
        return 0
    if a.cmd == "generate":
        from host_tools.suite.generate import generate_case
        for c in sel:
            generate_case(c, a.out, overwrite=True)
        print(f"{len(sel)} cases under {os.path.join(a.out, 'runs')}; labels under "
              f"{os.path.join(a.out, 'labels')}")
        return 0
    if a.cmd == "conceal":
        from host_tools.suite.conceal import evidence
        from host_tools.suite.generate import generate_case
        print(f"{'case':<28} {'concealment':<28} {'track':>6} {'null':>6} {'late':>6} {'null':>6} {'odo mm':>7} {'omega':>6} {'duty':>6}")
        for c in sel:
            generate_case(c, a.out, overwrite=True)
            e = evidence(c, a.out)
            print(f"{c.name:<28} {','.join(c.concealment) or '-':<28} {1e3 * e['track_m']:6.1f} {1e3 * e['track_null_m']:6.1f} {1e3 * e['late_m']:6.1f} {1e3 * e['late_null_m']:6.1f} "
                  f"{1e3 * e['odo_m']:7.1f} {e['omega']:6.2f} {e['duty']:6.3f}", flush=True)
        print("track/null: max tracking error |p_true - p_ref| (mm) of the case and of the nominal "
              "truth with the same experiments (camera noise 1 mm), over the whole run and over its last 40 %; then max differences from the "
              "nominal truth: odometry (mm), board wheel speed (rad/s), duty")
        return 0
    if a.cmd == "score":
        from host_tools.suite.bench import collect, summarize
        try:
            res = collect(a.out, sel, rescore=a.rescore)
        except FileNotFoundError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        text, _ = summarize(res, sum(r.get("case_s", 0.0) for r in res))
        print(text)
        print("(total time = sum of the cases' analysis and generation times)")
        return 0
    from host_tools.suite.bench import bench
    _, m, text = bench(a.out, sel, jobs=a.jobs, regenerate=not a.reuse,
                       out=lambda s: print(s, flush=True))
    print(text)
    print(f"results: {os.path.join(a.out, 'bench.txt')}, {os.path.join(a.out, 'bench.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
