"""``python -m host_tools analyze RUN_DIR [RUN_DIR ...] --out OUT_DIR``

Replays each run through the nominal plant (lib/slipmodel via its C ABI), locates where the
recordings disagree with it, fits every effect of the vocabulary across all runs, selects
what the data support, and writes OUT_DIR/report.json (mismatch-report/1), report.md,
report.html, series/<run>.csv, PNG plots and model.json (the updated model parameters,
ddmodel/1), as one set: all or nothing per invocation.

Exit codes: 0 done, 2 bad input (the message says what is wrong and where: file, row,
column), 1 the native plant library could not be built or loaded, or writing the outputs
failed (e.g. the disk is full).  Every run is read and validated, and --out is created and
checked for writing, before any analysis starts."""
from __future__ import annotations

import argparse
import logging
import math
import os
import signal
from types import FrameType
from typing import TYPE_CHECKING, Any

from host_tools._stdio import STATUS, out

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from host_tools.runfmt import Run

# Bounds of the options (every option is bounded: a value outside gives exit 2).
DT_MIN_S, DT_MAX_S = 1e-4, 1e-2   # plant step; 5e-4 is the default, 1e-4 costs 5x as long
JOBS_MAX = 64
# The replay's grid has one point per inner tick over the run: a run longer than this many
# ticks is refused (5e6: 35 h at 25 ms, 1.4 h at 1 ms; the grid's arrays alone take about
# 40 MB each) instead of asking for hundreds of GiB (a last-row t_s of 1e9).
MAX_INNER_TICKS = 5_000_000
EFFECTS_MAX = 64

EPILOG = """\
outputs (in OUT_DIR):
  report.json   verdict, located mismatch windows, selected effects, every candidate, errors
  report.md     the human report: a ten-second summary, then the details (errors, plots)
  report.html   interactive, self-contained (plotly): every run and channel, x-y paths
  series/<run>.csv  per sample: recording, nominal/updated replay, residuals, noise band
  *.png         the largest mismatches first (every run represented), an x-y path per run
  model.json    updated model parameters (format ddmodel/1, see docs/analyzer.md)
the set is replaced all or nothing (staged in OUT_DIR/.analyze-staging-*, then renamed).

progress goes to stderr (a progress bar on a terminal; -q: errors only).  exit status: 0 done, 2 bad input (file, row, column), 1 native
plant unavailable or the outputs could not be written.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n")[1] if __doc__ else None
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR",
                        help="run folders (ddrun/1: meta.json, telemetry.csv, [groundtruth.csv]); "
                             "several runs must come from one robot (same parameters)")
    parser.add_argument("--out", required=True, metavar="OUT_DIR",
                        help="folder for report.json, report.md, report.html, series/, plots "
                             "and model.json (created if missing)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes fitting candidates in parallel, 1..%d (default "
                             "%%(default)s)" % JOBS_MAX)
    parser.add_argument("--effects", default=None, metavar="NAME[,NAME...]",
                        help="fit only these vocabulary effects (default: all)")
    parser.add_argument("--dt", type=float, default=5e-4, metavar="SECONDS",
                        help="plant integration step, %g..%g s (default %%(default)s)"
                             % (DT_MIN_S, DT_MAX_S))
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots "
                        "(report.html and the series are still written)")


def _native_build_error() -> type[BaseException]:
    try:
        from host_tools._native import NativeBuildError
        return NativeBuildError
    except Exception:  # the module itself is missing: ImportError covers it
        return ImportError


def _bad(msg: str) -> int:
    log.error("bad input: %s", msg)
    return 2


def check_out_dir(out: str) -> tuple[str | None, str | None]:
    """Create ``out`` (if missing) and in it the fresh staging folder of this analysis's outputs
    (report/outputs.py: created exclusively, so also the check that ``out`` can be written);
    (staging folder, None) or (None, what is wrong)."""
    from host_tools.analyzer.report import outputs
    from host_tools.runfmt import display

    shown = display(out)
    if os.path.exists(out) and not os.path.isdir(out):
        return None, f"--out {shown} exists and is not a folder"
    try:
        return outputs.create_staging(out), None
    except OSError as exc:
        return None, f"--out {shown} cannot be created or written: {exc.strerror or exc}"


def check_analyzable(runs: list[Run], dt_s: float) -> None:
    """What the analyzer needs beyond the run format (RunFormatError naming file, row, column):
    an inner loop no faster than the plant step (the replay applies one command per inner
    tick; a loop of 1e-5 s, the format's minimum, would take the replay hours for nothing it
    can resolve) and a run of at most :data:`MAX_INNER_TICKS` inner ticks."""
    import numpy as np

    from host_tools.runfmt import RunFormatError

    for r in runs:
        meta_file = os.path.join(r.path, "meta.json")
        tel_file = os.path.join(r.path, "telemetry.csv")
        inner = float(r.meta["periods_s"]["inner"])
        if inner < dt_s:
            raise RunFormatError(
                f"periods_s.inner = {inner:g} s is shorter than the plant step (--dt "
                f"{dt_s:g} s): the replay applies one command per inner tick, so the analyzer "
                "needs periods_s.inner >= --dt", file=meta_file, column="periods_s.inner")
        t = np.asarray(r.telemetry["t_s"], float)
        span = float(t[-1] - t[0]) if t.size else 0.0
        if not (np.isfinite(span) and span / inner <= MAX_INNER_TICKS):
            steps = np.diff(t)
            j = int(np.nanargmax(steps)) + 1 if steps.size else 0
            raise RunFormatError(
                f"the run spans {span:g} s (the largest step, {float(steps[j - 1]):g} s, ends "
                f"here): at periods_s.inner = {inner:g} s that is more than the analyzer's "
                f"{MAX_INNER_TICKS:.0e} inner ticks ({MAX_INNER_TICKS * inner / 3600:.3g} h); "
                "is a time stamp wrong?", file=tel_file, row=j + 1, column="t_s")


class _Interrupted(Exception):
    pass


_STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


def _stop_on_signals() -> dict[int, Any]:
    """SIGINT, SIGTERM and SIGHUP end the analysis with exit 1 and a message.  The first one
    raises :class:`_Interrupted`; the ones after it are ignored, so that a second SIGTERM (or a
    volley of Ctrl-Cs) cannot interrupt the clean-up and end in a traceback.  The worker
    processes it forks end silently on them (the default action), as the pool expects."""
    main_pid = os.getpid()

    def handler(signum: int, _frame: FrameType | None) -> None:
        if os.getpid() != main_pid:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        for name in _STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                signal.signal(sig, signal.SIG_IGN)
        raise _Interrupted(signal.Signals(signum).name)
    old: dict[int, Any] = {}
    for name in _STOP_SIGNALS:
        sig = getattr(signal, name, None)
        if sig is not None:
            old[sig] = signal.signal(sig, handler)
    return old


def main(args: argparse.Namespace) -> int:
    old = _stop_on_signals()
    state: dict[str, Any] = {"staging": None, "committed": False}
    try:
        return _main(args, state)
    except _Interrupted as exc:
        if state["committed"]:
            log.error(f"interrupted by {exc} after the outputs were written (complete)")
        else:
            log.error(f"interrupted by {exc}; no outputs written (the previous outputs in "
                      "--out, if any, are left as they were: the outputs are replaced as one set "
                      "or not at all)")
        return 1
    finally:
        if state["staging"] is not None and not state["committed"]:
            from host_tools.analyzer.report import outputs
            outputs.remove_staging(state["staging"])
        for sig, h in old.items():
            signal.signal(sig, h)
        from host_tools import _progress
        _progress.end_stages("analyze")


def _main(args: argparse.Namespace, state: dict[str, Any]) -> int:
    from host_tools import runfmt
    from host_tools.runfmt import RunFormatError

    if not 1 <= args.jobs <= JOBS_MAX:
        return _bad(f"--jobs {args.jobs} must be in 1..{JOBS_MAX}")
    if not (math.isfinite(args.dt) and DT_MIN_S <= args.dt <= DT_MAX_S):
        return _bad(f"--dt {args.dt:g} must be in [{DT_MIN_S:g}, {DT_MAX_S:g}] s")
    effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None
    if args.effects is not None and not effects:
        return _bad("--effects names no effect")
    if effects and (len(effects) > EFFECTS_MAX or
                    not all(e.isascii() and e.replace("_", "").isalnum() for e in effects)):
        return _bad(f"--effects must be up to {EFFECTS_MAX} vocabulary names "
                    "(letters, digits, '_') separated by commas")
    staging, problem = check_out_dir(args.out)
    if problem:
        return _bad(problem)
    state["staging"] = staging
    try:
        runs = [runfmt.load_run(p, min_rows=runfmt.ANALYZER_MIN_ROWS) for p in args.runs]
        runfmt.check_compatible(runs)
        check_analyzable(runs, args.dt)
    except RunFormatError as exc:
        return _bad(str(exc))
    runfmt.label_runs(runs)
    for r in runs:  # the plant steps explicitly: --dt must be stable for every run's robot
        dt_max = runfmt.max_stable_plant_dt_s(r.meta)
        if args.dt > dt_max:
            return _bad(f"--dt {args.dt:g} s is longer than the longest stable plant step for "
                        f"{runfmt.display(os.path.join(r.path, 'meta.json'))} ({dt_max:.3g} s: "
                        "twice a slipping wheel's back-EMF time constant); pass a smaller --dt")
    for r in runs:
        log.info("%s: %d telemetry rows", runfmt.display(r.path), len(r.telemetry["t_s"]))
    log.debug("options: --jobs %d, --dt %g s, --effects %s", args.jobs, args.dt,
              ",".join(effects) if effects else "all")
    notes = [n for r in runs for n in r.notes]
    for n in notes:
        log.log(STATUS, f"note: {n}")
    from host_tools.analyzer.pipeline import analyze
    from host_tools.analyzer.report.writers import write_outputs
    try:
        an = analyze(runs, jobs=args.jobs, effects=effects, dt_s=args.dt)
    except RunFormatError as exc:
        return _bad(str(exc))
    except (ImportError, OSError, _native_build_error()) as exc:
        # the native plant (lib/slipmodel via host_tools._native) could not be built or loaded
        log.error(f"the native plant is unavailable: {type(exc).__name__}: {exc}")
        return 1
    an.notes.extend(notes)
    try:
        write_outputs(an, args.out, plots=not args.no_plots, staging=staging,
                      on_commit=lambda: state.update(committed=True))
    except OSError as exc:
        log.error(f"cannot write the outputs into {runfmt.display(args.out)}: "
                  f"{exc.strerror or exc}; the previous outputs there, if any, are left as they "
                  "were")
        return 1
    from host_tools import _progress
    _progress.end_stages("analyze")  # the result below the finished stage line
    out(f"verdict: {an.verdict}; report: {runfmt.display(os.path.join(args.out, 'report.json'))}")
    return 0
