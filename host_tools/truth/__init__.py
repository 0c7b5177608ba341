"""The nominal closed loop and the independent truth simulator.

* :class:`Controller` — ``lib/control`` through its C ABI, re-exported from
  :mod:`host_tools.control` (where the binding lives).
* :func:`nominal_closed_loop` — that controller in closed loop with the *nominal* plant
  (``lib/slipmodel``), run forward tick by tick by ``lib/closedloop``'s driver
  (:class:`host_tools.control.ClosedLoop`). No physics in Python.
* :func:`build_truth`, :class:`TruthSim`, :func:`simulate_run` — the independent truth simulator
  of ``sim/truth`` (the one deliberate second implementation of the physics, see
  ``sim/truth/truth.h``), compiled with the firmware's ``lib/control`` into
  ``.build/truth/libtruth.so``; :data:`RECORDER_DEFAULTS` are the recorder variants (the
  firmware pipeline by default; the truth's own PI loop and odometry, other periods, jitter,
  lost frames, camera rate and noise, wrapped headings), :func:`tour_reference` a long
  reference, and the motor current is logged like the Motor Shield R3 does.

Modules: ``nominal`` (the nominal closed loop), ``sim`` (the truth simulator's binding),
``recorder`` (recorder options, the current sense), ``references`` (the tour and the reversals),
``engine`` (one run's simulator on the chosen engine), ``run`` (the run writer), ``cli``
(``python -m host_tools.truth``).
"""
from host_tools.control import INNER_S, ClosedLoop, Controller  # noqa: F401  (re-exported)
from host_tools.control import REF_KINDS as _REF_KINDS  # noqa: F401
from host_tools.truth.cli import main  # noqa: F401
from host_tools.truth.engine import configure  # noqa: F401
from host_tools.truth.nominal import nominal_closed_loop  # noqa: F401
from host_tools.truth.recorder import (CURRENT_SENSE, NOMINAL_META_MOTOR,  # noqa: F401
                                       NOMINAL_META_ROBOT, PPR, RECORDER_DEFAULTS,
                                       TELEMETRY_SPEC_COLUMNS, add_recorder_arguments,
                                       recorder_config, recorder_from_args, wrap_heading)
from host_tools.truth.references import reversal_reference, tour_reference  # noqa: F401
from host_tools.truth.run import simulate_run  # noqa: F401
from host_tools.truth.sim import (EXTRA_EFFECTS, SPEC_EFFECTS, TRUTH_LIB, TruthSim,  # noqa: F401
                                  _tlib, build_truth)
