"""host_tools.timing: budgets from protocol.json against simavr measurements and recorded runs."""
from __future__ import annotations

import argparse
import math
import json
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools import params
from host_tools import protocol as P
from host_tools import runfmt
from host_tools import timing as T

ROOT = Path(__file__).resolve().parents[2]
D = P.definition()


def sim_file(tmp_path, isr=55, inner=9000, outer=21000, telemetry=6000, other=None, name="sim.json", **extra):
    doc = {"format": "ddtiming/1", "source": "test", "isr": {"encoder": {"cycles_per_event": isr}},
           "tasks": {"inner": {"max_cycles": inner}, "outer": {"max_cycles": outer},
                     "telemetry": {"max_cycles": telemetry}}}
    if other:
        doc["other_isr"] = other
    doc.update(extra)
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return str(p)


def run_dir(tmp_path, inner_units=500, overruns=(0, 0), n=50, drop_col=None):
    path = tmp_path / "run"
    cols = {f.name: f for f in D.by_name["Telemetry"].fields}
    with runfmt.RunWriter(str(path), {"experiment": "t"}) as w:
        for i in range(n):
            row = {c: 0 for c in runfmt.TELEMETRY_COLUMNS}
            row["t_s"] = 0.02 * i
            for task in ("inner", "outer", "telemetry"):
                row[cols[f"{task}_last"].column] = 16 * (inner_units if task == "inner" else 300)
                row[cols[f"{task}_max"].column] = 16 * (inner_units if task == "inner" else 400)
                row[cols[f"{task}_overruns"].column] = overruns[0] if i < n // 2 else overruns[1]
            if drop_col:
                row.pop(drop_col)
            w.write_row(row)
    return str(path)


def args(**kw):
    p = argparse.ArgumentParser()
    T.add_arguments(p)
    a = p.parse_args([])
    for k, v in kw.items():
        setattr(a, k, v)
    return a


def test_edge_rate_from_the_motor_and_encoder():
    # 2 wheels at the datasheet no-load speed, the table's encoder edges per turn (about 21,700/s)
    no_load, ppr = params.MOTOR["no_load_rad_s"], params.ENCODER_PPR
    assert T.edge_rate_max(D) == pytest.approx(2 * no_load / (2 * math.pi) * ppr, rel=1e-12)


def test_within_budget(tmp_path, capsys):
    assert T.main(args(sim=[sim_file(tmp_path)])) == 0
    out = capsys.readouterr().out
    for check in ("isr encoder per edge", "isr load at 21,652 edges/s", "task inner (25 ms)", "task outer (50 ms)",
                  "task telemetry (20 ms)", "all tasks released together", "cpu utilisation"):
        assert check in out
    assert "OVER BUDGET" not in out


def test_isr_over_budget(tmp_path, capsys):
    assert T.main(args(sim=[sim_file(tmp_path, isr=61)])) == 1
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("isr encoder per edge"))
    assert "OVER BUDGET" in line and "-1" in line


def test_isr_preemption_pushes_task_over_budget(tmp_path, capsys):
    budget = next(t["budget_cycles"] for t in D.tasks() if t["name"] == "inner")
    measured = budget * 0.95  # fits on its own...
    assert T.main(args(sim=[sim_file(tmp_path, isr=1, inner=measured)])) == 0
    capsys.readouterr()
    # ...but not with the encoder ISR at 58 cycles/edge stealing ~7.8 % of the CPU
    assert T.main(args(sim=[sim_file(tmp_path, isr=58, inner=measured)])) == 1
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("task inner"))
    assert "OVER BUDGET" in line and "ISR load" in line


def test_other_isrs_and_design_rate(tmp_path, capsys):
    # a UART ISR so heavy that the CPU saturates
    f = sim_file(tmp_path, other=[{"name": "uart", "cycles_per_event": 3000, "events_per_s": 5000}])
    assert T.main(args(sim=[f])) == 1
    assert "isr load at" in capsys.readouterr().out
    # 90 cycles/edge cannot keep up with 200 000 edges/s (18 M cycles/s > 16 M)
    assert T.main(args(sim=[sim_file(tmp_path, isr=90)])) == 1
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("isr load at design"))
    assert "OVER BUDGET" in line


def test_recorded_run(tmp_path, capsys):
    r = run_dir(tmp_path)
    assert T.main(args(run=[r], isr_cycles=50)) == 0
    out = capsys.readouterr().out
    assert "task inner (25 ms)" in out and "run" in out
    assert "telemetry interval median 20.00 ms" in out


def test_recorded_run_with_overruns_fails(tmp_path, capsys):
    r = run_dir(tmp_path, overruns=(2, 5))
    assert T.main(args(run=[r])) == 1
    out = capsys.readouterr().out
    assert "3 overruns during the run" in out
    assert "NOT inflated" in out  # said plainly when no ISR figure was given


def test_recorded_run_saturated_time_fails(tmp_path, capsys):
    r = run_dir(tmp_path, inner_units=65535)
    assert T.main(args(run=[r])) == 1
    assert "saturated" in capsys.readouterr().out


def test_bad_inputs_exit_2(tmp_path, capsys):
    assert T.main(args()) == 2
    assert "nothing to check" in capsys.readouterr().err
    p = tmp_path / "x.json"
    p.write_text("{\"format\": \"ddtiming/1\", \"isr\": {\"encoder\": {\"cycles_per_event\": \"fast\"}}}")
    assert T.main(args(sim=[str(p)])) == 2
    assert "key 'isr.encoder.cycles_per_event': must be a number in [0," in capsys.readouterr().err
    p.write_text("{not json")
    assert T.main(args(sim=[str(p)])) == 2
    assert "x.json, line 1, character 2: invalid JSON" in capsys.readouterr().err
    r = run_dir(tmp_path, drop_col="outer_overruns")
    assert T.main(args(run=[r])) == 2
    assert "line 1, column 'outer_overruns': missing" in capsys.readouterr().err
    assert T.main(args(sim=[sim_file(tmp_path, f_cpu_hz=8000000)])) == 2


def test_cli_through_dispatcher(tmp_path):
    f = sim_file(tmp_path, isr=61)
    r = subprocess.run([sys.executable, "-m", "host_tools", "timing", "--sim", f, "--json", str(tmp_path / "o.json")],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 1, r.stderr
    rows = json.loads((tmp_path / "o.json").read_text())["rows"]
    assert any(row["check"] == "isr encoder per edge" and not row["ok"] for row in rows)


def test_fil_json_in_the_run_folder_is_used(tmp_path, capsys):
    r = run_dir(tmp_path)
    fil = {"encoder_isr": {"edges_driven": 1000, "calls": 1000, "max_cycles": 64, "mean_cycles": 55.0},
           "tasks": {"inner": {"max_cycles": 9000, "overruns": 0}, "outer": {"max_cycles": 20000, "overruns": 0},
                     "telemetry": {"max_cycles": 19000, "overruns": 0}, "running_frames": 10}}
    (Path(r) / "fil.json").write_text(json.dumps(fil))
    assert T.main(args(run=[r])) == 1  # 64 cycles per edge > 60
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("isr encoder per edge"))
    assert "run/fil.json" in line and "OVER BUDGET" in line
    assert T.main(args(run=[r], no_fil=True)) == 0
