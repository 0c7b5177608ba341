"""Read, validate and write run folders (``ddrun/1``, see shared/spec/run-format.md).

A run is a folder with ``meta.json``, ``telemetry.csv`` and optionally
``groundtruth.csv``.  This package is the one place that knows that layout:

* :func:`load_run` reads a folder into a :class:`Run` (meta with defaults filled,
  unknown keys kept; telemetry and ground truth as dicts of numpy columns) and
  validates it; :func:`read_groundtruth` reads a tracker's CSV with the same rules;
* :class:`RunWriter` streams ``telemetry.csv`` row by row (flushing as it goes)
  and writes ``meta.json``; :func:`write_groundtruth` writes ``groundtruth.csv``;
* :func:`check_compatible` refuses a set of runs whose parameters disagree.

Every problem raises :class:`RunFormatError`, whose message names the file and,
where it applies, the data row (1-based, the header is not counted), the line
of the file and the column.

Modules, by concern: ``spec`` (what the format is: version, defaults, columns, :class:`Run`,
:class:`RunFormatError`), ``read`` (text, CSV, meta.json, whole folders), ``validate``
(values, ranges, time, units, compatibility of runs) and ``write``.  Everything is
re-exported here: use ``from host_tools import runfmt`` / ``runfmt.load_run``.  The
underscored ``_PARAM_RANGES`` is re-exported for the test that checks it against params.json.
"""
from __future__ import annotations

from host_tools.runfmt.spec import (DEFAULT_META, FORMAT, GROUNDTRUTH_COLUMNS,
                                    GROUNDTRUTH_REQUIRED, TELEMETRY_COLUMNS, Run,
                                    RunFormatError, show_value, display)  # noqa: F401  (re-exported)
from host_tools.runfmt.validate import (_PARAM_RANGES, check_compatible,  # noqa: F401  (re-exported)
                                        max_stable_plant_dt_s, split_unknown, validate_meta)
from host_tools.runfmt.read import (ANALYZER_MIN_ROWS, json_depth_ok, label_runs,  # noqa: F401  (re-exported)
                                    load_meta, load_run, parse_number, read_groundtruth, read_text)
from host_tools.runfmt.write import RunWriter, write_atomic, write_groundtruth, write_run

__all__ = [
    "ANALYZER_MIN_ROWS", "DEFAULT_META", "FORMAT", "GROUNDTRUTH_COLUMNS", "GROUNDTRUTH_REQUIRED",
    "TELEMETRY_COLUMNS", "Run", "RunFormatError", "RunWriter", "check_compatible", "display", "json_depth_ok", "show_value",
    "label_runs", "load_meta", "load_run", "max_stable_plant_dt_s", "parse_number", "read_groundtruth", "read_text", "split_unknown",
    "validate_meta", "write_atomic", "write_groundtruth", "write_run",
]
