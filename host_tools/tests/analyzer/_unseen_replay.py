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
