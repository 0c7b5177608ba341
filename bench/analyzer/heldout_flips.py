"""Which candidates the adoption test's error changes: ``python bench/analyzer/heldout_flips.py
run --sets 13-23 --out FILE [--jobs 2] [--cases A,B]`` and ``... summary FILE``.

Measurement only.  ``run`` analyses every case of the generated held-back sets
(``/work/wt/score-data/heldbackN/runs``, made by ``python -m host_tools.suite generate --set
heldbackN``) with the analyzer as it is, and after each candidate's judgement (``select.judge``)
computes the held-out paired test's z both ways, the fixed-design error per segment
(``fit.judge.paired_better`` with the candidate's segments, the rule) and the sample spread of
the differences (without them); a candidate whose held-out check differs between the two is a
flip, listed with its other checks (a flip decides nothing where another check refuses the
candidate).  A case with no flip whose other checks all pass is analysed exactly as with the
sample-spread test (the test enters nothing else), so only the cases with a deciding flip need
the analyzer before the rule to compare (``suite bench --cases``).  Each case's verdict,
selected effects and label go to FILE as one JSON line.

``summary`` lists the cases with a deciding flip and counts them.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import multiprocessing as mp
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from heldout_null_variance import SCORE, _sets  # noqa: E402  (sets the project's path too)


def _one(case_dir: str) -> dict:
    import logging

    from host_tools.analyzer import pipeline, select
    from host_tools.analyzer.fit import judge as jm
    logging.disable(logging.WARNING)
    flips: list[dict] = []
    original = select.judge

    def judged(problem, cand, *a, **k):
        original(problem, cand, *a, **k)
        if cand.heldout_pooled is None:
            return
        old_ok, z_old = jm.paired_better(*cand.heldout_pooled)
        new_ok = cand.checks.get("heldout")
        if bool(old_ok) != bool(new_ok):
            others = {c: v for c, v in cand.checks.items() if c != "heldout"}
            flips.append({"effect": cand.name, "z_sample_spread": z_old,
                          "z_fixed_design": cand.heldout_z, "new_ok": bool(new_ok),
                          "others_pass": all(others.values()), "delta_bic": cand.delta_bic,
                          "failing": [c for c, v in others.items() if not v]})

    select.judge = judged
    runs = sorted(d for d in glob.glob(os.path.join(case_dir, "run-*"))
                  if os.path.exists(os.path.join(d, "meta.json")))
    an = pipeline.analyze(runs, jobs=1, log=lambda _m: None)
    case = os.path.basename(case_dir)
    n = int(case.split("_")[0][2:])
    lab = json.load(open(f"{SCORE}/heldback{n}/labels/{case}.json"))
    out = {"case": case, "verdict": an.verdict,
           "selected": [s["effect"] for s in an.selected], "flips": flips,
           "true_effects": lab.get("true_effects", []), "expect": lab.get("expect")}
    if any(f["others_pass"] for f in flips):
        # a deciding flip: the same case with the sample spread's test throughout
        select.judge = original
        rule = jm.paired_better
        jm.paired_better = lambda b, a, z=jm.HELDOUT_Z, segments=None: rule(b, a, z)  # type: ignore
        old = pipeline.analyze(runs, jobs=1, log=lambda _m: None)
        jm.paired_better = rule
        out["before_rule"] = {"verdict": old.verdict,
                              "selected": [s["effect"] for s in old.selected]}
    return out


def run(sets: list[int], out: str, jobs: int, cases: str | None) -> None:
    done = set()
    if os.path.exists(out):
        done = {json.loads(ln)["case"] for ln in open(out)}
    dirs = [d for n in sets for d in sorted(glob.glob(f"{SCORE}/heldback{n}/runs/hb*"))
            if os.path.basename(d) not in done
            and (cases is None or os.path.basename(d) in cases.split(","))]
    ctx = mp.get_context("fork")
    with ctx.Pool(jobs, maxtasksperchild=1) as pool, open(out, "a") as fh:
        for res in pool.imap_unordered(_one, dirs):
            fh.write(json.dumps(res) + "\n")
            fh.flush()
            deciding = [f for f in res["flips"] if f["others_pass"]]
            print(f"{res['case']:34s} {res['verdict']:12s} {'+'.join(res['selected']) or '-':30s} "
                  f"flips {len(res['flips'])} deciding {len(deciding)} "
                  + (f"[before the rule: {res['before_rule']['verdict']} "
                     f"{'+'.join(res['before_rule']['selected']) or '-'}] "
                     if "before_rule" in res else "")
                  + " ".join(f"{f['effect']}:{f['z_sample_spread']:.2f}->{f['z_fixed_design']:.2f}"
                             for f in deciding), flush=True)


def summary(path: str) -> None:
    rows = [json.loads(ln) for ln in open(path)]
    nflip = ndec = 0
    for r in rows:
        dec = [f for f in r["flips"] if f["others_pass"]]
        nflip += bool(r["flips"])
        ndec += bool(dec)
        for f in r["flips"]:
            print(f"{r['case']:34s} {f['effect']:28s} z {f['z_sample_spread']:6.2f} -> "
                  f"{f['z_fixed_design']:6.2f} {'pass' if f['new_ok'] else 'refuse'} "
                  f"{'DECIDING' if f['others_pass'] else 'refused by ' + ','.join(f['failing'])}"
                  f"  dBIC {f['delta_bic']:.1f}  | now {r['verdict']} "
                  f"{'+'.join(r['selected']) or '-'} true {'+'.join(r['true_effects']) or '-'}"
                  + (f" | before the rule {r['before_rule']['verdict']} "
                     f"{'+'.join(r['before_rule']['selected']) or '-'}" if "before_rule" in r
                     else ""))
    zs = [f["z_fixed_design"] for r in rows for f in r["flips"]]
    print(f"{len(rows)} cases, {nflip} with a flip, {ndec} with a deciding flip "
          f"(z range {min(zs, default=math.nan):.2f}..{max(zs, default=math.nan):.2f})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/heldout_flips.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("run")
    p.add_argument("--sets", default="13-23")
    p.add_argument("--out", required=True)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--cases")
    p = sub.add_parser("summary")
    p.add_argument("file")
    a = ap.parse_args(argv)
    if a.cmd == "run":
        run(_sets(a.sets), a.out, a.jobs, a.cases)
    else:
        summary(a.file)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
