"""The main job: ``python -m host_tools demo --out OUT_DIR``.

1. **Thesis reproduction (II.6)** under ``OUT_DIR/thesis/``: the open-loop torque steps
   (II.6.1, slip plant against pure rolling), the 44/48/72 rad/s² profiles with the τmax clamp
   off (II.6.2, with the thesis controller's gain grid) and 72 rad/s² with the clamp on and off
   (II.6.3, beside the traction floor and the parameter change that would give the thesis's
   0.16 m), each with both velocity loops (``thesis``: II.47 as printed; ``improved``), the
   torque utilisation, as PNG figures, ``results.json`` and a Markdown table against the numbers
   the thesis states. The physics is ``lib/slipmodel`` (through ``host_tools._native.Plant``)
   and the controller is the firmware's ``lib/control`` (through
   ``host_tools.truth.Controller``); Python only drives them and draws.
2. **The analyzer on a concealed-effect dataset** under ``OUT_DIR/analyzer/``: runs made by the
   independent truth simulator (``sim/truth``) with an effect the nominal model leaves out, then
   ``host_tools analyze`` on them; its report and plots show the fit before and after.

Exit codes: 0 done, 1 a step failed, 2 bad input.

Modules: ``common`` (the thesis's stated numbers, the velocity loops, the grids), ``thesis``
(part 1), ``ii62``, ``ii63`` and ``utilisation`` (its experiments), ``table`` (its table against
the thesis), ``analyzer_part`` (part 2), ``cli`` (the command).
"""
from host_tools.demo.analyzer_part import _fit_plot, analyzer_demo  # noqa: F401
from host_tools.demo.cli import _index, add_arguments, main  # noqa: F401
from host_tools.demo.common import (ACCEL_TIME_S, CONTROLLERS, GAIN_GRID_KL,  # noqa: F401
                                    GAIN_GRID_KX, THESIS, THESIS_II62_PEAK_NM, THESIS_II62_SLIP,
                                    _plt)
from host_tools.demo.thesis import thesis_reproduction  # noqa: F401
