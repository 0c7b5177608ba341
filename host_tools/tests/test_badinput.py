"""Bad input to the analyzer (``analyze``) and the timing tool (``timing``): every case
gives exit 2 with the file and where in it (row, line, column or key), never a traceback;
and no silent wrong result (numbers like ``1_0``, ground truth outside the
telemetry's time, two runs with one folder name, unknown meta keys, non-UTF-8 paths).

Each case is an attack on one valid run folder (``_base``), which both tools accept."""
from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest

from host_tools import protocol as P
from host_tools import runfmt
from host_tools.__main__ import main as cli
from test_runfmt import _columns as runfmt_columns

D = P.definition()


def _columns(n=76):
    """Kinematically consistent telemetry plus the task-timing columns of protocol.json."""
    cols = runfmt_columns(n=n, turn=1.0)
    fields = {f.name: f for f in D.by_name["Telemetry"].fields}
    for task in ("inner", "outer", "telemetry"):
        cols[fields[f"{task}_last"].column] = np.full(n, 16 * 300)
        cols[fields[f"{task}_max"].column] = np.full(n, 16 * 400)
        cols[fields[f"{task}_overruns"].column] = np.zeros(n, dtype=int)
    return cols


def _base(path, meta=None, gt_shift=0.0, n=76):
    cols = _columns(n=n)
    g = {"t_s": cols["t_s"][::2] + 0.001 + gt_shift, "x_m": cols["x_odo_m"][::2],
         "y_m": cols["y_odo_m"][::2], "phi_rad": cols["phi_odo_rad"][::2]}
    runfmt.write_run(path, meta or {"experiment": "base"}, cols, g)
    return path


def _lines(p):
    return p.read_bytes().split(b"\n")


def _set_cell(p, row, column, value: bytes):
    """Replace one cell (data row ``row``, 1-based) of a CSV file by raw bytes."""
    lines = _lines(p)
    header = lines[0].split(b",")
    j = header.index(column.encode())
    cells = lines[row].split(b",")
    cells[j] = value
    lines[row] = b",".join(cells)
    p.write_bytes(b"\n".join(lines))


def _meta_bytes(run, data: bytes):
    (run / "meta.json").write_bytes(data)


def _meta_edit(run, **kw):
    meta = json.loads((run / "meta.json").read_text())
    for k, v in kw.items():
        if isinstance(v, dict) and isinstance(meta.get(k), dict):
            meta[k].update(v)
        else:
            meta[k] = v
    (run / "meta.json").write_text(json.dumps(meta))


def _meta_raw(run, key, raw: str):
    """Set ``key`` of meta.json to a raw JSON text (NaN, Infinity, huge literals)."""
    meta = json.loads((run / "meta.json").read_text())
    meta[key] = "@@@"
    (run / "meta.json").write_text(json.dumps(meta).replace('"@@@"', raw))


def _keep_rows(p, n):
    lines = [ln for ln in _lines(p) if ln]
    p.write_bytes(b"\n".join(lines[:n + 1]) + b"\n")


# name -> (attack, expected pieces of the message, does the timing tool refuse it too)
CASES = {
    "meta latin-1": (lambda r: _meta_bytes(r, b'{"experiment": "caf\xe9"}'),
                     ["meta.json", "line 1", "character 20", "not UTF-8"], True),
    "meta UTF-16": (lambda r: _meta_bytes(r, '{"experiment": "x"}'.encode("utf-16")),
                    ["meta.json", "UTF-16"], True),
    "meta UTF-16 without BOM": (lambda r: _meta_bytes(r, '{"a": 1}'.encode("utf-16-le")),
                                ["meta.json", "NUL byte", "line 1"], True),
    "meta UTF-8 BOM": (lambda r: _meta_bytes(r, b'\xef\xbb\xbf{"experiment": "x"}'),
                       ["meta.json", "byte-order mark", "EF BB BF"], True),
    "telemetry latin-1 cell": (lambda r: _set_cell(r / "telemetry.csv", 3, "omega_r", b"1\xb0"),
                               ["telemetry.csv", "row 3", "column 'omega_r'", "not UTF-8"], True),
    "telemetry UTF-8 BOM": (lambda r: (r / "telemetry.csv").write_bytes(
        b"\xef\xbb\xbf" + (r / "telemetry.csv").read_bytes()),
        ["telemetry.csv", "line 1", "byte-order mark"], True),
    "telemetry UTF-16": (lambda r: (r / "telemetry.csv").write_bytes(
        (r / "telemetry.csv").read_text().encode("utf-16")),
        ["telemetry.csv", "UTF-16 little-endian"], True),
    "groundtruth UTF-16 without BOM": (lambda r: (r / "groundtruth.csv").write_bytes(
        (r / "groundtruth.csv").read_text().encode("utf-16-le")),
        ["groundtruth.csv", "NUL byte", "line 1"], True),
    "groundtruth latin-1": (lambda r: _set_cell(r / "groundtruth.csv", 5, "x_m", b"\xff"),
                            ["groundtruth.csv", "row 5", "column 'x_m'", "not UTF-8"], True),
    "meta nested 100000 deep": (lambda r: _meta_bytes(
        r, b'{"x": ' + b"[" * 100000 + b"]" * 100000 + b"}"),
        ["meta.json", "nested"], True),
    "meta nested 500 deep": (lambda r: _meta_bytes(
        r, b'{"x": ' + b"[" * 500 + b"]" * 500 + b"}"), ["meta.json", "nested more than 64"], True),
    "meta integer of 5000 digits": (lambda r: _meta_raw(r, "encoder_ppr", "9" * 5000),
                                    ["meta.json", "invalid JSON"], True),
    "CSV field over 128 KB": (lambda r: _set_cell(r / "telemetry.csv", 2, "enc_r",
                                                  b"1" * 200_000),
                              ["telemetry.csv", "row 2", "field larger than field limit"], True),
    "CSV bad quoting": (lambda r: _set_cell(r / "telemetry.csv", 4, "enc_l", b'"1"2'),
                        ["telemetry.csv", "row 4", "not valid CSV"], True),
    "encoder_ppr NaN": (lambda r: _meta_raw(r, "encoder_ppr", "NaN"),
                        ["meta.json", "column 'encoder_ppr'", "got nan"], True),
    "encoder_ppr Infinity": (lambda r: _meta_raw(r, "encoder_ppr", "Infinity"),
                             ["meta.json", "column 'encoder_ppr'", "got inf"], True),
    "encoder_ppr 1e300": (lambda r: _meta_raw(r, "encoder_ppr", "1e300"),
                          ["meta.json", "column 'encoder_ppr'", "1e+300"], True),
    "encoder_ppr huge integer": (lambda r: _meta_raw(r, "encoder_ppr", "1" + "0" * 400),
                                 ["meta.json", "column 'encoder_ppr'"], True),
    "encoder_ppr 0": (lambda r: _meta_raw(r, "encoder_ppr", "0"),
                      ["meta.json", "column 'encoder_ppr'"], True),
    "robot.r 1e400 (inf)": (lambda r: _meta_edit(r, robot={"r": "@"}) or
                            (r / "meta.json").write_text(
                                (r / "meta.json").read_text().replace('"@"', "1e400")),
                            ["meta.json", "column 'robot.r'", "inf"], True),
    "robot.r huge integer": (lambda r: _meta_edit(r, robot={"r": 10 ** 400}),
                             ["meta.json", "column 'robot.r'", "outside the plausible range"],
                             True),
    "start_pose 1e300": (lambda r: _meta_edit(r, start_pose=[1e300, 0.0, 0.0]),
                         ["meta.json", "column 'start_pose'", "1e+300"], True),
    "start_pose NaN": (lambda r: _meta_raw(r, "start_pose", "[0, 0, NaN]"),
                       ["meta.json", "column 'start_pose'"], True),
    "start_pose not a list": (lambda r: _meta_edit(r, start_pose={"x": 1}),
                              ["meta.json", "column 'start_pose'"], True),
    "robot not an object": (lambda r: _meta_edit(r, robot=[1, 2]),
                            ["meta.json", "column 'robot'"], True),
    "torque_clamp a string": (lambda r: _meta_edit(r, torque_clamp="yes"),
                              ["meta.json", "column 'torque_clamp'"], True),
    "reference kind a list": (lambda r: _meta_edit(r, reference={"kind": ["line"]}),
                              ["meta.json", "column 'reference.kind'"], True),
    "reference t0_s a string": (lambda r: _meta_edit(r, reference={"kind": "line",
                                                                   "t0_s": "soon"}),
                                ["meta.json", "column 'reference.t0_s'"], True),
    "meta a JSON list": (lambda r: _meta_bytes(r, b"[1, 2]"), ["meta.json", "JSON object"], True),
    "meta invalid JSON": (lambda r: _meta_bytes(r, b'{"a": 1,\n "b": }'),
                          ["meta.json", "line 2", "character 7", "invalid JSON"], True),
    "telemetry 1 row": (lambda r: _keep_rows(r / "telemetry.csv", 1),
                        ["telemetry.csv", "row 1", "has 1 data row", "at least 6"], False),
    "telemetry 2 rows": (lambda r: _keep_rows(r / "telemetry.csv", 2),
                         ["telemetry.csv", "row 2", "has 2 data rows", "at least 6"], False),
    "telemetry 5 rows": (lambda r: _keep_rows(r / "telemetry.csv", 5),
                         ["telemetry.csv", "row 5", "at least 6"], False),
    "number with underscore 1_0": (lambda r: _set_cell(r / "telemetry.csv", 7, "enc_r", b"1_0"),
                                   ["telemetry.csv", "row 7", "column 'enc_r'", "'1_0'",
                                    "plain decimal"], True),
    "number with arabic digits": (lambda r: _set_cell(r / "telemetry.csv", 7, "enc_r",
                                                      "١٢".encode()),
                                  ["telemetry.csv", "row 7", "column 'enc_r'"], True),
    "number 1e999": (lambda r: _set_cell(r / "telemetry.csv", 8, "pwm_l", b"1e999"),
                     ["telemetry.csv", "row 8", "column 'pwm_l'", "too large"], True),
    "number infinity": (lambda r: _set_cell(r / "telemetry.csv", 8, "pwm_l", b"-Infinity"),
                        ["telemetry.csv", "row 8", "column 'pwm_l'", "NaN and infinity"], True),
    "time repeats": (lambda r: _set_cell(r / "telemetry.csv", 4, "t_s", b"0.04"),
                     ["telemetry.csv", "row 4", "column 't_s'", "0.04 after 0.04"], True),
    "groundtruth time goes back": (lambda r: _set_cell(r / "groundtruth.csv", 3, "t_s", b"0.5"),
                                   ["groundtruth.csv", "row 4", "column 't_s'",
                                    "0.121 after 0.5"], True),
    "header duplicate": (lambda r: (r / "telemetry.csv").write_bytes(
        (r / "telemetry.csv").read_bytes().replace(b"enc_l", b"enc_r", 1)),
        ["telemetry.csv", "line 1", "column 'enc_r'", "twice"], True),
    "groundtruth is a folder": (lambda r: (os.remove(r / "groundtruth.csv"),
                                           os.mkdir(r / "groundtruth.csv")),
                                ["groundtruth.csv", "not a regular file"], True),
    "telemetry missing": (lambda r: os.remove(r / "telemetry.csv"),
                          ["telemetry.csv", "missing"], True),
}


def _check_message(err, expect):
    assert "Traceback" not in err
    assert "np.float64" not in err and "np.int64" not in err
    for piece in expect:
        assert piece in err, (piece, err)


def test_the_base_run_is_accepted_by_both_tools(tmp_path, capsys):
    run = _base(tmp_path / "run")
    assert runfmt.load_run(run, min_rows=runfmt.ANALYZER_MIN_ROWS).telemetry["t_s"].size == 76
    assert cli(["timing", "--run", str(run), "--isr-cycles", "44"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_exit_2_with_where_and_no_traceback(tmp_path, capsys, monkeypatch, name):
    attack, expect, timing_too = CASES[name]
    run = _base(tmp_path / "run")
    attack(run)
    # the analysis itself must never start on bad input: the runs are validated first
    import host_tools.analyzer.pipeline as analysis
    monkeypatch.setattr(analysis, "analyze", lambda *a, **k: pytest.fail("analysis started"))
    rc = cli(["analyze", str(run), "--out", str(tmp_path / "out"), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 2, err
    _check_message(err, expect)
    rc = cli(["timing", "--run", str(run), "--isr-cycles", "44"])
    cap = capsys.readouterr()
    if timing_too:
        assert rc == 2, cap.out + cap.err
        _check_message(cap.err, expect)
    else:
        assert rc == 0, cap.err  # timing looks at single rows: 1 row is enough for it


OPTION_CASES = {
    "--dt 1e-7": (["--dt", "1e-7"], "--dt 1e-07 must be in [0.0001, 0.01]"),
    "--dt nan": (["--dt", "nan"], "--dt nan must be in"),
    "--dt 1": (["--dt", "1"], "--dt 1 must be in"),
    "--jobs 0": (["--jobs", "0"], "--jobs 0 must be in 1..64"),
    "--jobs 1e6": (["--jobs", "1000000"], "--jobs 1000000 must be in 1..64"),
    "--effects empty": (["--effects", ",,"], "--effects names no effect"),
    "--effects garbage": (["--effects", "a b;rm"], "--effects must be up to"),
}


@pytest.mark.parametrize("name", list(OPTION_CASES))
def test_every_analyzer_option_is_bounded(tmp_path, capsys, monkeypatch, name):
    extra, expect = OPTION_CASES[name]
    run = _base(tmp_path / "run")
    import host_tools.analyzer.pipeline as analysis
    monkeypatch.setattr(analysis, "analyze", lambda *a, **k: pytest.fail("analysis started"))
    rc = cli(["analyze", str(run), "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and expect in err, err


@pytest.mark.parametrize("extra, expect", [
    (["--edge-rate", "1e300"], "--edge-rate 1e+300 must be in"),
    (["--edge-rate", "nan"], "--edge-rate nan must be in"),
    (["--edge-rate", "-5"], "--edge-rate -5 must be in"),
    (["--isr-cycles", "inf"], "--isr-cycles inf must be in"),
    (["--isr-cycles", "0"], "--isr-cycles 0 must be in"),
])
def test_every_timing_option_is_bounded(tmp_path, capsys, extra, expect):
    run = _base(tmp_path / "run")
    assert cli(["timing", "--run", str(run), *extra]) == 2
    assert expect in capsys.readouterr().err


@pytest.mark.parametrize("how", ["existing file", "below a file", "under /proc"])
def test_out_that_cannot_be_created_is_refused_before_reading_or_analysis(
        tmp_path, capsys, monkeypatch, how):
    run = _base(tmp_path / "run")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out = {"existing file": blocker, "below a file": blocker / "sub",
           "under /proc": "/proc/no-such-dir/out"}[how]
    import host_tools.analyzer.pipeline as analysis
    monkeypatch.setattr(analysis, "analyze", lambda *a, **k: pytest.fail("analysis started"))
    monkeypatch.setattr(runfmt, "load_run", lambda *a, **k: pytest.fail("runs read first"))
    rc = cli(["analyze", str(run), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "--out" in err and "Traceback" not in err, err


def test_timing_json_that_cannot_be_written_is_refused_first(tmp_path, capsys):
    run = _base(tmp_path / "run")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert cli(["timing", "--run", str(run), "--json", str(blocker / "o.json")]) == 2
    assert "--json" in capsys.readouterr().err
    assert cli(["timing", "--run", str(run), "--json", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err


@pytest.mark.parametrize("doc, expect", [
    (b'{"format": "ddtiming/1", "isr": [1, 2]}', "key 'isr': must be an object of objects"),
    (b'{"format": "ddtiming/1", "tasks": {"inner": {"max_cycles": 1e400}}}',
     "key 'tasks.inner.max_cycles'"),
    (b'{"format": "ddtiming/1", "other_isr": {"a": 1}}', "key 'other_isr': must be a list"),
    (b'{"format": "ddtiming/1", "other_isr": [5]}', "key 'other_isr[0].cycles_per_event'"),
    (b'{"format": "ddtiming/1", "f_cpu_hz": NaN}', "key '.f_cpu_hz'"),
    (b'\xff\xfe{', "UTF-16"),
    (b'{"format": "ddtiming/1", "source": "\xe9"}', "not UTF-8"),
    (b'[' * 100000, "nested"),
])
def test_timing_sim_file_bad_input(tmp_path, capsys, doc, expect):
    f = tmp_path / "sim.json"
    f.write_bytes(doc)
    assert cli(["timing", "--sim", str(f)]) == 2
    err = capsys.readouterr().err
    assert expect in err and "sim.json" in err and "Traceback" not in err, err


@pytest.mark.parametrize("doc", [b'{"encoder_isr": 5, "tasks": {}}',
                                 b'{"encoder_isr": {"max_cycles": "x"}, "tasks": {}}',
                                 b'{"encoder_isr": {"max_cycles": 1}, "tasks": '
                                 b'{"inner": {"max_cycles": -1}}}', b"\x00"])
def test_timing_bad_fil_json_in_a_run(tmp_path, capsys, doc):
    run = _base(tmp_path / "run")
    (run / "fil.json").write_bytes(doc)
    assert cli(["timing", "--run", str(run)]) == 2
    err = capsys.readouterr().err
    assert "fil.json" in err and "Traceback" not in err, err


def test_underscore_numbers_make_an_extra_column_text_not_ten(tmp_path):
    run = _base(tmp_path / "run")
    p = run / "telemetry.csv"
    lines = p.read_text().splitlines()
    lines[0] += ",note"
    lines[1:] = [ln + (",1_0" if i == 0 else ",10") for i, ln in enumerate(lines[1:])]
    p.write_text("\n".join(lines) + "\n")
    col = runfmt.load_run(run).telemetry["note"]
    assert col.dtype == object and col[0] == "1_0"  # kept as text, never read as 10


def test_label_runs_tells_runs_with_one_folder_name_apart(tmp_path):
    runs = [runfmt.load_run(_base(tmp_path / d / "run-0")) for d in ("a", "b")]
    runs.append(runfmt.load_run(_base(tmp_path / "c" / "x" / "run-1")))
    runfmt.label_runs(runs)
    assert [r.name for r in runs] == ["a/run-0", "b/run-0", "run-1"]
    same = [runfmt.load_run(tmp_path / "a" / "run-0") for _ in range(2)]
    runfmt.label_runs(same)
    assert same[0].name != same[1].name


def test_unknown_meta_keys_are_kept_and_ignored(tmp_path):
    run = _base(tmp_path / "run", meta={"robot": {"foo": [1, 2], "r": 0.04},
                                        "motor": {"bar": {"x": 1}}, "periods_s": {"z": 1},
                                        "my_top_key": [1]})
    r = runfmt.load_run(run)
    assert set(r.meta["robot"]) == set(runfmt.DEFAULT_META["robot"])
    assert set(r.meta["motor"]) == set(runfmt.DEFAULT_META["motor"])
    assert r.ignored_keys == {"robot.foo": [1, 2], "motor.bar": {"x": 1}, "periods_s.z": 1}
    assert r.meta["my_top_key"] == [1]
    assert any("unknown key 'robot.foo' ignored" in n for n in r.notes)


def test_groundtruth_outside_the_telemetry_time_is_noted(tmp_path):
    r = runfmt.load_run(_base(tmp_path / "run", gt_shift=100.0))
    assert any("wholly outside" in n for n in r.notes)
    assert not runfmt.load_run(_base(tmp_path / "ok")).notes


def test_analysis_with_unknown_keys_same_names_non_utf8_path_and_outside_groundtruth(
        tmp_path, capsys):
    """One real analysis (a one-effect subset, no plots of all channels: a few seconds):
    unknown robot/motor keys (a list value too) do not crash the plant; two runs named
    run-0 get distinct labels and plot files; a run path that is not UTF-8 does not break
    report.md; ground truth outside the telemetry's time is a note in the report."""
    a = _base(tmp_path / "a" / "run-0", meta={"robot": {"foo": [1, 2]}, "motor": {"bar": 3}})
    bad_dir = os.path.join(os.fsencode(tmp_path), b"b\xff")
    os.mkdir(bad_dir)
    b = os.fsdecode(os.path.join(bad_dir, b"run-0"))
    _base(__import__("pathlib").Path(b), gt_shift=100.0)
    out = tmp_path / "out"
    t0 = time.time()
    rc = cli(["analyze", str(a), b, "--out", str(out), "--jobs", "1",
              "--effects", "wheel_radius"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "Traceback" not in err
    md = (out / "report.md").read_bytes().decode("utf-8")  # valid UTF-8, whole
    assert "Updated model parameters" in md
    assert "`a/run-0`" in md and "`b\\xff/run-0`" in md
    rep = json.loads((out / "report.json").read_text())
    assert any("wholly outside" in n for n in rep["notes"])
    assert any("unknown key 'robot.foo' ignored" in n for n in rep["notes"])
    pngs = sorted(f for f in os.listdir(out) if f.endswith(".png"))
    assert any(f.startswith("a_run-0") for f in pngs) and any(f.startswith("b") for f in pngs)
    assert time.time() - t0 < 120


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT", "SIGHUP"])
def test_analyzer_stopped_by_a_signal_exits_1_without_partial_outputs(tmp_path, sig):
    import signal
    import subprocess
    import sys
    import threading
    from pathlib import Path

    run = _base(tmp_path / "run", n=600)
    out = tmp_path / "out"
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, "-m", "host_tools", "analyze", str(run), "--out",
                             str(out), "--jobs", "2", "--no-plots"], cwd=root,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err_lines: list[str] = []
    started = threading.Event()

    def read():
        for line in proc.stderr:
            err_lines.append(line)
            if "fitted in" in line:  # the candidate fits (worker processes) are under way
                started.set()
    t = threading.Thread(target=read, daemon=True)
    t.start()
    assert started.wait(120), "".join(err_lines)
    proc.send_signal(getattr(signal, sig))
    proc.wait(60)
    t.join(10)
    err = "".join(err_lines)
    assert proc.returncode == 1, err
    assert f"interrupted by {sig}" in err and "Traceback" not in err, err
    assert not any(out.glob("report.*")) and not any(out.glob("*.tmp"))
