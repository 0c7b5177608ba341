"""The analyzer, by stage in the order ``pipeline.analyze`` calls them (docs/ARCHITECTURE.md).

Its messages have one path: the package's logger :data:`log` (``host_tools.analyzer``), whose
records ``host_tools._stdio`` writes; :data:`stage_log` is the default ``log`` of ``analyze``
(a stage line on a terminal, else a STATUS line), :data:`lines` the lines of the fits'
progress where no bar is drawn."""
from __future__ import annotations

import logging

from host_tools import _progress

log = logging.getLogger(__name__)
stage_log = _progress.stages("analyze", log)
lines = _progress.stamped("analyze", log)
