"""The ``load_transfer`` fit's nuisance spin share k (fit/params.py ``spin_param``): fitted
beside h through the plant's own theta'' term and kept where its 1-sigma is below the
tolerance's standard uncertainty (params.json ``model.spin_share``: 0.5/sqrt(3)); otherwise the
fit is the nominal model's form (k^ h_s as a rolling height), unchanged."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from _native_skip import needs_native

pytestmark = needs_native()

from host_tools import params as P  # noqa: E402

H_TRUE = 0.06


def _problem(tmp_path: Path) -> Any:
    """The analyzer's own fit problem (the pipeline's stages up to the detection) of slipping
    starts and stops of a robot whose whole spin-up reacts on the body (k = 1, the truth
    simulator's physics, through the plant's own theta'' term) with its centre of mass at
    H_TRUE."""
    from host_tools import _native
    from host_tools.analyzer import pipeline as PL
    from host_tools.analyzer import synth
    from host_tools.analyzer.replay.normal_forces import wheels_on_axle

    def factory(meta: Any) -> Any:
        pl = _native.Plant.from_meta(meta)
        for k, v in wheels_on_axle(dict(meta["robot"]), 1.0).items():
            pl.set(f"robot.{k}", v)
        pl.set("plant.spin_share", 1.0)
        return pl
    paths = synth.make_case(tmp_path / "k1", {"load_transfer": {"h": H_TRUE}},
                            profiles=("ramp", "brake", "ramp"), seed=3, duration_s=2.0,
                            plant_factory=factory)
    return PL.front(paths).det.problem


def test_the_spin_share_is_fitted_beside_h_where_the_slips_identify_it(tmp_path: Path) -> None:
    """A robot with the whole spin-up (k = 1): the nominal model's form (k^ = 1/2 as a rolling
    height) fits h some (1 - k^) h_s = 20 mm high; with k fitted beside it through the plant's
    theta'' term the slips identify k (1-sigma below 0.5/sqrt(3)), k comes out near 1 and h near
    its true value; the kept k counts as a fitted parameter (BIC, folds) and stays out of the
    vocabulary's parameters (the report's ``params``: h only)."""
    from host_tools.analyzer.replay.normal_forces import SPIN_SHARE, spin_height
    problem = _problem(tmp_path)
    runs = list(range(len(problem.preps)))
    fit = problem.fit(["load_transfer"], runs)
    h_s = spin_height(problem.preps[0].robot)
    # before the nuisance: h 89.6 mm (the rolling height's (1 - k^) h_s and the slips' share)
    assert abs(fit.params["load_transfer"]["h"] - H_TRUE) < 0.25 * (1.0 - SPIN_SHARE) * h_s, \
        fit.params
    from host_tools.analyzer.fit.params import fitted_nuisance, vocabulary_only
    from host_tools.analyzer.replay.normal_forces import SPIN_KEY
    sigma_max = P.TOLERANCES[("model", "spin_share")] / math.sqrt(3.0)
    assert SPIN_KEY in fit.params["load_transfer"], fit.params
    nu = fitted_nuisance(fit, "load_transfer")[SPIN_KEY]
    assert nu["std"] < sigma_max
    assert abs(nu["value"] - 1.0) < max(2.0 * nu["std"], 0.1), nu
    assert fit.n_free == 2
    assert vocabulary_only(fit.params) == {"load_transfer": {"h": fit.params["load_transfer"]["h"]}}
    # the nominal model's form (the nuisance pinned, carried not at all): h high by about
    # (1 - k^) h_s, as the analyzer fitted it before
    k_idx = fit.coords.index(("load_transfer", SPIN_KEY))
    pinned = problem.fit(["load_transfer"], runs, fixed={k_idx: SPIN_SHARE})
    assert SPIN_KEY not in pinned.params["load_transfer"] and pinned.n_free == 1
    assert pinned.params["load_transfer"]["h"] - H_TRUE > 0.5 * (1.0 - SPIN_SHARE) * h_s


def test_an_unkept_spin_share_leaves_the_nominal_form_exactly() -> None:
    """The nuisance pinned is carried not at all: the plant is the nominal model's (k^ h_s as a
    rolling height, its own theta'' term off), the same plant as a load transfer without it;
    kept, the plant carries k through its theta'' term and h alone as the height."""
    from host_tools.analyzer.fit.params import effects_dict, params_for
    from host_tools.analyzer.replay.normal_forces import (SPIN_KEY, SPIN_SHARE, plant_config,
                                                          spin_height)
    from host_tools.runfmt import validate_meta
    meta = validate_meta({})
    ps = params_for(["load_transfer"], meta, {"load_transfer": {"h": 0.0}})
    assert [(p.effect, p.name) for p in ps] == [("load_transfer", "h"),
                                                ("load_transfer", SPIN_KEY)]
    assert math.isclose(float(ps[1].nuisance or 0.0),
                        P.TOLERANCES[("model", "spin_share")] / math.sqrt(3.0))
    pinned = effects_dict(ps, [0.07, SPIN_SHARE], {1: 0.5})
    assert pinned == {"load_transfer": {"h": 0.07}}
    a, b = plant_config(P.ROBOT, pinned), plant_config(P.ROBOT, {"load_transfer": {"h": 0.07}})
    assert a == b and a.keys == {"plant.spin_share": 0.0}
    assert math.isclose(a.effects["load_transfer"]["h"],
                        0.07 + SPIN_SHARE * spin_height(P.ROBOT), rel_tol=1e-12)
    kept = plant_config(P.ROBOT, effects_dict(ps, [0.07, 0.9]))
    assert kept.keys == {"plant.spin_share": 0.9}
    assert math.isclose(kept.effects["load_transfer"]["h"], 0.07, rel_tol=1e-12)
    # the tolerance ensemble replays the nominal model (no effect): never the theta'' term
    assert plant_config(P.ROBOT, {}).keys == {"plant.spin_share": 0.0}
    assert np.isfinite(a.effects["load_transfer"]["h"])


def test_the_model_carries_a_kept_spin_share_in_the_nominal_form() -> None:
    """model.json is replayed in the nominal model's form (``plant_config``: k^ h_s added to
    its height, ``fil.model_plant_keys``): a kept k is folded into h there, so the model's
    rolling height is the fitted plant's, h + k h_s, and no nuisance key reaches the model."""
    from host_tools.analyzer.replay.normal_forces import SPIN_KEY, plant_config, spin_height
    from host_tools.analyzer.report.model import updated_model
    from host_tools.runfmt import validate_meta
    meta = validate_meta({})
    fitted = {"load_transfer": {"h": 0.06, SPIN_KEY: 1.0}}
    model = updated_model(meta, fitted, ["run-0"])
    lt = model["effects"]["load_transfer"]
    assert set(lt) == {"h"}
    replayed = plant_config(dict(meta["robot"]), model["effects"])
    assert replayed.keys == {"plant.spin_share": 0.0}
    assert math.isclose(replayed.effects["load_transfer"]["h"],
                        0.06 + 1.0 * spin_height(meta["robot"]), rel_tol=1e-12)
    # without a kept k the model's h is the fit's, as before
    plain = updated_model(meta, {"load_transfer": {"h": 0.06}}, ["run-0"])
    assert plain["effects"]["load_transfer"] == {"h": 0.06}
