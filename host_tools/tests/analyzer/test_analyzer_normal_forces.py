"""The nominal model's left-out physics of the normal forces as its own tolerance
(replay/tolerance.py ``left_out_normal_forces``, ``wheels_on_axle``, ``ensemble_draws``; the size
test's ``left_out`` ranges, fit/judge.py SIZE_RULE): where the wheels' mass sits, the
longitudinal load transfer of a centre of mass at Table II.2's height and the wheels' spin-up
reaction are drawn in the replay's tolerance ensemble, and a fitted friction shift or
load-transfer height within them is no evidence, while a load transfer beyond them still
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


def test_wheels_on_the_axle_give_the_caster_the_platforms_share_only() -> None:
    """With the wheels' mass on the axle the robot's centre of mass is m_r d / m_t ahead of o and
    the caster carries m_r g d / (d + e) (the plant's N_c), not m_t g d / (d + e); the wheels
    carry the rest, 2 m_w d / (m_t e) more than the nominal model gives (``mu_excess``' static
    part).  Share 0 is the nominal robot."""
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces, wheels_on_axle
    R = dict(P.ROBOT)
    m_t = R["m_r"] + 2 * R["m_w"]
    nom = _at_rest(R)
    axle = _at_rest({**R, **wheels_on_axle(R, 1.0)})
    assert math.isclose(float(axle["N_c"][0]), R["m_r"] * R["g"] * R["d"] / (R["d"] + R["e"]),
                        rel_tol=1e-9)
    assert math.isclose(float(nom["N_c"][0]), m_t * R["g"] * R["d"] / (R["d"] + R["e"]),
                        rel_tol=1e-9)
    excess = float(axle["N_r"][0]) / float(nom["N_r"][0]) - 1.0
    assert math.isclose(excess, 2 * R["m_w"] * R["d"] / (m_t * R["e"]), rel_tol=1e-9)
    lo = left_out_normal_forces(R)
    assert math.isclose(lo.wheel_shift_m, R["d"] - wheels_on_axle(R, 1.0)["d"], rel_tol=1e-12)
    assert math.isclose(lo.excess[0], excess, rel_tol=1e-9)
    # the table's height's transfer, and the spin-up's as a height, at the acceleration where the
    # wheels reach mu_s N
    h = R["h"] + P.TOLERANCES[("robot", "h")]
    assert math.isclose(lo.excess[1], R["mu_s"] * h / (R["d"] + R["e"]), rel_tol=1e-9)
    assert math.isclose(lo.spin_h_m, 2 * R["I_wy"] / (m_t * R["r"]), rel_tol=1e-12)
    assert math.isclose(lo.excess[2], R["mu_s"] * lo.spin_h_m / (R["d"] + R["e"]), rel_tol=1e-9)
    assert math.isclose(lo.mu_excess, sum(lo.excess), rel_tol=1e-12)
    assert wheels_on_axle(R, 0.0) == {"d": R["d"], "e": R["e"], "I_rz": R["I_rz"]}
    # the caster stays where it is; the yaw inertia about the new centre of mass grows by the
    # masses' parallel-axis terms
    w = wheels_on_axle(R, 1.0)
    assert math.isclose(w["d"] + w["e"], R["d"] + R["e"], rel_tol=1e-12)
    d_c = w["d"]
    assert math.isclose(w["I_rz"], R["I_rz"] + R["m_r"] * (R["d"] - d_c) ** 2
                        + 2 * R["m_w"] * d_c ** 2, rel_tol=1e-12)


def test_the_ensemble_draws_span_the_left_out_normal_forces() -> None:
    """The draws reach from the nominal caster load to that of the wheels on the axle and from
    no pitch balance to Table II.2's height with the whole spin-up, besides the parameters
    within their params.json tolerance."""
    from host_tools.analyzer.replay.tolerance import ensemble_draws, left_out_normal_forces
    R = dict(P.ROBOT)
    draws = ensemble_draws(R, 200, np.random.default_rng(7))
    # the caster's share of the weight, N_c / (m_t g) (the plant's II.29): d / (d + e) nominal,
    # m_r d / (m_t (d + e)) with the wheels on the axle; the tolerances of d and e move it by
    # about a tenth of that gap
    m_t = R["m_r"] + 2 * R["m_w"]
    f_nom = R["d"] / (R["d"] + R["e"])
    f_axle = R["m_r"] * R["d"] / (m_t * (R["d"] + R["e"]))
    share = []
    for d in draws[:60]:
        rob = {**R, **d.robot}
        f = float(_at_rest(rob)["N_c"][0]) / ((rob["m_r"] + 2 * rob["m_w"]) * rob["g"])
        share.append((f_nom - f) / (f_nom - f_axle))
    assert min(share) < 0.15 and max(share) > 0.85          # both readings reached
    assert min(share) > -0.2 and max(share) < 1.2           # and nothing beyond them
    # the pitch balance while rolling: a centre of mass from the ground to Table II.2's h plus a
    # share of the spin-up's rolling height, from none (the planar nominal model) to all; the
    # effect's own spin term (which follows a slipping wheel's acceleration) stays off
    h = np.array([d.effects["load_transfer"]["h"] for d in draws])
    lo = left_out_normal_forces(R)
    top = lo.h_max_m + lo.spin_h_m
    assert h.min() >= 0.0 and h.max() <= top and h.min() < 0.1 * top and h.max() > 0.7 * top
    assert all(d.spin_share == 0.0 for d in draws)
    for name in ("b", "mu_s", "m_r", "r"):
        vals = np.array([d.robot[name] for d in draws])
        assert np.all(np.abs(vals - R[name]) <= P.TOLERANCES[("robot", name)] + 1e-15)


def _detect(paths: list[str], left_out: bool, monkeypatch: Any) -> bool:
    """Whether detection sees a mismatch, with the tolerance ensemble drawing the left-out
    normal forces (``left_out``) or only the parameters."""
    from test_analyzer_stats import _detect as detect

    from host_tools.analyzer.replay import tolerance as T
    with monkeypatch.context() as mp:
        if not left_out:
            mp.setattr(T, "ensemble_draws", lambda robot, n, rng: [
                T.EnsembleDraw(d, {}) for d in T.tolerance_draws(robot, n, rng)])
        return bool(detect(paths, True, monkeypatch))


def test_a_robot_with_its_wheels_on_the_axle_is_a_null_and_a_larger_load_transfer_is_not(
        tmp_path: Path, monkeypatch: Any) -> None:
    """Slipping starts of a robot whose wheels' mass sits on the axle, whose centre of mass is at
    Table II.2's height and whose wheels' spin-up reacts with half of I_wy (MuJoCo's wheel body
    carries I_wz of it): a mismatch against the nominal replay without the left-out draws, a
    null with them; the lumped robot with a load transfer at 90 mm still shows."""
    from host_tools import _native
    from host_tools.analyzer import synth
    from host_tools.analyzer.replay.tolerance import wheels_on_axle

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
    real = case("axle", 1.0, P.ROBOT["h"], 0.5)
    assert _detect(real, False, monkeypatch)
    assert not _detect(real, True, monkeypatch)
    assert _detect(case("h90", 0.0, 0.09, 1.0), True, monkeypatch)


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
    """The nominal model leaves out the pitch balance: the longitudinal transfer of a centre of
    mass that Table II.2 puts at h and the wheels' spin-up reaction, which the effect carries
    with the whole I_wy.  As the effect's height, a robot with its centre of mass at H and a
    share k of the spin-up rolls like H - (1 - k) h_s: the planar nominal model (-h_s), MuJoCo's
    (the table's h, k = 1/2) and the table's robot (h) are no evidence; 90 mm is."""
    from host_tools.analyzer import effects as fx
    from host_tools.analyzer.fit.judge import significant_deviation
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    from host_tools.runfmt import validate_meta
    lo = left_out_normal_forces(dict(P.ROBOT))
    for h in (P.ROBOT["h"] - 0.5 * lo.spin_h_m, lo.h_max_m, -lo.spin_h_m):
        assert not _judge("load_transfer", "h", h, 1e-3).checks["size"]
    assert _judge("load_transfer", "h", 0.09, 1e-3).checks["size"]
    ranges = fx.left_out_ranges("load_transfer", "h", validate_meta({}))
    assert ranges == ((0.0, lo.h_max_m), (-lo.spin_h_m, 0.0))
    planar = -lo.spin_h_m
    assert significant_deviation(planar, 1e-3, 0.0)        # without the left-out ranges it counted
    assert not significant_deviation(planar, 1e-3, 0.0, left_out=ranges)
    assert significant_deviation(lo.h_max_m + 0.01, 1e-3, 0.0, left_out=ranges)


@pytest.mark.parametrize("effect,name,key", [("friction_coefficient", "mu_s", "mu_s"),
                                             ("stribeck", "mu_k0", "mu_k")])
def test_a_friction_shift_within_the_normal_force_excess_is_no_evidence(effect: str, name: str,
                                                                         key: str) -> None:
    """Wheels that carry more than the nominal model gives replay as more friction, never less:
    any robot the ensemble draws (up to all the left-out physics at its full size) is no
    evidence, nor MuJoCo's (the wheels on the axle, the table's h, half the spin-up); beyond
    that range, or below the nominal coefficient, a deviation counts from SIZE_Z times the
    tolerance's standard uncertainty (the vocabulary's friction and Stribeck cases, 15 % lower,
    far beyond)."""
    from host_tools.analyzer import effects as fx
    from host_tools.analyzer.fit.judge import SIZE_Z, significant_deviation
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    from host_tools.runfmt import validate_meta
    meta = validate_meta({})
    mu = float(meta["robot"][key])
    tol = P.TOLERANCES[("robot", key)]
    ranges = fx.left_out_ranges(effect, name, meta)
    lo = left_out_normal_forces(meta["robot"], mu)
    x = lo.excess
    assert ranges == tuple((0.0, mu * v) for v in x)
    mujoco = mu * (x[0] + x[1] + 0.5 * x[2])
    assert significant_deviation(mujoco, 1e-4, tol)             # the size test before
    assert not significant_deviation(mujoco, 1e-4, tol, left_out=ranges)
    u = SIZE_Z * tol / math.sqrt(3.0)
    top = mu * lo.mu_excess
    assert not significant_deviation(top, 0.0, tol, left_out=ranges)
    assert not significant_deviation(top + 0.95 * u, 0.0, tol, left_out=ranges)
    assert significant_deviation(top + 1.05 * u, 0.0, tol, left_out=ranges)
    assert not significant_deviation(-0.95 * u, 0.0, tol, left_out=ranges)
    assert significant_deviation(-1.05 * u, 0.0, tol, left_out=ranges)
    assert significant_deviation(-0.15 * mu, 1e-4, tol, left_out=ranges)


def test_a_pair_partner_within_the_left_out_physics_is_dropped() -> None:
    """A payload fitted beside a load transfer of 59 mm ± 1 mm (MuJoCo's payload case, fitted
    by the effect without the spin-up: 59 mm - h_s with it): the height is 20 sigma from zero
    but within the table's h and the spin-up's range, so the partner is dropped and the payload
    stands alone; at 90 mm it stays."""
    from host_tools.analyzer.replay.tolerance import left_out_normal_forces
    from host_tools.analyzer.fit.judge import Candidate
    from host_tools.analyzer.fit.params import FitResult
    from host_tools.analyzer.select import _insignificant_partners
    from host_tools.runfmt import validate_meta

    class _Prob:
        meta = validate_meta({})
        vocab = {"payload": {"mass_kg": 0.0}, "load_transfer": {"h": 0.0}}
        floors: dict[str, float] = {}

    def pair(h: float) -> Any:
        fit = FitResult(["payload", "load_transfer"],
                        {"payload": {"mass_kg": 0.5}, "load_transfer": {"h": h}}, [0.5, h],
                        np.array([0.5, 0.3]), 10.0, 1000, [0.005, 0.001], 10)
        return Candidate(fit.effects, fit, -300.0, 2.0, 1.0, {}, {}, [[0.5, h]], 3.0)
    h = 0.059 - left_out_normal_forces(dict(P.ROBOT)).spin_h_m
    assert [e for e, _ in _insignificant_partners(pair(h), _Prob())] == ["load_transfer"]
    assert _insignificant_partners(pair(0.09), _Prob()) == []


def test_mujocos_spin_up_share_is_inside_the_draws() -> None:
    """MuJoCo's wheels spinning up on a floor of mu = 0.001 with the body at rest: the caster's
    load falls by k I_wy (theta''_r + theta''_l) / (d + e) (lib/slipmodel/README.md, "Load
    transfer and spin-up") with k = 1/2, its wheel body's I_wz of I_wy (the armature does not
    react): inside the ensemble's k in [0, 1], and not the effect's own k = 1."""
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
    assert 0.0 <= k <= 1.0
