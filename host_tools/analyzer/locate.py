"""Stage 3 of the analysis: noise floors from the data, the windows where each nominal replay's
residual stands out of them, and whether the recordings disagree with the nominal model at all."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from host_tools.analyzer import signals as sg
from host_tools.analyzer.fit.problem import Problem
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import CHANNELS, CUMULATIVE, FIT_CHANNELS, Channel
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

# A consistent bias: many samples that agree, each below STRONG_WINDOW.  The residual of each
# fit channel (in noise floors, deflated by the replay's uncertainty) is cut into blocks of
# BIAS_BLOCK_S within its replay windows; the block means are the effective samples (noise and
# the replay's own short-lived errors decorrelate within a block, so the autocorrelation of the
# samples inside a block does not count them many times) and a t-test over them, pooled over the
# runs, asks whether their mean differs from zero.  The threshold comes from the false-alarm
# rate BIAS_ALPHA per analysis, two-sided, shared by the fit channels (Bonferroni).  A bias below
# BIAS_MIN_FLOORS counts for nothing however many samples agree: it is the smallest output
# change an update may make to be adopted (``judge``'s min_output), so a smaller one could never
# be named.
BIAS_BLOCK_S = 1.0
BIAS_ALPHA = 0.01
BIAS_MIN_FLOORS = 0.5

# The two wheels' difference.  A per-wheel effect (a motor-gain asymmetry) moves the two wheels'
# residuals in opposite directions while the body's motion, and most of the replay's own error,
# moves them alike: the difference (r - l)/sqrt(2) of a wheel pair's residuals in floors (speeds,
# currents) holds the one without the other (heldback6's MuJoCo 10 % asymmetry: currents -0.64
# and +0.48 floors, t -2.5 and +1.5 per wheel; their difference -0.79 floors, and its block means
# decorrelate within half a second).  It is tested as one more channel (Bonferroni over the fit
# channels and these), in blocks of PAIR_BLOCK_S: on the tuning and heldback6 nulls the lag-1
# autocorrelation of the difference's 0.5 s block means is at most 0.2, so they are independent
# samples.  The tolerance's allowed bias of the difference is that of the draws' differences
# (``tolerance_draw_means``): the drawn parameters are the robot's, common to both wheels, so
# it is small where the per-wheel one is not.
WHEEL_PAIRS = (("omega_r", "omega_l"), ("current_r_a", "current_l_a"))
PAIR_BLOCK_S = 0.5


def pair_name(a: str, b: str) -> str:
    return f"{a}-{b}"


def _block_means(ch: Channel, floor: float, block_s: float = BIAS_BLOCK_S,
                 no_evidence: float | None = None) -> list[float]:
    """Means of the channel's residual (in floors) over blocks of ``block_s`` within each
    replay window; a block with fewer than 3 samples is left out, and so are the samples whose
    replay uncertainty is ``no_evidence`` or more (default SLIP_UNC: ``unpinned_episodes``)."""
    z = ch.resid / floor
    t = np.asarray(ch.t, float)
    seg = ch.seg if ch.seg is not None else np.zeros(t.size, int)
    ok = np.isfinite(z)
    if ch.unc is not None:
        ok &= ch.unc < (SLIP_UNC if no_evidence is None else no_evidence)
    out: list[float] = []
    for s in np.unique(seg):
        m = (seg == s) & ok
        if m.sum() < 3:
            continue
        ts, zs = t[m], z[m]
        k = np.floor((ts - ts[0]) / block_s).astype(int)
        # a short last block joins the one before it
        if k.size and k[-1] > 0 and ts[-1] - (ts[0] + k[-1] * block_s) < 0.5 * block_s:
            k[k == k[-1]] = k[-1] - 1
        for b in np.unique(k):
            zb = zs[k == b]
            if zb.size >= 3:
                out.append(float(np.mean(zb)))
    return out


def bias_test(nominal: Sequence[Mapping[str, Channel]], floors: Mapping[str, float],
              channels_: Sequence[str], alpha: float = BIAS_ALPHA,
              min_floors: float = BIAS_MIN_FLOORS,
              allowed: Sequence[Mapping[str, float] | None] | None = None
              ) -> dict[str, dict[str, Any]]:
    """Per fit channel: the mean residual over all runs (in noise floors), the number of
    blocks (effective samples), the t statistic of the block means, the threshold for the
    false-alarm rate ``alpha`` per analysis (two-sided, Bonferroni over ``channels_``) and
    whether the bias is significant and at least ``min_floors``; and the same for each wheel
    pair's difference (``WHEEL_PAIRS``, keyed ``pair_name``, in blocks of PAIR_BLOCK_S; the
    Bonferroni count includes them).  ``allowed`` (per run,
    channel -> std of the whole-run bias the model's tolerance allows, ``tolerance_bias``)
    joins the standard error: the tolerance is one set of parameters for all runs, so its
    error does not average out over blocks; it is taken as fully shared by the runs."""
    from scipy import stats
    from host_tools.analyzer.replay.channels import Channel
    out: dict[str, dict[str, Any]] = {}
    tests: list[tuple[str, list[tuple[list[float], float]], float, float]] = []
    for c in channels_:
        f = floors.get(c, 0.0)
        if not f > 0:
            continue
        tests.append((c, [(_block_means(chans[c], f),
                           (allowed[i] or {}).get(c, 0.0) / f if allowed else 0.0)
                          for i, chans in enumerate(nominal) if c in chans], f, BIAS_BLOCK_S))
    for a, b in WHEEL_PAIRS:
        fa, fb = floors.get(a, 0.0), floors.get(b, 0.0)
        if a not in channels_ or b not in channels_ or not (fa > 0 and fb > 0):
            continue
        name = pair_name(a, b)
        per_run = []
        for i, chans in enumerate(nominal):
            ca, cb = chans.get(a), chans.get(b)
            if ca is None or cb is None or ca.t.size != cb.t.size or np.any(ca.t != cb.t):
                continue
            d = Channel(name, ca.t, (ca.resid / fa - cb.resid / fb) / math.sqrt(2),
                        np.zeros(ca.t.size), "floors", ca.seg,
                        None if ca.unc is None and cb.unc is None else
                        np.maximum(ca.unc if ca.unc is not None else 0.0,
                                   cb.unc if cb.unc is not None else 0.0))
            per_run.append((_block_means(d, 1.0, PAIR_BLOCK_S, UNPINNED_UNC),
                            (allowed[i] or {}).get(name, 0.0) if allowed else 0.0))
        tests.append((name, per_run, 1.0, PAIR_BLOCK_S))
    m = max(len(tests), 1)
    for c, per_run, f, block_s in tests:
        means = [v for bm, _ in per_run for v in bm]
        n = len(means)
        if n < 3:
            continue
        sys_ = sum(len(bm) * a for bm, a in per_run) / n
        mu = float(np.mean(means))
        sd = float(np.std(means, ddof=1))
        se = math.sqrt(sd ** 2 / n + sys_ ** 2)
        tstat = mu / se if se > 0 else (math.inf if mu != 0 else 0.0)
        thr = float(stats.t.ppf(1 - alpha / (2 * m), n - 1))
        out[c] = {"bias_floors": mu, "blocks": n, "block_s": block_s, "t": tstat,
                  "t_threshold": thr, "tolerance_floors": sys_,
                  "significant": bool(abs(tstat) > thr and abs(mu) >= min_floors)}
    return out


def allowed_bias(prep: PreparedRun, floors: Mapping[str, float]) -> dict[str, float]:
    """The whole-run bias the model's tolerance allows (``prep.tolerance_bias``, channel units)
    and, for each wheel pair, that of the pair's difference in floors: the std over the
    tolerance draws of (mean_r / floor_r - mean_l / floor_l) / sqrt(2)."""
    out = dict(prep.tolerance_bias or {})
    draws = prep.tolerance_draw_means or {}
    for a, b in WHEEL_PAIRS:
        fa, fb = floors.get(a, 0.0), floors.get(b, 0.0)
        if a in draws and b in draws and fa > 0 and fb > 0 and len(draws[a]) == len(draws[b]):
            d = (np.asarray(draws[a]) / fa - np.asarray(draws[b]) / fb) / math.sqrt(2)
            out[pair_name(a, b)] = float(np.std(d))
    return out


def _current_lsb_a() -> float:
    """One ADC count of the motor-current telemetry (protocol.json's scale of current_r)."""
    from host_tools import protocol
    for m in protocol.definition().by_name.values():
        for f in m.fields:
            if f.name == "current_r" and f.scale:
                return float(f.scale)
    return 0.0


def current_count_a(preps: Sequence[PreparedRun]) -> float:
    """One count of the motor-current sense, in A: the run's meta.json when it describes its
    current sense (``current_sense``: ``adc_vref_v / 2^adc_bits / volts_per_amp``), else the
    quantization step of the recorded current columns (:func:`signals.quantization_step`);
    the largest over the runs, 0 when neither says."""
    counts = []
    for p in preps:
        cs: Any = p.run.meta.get("current_sense") if isinstance(p.run.meta, Mapping) else None
        try:
            counts.append(float(cs["adc_vref_v"]) / 2 ** int(cs["adc_bits"])
                          / float(cs["volts_per_amp"]))
            continue
        except (TypeError, KeyError, ValueError, ZeroDivisionError):
            pass
        for side in ("r", "l"):
            col = p.run.telemetry.get(f"current_{side}_a")
            if col is not None and np.ptp(col) > 0:
                counts.append(sg.quantization_step(col))
    return max(counts, default=0.0)


def noise_floors(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, Channel]]
                 ) -> dict[str, float]:
    """Per-channel noise floor, pooled over runs, estimated from the data:
    encoder quantization for wheel speeds and counts, at least one ADC count for the motor
    current (:func:`current_count_a`), the high-frequency part of the
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
    names = sorted(set().union(*[set(c) for c in nominal]))  # report.json: one key order
    count_a = current_count_a(preps) if any(c.startswith("current") for c in names) else 0.0
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
        if c.startswith("current"):
            # never below one ADC count: a magnitude-only sense reads long runs of exact zeros
            # at rest, where the MAD of second differences is nil, and had put the floor at
            # 0.6 of a count, so that a reading two counts off stood out
            f = max(f, count_a)
        if c in CUMULATIVE:
            # within a replay window (a long run is compared window by window)
            span = max(max(ch[c].spans()) for ch in nominal if c in ch)
            f = max(f, 0.01 * span)
        floors[c] = f
    return floors


# Where the nominal model cannot pin the replay down, the replay is no evidence.  A run replayed
# in windows notes its nominal replay's slip episodes (``replay.anchors``).  In a slip the body's
# motion and the slipping wheels follow the contact forces, whose size and direction follow the
# slip velocity and the contact's form, which no plant reproduces in detail: the tolerance
# ensemble can call a slip pinned and the recording still depart (a braking reversal of the
# MuJoCo tuning set's 60 s null: 6 camera floors of slip distance where the 8 draws spread by
# 0.4, and 4-6 floors of current in a slipping reversal where they spread by 0.5).  So:
# - the pose channels are no evidence from a slip's onset until the replay is re-anchored (the
#   end of its window; a window is cut after each slip, ``anchors._edges_after_slip``): the pose
#   integrates the slip's error;
# - the wheel-speed and current channels are no evidence within a slip episode, and when the
#   episode is unpinned — inside it the replay's own uncertainty of a pose channel (the tolerance
#   ensemble and the input spread, ``Channel.unc``) exceeds that channel's noise floor: the model
#   cannot say where the body goes (a 3 s spin at the start of heldback6's MuJoCo 60 s null ended
#   2.5 rad off, the ensemble spreading by 0.28 rad) — until BURN_IN_S after it ends, while the
#   wheels settle from the body's unpinned motion.  Elsewhere they are evidence, the ensemble's
#   spread joining the noise floor as everywhere.
# "No evidence" is an unbounded replay uncertainty (UNPINNED_UNC): the deflated residual is nil
# there, in the decisions and the fits alike.  A run replayed in one window (up to 6 s, from
# rest) notes no episodes: its slips are the experiment's regime, its replay starts pinned at
# rest, and the friction effects show there.
POSE_CHANNELS = ("x_m", "y_m", "phi_rad")
UNPINNED_UNC = 1e9
SLIP_UNC = 1e8      # a wheel channel in a pinned slip: no evidence, its pair's difference is


@dataclass(frozen=True)
class Unpinned:
    """What :func:`unpinned_episodes` returns, per run."""
    preps: list[PreparedRun]               # with that replay uncertainty (``replay_unc``)
    nominal: list[dict[str, Channel]]      # the nominal channels with it (``unc``)
    episodes: list[list[tuple[float, float]]]  # (onset, end) of the unpinned episodes


def unpinned_episodes(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, Channel]],
                      floors: Mapping[str, float]) -> Unpinned:
    """Mark the nominal replay's slip episodes as no evidence (above): per run, the replay
    uncertainty ``replay_unc`` (which every later replay of the run attaches to its channels)
    and the nominal channels' ``unc`` are UNPINNED_UNC over the spans they cover.  Returns
    the prepared runs and nominal channels with that uncertainty (new values; those given are
    left as they are) and per run the (onset, end) of the unpinned episodes."""
    from host_tools.analyzer.prepare.run import BURN_IN_S
    out: list[list[tuple[float, float]]] = []
    out_preps: list[PreparedRun] = []
    out_nominal: list[dict[str, Channel]] = []
    for prep, given in zip(preps, nominal):
        chans = dict(given)
        found: list[tuple[float, float]] = []
        slips = list(prep.slip_episodes)
        unc = dict(prep.replay_unc or {})
        for a, b in prep.slip_episodes:
            onset = math.inf
            for c in POSE_CHANNELS:
                ch = chans.get(c)
                f = floors.get(c, 0.0)
                if ch is None or ch.unc is None or not f > 0:
                    continue
                m = (ch.t >= a) & (ch.t <= b) & (ch.unc > f)
                if m.any():
                    onset = min(onset, float(ch.t[m][0]))
            if math.isfinite(onset):
                found.append((onset, b))
        if not found and not slips:
            out.append([])
            out_preps.append(prep)
            out_nominal.append(chans)
            continue
        for c, ch in chans.items():
            if c not in FIT_CHANNELS or ch.t.size == 0:
                continue
            seg = ch.seg if ch.seg is not None else np.zeros(ch.t.size, int)
            mask = np.zeros(ch.t.size, bool)
            slip = np.zeros(ch.t.size, bool)
            if c in POSE_CHANNELS:
                for a, b in slips:
                    here = seg[np.argmin(np.abs(ch.t - a))]
                    mask |= (ch.t >= a) & (seg == here)
            else:
                for onset, b in found:
                    mask |= (ch.t >= onset) & (ch.t <= b + BURN_IN_S)
                for a, b in slips:
                    slip |= (ch.t >= a) & (ch.t <= b)
            if not (mask.any() or slip.any()):
                continue
            base = ch.unc if ch.unc is not None else np.zeros(ch.t.size)
            new = np.where(mask, UNPINNED_UNC, np.where(slip, np.maximum(base, SLIP_UNC), base))
            chans[c] = dataclasses.replace(ch, unc=new)
            unc[c] = (ch.t.copy(), new.copy())
        out_preps.append(dataclasses.replace(prep, replay_unc=unc))
        out_nominal.append(chans)
        out.append(found)
    return Unpinned(out_preps, out_nominal, out)


def closed_loop_floors(chans_per_run: Sequence[Mapping[str, Channel]]) -> dict[str, float]:
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
    log("noise floors: " + ", ".join(f"{c}={v:.3g}" for c, v in sorted(floors.items())))
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
    cl_floors = closed_loop_floors(cl_nominal)
    cl_entries: list[dict[str, Any]] = []
    cl_wins: dict[tuple[int, str], list[sg.Window]] = {}
    if any(cl_nominal):
        cl_entries, cl_wins = _window_entries(preps, cl_nominal, cl_floors,
                                              [c for c in CLOSED_LOOP_CHANNELS if c in cl_floors],
                                              "closed-loop", states, tau_max)
    return preps, nominal, Located(floors, floors_t, cl_floors, entries, entries_t, cl_entries,
                                   wins, cl_wins)


@dataclass
class Detection:
    """The fit problem and whether the recordings disagree with the nominal model."""
    problem: Problem
    rss0: float             # nominal residual sum of squares (fit channels, in noise floors)
    nrms0: float            # ... as a normalized RMS
    strong_k: float         # noise floors that make one window a mismatch on its own
    mismatch_seen: bool
    bias: dict[str, dict[str, Any]] | None = None  # channel -> bias_test's figures


def detect_mismatch(preps: Sequence[PreparedRun], nominal: Sequence[dict[str, Channel]], loc: Located,
                    vocab: dict[str, dict[str, float]], dt_s: float, notes: list[str], log: Callable[[str], None]) -> Detection:
    """Build the fit problem (the fit channels, and on long runs the windows the fits see) and
    decide whether there is a mismatch at all: a strong window in a fit channel (``strong_k``
    floors, raised with the recording's length so the false-alarm rate per analysis stays
    what it is on 12 s), significant windows with an overall normalized RMS above
    ``MISMATCH_RMS``, or a consistent bias over many samples (``bias_test``).  The torque
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
    total_s = sum(float(p.run.telemetry["t_s"][-1] - p.run.telemetry["t_s"][0]) for p in preps)
    strong_k = strong_threshold(total_s)
    strong0 = [e for e in sig_fit if e["rms"] >= strong_k * e["noise_floor"]]
    bias = bias_test(nominal, floors, fit_chans,
                     allowed=[allowed_bias(p, floors) for p in preps])
    biased = [c for c, v in bias.items() if v["significant"]]
    if biased:
        log("consistent bias: " + ", ".join(
            f"{c} {bias[c]['bias_floors']:+.2f} floors (t {bias[c]['t']:.1f} > "
            f"{bias[c]['t_threshold']:.1f}, {bias[c]['blocks']} blocks)" for c in biased))
        notes.append("a consistent bias over many samples, each below the strong-window "
                     "threshold: " + ", ".join(f"{c} {bias[c]['bias_floors']:+.2f} noise floors "
                                               f"over {bias[c]['blocks']} blocks of "
                                               f"{bias[c]['block_s']:g} s" for c in biased))
    mismatch_seen = (bool(strong0) or (bool(sig_fit) and nrms0 > MISMATCH_RMS)
                     or bool(biased))
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
    return Detection(problem, rss0, nrms0, strong_k, mismatch_seen, bias)


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
