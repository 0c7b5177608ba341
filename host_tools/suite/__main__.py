"""``python -m host_tools.suite {list,generate,conceal,bench,score} [--set NAME]`` — the
concealed-effect suite. The tuning set (default) and the MuJoCo tuning group are where analyzer
rules may be settled; the held-back sets (other seeds, effect sizes and recorders, long runs)
are only scored and their figures are the ones that count (docs/suite.md, docs/validation.md)."""
from __future__ import annotations

import argparse
import logging
import os
import sys

log = logging.getLogger("host_tools.suite")  # also when run as __main__


def _recorder_option(text: str, profiles: dict) -> tuple[dict, str]:
    """``--recorder`` value: a profile name or ``key=value,...`` -> (options, name)."""
    from host_tools import truth
    if text in profiles:
        return dict(profiles[text]), text
    opts: dict = {}
    for item in filter(None, text.split(",")):
        k, eq, v = item.partition("=")
        if not eq:
            raise ValueError(f"--recorder {text!r}: a profile ({', '.join(profiles)}) or "
                             "key=value[,key=value]")
        k = k.strip()
        try:
            opts[k] = float(v) if k not in ("current",) else bool(int(v))
        except ValueError:
            opts[k] = v.strip()
    truth.recorder_config(opts)  # checks names and values
    return opts, text


def main(argv=None) -> int:
    from host_tools.suite import cases as C
    ap = argparse.ArgumentParser(prog="python -m host_tools.suite", description=__doc__)
    from host_tools.__main__ import add_verbosity, setup_logging
    add_verbosity(ap)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name, help_ in (("list", "list the cases"), ("generate", "write the runs and hidden labels"),
                        ("bench", "generate, run the analyzer on every case, score"),
                        ("conceal", "how much each case differs from the nominal truth, per channel"),
                        ("score", "summarize the scores of earlier bench runs (no analysis)")):
        p = sub.add_parser(name, help=help_)
        p.add_argument("--set", dest="which", choices=C.SETS, default="tuning",
                       help="tuning or mujoco (rules may be settled on them), heldback, "
                            f"heldback2 to {C.SETS[-1]} (only scored)")
        p.add_argument("--fast", action="store_true", help="only the set's fast subset (CI)")
        p.add_argument("--no-long", action="store_true",
                       help="leave out the 10-minute cases (held-back set)")
        p.add_argument("--cases", default=None, help="comma-separated case names")
        if name != "list":
            p.add_argument("--out", default=None,
                           help="data folder (default out/suite, or out/suite-heldback)")
            p.add_argument("--seed-offset", type=int, default=0,
                           help="add to every case's seed (other noise, phases; same physics)")
            p.add_argument("--recorder", default=None, metavar="PROFILE|KEY=VALUE,...",
                           help="record the selected cases with another recorder: a profile ("
                                + ", ".join(C.RECORDERS) + ") or options of "
                                "host_tools.truth.RECORDER_DEFAULTS (controller=cascade|pi, "
                                "odometry=firmware|ticks|frames, integration=arc|midpoint, "
                                "inner_s, tel_jitter_s, tel_drop, cam_hz, cam_noise_m, "
                                "cam_noise_rad, cam_dropout, heading_tel=unwrapped|wrapped, "
                                "heading_gt=unwrapped|wrapped, current=0|1, adc_noise_lsb), "
                                "applied over each case's own")
            p.add_argument("--engine", choices=("truth", "mujoco"), default=None,
                           help="record the selected cases on this physics engine instead of "
                                "each case's own (the MuJoCo model needs the mujoco package)")
        if name == "score":
            p.add_argument("--rescore", action="store_true",
                           help="score again from the stored reports and labels")
        if name == "bench":
            p.add_argument("--jobs", type=int, default=2, help="analyzer processes (default 2)")
            p.add_argument("--reuse", action="store_true", help="reuse runs already generated")
            p.add_argument("--timeout", type=float, default=None,
                           help="analyzer time limit per case, s (default 300; a case past it "
                                "is stopped and scored as a timeout)")
            p.add_argument("--dask", action="store_true",
                           help="run the cases as one batch on a local Dask cluster of --jobs "
                                "workers (host_tools.batch)")
            p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                           help="run the cases as one batch on the Dask cluster at ADDRESS")
    a = ap.parse_args(argv)
    setup_logging(-1 if a.quiet_log else a.verbose)
    try:
        sel = C.get(a.cases.split(",") if a.cases else None, fast=a.fast, which=a.which,
                    long=not a.no_long)
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    if getattr(a, "out", "") is None:
        a.out = "out/suite" if a.which == "tuning" else f"out/suite-{a.which}"
    for c in sel:
        c.seed += getattr(a, "seed_offset", 0)
    if getattr(a, "recorder", None):
        try:
            extra, name = _recorder_option(a.recorder, C.RECORDERS)
        except ValueError as exc:
            log.error("%s", exc)
            return 2
        for c in sel:
            c.recorder = {**c.recorder, **extra}
            c.recorder_name = name if c.recorder_name == "firmware" else f"{c.recorder_name}+{name}"
    if getattr(a, "engine", None):
        for c in sel:
            if c.engine != a.engine:
                c.engine, c.engine_options = a.engine, {}
    if a.cmd == "list":
        for c in sel:
            print(f"{c.name:<32} expect {c.expect:<12} {len(c.experiments)} runs "
                  f"{c.length:<6} {c.recorder_name:<18} {'long ' if c.long else ''}"
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
        print(f"{'case':<32} {'concealment':<28} {'track':>6} {'null':>6} {'late':>6} {'null':>6} {'odo mm':>7} {'omega':>6} {'duty':>6}")
        for c in sel:
            generate_case(c, a.out, overwrite=True)
            e = evidence(c, a.out)
            print(f"{c.name:<32} {','.join(c.concealment) or '-':<28} {1e3 * e['track_m']:6.1f} {1e3 * e['track_null_m']:6.1f} {1e3 * e['late_m']:6.1f} {1e3 * e['late_null_m']:6.1f} "
                  f"{1e3 * e['odo_m']:7.1f} {e['omega']:6.2f} {e['duty']:6.3f}", flush=True)
        print("track/null: max tracking error |p_true - p_ref| (mm) of the case and of the nominal "
              "truth with the same experiments (camera noise 1 mm), over the whole run and over its last 40 %; then max differences from the "
              "nominal truth: odometry (mm), board wheel speed (rad/s), duty")
        return 0
    if a.cmd == "score":
        from host_tools.suite.bench import ScoreFileError, collect, summarize
        try:
            res = collect(a.out, sel, rescore=a.rescore)
        except (FileNotFoundError, ScoreFileError) as exc:
            log.error("%s", exc)
            return 2
        text, _ = summarize(res, sum(r.get("case_s", 0.0) for r in res))
        print(f"set: {a.which}")
        print(text)
        print("(total time = sum of the cases' analysis and generation times)")
        return 0
    from host_tools.suite.bench import bench
    from host_tools.suite.bench import DEFAULT_TIMEOUT_S
    _, m, text = bench(a.out, sel, jobs=a.jobs, regenerate=not a.reuse,
                       out=lambda s: print(s, flush=True),
                       timeout_s=a.timeout if a.timeout is not None else DEFAULT_TIMEOUT_S,
                       scheduler=a.scheduler or ("local" if a.dask else None))
    print(f"set: {a.which}" + (" (fast subset)" if a.fast else "") +
          (" (without the 10-minute cases)" if a.no_long else ""))
    print(text)
    print(f"results: {os.path.join(a.out, 'bench.txt')}, {os.path.join(a.out, 'bench.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
