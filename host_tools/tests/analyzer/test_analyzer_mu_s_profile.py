"""The profile of mu_s (docs/analyzer.md, "Identifiability"): its staircase cost scanned before
the gradient solve, and its profile set in the report."""
from __future__ import annotations

import json
import math

import pytest
from scipy.stats import chi2

from _native_skip import needs_native
from _truth_loads import slip_load_ratio
from host_tools import params
from host_tools.analyzer.fit.solver import (flat_minimum, profile_interval, profile_scan,
                                            profile_steps)

pytestmark = needs_native(truth=True)

LO, HI, TOL = 0.16, 0.32, 0.006


def _staircase(f, quantum=0.0011):
    """``f`` made piecewise constant in steps of ``quantum`` (a breakaway moving by one plant
    step at a time)."""
    return lambda v: f(math.floor(v / quantum) * quantum)


def _profile(f, scale=1.0):
    coarse, fine = profile_steps(TOL, LO, HI)
    cost = _staircase(f)
    pts = profile_scan(cost, LO, HI, coarse, fine)
    return pts, profile_interval(cost, pts, LO, HI, fine, scale), fine


def test_a_narrow_minimum_far_from_the_start_is_found_and_bounded_on_both_sides():
    """A parabola of the chi-square scale: the set is where it rises by 3.84, two-sided."""
    true, curv = 0.205, 1.0 / 0.004 ** 2        # 1-sigma 0.004
    pts, (lo, hi, kind, sigma), fine = _profile(lambda v: 500.0 + curv * (v - true) ** 2)
    a, b = flat_minimum(pts)
    assert abs(0.5 * (a + b) - true) < fine
    half = math.sqrt(chi2.ppf(0.95, 1)) * 0.004
    assert kind == "two_sided"
    assert abs(lo - (true - half)) < 2 * fine and abs(hi - (true + half)) < 2 * fine
    assert sigma == pytest.approx(0.004, rel=0.35)


def test_a_cost_flat_from_the_bottom_gives_an_upper_bound():
    """Every run slipping from the first tick: flat from mu_k up to the lowest commanded
    traction (0.23 here), rising beyond; the set is one-sided (2.71, 95 %)."""
    pts, (lo, hi, kind, sigma), fine = _profile(
        lambda v: 800.0 + (0.0 if v < 0.23 else 4e5 * (v - 0.23) ** 2))
    assert kind == "upper_bound"
    assert lo == LO
    edge = 0.23 + math.sqrt(chi2.ppf(0.90, 1) / 4e5)
    assert abs(hi - edge) < 2 * fine
    a, b = flat_minimum(pts)     # its end known to the coarse grid (the tolerance)
    assert a == LO and 0.23 - TOL <= b <= 0.23
    assert math.isfinite(sigma)


def test_the_nominal_point_on_mu_s_line_keeps_the_nominal_ratio_to_mu_k():
    """solver.given_neutral on the friction effect's mu_s (mu_k held): mu_s = mu_k / (the
    nominal mu_k/mu_s), the nominal mu_s itself at the nominal mu_k, and the nearest end of
    the possible range where that point lies outside it."""
    from host_tools.analyzer.fit.params import params_for
    from host_tools.analyzer.fit.solver import given_line, given_neutral
    meta = {"robot": dict(params.ROBOT)}
    ps = params_for(["friction_coefficient"], meta, {})
    i, j = [p.name for p in ps].index("mu_s"), [p.name for p in ps].index("mu_k_over_mu_s")
    ratio = params.ROBOT["mu_k"] / params.ROBOT["mu_s"]
    for mu_k in (0.15, 0.187, params.ROBOT["mu_k"], 0.36):
        values = [0.0, 0.0]
        values[i], values[j] = 1.2 * mu_k, 1 / 1.2
        line = given_line(ps, [0, 1], i, values, meta)
        assert line is not None
        _, held, lo, hi, _ = line
        assert held == pytest.approx(mu_k)
        v = given_neutral(ps, i, j, held, lo, hi)
        assert v == pytest.approx(min(max(mu_k / ratio, lo), hi), rel=1e-9)
        if mu_k == params.ROBOT["mu_k"]:
            assert v == pytest.approx(params.ROBOT["mu_s"], rel=1e-9)
    # a range that excludes it: its nearest end
    assert given_neutral(ps, i, j, 0.2, 0.25, 0.3) == 0.25
    assert given_neutral(ps, i, j, 0.2, 0.1, 0.15) == 0.15


def test_a_cost_flat_everywhere_is_unbounded():
    pts, (lo, hi, kind, sigma), _ = _profile(lambda v: 800.0)
    assert (lo, hi, kind) == (LO, HI, "unbounded") and sigma == math.inf
    assert flat_minimum(pts) == (LO, HI)


def test_the_scan_is_bounded_and_does_not_depend_on_where_the_nominal_sits():
    """The grid spans the possible range only: coarse at the tolerance's full width 2 tol,
    the best point refined by halving down to tol/5, the set's edges bisected to tol/5."""
    calls = []
    stairs = _staircase(lambda v: 1000.0 + 1e4 * (v - 0.3) ** 2)

    def cost(v):
        calls.append(v)
        return stairs(v)
    coarse, fine = profile_steps(TOL, LO, HI)
    pts = profile_scan(cost, LO, HI, coarse, fine)
    profile_interval(cost, pts, LO, HI, fine, 1.0)
    assert min(calls) >= LO and max(calls) <= HI
    assert len(calls) == len(set(calls)) <= (HI - LO) / (2 * TOL) + 1 + 2 * 4 + 2 * 4


# ------------------------------------------------------------------ end to end, truth engine

@pytest.fixture
def cli():
    from host_tools.__main__ import main
    return main


def _friction_analysis(tmp_path, runs, cli):
    """(report.json, its selected friction entry, report.md) of ``runs`` analyzed for
    friction alone."""
    out = tmp_path / "out"
    assert cli(["analyze", *runs, "--out", str(out), "--jobs", "1", "--no-plots",
                "--effects", "friction_coefficient"]) == 0
    rep = json.load(open(out / "report.json"))
    fc = {s["effect"]: s for s in rep["selected"]}.get("friction_coefficient", {})
    return rep, fc, open(out / "report.md").read()


GRIP_THEN_SLIP = {"friction_coefficient": {"mu_s": 0.19, "mu_k": 0.17}}


def test_mu_s_fitted_on_its_profile_where_the_wheels_grip_then_slip(tmp_path, cli):
    """Truth-engine runs whose wheels stick, break away and re-stick (clamped ramps on the
    nominal mu, one harder unclamped start): the cost in mu_s is a staircase, and a gradient
    solve from the nominal mu_s stayed on the nominal's flat step (mu_s 0.254, verdict
    unexplained).  The profile scan finds the step of the true 0.19, the report gives its
    profile set, which holds the fitted value and the truth and not the nominal."""
    from host_tools import truth
    exps = [({"kind": "line", "accel": 1.0, "cruise": 0.6}, True),
            ({"kind": "arc", "accel": 1.0, "cruise": 0.5, "radius": 0.6}, True),
            ({"kind": "line", "accel": 1.75, "cruise": 0.9}, False)]
    runs = [truth.simulate_run(tmp_path / f"run{i}", ref, GRIP_THEN_SLIP, clamp=clamp,
                               duration_s=1.5, seed=50 + i, hidden_dir=tmp_path / "hidden")
            for i, (ref, clamp) in enumerate(exps)]
    rep, fc, md = _friction_analysis(tmp_path, runs, cli)
    assert rep["verdict"] == "explained"
    mu_s, mu_k = fc["params"]["mu_s"], fc["params"]["mu_k"]
    assert abs(mu_s - 0.19) < 0.1 * 0.19
    # mu_k: the true one times the truth's slipping wheels' load against the nominal model's
    # (its whole spin-up reacts, k = 1 against k^), to 2 %
    want = 0.17 * slip_load_ratio(tmp_path / "hidden")
    assert abs(mu_k - want) < 0.02 * want
    iv = fc["interval"]["mu_s"]
    lo = iv["lo"] if iv["lo"] is not None else iv["possible"][0]
    assert iv["hi"] is not None
    assert lo <= mu_s <= iv["hi"]
    assert lo <= 0.19 <= iv["hi"] < params.ROBOT["mu_s"]
    cand = next(c for c in rep["candidates"] if c["effect"] == "friction_coefficient")
    assert cand["param_interval"]["mu_s"] == iv
    # the 1-sigma of mu_s is the set's, not a finite difference across one step
    width = iv["hi"] - lo
    assert cand["param_std"]["mu_s"] > 0.1 * width


HIGH = {"friction_coefficient": {"mu_s": 0.40, "mu_k": 0.36}}


def test_mu_s_bounded_on_one_side_where_every_run_slips_from_the_first_tick(tmp_path, cli):
    """A grippy floor (mu_k above the nominal mu_s) and hard unclamped starts: the wheels slip
    from the first tick, so the cost is flat in mu_s from mu_k up to the lowest commanded
    traction, here inside mu_s's possible range [mu_k, 2 mu_k].  mu_k is fitted (the grid
    start's levels of mu_s at mu_k ~ mu_s reach above the nominal), mu_s stays unidentified,
    and the report gives the one-sided bound the data do support: mu_s <= hi, truth inside."""
    from host_tools import truth
    runs = [truth.simulate_run(tmp_path / f"run{i}", {"kind": "line", "accel": a, "cruise": 1.2},
                               HIGH, clamp=False, duration_s=1.5, seed=80 + i,
                               hidden_dir=tmp_path / "hidden")
            for i, a in enumerate([4.0, 3.5])]
    rep, fc, md = _friction_analysis(tmp_path, runs, cli)
    assert rep["verdict"] == "explained"
    mu_s, mu_k = fc["params"]["mu_s"], fc["params"]["mu_k"]
    want = 0.36 * slip_load_ratio(tmp_path / "hidden")   # as above
    assert abs(mu_k - want) < 0.02 * want
    assert "mu_s" in fc["unidentified"]
    iv = fc["interval"]["mu_s"]
    assert iv["kind"] == "upper_bound" and iv["lo"] is None
    assert abs(iv["possible"][0] - mu_k) < 1e-3 * mu_k
    assert 0.40 <= iv["hi"] < iv["possible"][1]
    assert iv["flat"][0] == iv["possible"][0]          # flat from mu_k
    assert mu_k <= mu_s <= iv["hi"]
    # the point value: the nominal model's mu_s/mu_k at the fitted mu_k (inside the set), not
    # the nominal's absolute mu_s clipped into it (which would be the set's floor, mu_k)
    ratio = params.ROBOT["mu_s"] / params.ROBOT["mu_k"]
    assert mu_s == pytest.approx(mu_k * ratio, rel=2e-4)
    assert "mu_s ≤" in md
