"""Bad input to the logger, --attach-groundtruth, model.json readers and the installation's
own tables: exit 2 with the file and the place, never a traceback, nothing sent or written."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools import gt_align
from host_tools import model as M
from test_logger import _args, _make_run
from host_tools import logger as L

ROOT = Path(__file__).resolve().parents[2]
GOOD_MODEL = {"format": "ddmodel/1", "robot": {"mu_s": 0.3, "mu_k": 0.25}, "motor": {}, "effects": {}}


def _tracked_run(tmp_path, offset=0.5):
    """A recorded run and a tracker CSV (``tracker.csv`` beside it) ``offset`` s off."""
    run = tmp_path / "run"
    tt, xt, yt = _make_run(str(run), offset=offset)
    csv = tmp_path / "tracker.csv"
    csv.write_text("t_s,x_m,y_m,phi_rad\n" + "".join(f"{a:.4f},{b:.5f},{c:.5f},\n" for a, b, c in zip(tt, xt, yt)))
    return run, csv


def _model(tmp_path, text: bytes | str) -> str:
    p = tmp_path / "model.json"
    p.write_bytes(text.encode() if isinstance(text, str) else text)
    return str(p)


@pytest.mark.parametrize("text, expect", [
    (json.dumps(dict(GOOD_MODEL, robot={"mu_s": True, "mu_k": 0.25})), "robot.mu_s = True is not a number"),
    (json.dumps(dict(GOOD_MODEL, robot={"mu_s": 1e308, "mu_k": 0.25})), "'robot.mu_s'"),
    ('{"format": "ddmodel/1", "robot": {"mu_s": 0.3, "mu_k": 0.25}, "x": "caf\xe9"}'.encode("latin-1"),
     "is not UTF-8"),
    ('{"format": "ddmodel/1", "robot": {"mu_s": ' + "1" * 5000 + ', "mu_k": 0.25}}', "model.json: not readable JSON"),
    ("[" * 100_000 + "]" * 100_000, "model.json: not readable JSON: nested"),
    (json.dumps(dict(GOOD_MODEL, robot={"mu_s": 0.3, "mu_k": 0.25, "I_wy": 1e-9})), "'robot.I_wy'"),
])
def test_bad_model_files_are_refused_naming_the_file(tmp_path, capsys, text, expect):
    path = _model(tmp_path, text)
    with pytest.raises(M.ModelError) as e:
        M.load_model(path)
    assert path in str(e.value) and expect in str(e.value)
    # the logger refuses it before the port is opened: nothing sent, no folder
    assert L.main(_args(["--port", "loop://", "--out", str(tmp_path / "run"), "--model", path])) == 2
    err = capsys.readouterr().err
    assert expect in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_fil_record_refuses_the_same_model_files(tmp_path):
    path = _model(tmp_path, "[" * 100_000 + "]" * 100_000)
    r = subprocess.run([sys.executable, "-m", "host_tools", "fil", "record", "--out", str(tmp_path / "run"),
                        "--model", path], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert "model.json" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("opt", [["--experiment", "straight", "--accel", "1e308"],
                                 ["--experiment", "straight", "--duration", "1e308"],
                                 ["--mu-s", "1e308", "--mu-k", "0.2"],
                                 ["--mu-s=-1e308", "--mu-k", "0.2"]])
def test_huge_option_values_are_refused_naming_the_field(tmp_path, capsys, opt):
    assert L.main(_args(["--port", "loop://", "--out", str(tmp_path / "run"), *opt])) == 2
    err = capsys.readouterr().err
    assert "out of range" in err and "Traceback" not in err


def test_out_holding_only_a_meta_json_is_refused_before_the_port(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "meta.json").write_text("{}")
    opened = []
    lg = L.Logger(str(out), lambda: opened.append(1), "x", 115200, status=False)
    with pytest.raises(L.LoggerError) as e:
        lg.run()
    assert e.value.code == 2 and "meta.json" in str(e.value) and not opened
    assert sorted(p.name for p in out.iterdir()) == ["meta.json"]  # no reserve file left


@pytest.mark.parametrize("max_offset", ["nan", "1e9", "1e5", "-1", "inf"])
def test_gt_max_offset_is_bounded(tmp_path, capsys, max_offset):
    run, csv = _tracked_run(tmp_path)
    code = L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv),
                         "--gt-max-offset", max_offset]))
    assert code == 2
    assert "--gt-max-offset" in capsys.readouterr().err
    assert not (run / "groundtruth.csv").exists()


def test_a_large_max_offset_searches_only_where_the_recordings_can_overlap(tmp_path):
    run, csv = _tracked_run(tmp_path)
    info = gt_align.attach_groundtruth(str(run), str(csv), max_offset_s=86_400.0)
    assert info["offset_s"] == pytest.approx(0.5, abs=0.02)


def test_a_tracker_clock_glitch_in_the_last_row_is_refused_not_allocated(tmp_path, capsys):
    run, csv = _tracked_run(tmp_path)
    lines = csv.read_text().splitlines()
    cells = lines[-1].split(",")
    cells[0] = "1e9"
    lines[-1] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(csv)])) == 2
    err = capsys.readouterr().err
    assert f"data row {len(lines) - 1}" in err and "clock glitch" in err and "Traceback" not in err


@pytest.mark.parametrize("table, damage", [
    ("params/params.json", "truncated"), ("params/params.json", "nested"),
    ("protocol/protocol.json", "truncated"), ("protocol/protocol.json", "nested")])
def test_a_broken_table_of_the_installation_is_named_without_a_traceback(tmp_path, table, damage):
    inst = tmp_path / "inst"
    shutil.copytree(ROOT / "host_tools", inst / "host_tools", ignore=shutil.ignore_patterns("tests", "__pycache__"))
    for d in ("params", "protocol"):
        shutil.copytree(ROOT / d, inst / d)
    f = inst / table
    f.write_text(f.read_text()[:300] if damage == "truncated" else "[" * 100_000 + "]" * 100_000)
    for argv in (["--help"], ["log", "--help"], ["timing", "--sim", "x.json"]):
        r = subprocess.run([sys.executable, "-m", "host_tools", *argv], cwd=inst, capture_output=True, text=True)
        assert r.returncode == 2, (argv, r.stderr)
        assert str(f) in r.stderr and "Traceback" not in r.stderr, r.stderr
