"""Tests of ``ddrobot batch`` (host_tools.batch): run sets from trees and manifests, the drift
test, failures recorded per set, resumability, and a real cluster: a ``dask scheduler`` and
two ``dask worker`` processes on 127.0.0.1, one of them killed mid-batch."""
from __future__ import annotations

import json
import os
import threading
import time

import numpy as np
import pytest

from _native_skip import needs_native

from host_tools.batch import fleet
from host_tools.batch.cluster import ProcessCluster
from host_tools.batch import task as T
from host_tools.batch.sets import BadInput, RunSet, discover, from_manifest, from_tree

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}
ARC = {"kind": "arc", "accel": 0.8, "cruise": 0.5, "radius": 0.5}


def _fake_run(path):
    os.makedirs(path)
    with open(os.path.join(path, "meta.json"), "w") as fh:
        fh.write("{}")


# ------------------------------------------------------------------ run sets


def test_tree_gives_one_set_per_robot_and_day(tmp_path):
    for robot, date, runs in (("r1", "2026-01-02", 2), ("r1", "2026-01-03", 1),
                              ("r2", "2026-01-02", 1)):
        for k in range(runs):
            _fake_run(tmp_path / robot / date / f"run-{k}")
    _fake_run(tmp_path / "r2" / "2026-01-04" / "morning" / "run-0")
    sets = from_tree(str(tmp_path))
    assert [(s.robot, s.date, s.name, len(s.runs)) for s in sets] == [
        ("r1", "2026-01-02", "", 2), ("r1", "2026-01-03", "", 1), ("r2", "2026-01-02", "", 1),
        ("r2", "2026-01-04", "morning", 1)]
    assert sets[3].set_id == "r2/2026-01-04/morning"
    assert all(os.path.isabs(r) for s in sets for r in s.runs)


def test_manifest_csv_groups_rows_and_names_the_bad_cell(tmp_path):
    for k in range(3):
        _fake_run(tmp_path / "runs" / f"a{k}")
    m = tmp_path / "m.csv"
    m.write_text("robot,date,run\nr1,2026-01-02,runs/a0\nr1,2026-01-02,runs/a1\n"
                 "r2,2026-01-02,runs/a2\n")
    sets = discover(str(m))
    assert [(s.set_id, len(s.runs)) for s in sets] == [("r1/2026-01-02", 2), ("r2/2026-01-02", 1)]
    m.write_text("robot,date,run\nr1,2026-01-02,runs/a0\nr1,2026-13-02,runs/a1\n")
    with pytest.raises(BadInput, match=r"row 3, column 2 \(date\)"):
        from_manifest(str(m))
    m.write_text("robot,date,run\nr1,2026-01-02,runs/nothing\n")
    with pytest.raises(BadInput, match=r"row 2, column 3 \(run\).*not a run folder"):
        from_manifest(str(m))
    m.write_text("robot,run\nr1,runs/a0\n")
    with pytest.raises(BadInput, match="missing column.*date"):
        from_manifest(str(m))


def test_manifest_json(tmp_path):
    _fake_run(tmp_path / "x")
    m = tmp_path / "m.json"
    m.write_text(json.dumps({"sets": [{"robot": "r9", "date": "2026-02-01", "runs": ["x"]}]}))
    (s,) = from_manifest(str(m))
    assert (s.robot, s.date, s.runs) == ("r9", "2026-02-01", [str(tmp_path / "x")])
    m.write_text(json.dumps({"sets": [{"robot": "r9", "date": "2026-02-01", "runs": [3]}]}))
    with pytest.raises(BadInput, match=r"sets\[0\], runs\[0\]"):
        from_manifest(str(m))


def test_bad_manifest_exits_2(tmp_path, capsys):
    from host_tools.__main__ import main
    m = tmp_path / "m.csv"
    m.write_text("robot,date,run\nr1,yesterday,x\n")
    assert main(["batch", str(m), "--out", str(tmp_path / "out")]) == 2
    assert "row 2, column 2" in capsys.readouterr().err


# ------------------------------------------------------------------ drift test


def _records(robot, values, stds, param="wheel_radius.r_eff"):
    eff, p = param.split(".")
    return [{"status": "ok", "robot": robot, "date": f"2026-03-{d + 1:02d}", "set_id": robot,
             "report": {"verdict": "explained",
                        "selected": [{"effect": eff, "params": {p: v}}],
                        "candidates": [{"effect": eff, "params": {p: v}, "param_std": {p: s}}]}}
            for d, (v, s) in enumerate(zip(values, stds))]


def test_trend_flagged_against_uncertainty_and_scatter():
    rng = np.random.default_rng(1)
    days = np.arange(10)
    scatter = 1e-4  # day-to-day scatter well beyond the fits' stated 5e-6
    wear = 0.0360 - 1.2e-4 * days + rng.normal(0, scatter, 10)
    steady = 0.0374 + rng.normal(0, scatter, 10)
    small = 0.0374 - 0.2e-4 * days + rng.normal(0, scatter, 10)  # a trend inside the scatter
    recs = (_records("wear", wear, [5e-6] * 10) + _records("steady", steady, [5e-6] * 10) +
            _records("small", small, [5e-6] * 10))
    series = {s["robot"]: s for s in fleet.drift(recs)}
    assert series["wear"]["flag"]
    assert not series["steady"]["flag"]
    assert not series["small"]["flag"]
    # the scatter is estimated: without it, the stated 5e-6 would make 'steady' a drift
    assert series["steady"]["test"]["tau"] > 5 * 5e-6
    t = fleet.trend_test(days, steady, [5e-6] * 10)
    assert t["p"] > 1e-3


def test_trend_uses_the_fit_uncertainty_when_there_is_no_extra_scatter():
    rng = np.random.default_rng(2)
    days = np.arange(8)
    sd = np.full(8, 0.02)
    y = 0.6 + 0.03 * days + rng.normal(0, 0.02, 8)  # 0.21 V over 8 days, sigma 0.02
    assert fleet.trend_test(days, y, sd)["p"] < 1e-3
    # the same values with ten times the stated uncertainty are not a significant trend
    assert fleet.trend_test(days, y, 10 * sd)["p"] > 0.01


def test_too_few_days_not_tested():
    recs = _records("r", [0.036, 0.035, 0.034], [1e-6] * 3)
    (s,) = fleet.drift(recs)
    assert not s["tested"] and not s["flag"]


def test_table_and_report(tmp_path):
    pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq
    recs = _records("wear", 0.036 - 1e-4 * np.arange(6), [1e-6] * 6)
    recs.append({"status": "timeout", "robot": "wear", "date": "2026-03-09", "set_id": "x",
                 "error": "stopped after 5 s"})
    p, c = fleet.write_table(recs, str(tmp_path))
    t = pq.read_table(p).to_pydict()
    assert t["wheel_radius.r_eff"][:2] == [0.036, 0.036 - 1e-4]
    assert t["wheel_radius.r_eff_std"][0] == 1e-6
    assert t["status"][-1] == "timeout" and t["wheel_radius.r_eff"][-1] is None
    assert open(c).readline().startswith('"set_id","robot","date"')
    md, series = fleet.write_report(recs, str(tmp_path))
    text = open(md).read()
    assert "| wear | wheel_radius.r_eff |" in text and "stopped after 5 s" in text
    assert os.path.isfile(tmp_path / "plots" / "wear__wheel_radius.r_eff.png")


def test_launch_limits_the_memory_of_the_analysis():
    """The subprocess's own limit: 600 MB fail under a 300 MB address-space limit, pass without."""
    import subprocess
    import sys
    code = "b = bytearray(600 * 2**20); print('allocated')"
    for mem_mb, ok in ((0, True), (300, False)):
        r = subprocess.run([sys.executable, "-m", "host_tools.batch._launch", str(os.getpid()),
                            str(mem_mb), "--", sys.executable, "-c", code],
                           capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert (r.returncode == 0 and "allocated" in r.stdout) == ok, (mem_mb, r.stderr)
        if not ok:
            assert "MemoryError" in r.stderr


# ------------------------------------------------------------------ tasks (real analyses)


def _sim(path, effects=None, seed=0, ref=LINE):
    from host_tools import truth
    return truth.simulate_run(str(path), ref, effects or {}, duration_s=1.5, seed=seed)


@needs_native(truth=True)
def test_task_records_failures_and_resumes(tmp_path):
    good = RunSet("r1", "2026-01-01", "", [_sim(tmp_path / "runs" / "g0", seed=1)])
    # a run folder whose telemetry is broken: the analyzer's exit 2, with the file and row
    bad_run = _sim(tmp_path / "runs" / "b0", seed=2)
    with open(os.path.join(bad_run, "telemetry.csv"), "a") as fh:
        fh.write("1,2,x\n")
    bad = RunSet("r1", "2026-01-02", "", [bad_run])
    out = str(tmp_path / "out")
    rec = T.analyze_set(good, out, timeout_s=300)
    assert rec["status"] == "ok" and rec["report"]["verdict"] in ("no_mismatch", "explained",
                                                                  "unexplained")
    assert T.is_done(out, good)
    rec = T.analyze_set(bad, out, timeout_s=300)
    assert rec["status"] == "bad_input" and "telemetry.csv" in rec["error"]
    slow = RunSet("r1", "2026-01-03", "", good.runs)
    rec = T.analyze_set(slow, out, timeout_s=0.3)
    assert rec["status"] == "timeout" and not T.is_done(out, slow)
    assert T.read_result(out, slow.set_id)["status"] == "timeout"
    assert os.listdir(os.path.join(out, ".partial")) == []  # every attempt was published
    # a changed recording is not done any more
    os.utime(os.path.join(good.runs[0], "telemetry.csv"), ns=(1, 1))
    assert not T.is_done(out, good)


# ------------------------------------------------------------------ a real cluster


@needs_native(truth=True)
def test_cluster_with_a_worker_killed_mid_batch(tmp_path):
    """A scheduler and two workers as separate processes on 127.0.0.1; one worker (with its
    nanny) is killed while both are analyzing: every set still gets its result, the killed
    worker's analysis does not outlive it, and a re-run skips everything."""
    psutil = pytest.importorskip("psutil")
    from host_tools.batch.run import run_batch
    sets = []
    effects = [None, {"wheel_radius": {"r_eff": 0.0378}}, None,
               {"driver_voltage_drop": {"volts": 1.0}}]
    for i, eff in enumerate(effects):
        run = _sim(tmp_path / "fleet" / f"r{i}" / "2026-01-01" / "run-0", eff, seed=10 + i,
                   ref=LINE if i % 2 else ARC)
        sets.append(RunSet(f"r{i}", "2026-01-01", "", [run]))
    with ProcessCluster(2, log=str(tmp_path / "cluster.log")) as cluster:
        address = cluster.address
        assert address.startswith("tcp://127.0.0.1:")
        out = str(tmp_path / "out")
        result: dict = {}
        lines: list[str] = []
        th = threading.Thread(target=lambda: result.update(
            zip(("records", "stats"), run_batch(sets, out, scheduler=address, timeout_s=120,
                                                progress=lines.append))))
        th.start()
        partial = os.path.join(out, ".partial")
        victim = cluster.workers[1]

        def victims_analyses():
            found = []
            for p in psutil.Process(victim.pid).children(recursive=True):
                try:
                    if "analyze" in " ".join(p.cmdline()):
                        found.append(p)
                except psutil.Error:  # it ended while we looked
                    pass
            return found

        # both workers busy: two analyses in flight, the victim's started (its attempt folder
        # is made before its analyzer process, which is what the kill must take with it)
        analyses: list = []
        t0 = time.time()
        while time.time() - t0 < 90:
            if os.path.isdir(partial) and len(os.listdir(partial)) >= 2:
                analyses = victims_analyses()
                if analyses:
                    break
            time.sleep(0.1)
        in_flight = set(os.listdir(partial)) if os.path.isdir(partial) else set()
        assert len(in_flight) >= 2, "the workers never started two analyses"
        assert analyses, "the killed worker was running no analysis"
        cluster.kill_worker(1)  # nanny and worker: SIGKILL to the process group
        th.join(timeout=240)
        assert not th.is_alive(), "the batch did not finish"
        recs = result["records"]
        assert [r["status"] for r in recs] == ["ok"] * len(sets), \
            [(r["set_id"], r["status"], r.get("error")) for r in recs]
        for s in sets:
            assert T.read_result(out, s.set_id)["report"]["verdict"]
        # progress: one line per finished set, with the counts
        done = [ln for ln in lines if ln.startswith("[")]
        assert len(done) == len(sets) and done[-1].startswith(f"[{len(sets)}/{len(sets)}]")
        assert f"{len(sets)} ok, 0 failed" in done[-1]
        # the killed worker's analysis was stopped with it (it would race its redo): it ends,
        # and before its end it wrote no report (an analysis left to run would have finished)
        def running(p):
            try:
                return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
            except psutil.Error:
                return False
        t0 = time.time()
        while [p for p in analyses if running(p)] and time.time() - t0 < 30:
            time.sleep(0.1)
        assert not [p for p in analyses if running(p)]
        # its task was redone: its attempt folder was left unpublished, without a report, and
        # its set still has a result from another attempt
        left = set(os.listdir(partial)) & in_flight
        assert left, "no attempt was lost with the killed worker"
        for name in left:
            assert not os.path.exists(os.path.join(partial, name, "report.json")), name
            assert T.read_result(out, name.rsplit(".", 1)[0].replace("~", "/"))["status"] == "ok"
        recs2, stats2 = run_batch(sets, out, scheduler=address, progress=lambda s: None)
        assert stats2["skipped"] == len(sets) and stats2["run"] == 0


@needs_native(truth=True)
def test_suite_bench_through_the_batch(tmp_path):
    """``suite bench --dask``: the cases run as one batch and are scored as before."""
    from host_tools.suite import bench, cases
    null, emf = cases.get(["null_std", "motor_back_emf_strong"])
    for c in (null, emf):
        c.experiments = c.experiments[:1]
        c.experiments[0] = c.experiments[0][:2] + (1.5,)
    results, m, text = bench.bench(str(tmp_path), [null, emf], jobs=2, out=lambda s: None,
                                   scheduler="local")
    assert [r["case"] for r in results] == ["null_std", "motor_back_emf_strong"]
    for r in results:
        assert r["rc"] == 0 and r["verdict"] in ("no_mismatch", "explained", "unexplained")
        assert r["analysis_s"] > 0
        rec = T.read_result(str(tmp_path / "reports"), r["case"])
        assert rec["status"] == "ok" and rec["report"]["verdict"] == r["verdict"]
        assert os.path.isfile(tmp_path / "reports" / r["case"] / "score.json")
    assert results[0]["ok"] == (results[0]["verdict"] == "no_mismatch")
    assert "cases: 2" in text
