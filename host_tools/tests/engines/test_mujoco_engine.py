"""The MuJoCo engine (host_tools/engines/mujoco_robot.py) under sim/truth's recorder: the model
is the parameter table's, it agrees with lib/slipmodel where both make the same assumptions
(tolerances from the validation figures in docs/suite.md), the friction switches by slip
state, every effect acts, and its run folders cannot be told from the truth engine's."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")

from host_tools import params, truth  # noqa: E402
from host_tools.engines import mujoco_robot as mr, validate  # noqa: E402

ROBOT, MOTOR = params.ROBOT, params.MOTOR
SC = {s.name: s for s in validate.SCENARIOS}


def _body(p, name):
    import mujoco
    return mujoco.mj_name2id(p.model, mujoco.mjtObj.mjOBJ_BODY, name)


def test_model_is_built_from_the_table():
    p = mr.MujocoRobot()
    m = p.model
    ch, wr, wl = _body(p, "chassis"), _body(p, "wheel_r"), _body(p, "wheel_l")
    assert m.body_mass[ch] == pytest.approx(ROBOT["m_r"])
    assert m.body_inertia[ch][2] == pytest.approx(ROBOT["I_rz"])
    assert m.body_ipos[ch] == pytest.approx([ROBOT["d"], 0.0, ROBOT["h"] - ROBOT["r"]])
    for w, side in ((wr, -1), (wl, 1)):
        assert m.body_mass[w] == pytest.approx(ROBOT["m_w"])
        assert m.body_pos[w] == pytest.approx([0.0, side * ROBOT["b"], 0.0])
        # spin inertia: the wheel body's plus the hinge's armature (rotor through the gear)
        dof = m.jnt_dofadr[m.body_jntadr[w]]
        assert m.body_inertia[w][1] + m.dof_armature[dof] == pytest.approx(ROBOT["I_wy"])
        assert m.body_inertia[w][2] == pytest.approx(ROBOT["I_wz"])
    assert m.geom_size[p._gid[0]][0] == pytest.approx(ROBOT["r"])
    # at rest the contacts carry the weight: the caster m_r g d/(d+e), the wheels the rest
    n_r, n_l, n_c = p.normal_forces()
    weight = (ROBOT["m_r"] + 2 * ROBOT["m_w"]) * ROBOT["g"]
    assert n_r + n_l + n_c == pytest.approx(weight, rel=1e-3)
    assert n_c == pytest.approx(ROBOT["m_r"] * ROBOT["g"] * ROBOT["d"] / (ROBOT["d"] + ROBOT["e"]),
                                rel=0.01)
    # payload: extra mass at c, I_rz unchanged; lumped: the thesis's mass distribution
    q = mr.MujocoRobot({"payload": {"mass_kg": 0.4}})
    assert q.model.body_mass[ch] == pytest.approx(ROBOT["m_r"] + 0.4)
    assert q.model.body_inertia[ch][2] == pytest.approx(ROBOT["I_rz"])
    lm = mr.MujocoRobot(lumped=True)
    assert lm.model.body_mass[ch] == pytest.approx(ROBOT["m_r"] + 2 * ROBOT["m_w"])
    assert lm.model.body_inertia[ch][2] == pytest.approx(
        ROBOT["I_rz"] + 2 * ROBOT["m_w"] * ROBOT["b"] ** 2)
    with pytest.raises(ValueError, match="unknown effect"):
        mr.MujocoRobot({"flux_capacitor": {}})
    with pytest.raises(ValueError, match="has no parameter"):
        mr.MujocoRobot({"payload": {"kg": 1}})


# Tolerances: the validation figures (docs/suite.md, python -m host_tools.engines.validate)
# rounded up to the next step of 1-2-5, so that a change of the engine's physics shows.
def test_rolling_agrees_with_slipmodel_with_the_same_assumptions():
    """Open loop, the same duties: the arc (figures 1.7 mm, 0.3 mrad, 0.002 rad/s) and the
    closed loop on the arc (1.7 mm, 0.2 mrad, 0.035 rad/s); the physical model's open loop on
    the arc turns 23.6 mrad further."""
    ol = validate.open_loop(SC["arc"], "matched")
    f = validate._figures(ol["slipmodel"], ol["mujoco"])
    assert f["end_mm"] < 2.0 and f["phi_mrad"] < 0.5 and f["w_rms"] < 0.005
    assert math.isnan(f["onset_s"])
    cl = validate.closed_loop(SC["arc"], "matched")
    f = validate._figures(cl["slipmodel"], cl["mujoco"])
    assert f["end_mm"] < 2.0 and f["phi_mrad"] < 0.5 and f["w_rms"] < 0.05
    # the physical mass distribution (wheels on their axles) turns the arc differently open loop
    ol = validate.open_loop(SC["arc"], "physical")
    f = validate._figures(ol["slipmodel"], ol["mujoco"])
    assert f["phi_mrad"] > 10.0


def test_slipping_null_slips_like_slipmodel():
    """72 rad/s^2 with the clamp off: both slip from the start (onset 0.004 s against 0.001 s
    at the 2 ms telemetry); sliding all run long, MuJoCo ends 67.8 mm away (wheel-speed RMS
    0.310 rad/s) with the physical mass distribution, 23.5 mm (0.116 rad/s) matched."""
    for config, end_mm, w_rms in (("physical", 100.0, 0.5), ("matched", 50.0, 0.2)):
        cl = validate.closed_loop(SC["straight_72"], config)
        f = validate._figures(cl["slipmodel"], cl["mujoco"])
        assert f["onset_s"] - cl["slipmodel"]["onset_fine"] < 0.005
        assert f["end_mm"] < end_mm and f["w_rms"] < w_rms, (config, f)


def _open(effects=None, u=(0.3, 0.3), T=0.6, **kw):
    p = mr.MujocoRobot(effects, **kw)
    n = int(round(T / p.dt))
    for i in range(n):
        p.step(i * p.dt, *u)
    return p


def test_friction_switches_between_mu_s_and_mu_k_by_slip_state():
    eff = {"friction_coefficient": {"mu_s": 0.3, "mu_k": 0.15}}
    p = _open(eff, u=(0.05, 0.05))  # gentle: sticks, coefficient mu_s
    assert p.sliding == [False, False] and max(p.slip_speed) < mr.SLIP_ON_M_S
    assert p.model.geom_friction[p._gid[0], 0] == pytest.approx(0.3)
    p = _open(eff, u=(1.0, 1.0), T=0.3)  # full duty: slides, coefficient mu_k
    assert p.sliding == [True, True]
    x0, v0 = p.data.qpos[0], p.data.qvel[0]
    n = 200
    for i in range(n):
        p.step(0.3 + i * p.dt, 1.0, 1.0)
    assert p.model.geom_friction[p._gid[0], 0] == pytest.approx(0.15)
    # while both wheels slide, traction is mu_k times the wheels' load: the robot accelerates
    # at about mu_k g N_wheels / W (the load transfer and the hopping of the soft contacts
    # while sliding make it approximate)
    a = (p.data.qvel[0] - v0) / (n * p.dt)
    m_t = ROBOT["m_r"] + 2 * ROBOT["m_w"]
    n_w = m_t * ROBOT["g"] - ROBOT["m_r"] * ROBOT["g"] * ROBOT["d"] / (ROBOT["d"] + ROBOT["e"])
    assert a == pytest.approx(0.15 * n_w / m_t, rel=0.15)
    assert p.data.qpos[0] > x0


@pytest.mark.parametrize("effect,params,check", [
    ("payload", {"mass_kg": 0.5}, lambda p, q: q.data.qpos[0] < p.data.qpos[0]),
    ("axle_viscous", {"c": 0.003}, lambda p, q: q.data.qvel[6] < p.data.qvel[6] - 0.5),
    ("axle_coulomb", {"torque": 0.03}, lambda p, q: q.data.qvel[6] < p.data.qvel[6] - 0.5),
    ("motor_back_emf", {"ke_ratio": 1.2}, lambda p, q: q.data.qvel[6] < p.data.qvel[6] - 0.5),
    ("driver_voltage_drop", {"volts": 1.5}, lambda p, q: q.data.qvel[6] < p.data.qvel[6] - 0.5),
    ("deadband", {"volts": 1.0}, lambda p, q: q.data.qvel[6] < p.data.qvel[6] - 0.5),
    # torque and current retarded: 50 ms into the run
    ("motor_lag", {"tau_s": 0.1}, lambda p, q: q.tau[0] < 0.8 * p.tau[0] and q.i2[0] < 0.8 * p.i2[0]),
    ("actuation_delay", {"delay_s": 0.1}, lambda p, q: abs(q.tau[0]) < 1e-6 < p.tau[0]),
    ("floor_slope", {"rad": 0.05}, lambda p, q: q.data.qpos[0] < p.data.qpos[0] - 1e-3),
    ("wheel_radius", {"r_eff": 0.0385}, lambda p, q: q.data.qpos[0] > p.data.qpos[0]),
    ("track_width", {"b_eff": 0.12}, lambda p, q: abs(q.phi) < abs(p.phi) - 1e-3),
    ("motor_gain_asymmetry", {"ratio": 1.2}, lambda p, q: q.phi > p.phi + 1e-3),
    ("caster_drag", {"mu": 0.1}, lambda p, q: q.data.qpos[0] < p.data.qpos[0] - 1e-3),
    ("battery_sag", {"r_int": 2.0, "v_per_as": 1.0}, lambda p, q: q.v_batt < p.v_batt - 0.1),
    ("eccentric_wheel", {"eps": 0.05}, lambda p, q: abs(q.phi - p.phi) > 1e-3),
    ("friction_patch", {"x0": -1.0, "x1": 1.0, "factor": 0.2}, lambda p, q: q.sliding[0]),
])
def test_every_effect_acts(effect, params, check):
    u = (0.35, 0.25)  # a turn, so that the yaw effects show
    T = 0.05 if effect in ("motor_lag", "actuation_delay") else 0.6
    p = _open(None, u=u, T=T)
    q = _open({effect: params}, u=u, T=T)
    assert check(p, q), effect


def test_inductance_delays_the_current():
    p = mr.MujocoRobot(inductance_h=0.01)
    L_over_R = 0.01 / (MOTOR["supply_v"] / mr._table()[1]["stall_a"])
    n = int(round(L_over_R / p.dt))
    for i in range(n):
        p.step(i * p.dt, 0.3, 0.3)
    q = mr.MujocoRobot()
    for i in range(n):
        q.step(i * q.dt, 0.3, 0.3)
    # after one electrical time constant: about 1 - 1/e of the current without inductance
    assert p.i2[0] / q.i2[0] == pytest.approx(1 - math.exp(-1), abs=0.08)


def test_run_folders_cannot_be_told_apart(tmp_path):
    ref = {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.5}
    rec = {"inner_s": 0.010, "tel_drop": 0.02}
    runs = {}
    for engine in ("truth", "mujoco"):
        runs[engine] = truth.simulate_run(tmp_path / engine, ref, {"payload": {"mass_kg": 0.3}},
                                          duration_s=1.5, seed=4, recorder=rec, engine=engine,
                                          hidden_dir=tmp_path / f"h_{engine}")
    a, b = runs["truth"], runs["mujoco"]
    assert sorted(os.listdir(a)) == sorted(os.listdir(b))
    assert open(os.path.join(a, "meta.json")).read() == open(os.path.join(b, "meta.json")).read()
    for f in ("telemetry.csv", "groundtruth.csv"):
        ta, tb = (np.genfromtxt(os.path.join(x, f), delimiter=",", names=True) for x in (a, b))
        assert ta.dtype.names == tb.dtype.names
        assert np.array_equal(ta["t_s"], tb["t_s"])  # same clocks, frames lost alike
    ta, tb = (np.genfromtxt(os.path.join(x, "telemetry.csv"), delimiter=",", names=True)
              for x in (a, b))
    # both robots drive the arc: the encoders agree to a few percent
    assert abs(ta["enc_r"][-1] - tb["enc_r"][-1]) < 0.03 * abs(ta["enc_r"][-1])
    meta = json.load(open(os.path.join(b, "meta.json")))
    assert "mujoco" not in json.dumps(meta).lower() and "engine" not in meta


def test_engine_errors_are_reported():
    with pytest.raises(ValueError, match="engine must be one of"):
        truth.simulate_run("/nonexistent/x", {"kind": "line"}, engine="bullet")
    sim = truth.TruthSim()
    p = mr.MujocoRobot()
    sim.set_plant(p)
    sim.set("sim.dt", 5e-4)  # not the engine's step
    sim.set("sim.duration", 0.1)
    with pytest.raises(ValueError, match="external plant failed.*the recorder steps"):
        sim.run()
    sim.set_plant(None)  # back to the truth's own physics
    tel, _ = sim.run()
    assert tel["t_s"].size > 0


def test_mujoco_is_imported_only_by_the_engine():
    code = ("import sys, host_tools.truth, host_tools.suite.cases, host_tools.suite.generate, "
            "host_tools.engines.mujoco_robot, host_tools.engines.validate; "
            "print('mujoco' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
