"""The analyzer's model.json loaded by the plant, the FIL simulator and the firmware."""
from __future__ import annotations

import json
import math

import pytest

from host_tools import _native
from host_tools import model as M
from host_tools import params


def _write(tmp_path, model):
    p = tmp_path / "model.json"
    p.write_text(json.dumps(model))
    return p


MODEL = {"format": "ddmodel/1", "robot": {"mu_s": 0.30, "mu_k": 0.28, "r": 0.036},
         "motor": {"stall_nm": 0.70}, "effects": {"motor_back_emf": {"ke_ratio": 1.2}}}


def test_plant_loads_the_model(tmp_path):
    m = M.load_model(_write(tmp_path, MODEL))
    nominal, updated = _native.Plant(), _native.Plant()
    for key, value in M.plant_keys(m).items():
        updated.set(key, value)
    assert updated.get("robot.mu_s") == pytest.approx(0.30)
    assert updated.get("motor_back_emf.ke_ratio") == pytest.approx(1.2)
    # II.51 is linear in mu_s: tau_max scales by 0.30/mu_s (r changes it a little too)
    ratio = updated.tau_max()[0] / nominal.tau_max()[0]
    assert 1.15 < ratio < 1.30
    # the back-EMF effect acts: the same duty gives a slower wheel
    t = [i * 0.01 for i in range(101)]
    u = [0.8] * len(t)
    w_nom = nominal.simulate(t, u, u, mode="duty")["dtheta_r_rad_s"][-1]
    w_upd = updated.simulate(t, u, u, mode="duty")["dtheta_r_rad_s"][-1]
    assert w_upd < w_nom - 1.0
    assert M.firmware_mu(m) == (0.30, 0.28)


@pytest.mark.parametrize("bad, needle", [
    ({"format": "ddmodel/2"}, "format"),
    ({"format": "ddmodel/1", "robot": {"mu_s": float("nan")}}, "robot.mu_s"),
    ({"format": "ddmodel/1", "effects": {"stribeck": 3}}, "effects.stribeck"),
    ({"format": "ddmodel/1", "robot": "x"}, "'robot'"),
])
def test_bad_model_files_are_named(tmp_path, bad, needle):
    p = tmp_path / "model.json"
    p.write_text(json.dumps(bad).replace("NaN", "NaN"))
    with pytest.raises(M.ModelError, match=needle) as info:
        M.load_model(p)
    assert str(p) in str(info.value)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(M.ModelError, match="no such model file"):
        M.load_model(tmp_path / "none.json")
    (tmp_path / "x.json").write_text("{")
    with pytest.raises(M.ModelError, match="not readable JSON"):
        M.load_model(tmp_path / "x.json")
    with pytest.raises(M.ModelError, match="mu_s and robot.mu_k"):
        M.firmware_mu({"format": "ddmodel/1", "robot": {}})


def test_fil_run_with_the_model(elf, sim, tmp_path):
    """The FIL plant takes the model's parameters and the firmware its mu (SetMu): the run's
    meta.json reports the firmware's mu, and fil.json the keys the plant was given."""
    from host_tools import fil

    out = tmp_path / "run"
    import argparse
    ap = argparse.ArgumentParser()
    fil.add_arguments(ap)
    args = ap.parse_args(["record", "--out", str(out), "--elf", str(elf), "--accel", "20",
                          "--duration", "1", "--model", str(_write(tmp_path, MODEL))])
    assert fil.main(args) == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta["robot"]["mu_s"] == pytest.approx(0.30, abs=1e-3)
    assert meta["robot"]["mu_k"] == pytest.approx(0.28, abs=1e-3)
    fil_json = json.loads((out / "fil.json").read_text())
    text = json.dumps(fil_json)
    assert "motor_back_emf" in text and math.isfinite(meta["robot"]["mu_s"])


def test_firmware_model_composes_the_motor_fit_with_the_datasheet():
    """SetModel's back-EMF ratio and voltage drop are relative to the datasheet motor: a model
    whose motor is already a fit (the map's motor of a run after SetModel, meta.json "motor")
    composes with its effects; the torque of the composed fit equals the model's own."""
    sheet = params.MOTOR
    S, st0, nl0 = sheet["supply_v"], sheet["stall_nm"], sheet["no_load_rad_s"]
    st_m, nl_m, k_m, d_m = 0.70, 33.0, 1.1, 0.8
    m = {"format": M.FORMAT, "robot": dict(params.ROBOT), "motor": {"supply_v": S, "stall_nm": st_m,
         "no_load_rad_s": nl_m}, "effects": {"motor_back_emf": {"ke_ratio": k_m},
                                            "driver_voltage_drop": {"volts": d_m}}}
    v = M.firmware_model(m)
    for u, w in ((0.5, 10.0), (-0.3, -20.0), (0.9, 30.0)):
        model_tau = st_m * (u * (S - d_m) / S - k_m * w / nl_m)
        fit_tau = st0 * (u * (S - v["drop_v"]) / S - v["ke_ratio"] * w / nl0)
        assert fit_tau == pytest.approx(model_tau, abs=2e-4)
    # the datasheet motor and no effects: neutral; the analyzer's folded radius and half track
    m = {"format": M.FORMAT, "robot": dict(params.ROBOT, r=0.0372, b=0.107), "motor": dict(sheet)}
    assert M.firmware_model(m) == {"r": 0.0372, "b": 0.107, "ke_ratio": 1.0, "drop_v": 0.0}
    with pytest.raises(M.ModelError, match="supply_v"):
        M.firmware_model({"motor": {"supply_v": S + 1}})
