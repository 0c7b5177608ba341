"""The nominal model's normal forces (replay/normal_forces.py: the wheels' mass on the axle, the
transfer at Table II.2's h plus the spin-up's rolling height k^ h_s) and what it can only guess
of them as its own tolerance (replay/tolerance.py ``left_out_normal_forces``,
``ensemble_draws``; the size test's ``left_out`` ranges, fit/judge.py SIZE_RULE): where the
wheels' mass sits, the centre of mass's height and the spin-up's share are drawn about the
nominal model in the replay's tolerance ensemble, and a fitted friction shift or load-transfer
height within them, either way, is no evidence, while a load transfer beyond them still
shows."""
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from host_tools import params as P


def _at_rest(robot: dict[str, float], effects: dict[str, dict[str, float]] | None = None
             ) -> dict[str, np.ndarray]:
    from host_tools import _native
    pl = _native.Plant(robot=robot)
    for name, ps in (effects or {}).items():
        pl.set_effect(name, **ps)
    t = np.arange(0.0, 0.01, 0.001)
    z = np.zeros_like(t)
    return pl.simulate(t, z, z, mode="duty")


def test_the_nominal_plant_has_the_wheels_on_the_axle_and_the_transfer_at_the_tables_h() -> None:
    """The nominal model's plant (replay/normal_forces.py ``plant_config``): the wheels' mass on
    the axle, so at rest the caster carries m_r g d / (d + e) (II.29 with the whole mass at c
    would give m_t g d / (d + e)) and each wheel 2 m_w d / (m_t e) more than II.29's; the
    ``load_transfer`` effect at Table II.2's h plus k^ h_s (k^ params.json's model.spin_share,
    h_s = 2 I_wy / (m_t r)) with the plant's own spin term off; a candidate's h replaces the
    table's, and a payload is mass at the platform's c, before the split."""
    from host_tools.analyzer.replay.normal_forces import (NOMINAL, SPIN_SHARE, plant_config,
                                                          spin_height, wheels_on_axle)
    R = dict(P.ROBOT)
    m_t = R["m_r"] + 2 * R["m_w"]
    assert SPIN_SHARE == P.MODEL["spin_share"]
    cfg = plant_config(R, {})
    assert cfg.keys == {"plant.spin_share": 0.0}
    nom = _at_rest(cfg.robot, cfg.effects)
    planar = _at_rest(R)
    assert math.isclose(float(nom["N_c"][-1]), R["m_r"] * R["g"] * R["d"] / (R["d"] + R["e"]),
                        rel_tol=1e-9)
    assert math.isclose(float(planar["N_c"][-1]), m_t * R["g"] * R["d"] / (R["d"] + R["e"]),
                        rel_tol=1e-9)
    x = float(nom["N_r"][-1]) / float(planar["N_r"][-1]) - 1.0
    assert math.isclose(x, 2 * R["m_w"] * R["d"] / (m_t * R["e"]), rel_tol=1e-9)
    h_s = 2 * R["I_wy"] / (m_t * R["r"])
    assert math.isclose(spin_height(R), h_s, rel_tol=1e-12)
    assert math.isclose(cfg.effects["load_transfer"]["h"], R["h"] + SPIN_SHARE * h_s, rel_tol=1e-12)
    assert cfg.robot == {**R, **wheels_on_axle(R, 1.0)} and NOMINAL.share == 1.0
    cand = plant_config(R, {"load_transfer": {"h": 0.09}})
    assert math.isclose(cand.effects["load_transfer"]["h"], 0.09 + SPIN_SHARE * h_s, rel_tol=1e-12)
    # a payload at the platform's c: the caster's m_r + mass_kg share at rest, and h_s of the
    # heavier robot
    pay = plant_config(R, {"payload": {"mass_kg": 0.4}})
    heavy = {**R, "m_r": R["m_r"] + 0.4}
    assert math.isclose(float(_at_rest(pay.robot, pay.effects)["N_c"][-1]),
                        heavy["m_r"] * R["g"] * R["d"] / (R["d"] + R["e"]), rel_tol=1e-9)
    assert math.isclose(pay.effects["load_transfer"]["h"],
                        R["h"] + SPIN_SHARE * spin_height(heavy), rel_tol=1e-12)
    # the wheels' split: share 0 is the planar II.29, the caster stays where it is, the yaw
    # inertia about the new centre of mass grows by the masses' parallel-axis terms
    assert wheels_on_axle(R, 0.0) == {"d": R["d"], "e": R["e"], "I_rz": R["I_rz"]}
    w = wheels_on_axle(R, 1.0)
    assert math.isclose(w["d"] + w["e"], R["d"] + R["e"], rel_tol=1e-12)
    d_c = w["d"]
    assert math.isclose(d_c, R["m_r"] * R["d"] / m_t, rel_tol=1e-12)
    assert math.isclose(w["I_rz"], R["I_rz"] + R["m_r"] * (R["d"] - d_c) ** 2
                        + 2 * R["m_w"] * d_c ** 2, rel_tol=1e-12)


def test_every_replay_of_the_nominal_model_is_built_with_its_normal_forces(tmp_path: Path
                                                                           ) -> None:
    """The open-loop replays (duty and torque) and the closed-loop replay build their plants
    with ``plant_config``: the wheels on the axle, the transfer at h + k^ h_s, the plant's own
    spin term off."""
    from host_tools.analyzer import pipeline as PL
    from host_tools.analyzer import synth
    from host_tools.analyzer.prepare.inputs import prepare_runs
    from host_tools.analyzer.replay import closedloop
    from host_tools.analyzer.replay.normal_forces import plant_config
    from host_tools.analyzer.replay.openloop import OpenLoopReplay
    paths = synth.make_case(tmp_path / "c", None, profiles=("ramp",), seed=1, duration_s=0.5)
    prep = prepare_runs(PL._load_runs(paths, lambda m: None), lambda m: None)[0]
    want = plant_config(prep.robot, {"load_transfer": {"h": 0.05}})
    for mode in ("duty", "torque"):
        plant = OpenLoopReplay(mode)._ready(prep, {"load_transfer": {"h": 0.05}})[0]
        assert math.isclose(plant.get("robot.d"), want.robot["d"], rel_tol=1e-12)
        assert math.isclose(plant.get("load_transfer.h"), want.effects["load_transfer"]["h"],
                            rel_tol=1e-12)
        assert plant.get("plant.spin_share") == 0.0
    seen = []
    real = closedloop.plant_config

    def spy(*a: Any, **k: Any) -> Any:
        seen.append(a)
        return real(*a, **k)
    closedloop.plant_config = spy  # type: ignore[assignment]
    try:
        rep = closedloop.ClosedLoopReplay()
        setup = {"kind": "line", "accel": 0.5, "cruise": 0.3, "radius": 1.0, "clamp": True,
                 "drive": None, "t0_s": 0.0, "inner_s": 0.025, "outer_every": 2, "controller": 0}
        rep.simulate(prep, {}, setup)
    finally:
        closedloop.plant_config = real  # type: ignore[assignment]
    assert len(seen) == 1


def test_the_left_out_ranges_hold_the_nominal_model_inside() -> None:
    """Each part's range of the fitted friction coefficient holds the nominal model (0) inside:
    the planar robot's wheels carry x / (1 + x) less, x = 2 m_w d / (m_t e); a centre of mass
    from the ground to h + tol_h moves the slip onset by mu (H - h) / (d + e); a spin share
    from 0 to 1 against k^ by mu (k - k^) h_s / (d + e)."""
    from host_tools.analyzer.replay.normal_forces import SPIN_SHARE
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    R = dict(P.ROBOT)
    m_t = R["m_r"] + 2 * R["m_w"]
    lo = left_out_normal_forces(R)
    x = 2 * R["m_w"] * R["d"] / (m_t * R["e"])
    c = R["mu_s"] / (R["d"] + R["e"])
    h_max = R["h"] + P.TOLERANCES[("robot", "h")]
    assert math.isclose(lo.wheel_shift_m, 2 * R["m_w"] * R["d"] / m_t, rel_tol=1e-12)
    assert math.isclose(lo.mu_ranges[0][0], -x / (1 + x), rel_tol=1e-12) and lo.mu_ranges[0][1] == 0
    assert math.isclose(lo.mu_ranges[1][0], -c * R["h"], rel_tol=1e-12)
    assert math.isclose(lo.mu_ranges[1][1], c * (h_max - R["h"]), rel_tol=1e-9)
    assert math.isclose(lo.mu_ranges[2][0], -c * SPIN_SHARE * lo.spin_h_m, rel_tol=1e-12)
    assert math.isclose(lo.mu_ranges[2][1], c * (1 - SPIN_SHARE) * lo.spin_h_m, rel_tol=1e-12)
    assert all(a <= 0.0 <= b for a, b in lo.mu_ranges)
    low, high = lo.mu_range
    assert low < 0.0 < high


def test_the_ensemble_draws_span_the_normal_forces_about_the_nominal_model() -> None:
    """The draws reach from the planar caster load to that of the wheels on the axle (the
    nominal model's), a centre of mass from the ground to Table II.2's h plus its tolerance,
    and a spin share from 0 to 1, so their rolling transfer height lies on both sides of the
    nominal model's h + k^ h_s; besides the parameters within their params.json tolerance."""
    from host_tools.analyzer.replay.normal_forces import SPIN_SHARE, plant_config
    from host_tools.analyzer.replay.tolerance import ensemble_draws, left_out_normal_forces
    R = dict(P.ROBOT)
    draws = ensemble_draws(R, 200, np.random.default_rng(7))
    # the caster's share of the weight, N_c / (m_t g): d / (d + e) planar, m_r d / (m_t (d +
    # e)) with the wheels on the axle; the tolerances of d and e move it by about a tenth of
    # that gap
    m_t = R["m_r"] + 2 * R["m_w"]
    f_planar = R["d"] / (R["d"] + R["e"])
    f_axle = R["m_r"] * R["d"] / (m_t * (R["d"] + R["e"]))
    share = []
    for d in draws[:60]:
        cfg = plant_config({**R, **d.params}, {}, d.forces)
        rob = cfg.robot
        f = float(_at_rest(rob)["N_c"][-1]) / ((rob["m_r"] + 2 * rob["m_w"]) * rob["g"])
        share.append((f_planar - f) / (f_planar - f_axle))
    assert min(share) < 0.15 and max(share) > 0.85          # both readings reached
    assert min(share) > -0.2 and max(share) < 1.2           # and nothing beyond them
    lo = left_out_normal_forces(R)
    h = np.array([plant_config({**R, **d.params}, {}, d.forces).effects["load_transfer"]["h"]
                  for d in draws])
    # each draw's own ceiling: its centre of mass at most h + tol_h, its whole spin-up (h_s of
    # the drawn parameters)
    tops = np.array([(lambda lo_d: lo_d.h_max_m + lo_d.spin_h_m)(
        left_out_normal_forces({**R, **d.params})) for d in draws])
    top = lo.h_max_m + lo.spin_h_m
    nominal = R["h"] + SPIN_SHARE * lo.spin_h_m
    assert h.min() >= 0.0 and np.all(h <= tops * (1.0 + 1e-12))
    assert h.min() < 0.1 * top and h.max() > 0.7 * top
    assert (h < nominal).sum() > 40 and (h > nominal).sum() > 40
    k = np.array([d.forces.spin_share for d in draws])
    assert k.min() < 0.05 and k.max() > 0.95 and k.min() >= 0.0 and k.max() <= 1.0
    for name in ("b", "mu_s", "m_r", "r"):
        vals = np.array([d.params[name] for d in draws])
        assert np.all(np.abs(vals - R[name]) <= P.TOLERANCES[("robot", name)] + 1e-15)


def _detect(paths: list[str], left_out: bool, monkeypatch: Any) -> bool:
    """Whether detection sees a mismatch, with the tolerance ensemble drawing the normal forces'
    physics (``left_out``) or only the parameters (with the nominal model's normal forces)."""
    from test_analyzer_stats import _detect as detect

    from host_tools.analyzer.replay import tolerance as T
    from host_tools.analyzer.replay.normal_forces import NOMINAL
    with monkeypatch.context() as mp:
        if not left_out:
            mp.setattr(T, "ensemble_draws", lambda robot, n, rng: [
                T.EnsembleDraw(d, NOMINAL) for d in T.tolerance_draws(robot, n, rng)])
        return bool(detect(paths, True, monkeypatch))


def test_a_robot_inside_the_normal_forces_range_is_a_null_and_a_larger_load_transfer_is_not(
        tmp_path: Path, monkeypatch: Any) -> None:
    """Slipping starts of a robot with II.29's mass layout (its wheels' mass at c), its centre of
    mass on the ground and MuJoCo's spin share (1/2, through the plant's own spin term): the low
    ends of two of the normal forces' ranges, some 8 % less traction at the slip onset than the
    nominal model gives; a mismatch against the nominal replay without the ensemble's
    normal-force draws, a null with them.  A robot with its centre of mass at 90 mm and its
    whole spin-up still shows."""
    from host_tools import _native
    from host_tools.analyzer import synth
    from host_tools.analyzer.replay.normal_forces import wheels_on_axle

    def case(name: str, share: float, h: float, spin: float) -> list[str]:
        def factory(meta: Any) -> Any:
            pl = _native.Plant.from_meta(meta)
            for k, v in wheels_on_axle(dict(meta["robot"]), share).items():
                pl.set(f"robot.{k}", v)
            pl.set("plant.spin_share", spin)
            return pl
        return synth.make_case(tmp_path / name, {"load_transfer": {"h": h}},
                               profiles=("ramp", "brake", "ramp"), seed=3, duration_s=2.0,
                               plant_factory=factory)
    inside = case("inside", 0.0, 0.0, 0.5)
    assert _detect(inside, False, monkeypatch)
    assert not _detect(inside, True, monkeypatch)
    assert _detect(case("h90", 1.0, 0.09, 1.0), True, monkeypatch)


def _judge(effect: str, name: str, value: float, sigma: float) -> Any:
    from host_tools.analyzer.fit.judge import Candidate, judge
    from host_tools.analyzer.fit.params import FitResult
    from host_tools.runfmt import validate_meta

    class _Prob:
        meta = validate_meta({})
        vocab = {effect: {name: value}}
        floors = {"omega_r": 0.1}
    fit = FitResult([effect], {effect: {name: value}}, [value], np.array([0.5]), 10.0, 1000,
                    [sigma], 10)
    rng = np.random.default_rng(3)
    before = rng.standard_normal(3000) + 0.3
    after = rng.standard_normal(3000)
    c = Candidate([effect], fit, -300.0, 1.3, 0.8, {"omega_r": 0.5}, {"omega_r": 0.5},
                  [[value + sigma], [value - sigma]], 1.0, heldout_pooled=(before, after))
    judge(_Prob(), c)
    return c


def test_a_load_transfer_within_the_left_out_physics_is_no_evidence_and_90mm_is() -> None:
    """The ``load_transfer`` effect's h is the centre-of-mass height, Table II.2's h in the
    nominal model (which adds k^ h_s): a robot with its centre of mass at H and a share k of the
    spin-up rolls like the effect at H + (k - k^) h_s.  The planar robot (H = 0, k = 0), the
    thin-disc robot (the table's h, k = 1), MuJoCo's (the table's h, k = 1/2) and the highest
    centre of mass the table allows are no evidence, either way from the nominal value; 90 mm
    is."""
    from host_tools.analyzer import effects as fx
    from host_tools.analyzer.fit.judge import significant_deviation
    from host_tools.analyzer.replay.normal_forces import SPIN_SHARE
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    from host_tools.runfmt import validate_meta
    meta = validate_meta({})
    h0 = P.ROBOT["h"]
    assert fx.SPECS["load_transfer"].params[0].neutral(meta) == h0
    lo = left_out_normal_forces(dict(P.ROBOT))
    for h in (-SPIN_SHARE * lo.spin_h_m, h0 + (1 - SPIN_SHARE) * lo.spin_h_m, h0, lo.h_max_m):
        assert not _judge("load_transfer", "h", h, 1e-3).checks["size"], h
    assert _judge("load_transfer", "h", 0.09, 1e-3).checks["size"]
    ranges = fx.left_out_ranges("load_transfer", "h", meta)
    assert ranges == ((-h0, lo.h_max_m - h0),
                      (-SPIN_SHARE * lo.spin_h_m, (1 - SPIN_SHARE) * lo.spin_h_m))
    planar = -SPIN_SHARE * lo.spin_h_m - h0
    assert significant_deviation(planar, 1e-3, 0.0)        # without the left-out ranges it counted
    assert not significant_deviation(planar, 1e-3, 0.0, left_out=ranges)
    assert significant_deviation(lo.h_max_m - h0 + (1 - SPIN_SHARE) * lo.spin_h_m + 0.01, 1e-3,
                                 0.0, left_out=ranges)


@pytest.mark.parametrize("effect,name,key", [("friction_coefficient", "mu_s", "mu_s"),
                                             ("stribeck", "mu_k0", "mu_k")])
def test_a_friction_shift_within_the_normal_force_range_is_no_evidence_either_way(
        effect: str, name: str, key: str) -> None:
    """With the nominal model inside the normal forces' range, a robot at either end replays
    as another friction coefficient, more or less: the planar robot (wheels' mass at c, no
    transfer, no spin-up) as ``mu (1 + sum lo)``, the highest centre of mass with the whole
    spin-up as ``mu (1 + sum hi)``; neither is evidence (the planar one was, with the old
    one-sided allowance), and beyond either end a deviation counts from the uniform tolerance's
    one-sided 1 % point, 0.98 tol (the vocabulary's friction and Stribeck cases, 15 % off,
    far beyond)."""
    from host_tools.analyzer import effects as fx
    from host_tools.analyzer.fit.judge import significant_deviation, size_threshold
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    from host_tools.runfmt import validate_meta
    meta = validate_meta({})
    mu = float(meta["robot"][key])
    tol = P.TOLERANCES[("robot", key)]
    ranges = fx.left_out_ranges(effect, name, meta)
    lo = left_out_normal_forces(meta["robot"], mu)
    assert ranges == tuple((mu * a, mu * b) for a, b in lo.mu_ranges)
    low, high = mu * lo.mu_range[0], mu * lo.mu_range[1]
    assert low < -mu * 0.05 and high > mu * 0.02
    assert significant_deviation(low, 1e-4, tol)                 # the size test without them
    # and with a one-sided allowance (the nominal model at the range's low end, "up to the
    # excess above, never below"): the planar robot counted
    assert significant_deviation(low, 1e-4, tol, left_out=[(0.0, mu * b) for _, b in lo.mu_ranges])
    u = size_threshold(0.0, tol)     # the uniform tolerance's one-sided 1 % point
    for end, sign in ((low, -1.0), (high, 1.0)):
        assert not significant_deviation(end, 0.0, tol, left_out=ranges)
        assert not significant_deviation(end + sign * 0.95 * u, 0.0, tol, left_out=ranges)
        assert significant_deviation(end + sign * 1.05 * u, 0.0, tol, left_out=ranges)
    assert significant_deviation(-0.15 * mu, 1e-4, tol, left_out=ranges)
    assert significant_deviation(0.15 * mu, 1e-4, tol, left_out=ranges)


def test_a_pair_partner_within_the_left_out_physics_is_dropped() -> None:
    """A payload fitted beside a load transfer whose rolling height is 59 mm +- 1 mm (MuJoCo's
    payload case, fitted by the effect without the spin-up; the effect's h is that minus
    k^ h_s): the height is 20 sigma off the table's h but within the centre of mass's and the
    spin share's ranges, so the partner is dropped and the payload stands alone; at 90 mm it
    stays."""
    from host_tools.analyzer.replay.normal_forces import SPIN_SHARE
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    from host_tools.analyzer.fit.judge import Candidate
    from host_tools.analyzer.fit.params import FitResult
    from host_tools.analyzer.select import _insignificant_partners
    from host_tools.runfmt import validate_meta

    class _Prob:
        meta = validate_meta({})
        vocab = {"payload": {"mass_kg": 0.0}, "load_transfer": {"h": P.ROBOT["h"]}}
        floors: dict[str, float] = {}

    def pair(h: float) -> Any:
        fit = FitResult(["payload", "load_transfer"],
                        {"payload": {"mass_kg": 0.5}, "load_transfer": {"h": h}}, [0.5, h],
                        np.array([0.5, 0.3]), 10.0, 1000, [0.005, 0.001], 10)
        return Candidate(fit.effects, fit, -300.0, 2.0, 1.0, {}, {}, [[0.5, h]], 3.0)
    h = 0.059 - SPIN_SHARE * left_out_normal_forces(dict(P.ROBOT)).spin_h_m
    assert [e for e, _ in _insignificant_partners(pair(h), _Prob())] == ["load_transfer"]
    assert _insignificant_partners(pair(0.09), _Prob()) == []


def test_mujocos_spin_up_share_is_inside_the_draws() -> None:
    """MuJoCo's wheels spinning up on a floor of mu = 0.001 with the body at rest: the caster's
    load falls by k I_wy (theta''_r + theta''_l) / (d + e) (lib/slipmodel/README.md, "Load
    transfer and spin-up") with k = 1/2, its wheel body's I_wz of I_wy (the armature does not
    react): the nominal model's k^ (params.json model.spin_share) and inside the ensemble's
    k in [0, 1], not the effect's own k = 1."""
    pytest.importorskip("mujoco")
    from host_tools.engines.mujoco_robot import MujocoRobot
    R = dict(P.ROBOT)
    m_t = R["m_r"] + 2 * R["m_w"]
    rb = MujocoRobot({"friction_coefficient": {"mu_s": 1e-3, "mu_k": 1e-3}})
    nc0 = rb.normal_forces()[2]
    t = 0.0
    for _ in range(100):
        rb.step(t, 0.3, 0.3)
        t += rb.dt
    w0, v0 = rb.data.qvel[6:8].copy(), float(rb.data.qvel[0])
    nc = []
    for _ in range(50):
        rb.step(t, 0.3, 0.3)
        t += rb.dt
        nc.append(rb.normal_forces()[2])
    span = 50 * rb.dt
    spin = float(np.sum(rb.data.qvel[6:8] - w0)) / span
    a_x = (float(rb.data.qvel[0]) - v0) / span
    assert abs(a_x) < 0.05 and spin > 100.0          # the body at rest, the wheels spinning up
    k = -((float(np.mean(nc)) - nc0) * (R["d"] + R["e"]) + m_t * a_x * R["h"]) / (R["I_wy"] * spin)
    assert abs(k - R["I_wz"] / R["I_wy"]) < 0.02
    assert 0.0 <= k <= 1.0 and abs(k - P.MODEL["spin_share"]) < 0.02
