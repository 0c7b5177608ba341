"""analyze with its status streams closed (``2>&1 | head -1``) and stale temp-file links in
--out: the analysis ends normally with a whole report and the run untouched; the shortest
documented inner period still gets a phase search."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from test_badinput import _base

ROOT = Path(__file__).resolve().parents[3]


def test_stale_temp_links_and_a_closed_status_pipe(tmp_path):
    """``OUT/report.json.tmp`` and ``OUT/model.json.tmp`` linked to the run's files; stderr
    and stdout closed after the first line: exit 0, a whole report, the run untouched."""
    run = _base(tmp_path / "run", n=600)
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.json.tmp").symlink_to(run / "meta.json")
    (out / "model.json.tmp").symlink_to(run / "telemetry.csv")
    before = {f: (run / f).read_bytes() for f in ("meta.json", "telemetry.csv")}
    proc = subprocess.Popen([sys.executable, "-m", "host_tools", "analyze", str(run), "--out",
                             str(out), "--jobs", "2", "--no-plots"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stderr.readline()
    proc.stderr.close()
    proc.stdout.close()
    assert proc.wait(300) == 0
    assert {f: (run / f).read_bytes() for f in before} == before
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] and (out / "report.md").is_file() and not (out / "report.md").is_symlink()
    assert not [p for p in out.iterdir() if p.name.startswith(".analyze-staging-")]


def test_the_shortest_documented_inner_period_has_a_phase_search():
    """periods_s.inner = 1e-5 (the documented minimum) is shorter than the phase search's
    5e-5 s step: the search takes phases across the period instead of none."""
    import numpy as np
    from host_tools import params
    from host_tools.analyzer.prepare.timing import board_rate_phase

    ppr = params.ENCODER_PPR
    t = np.arange(0, 1.5, 0.02)
    n = np.round(1000 * t ** 2)
    w = np.gradient(n, t) * 2 * np.pi / ppr
    tel = {"t_s": t, "enc_r": n, "enc_l": n, "omega_r": w, "omega_l": w}
    phase = board_rate_phase(tel, 1e-5, ppr)
    assert phase is None or 0 <= phase < 1e-5
