"""The command-to-duty delay (prepare.command_lag): a recorder whose pwm_* is the duty in force
and tau_cmd_* the controller's decision shows an actuation delay only as pwm lagging tau_cmd;
the analyzer measures that lag and selects actuation_delay with it (docs/analyzer.md)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import runfmt, truth  # noqa: E402
from host_tools.__main__ import main as cli  # noqa: E402
from host_tools.analyzer.prepare.command_lag import command_lag  # noqa: E402
from host_tools.analyzer.prepare.inputs import prepare_timed  # noqa: E402

REF = {"kind": "figure_eight", "accel": 0.6, "cruise": 0.5, "radius": 0.5}


def _run(tmp_path, name, delay_s, engine="truth", **recorder):
    fx = {"actuation_delay": {"delay_s": delay_s}} if delay_s else {}
    return truth.simulate_run(tmp_path / name, REF, fx, clamp=True, duration_s=2.0, seed=3,
                              recorder={"pwm": "in_force", **recorder}, engine=engine)


def _lag(path):
    return command_lag([prepare_timed(runfmt.load_run(path))])


@pytest.mark.parametrize("recorder", [{"controller": "cascade", "inner_s": 0.025},
                                      {"controller": "pi", "inner_s": 0.01}])
def test_null_has_no_significant_lag(tmp_path, recorder):
    lag = _lag(_run(tmp_path, "null", 0.0, **recorder))
    assert lag is not None and not lag["significant"] and lag["delay_s"] == 0.0


def test_30ms_delay_found_and_selected(tmp_path):
    path = _run(tmp_path, "d30", 0.03)
    lag = _lag(path)
    assert lag["significant"]
    assert abs(lag["delay_s"] - 0.03) <= 0.15 * 0.03
    assert abs(lag["delay_s"] - 0.03) <= 2 * lag["std_s"]
    out = tmp_path / "out"
    assert cli(["analyze", path, "--out", str(out), "--jobs", "1", "--no-plots"]) == 0
    rep = json.load(open(out / "report.json"))
    sel = {s["effect"]: s for s in rep["selected"]}
    assert rep["verdict"] == "explained"
    assert abs(sel["actuation_delay"]["params"]["delay_s"] - 0.03) <= 0.15 * 0.03
    assert any("lags the torque command" in n for n in rep["notes"])
    assert json.load(open(out / "model.json"))["effects"]["actuation_delay"]["delay_s"] > 0


def test_mujoco_engine_reports_its_delayed_duty_in_force(tmp_path):
    """The recorder's in-force duty follows the MuJoCo plant's own actuation delay (the effect
    lives in the engine, not in sim/truth's drive)."""
    pytest.importorskip("mujoco")
    runs = {d: runfmt.load_run(truth.simulate_run(
        tmp_path / f"mj{d}", REF, {"actuation_delay": {"delay_s": 0.03}}, clamp=True,
        duration_s=1.0, seed=5, engine="mujoco",
        recorder={"pwm": d, "tel_s": 0.005, "current": False})).telemetry
        for d in ("commanded", "in_force")}
    cmd, force = runs["commanded"]["pwm_r"], runs["in_force"]["pwm_r"]
    assert np.array_equal(force[6:], cmd[:-6])   # 30 ms in 5 ms frames
