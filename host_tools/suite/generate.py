"""Generate the suite's run folders with the truth simulator's recorder, deterministically,
each case with its own recorder (``Case.recorder``: host_tools.truth.RECORDER_DEFAULTS
overrides) and engine (``Case.engine``: the truth's physics or the MuJoCo model).

Layout under the data folder::

    runs/<case>/run-<k>/        meta.json, telemetry.csv, groundtruth.csv  (what the analyzer reads)
    labels/<case>.json          the hidden truth (never passed to the analyzer)
    labels/<case>/run-<k>.truth.csv   true state per telemetry frame
"""
from __future__ import annotations

import json
import os
import shutil

from host_tools import truth
from host_tools.suite.cases import Case


def generate_case(case: Case, data_dir: str, overwrite: bool = False) -> list[str]:
    """Write the case's runs and label; return the run folders."""
    run_root = os.path.join(data_dir, "runs", case.name)
    label_root = os.path.join(data_dir, "labels")
    if os.path.isdir(run_root):
        if not overwrite:
            raise FileExistsError(f"{run_root} exists (use overwrite)")
        shutil.rmtree(run_root)
    hidden = os.path.join(label_root, case.name)
    shutil.rmtree(hidden, ignore_errors=True)
    os.makedirs(label_root, exist_ok=True)
    runs = []
    for k, (ref, clamp, dur) in enumerate(case.experiments):
        path = os.path.join(run_root, f"run-{k}")
        truth.simulate_run(path, ref, case.effects, clamp=clamp, duration_s=dur,
                           seed=case.seed + k, hidden_dir=hidden, recorder=case.recorder,
                           engine=case.engine, engine_options=case.engine_options or None)
        runs.append(path)
    with open(os.path.join(label_root, f"{case.name}.json"), "w") as fh:
        json.dump(case.label(), fh, indent=2)
    return runs
