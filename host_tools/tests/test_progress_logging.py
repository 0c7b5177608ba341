"""Conventions of the tools' output (issue 25 item 5): progress bars on a terminal only (a
pseudo-terminal here), never in a pipe or with -q; the messages through ``logging`` (module
loggers under ``host_tools``, configured once from -v/-q) with today's line formats; a closed
stderr never ends the work."""
from __future__ import annotations

import io
import logging
import os
import pty
import re
import select
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from host_tools import _progress, _stdio
from host_tools.__main__ import main, setup_logging

ROOT = Path(__file__).resolve().parents[2]
BAR = "%|"  # tqdm's percentage and the start of its bar


def _on_pty(cmd: list[str], timeout_s: float = 600.0) -> tuple[int, str, str]:
    """Run ``cmd`` with stderr on a pseudo-terminal and stdout on a pipe: (exit code, stdout,
    what the terminal received)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=slave)
    os.close(slave)
    got = b""
    try:
        while True:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # EIO: the process closed its end
                    break
                if not chunk:
                    break
                got += chunk
            elif proc.poll() is not None:
                break
        out = proc.stdout.read().decode() if proc.stdout else ""
        return proc.wait(timeout_s), out, got.decode(errors="replace")
    finally:
        os.close(master)


def _piped(cmd: list[str], timeout_s: float = 600.0) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout_s)


@pytest.fixture
def caught(caplog):
    """caplog on the host_tools loggers (their handler does not pass records to the root)."""
    root = logging.getLogger("host_tools")
    root.addHandler(caplog.handler)
    caplog.handler.setLevel(logging.DEBUG)
    yield caplog
    root.removeHandler(caplog.handler)
    setup_logging(0)


# ------------------------------------------------------------------ the handler and the levels

def test_status_lines_bare_others_with_their_level(capsys):
    setup_logging(0)
    log = logging.getLogger("host_tools.test")
    log.log(_stdio.STATUS, "[analyze 12:00:00] loaded 1 run(s)")
    log.info("hidden by default")
    log.warning("careful")
    log.error("broken")
    assert capsys.readouterr().err.splitlines() == [
        "[analyze 12:00:00] loaded 1 run(s)", "warning: careful", "error: broken"]
    setup_logging(-1)
    log.log(_stdio.STATUS, "progress")
    log.error("still shown")
    assert capsys.readouterr().err == "error: still shown\n"
    setup_logging(0)


def test_a_closed_stderr_never_ends_the_work(monkeypatch):
    setup_logging(0)
    dead = io.StringIO()
    dead.close()
    monkeypatch.setattr(sys, "stderr", dead)
    log = logging.getLogger("host_tools.analyzer.test")
    log.log(_stdio.STATUS, "a status line")   # no exception, no "--- Logging error ---"
    log.error("an error")
    with _progress.Progress(3, "work") as bar:  # not a terminal: lines, through the handler
        bar.step("step 1")


def test_an_open_status_line_is_ended_before_a_message(capsys):
    setup_logging(0)
    _stdio.say("\rrows 10", end="")
    logging.getLogger("host_tools.logger.test").warning("the robot reports clamp_on 0")
    assert capsys.readouterr().err == "\rrows 10\nwarning: the robot reports clamp_on 0\n"


def test_the_library_default_shows_status_without_the_command_line(capsys):
    """A tool used as a library (no setup_logging) still shows its progress and errors."""
    code = textwrap.dedent("""
        import logging
        from host_tools.analyzer import stage_log
        stage_log("loaded 1 run(s): r")
        logging.getLogger("host_tools.timing").error("bad --json")
        logging.getLogger("host_tools.timing").info("a detail")
    """)
    r = _piped([sys.executable, "-c", code])
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 2 and lines[0].startswith("[analyze ") and \
        lines[0].endswith("] loaded 1 run(s): r") and lines[1] == "error: bad --json", lines


# ------------------------------------------------------------------ messages through logging

def test_the_tools_messages_are_log_records(caught, tmp_path, monkeypatch):
    assert main(["analyze", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert main(["timing", "--edge-rate", "-1"]) == 2
    assert main(["log", "--out", str(tmp_path / "r")]) == 2
    from host_tools.suite.__main__ import main as suite_main
    assert suite_main(["list", "--cases", "no_such_case"]) == 2
    assert main(["drive", "--port", "loop://", "--out", str(tmp_path / "d"),
                 "--path", str(tmp_path / "no_path.csv")]) == 2
    assert main(["batch", str(tmp_path / "no_fleet"), "--out", str(tmp_path / "b")]) == 2
    from host_tools.analyzer import stage_log
    stage_log("loaded 1 run(s): r")
    got = {(r.name, r.levelno) for r in caught.records}
    assert {("host_tools.analyzer.cli", logging.ERROR), ("host_tools.timing", logging.ERROR),
            ("host_tools.logger.cli", logging.ERROR),
            ("host_tools.suite", logging.ERROR), ("host_tools.robot", logging.ERROR),
            ("host_tools.batch.cli", logging.ERROR),
            ("host_tools.analyzer", _stdio.STATUS)} <= got, got
    bad = next(r for r in caught.records if r.name == "host_tools.analyzer.cli")
    assert bad.getMessage().startswith("bad input: ")


def test_fitting_progress_is_a_bar_or_lines(caught):
    """run_tasks's per-candidate lines: STATUS records when no bar is drawn (not a terminal)."""
    from host_tools import analyzer
    bar = _progress.Progress(2, "fitting candidates", logger=analyzer.log, emit=analyzer.lines)
    assert bar.bar is None  # pytest's stderr is not a terminal
    bar.step("candidate 1/2: wheel_radius fitted in 0.5 s")
    rec = [r for r in caught.records if r.name == "host_tools.analyzer"]
    assert [r.levelno for r in rec] == [_stdio.STATUS]
    assert rec[0].getMessage().endswith("] candidate 1/2: wheel_radius fitted in 0.5 s")


# ------------------------------------------------------------------ bars on a pseudo-terminal

_BAR_SCRIPT = textwrap.dedent("""
    import os, sys, types
    from host_tools.__main__ import setup_logging
    setup_logging({level})
    from host_tools.suite import bench as B
    # suite bench's own loop, with the cases' generation, analysis and scoring stubbed out
    data = sys.argv[1]
    os.makedirs(os.path.join(data, "labels"), exist_ok=True)
    cases = [types.SimpleNamespace(name=f"case_{{i}}") for i in range(4)]
    for c in cases:
        open(os.path.join(data, "labels", c.name + ".json"), "w").write("{{}}")
    B._case_runs = lambda case, data_dir, regenerate: []
    def run_analyzer(runs, rep_dir, jobs, log, timeout_s, perf):
        perf.update(wall_s=1.0, peak_rss_mb=100.0)
        return 0, None
    B.run_analyzer = run_analyzer
    B.score_case = lambda label, rc, report: {{"ok": True, "verdict": "explained", "named": "x"}}
    B.summarize = lambda results, total_s: ("summary", {{}})
    B.bench(data, cases, out=print)
    from host_tools import fil
    on_row, fbar = fil._record_progress({{"duration": 2.0}}, None, None)
    with fbar:
        for k in range(81):
            on_row({{"t_s": 0.3 + 0.025 * k}})
""")


@pytest.mark.parametrize("level", [0, -1, 1])
def test_bars_on_a_terminal_lines_elsewhere(level, tmp_path):
    script = [sys.executable, "-c", _BAR_SCRIPT.format(level=level), str(tmp_path)]
    rc, out, term = _on_pty(script)
    assert rc == 0, term
    piped = _piped(script)
    assert piped.returncode == 0, piped.stderr
    lines = [f"[{i + 1}/4] case_{i}: OK verdict explained named x (analysis 1 s, 100 MB; "
             "case 0 s)" for i in range(4)]
    # piped: the one-line messages as before (to stdout, as bench's lines), never a bar
    assert piped.stdout.splitlines() == lines and BAR not in piped.stderr + piped.stdout
    if level == -1:  # -q: nothing on stderr; bench's lines on stdout stay (a result)
        assert term == "" and out.splitlines() == lines
        return
    assert "suite bench: 100%|" in term and "4/4" in term
    assert re.search(r"4/4 \[\d\d:\d\d<\d\d:\d\d", term)  # elapsed < ETA
    assert "fil record: 100%|" in term and "2.0/2 simulated s" in term
    assert out == ""  # on a terminal the bar replaces the lines
    assert ("info: [1/4] case_0: OK" in term) == (level == 1)
    assert "case_0" not in term.replace("info: [1/4] case_0", "")  # -v: the lines above the bar


def _small_run(tmp_path: Path) -> Path:
    sys.path.insert(0, str(Path(__file__).parent))
    from test_badinput import _base
    return _base(tmp_path / "run", n=300)


def test_analyze_bar_on_a_terminal_lines_in_a_pipe_nothing_with_q(tmp_path):
    run = _small_run(tmp_path)
    base = [sys.executable, "-m", "host_tools"]
    args = ["analyze", str(run), "--no-plots", "--jobs", "1",
            "--effects", "wheel_radius,track_width,payload"]

    rc, out, term = _on_pty(base + args + ["--out", str(tmp_path / "tty")])
    assert rc == 0, term
    assert "fitting candidates:" in term and BAR in term and "3/3" in term
    assert "analyze: loaded 1 run(s)" in term            # the stage line
    assert "candidate 1/3:" not in term                 # the bar replaces the lines
    assert out.startswith("verdict: ")

    rc, out, term = _on_pty(base + ["-v"] + args + ["--out", str(tmp_path / "tty_v")])
    assert rc == 0, term
    assert BAR in term and "info: candidate 1/3:" in term

    rc, out, term = _on_pty(base + ["-q"] + args + ["--out", str(tmp_path / "tty_q")])
    assert rc == 0 and term == "" and out.startswith("verdict: "), term

    r = _piped(base + args + ["--out", str(tmp_path / "pipe")])
    assert r.returncode == 0, r.stderr
    assert BAR not in r.stderr and "\r" not in r.stderr
    assert "] candidate 1/3: " in r.stderr and "] loaded 1 run(s): run" in r.stderr
    assert "info:" not in r.stderr and "debug:" not in r.stderr

    r = _piped(base + ["-vv"] + args + ["--out", str(tmp_path / "pipe_vv")])
    assert r.returncode == 0, r.stderr
    assert "info: " in r.stderr and "telemetry rows" in r.stderr
    assert "debug: options: --jobs 1, --dt 0.0005 s, --effects " \
           "wheel_radius,track_width,payload" in r.stderr
    r = _piped(base + ["-v"] + args + ["--out", str(tmp_path / "pipe_v")])
    assert "info: " in r.stderr and "debug:" not in r.stderr


def test_fil_record_bar_on_a_terminal(elf, tmp_path):
    cmd = [sys.executable, "-m", "host_tools", "fil", "record", "--elf", str(elf),
           "--duration", "0.5"]
    rc, out, term = _on_pty(cmd + ["--out", str(tmp_path / "tty")])
    assert rc == 0, term
    assert "fil record:" in term and "simulated s" in term and BAR in term
    assert "telemetry rows" in out
    r = _piped(cmd + ["--out", str(tmp_path / "pipe")])
    assert r.returncode == 0, r.stderr
    assert BAR not in r.stderr and "simulated s [" not in r.stderr


def test_suite_as_a_module_logs_through_the_handler():
    """``python -m host_tools.suite``: its module is __main__, its messages still go through the
    host_tools handler (``error: ...``), and -q keeps them (errors)."""
    for flags in ([], ["-q"]):
        r = _piped([sys.executable, "-m", "host_tools.suite", *flags, "list", "--cases", "nope"])
        assert r.returncode == 2 and r.stderr.startswith("error: unknown case(s) nope"), r.stderr


def test_a_terminal_gone_mid_bar_never_ends_the_work(monkeypatch):
    term = io.StringIO()
    monkeypatch.setattr(sys, "stderr", term)
    monkeypatch.setattr(_progress, "shown", lambda: True)
    bar = _progress.Progress(10, "work")
    assert bar.bar is not None
    bar.step()
    term.close()           # writes now raise ValueError
    for _ in range(5):
        bar.step("a line")  # no exception
        bar.set(9)
    logging.getLogger("host_tools.test").error("after the terminal went")
    bar.close()
    assert not _progress._bars
