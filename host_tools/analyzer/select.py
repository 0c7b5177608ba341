"""Stage 5 of the analysis: select the effects the fits support, their equivalents, and decide
the verdict."""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np

from host_tools.analyzer import effects as fx
from host_tools.analyzer import signals as sg
from host_tools.analyzer.fit.invariance import Invariance, invariance_check
from host_tools.analyzer.fit.state_dependence import state_dependence_check
from host_tools.analyzer.fit.judge import (HELDOUT_Z, Candidate, delta_bic, judge, paired_better,
                                           significant_deviation)
from host_tools.analyzer.fit.params import fitted_nuisance, params_for, vocabulary_only
from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.fit.solver import effective_n
from host_tools.analyzer.fit.workers import run_tasks
from host_tools.analyzer.locate.mismatch import STRONG_WINDOW, Detection, state_table
from host_tools.analyzer.locate.revolution import revolution_remains
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import Channel, channels
from host_tools.analyzer.replay.openloop import OpenLoopReplay
from host_tools.analyzer.signals import round_sig

if TYPE_CHECKING:
    from host_tools.analyzer.fit.workers import FitTask


# After the update: explained when the residual is back within the noise floor (normalized RMS
# <= 1).  Detection keeps a margin above the floor against false alarms; a claim of explanation
# asks for the residual to be at noise level.  Settled on the concealed-effect suite (both seed
# sets, with the inner-loop timing from the board's wheel speeds): nulls leave 0.77-0.89 with
# the nominal model, correct explanations 0.77-0.89, a weak battery sag (outside the
# vocabulary) 1.15 with a voltage drop and a 6 ms delay; the detection threshold (1.25) would
# call that sag explained.
EXPLAINED_RMS = 1.0


def excess(problem: Problem, effects: Mapping[str, Mapping[str, float]]) -> float:
    r = problem.residual(effects, list(range(len(problem.preps))), full=True)
    return float(np.mean(r ** 2)) if r.size else 0.0


def fit_candidates(det: Detection, vocab_fit: Mapping[str, Mapping[str, float]], jobs: int, notes: list[str],
                   log: Callable[[str], None]) -> list[Candidate]:
    """Fit every effect of ``vocab_fit`` alone and judge it (``fit.judge``: BIC, held-out
    error, size, physical possibility, per-channel veto); sorted by BIC gain.  Without a
    mismatch nothing is fitted: the verdict does not depend on the candidates."""
    tasks: list[FitTask] = [([e], None, {}) for e in vocab_fit] if det.mismatch_seen else []
    if tasks:
        log(f"fitting {len(tasks)} candidate effect(s) on {jobs} process(es)")
    else:
        notes.append("no mismatch beyond the noise floors: no candidate effect was fitted")
    cands = run_tasks(det.problem, tasks, jobs, "candidate") if tasks else []
    for c in cands:
        judge(det.problem, c)
    cands.sort(key=lambda c: c.delta_bic)
    return cands


@dataclass
class Selection:
    """What the fits select."""
    chosen: Candidate | None        # the accepted single or pair, or None
    effects: dict[str, dict[str, float]]  # its fitted effects: name -> params ({} when none)
    singles: list[Candidate]        # the single effects fitted (judged, by BIC gain)
    pairs: list[Candidate]          # the pairs fitted (judged, by BIC gain), or []


def select_effects(det: Detection, cands: list[Candidate], jobs: int, pairs_top: int,
                   log: Callable[[str], None]) -> Selection:
    """The best accepted single effect; then, when no single is accepted or one leaves a
    strong window or a normalized RMS above ``EXPLAINED_RMS``, pairs of effects
    (``_fit_pairs``), and the best accepted pair replaces the single.  Nothing is selected
    without a mismatch."""
    if not det.mismatch_seen:
        return Selection(None, {}, cands, [])
    problem = det.problem
    best_single = next((c for c in cands if c.accepted), None)
    chosen = best_single
    final_effects = dict(best_single.fit.params) if best_single is not None else {}
    pair_cands: list[Candidate] = []
    remaining = _remaining_windows(problem, final_effects, problem.fit_channels, det.strong_k)
    nrms1 = math.sqrt(excess(problem, final_effects))
    if not final_effects or remaining or nrms1 > EXPLAINED_RMS:
        pair_cands = _fit_pairs(problem, cands, best_single, det.rss0, jobs, pairs_top, log)
        best_pair = next((c for c in pair_cands if c.accepted), None)
        if best_pair is not None:
            chosen = best_pair
            final_effects = dict(best_pair.fit.params)
    return Selection(chosen, final_effects, cands, pair_cands)


def _pair_start(problem: Problem, a: Candidate, b: Candidate) -> np.ndarray:
    """A pair's start: each single's fitted coordinates, for the coordinates the pair's fit
    has (a single's nuisance that a pair does not carry, the friction single's creep, left
    out)."""
    at = {**dict(zip(a.fit.coords, a.fit.x)), **dict(zip(b.fit.coords, b.fit.x))}
    ps = params_for([*a.effects, *b.effects], problem.meta, problem.vocab)
    return np.array([float(at[(p.effect, p.name)]) for p in ps])

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
    pair_tasks: list[FitTask] = [([a, b], _pair_start(problem, single[a], single[b]), {})
                                 for a, b in combos]
    if not pair_tasks:
        return []
    log(f"one effect leaves a mismatch: fitting {len(pair_tasks)} pair(s)")
    pair_cands = run_tasks(problem, pair_tasks, jobs, "pair")
    for pc in pair_cands:
        judge(problem, pc)
        for e in pc.effects:
            alone = single[e]
            better = (pc.fit.rss < alone.fit.rss and
                      _pair_bic(pc, alone, problem) < -10.0 and
                      _heldout_beats(pc, alone))
            if not better:
                pc.checks["adds"] = False
                pc.reasons.append(f"not clearly better than {e} alone")
        if "adds" not in pc.checks:
            pc.checks["adds"] = True
        weak = _insignificant_partners(pc, problem)
        pc.checks["partners_significant"] = not weak
        for e, zs in weak:
            pc.reasons.append(f"{e} insignificant in the pair (its parameter {zs:.2f} sigma from "
                              f"nominal, not beyond what the nominal model allows by the "
                              f"one-sided 1 % point of its error and its tolerance): dropped")
    pair_cands.sort(key=lambda c: c.delta_bic)
    return pair_cands


def _heldout_beats(pair: Candidate, single: Candidate) -> bool:
    """The pair's held-out errors below the single's, sample by sample (``paired_better``, the
    same held-out folds); without the samples, the pooled RMS must fall."""
    if (pair.heldout_pooled is not None and single.heldout_pooled is not None
            and pair.heldout_pooled[1].size == single.heldout_pooled[1].size):
        return paired_better(single.heldout_pooled[1], pair.heldout_pooled[1])[0]
    return pair.heldout_after < single.heldout_after


def _insignificant_partners(pair: Candidate, problem: Problem) -> list[tuple[str, float]]:
    """Effects of a pair none of whose fitted parameters is significantly off nominal: the
    size test a single effect passes (``judge.significant_deviation``: beyond the range the
    nominal model's left-out physics of the normal forces moves it by, by more than the
    one-sided 1 % point, HELDOUT_Z's rate, of the fit's error plus the nominal parameter's
    tolerance, ``judge.size_threshold``).  Such a partner only bends the fit -- a deviation the
    nominal model's own tolerance allows is no evidence of the effect, alone or in a pair --
    and the pair is refused so its other effect stands alone.  Shape parameters and
    unidentified coordinates do not count."""
    params = params_for(pair.effects, problem.meta, problem.vocab)
    best: dict[str, float] = {}
    strong: set[str] = set()
    for j, p in enumerate(params):
        if (p.shape or j >= len(pair.fit.std)
                or f"{p.effect}.{p.name}" in pair.fit.unidentified):
            continue
        sd = pair.fit.std[j]
        dev = pair.fit.values[j] - p.neutral
        zs = abs(dev) / sd if math.isfinite(sd) and sd > 0 else (math.inf if dev else 0.0)
        best[p.effect] = max(best.get(p.effect, 0.0), zs)
        if significant_deviation(dev, sd, p.tol, HELDOUT_Z,
                                 fx.left_out_ranges(p.effect, p.name, problem.meta,
                                                    pair.fit.params)):
            strong.add(p.effect)
    for jd in fx.judged_sets(params, pair.fit.values, pair.fit.std, [], problem.meta):
        zs = abs(jd.dev) / jd.std if math.isfinite(jd.std) and jd.std > 0 else math.inf
        best[jd.effect] = max(best.get(jd.effect, 0.0), zs)
        if significant_deviation(jd.dev, jd.std, jd.tol, HELDOUT_Z, jd.left_out):
            strong.add(jd.effect)
    return [(e, zs) for e, zs in best.items() if e not in strong]


def _pair_bic(pair: Candidate, single: Candidate, problem: Problem) -> float:
    r = problem.residual(single.fit.params, list(range(len(problem.preps))))
    return delta_bic(pair.fit.rss, single.fit.rss, effective_n(r),
                     pair.fit.n_free - single.fit.n_free)


def _remaining_windows(problem: Problem, effects: Mapping[str, Mapping[str, float]], fit_chans: Sequence[str],
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


def selected_entries(sel: Selection, rss0: float) -> list[dict[str, Any]]:
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
                                                    "adds", "partners_significant"))
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
        entry: dict[str, Any] = {
            "effect": e, "params": {k: round_sig(v, 5) for k, v in
                                    vocabulary_only(sel_c.fit.params)[e].items()},
            "unidentified": [u.split(".", 1)[1] for u in sel_c.fit.unidentified
                             if u.startswith(e + ".")],
            "equivalent": equiv,
            "separating_measurement": {q: fx.separator(e, q) for q in equiv}}
        nuis = fitted_nuisance(sel_c.fit, e)
        if nuis:   # not a vocabulary parameter: beside the params (run-format's report.json)
            entry["nuisance"] = {k: {q: round_sig(x, 4) for q, x in v.items()}
                                 for k, v in nuis.items()}
        selected.append(entry)
    return selected


def invariance_of(det: Detection, sel: Selection) -> Invariance | None:
    """The time-invariance check of the selected model (``fit.invariance``) with its
    dependence on the drive's load (``fit.state_dependence``), run when it would otherwise
    explain the mismatch (None: not run)."""
    if (not det.mismatch_seen or sel.chosen is None
            or math.sqrt(excess(det.problem, sel.effects)) > EXPLAINED_RMS):
        return None
    return invariance_check(det.problem, sel.chosen).with_state(
        state_dependence_check(det.problem, sel.chosen))


def decide_verdict(det: Detection, final_effects: Mapping[str, Mapping[str, float]],
                   selected: Sequence[dict[str, Any]], preps: Sequence[PreparedRun],
                   duty: OpenLoopReplay, notes: list[str],
                   invariance: Invariance | None = None) -> tuple[str, dict[str, Any] | None]:
    """(verdict, hint).  ``no_mismatch`` when detection saw none; ``explained`` when effects
    were selected, their residual is back within the noise floor (normalized RMS at most
    ``EXPLAINED_RMS``: a claim of explanation asks for noise level, not merely below the
    detection threshold) and their parameters do not drift in time (``invariance``,
    :func:`invariance_of`); otherwise ``unexplained``, with a sparse regression of what remains
    (``sparse_hint``) as a hint towards the missing physics."""
    if not det.mismatch_seen:
        return "no_mismatch", None
    nrms1 = math.sqrt(excess(det.problem, final_effects))
    drift = invariance is not None and invariance.drift
    remains = (revolution_remains(det, preps, duty, final_effects)
               if selected and nrms1 <= EXPLAINED_RMS and not drift else [])
    if selected and nrms1 <= EXPLAINED_RMS and not drift and not remains:
        return "explained", None
    if remains:
        notes.append("the once-per-revolution term of " + ", ".join(remains) + " remains after "
                     "the selected effects: they do not explain it")
    if drift and invariance is not None:
        notes.append(invariance.note())
    chans_after = [channels(p, duty.simulate_windows(p, final_effects), "duty") for p in preps]
    hint = sparse_hint(preps, chans_after)
    if selected:
        notes.append("the selected effects explain part of the mismatch only "
                     f"(normalized RMS residual {det.nrms0:.3g} -> {nrms1:.3g}, noise = 1)")
    return "unexplained", hint


def sparse_hint(preps: Sequence[PreparedRun], chans_per_run: Sequence[Mapping[str, Channel]]
                ) -> dict[str, Any] | None:
    """Sparse regression of the wheel-acceleration residual on named state features."""
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
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
            xs.append(np.column_stack([np.ones_like(w), np.sign(w) * (np.abs(w) > 0.5), w,
                                       w * np.abs(w), a, tau, u, yaw * sgn, u * w, ch.t]))
            ys.append(acc)
    if not xs:
        return None
    X = np.vstack(xs)
    y = np.concatenate(ys)
    terms = sg.stlsq(X, y, names, threshold=0.15, max_terms=3)
    if not terms:
        return {"target": "d/dt of the wheel-speed residual (rad/s^2)", "terms": {},
                "r2": 0.0, "text": "no sparse combination of the state features fits"}
    idx = [names.index(n) for n in terms]
    yhat = X[:, idx] @ np.array([terms[n] for n in terms])
    r2 = sg.r_squared(y, yhat)
    text = " + ".join(f"{v:.4g}*{n}" if n != "1" else f"{v:.4g}" for n, v in terms.items())
    return {"target": "d/dt of the wheel-speed residual (rad/s^2), per wheel",
            "terms": {n: round_sig(v) for n, v in terms.items()}, "r2": round(r2, 3),
            "text": f"residual wheel acceleration ~ {text}"}
