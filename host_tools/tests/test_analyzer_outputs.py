"""analyze's outputs as one set (issue 24): never written through a stale link in --out, never
a mix of two analyses or of a finished and an interrupted one, a closed status pipe ends
nothing, and a killed fitting worker ends the analysis instead of hanging it."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import types
from pathlib import Path

import pytest

from host_tools.analyzer.report import writers
from test_badinput import _base

ROOT = Path(__file__).resolve().parents[2]


def _analyze(run, out, *extra):
    return subprocess.Popen([sys.executable, "-m", "host_tools", "analyze", str(run), "--out", str(out),
                             "--jobs", "2", "--no-plots", *extra], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_stale_temp_links_and_a_closed_status_pipe(tmp_path):
    """``OUT/report.json.tmp`` and ``OUT/model.json.tmp`` linked to the run's files; stderr
    and stdout closed after the first line (``2>&1 | head -1``): the analysis ends normally,
    exit 0, a whole report, the run untouched."""
    run = _base(tmp_path / "run", n=600)
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.json.tmp").symlink_to(run / "meta.json")
    (out / "model.json.tmp").symlink_to(run / "telemetry.csv")
    before = {f: (run / f).read_bytes() for f in ("meta.json", "telemetry.csv")}
    proc = _analyze(run, out)
    proc.stderr.readline()
    proc.stderr.close()
    proc.stdout.close()
    assert proc.wait(300) == 0
    assert {f: (run / f).read_bytes() for f in before} == before
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] and (out / "report.md").is_file() and not (out / "report.md").is_symlink()
    assert not [p for p in out.iterdir() if p.name.startswith(".analyze-stage-")]  # no staging left


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(x) for x in fh.read().split()]
    except OSError:
        return []


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_a_killed_fitting_worker_ends_the_analysis_instead_of_hanging_it(tmp_path, sig):
    run = _base(tmp_path / "run", n=600)
    out = tmp_path / "out"
    proc = _analyze(run, out)
    lines: list[str] = []
    started = threading.Event()

    def read():
        for line in proc.stderr:
            lines.append(line.decode(errors="replace"))
            if b"fitted in" in line:
                started.set()
    t = threading.Thread(target=read, daemon=True)
    t.start()
    try:
        assert started.wait(120), "".join(lines)
        workers = _children(proc.pid)
        assert workers, "no worker process to kill"
        os.kill(workers[0], getattr(signal, sig))  # what the out-of-memory killer sends
        rc = proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    t.join(10)
    err = "".join(lines)
    assert rc == 1, err
    assert "worker process ended without its result" in err and "Traceback" not in err
    assert not list(out.glob("report.*")) and not list(out.glob("model.json"))


def _fake_analysis(verdict):
    return types.SimpleNamespace(model={"verdict_of": verdict})


@pytest.mark.parametrize("fail", ["full disk", "signal"])
def test_a_failure_while_writing_leaves_the_previous_set_whole(tmp_path, monkeypatch, fail):
    out = tmp_path / "out"
    monkeypatch.setattr(writers, "report_dict", lambda an: {"verdict": an.model["verdict_of"]})
    monkeypatch.setattr(writers, "_md", lambda an, rep, files: f"# {rep['verdict']}\n")

    def plots(an, where):
        Path(where, "run_omega_r.png").write_bytes(b"png " + an.model["verdict_of"].encode())
        return ["run_omega_r.png"]
    monkeypatch.setattr(writers, "_plots", plots)
    writers.write_outputs(_fake_analysis("first"), str(out))
    first = {p.name: p.read_bytes() for p in out.iterdir() if not p.name.startswith(".")}
    assert sorted(first) == ["model.json", "report.json", "report.md", "run_omega_r.png"]

    def broken_md(an, rep, files):  # after the plots and two of the files were written
        if fail == "full disk":
            raise OSError(28, "No space left on device")
        raise KeyboardInterrupt  # SIGTERM while plotting (the command turns it into an exit)
    monkeypatch.setattr(writers, "_md", broken_md)
    with pytest.raises(OSError if fail == "full disk" else KeyboardInterrupt):
        writers.write_outputs(_fake_analysis("second"), str(out))
    now = {p.name: p.read_bytes() for p in out.iterdir() if not p.name.startswith(".")}
    assert now == first
    assert not [p for p in out.iterdir() if p.name.startswith(".analyze-stage-")]


def test_two_analyses_into_one_folder_leave_one_whole_set(tmp_path, monkeypatch):
    """Two writers racing into one --out: the set in place at the end is one writer's."""
    out = tmp_path / "out"
    monkeypatch.setattr(writers, "report_dict", lambda an: {"verdict": an.model["verdict_of"]})
    monkeypatch.setattr(writers, "_md", lambda an, rep, files: f"# {rep['verdict']}\n")
    monkeypatch.setattr(writers, "_plots", lambda an, where: [])
    errors = []

    def write(tag):
        try:
            for _ in range(30):
                writers.write_outputs(_fake_analysis(tag), str(out))
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)
    ts = [threading.Thread(target=write, args=(tag,)) for tag in ("A", "B")]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors
    v = json.loads((out / "report.json").read_text())["verdict"]
    assert (out / "report.md").read_text() == f"# {v}\n"
    assert json.loads((out / "model.json").read_text())["verdict_of"] == v
