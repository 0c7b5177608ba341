"""The analysis pipeline (:func:`analyze`): load runs, replay them nominally (closed loop
through lib/control, open loop driven by the recorded duty and torque), locate the mismatch in
noise floors, fit every vocabulary effect (in parallel) and pairs of them, select, decide the
verdict, and assemble the :class:`Analysis` that ``report.py`` writes.  Each stage is a
function of its own, in the order :func:`analyze` calls them."""
from __future__ import annotations

import itertools
import math
import multiprocessing as mp
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from host_tools import runfmt
from host_tools.analyzer import effects as fx
from host_tools.analyzer import signals as sg
from host_tools.analyzer.fit import (HELDOUT_RULE, Candidate, Problem, evaluate_candidate,
                                    heldout_channel_check, judge, params_for)
from host_tools.analyzer.prepare.inputs import prepare_timed
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.anchors import note_slip_episodes
from host_tools.analyzer.replay.channels import (CHANNELS, CUMULATIVE, DERIVED, FIT_CHANNELS,
                                                 channels, state_table)
from host_tools.analyzer.replay.closedloop import (CLOSED_LOOP_CHANNELS, ClosedLoopReplay,
                                                   closed_loop_channels)
from host_tools.analyzer.replay.openloop import OpenLoopReplay
from host_tools.analyzer.replay.unseen import fill_unseen_from_controller, input_uncertainty

REPORT_FORMAT = "mismatch-report/1"

# Decision thresholds (normalized residual = residual / noise floor over the fit channels).
STRONG_WINDOW = 3.0      # a window whose RMS is this many floors is a mismatch on its own
# ... on a recording of STRONG_REF_S in all (four 3 s runs).  A longer recording offers more
# windows, and the largest of N noise-like excursions grows like sqrt(2 ln N): the threshold is
# raised by that law, so that the chance of a false alarm per analysis stays what it is on
# STRONG_REF_S (12 s: 3.0 floors; 120 s: 3.7; 600 s: 4.1).
STRONG_REF_S = 12.0


def strong_threshold(total_s: float) -> float:
    return math.sqrt(STRONG_WINDOW ** 2 + 2 * math.log(max(1.0, total_s / STRONG_REF_S)))


MISMATCH_RMS = 1.25      # otherwise the overall normalized RMS must exceed this
# After the update: explained when the residual is back within the noise floor (normalized RMS
# <= 1).  Detection keeps a margin above the floor against false alarms; a claim of explanation
# asks for the residual to be at noise level.  Settled on the concealed-effect suite (both seed
# sets, with the inner-loop timing from the board's wheel speeds): nulls leave 0.77-0.89 with
# the nominal model, correct explanations 0.77-0.89, a weak battery sag (outside the
# vocabulary) 1.15 with a voltage drop and a 6 ms delay; the detection threshold (1.25) would
# call that sag explained.
EXPLAINED_RMS = 1.0
MODEL_FORMAT = "ddmodel/1"


def _current_lsb_a() -> float:
    """One ADC count of the motor-current telemetry (protocol.json's scale of current_r)."""
    from host_tools import protocol
    for m in protocol.definition().by_name.values():
        for f in m.fields:
            if f.name == "current_r" and f.scale:
                return float(f.scale)
    return 0.0


def _log(msg: str) -> None:
    print(f"[analyze {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------- noise floors


def noise_floors(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, object]]
                 ) -> dict[str, float]:
    """Per-channel noise floor, pooled over runs, estimated from the data:
    encoder quantization for wheel speeds and counts, the high-frequency part of the
    residual for everything (ground-truth camera noise shows up there), and for cumulative
    channels (counts, odometry) a 1 % tolerance of their range, since tiny speed differences
    integrate."""
    meta = preps[0].run.meta
    ppr = int(meta["encoder_ppr"])
    r = float(meta["robot"]["r"])
    b = float(meta["robot"]["b"])
    k = 2 * math.pi / ppr
    dts = np.concatenate([np.diff(p.run.telemetry["t_s"]) for p in preps])
    dt = float(np.median(dts))
    floors: dict[str, float] = {}
    names = set().union(*[set(c) for c in nominal])
    for c in names:
        res = [ch[c].resid for ch in nominal if c in ch]
        hf = float(np.sqrt(np.mean([sg.hf_noise_std(x) ** 2 for x in res])))
        if c.startswith("omega"):
            base = sg.quantization_std(k / dt)
        elif c.startswith("enc"):
            base = sg.quantization_std(1.0)
        elif c.startswith("current"):
            base = max(sg.quantization_std(_current_lsb_a()), 1e-6)
        elif c in ("x_odo_m", "y_odo_m"):
            base = r * k
        elif c == "phi_odo_rad":
            base = r * k / (2 * b)
        elif c in ("x_m", "y_m"):
            base = 2e-4
        elif c == "phi_rad":
            base = 2e-3
        else:
            base = 1e-6
        f = max(base, hf)
        if c in CUMULATIVE:
            # within a replay window (a long run is compared window by window)
            span = max(max(ch[c].spans()) for ch in nominal if c in ch)
            f = max(f, 0.01 * span)
        floors[c] = f
    return floors


def closed_loop_floors(chans_per_run: Sequence[Mapping[str, object]]) -> dict[str, float]:
    """Noise floor of the closed-loop channels (recorded minus replayed controller output),
    from the data: the white part of the nominal residual (MAD of second differences), which
    holds the torque jumps that single encoder-count differences between the real wheel and the
    plant cause through the speed loop; at least the telemetry's resolution (0.1 mN m for the
    torque command, 2^-15 for the duty) as a uniform quantization std."""
    base = {"tau_cmd_r": 1e-4 / math.sqrt(12), "tau_cmd_l": 1e-4 / math.sqrt(12),
            "pwm_r": 2.0 ** -15 / math.sqrt(12), "pwm_l": 2.0 ** -15 / math.sqrt(12)}
    floors = {}
    for c in CLOSED_LOOP_CHANNELS:
        res = [ch[c].resid for ch in chans_per_run if ch and c in ch]
        if not res:
            continue
        hf = float(np.sqrt(np.mean([sg.hf_noise_std(x) ** 2 for x in res])))
        floors[c] = max(base[c], hf)
    return floors


def _pooled_rmse(chans_per_run, names) -> dict[str, float]:
    out = {}
    for c in names:
        r = [ch[c].resid for ch in chans_per_run if ch and c in ch]
        if r and sum(x.size for x in r):
            out[c] = float(np.sqrt(np.mean(np.concatenate(r) ** 2)))
    return out


# ------------------------------------------------------------------------ worker


_PROBLEM: Problem | None = None
_MAIN_PID = os.getpid()


def _init_worker(problem: Problem) -> None:
    global _PROBLEM
    _PROBLEM = problem
    if os.getpid() != _MAIN_PID:
        # A worker ends at once on the pool's SIGTERM, whatever C code it is in: a Python-level
        # handler inherited from the command line (which turns signals into a clean exit of the
        # main process) runs only between bytecodes, and a worker that never gets there would
        # keep Pool.terminate() waiting for ever.  Ctrl-C is the main process's to handle.
        import signal
        for name in ("SIGTERM", "SIGHUP"):
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _eval_task(args):
    names, x0, ref_effects = args
    t0 = time.time()
    cand = evaluate_candidate(_PROBLEM, names, x0=x0, ref_effects=ref_effects)
    return cand, time.time() - t0


def _run_tasks(problem: Problem, tasks: list, jobs: int, label: str) -> list[Candidate]:
    out: list[Candidate] = []
    if jobs <= 1 or len(tasks) <= 1:
        _init_worker(problem)
        for i, task in enumerate(tasks, 1):
            cand, dt = _eval_task(task)
            out.append(cand)
            _log(f"{label} {i}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s")
        return out
    ctx = mp.get_context("fork")
    with ctx.Pool(jobs, initializer=_init_worker, initargs=(problem,)) as pool:
        for i, (cand, dt) in enumerate(pool.imap_unordered(_eval_task, tasks), 1):
            out.append(cand)
            _log(f"{label} {i}/{len(tasks)}: {cand.name} fitted in {dt:.1f} s")
    order = {tuple(t[0]): i for i, t in enumerate(tasks)}
    out.sort(key=lambda c: order[tuple(c.effects)])
    return out


# ----------------------------------------------------------------------- result


@dataclass
class Analysis:
    runs: list[runfmt.Run]
    preps: list[PreparedRun]
    floors: dict[str, float]
    nominal: list[dict]                 # per run: channel -> Channel (duty replay)
    nominal_torque: list[dict]          # per run: channel -> Channel (torque replay)
    updated: list[dict] | None
    mismatch: list[dict]
    candidates: list[Candidate]
    selected: list[dict]
    verdict: str
    fit_table: dict
    hint: dict | None
    model: dict
    notes: list[str] = field(default_factory=list)
    torque_mismatch: list[dict] = field(default_factory=list)
    windows: dict = field(default_factory=dict)   # (run idx, channel) -> [Window]
    timing_s: float = 0.0
    closed_loop: dict = field(default_factory=dict)      # report section (see docs/analyzer.md)
    cl_nominal: list = field(default_factory=list)       # per run: channel -> Channel, or {}
    cl_updated: list = field(default_factory=list)
    recorder: dict = field(default_factory=dict)         # findings about the recorder
    localization: list = field(default_factory=list)     # where in time the mismatch is


def _window_entries(preps, chans_per_run, floors, channel_names, replay_name,
                    regime_cands_per_run, tau_max) -> tuple[list[dict], dict, float]:
    """Significant windows of every channel, with the regime that best explains them.
    Returns the report entries, {(run, channel): windows} and the significant fraction."""
    entries: list[dict] = []
    wins: dict = {}
    for c in channel_names:
        masks, preds_runs, per_run = [], [], []
        for i, (prep, chans) in enumerate(zip(preps, chans_per_run)):
            ch = chans.get(c)
            if ch is None:
                continue
            w, m = sg.significant_windows(ch.t, ch.deflated(floors[c]), floors[c])
            wins[(i, c)] = w
            per_run.append((i, ch, w))
            masks.append(m)
            st = regime_cands_per_run[i]
            preds_runs.append({k: np.interp(ch.t, st["t"], v) for k, v in st.items()})
        if not masks or not any(m.any() for m in masks):
            continue
        pooled = {k: np.concatenate([p[k] for p in preds_runs]) for k in preds_runs[0]}
        regime = sg.best_regime(np.concatenate(masks), sg.regime_candidates(pooled, tau_max))
        for i, ch, w in per_run:
            for win in w:
                entries.append({"run": preps[i].name, "channel": c,
                                "t_start_s": round(win.t_start_s, 4),
                                "t_end_s": round(win.t_end_s, 4), "rms": _r(win.rms),
                                "noise_floor": _r(floors[c]),
                                "regime": regime.description if regime else "unknown",
                                "regime_f1": round(regime.score, 3) if regime else 0.0,
                                "replay": replay_name})
    return entries, wins, 0.0


def _r(v: float, sig: int = 4) -> float:
    if v == 0 or not math.isfinite(v):
        return float(v) if math.isfinite(v) else None  # type: ignore[return-value]
    return float(f"{v:.{sig}g}")


def _excess(problem: Problem, effects: Mapping) -> float:
    r = problem.residual(effects, list(range(len(problem.preps))), full=True)
    return float(np.mean(r ** 2)) if r.size else 0.0


def sparse_hint(preps, chans_per_run) -> dict | None:
    """Sparse regression of the wheel-acceleration residual on named state features."""
    X, y = [], []
    names = ["1", "sign(w)", "w", "w*|w|", "dw/dt", "tau_cmd", "duty", "yaw_rate*side",
             "duty*w", "t"]
    for prep, chans in zip(preps, chans_per_run):
        st = state_table(prep)
        for side, sgn in (("r", 1.0), ("l", -1.0)):
            ch = chans.get(f"omega_{side}")
            if ch is None or ch.t.size < 5:
                continue
            res = sg.smooth(ch.resid, 3)
            acc = np.gradient(res, ch.t)
            w = np.interp(ch.t, st["t"], st[f"w_{side}"])
            a = np.interp(ch.t, st["t"], st[f"a_{side}"])
            tau = np.interp(ch.t, st["t"], st[f"tau_{side}"])
            u = np.interp(ch.t, st["t"], st[f"u_{side}"])
            yaw = np.interp(ch.t, st["t"], st["yaw"])
            X.append(np.column_stack([np.ones_like(w), np.sign(w) * (np.abs(w) > 0.5), w,
                                      w * np.abs(w), a, tau, u, yaw * sgn, u * w, ch.t]))
            y.append(acc)
    if not X:
        return None
    X = np.vstack(X)
    y = np.concatenate(y)
    terms = sg.stlsq(X, y, names, threshold=0.15, max_terms=3)
    if not terms:
        return {"target": "d/dt of the wheel-speed residual (rad/s^2)", "terms": {},
                "r2": 0.0, "text": "no sparse combination of the state features fits"}
    idx = [names.index(n) for n in terms]
    yhat = X[:, idx] @ np.array([terms[n] for n in terms])
    r2 = sg.r_squared(y, yhat)
    text = " + ".join(f"{v:.4g}*{n}" if n != "1" else f"{v:.4g}" for n, v in terms.items())
    return {"target": "d/dt of the wheel-speed residual (rad/s^2), per wheel",
            "terms": {n: _r(v) for n, v in terms.items()}, "r2": round(r2, 3),
            "text": f"residual wheel acceleration ~ {text}"}


def analyze(run_dirs: Sequence[str], jobs: int = 2, effects: Sequence[str] | None = None,
            dt_s: float = 5e-4, pairs_top: int = 5,
            log: Callable[[str], None] = _log) -> Analysis:
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
    cl = _replay_closed_loop(preps, dt_s, notes, log)
    nominal, nominal_t = _replay_nominal(preps, duty, torque)
    loc = _locate(preps, nominal, nominal_t, cl.nominal, log)
    det = _detect(preps, nominal, loc, vocab, dt_s, notes, log)
    cands = _fit_candidates(det, vocab_fit, jobs, notes, log)
    sel = _select(det, cands, jobs, pairs_top, log)
    selected = _selected_entries(sel, det.rss0)
    verdict, hint = _verdict(det, sel.effects, selected, preps, duty, notes)
    updated, cl_updated = _replay_updated(preps, duty, cl, sel.effects)
    closed_loop = _closed_loop_report(cl, cl_updated, loc, sel.effects)
    fit_table = _error_tables(det, sel, loc.floors, closed_loop)
    recorder = recorder_findings(preps, nominal, loc.floors, notes)
    localization = localize(preps, nominal, updated, loc.floors, det.problem.fit_channels,
                            det.strong_k)
    model = updated_model(runs[0].meta, sel.effects, [r.path for r in runs])
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


# ------------------------------------------------------------------------ stages


def _load_runs(run_dirs: Sequence[str], log: Callable[[str], None]) -> list[runfmt.Run]:
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


def _vocabulary(effects: Sequence[str] | None) -> tuple[dict, dict]:
    """(the whole effect vocabulary of lib/slipmodel, the effects to fit as candidates).  The
    fit problem knows the whole vocabulary; ``effects`` (the command line's ``--effects``) only
    narrows which candidates are fitted, and an unknown name is an input error, not an empty
    fit."""
    from host_tools import _native
    vocab = _native.effect_vocabulary()
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
class _ClosedLoop:
    """The nominal closed-loop replay, per run."""
    replay: ClosedLoopReplay
    setups: list            # the replay's set-up (reference, clamp, schedule), or None
    runs: list[dict]        # the report's entry: replayed, problems, assumptions, reference
    nominal: list[dict]     # channel -> Channel of the nominal replay, or {} when not replayed


def _replay_closed_loop(preps: Sequence[PreparedRun], dt_s: float, notes: list[str],
                        log: Callable[[str], None]) -> _ClosedLoop:
    """Replay each run closed loop through lib/control: the torque and duty the firmware should
    have commanded.  Runs first because it also refines the inputs of the open-loop replays:
    the inner ticks that no telemetry frame reported get their commands from the line between
    the reported ones plus this replay's pattern (``fill_unseen_from_controller``, which
    changes ``preps``).  A run that cannot be replayed (no lib/control binding, or a set-up the
    meta data does not give) is reported with its problems; the analysis goes on without it,
    since the closed-loop channels are reported and not used for decisions."""
    clr = ClosedLoopReplay(dt_s=dt_s)
    ok, why = clr.available()
    setups: list = [None] * len(preps)
    runs: list[dict] = []
    nominal: list[dict] = [{} for _ in preps]
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
            n_fill = fill_unseen_from_controller(p, cl_sim)
            if n_fill:
                runs[-1]["assumptions"].append(
                    f"{n_fill} inner ticks were reported by no frame: their commands are the "
                    "line between the reported ones plus the closed-loop replay's pattern")
        else:
            notes.append(f"closed-loop replay of {p.name} not run: " + "; ".join(problems))
    n_cl = sum(1 for c in nominal if c)
    if n_cl:
        log(f"closed-loop replay through lib/control: {n_cl}/{len(preps)} run(s)")
    return _ClosedLoop(clr, setups, runs, nominal)


def _replay_nominal(preps: Sequence[PreparedRun], duty: OpenLoopReplay, torque: OpenLoopReplay
                    ) -> tuple[list[dict], list[dict]]:
    """The nominal open-loop replays (no effect), per run: channel -> Channel, driven by the
    recorded duty (what locates the mismatch and decides) and by the recorded torque command
    (reported apart: it separates motor and driver from the rest).  On a run of several
    windows the duty replay's slip episodes are noted first (``note_slip_episodes``): the
    window anchors to the camera are fitted within the slip-free spans."""
    for p in preps:
        if len(p.windows) > 1:
            note_slip_episodes(p, duty.simulate_windows(p, {}))
        input_uncertainty(p, duty)
    nominal = [channels(p, duty.simulate_windows(p, {}), "duty") for p in preps]
    nominal_t = [channels(p, torque.simulate_windows(p, {}), "torque") for p in preps]
    return nominal, nominal_t


@dataclass
class _Located:
    """Noise floors and significant windows of the nominal replays."""
    floors: dict            # duty replay's channels
    floors_t: dict          # torque replay's channels
    cl_floors: dict         # closed-loop channels
    entries: list[dict]     # the report's mismatch entries (duty replay)
    entries_t: list[dict]   # ... of the torque replay
    cl_entries: list[dict]  # ... of the closed-loop replay
    windows: dict           # (run index, channel) -> [Window], duty replay
    cl_windows: dict        # ... closed-loop replay


def _locate(preps: Sequence[PreparedRun], nominal: Sequence[dict], nominal_t: Sequence[dict],
            cl_nominal: Sequence[dict], log: Callable[[str], None]) -> _Located:
    """Noise floors from the data (``noise_floors``, ``closed_loop_floors``) and the windows
    where each replay's residual stands out of them, each with the regime of the run's state
    (speed, torque against its limit, ...) that best explains where they are.  A residual only
    means something in units of its channel's noise, so every later decision is in noise
    floors."""
    floors = noise_floors(preps, nominal)
    floors_t = noise_floors(preps, nominal_t)
    log("noise floors: " + ", ".join(f"{c}={v:.3g}" for c, v in sorted(floors.items())))
    from host_tools import _native
    plant = _native.Plant.from_meta(preps[0].run.meta)
    tau_max = float(min(plant.tau_max()))
    states = [state_table(p) for p in preps]
    chan_names = [c for c in CHANNELS if any(c in ch for ch in nominal)]
    entries, wins, _ = _window_entries(preps, nominal, floors, chan_names, "duty", states,
                                       tau_max)
    entries_t, _, _ = _window_entries(preps, nominal_t, floors_t, chan_names, "torque",
                                      states, tau_max)
    cl_floors = closed_loop_floors(cl_nominal)
    cl_entries: list[dict] = []
    cl_wins: dict = {}
    if any(cl_nominal):
        cl_entries, cl_wins, _ = _window_entries(preps, cl_nominal, cl_floors,
                                                 [c for c in CLOSED_LOOP_CHANNELS
                                                  if c in cl_floors], "closed-loop", states,
                                                 tau_max)
    return _Located(floors, floors_t, cl_floors, entries, entries_t, cl_entries, wins, cl_wins)


@dataclass
class _Detection:
    """The fit problem and whether the recordings disagree with the nominal model."""
    problem: Problem
    rss0: float             # nominal residual sum of squares (fit channels, in noise floors)
    nrms0: float            # ... as a normalized RMS
    strong_k: float         # noise floors that make one window a mismatch on its own
    mismatch_seen: bool


def _detect(preps: Sequence[PreparedRun], nominal: Sequence[dict], loc: _Located, vocab: dict,
            dt_s: float, notes: list[str], log: Callable[[str], None]) -> _Detection:
    """Build the fit problem (the fit channels, and on long runs the windows the fits see) and
    decide whether there is a mismatch at all: a strong window in a fit channel (``strong_k``
    floors, raised with the recording's length so the false-alarm rate per analysis stays
    what it is on 12 s), or significant windows with an overall normalized RMS above
    ``MISMATCH_RMS``.  The torque replay does not decide; it adds a note on where the mismatch
    sits (between duty and torque, or not)."""
    floors = loc.floors
    fit_chans = [c for c in FIT_CHANNELS if c in floors]
    sig_fit = [e for e in loc.entries if e["channel"] in fit_chans]
    problem = Problem(preps, floors, vocab, dt_s=dt_s, fit_channels=fit_chans)
    fitw = problem.select_windows(nominal)
    if fitw is not None:
        log("fitting on " + ", ".join(f"{preps[i].name}: {len(w)}/{len(preps[i].windows)}"
                                      for i, w in fitw.items()) + " windows")
    r0 = problem.residual({}, list(range(len(preps))), full=True)
    rss0 = float(np.sum(r0 ** 2))
    nrms0 = math.sqrt(rss0 / max(r0.size, 1))
    total_s = sum(float(p.run.telemetry["t_s"][-1] - p.run.telemetry["t_s"][0]) for p in preps)
    strong_k = strong_threshold(total_s)
    strong0 = [e for e in sig_fit if e["rms"] >= strong_k * e["noise_floor"]]
    mismatch_seen = bool(strong0) or (bool(sig_fit) and nrms0 > MISMATCH_RMS)
    sig_t = [e for e in loc.entries_t if e["channel"] in fit_chans]
    if mismatch_seen and not sig_t:
        notes.append("the torque-driven replay agrees with the recording while the duty-driven "
                     "one does not: the mismatch sits between duty and torque (motor, driver)")
    elif sig_t:
        notes.append("the torque-driven replay also disagrees with the recording; it is open "
                     "loop without back-EMF damping, so its errors integrate and it is reported "
                     "separately (torque_replay_mismatch), not used to locate or decide")
    log(f"nominal replay: {len(loc.entries)} significant window(s) "
        f"({len(sig_fit)} in fit channels {', '.join(fit_chans)})")
    return _Detection(problem, rss0, nrms0, strong_k, mismatch_seen)


def _fit_candidates(det: _Detection, vocab_fit: Mapping, jobs: int, notes: list[str],
                    log: Callable[[str], None]) -> list[Candidate]:
    """Fit every effect of ``vocab_fit`` alone and judge it (``fit.judge``: BIC, held-out
    error, size, physical possibility, per-channel veto); sorted by BIC gain.  Without a
    mismatch nothing is fitted: the verdict does not depend on the candidates."""
    tasks = [([e], None, {}) for e in vocab_fit] if det.mismatch_seen else []
    if tasks:
        log(f"fitting {len(tasks)} candidate effect(s) on {jobs} process(es)")
    else:
        notes.append("no mismatch beyond the noise floors: no candidate effect was fitted")
    cands = _run_tasks(det.problem, tasks, jobs, "candidate") if tasks else []
    for c in cands:
        judge(det.problem, c)
    cands.sort(key=lambda c: c.delta_bic)
    return cands


@dataclass
class _Selection:
    """What the fits select."""
    chosen: Candidate | None        # the accepted single or pair, or None
    effects: dict                   # its fitted effects: name -> params ({} when none)
    singles: list[Candidate]        # the single effects fitted (judged, by BIC gain)
    pairs: list[Candidate]          # the pairs fitted (judged, by BIC gain), or []


def _select(det: _Detection, cands: list[Candidate], jobs: int, pairs_top: int,
            log: Callable[[str], None]) -> _Selection:
    """The best accepted single effect; then, when no single is accepted or one leaves a
    strong window or a normalized RMS above ``EXPLAINED_RMS``, pairs of effects
    (``_fit_pairs``), and the best accepted pair replaces the single.  Nothing is selected
    without a mismatch."""
    if not det.mismatch_seen:
        return _Selection(None, {}, cands, [])
    problem = det.problem
    best_single = next((c for c in cands if c.accepted), None)
    chosen = best_single
    final_effects = dict(best_single.fit.params) if best_single is not None else {}
    pair_cands: list[Candidate] = []
    remaining = _remaining_windows(problem, final_effects, problem.fit_channels, det.strong_k)
    nrms1 = math.sqrt(_excess(problem, final_effects))
    if not final_effects or remaining or nrms1 > EXPLAINED_RMS:
        pair_cands = _fit_pairs(problem, cands, best_single, det.rss0, jobs, pairs_top, log)
        best_pair = next((c for c in pair_cands if c.accepted), None)
        if best_pair is not None:
            chosen = best_pair
            final_effects = dict(best_pair.fit.params)
    return _Selection(chosen, final_effects, cands, pair_cands)


def _fit_pairs(problem: Problem, cands: list[Candidate], best_single: Candidate | None,
               rss0: float, jobs: int, pairs_top: int, log: Callable[[str], None]
               ) -> list[Candidate]:
    """Fit and judge pairs of effects, started from their singles' fits; sorted by BIC gain.
    The pairs: those of the best singles by BIC (``pairs_top``), accepted or not, since in a
    pair case each single may fail (the other effect spoils its held-out error) while the pair
    passes; and forward steps, every other effect added to the best accepted single and to the
    best-fitting single.  The best fit may fail the acceptance tests only because its partner
    is missing (e.g. it makes one channel worse that the partner puts right), and its partner
    may explain little on its own.  A pair is accepted only if it is also clearly better than
    each of its singles (check ``adds``)."""
    ranked = [c.effects[0] for c in cands if c.fit.rss < rss0][:pairs_top]
    if best_single is not None and best_single.effects[0] not in ranked:
        ranked = [best_single.effects[0]] + ranked[:pairs_top - 1]
    combos = list(itertools.combinations(ranked[:pairs_top - 1], 2))
    leads = []
    if best_single is not None:
        leads.append(best_single.effects[0])
    if ranked and ranked[0] not in leads:
        leads.append(ranked[0])
    for lead in leads:
        for c in cands:
            e = c.effects[0]
            if e != lead and (lead, e) not in combos and (e, lead) not in combos:
                combos.append((lead, e))
    single = {c.effects[0]: c for c in cands}
    pair_tasks = [([a, b], np.concatenate([single[a].fit.x, single[b].fit.x]), {})
                  for a, b in combos]
    if not pair_tasks:
        return []
    log(f"one effect leaves a mismatch: fitting {len(pair_tasks)} pair(s)")
    pair_cands = _run_tasks(problem, pair_tasks, jobs, "pair")
    for pc in pair_cands:
        judge(problem, pc)
        for e in pc.effects:
            alone = single[e]
            better = (pc.fit.rss < alone.fit.rss and
                      _pair_bic(pc, alone, problem) < -10.0 and
                      pc.heldout_after < 0.95 * alone.heldout_after)
            if not better:
                pc.checks["adds"] = False
                pc.reasons.append(f"not clearly better than {e} alone")
        if "adds" not in pc.checks:
            pc.checks["adds"] = True
    pair_cands.sort(key=lambda c: c.delta_bic)
    return pair_cands


def _selected_entries(sel: _Selection, rss0: float) -> list[dict]:
    """The report's entries of the selected effects, each with its equivalents: alternatives
    that explain about as much (BIC within 10, held-out error close) and would themselves be
    worth adopting (BIC, held-out gain, size, physically possible; not the per-channel veto,
    which is what picked one of them), and the measurement that would separate them.  For a
    single: other singles.  For a pair (a, b): pairs (a, c) standing in for b."""
    sel_c = sel.chosen
    if sel_c is None:
        return []
    pool = sel.singles if len(sel_c.effects) == 1 else sel.pairs

    def _close(c: Candidate, me: Candidate) -> bool:
        worth = all(c.checks.get(k, True) for k in ("bic", "heldout", "size", "physical",
                                                    "adds"))
        return ((c.delta_bic - me.delta_bic) < 10.0 and c.fit.rss < rss0 and worth and
                c.heldout_after <= max(1.25 * me.heldout_after, me.heldout_after + 0.1))

    selected = []
    for e in sel_c.effects:
        equiv = []
        others = [x for x in sel_c.effects if x != e]
        for c in pool:
            if c is sel_c or e in c.effects or not set(others) <= set(c.effects):
                continue
            alt = [x for x in c.effects if x not in others]
            if len(alt) == 1 and _close(c, sel_c) and alt[0] not in equiv:
                equiv.append(alt[0])
        selected.append({"effect": e, "params": {k: _r(v, 5) for k, v in
                                                sel_c.fit.params[e].items()},
                         "unidentified": [u.split(".", 1)[1] for u in sel_c.fit.unidentified
                                          if u.startswith(e + ".")],
                         "equivalent": equiv,
                         "separating_measurement": {q: fx.separator(e, q) for q in equiv}})
    return selected


def _verdict(det: _Detection, final_effects: Mapping, selected: Sequence[dict],
             preps: Sequence[PreparedRun], duty: OpenLoopReplay, notes: list[str]
             ) -> tuple[str, dict | None]:
    """(verdict, hint).  ``no_mismatch`` when detection saw none; ``explained`` when effects
    were selected and their residual is back within the noise floor (normalized RMS at most
    ``EXPLAINED_RMS``: a claim of explanation asks for noise level, not merely below the
    detection threshold); otherwise ``unexplained``, with a sparse regression of what remains
    (``sparse_hint``) as a hint towards the missing physics."""
    if not det.mismatch_seen:
        return "no_mismatch", None
    nrms1 = math.sqrt(_excess(det.problem, final_effects))
    if selected and nrms1 <= EXPLAINED_RMS:
        return "explained", None
    chans_after = [channels(p, duty.simulate_windows(p, final_effects), "duty") for p in preps]
    hint = sparse_hint(preps, chans_after)
    if selected:
        notes.append("the selected effects explain part of the mismatch only "
                     f"(normalized RMS residual {det.nrms0:.3g} -> {nrms1:.3g}, noise = 1)")
    return "unexplained", hint


def _replay_updated(preps: Sequence[PreparedRun], duty: OpenLoopReplay, cl: _ClosedLoop,
                    final_effects: Mapping) -> tuple[list[dict] | None, list[dict]]:
    """The replays with the selected effects: the duty replay (None without an update) and the
    closed loop (a run without an update, or not replayed, keeps its nominal channels)."""
    updated = None
    if final_effects:
        updated = [channels(p, duty.simulate_windows(p, final_effects), "duty") for p in preps]
    cl_updated = [closed_loop_channels(p, cl.replay.simulate(p, final_effects, cl.setups[i]))
                  if (final_effects and cl.setups[i] is not None) else cl.nominal[i]
                  for i, p in enumerate(preps)]
    return updated, cl_updated


def _closed_loop_report(cl: _ClosedLoop, cl_updated: Sequence[dict], loc: _Located,
                        final_effects: Mapping) -> dict:
    """The report's closed-loop section (see docs/analyzer.md): per run whether it was replayed
    and on which assumptions, the controller-output errors before and after the update, in
    their units and in noise floors, and the closed loop's significant windows.  Reported, not
    used for decisions (``used_for_decisions``)."""
    cl_floors = loc.cl_floors
    cl_b = _pooled_rmse(cl.nominal, CLOSED_LOOP_CHANNELS)
    cl_a = _pooled_rmse(cl_updated, CLOSED_LOOP_CHANNELS)

    def _nrms(chs):
        r = [ch[c].resid / cl_floors[c] for ch in chs if ch for c in cl_floors if c in ch]
        return _r(float(np.sqrt(np.mean(np.concatenate(r) ** 2)))) if r else None

    return {
        "replay": "lib/control fixed-point cascade (ctl_* C ABI) against the lib/slipmodel "
                  "plant, firmware schedule, encoder counts quantised from the plant",
        "runs": cl.runs, "channels": list(cl_b),
        "noise_floor": {c: _r(v) for c, v in cl_floors.items()},
        "rmse_nominal": {c: _r(v) for c, v in cl_b.items()},
        "rmse_updated": {c: _r(v) for c, v in cl_a.items()},
        "normalized_rms_nominal": _nrms(cl.nominal),
        "normalized_rms_updated": _nrms(cl_updated),
        "updated_effects": {k: dict(v) for k, v in final_effects.items()},
        "mismatch": loc.cl_entries,
        "used_for_decisions": False}


def _error_tables(det: _Detection, sel: _Selection, floors: Mapping, closed_loop: Mapping
                  ) -> dict:
    """The report's error tables: RMSE per channel before and after the update on the fitting
    data and on the held-out parts (leave one run out, or a time split of a single run) with
    the held-out rule's per-channel check, the noise floors, and the normalized RMS before and
    after; the closed-loop channels' rows come from the closed-loop section.  Without an update
    the errors after are the errors before."""
    problem, final_effects = det.problem, sel.effects
    runs_idx = list(range(len(problem.preps)))
    rb = problem.channel_rmse({}, runs_idx, full=True)
    ra = problem.channel_rmse(final_effects, runs_idx, full=True) if final_effects else dict(rb)
    hpairs = None
    if sel.chosen is not None:
        hb, ha = sel.chosen.heldout_channels_before, sel.chosen.heldout_channels_after
        hpairs = sel.chosen.heldout_pairs
    else:
        # no update: held-out error equals the nominal one on the held-out parts
        c0 = sel.singles[0] if sel.singles else None
        hb = c0.heldout_channels_before if c0 else dict(rb)
        ha = dict(hb)
    fit_table = {"rmse_before": {k: _r(v) for k, v in rb.items()},
                 "rmse_after": {k: _r(v) for k, v in ra.items()},
                 "heldout_rmse_before": {k: _r(v) for k, v in hb.items()},
                 "heldout_rmse_after": {k: _r(v) for k, v in ha.items()},
                 "heldout_method": ("leave one run out" if len(runs_idx) > 1 else
                                    f"time split at {problem.split_frac:.0%} of the run"),
                 "noise_floor": {k: _r(v) for k, v in floors.items()},
                 "heldout_rule": HELDOUT_RULE,
                 "heldout_check": {k: {q: (_r(x) if isinstance(x, float) and q != "ok" else x)
                                       for q, x in v.items()}
                                   for k, v in heldout_channel_check(hb, ha, floors,
                                                                     hpairs).items()},
                 "derived_channels": list(DERIVED),
                 "normalized_rms_before": _r(det.nrms0),
                 "normalized_rms_after": _r(math.sqrt(_excess(problem, final_effects)))}
    for c in closed_loop["channels"]:
        fit_table["rmse_before"][c] = closed_loop["rmse_nominal"][c]
        fit_table["rmse_after"][c] = closed_loop["rmse_updated"][c]
        fit_table["noise_floor"][c] = closed_loop["noise_floor"][c]
    return fit_table


def recorder_findings(preps: Sequence[PreparedRun], nominal: Sequence[Mapping], floors: Mapping,
                      notes: list[str]) -> dict:
    """What the recording says about its recorder (not about the physics): how its odometry
    columns relate to its own counts (replay.recorder_odometry), and whether the derived
    odometry channels disagree with the replay while the counts agree."""
    runs = []
    for prep, chans in zip(preps, nominal):
        rec = dict(prep.extras.get("recorder_odometry") or {})
        entry = {"run": prep.name, "odometry_schedule": rec.get("schedule"),
                 "odometry_matches_lib_control": rec.get("agrees"),
                 "odometry_vs_lib_control": {k: {q: _r(v) for q, v in d.items()}
                                             for k, d in rec.get("by_schedule", {}).items()},
                 "input_timing": prep.extras.get("timing")}
        enc_ok = all(c in chans and floors.get(c) and
                     float(np.sqrt(np.mean(chans[c].resid ** 2))) <= floors[c]
                     for c in ("enc_r", "enc_l"))
        odo_bad = [c for c in DERIVED if c in chans and floors.get(c) and
                   float(np.sqrt(np.mean(chans[c].resid ** 2))) > floors[c]]
        entry["derived_disagree_while_counts_agree"] = bool(enc_ok and odo_bad)
        if rec and not rec.get("agrees"):
            best = rec["by_schedule"][rec["schedule"]]
            notes.append(f"{prep.name}: the recorder's odometry differs from lib/control's "
                         f"integration of its own counts by {best['rms_m'] * 1e3:.2g} mm / "
                         f"{best['rms_rad'] * 1e3:.2g} mrad RMS at its best-matching schedule "
                         f"({rec['schedule']}): it computes odometry differently (integration "
                         "rule, wheel geometry or schedule). A finding about the recorder; its "
                         "odometry columns are not used as evidence about the physics")
        elif enc_ok and odo_bad:
            notes.append(f"{prep.name}: odometry channels {', '.join(odo_bad)} disagree with "
                         "the replay while the encoder counts agree: the recorder computes "
                         "odometry differently from lib/control (a recorder finding)")
        runs.append(entry)
    return {"runs": runs, "derived_channels": list(DERIVED),
            "derived_used_for_decisions": False}


def localize(preps: Sequence[PreparedRun], nominal: Sequence[Mapping],
             updated: Sequence[Mapping] | None, floors: Mapping, fit_chans: Sequence[str],
             strong_k: float, merge_s: float = 0.5) -> list[dict]:
    """Where in time the recordings disagree with the nominal model: significant windows of the
    fit channels merged across channels (gaps under ``merge_s``), each with its peak in noise
    floors and whether it remains after the update (an effect that holds for part of a run,
    such as a patch of floor, shows as a span that the update does not remove)."""
    out = []
    for i, prep in enumerate(preps):
        spans = []
        for c in fit_chans:
            ch = nominal[i].get(c)
            if ch is None:
                continue
            w, _ = sg.significant_windows(ch.t, ch.deflated(floors[c]), floors[c])
            spans += [(x.t_start_s, x.t_end_s, x.rms / floors[c], c) for x in w]
        spans.sort()
        merged: list[list] = []
        for a, b, pk, c in spans:
            if merged and a <= merged[-1][1] + merge_s:
                m = merged[-1]
                m[1], m[2] = max(m[1], b), max(m[2], pk)
                m[3].add(c)
            else:
                merged.append([a, b, pk, {c}])
        for a, b, pk, cs in merged:
            after = None
            if updated is not None:
                after = 0.0
                for c in cs:
                    ch = updated[i].get(c)
                    if ch is None:
                        continue
                    m = (ch.t >= a) & (ch.t <= b)
                    if m.any():
                        after = max(after, float(np.sqrt(np.mean(ch.deflated(floors[c])[m] ** 2)))
                                    / floors[c])
            out.append({"run": prep.name, "t_start_s": round(a, 3), "t_end_s": round(b, 3),
                        "peak_noise_floors": _r(pk), "channels": sorted(cs),
                        "strong": bool(pk >= strong_k),
                        "rms_after_update_noise_floors": None if after is None else _r(after)})
    return out


def _pair_bic(pair: Candidate, single: Candidate, problem: Problem) -> float:
    from host_tools.analyzer.fit import delta_bic, effective_n
    r = problem.residual(single.fit.params, list(range(len(problem.preps))))
    return delta_bic(pair.fit.rss, single.fit.rss, effective_n(r),
                     pair.fit.n_free - single.fit.n_free)


def _remaining_windows(problem: Problem, effects: Mapping, fit_chans: Sequence[str],
                       strong: float = STRONG_WINDOW) -> int:
    """Number of significant windows left whose RMS is at least ``strong`` noise floors."""
    n = 0
    for prep, chans in zip(problem.preps, problem.sim_channels(effects,
                                                               range(len(problem.preps)),
                                                               full=True)):
        for c in fit_chans:
            ch = chans.get(c)
            if ch is None:
                continue
            w, _ = sg.significant_windows(ch.t, ch.deflated(problem.floors[c]), problem.floors[c])
            n += sum(1 for x in w if x.rms >= strong * problem.floors[c])
    return n


def updated_model(meta: Mapping, effects: Mapping[str, Mapping[str, float]],
                  sources: Sequence[str]) -> dict:
    """The updated model-parameter file (format ``ddmodel/1``, see docs/analyzer.md)."""
    from host_tools import _native
    robot = dict(meta["robot"])
    motor = dict(meta["motor"])
    plant = _native.Plant.from_meta(meta)
    for name, params in effects.items():
        plant.set_effect(name, **params)
    # fold the effects that are plain parameter changes into the parameters themselves
    if "friction_coefficient" in effects:
        robot["mu_s"] = effects["friction_coefficient"].get("mu_s", robot["mu_s"])
        robot["mu_k"] = effects["friction_coefficient"].get("mu_k", robot["mu_k"])
    if "wheel_radius" in effects:
        robot["r"] = effects["wheel_radius"]["r_eff"]
    if "track_width" in effects:
        robot["b"] = effects["track_width"]["b_eff"]
    tr, tl = plant.tau_max()
    return {"format": MODEL_FORMAT, "robot": robot, "motor": motor,
            "encoder_ppr": int(meta["encoder_ppr"]),
            "effects": {k: {p: float(v) for p, v in d.items()} for k, d in effects.items()},
            "tau_max_nm": {"right": tr, "left": tl, "min": min(tr, tl)},
            "source_runs": list(sources)}
