"""The duty replay of a run whose unreported ticks were filled, beside the same replay from the
commands the controller really gave, for tests of the replay's uncertainty from unreported
commands (replay/unseen.py)."""
from __future__ import annotations

import dataclasses


def filled_and_given(prep, given):
    """(channels replayed from the fill, with the replay's uncertainty from unreported commands
    attached; channels replayed from ``given``, the commands at every tick)."""
    from host_tools.analyzer.replay import channels as CH
    from host_tools.analyzer.replay import openloop as OL
    from host_tools.analyzer.replay import unseen as UN
    duty = OL.OpenLoopReplay("duty")
    unc = UN.input_uncertainty(prep, duty)
    assert unc
    p = dataclasses.replace(prep, replay_unc=unc)
    filled = CH.channels(p, duty.simulate_windows(p, {}), "duty")
    p_true = dataclasses.replace(p, duty=given)
    return filled, CH.channels(p_true, duty.simulate_windows(p_true, {}), "duty")


def line_seen_slowly(d, line, seed: int, inner_s: float, tel_s: float):
    """(prepared run, the commands the controller gave at its ticks, the closed-loop replay) of
    the truth simulator's clamped ``line`` under an ``inner_s`` loop seen every ``tel_s``: the
    same run recorded with a frame at every tick gives the unreported ticks' commands (the
    simulator's controller and physics do not depend on the telemetry period)."""
    from host_tools import truth
    from host_tools.analyzer.prepare import inputs as PI
    from host_tools.analyzer.replay import closedloop as CL
    from host_tools.runfmt import load_run
    from test_analyzer_unseen_phase import given_commands
    rec = {"inner_s": inner_s, "tel_s": tel_s}
    run = load_run(truth.simulate_run(d / "run", line, None, clamp=True, duration_s=2.0,
                                      seed=seed, recorder=rec))
    full = load_run(truth.simulate_run(d / "full", line, None, clamp=True, duration_s=2.0,
                                       seed=seed, recorder=dict(rec, tel_s=inner_s)))
    prep = PI.prepare_timed(run)
    return prep, given_commands(prep, full, inner_s), CL.ClosedLoopReplay().simulate(prep, {})
