"""The analysis pipeline (:func:`analyze`): load runs, prepare them (input timing), replay them
nominally (closed loop through lib/control, open loop driven by the recorded duty and torque),
locate the mismatch in noise floors, fit every vocabulary effect (in parallel) and pairs of
them, select, decide the verdict, and assemble the :class:`Analysis` that ``report.writers``
writes.  Each stage lives in its own module, in the order :func:`analyze` calls them."""
from __future__ import annotations

import dataclasses
import os
import time
from typing import Callable, Sequence

from host_tools import runfmt
from host_tools.analyzer import stage_log
from host_tools.analyzer.locate.mismatch import Detection, Located, detect_mismatch, locate_mismatch
from host_tools.analyzer.prepare.command_lag import select_command_delay
from host_tools.analyzer.prepare.inputs import prepare_runs
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import Channel
from host_tools.analyzer.replay.nominal import (NominalClosedLoop, NominalOpenLoop,
                                                replay_closed_loop, replay_open_loop)
from host_tools.analyzer.report.model import updated_model
from host_tools.analyzer.report.sections import (Analysis, closed_loop_report, error_tables,
                                                 localize, recorder_findings, replay_updated)
from host_tools.analyzer.select import (decide_verdict, fit_candidates, invariance_of,
                                        select_effects, selected_entries)


def analyze(run_dirs: Sequence[str | os.PathLike[str] | runfmt.Run], jobs: int = 2,
            effects: Sequence[str] | None = None, dt_s: float = 5e-4, pairs_top: int = 5,
            log: Callable[[str], None] = stage_log) -> Analysis:
    """Analyze the runs in ``run_dirs`` (one robot): the stages below, in this order.  Each
    stage's docstring says what it decides and why.  ``notes`` collects the report's notes in
    the order the stages add them.  ``log`` gets each finished stage's message (default: the
    package's stage line, ``host_tools.analyzer.stage_log``); the fits' progress goes to the
    package's logger (``host_tools.analyzer.log``), which the logging configuration silences."""
    t_start = time.time()
    notes: list[str] = []
    fr = front(run_dirs, effects, dt_s, notes, log)
    runs, preps, cl, ol, nominal, loc, det = fr.runs, fr.preps, fr.cl, fr.ol, fr.nominal, fr.loc, fr.det
    cands = fit_candidates(det, fr.vocab_fit, jobs, notes, log)
    sel = select_effects(det, cands, jobs, pairs_top, log)
    selected = selected_entries(sel, det.rss0)
    invariance = invariance_of(det, sel)
    verdict, hint = decide_verdict(det, sel.effects, selected, preps, ol.duty, notes, invariance)
    verdict, model_effects = select_command_delay(preps, selected, verdict, sel.effects, notes,
                                                  log)
    updated, cl_updated = replay_updated(preps, ol.duty, cl, sel.effects)
    closed_loop = closed_loop_report(cl, cl_updated, loc, sel.effects)
    fit_table = error_tables(det, sel, loc.floors, closed_loop)
    if invariance is not None:
        fit_table["invariance"] = invariance.report()
    recorder = recorder_findings(preps, nominal, loc.floors, notes)
    localization = localize(preps, nominal, updated, loc.floors, det.problem.fit_channels,
                            det.strong_k)
    model = updated_model(runs[0].meta, model_effects, [r.path for r in runs])
    an = Analysis(runs, preps, loc.floors, nominal, ol.nominal_t, updated,
                  loc.entries if verdict != "no_mismatch" else [],
                  sorted(sel.singles + sel.pairs, key=lambda c: c.delta_bic), selected, verdict,
                  fit_table, hint, model, notes, torque_mismatch=loc.entries_t,
                  windows={**loc.windows, **loc.cl_windows}, closed_loop=closed_loop,
                  cl_nominal=cl.nominal, cl_updated=cl_updated, recorder=recorder,
                  localization=localization)
    an.timing_s = time.time() - t_start
    log(f"verdict: {verdict}" + (f"; selected {', '.join(s['effect'] for s in selected)}"
                                 if selected else "") + f" ({an.timing_s:.1f} s)")
    return an


@dataclasses.dataclass
class Front:
    """The stages of :func:`analyze` up to the mismatch's detection, in its order: the loaded
    runs, the candidates' vocabulary, the prepared runs (as located), both nominal replays, the
    nominal channels, the located mismatch and its detection (``det.problem``: the fit problem
    every candidate is fitted on)."""
    runs: list[runfmt.Run]
    vocab_fit: dict[str, dict[str, float]]
    preps: list[PreparedRun]
    cl: NominalClosedLoop
    ol: NominalOpenLoop
    nominal: list[dict[str, Channel]]
    loc: Located
    det: Detection


def _quiet(_msg: str) -> None:
    return None


def front(run_dirs: Sequence[str | os.PathLike[str] | runfmt.Run],
          effects: Sequence[str] | None = None, dt_s: float = 5e-4,
          notes: list[str] | None = None, log: Callable[[str], None] = _quiet) -> Front:
    """:func:`analyze`'s stages up to the detection, for :func:`analyze` and for the tools and
    tests that fit on an analysis's own problem (``front(paths).det.problem``).  ``notes``
    collects the stages' report notes (a new list when not given); ``log`` is silent unless
    given."""
    notes = [] if notes is None else notes
    runs = _load_runs(run_dirs, log)
    vocab, vocab_fit = _vocabulary(effects)
    preps = prepare_runs(runs, log)
    preps, cl = replay_closed_loop(preps, dt_s, notes, log)
    ol = replay_open_loop(preps, dt_s)
    preps, nominal, loc = locate_mismatch(ol.preps, ol.nominal, ol.nominal_t, cl.nominal, log)
    det = detect_mismatch(preps, nominal, loc, vocab, dt_s, notes, log)
    return Front(runs, vocab_fit, preps, cl, ol, nominal, loc, det)


def _load_runs(run_dirs: Sequence[str | os.PathLike[str] | runfmt.Run],
               log: Callable[[str], None]) -> list[runfmt.Run]:
    """Load and validate the run folders.  Several runs must come from one robot
    (``runfmt.check_compatible``): the fits pool them under one set of parameters.  When two
    folders share a base name, the report's run list and the model's sources give full paths,
    so that the two can be told apart (on new values: a loaded run passed in is left as it
    is)."""
    runs = [runfmt.load_run(p) for p in run_dirs]
    runfmt.check_compatible(runs)
    names_seen = [r.name for r in runs]
    if len(set(names_seen)) != len(names_seen):
        runs = [dataclasses.replace(r, path=os.path.abspath(r.path)) for r in runs]
    log(f"loaded {len(runs)} run(s): " + ", ".join(r.name for r in runs))
    return runs


def _vocabulary(effects: Sequence[str] | None
                ) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, float]]]:
    """(the whole effect vocabulary of lib/slipmodel, the effects to fit as candidates).  The
    fit problem knows the whole vocabulary; ``effects`` (the command line's ``--effects``) only
    narrows which candidates are fitted, and an unknown name is an input error, not an empty
    fit."""
    from host_tools import _native
    from host_tools.analyzer.effects import parameter_effect_vocabulary
    vocab = {**_native.effect_vocabulary(), **parameter_effect_vocabulary()}
    if not effects:
        return vocab, vocab
    unknown = [e for e in effects if e not in vocab]
    if unknown:
        raise runfmt.RunFormatError(f"unknown effect(s) {unknown}; known: {list(vocab)}")
    return vocab, {e: vocab[e] for e in effects}
