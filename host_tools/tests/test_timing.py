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


def run_with_overruns(tmp_path, overruns, boots=None, name="run"):
    """A run whose inner task counts ``overruns`` row by row (boot_count ``boots``)."""
    path = tmp_path / name
    cols = {f.name: f for f in D.by_name["Telemetry"].fields}
    with runfmt.RunWriter(str(path), {"experiment": "t"}) as w:
        for i, ovr in enumerate(overruns):
            row = {c: 0 for c in runfmt.TELEMETRY_COLUMNS}
            row["t_s"] = 0.02 * (i + 1)
            for task in ("inner", "outer", "telemetry"):
                row[cols[f"{task}_last"].column] = 16 * 300
                row[cols[f"{task}_max"].column] = 16 * 400
                row[cols[f"{task}_overruns"].column] = ovr if task == "inner" else 0
            row[cols["boot_count"].column] = boots[i] if boots else 7
            w.write_row(row)
    return str(path)


@pytest.mark.parametrize("overruns, boots, n", [
    ([0, 1, 2, 3, 0, 0], [7, 7, 7, 7, 8, 8], 3),              # a reset restarts the counter
    ([0, 2, 0, 1], [7, 7, 8, 8], 3),                          # overruns on both sides of it
    ([65534, 65535, 0, 1], None, 3),                          # the 16-bit counter wraps
])
def test_overruns_across_resets_and_wraps_are_counted(tmp_path, capsys, overruns, boots, n):
    r = run_with_overruns(tmp_path, overruns, boots)
    assert T.main(args(run=[r], isr_cycles=50)) == 1
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("task inner"))
    assert f"{n} overruns during the run" in line and "OVER BUDGET" in line
    assert T.overrun_increments(overruns, boots) == n


def test_an_isr_load_beyond_the_cpu_is_never_infinity(tmp_path, capsys):
    """--isr-cycles 1e6: the ISRs alone need 1,356 CPUs; the tasks have no bound and the
    --json is valid JSON (no Infinity), the utilisation over budget, exit 1."""
    o = tmp_path / "o.json"
    assert T.main(args(sim=[sim_file(tmp_path)], isr_cycles=1e6, json=str(o))) == 1
    out = capsys.readouterr().out
    assert "inf" not in out.replace("inflated", "")
    doc = json.loads(o.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in --json"))
    rows = {r["check"]: r for r in doc["rows"]}
    assert rows["task inner (25 ms)"]["worst"] is None and not rows["task inner (25 ms)"]["ok"]
    assert rows["cpu utilisation"]["worst"] > 1 and not rows["cpu utilisation"]["ok"]


def test_json_never_overwrites_an_input(tmp_path, capsys):
    r = run_with_overruns(tmp_path, [0, 0, 0])
    meta = Path(r, "meta.json").read_bytes()
    assert T.main(args(run=[r], json=str(Path(r, "meta.json")))) == 2
    assert "file of the run" in capsys.readouterr().err
    link = tmp_path / "o.json"
    link.symlink_to(Path(r, "telemetry.csv"))
    assert T.main(args(run=[r], json=str(link))) == 2
    sim = sim_file(tmp_path)
    assert T.main(args(sim=[sim], json=sim)) == 2
    assert Path(r, "meta.json").read_bytes() == meta
    assert json.loads(Path(sim).read_text())["format"] == "ddtiming/1"


def test_json_is_written_beside_and_renamed_not_through_a_link(tmp_path, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    o = tmp_path / "o.json"
    o.symlink_to(victim)  # a stale link where the output goes
    assert T.main(args(sim=[sim_file(tmp_path)], json=str(o))) == 0
    assert victim.read_text() == "keep" and not o.is_symlink()
    assert json.loads(o.read_text())["rows"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.json", "sim.json", "victim.txt"]


@pytest.mark.parametrize("kind", ["fifo", "/dev/zero"])
def test_sim_that_is_not_a_regular_file_is_refused_at_once(tmp_path, capsys, kind):
    import os
    path = "/dev/zero"
    if kind == "fifo":
        path = str(tmp_path / "fifo")
        os.mkfifo(path)
    assert T.main(args(sim=[path])) == 2
    assert "not a regular file" in capsys.readouterr().err


def test_one_row_per_task_with_units_and_every_measured_isr(tmp_path, capsys):
    """A run with fil.json: each task once (the worst of both sources), units on every
    figure, and the ISRs fil.json measured besides the encoder's (the 1 kHz tick, the UART
    UDRE) in the ISR load."""
    r = run_dir(tmp_path)
    sim_s = 2.0
    fil = {"sim_s": sim_s,
           "isr_cycles": {"1": {"calls": 400, "max": 58, "mean": 50.0}, "2": {"calls": 600, "max": 58, "mean": 50.0},
                          "42": {"calls": 2000, "max": 400, "mean": 326.0},
                          "52": {"calls": 9400, "max": 90, "mean": 82.0}},
           "encoder_isr": {"edges_driven": 1000, "calls": 1000, "max_cycles": 58, "mean_cycles": 50.0},
           "tasks": {"inner": {"max_cycles": 9000}, "outer": {"max_cycles": 20000},
                     "telemetry": {"max_cycles": 6000}}}
    (Path(r) / "fil.json").write_text(json.dumps(fil))
    T.main(args(run=[r]))
    out = capsys.readouterr().out
    lines = out.splitlines()
    for task in ("inner", "outer", "telemetry"):
        assert sum(ln.startswith(f"task {task} ") for ln in lines) == 1
    other = (2000 * 326.0 + 9400 * 82.0) / sim_s / 16e6
    assert f"other ISRs {100 * other:.2f} %" in out  # about 4.5 %
    inner = next(ln for ln in lines if ln.startswith("task inner"))
    assert "40,000 cycles" in inner and "worst of" in inner
    assert "% CPU" in next(ln for ln in lines if ln.startswith("cpu utilisation"))
