"""The friction single's nuisance creep speed (fit/params.py ``creep_param``): the plant's
Stribeck law tied to mu_s, fitted over a grid of speeds with mu_s profiled at each, and kept only
where the likelihood ratio against the fit without it passes (``Problem._fit_creep``);
otherwise the friction fit is the nominal model's form (Coulomb switch at mu_s)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from _native_skip import needs_native

pytestmark = needs_native()

MU_S, MU_K, V_CREEP = 0.19, 0.17, 0.01


def _problem(tmp_path: Path, effects: dict[str, dict[str, float]], seed: int) -> Any:
    """The analyzer's own fit problem of three 2 s duty runs (ramp, brake, ramp) on the
    nominal plant with ``effects`` (the friction's creep through effects.creep_form)."""
    from host_tools.analyzer import pipeline as PL
    from host_tools.analyzer import synth
    paths = synth.make_case(tmp_path / f"s{seed}", effects, profiles=("ramp", "brake", "ramp"),
                            seed=seed, duration_s=2.0)
    return PL.front(paths).det.problem


def test_the_creep_is_the_plants_stribeck_law_tied_to_mu_s() -> None:
    """effects.creep_form: a friction with the creep key becomes the friction's coefficients
    plus the plant's Stribeck law with mu_k0 = mu_s, v_s = the creep speed; without the key
    nothing changes; plant_setup applies it (the one path every replay's plant is built by)."""
    from host_tools import params as P
    from host_tools.analyzer.effects import CREEP_KEY, creep_form, plant_setup
    fc = {"friction_coefficient": {"mu_s": MU_S, "mu_k": MU_K, CREEP_KEY: V_CREEP}}
    out = creep_form(fc)
    assert out == {"friction_coefficient": {"mu_s": MU_S, "mu_k": MU_K},
                   "stribeck": {"mu_k0": MU_S, "v_s": V_CREEP}}
    plain = {"friction_coefficient": {"mu_s": MU_S, "mu_k": MU_K}, "deadband": {"volts": 0.1}}
    assert creep_form(plain) == plain
    _, fx = plant_setup(P.ROBOT, fc)
    assert fx == out


def test_a_creeping_contact_is_fitted_with_its_creep_and_mu_s_comes_back(tmp_path: Path) -> None:
    """On data whose wheels creep at mu_s up to about 10 mm/s before they slide, the fit without
    creep puts mu_s some 0.04 high (the later slide matched by a later breakaway); with the creep
    kept, mu_s within 0.006 of the truth (a tolerance of params.json's mu_s) and the true speed
    inside the grid's set; the creep counts as a fitted parameter and stays out of the
    vocabulary's parameters."""
    from host_tools import params as P
    from host_tools.analyzer.effects import CREEP_KEY
    from host_tools.analyzer.fit.params import fitted_nuisance, vocabulary_only
    problem = _problem(tmp_path, {"friction_coefficient": {
        "mu_s": MU_S, "mu_k": MU_K, CREEP_KEY: V_CREEP}}, seed=13)
    runs = list(range(len(problem.preps)))
    fit = problem.fit(["friction_coefficient"], runs)
    assert CREEP_KEY in fit.params["friction_coefficient"], fit.params
    nu = fitted_nuisance(fit, "friction_coefficient")[CREEP_KEY]
    assert nu["lo"] <= V_CREEP <= nu["hi"], nu
    assert abs(fit.params["friction_coefficient"]["mu_s"] - MU_S) <= \
        P.TOLERANCES[("robot", "mu_s")], fit.params
    assert fit.n_free == 3
    assert CREEP_KEY not in vocabulary_only(fit.params)["friction_coefficient"]
    # the nominal model's form (the creep pinned: carried not at all) fits mu_s high
    c_idx = fit.coords.index(("friction_coefficient", CREEP_KEY))
    pinned = problem.fit(["friction_coefficient"], runs,
                         fixed={c_idx: 0.0}, decide_nuisance=False)
    assert CREEP_KEY not in pinned.params["friction_coefficient"]
    assert pinned.params["friction_coefficient"]["mu_s"] - MU_S > 0.02, pinned.params


def test_no_creep_is_kept_on_a_contact_that_slides_at_once(tmp_path: Path) -> None:
    """The nominal plant's own Coulomb switch (no creep): the likelihood ratio stays under its
    threshold, the fit is the nominal model's form (no creep key, two coordinates at most)."""
    from host_tools.analyzer.effects import CREEP_KEY
    from host_tools.analyzer.fit.params import fitted_nuisance
    for seed in (12, 17):
        problem = _problem(tmp_path, {"friction_coefficient": {"mu_s": MU_S, "mu_k": MU_K}},
                           seed)
        fit = problem.fit(["friction_coefficient"], list(range(len(problem.preps))))
        assert CREEP_KEY not in fit.params["friction_coefficient"], (seed, fit.params)
        assert fitted_nuisance(fit, "friction_coefficient") == {}
        assert fit.n_free <= 2 and not fit.nuisance_sets


def test_a_kept_creep_is_held_in_the_held_out_folds(tmp_path: Path) -> None:
    """The held-out folds refit the friction with the creep held at the whole fit's value (as
    mu_s's profile and a kept spin share): every fold carries the same speed."""
    from host_tools.analyzer.effects import CREEP_KEY
    from host_tools.analyzer.fit.judge import evaluate_candidate
    problem = _problem(tmp_path, {"friction_coefficient": {
        "mu_s": MU_S, "mu_k": MU_K, CREEP_KEY: V_CREEP}}, seed=13)
    cand = evaluate_candidate(problem, ["friction_coefficient"])
    c_idx = cand.fit.coords.index(("friction_coefficient", CREEP_KEY))
    assert CREEP_KEY in cand.fit.params["friction_coefficient"]
    v = cand.fit.values[c_idx]
    assert cand.fold_values and all(math.isclose(f[c_idx], v, rel_tol=1e-9)
                                    for f in cand.fold_values)
    assert np.isfinite(cand.delta_bic)
