"""The analysis pipeline (:func:`analyze`): load runs, prepare them (input timing), replay them
nominally (closed loop through lib/control, open loop driven by the recorded duty and torque),
locate the mismatch in noise floors, fit every vocabulary effect (in parallel) and pairs of
them, select, decide the verdict, and assemble the :class:`Analysis` that ``report.writers``
writes.  Each stage lives in its own module, in the order :func:`analyze` calls them."""
from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from host_tools import runfmt
from host_tools.analyzer.fit.workers import log_stderr
from host_tools.analyzer.locate.mismatch import detect_mismatch, locate_mismatch
from host_tools.analyzer.prepare.command_lag import command_lag
from host_tools.analyzer.prepare.inputs import prepare_timed
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.anchors import edges_outside_slip
from host_tools.analyzer.replay.channels import Channel, channels
from host_tools.analyzer.replay.closedloop import ClosedLoopReplay, closed_loop_channels
from host_tools.analyzer.replay.openloop import OpenLoopReplay
from host_tools.analyzer.replay.tolerance import tolerance_uncertainty
from host_tools.analyzer.replay.unseen import fill_unseen_from_controller, input_uncertainty
from host_tools.analyzer.report.model import updated_model
from host_tools.analyzer.report.sections import (Analysis, closed_loop_report, error_tables,
                                                 localize, recorder_findings)
from host_tools.analyzer.select import (decide_verdict, fit_candidates, invariance_of,
                                         select_effects,
                                         selected_entries)


def analyze(run_dirs: Sequence[str | os.PathLike[str] | runfmt.Run], jobs: int = 2,
            effects: Sequence[str] | None = None, dt_s: float = 5e-4, pairs_top: int = 5,
            log: Callable[[str], None] = log_stderr) -> Analysis:
    """Analyze the runs in ``run_dirs`` (one robot): the stages below, in this order.  Each
    stage's docstring says what it decides and why.  ``notes`` collects the report's notes in
    the order the stages add them."""
    t_start = time.time()
    runs = _load_runs(run_dirs, log)
    vocab, vocab_fit = _vocabulary(effects)
    notes: list[str] = []
    duty = OpenLoopReplay("duty", dt_s=dt_s)
    torque = OpenLoopReplay("torque", dt_s=dt_s)
    preps = _prepare(runs, log)
    preps, cl = _replay_closed_loop(preps, dt_s, notes, log)
    preps, nominal, nominal_t = _replay_nominal(preps, duty, torque)
    preps, nominal, loc = locate_mismatch(preps, nominal, nominal_t, cl.nominal, log)
    det = detect_mismatch(preps, nominal, loc, vocab, dt_s, notes, log)
    cands = fit_candidates(det, vocab_fit, jobs, notes, log)
    sel = select_effects(det, cands, jobs, pairs_top, log)
    selected = selected_entries(sel, det.rss0)
    invariance = invariance_of(det, sel)
    verdict, hint = decide_verdict(det, sel.effects, selected, preps, duty, notes, invariance)
    verdict, model_effects = _command_delay(preps, selected, verdict, sel.effects, notes, log)
    updated, cl_updated = _replay_updated(preps, duty, cl, sel.effects)
    closed_loop = closed_loop_report(cl, cl_updated, loc, sel.effects)
    fit_table = error_tables(det, sel, loc.floors, closed_loop)
    if invariance is not None:
        fit_table["invariance"] = invariance.report()
    recorder = recorder_findings(preps, nominal, loc.floors, notes)
    localization = localize(preps, nominal, updated, loc.floors, det.problem.fit_channels,
                            det.strong_k)
    model = updated_model(runs[0].meta, model_effects, [r.path for r in runs])
    an = Analysis(runs, preps, loc.floors, nominal, nominal_t, updated,
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


def _load_runs(run_dirs: Sequence[str | os.PathLike[str] | runfmt.Run],
               log: Callable[[str], None]) -> list[runfmt.Run]:
    """Load and validate the run folders.  Several runs must come from one robot
    (``runfmt.check_compatible``): the fits pool them under one set of parameters.  When two
    folders share a base name, the report's run list and the model's sources give full paths,
    so that the two can be told apart."""
    runs = [runfmt.load_run(p) for p in run_dirs]
    runfmt.check_compatible(runs)
    names_seen = [r.name for r in runs]
    if len(set(names_seen)) != len(names_seen):
        for r in runs:
            r.path = os.path.abspath(r.path)
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


def _prepare(runs: Sequence[runfmt.Run], log: Callable[[str], None]) -> list[PreparedRun]:
    """Input timing and preparation (``replay.prepare_timed``): when each recorded duty and
    torque command took effect on the board, the replay grid, and the replay windows.  A long
    run is cut into windows re-anchored to the recording, so that the open-loop replay's
    errors do not integrate over the whole run."""
    preps = [prepare_timed(r) for r in runs]
    n_win = sum(len(p.windows) for p in preps)
    if n_win > len(preps):
        log(f"long run(s): replayed in {n_win} windows re-anchored to the recording")
    return preps


@dataclass
class NominalClosedLoop:
    """The nominal closed-loop replay, per run."""
    replay: ClosedLoopReplay
    setups: list[dict[str, Any] | None]  # the replay's set-up (reference, clamp, schedule)
    runs: list[dict[str, Any]]  # the report's entry: replayed, problems, assumptions, reference
    nominal: list[dict[str, Channel]]  # channel -> Channel of the nominal replay, or {}


def _replay_closed_loop(preps: Sequence[PreparedRun], dt_s: float, notes: list[str],
                        log: Callable[[str], None]
                        ) -> tuple[list[PreparedRun], NominalClosedLoop]:
    """Replay each run closed loop through lib/control: the torque and duty the firmware should
    have commanded.  Runs first because it also refines the inputs of the open-loop replays:
    the inner ticks that no telemetry frame reported get their commands from the line between
    the reported ones plus this replay's pattern (``fill_unseen_from_controller``).  Returns
    (the prepared runs with those refined inputs, which every later stage replays; the nominal
    closed-loop replay).  A run that cannot be replayed (no lib/control binding, or a set-up the
    meta data does not give) is reported with its problems; the analysis goes on without it,
    since the closed-loop channels are reported and not used for decisions."""
    clr = ClosedLoopReplay(dt_s=dt_s)
    ok, why = clr.available()
    setups: list[dict[str, Any] | None] = [None] * len(preps)
    runs: list[dict[str, Any]] = []
    nominal: list[dict[str, Channel]] = [{} for _ in preps]
    filled = list(preps)
    for i, p in enumerate(preps):
        if not ok:
            runs.append({"run": p.name, "replayed": False, "problems": [why],
                         "assumptions": []})
            continue
        setup, problems, assumptions = clr.setup(p)
        setups[i] = setup
        runs.append({"run": p.name, "replayed": setup is not None, "problems": problems,
                     "assumptions": assumptions, "reference": setup})
        if setup is not None:
            cl_sim = clr.simulate(p, {}, setup)
            nominal[i] = closed_loop_channels(p, cl_sim)
            filled[i], n_fill = fill_unseen_from_controller(p, cl_sim)
            if n_fill:
                runs[-1]["assumptions"].append(
                    f"{n_fill} inner ticks were reported by no frame: their commands are the "
                    "line between the reported ones plus the closed-loop replay's pattern")
        else:
            notes.append(f"closed-loop replay of {p.name} not run: " + "; ".join(problems))
    n_cl = sum(1 for c in nominal if c)
    if n_cl:
        log(f"closed-loop replay through lib/control: {n_cl}/{len(preps)} run(s)")
    return filled, NominalClosedLoop(clr, setups, runs, nominal)


def _replay_nominal(preps: Sequence[PreparedRun], duty: OpenLoopReplay, torque: OpenLoopReplay
                    ) -> tuple[list[PreparedRun], list[dict[str, Channel]],
                               list[dict[str, Channel]]]:
    """The nominal open-loop replays (no effect), per run: channel -> Channel, driven by the
    recorded duty (what locates the mismatch and decides) and by the recorded torque command
    (reported apart: it separates motor and driver from the rest).  On a run of several
    windows the duty replay's slip episodes are noted first and the window edges moved out
    of them, with a cut after each (``edges_outside_slip``): a window cannot start from the
    recorded state inside a slip, the window anchors to the camera are fitted within the
    slip-free spans, and ``locate`` takes the slips as no evidence.  The replay's own
    uncertainty (unreported commands, the model's tolerance) is drawn before the channels are
    compared, and the prepared runs returned carry it (``replay_unc``, ``tolerance_bias``,
    ``tolerance_draw_means``) for every later replay and decision.  Returns (those prepared
    runs, the duty replay's channels, the torque replay's)."""
    out = []
    for p in preps:
        if len(p.windows) > 1:
            p, _ = edges_outside_slip(p, duty)
        unc = input_uncertainty(p, duty)
        if unc is not None:
            p = dataclasses.replace(p, replay_unc=unc)
        tol = tolerance_uncertainty(p, duty)
        if tol is not None:
            p = dataclasses.replace(p, replay_unc=tol.replay_unc, tolerance_bias=tol.tolerance_bias,
                                    tolerance_draw_means=tol.tolerance_draw_means)
        out.append(p)
    nominal = [channels(p, duty.simulate_windows(p, {}), "duty") for p in out]
    nominal_t = [channels(p, torque.simulate_windows(p, {}), "torque") for p in out]
    return out, nominal, nominal_t


def _command_delay(preps: Sequence[PreparedRun], selected: list[dict[str, Any]], verdict: str,
                   effects: Mapping[str, Mapping[str, float]], notes: list[str],
                   log: Callable[[str], None]) -> tuple[str, dict[str, Mapping[str, float]]]:
    """The command-to-duty delay (``prepare.command_lag``): where the recorded duty (the duty
    in force) lags the torque command significantly, ``actuation_delay`` is selected with the
    lag as ``delay_s`` (and its standard error), the updated model gets it, and a note says so.
    The duty replay, driven by that duty in force, cannot see such a delay, so it is neither
    fitted there nor added to the replays' effects; a run without the delay's signature leaves
    the verdict as the replays decided it.  Returns (verdict, the updated model's effects)."""
    lag = command_lag(preps)
    if lag is None or not lag["significant"] or "actuation_delay" in effects:
        return verdict, dict(effects)
    d, sd = lag["delay_s"], lag["std_s"]
    log(f"command-to-duty lag: {1e3 * d:.1f} +- {1e3 * sd:.1f} ms (F = {lag['F']:.3g})")
    notes.append(f"the recorded duty lags the torque command by {1e3 * d:.1f} +- {1e3 * sd:.1f} ms "
                 f"(F = {lag['F']:.3g} against no lag, {lag['n_eff']:.0f} effective samples): "
                 "actuation_delay selected from the command-to-duty lag, which the duty replay "
                 "(driven by the duty in force) cannot see")
    selected.append({"effect": "actuation_delay", "params": {"delay_s": round(d, 4)},
                     "std": {"delay_s": round(sd, 4)}, "unidentified": [], "equivalent": [],
                     "separating_measurement": {}, "from": "command_lag"})
    return ("explained" if verdict == "no_mismatch" else verdict,
            {**effects, "actuation_delay": {"delay_s": d}})


def _replay_updated(preps: Sequence[PreparedRun], duty: OpenLoopReplay, cl: NominalClosedLoop,
                    final_effects: Mapping[str, Mapping[str, float]]
                    ) -> tuple[list[dict[str, Channel]] | None, list[dict[str, Channel]]]:
    """The replays with the selected effects: the duty replay (None without an update) and the
    closed loop (a run without an update, or not replayed, keeps its nominal channels)."""
    updated = None
    if final_effects:
        updated = [channels(p, duty.simulate_windows(p, final_effects), "duty") for p in preps]
    cl_updated = [closed_loop_channels(p, cl.replay.simulate(p, final_effects, cl.setups[i]))
                  if (final_effects and cl.setups[i] is not None) else cl.nominal[i]
                  for i, p in enumerate(preps)]
    return updated, cl_updated
