"""analyze's outputs as one set (issue 24): never written through a stale link in --out, never
a mix of two analyses or of a finished and an interrupted one, a closed status pipe ends
nothing, and a killed fitting worker ends the analysis instead of hanging it."""
from __future__ import annotations

import contextlib
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


@contextlib.contextmanager
def _analysis_fitting(tmp_path):
    """``analyze`` in a subprocess, yielded once its candidate fits are under way, as
    (process, stderr lines so far, out folder); ended however the test ends."""
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
        yield proc, lines, out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        t.join(10)


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_a_killed_fitting_worker_ends_the_analysis_instead_of_hanging_it(tmp_path, sig):
    with _analysis_fitting(tmp_path) as (proc, lines, out):
        workers = _children(proc.pid)
        assert workers, "no worker process to kill"
        os.kill(workers[0], getattr(signal, sig))  # what the out-of-memory killer sends
        rc = proc.wait(120)
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


@pytest.mark.parametrize("t_last", [b"1e9", b"1e308"])
def test_a_clock_glitch_in_the_last_row_is_bad_input_not_an_allocation(tmp_path, capsys, t_last):
    from host_tools.__main__ import main as cli
    from test_badinput import _set_cell

    run = _base(tmp_path / "run")
    _set_cell(run / "telemetry.csv", 76, "t_s", t_last)
    assert cli(["analyze", str(run), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "row 76 (line 77), column 't_s'" in err and "clock glitch" in err


def test_the_shortest_documented_inner_period_has_a_phase_search():
    """periods_s.inner = 1e-5 (the documented minimum) is shorter than the phase search's
    5e-5 s step: the search takes ten phases across the period instead of none."""
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


def test_a_second_sigterm_during_the_cleanup_gives_no_traceback(tmp_path):
    with _analysis_fitting(tmp_path) as (proc, lines, _out):
        proc.send_signal(signal.SIGTERM)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(60)
    err = "".join(lines)
    assert rc == 1 and "interrupted by SIGTERM" in err and "Traceback" not in err, err
