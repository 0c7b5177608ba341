"""The time-invariance check of the selected model (fit/invariance.py): a vocabulary effect's
parameter is constant; fitted on the first and the second half of each run it agrees within the
fits' uncertainty, while a supply that sags with the charge drawn looks like a driver voltage
drop that grows over the run."""
from __future__ import annotations

from types import SimpleNamespace

import pytest
from _native_skip import needs_native

REFS = ({"kind": "line", "accel": 1.0, "cruise": 0.6},
        {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.6})


def _problem(tmp_path, effects):
    from host_tools import truth
    from host_tools.analyzer import locate, pipeline as PL
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    from host_tools.runfmt import load_run
    runs = [load_run(truth.simulate_run(tmp_path / f"run-{i}", ref, effects, clamp=True,
                                        duration_s=3.0, seed=60 + i))
            for i, ref in enumerate(REFS)]
    quiet = lambda s: None  # noqa: E731
    preps = PL._prepare(runs, quiet)
    preps, nominal, nominal_t = PL._replay_nominal(preps, OpenLoopReplay("duty"),
                                                   OpenLoopReplay("torque"))
    preps, nominal, loc = locate.locate_mismatch(preps, nominal, nominal_t,
                                                 [{} for _ in preps], quiet)
    det = locate.detect_mismatch(preps, nominal, loc, PL._vocabulary(None)[0], 5e-4, [], quiet)
    assert det.mismatch_seen
    return det.problem


@needs_native(truth=True)
@pytest.mark.parametrize("effects, drift", [
    ({"driver_voltage_drop": {"volts": 1.2}}, False),
    ({"battery_sag": {"r_int": 0.0, "v_per_as": 1.0}}, True)])
def test_a_drifting_parameter_is_told_from_a_constant_one(tmp_path, effects, drift):
    from host_tools.analyzer.fit.invariance import invariance_check
    problem = _problem(tmp_path, effects)
    names = ["driver_voltage_drop"]
    whole = problem.fit(names, list(range(len(problem.preps))))
    inv = invariance_check(problem, SimpleNamespace(effects=names, fit=whole))
    (c,) = inv.coords
    assert (c["effect"], c["param"]) == ("driver_voltage_drop", "volts")
    assert inv.drift is drift, inv.report()
    if drift:
        assert abs(c["z"]) > inv.z_threshold and c["drift"] < 0   # the drop grows with the charge
    assert problem.split_frac == 0.6     # the held-out split is left as it was
