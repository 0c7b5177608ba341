"""The thesis's stated numbers the demo holds its results against, the velocity loops, the gain
grid and the II.6 profile's ramp time; the plotting backend."""
from __future__ import annotations

from host_tools import protocol as P


THESIS = {
    "tau_max_nm": 0.095,
    "ii63_max_err_off_m": 0.30,
    "ii63_max_err_on_m": 0.16,
}
#: II.6.2: the captions' torques for the three profiles (Figs. II.16-II.21) and the simulated
#: slip (the text: 44 below the limit, 48 above, 72 at the motor's rated torque)
THESIS_II62_PEAK_NM = {44.0: 0.09, 48.0: 0.1, 72.0: 0.13}
THESIS_II62_SLIP = {44.0: False, 48.0: True, 72.0: True}
#: the velocity loops, name -> code of the C ABI's "controller" key: the protocol's
#: ``controller`` enum (protocol/protocol.json, whose codes are lib/control's), the thesis's
#: first, the order of the demo's tables and plots
CONTROLLERS = dict(sorted(P.definition().enums["controller"].items(),
                          key=lambda kv: (kv[0] != "thesis", kv[1])))
#: the thesis controller's gain grid for the sensitivity table (k_x 1/s, k_l N s/m)
GAIN_GRID_KX = (1.0, 2.0, 3.0)
GAIN_GRID_KL = (3.0, 4.0, 5.0, 6.0, 8.0)
#: II.6 profiles: wheel acceleration alpha for this long, then cruise
ACCEL_TIME_S = 0.5


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _total_mass_kg(plant) -> float:
    """m_t as lib/slipmodel has it: the static normal forces carry the whole weight m_t g."""
    return sum(plant.normal_forces()) / plant.get("robot.g")
