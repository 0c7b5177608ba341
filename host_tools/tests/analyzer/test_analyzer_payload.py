"""payload (mass_kg): extra mass at the platform's centre of mass c (m_r + mass_kg, I_rz
unchanged), the convention of the truth and MuJoCo engines, fitted as a change of the nominal
plant's parameters (lib/slipmodel has no payload effect; docs/analyzer.md)."""
from __future__ import annotations

import json

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import _native, params, truth  # noqa: E402
from host_tools import model as M  # noqa: E402
from host_tools.__main__ import main as cli  # noqa: E402
from host_tools.analyzer import effects as fx  # noqa: E402

PAYLOAD = {"payload": {"mass_kg": 0.5}}
REFS = [{"kind": "line", "accel": 0.8, "cruise": 0.6},
        {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.6},
        {"kind": "figure_eight", "accel": 0.6, "cruise": 0.5, "radius": 0.5}]


def test_payload_is_a_parameter_change_of_the_nominal_plant():
    robot = dict(params.ROBOT)
    r, plant_fx = fx.plant_setup(robot, {"payload": {"mass_kg": 0.4}, "wheel_radius": {"r_eff": 0.037}})
    assert r["m_r"] == robot["m_r"] + 0.4 and r["I_rz"] == robot["I_rz"]
    assert plant_fx == {"wheel_radius": {"r_eff": 0.037}}
    heavy = _native.Plant(robot=r)
    light = _native.Plant(robot=robot)
    assert min(heavy.tau_max()) > min(light.tau_max())          # more normal force
    assert fx.physically_possible("payload", {"mass_kg": -0.1})
    assert not fx.physically_possible("payload", {"mass_kg": 0.1})


def test_payload_fitted_on_truth_engine_runs(tmp_path):
    runs = [truth.simulate_run(tmp_path / f"run{i}", ref, PAYLOAD, clamp=True, duration_s=3.0,
                               seed=70 + i) for i, ref in enumerate(REFS)]
    out = tmp_path / "out"
    assert cli(["analyze", *runs, "--out", str(out), "--jobs", "1", "--no-plots",
                "--effects", "payload"]) == 0
    rep = json.load(open(out / "report.json"))
    assert rep["verdict"] == "explained"
    sel = {s["effect"]: s["params"] for s in rep["selected"]}
    assert abs(sel["payload"]["mass_kg"] - 0.5) < 0.05
    model = json.load(open(out / "model.json"))
    assert abs(model["robot"]["m_r"] - params.ROBOT["m_r"] - sel["payload"]["mass_kg"]) < 1e-4
    keys = M.plant_keys(model)
    assert not any(k.startswith("payload.") for k in keys)   # folded into robot.m_r, not twice
    plant = _native.Plant()
    for k, v in keys.items():
        plant.set(k, v)
    assert min(plant.tau_max()) == model["tau_max_nm"]["min"]
