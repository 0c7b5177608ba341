"""Stage 2 of the analysis, over all runs at once: the nominal replays (no effect).  The closed
loop comes first (:func:`replay_closed_loop`): it refines the inputs that the open-loop replays
are driven by.  The open-loop replays (:func:`replay_open_loop`), driven by the recorded duty
and by the recorded torque command, follow, with the windows moved out of slips and the
replay's own uncertainty drawn."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.edges import edges_outside_slip
from host_tools.analyzer.replay.channels import Channel, channels
from host_tools.analyzer.replay.closedloop import ClosedLoopReplay, closed_loop_channels
from host_tools.analyzer.replay.openloop import OpenLoopReplay
from host_tools.analyzer.replay.tolerance import tolerance_uncertainty
from host_tools.analyzer.replay.unseen import (count_gains, fill_count_level, fill_unseen_from_controller,
                                               input_uncertainty)


@dataclass
class NominalClosedLoop:
    """The nominal closed-loop replay, per run."""
    replay: ClosedLoopReplay
    setups: list[dict[str, Any] | None]  # the replay's set-up (reference, clamp, schedule)
    runs: list[dict[str, Any]]  # the report's entry: replayed, problems, assumptions, reference
    nominal: list[dict[str, Channel]]  # channel -> Channel of the nominal replay, or {}


@dataclass
class NominalOpenLoop:
    """The nominal open-loop replays, per run."""
    duty: OpenLoopReplay  # the duty-driven replayer (it locates, decides and fits)
    preps: list[PreparedRun]  # with the windows out of slips and the replay's uncertainty
    nominal: list[dict[str, Channel]]  # channel -> Channel of the duty replay
    nominal_t: list[dict[str, Channel]]  # ... of the torque replay


def replay_closed_loop(preps: Sequence[PreparedRun], dt_s: float, notes: list[str],
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
    gains = count_gains(filled)
    for i, p in enumerate(filled):
        if gains[i] is not None:
            p = dataclasses.replace(p, count_gains=gains[i])
        filled[i], n_lvl = fill_count_level(p)
        if n_lvl:
            runs[i]["assumptions"].append(
                f"{n_lvl} inner ticks were reported by no frame: their commands are the line "
                "between the reported ones with the reported ticks' count quantization taken out")
    n_cl = sum(1 for c in nominal if c)
    if n_cl:
        log(f"closed-loop replay through lib/control: {n_cl}/{len(preps)} run(s)")
    return filled, NominalClosedLoop(clr, setups, runs, nominal)


def replay_open_loop(preps: Sequence[PreparedRun], dt_s: float) -> NominalOpenLoop:
    """The nominal open-loop replays (no effect), per run: channel -> Channel, driven by the
    recorded duty (what locates the mismatch and decides) and by the recorded torque command
    (reported apart: it separates motor and driver from the rest).  On a run of several
    windows the duty replay's slip episodes are noted first and the window edges moved out
    of them, with a cut after each (``edges_outside_slip``): a window cannot start from the
    recorded state inside a slip, the window anchors to the camera are fitted within the
    slip-free spans, and ``locate`` takes the slips as no evidence.  The replay's own
    uncertainty (unreported commands, the model's tolerance) is drawn before the channels are
    compared, and the prepared runs returned carry it (``replay_unc``, ``tolerance_bias``,
    ``tolerance_draw_means``) for every later replay and decision.  Each step is taken for
    every run before the next (each run's draws are seeded by its own content)."""
    duty = OpenLoopReplay("duty", dt_s=dt_s)
    torque = OpenLoopReplay("torque", dt_s=dt_s)
    out = [edges_outside_slip(p, duty)[0] if len(p.windows) > 1 else p for p in preps]
    uncs = [input_uncertainty(p, duty) for p in out]
    out = [p if unc is None else dataclasses.replace(p, replay_unc=unc)
           for p, unc in zip(out, uncs)]
    tols = [tolerance_uncertainty(p, duty) for p in out]
    out = [p if tol is None else
           dataclasses.replace(p, replay_unc=tol.replay_unc, tolerance_bias=tol.tolerance_bias,
                               tolerance_draw_means=tol.tolerance_draw_means)
           for p, tol in zip(out, tols)]
    nominal = [replay_channels(p, duty, {}) for p in out]
    nominal_t = [replay_channels(p, torque, {}) for p in out]
    return NominalOpenLoop(duty, out, nominal, nominal_t)


def replay_channels(prep: PreparedRun, replay: OpenLoopReplay,
                    effects: Mapping[str, Mapping[str, float]]) -> dict[str, Channel]:
    """The channels of ``prep`` replayed open loop by ``replay`` with ``effects``."""
    return channels(prep, replay.simulate_windows(prep, effects), replay.mode)
