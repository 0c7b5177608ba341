"""The stage's two steps: the windows where each nominal replay's residual stands out of the noise
floors (:func:`locate_mismatch`), and whether the recordings disagree with the nominal model at
all (:func:`detect_mismatch`)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from host_tools.analyzer import signals as sg
from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.locate.bias import WHEEL_PAIRS, allowed_bias, bias_test, pair_name
from host_tools.analyzer.locate.episodes import unpinned_episodes
from host_tools.analyzer.locate.floors import closed_loop_floors, noise_floors
from host_tools.analyzer.locate.revolution import REV_CHANNELS, revolution_of
from host_tools.analyzer.locate.wheels import imbalance_of
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import CHANNELS, FIT_CHANNELS, Channel
from host_tools.analyzer.replay.closedloop import CLOSED_LOOP_CHANNELS
from host_tools.analyzer.signals import round_sig


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


def slip_difference_rss(problem: Problem, pair_unc: Sequence[Mapping[str, tuple[np.ndarray, np.ndarray]]]
                        ) -> tuple[float, float]:
    """The wheel pairs' differences in pinned slips (``Problem.slip_differences``) as the
    normalized RMS counts them: (their raw sum of squares in floors, the same deflated by the
    difference's own replay uncertainty).  In such a slip each wheel is no evidence, so its
    channel's uncertainty reads SLIP_UNC; the difference (r - l)/sqrt(2) is evidence, but only
    up to the uncertainty the two wheels had before (the tolerance ensemble's spread, the input
    spread and the sampling band, ``pair_unc``: per run, channel -> (t, uncertainty)), which
    carries over to the difference as sqrt(u_r^2 + u_l^2)/sqrt(2) in floors (the two wheels'
    errors counted independent).  Every other sample of the normalized RMS is deflated that
    way (``Channel.deflated``); a difference left raw counts a slip the ensemble spreads by
    10-30 floors as that many floors of mismatch."""
    raw = defl = 0.0
    pairs = {pair_name(a, b): (a, b) for a, b in WHEEL_PAIRS}
    runs = list(range(len(problem.preps)))
    for i, chans in zip(runs, problem.sim_channels({}, runs, True, fit_only=True)):
        units = pair_unc[i] if i < len(pair_unc) else {}
        for name, d, t in problem.named_slip_differences(chans):
            a, b = pairs[name]
            u2 = np.zeros(t.size)
            for c in (a, b):
                if c in units:
                    tu, uu = units[c]
                    u2 += (np.interp(t, tu, uu) / problem.floors[c]) ** 2
            d = np.where(np.isfinite(d), d, 1e6)
            raw += float(np.sum(d ** 2))
            defl += float(np.sum(d ** 2 / (1.0 + u2 / 2.0)))
    return raw, defl

def _window_entries(preps: Sequence[PreparedRun], chans_per_run: Sequence[Mapping[str, Channel]],
                    floors: Mapping[str, float], channel_names: Sequence[str], replay_name: str,
                    regime_cands_per_run: Sequence[Mapping[str, np.ndarray]], tau_max: float
                    ) -> tuple[list[dict[str, Any]], dict[tuple[int, str], list[sg.Window]]]:
    """Significant windows of every channel, with the regime that best explains them.
    Returns the report entries and {(run, channel): windows}."""
    entries: list[dict[str, Any]] = []
    wins: dict[tuple[int, str], list[sg.Window]] = {}
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
                                "t_end_s": round(win.t_end_s, 4), "rms": round_sig(win.rms),
                                "noise_floor": round_sig(floors[c]),
                                "regime": regime.description if regime else "unknown",
                                "regime_f1": round(regime.score, 3) if regime else 0.0,
                                "replay": replay_name})
    return entries, wins


@dataclass
class Located:
    """Noise floors and significant windows of the nominal replays."""
    floors: dict[str, float]            # duty replay's channels
    floors_t: dict[str, float]          # torque replay's channels
    cl_floors: dict[str, float]         # closed-loop channels
    entries: list[dict[str, Any]]       # the report's mismatch entries (duty replay)
    entries_t: list[dict[str, Any]]     # ... of the torque replay
    cl_entries: list[dict[str, Any]]    # ... of the closed-loop replay
    windows: dict[tuple[int, str], list[sg.Window]]     # (run index, channel) -> [Window], duty
    cl_windows: dict[tuple[int, str], list[sg.Window]]  # ... closed-loop replay
    # per run, each wheel pair channel's (t, replay uncertainty with its sampling band) before
    # the slips were marked no evidence (``slip_difference_rss``)
    pair_unc: list[dict[str, tuple[np.ndarray, np.ndarray]]] = dataclasses.field(
        default_factory=list)


# The shield's current sense reads |I| and its ADC no negative counts: the noise of a reading
# near nil is clipped at 0, so that a motor at rest reads sigma / sqrt(2 pi) (0.40 of the noise)
# on average and a replay of |I| sits below the recording there by that much.  Over a run that
# rests or cruises on little current most of its time (a tour: 75-80 % of its samples within
# half a floor of nil) that is a bias of 0.4-0.8 floors in both currents, which the bias test
# counts as a mismatch over many samples.  A current channel therefore replays the sense's mean
# reading (signals.clipped_reading_mean) with the channel's noise floor as the noise: where
# the floor is the clipped spread itself (few samples where the current flows,
# floors.sense_linear_noise_std) it is below the noise, the mean reading at rest the lower and
# part of the bias stays.
def with_sense_noise(preps: Sequence[PreparedRun], floors: Mapping[str, float],
                     replays: Sequence[Sequence[dict[str, Channel]]]
                     ) -> tuple[list[PreparedRun], list[list[dict[str, Channel]]]]:
    """The runs with their current sense's noise (``PreparedRun.sense_noise_a``: the current
    channels' noise floors) and each replay's channels (per run, name -> channel) with their
    current channels replaying the mean reading; the runs and replays as they are without
    both current channels' floors."""
    if not all(floors.get(c, 0.0) > 0 for c in ("current_r_a", "current_l_a")):
        return list(preps), [list(r) for r in replays]
    sig = (floors["current_r_a"], floors["current_l_a"])
    out = []
    for chans_per_run in replays:
        new = []
        for chans in chans_per_run:
            chans = dict(chans)
            for c, s in zip(("current_r_a", "current_l_a"), sig):
                if c in chans:
                    ch = chans[c]
                    chans[c] = dataclasses.replace(ch, sim=sg.clipped_reading_mean(ch.sim, s))
            new.append(chans)
        out.append(new)
    return [dataclasses.replace(p, sense_noise_a=sig) for p in preps], out


def locate_mismatch(preps: Sequence[PreparedRun], nominal: Sequence[dict[str, Channel]],
                    nominal_t: Sequence[dict[str, Channel]], cl_nominal: Sequence[dict[str, Channel]],
                    log: Callable[[str], None]
                    ) -> tuple[list[PreparedRun], list[dict[str, Channel]], Located]:
    """Noise floors from the data (``noise_floors``, ``closed_loop_floors``) and the windows
    where each replay's residual stands out of them, each with the regime of the run's state
    (speed, torque against its limit, ...) that best explains where they are.  A residual only
    means something in units of its channel's noise, so every later decision is in noise
    floors.  The slips the model's tolerance does not pin down are no evidence
    (``unpinned_episodes``): returns (the prepared runs and the nominal duty replay's channels
    with that uncertainty, which every later stage uses; what was located)."""
    floors = noise_floors(preps, nominal)
    floors_t = noise_floors(preps, nominal_t)
    preps, (nominal, nominal_t) = with_sense_noise(preps, floors, (nominal, nominal_t))
    cl_floors = closed_loop_floors(cl_nominal)
    log("noise floors: " + ", ".join(f"{c}={v:.3g}" for c, v in sorted(floors.items())))
    pair_unc = [{c: (ch.t, ch.total_unc) for c in {x for p in WHEEL_PAIRS for x in p}
                 if (ch := chans.get(c)) is not None and ch.total_unc is not None}
                for chans in nominal]
    unpinned = unpinned_episodes(preps, nominal, floors)
    preps, nominal = unpinned.preps, unpinned.nominal
    if any(unpinned.episodes):
        log("slip episodes the model's tolerance does not pin down: " + "; ".join(
            f"{p.name} " + ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in u)
            for p, u in zip(preps, unpinned.episodes) if u))
    from host_tools import _native
    plant = _native.Plant.from_meta(preps[0].run.meta)
    tau_max = float(min(plant.tau_max()))
    states = [state_table(p) for p in preps]
    chan_names = [c for c in CHANNELS if any(c in ch for ch in nominal)]
    entries, wins = _window_entries(preps, nominal, floors, chan_names, "duty", states, tau_max)
    entries_t, _ = _window_entries(preps, nominal_t, floors_t, chan_names, "torque", states,
                                   tau_max)
    cl_entries: list[dict[str, Any]] = []
    cl_wins: dict[tuple[int, str], list[sg.Window]] = {}
    if any(cl_nominal):
        cl_entries, cl_wins = _window_entries(preps, cl_nominal, cl_floors,
                                              [c for c in CLOSED_LOOP_CHANNELS if c in cl_floors],
                                              "closed-loop", states, tau_max)
    return preps, nominal, Located(floors, floors_t, cl_floors, entries, entries_t, cl_entries,
                                   wins, cl_wins, pair_unc)


@dataclass
class Detection:
    """The fit problem and whether the recordings disagree with the nominal model."""
    problem: Problem
    rss0: float             # nominal residual sum of squares (fit channels, in noise floors)
    nrms0: float            # ... as a normalized RMS
    strong_k: float         # noise floors that make one window a mismatch on its own
    mismatch_seen: bool
    bias: dict[str, dict[str, Any]] | None = None  # channel -> bias_test's figures
    imbalance: dict[str, Any] | None = None  # wheels.imbalance_test's figures
    revolution: dict[str, dict[str, Any]] | None = None  # wheel speed -> revolution_test's
    revolution_cache: dict[str, Any] | None = None  # its tolerance replays (revolution_of)
    nominal: Sequence[Mapping[str, Channel]] | None = None  # the nominal duty replay's channels


def detect_mismatch(preps: Sequence[PreparedRun], nominal: Sequence[dict[str, Channel]], loc: Located,
                    vocab: dict[str, dict[str, float]], dt_s: float, notes: list[str], log: Callable[[str], None]) -> Detection:
    """Build the fit problem (the fit channels, and on long runs the windows the fits see) and
    decide whether there is a mismatch at all: a strong window in a fit channel (``strong_k``
    floors, raised with the recording's length so the false-alarm rate per analysis stays
    what it is on 12 s), significant windows with an overall normalized RMS above
    ``MISMATCH_RMS``, a consistent bias over many samples (``bias_test``) or the wheels'
    differences following a per-wheel torque imbalance (``wheels.imbalance_of``, in the bias
    test's Bonferroni share) or a wheel speed's residual following its own wheel's angle
    (``revolution.revolution_of``, one test per wheel in the same share).  The torque
    replay does not decide; it adds a note on where the mismatch sits (between duty and
    torque, or not)."""
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
    diff_raw, diff_defl = slip_difference_rss(problem, loc.pair_unc)
    nrms_rule = math.sqrt(max(rss0 - diff_raw + diff_defl, 0.0) / max(r0.size, 1))
    if diff_raw > 0:
        log(f"normalized RMS {nrms0:.3g}; {nrms_rule:.3g} with the wheel pairs' differences in "
            f"pinned slips deflated by their replay uncertainty")
    total_s = sum(float(p.run.telemetry["t_s"][-1] - p.run.telemetry["t_s"][0]) for p in preps)
    strong_k = strong_threshold(total_s)
    strong0 = [e for e in sig_fit if e["rms"] >= strong_k * e["noise_floor"]]
    n_rev = sum(1 for c, _ in REV_CHANNELS if c in fit_chans)
    bias = bias_test(nominal, floors, fit_chans,
                     allowed=[allowed_bias(p, floors) for p in preps], extra_tests=1 + n_rev)
    biased = [c for c, v in bias.items() if v["significant"]]
    n_tests = next((v["tests"] for v in bias.values()), len(fit_chans) + 1 + n_rev)
    imb = imbalance_of(problem, nominal, n_tests)
    rev_cache: dict[str, Any] = {}
    rev = revolution_of(preps, nominal, {c: floors[c] for c, _ in REV_CHANNELS
                                         if c in fit_chans}, dt_s, n_tests, cache=rev_cache)
    for c, v in rev.items():
        log(f"once per revolution, {c}: F {v['F']:.1f} against {v['F_threshold']:.2f} "
            f"(F({v['df'][0]}, {v['df'][1]:.0f}), {v['blocks']} blocks, lag-1 {v['lag1']:.2f}), "
            f"amplitude {v['amplitude_floors']:.2f} floors, RMS {v['rms_floors']:.2f}"
            + ("" if v["tolerance_amplitude_floors"] is None else
               f", tolerance amplitude {v['tolerance_amplitude_floors']:.2f}"))
    revs = [c for c, v in rev.items() if v["significant"]]
    if revs:
        notes.append("a wheel speed's residual follows its own wheel's angle, once per "
                     "revolution (out of the vocabulary: eccentric wheel, flat spot, bent rim): "
                     + ", ".join(f"{c} amplitude {rev[c]['amplitude_floors']:.2f} noise floors "
                                 f"(F {rev[c]['F']:.1f} against {rev[c]['F_threshold']:.2f} "
                                 f"over {rev[c]['blocks']} blocks of {rev[c]['block_s']:g} s)"
                                 for c in revs))
    if imb is not None and imb["significant"]:
        log(f"wheels' torque imbalance: t {imb['t']:.1f} > {imb['t_threshold']:.1f} "
            f"({imb['blocks']} blocks), gain ratio {imb['ratio']:.3f}")
        notes.append("the wheels' speed and current differences follow a per-wheel torque "
                     f"imbalance: t {imb['t']:.1f} against {imb['t_threshold']:.1f} over "
                     f"{imb['blocks']} blocks of {imb['block_s']:g} s ({imb['n_eff']:.0f} "
                     f"effective), a gain ratio of {imb['ratio']:.3f} along the replay's "
                     f"response, {imb['output_floors']:.2f} noise floors of output")
    if biased:
        log("consistent bias: " + ", ".join(
            f"{c} {bias[c]['bias_floors']:+.2f} floors (t {bias[c]['t']:.1f} > "
            f"{bias[c]['t_threshold']:.1f}, {bias[c]['blocks']} blocks)" for c in biased))
        notes.append("a consistent bias over many samples, each below the strong-window "
                     "threshold: " + ", ".join(f"{c} {bias[c]['bias_floors']:+.2f} noise floors "
                                               f"over {bias[c]['blocks']} blocks of "
                                               f"{bias[c]['block_s']:g} s" for c in biased))
    mismatch_seen = (bool(strong0) or (bool(sig_fit) and nrms_rule > MISMATCH_RMS)
                     or bool(biased) or bool(imb and imb["significant"]) or bool(revs))
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
    return Detection(problem, rss0, nrms0, strong_k, mismatch_seen, bias, imb, rev, rev_cache,
                     nominal)


def state_table(prep: PreparedRun) -> dict[str, np.ndarray]:
    """Operating state at the telemetry frames (from the recording), for regime search."""
    tel = prep.run.telemetry
    t = tel["t_s"]
    k = 2 * np.pi / prep.ppr
    w_r = np.gradient(tel["enc_r"] * k, t)
    w_l = np.gradient(tel["enc_l"] * k, t)
    w_r, w_l = sg.smooth(w_r, 3), sg.smooth(w_l, 3)
    return {"t": t, "w_r": w_r, "w_l": w_l,
            "a_r": sg.smooth(np.gradient(w_r, t), 3), "a_l": sg.smooth(np.gradient(w_l, t), 3),
            "tau_r": tel["tau_cmd_r"], "tau_l": tel["tau_cmd_l"],
            "u_r": tel["pwm_r"], "u_l": tel["pwm_l"],
            "yaw": float(prep.robot["r"]) * (w_r - w_l) / (2 * float(prep.robot["b"]))}
