"""Stage 2 of the analysis: replay a prepared run through the plant and put recording and
simulation side by side.

The plant is lib/slipmodel's, reached through host_tools._native (never re-implemented
here).  A *replayer* turns (prepared run, effects) into simulated plant outputs; the
open-loop ones (:mod:`.openloop`) drive the plant with the recorded duty or the recorded
torque command.  :class:`~.closedloop.ClosedLoopReplay` runs the firmware's controller
(lib/control through its C ABI) against the plant and reproduces the torque and duty the
firmware should have commanded.  Commands no frame reported are filled in and their
uncertainty replayed (:mod:`.unseen`); long runs are replayed in windows (out of slips:
:mod:`.edges`) re-anchored to the camera (:mod:`.anchors`).  :mod:`.nominal` is the stage:
the nominal replays of all runs.

:func:`~.channels.channels` then maps a recording and a simulation onto common channels, each
a pair (recorded, simulated) on the recording's own time base."""
