"""The updated model-parameter file (model.json)."""
from __future__ import annotations

from typing import Any, Mapping, Sequence

from host_tools.analyzer.effects import creep_form, folded_robot, plant_setup
from host_tools.model import FORMAT as MODEL_FORMAT


def updated_model(meta: Mapping[str, Any], effects: Mapping[str, Mapping[str, float]],
                  sources: Sequence[str]) -> dict[str, Any]:
    """The updated model-parameter file (format ``ddmodel/1``, see docs/analyzer.md)."""
    from host_tools import _native
    from host_tools.analyzer.replay.normal_forces import rolling_form
    robot = dict(meta["robot"])
    # the model is replayed in the nominal model's form (plant_config): a kept spin share is
    # folded into the load transfer's height there, and no nuisance parameter is the model's;
    # a kept creep is the plant's own Stribeck law tied to mu_s (effects.creep_form)
    effects = creep_form(rolling_form(robot, effects))
    motor = dict(meta["motor"])
    plant_robot, plant_effects = plant_setup(robot, effects)
    plant = _native.Plant.from_meta({**meta, "robot": plant_robot})
    for name, params in plant_effects.items():
        plant.set_effect(name, **params)
    # fold the effects that are plain parameter changes into the parameters themselves
    robot = folded_robot(robot, effects)
    tr, tl = plant.tau_max()
    return {"format": MODEL_FORMAT, "robot": robot, "motor": motor,
            "encoder_ppr": int(meta["encoder_ppr"]),
            "effects": {k: {p: float(v) for p, v in d.items()} for k, d in effects.items()},
            "tau_max_nm": {"right": tr, "left": tl, "min": min(tr, tl)},
            "source_runs": list(sources)}
