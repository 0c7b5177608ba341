"""Physics engines other than the truth simulator's own, driven by the same recorder
(``sim/truth``'s external-plant mode, ``tr_set_plant``). Each engine module imports its
third-party physics library lazily, so that the rest of host_tools works without it.

* :mod:`host_tools.engines.mujoco_robot` — the robot as a MuJoCo model (PyPI ``mujoco``).
"""
ENGINES = ("truth", "mujoco")
