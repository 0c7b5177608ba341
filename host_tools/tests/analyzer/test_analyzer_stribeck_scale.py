"""Stribeck's v_s is fitted in the logarithm of its value (effects.ParamSpec.log): the plant uses
it only as the ratio |s| / v_s, and its search range [0.001, 1] m/s spans three decades.  On a
linear map the grid start's levels jumped from 0.001 to 0.17 m/s, a finite-difference step was
0.01 m/s (a fifth of a v_s of 0.05 m/s), and the solve stopped part-way along the curved valley
in which mu_k0 and v_s trade off (docs/analyzer.md, "Fit coordinates")."""
from __future__ import annotations

import math

import numpy as np

from _native_skip import needs_native
from host_tools import params
from host_tools.analyzer.fit.params import Param, params_for
from host_tools.analyzer.fit.solver import effective_n, param_std


def _v_s() -> Param:
    ps = params_for(["stribeck"], {"robot": dict(params.ROBOT)}, {})
    return next(p for p in ps if p.name == "v_s")


def test_v_s_coordinate_moves_it_by_one_ratio_wherever_it_lies():
    p = _v_s()
    assert p.log
    # the grid start's seven levels (solver.grid_start): one every half decade, so every
    # decade of the range holds a level (linear: none between 0.001 and 0.17 m/s)
    levels = [p.from_x(k / 6) for k in range(7)]
    ratios = [b / a for a, b in zip(levels, levels[1:])]
    assert max(ratios) / min(ratios) < 1 + 1e-9
    for d in range(3):
        lo, hi = p.lo * 10 ** d, p.lo * 10 ** (d + 1)
        assert any(lo <= v < hi for v in levels), (lo, hi, levels)
    # a finite-difference step of the solver (1e-2 of the coordinate) is the same relative
    # change at 0.05 m/s as at 0.5 m/s, and a small one
    for v in (0.05, 0.5):
        x = p.to_x(v)
        assert abs(p.from_x(x) - v) < 1e-12
        rel = p.from_x(x + 1e-2) / v - 1
        assert 0 < rel < 0.1
        assert abs(rel - (math.exp(1e-2 * math.log(p.hi / p.lo)) - 1)) < 1e-9


def test_a_log_coordinates_sigma_is_its_values():
    """sigma(v) = sigma(x) dv/dx = sigma(x) v ln(hi/lo) at the fitted value."""
    p = _v_s()
    lin = Param("wheel_radius", "r_eff", 0.03, 0.02, 0.05, 1e-4)
    rng = np.random.default_rng(7)
    r = rng.normal(0.0, 1.0, 400)
    J = np.column_stack([rng.normal(0.0, 5.0, 400), rng.normal(0.0, 2.0, 400)])
    s2 = float(np.sum(r ** 2)) / (r.size - 2)
    cov = np.linalg.inv(J.T @ J) * s2 * (r.size / max(effective_n(r), 1.0))
    for v_s in (0.02, 0.2):
        std = param_std(J, r, [lin, p], [0, 1], [0.03, v_s])
        assert abs(std[0] - math.sqrt(cov[0, 0]) * (lin.hi - lin.lo)) < 1e-9 * std[0]
        want = math.sqrt(cov[1, 1]) * v_s * math.log(p.hi / p.lo)
        assert abs(std[1] - want) < 1e-9 * want


@needs_native(truth=True)
def test_a_stribeck_fit_reaches_the_floor_of_its_valley(tmp_path):
    """Four closed-loop runs (two hard line starts without the clamp, an arc and a line with
    it), a recorder with 36 ms frames, 19 % of them lost and the heading wrapped, Stribeck
    mu_k0 0.167, v_s 0.129 m/s: the fit of Stribeck alone reaches mu_k0 within 0.01 of the
    true value (on the linear map it stopped at mu_k0 0.066, v_s 0.031, with a residual sum of
    squares a third higher)."""
    from host_tools import truth
    from host_tools.analyzer.pipeline import front
    rec = {"heading_tel": "wrapped", "tel_s": 0.036, "tel_drop": 0.19}
    exps = [({"kind": "line", "accel": 2.628, "cruise": 1.314}, False),
            ({"kind": "line", "accel": 1.752, "cruise": 0.876}, False),
            ({"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": 0.6}, True),
            ({"kind": "line", "accel": 1.0, "cruise": 0.6}, True)]
    true = {"mu_k0": 0.167, "v_s": 0.129}
    paths = [truth.simulate_run(tmp_path / f"run-{i}", ref, {"stribeck": true}, clamp=clamp,
                                duration_s=2.0, seed=5 + i, recorder=rec)
             for i, (ref, clamp) in enumerate(exps)]
    pb = front(paths).det.problem
    fit = pb.fit(["stribeck"], list(range(len(paths))))
    got = fit.params["stribeck"]
    assert abs(got["mu_k0"] - true["mu_k0"]) < 0.01, got
    assert 0.5 * true["v_s"] < got["v_s"] < 2 * true["v_s"], got

