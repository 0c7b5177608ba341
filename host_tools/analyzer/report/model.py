"""The updated model-parameter file (model.json)."""
from __future__ import annotations

from typing import Mapping, Sequence

from host_tools.model import FORMAT as MODEL_FORMAT


def updated_model(meta: Mapping, effects: Mapping[str, Mapping[str, float]],
                  sources: Sequence[str]) -> dict:
    """The updated model-parameter file (format ``ddmodel/1``, see docs/analyzer.md)."""
    from host_tools import _native
    robot = dict(meta["robot"])
    motor = dict(meta["motor"])
    plant = _native.Plant.from_meta(meta)
    for name, params in effects.items():
        plant.set_effect(name, **params)
    # fold the effects that are plain parameter changes into the parameters themselves
    if "friction_coefficient" in effects:
        robot["mu_s"] = effects["friction_coefficient"].get("mu_s", robot["mu_s"])
        robot["mu_k"] = effects["friction_coefficient"].get("mu_k", robot["mu_k"])
    if "wheel_radius" in effects:
        robot["r"] = effects["wheel_radius"]["r_eff"]
    if "track_width" in effects:
        robot["b"] = effects["track_width"]["b_eff"]
    tr, tl = plant.tau_max()
    return {"format": MODEL_FORMAT, "robot": robot, "motor": motor,
            "encoder_ppr": int(meta["encoder_ppr"]),
            "effects": {k: {p: float(v) for p, v in d.items()} for k, d in effects.items()},
            "tau_max_nm": {"right": tr, "left": tl, "min": min(tr, tl)},
            "source_runs": list(sources)}
