"""Stage 6 of the analysis: the report's sections (the :class:`Analysis` that the writers turn
into report.json and report.md)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from host_tools import runfmt
from host_tools.analyzer import signals as sg
from host_tools.analyzer.fit.judge import (HELDOUT_RULE, Candidate, heldout_channel_check,
                                           heldout_method)
from host_tools.analyzer.locate.mismatch import Detection, Located
from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import DERIVED, Channel
from host_tools.analyzer.replay.closedloop import CLOSED_LOOP_CHANNELS, closed_loop_channels
from host_tools.analyzer.replay.nominal import NominalClosedLoop, replay_channels
from host_tools.analyzer.select import excess, Selection
from host_tools.analyzer.signals import round_sig

if TYPE_CHECKING:
    from host_tools.analyzer.replay.openloop import OpenLoopReplay


REPORT_FORMAT = "mismatch-report/1"


def _pooled_rmse(chans_per_run: Sequence[Mapping[str, Channel]], names: Sequence[str]
                 ) -> dict[str, float]:
    out = {}
    for c in names:
        r = [ch[c].resid for ch in chans_per_run if ch and c in ch]
        if r and sum(x.size for x in r):
            out[c] = float(np.sqrt(np.mean(np.concatenate(r) ** 2)))
    return out


@dataclass
class Analysis:
    runs: list[runfmt.Run]
    preps: list[PreparedRun]
    floors: dict[str, float]
    nominal: list[dict[str, Channel]]   # per run: channel -> Channel (duty replay)
    nominal_torque: list[dict[str, Channel]]  # per run: channel -> Channel (torque replay)
    updated: list[dict[str, Channel]] | None
    mismatch: list[dict[str, Any]]
    candidates: list[Candidate]
    selected: list[dict[str, Any]]
    verdict: str
    fit_table: dict[str, Any]
    hint: dict[str, Any] | None
    model: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    torque_mismatch: list[dict[str, Any]] = field(default_factory=list)
    windows: dict[tuple[int, str], list[sg.Window]] = field(default_factory=dict)
    timing_s: float = 0.0
    closed_loop: dict[str, Any] = field(default_factory=dict)  # report section (docs/analyzer.md)
    cl_nominal: list[dict[str, Channel]] = field(default_factory=list)  # per run, or {}
    cl_updated: list[dict[str, Channel]] = field(default_factory=list)
    recorder: dict[str, Any] = field(default_factory=dict)     # findings about the recorder
    localization: list[dict[str, Any]] = field(default_factory=list)  # where the mismatch is


def replay_updated(preps: Sequence[PreparedRun], duty: OpenLoopReplay, cl: NominalClosedLoop,
                   final_effects: Mapping[str, Mapping[str, float]]
                   ) -> tuple[list[dict[str, Channel]] | None, list[dict[str, Channel]]]:
    """The replays with the selected effects that the report compares with the nominal ones:
    the duty replay (None without an update) and the closed loop (a run without an update, or
    not replayed, keeps its nominal channels)."""
    updated = None
    if final_effects:
        updated = [replay_channels(p, duty, final_effects) for p in preps]
    cl_updated = [closed_loop_channels(p, cl.replay.simulate(p, final_effects, cl.setups[i]))
                  if (final_effects and cl.setups[i] is not None) else cl.nominal[i]
                  for i, p in enumerate(preps)]
    return updated, cl_updated


def closed_loop_report(cl: NominalClosedLoop, cl_updated: Sequence[Mapping[str, Channel]],
                       loc: Located, final_effects: Mapping[str, Mapping[str, float]]
                       ) -> dict[str, Any]:
    """The report's closed-loop section (see docs/analyzer.md): per run whether it was replayed
    and on which assumptions, the controller-output errors before and after the update, in
    their units and in noise floors, and the closed loop's significant windows.  Reported, not
    used for decisions (``used_for_decisions``)."""
    cl_floors = loc.cl_floors
    cl_b = _pooled_rmse(cl.nominal, CLOSED_LOOP_CHANNELS)
    cl_a = _pooled_rmse(cl_updated, CLOSED_LOOP_CHANNELS)

    def _nrms(chs: Sequence[Mapping[str, Channel]]) -> float | None:
        r = [ch[c].resid / cl_floors[c] for ch in chs if ch for c in cl_floors if c in ch]
        return round_sig(float(np.sqrt(np.mean(np.concatenate(r) ** 2)))) if r else None

    return {
        "replay": "lib/control fixed-point cascade (ctl_* C ABI) against the lib/slipmodel "
                  "plant, firmware schedule, encoder counts quantised from the plant",
        "runs": cl.runs, "channels": list(cl_b),
        "noise_floor": {c: round_sig(v) for c, v in cl_floors.items()},
        "rmse_nominal": {c: round_sig(v) for c, v in cl_b.items()},
        "rmse_updated": {c: round_sig(v) for c, v in cl_a.items()},
        "normalized_rms_nominal": _nrms(cl.nominal),
        "normalized_rms_updated": _nrms(cl_updated),
        "updated_effects": {k: dict(v) for k, v in final_effects.items()},
        "mismatch": loc.cl_entries,
        "used_for_decisions": False}


def error_tables(det: Detection, sel: Selection, floors: Mapping[str, float],
                 closed_loop: Mapping[str, Any]) -> dict[str, Any]:
    """The report's error tables: RMSE per channel before and after the update on the fitting
    data and on the held-out parts (``fit.judge.heldout_folds``: runs left out, or a time split
    of a single run) with the held-out rule's per-channel check, the noise floors, and the
    normalized RMS before and after; the closed-loop channels' rows come from the closed-loop
    section.  Without an update the errors after are the errors before."""
    problem, final_effects = det.problem, sel.effects
    runs_idx = list(range(len(problem.preps)))
    rb = problem.channel_rmse({}, runs_idx, full=True)
    ra = problem.channel_rmse(final_effects, runs_idx, full=True) if final_effects else dict(rb)
    hpairs = hspread = None
    if sel.chosen is not None:
        hb, ha = sel.chosen.heldout_channels_before, sel.chosen.heldout_channels_after
        hpairs, hspread = sel.chosen.heldout_pairs, sel.chosen.heldout_spread
    else:
        # no update: held-out error equals the nominal one on the held-out parts
        c0 = sel.singles[0] if sel.singles else None
        hb = c0.heldout_channels_before if c0 else dict(rb)
        ha = dict(hb)
    fit_table: dict[str, Any] = {"rmse_before": {k: round_sig(v) for k, v in rb.items()},
                 "rmse_after": {k: round_sig(v) for k, v in ra.items()},
                 "heldout_rmse_before": {k: round_sig(v) for k, v in hb.items()},
                 "heldout_rmse_after": {k: round_sig(v) for k, v in ha.items()},
                 "heldout_method": heldout_method(len(runs_idx), problem.split_frac),
                 "noise_floor": {k: round_sig(v) for k, v in floors.items()},
                 "heldout_rule": HELDOUT_RULE,
                 "heldout_check": {k: {q: (round_sig(x) if isinstance(x, float) and q != "ok"
                                           else x)
                                       for q, x in v.items()}
                                   for k, v in heldout_channel_check(hb, ha, floors,
                                                                     hpairs, hspread).items()},
                 "derived_channels": list(DERIVED),
                 "normalized_rms_before": round_sig(det.nrms0),
                 "normalized_rms_after": round_sig(math.sqrt(excess(problem, final_effects)))}
    for c in closed_loop["channels"]:
        fit_table["rmse_before"][c] = closed_loop["rmse_nominal"][c]
        fit_table["rmse_after"][c] = closed_loop["rmse_updated"][c]
        fit_table["noise_floor"][c] = closed_loop["noise_floor"][c]
    return fit_table


def recorder_findings(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, Channel]],
                      floors: Mapping[str, float], notes: list[str]) -> dict[str, Any]:
    """What the recording says about its recorder (not about the physics): how its odometry
    columns relate to its own counts (replay.recorder_odometry), and whether the derived
    odometry channels disagree with the replay while the counts agree."""
    runs = []
    for prep, chans in zip(preps, nominal):
        rec = dict(prep.recorder_odometry or {})
        entry = {"run": prep.name, "odometry_schedule": rec.get("schedule"),
                 "odometry_matches_lib_control": rec.get("agrees"),
                 "odometry_vs_lib_control": {k: {q: round_sig(v) for q, v in d.items()}
                                             for k, d in rec.get("by_schedule", {}).items()},
                 "input_timing": prep.timing}
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


def localize(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, Channel]],
             updated: Sequence[Mapping[str, Channel]] | None, floors: Mapping[str, float],
             fit_chans: Sequence[str], strong_k: float, merge_s: float = 0.5
             ) -> list[dict[str, Any]]:
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
        merged: list[list[Any]] = []
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
                        "peak_noise_floors": round_sig(pk), "channels": sorted(cs),
                        "strong": bool(pk >= strong_k),
                        "rms_after_update_noise_floors":
                            None if after is None else round_sig(after)})
    return out
