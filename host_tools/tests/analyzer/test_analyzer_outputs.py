"""The analyzer's outputs: the per-sample series (series/<run>.csv), report.html (loaded in
headless Chromium: no console error), report.md's summary, the PNG choice, the output set
written all or nothing (a full disk or a signal while plotting, two analyses into one folder,
stale temp-file links), a killed fitting worker, and the inputs that used to end in a
traceback (issue 24)."""
from __future__ import annotations

import copy
import csv
import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import runfmt, truth  # noqa: E402
from host_tools.__main__ import main as cli  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}
EFFECTS = ["motor_back_emf", "axle_coulomb"]


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    """Two back-EMF runs of the truth simulator, analysed in-process (the Analysis kept) and
    through the command line (the outputs)."""
    from host_tools.analyzer.pipeline import analyze
    d = tmp_path_factory.mktemp("outputs")
    a = truth.simulate_run(d / "bemf", LINE, {"motor_back_emf": {"ke_ratio": 1.2}},
                           duration_s=1.5, seed=3)
    b = truth.simulate_run(d / "other", {**LINE, "cruise": 0.4},
                           {"motor_back_emf": {"ke_ratio": 1.2}}, duration_s=1.5, seed=5)
    assert cli(["analyze", str(a), str(b), "--out", str(d / "rep"), "--jobs", "1",
                "--effects", ",".join(EFFECTS)]) == 0
    runs = [runfmt.load_run(p) for p in (a, b)]
    runfmt.label_runs(runs)
    an = analyze(runs, jobs=1, effects=EFFECTS, log=lambda m: None)
    return d, (a, b), d / "rep", an


def _report(out):
    return json.loads((out / "report.json").read_text())


# ------------------------------------------------------------------ series/<run>.csv


def test_series_csv_per_run_and_channel(analysed):
    from host_tools.analyzer.report.series import COLUMNS
    d, runs, out, an = analysed
    rep = _report(out)
    assert rep["series"] == ["series/bemf.csv", "series/other.csv"]
    for k, (run_dir, name) in enumerate(zip(runs, rep["series"])):
        with open(out / name, newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert tuple(rows[0]) == COLUMNS
        by: dict[str, list] = {}
        for r in rows:
            by.setdefault(r["channel"], []).append(r)
        run = runfmt.load_run(run_dir)
        tel = run.telemetry
        # every channel of the open-loop and closed-loop replays
        assert {"omega_r", "omega_l", "enc_r", "x_m", "y_m", "phi_rad", "current_r_a"} <= set(by)
        assert {"tau_cmd_r", "pwm_l"} <= set(by)
        om = by["omega_r"]
        t = np.array([float(r["t_s"]) for r in om])
        rec = np.array([float(r["recording"]) for r in om])
        ch = an.nominal[k]["omega_r"]       # the analysis's own recording and replay
        np.testing.assert_allclose(t, ch.t, rtol=1e-9)       # written with 10 digits
        np.testing.assert_allclose(rec, ch.rec, rtol=1e-9)
        assert t[0] >= tel["t_s"][0] and t[-1] <= tel["t_s"][-1]
        nom = np.array([float(r["nominal"]) for r in om])
        upd = np.array([float(r["updated"]) for r in om])
        tol = 1e-9 * np.abs(rec).max()
        np.testing.assert_allclose([float(r["residual_nominal"]) for r in om], rec - nom,
                                   rtol=0, atol=tol)
        np.testing.assert_allclose([float(r["residual_updated"]) for r in om], rec - upd,
                                   rtol=0, atol=tol)
        np.testing.assert_allclose(nom, ch.sim, rtol=1e-9)
        floor = float(om[0]["noise_floor"])
        assert floor == pytest.approx(rep["fit"]["noise_floor"]["omega_r"], rel=1e-3)
        assert all(float(r["band"]) >= 3 * floor * (1 - 1e-9) for r in om)
        # the mismatch windows of report.json, sample by sample
        wins = [(m["t_start_s"], m["t_end_s"]) for m in rep["mismatch"]
                if m["run"] == run.name and m["channel"] == "omega_r"]
        assert wins
        inw = np.array([int(r["in_mismatch_window"]) for r in om])
        expect = np.zeros(t.size, int)
        for a, b in wins:
            expect |= ((t >= a - 5e-4) & (t <= b + 5e-4)).astype(int)
        assert (inw == expect).all()
        assert {r["replay_window"] for r in om} == {"0"}   # 1.5 s: one replay window


def test_series_mark_the_reanchoring_edges(analysed):
    """A long run is replayed in windows: the series say which window each sample is in."""
    from host_tools.analyzer.report.series import run_series
    d, runs, out, an = analysed
    a2 = copy.copy(an)
    ch = an.nominal[0]["omega_r"]
    seg = (ch.t > 0.7).astype(int)
    a2.nominal = [dict(an.nominal[0]), an.nominal[1]]
    a2.nominal[0]["omega_r"] = copy.copy(ch)
    a2.nominal[0]["omega_r"].seg = seg
    s = [x for x in run_series(a2, 0) if x.channel == "omega_r"][0]
    assert s.anchor_edges == [float(ch.t[np.argmax(ch.t > 0.7)])]


def test_series_leave_samples_that_are_no_evidence_without_a_band(analysed):
    """Samples of a slip that are no evidence (an unbounded replay uncertainty) have no band:
    empty in the CSV, undrawn, never outside it (a band of 3e9 had flattened every plot)."""
    from host_tools.analyzer.locate.episodes import SLIP_UNC, UNPINNED_UNC
    from host_tools.analyzer.report.series import COLUMNS, run_series, to_csv
    d, runs, out, an = analysed
    a2 = copy.copy(an)
    ch = copy.copy(an.nominal[0]["x_m"])
    gone = (ch.t > 0.5) & (ch.t < 0.9)
    ch.unc = np.where(gone, UNPINNED_UNC, 0.0)
    ch.rec = np.where(gone, ch.rec + 1.0, ch.rec)          # a metre off there
    a2.nominal = [{**an.nominal[0], "x_m": ch}, an.nominal[1]]
    s = [x for x in run_series(a2, 0) if x.channel == "x_m"][0]
    assert np.all(np.isnan(s.band[gone])) and np.all(np.isfinite(s.band[~gone]))
    assert not s.outside_band()[gone].any() and np.nanmax(s.band) < 1.0
    rows = [r.split(",") for r in to_csv([s]).splitlines()[1:]]
    assert all(r[COLUMNS.index("band")] == "" for r, g in zip(rows, gone) if g)
    assert SLIP_UNC <= UNPINNED_UNC


# ------------------------------------------------------------------ report.md


def test_report_md_opens_with_a_summary_without_python_reprs(analysed):
    d, runs, out, an = analysed
    md = (out / "report.md").read_text()
    rep = _report(out)
    head = md.split("# Details")[0]
    assert md.startswith("# Mismatch report\n\n## Summary\n")
    assert "**Verdict: explained**" in head and "back within the noise" in head
    cand = [c for c in rep["candidates"] if c["effect"] == "motor_back_emf"][0]
    sd = cand["param_std"]["ke_ratio"]
    val = rep["selected"][0]["params"]["ke_ratio"]
    assert f"ke_ratio = {val:.4g} ± {sd:.2g}" in head
    assert len(head.splitlines()) < 30 and "| run | channel |" not in head
    assert "report.html" in head
    for bad in ("{'", "[(", "[[", "np.float", "None"):
        assert bad not in md, bad


def test_summary_names_ties_and_the_separating_measurement(analysed):
    from host_tools.analyzer.report.writers import summary_lines
    d, runs, out, an = analysed
    a2 = copy.copy(an)
    a2.selected = [dict(an.selected[0], equivalent=["axle_viscous"],
                        separating_measurement={"axle_viscous": "the motor current at speed"})]
    text = "\n".join(summary_lines(a2))
    assert "ties with **axle_viscous**" in text and "the motor current at speed" in text


# ------------------------------------------------------------------ PNGs


def test_png_choice_largest_mismatch_first_every_run_and_a_path(analysed):
    from host_tools.analyzer.report.series import all_series
    from host_tools.analyzer.report.writers import plot_choice
    d, runs, out, an = analysed
    series = list(all_series(an))
    chosen = plot_choice(series, max_plots=3)
    assert len(chosen) == 3
    assert {s.run for s in chosen} == {"bemf", "other"}         # every run represented
    for i, ser in series:                                       # each run's largest first
        mine = [s for s in chosen if s.run == an.preps[i].name]
        assert mine[0].worst_floors() == max(s.worst_floors() for s in ser)
    rest = sorted((s for _, ser in series for s in ser if all(s is not c for c in chosen[:2])),
                  key=lambda s: s.worst_floors(), reverse=True)
    assert chosen[2].worst_floors() == rest[0].worst_floors()   # then the largest of all
    rep = _report(out)
    pngs = [o for o in rep["outputs"] if o.endswith(".png")]
    assert "bemf_path.png" in pngs and "other_path.png" in pngs
    assert all((out / p).is_file() for p in pngs)
    md = (out / "report.md").read_text()
    assert all(f"]({p})" in md for p in pngs)


# ------------------------------------------------------------------ report.html


def _chromium():
    for name in ("chromium", "chromium-browser"):
        p = shutil.which(name)
        if p:
            return p
    return None


def _load_in_chromium(page: Path, tmp_path: Path) -> tuple[str, str]:
    """(DOM after the scripts ran, Chromium's log with the page's console messages)."""
    exe = _chromium()
    res = subprocess.run([exe, "--headless=new", "--no-sandbox", "--disable-gpu",
                          "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
                          "--enable-logging=stderr", "--v=0", "--virtual-time-budget=20000",
                          "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=300,
                         start_new_session=True)   # its own process group: nothing it signals
                                                   # on the way out reaches pytest
    return res.stdout, res.stderr


def _console_errors(log: str) -> list[str]:
    return [ln for ln in log.splitlines() if "CONSOLE" in ln and
            re.search(r"error|uncaught", ln, re.I)]


def test_report_html_is_self_contained_and_has_every_series(analysed):
    from host_tools.analyzer.report.series import all_series
    d, runs, out, an = analysed
    page = (out / "report.html").read_text()
    assert not re.search(r"<script[^>]+src=", page)      # plotly.js inlined, nothing fetched
    figs = json.loads(re.search(r'<script type="application/json" id="figs">(.*?)</script>',
                                page, re.S).group(1).replace("<\\/", "</"))
    n_series = sum(len(s) for _, s in all_series(an))
    assert len(figs) == n_series + 2             # every run x channel, and one path per run
    f = [v for k, v in figs.items() if "bemf: omega_r" in v["layout"]["title"]["text"]][0]
    names = [t.get("name") for t in f["data"]]
    assert {"recording", "nominal simulation", "updated simulation", "nominal residual",
            "updated residual", "noise band (±3 floors)"} <= set(names)
    assert any(s["type"] == "rect" for s in f["layout"]["shapes"])   # mismatch windows
    assert "Verdict: explained" in page


@pytest.mark.skipif(_chromium() is None, reason="no chromium on PATH (scripts/setup.sh installs "
                    "Debian's chromium when it can; the page's content is checked without it)")
def test_report_html_loads_in_headless_chromium_without_console_errors(analysed, tmp_path):
    d, runs, out, an = analysed
    # the check itself sees a console error
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('boom'); undefinedCall();</script>"
                   "</body></html>")
    _, log = _load_in_chromium(bad, tmp_path)
    assert _console_errors(log), log
    dom, log = _load_in_chromium(out / "report.html", tmp_path)
    assert not _console_errors(log), _console_errors(log)
    figs = len(re.findall(r'class="fig"', (out / "report.html").read_text()))
    # plotly drew every figure (one main-svg per figure, at least)
    assert dom.count('class="main-svg"') >= figs, dom[:2000]


# ------------------------------------------------------------------ all or nothing


def _set_of(out: Path) -> dict:
    rep = _report(out)
    md = (out / "report.md").read_text()
    return {"verdict": rep["verdict"], "md": md, "outputs": rep["outputs"]}


def _consistent(out: Path) -> None:
    """Every output present is from the one analysis report.json describes."""
    rep = _report(out)
    md = (out / "report.md").read_text()
    assert f"**Verdict: {rep['verdict'].replace('_', ' ')}**" in md
    assert "Verdict: " + rep["verdict"].replace("_", " ") in (out / "report.html").read_text()
    for o in rep["outputs"]:
        assert (out / o).is_file(), o
    have = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()
            and not p.relative_to(out).parts[0].startswith(".analyze-staging-")}
    assert have == set(rep["outputs"]), have ^ set(rep["outputs"])


def _other_analysis(an):
    b = copy.copy(an)
    b.verdict = "unexplained"
    b.selected = []
    b.updated = None
    return b


def test_full_disk_while_plotting_leaves_the_previous_set(analysed, tmp_path, monkeypatch):
    from host_tools.analyzer.report import writers
    d, runs, _, an = analysed
    out = tmp_path / "out"
    writers.write_outputs(an, str(out), plots=False)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(writers, "_plots", full)
    with pytest.raises(OSError):
        writers.write_outputs(_other_analysis(an), str(out), plots=True)
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert not [p for p in out.iterdir() if p.name.startswith(".analyze-staging")]


def test_two_analyses_into_one_folder_never_mix(analysed, tmp_path, monkeypatch):
    """B runs whole while A plots: the folder holds A's set or B's, never report.json of one
    and report.md of the other."""
    from host_tools.analyzer.report import writers
    d, runs, _, an = analysed
    out = tmp_path / "out"
    real = writers._plots
    b = _other_analysis(an)

    def plots_with_b_meanwhile(a, staging, series):
        monkeypatch.setattr(writers, "_plots", real)
        writers.write_outputs(b, str(out), plots=True)
        _consistent(out)
        return real(a, staging, series)
    monkeypatch.setattr(writers, "_plots", plots_with_b_meanwhile)
    writers.write_outputs(an, str(out), plots=True)
    _consistent(out)
    assert _report(out)["verdict"] == "explained"


def test_stale_temp_links_in_out_are_never_written_through(analysed, tmp_path):
    from host_tools.analyzer.report import writers
    d, runs, _, an = analysed
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.json"
    victim.write_text("precious\n")
    for name in ("report.json.tmp", "model.json.tmp", "report.md.tmp", "report.json",
                 "report.html"):
        (out / name).symlink_to(victim)
    (out / "series").symlink_to(tmp_path)         # a link where the series folder goes
    writers.write_outputs(an, str(out), plots=False)
    assert victim.read_text() == "precious\n"
    assert not (out / "report.json").is_symlink() and not (out / "series").is_symlink()
    assert _report(out)["verdict"] == "explained"
    assert not list(tmp_path.glob("*.csv"))       # nothing written into the linked folder


def _cli_with_prepared(an, monkeypatch):
    import host_tools.analyzer.pipeline as pipeline
    monkeypatch.setattr(pipeline, "analyze", lambda *a, **k: an)


def test_sigterm_while_plotting_leaves_the_previous_set(analysed, tmp_path, monkeypatch,
                                                        capsys):
    from host_tools.analyzer.report import writers
    d, runs, _, an = analysed
    out = tmp_path / "out"
    _cli_with_prepared(an, monkeypatch)
    assert cli(["analyze", *map(str, runs), "--out", str(out), "--no-plots"]) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    _cli_with_prepared(_other_analysis(an), monkeypatch)
    real = writers._plots

    def killed(*a, **k):
        files = real(*a, **k)           # some PNGs are staged, then the signal comes
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)
        return files
    monkeypatch.setattr(writers, "_plots", killed)
    capsys.readouterr()
    assert cli(["analyze", *map(str, runs), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "interrupted by SIGTERM" in err and "Traceback" not in err
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert not [p for p in out.iterdir() if p.name.startswith(".analyze-staging")]


def test_a_second_sigterm_during_the_clean_up_is_no_traceback(analysed, tmp_path,
                                                              monkeypatch, capsys):
    from host_tools.analyzer.report import outputs, writers
    d, runs, _, an = analysed
    _cli_with_prepared(an, monkeypatch)

    def first(*a, **k):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)
    real_remove = outputs.remove_staging

    def second(staging):
        os.kill(os.getpid(), signal.SIGTERM)      # arrives while the first is handled
        time.sleep(0.5)
        real_remove(staging)
    monkeypatch.setattr(writers, "_plots", first)
    monkeypatch.setattr(outputs, "remove_staging", second)
    rc = cli(["analyze", *map(str, runs), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 1 and "interrupted by SIGTERM" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "report.json").exists()


# ------------------------------------------------------------------ a killed worker


def _children(pid: int) -> list[int]:
    try:
        return [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_a_killed_fitting_worker_does_not_hang_the_analysis(analysed, tmp_path, sig):
    d, runs, _, an = analysed
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "host_tools", "analyze", *map(str, runs),
                             "--out", str(out), "--jobs", "2", "--no-plots"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    started = threading.Event()

    def read():
        for ln in proc.stderr:
            lines.append(ln)
            if "fitting" in ln and "candidate" in ln:
                started.set()
    th = threading.Thread(target=read, daemon=True)
    th.start()
    try:
        assert started.wait(300), "".join(lines)
        victim = None
        for _ in range(200):
            kids = _children(proc.pid)
            if kids:
                victim = kids[0]
                break
            time.sleep(0.05)
        assert victim is not None, "no worker process seen"
        os.kill(victim, getattr(signal, sig))
        proc.wait(600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    th.join(10)
    err = "".join(lines)
    assert proc.returncode == 0, err
    assert "a fitting worker process died" in err and "Traceback" not in err
    assert _report(out)["verdict"] == "explained"


# ------------------------------------------------------------------ tracebacks of issue 24


def _bad_run(tmp_path, attack):
    sys.path.insert(0, str(Path(__file__).parent.parent))
    from test_badinput import _base, _lines, _set_cell
    run = _base(tmp_path / "run")
    if attack in ("1e9", "1e308"):
        n = len([ln for ln in _lines(run / "telemetry.csv") if ln]) - 1
        _set_cell(run / "telemetry.csv", n, "t_s", attack.encode())
    else:
        meta = json.loads((run / "meta.json").read_text())
        meta["periods_s"]["inner"] = 1e-5
        (run / "meta.json").write_text(json.dumps(meta))
    return run


@pytest.mark.parametrize("attack, expect", [
    ("1e9", ["telemetry.csv", "row 76", "t_s", "inner ticks"]),
    ("1e308", ["telemetry.csv", "row 76", "t_s", "inner ticks"]),
    ("inner", ["meta.json", "periods_s.inner = 1e-05 s is shorter than the plant step"]),
])
def test_inputs_that_ended_in_a_traceback_are_bad_input(tmp_path, capsys, monkeypatch, attack,
                                                        expect):
    run = _bad_run(tmp_path, attack)
    import host_tools.analyzer.pipeline as pipeline
    monkeypatch.setattr(pipeline, "analyze", lambda *a, **k: pytest.fail("analysis started"))
    rc = cli(["analyze", str(run), "--out", str(tmp_path / "out"), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err
    for piece in expect:
        assert piece in err, (piece, err)


def test_a_folder_where_an_output_goes_fails_before_anything_is_replaced(analysed, tmp_path):
    from host_tools.analyzer.report import writers
    d, runs, _, an = analysed
    out = tmp_path / "out"
    writers.write_outputs(an, str(out), plots=False)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    (out / "report.json").unlink()
    (out / "report.json").mkdir()           # renamed last: the others would have gone first
    (out / "report.json" / "keep").write_text("x")
    with pytest.raises(IsADirectoryError):
        writers.write_outputs(_other_analysis(an), str(out), plots=False)
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == {**{p: b for p, b in before.items() if p.name != "report.json"},
                     out / "report.json" / "keep": b"x"}


def test_an_interrupted_fitting_pool_leaves_no_manager_thread(monkeypatch):
    """A signal while the candidates are fitted (here: KeyboardInterrupt from the wait) stops
    the workers and waits for the pool's manager thread: left running, it races the
    interpreter's exit hook of concurrent.futures, and a cleanly interrupted analysis ended in
    a traceback ("Bad file descriptor") once in a while."""
    import concurrent.futures as cf
    import threading

    from host_tools.analyzer.fit import workers

    def interrupted(*_a, **_k):
        raise KeyboardInterrupt

    monkeypatch.setattr(cf, "wait", interrupted)
    before = set(threading.enumerate())
    with pytest.raises(KeyboardInterrupt):
        workers.run_tasks(object(), [(("wheel_radius",), None, None)] * 2, 2, "candidate")
    left = [t for t in set(threading.enumerate()) - before if t.is_alive()]
    assert not left, left


def test_report_json_is_the_same_whatever_the_hash_seed(tmp_path):
    """Two analyses of one run by processes with different string-hash seeds write the same
    report.json but its elapsed time (the noise floors were keyed in a set's order)."""
    from test_badinput import _base
    run = _base(tmp_path / "run", n=300)
    root = Path(__file__).resolve().parents[3]
    got = []
    for seed in ("1", "2"):
        out = tmp_path / f"out{seed}"
        env = dict(os.environ, PYTHONHASHSEED=seed)
        r = subprocess.run([sys.executable, "-m", "host_tools", "analyze", str(run), "--out",
                            str(out), "--no-plots", "--jobs", "1"], cwd=root, env=env,
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        text = (out / "report.json").read_text()
        got.append(re.sub(r'"elapsed_s": [0-9.eE+-]+', '"elapsed_s": 0', text))
    assert got[0] == got[1]
