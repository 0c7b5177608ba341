"""``python -m host_tools analyze RUN_DIR [RUN_DIR ...] --out OUT_DIR``

Replays each run through the nominal plant (lib/slipmodel via its C ABI), locates where the
recordings disagree with it, fits every effect of the vocabulary across all runs, selects
what the data support, and writes OUT_DIR/report.json (mismatch-report/1), report.md,
PNG plots and model.json (the updated model parameters, ddmodel/1).

Exit codes: 0 done, 2 bad input (the message says what is wrong and where), 1 the native
plant library could not be built or loaded."""
from __future__ import annotations

import argparse
import os
import sys

EPILOG = """\
outputs (in OUT_DIR):
  report.json   verdict, located mismatch windows, selected effects, every candidate, errors
  report.md     the human report (tables of errors before/after, plots)
  *.png         recording, nominal and updated simulation, windows of mismatch shaded
  model.json    updated model parameters (format ddmodel/1, see docs/analyzer.md)

progress goes to stderr.  exit status: 0 done, 2 bad input, 1 native plant unavailable.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n")[1] if __doc__ else None
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR",
                        help="run folders (ddrun/1: meta.json, telemetry.csv, [groundtruth.csv]); "
                             "several runs must come from one robot (same parameters)")
    parser.add_argument("--out", required=True, metavar="OUT_DIR",
                        help="folder for report.json, report.md, plots and model.json "
                             "(created if missing)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes fitting candidates in parallel (default %(default)s)")
    parser.add_argument("--effects", default=None, metavar="NAME[,NAME...]",
                        help="fit only these vocabulary effects (default: all)")
    parser.add_argument("--dt", type=float, default=5e-4, metavar="SECONDS",
                        help="plant integration step (default %(default)s)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")


def _native_build_error() -> type:
    try:
        from host_tools._native import NativeBuildError
        return NativeBuildError
    except Exception:  # the module itself is missing: ImportError covers it
        return ImportError


def main(args: argparse.Namespace) -> int:
    from host_tools.runfmt import RunFormatError

    if args.jobs < 1:
        print("error: --jobs must be at least 1", file=sys.stderr)
        return 2
    if not (args.dt > 0 and args.dt <= 0.01):
        print(f"error: --dt {args.dt} must be in (0, 0.01] s", file=sys.stderr)
        return 2
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        print(f"error: --out {args.out} exists and is not a folder", file=sys.stderr)
        return 2
    effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None
    from host_tools.analyzer.analysis import analyze
    from host_tools.analyzer.report import write_outputs
    try:
        an = analyze(args.runs, jobs=args.jobs, effects=effects, dt_s=args.dt)
    except RunFormatError as exc:
        print(f"error: bad input: {exc}", file=sys.stderr)
        return 2
    except (ImportError, OSError, _native_build_error()) as exc:
        # the native plant (lib/slipmodel via host_tools._native) could not be built or loaded
        print(f"error: the native plant is unavailable: {type(exc).__name__}: {exc}",
              file=sys.stderr)
        return 1
    write_outputs(an, args.out, plots=not args.no_plots)
    print(f"verdict: {an.verdict}; report: {os.path.join(args.out, 'report.json')}")
    return 0
