"""Tests of host_tools.runfmt: reading, validating and writing ddrun/1 folders."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from host_tools import params, runfmt
from host_tools.runfmt import RunFormatError, RunWriter, load_run, write_groundtruth


def _columns(n=76, turn=0.0, speed=10.0, ppr=params.ENCODER_PPR, r=params.ROBOT["r"],
             b=params.ROBOT["b"], dt=0.02):
    """A kinematically consistent telemetry table: wheel speeds ramp to `speed`
    (rad/s) with right/left differing by `turn` rad/s; odometry from the counts."""
    t = np.arange(n) * dt
    w_r = np.minimum(t / 0.5, 1.0) * (speed + turn / 2)
    w_l = np.minimum(t / 0.5, 1.0) * (speed - turn / 2)
    th_r = np.concatenate([[0], np.cumsum(w_r[1:] * dt)])
    th_l = np.concatenate([[0], np.cumsum(w_l[1:] * dt)])
    enc_r = np.floor(th_r * ppr / (2 * np.pi))
    enc_l = np.floor(th_l * ppr / (2 * np.pi))
    qr, ql = enc_r * 2 * np.pi / ppr, enc_l * 2 * np.pi / ppr
    phi = r * (qr - ql) / (2 * b)
    ds = np.diff(r * (qr + ql) / 2, prepend=0.0)
    x = np.cumsum(ds * np.cos(phi))
    y = np.cumsum(ds * np.sin(phi))
    om_r = np.diff(qr, prepend=0.0) / dt
    om_l = np.diff(ql, prepend=0.0) / dt
    return {"t_s": t, "enc_r": enc_r.astype(int), "enc_l": enc_l.astype(int),
            "omega_r": om_r, "omega_l": om_l, "tau_cmd_r": np.full(n, 0.05),
            "tau_cmd_l": np.full(n, 0.05), "pwm_r": np.full(n, 0.3), "pwm_l": np.full(n, 0.3),
            "x_odo_m": x, "y_odo_m": y, "phi_odo_rad": phi}


def _make(tmp_path, name="run", meta=None, gt=True, **kw):
    cols = _columns(**kw)
    path = tmp_path / name
    g = None
    if gt:
        g = {"t_s": cols["t_s"][::2] + 0.001, "x_m": cols["x_odo_m"][::2],
             "y_m": cols["y_odo_m"][::2], "phi_rad": cols["phi_odo_rad"][::2]}
    runfmt.write_run(path, meta or {}, cols, g)
    return path


def _rewrite_csv(path, fn):
    lines = open(path).read().splitlines()
    lines = fn(lines)
    open(path, "w").write("\n".join(lines) + "\n")


def _map_column(path, column, fn):
    """Rewrite one column of a CSV file, each value through ``fn`` (float in, float out)."""
    def edit(L):
        j = L[0].split(",").index(column)
        out = [L[0]]
        for line in L[1:]:
            c = line.split(",")
            c[j] = repr(fn(float(c[j])))
            out.append(",".join(c))
        return out
    _rewrite_csv(path, edit)


def test_roundtrip_exact_and_defaults(tmp_path):
    cols = _columns()
    p = tmp_path / "r"
    runfmt.write_run(p, {"experiment": "x", "robot": {"mu_k": 0.2}, "my_key": [1, 2]}, cols)
    run = load_run(p)
    for c in runfmt.TELEMETRY_COLUMNS:
        np.testing.assert_array_equal(run.telemetry[c], np.asarray(cols[c], dtype=float))
    assert run.meta["robot"]["mu_k"] == 0.2
    assert run.meta["robot"]["mu_s"] == params.ROBOT["mu_s"]  # default filled
    assert run.meta["my_key"] == [1, 2]  # unknown kept
    assert run.meta["encoder_ppr"] == params.ENCODER_PPR
    assert run.groundtruth is None
    assert run.start_pose == (0.0, 0.0, 0.0)


def test_missing_format_defaults_but_unknown_version_is_refused(tmp_path):
    p = _make(tmp_path)
    meta = json.load(open(p / "meta.json"))
    del meta["format"]
    json.dump(meta, open(p / "meta.json", "w"))
    assert load_run(p).meta["format"] == "ddrun/1"
    meta["format"] = "ddrun/2"
    json.dump(meta, open(p / "meta.json", "w"))
    with pytest.raises(RunFormatError, match="unknown format version 'ddrun/2'") as e:
        load_run(p)
    assert e.value.file.endswith("meta.json") and e.value.column == "format"


def test_missing_files(tmp_path):
    p = _make(tmp_path)
    os.remove(p / "telemetry.csv")
    with pytest.raises(RunFormatError, match="telemetry.csv.*missing"):
        load_run(p)
    os.remove(p / "meta.json")
    with pytest.raises(RunFormatError, match="meta.json.*missing"):
        load_run(p)
    with pytest.raises(RunFormatError, match="not a directory"):
        load_run(tmp_path / "nope")


def test_missing_column_named(tmp_path):
    p = _make(tmp_path)
    _rewrite_csv(p / "telemetry.csv",
                 lambda L: [",".join(c for i, c in enumerate(l.split(",")) if i != 3) for l in L])
    with pytest.raises(RunFormatError) as e:
        load_run(p)
    assert e.value.column == "omega_r" and "missing required column" in str(e.value)


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf", "", "abc"])
def test_bad_value_names_file_row_column(tmp_path, bad):
    p = _make(tmp_path)
    def edit(L):
        header = L[0].split(",")
        j = header.index("tau_cmd_l")
        cells = L[5].split(",")
        cells[j] = bad
        L[5] = ",".join(cells)
        return L
    _rewrite_csv(p / "telemetry.csv", edit)
    with pytest.raises(RunFormatError) as e:
        load_run(p)
    assert e.value.row == 5 and e.value.column == "tau_cmd_l"
    assert e.value.file.endswith("telemetry.csv")
    assert "row 5 (line 6)" in str(e.value)


def test_non_increasing_time(tmp_path):
    p = _make(tmp_path)
    def edit(L):
        cells = L[11].split(",")
        cells[0] = L[10].split(",")[0]
        L[11] = ",".join(cells)
        return L
    _rewrite_csv(p / "telemetry.csv", edit)
    with pytest.raises(RunFormatError, match="time does not increase") as e:
        load_run(p)
    assert e.value.row == 11 and e.value.column == "t_s"


def test_groundtruth_time_and_empty_phi(tmp_path):
    p = _make(tmp_path)
    _rewrite_csv(p / "groundtruth.csv",
                 lambda L: [L[0]] + [",".join(l.split(",")[:3] + [""]) for l in L[1:]])
    run = load_run(p)
    assert np.all(np.isnan(run.groundtruth["phi_rad"]))
    _rewrite_csv(p / "groundtruth.csv", lambda L: [L[0]] + L[1:4] + [L[2]] + L[4:])
    with pytest.raises(RunFormatError, match="groundtruth.csv.*row 4.*time does not increase"):
        load_run(p)


def test_a_trackers_csv_is_read_with_the_groundtruth_rules(tmp_path):
    """runfmt.read_groundtruth (gt_align's reader of a tracker's file): time must increase
    (row and column named), and a file without phi_rad gets none."""
    trk = tmp_path / "tracker.csv"
    trk.write_text("t_s,x_m,y_m\n0.0,0.0,0.0\n0.1,0.01,0.0\n0.1,0.02,0.0\n")
    with pytest.raises(RunFormatError, match="time does not increase") as e:
        runfmt.read_groundtruth(str(trk))
    assert e.value.row == 3 and e.value.column == "t_s"
    trk.write_text("t_s,x_m,y_m\n0.0,0.0,0.0\n0.1,0.01,0.0\n")
    cols = runfmt.read_groundtruth(str(trk))
    assert sorted(cols) == ["t_s", "x_m", "y_m"] and cols["x_m"][1] == 0.01


def test_groundtruth_nan_position_refused(tmp_path):
    p = _make(tmp_path)
    _rewrite_csv(p / "groundtruth.csv",
                 lambda L: L[:3] + [",".join(L[3].split(",")[:1] + ["nan"] + L[3].split(",")[2:])]
                 + L[4:])
    with pytest.raises(RunFormatError) as e:
        load_run(p)
    assert e.value.row == 3 and e.value.column == "x_m"


def test_phi_in_degrees_detected_in_odometry(tmp_path):
    p = _make(tmp_path, turn=4.0)
    _map_column(p / "telemetry.csv", "phi_odo_rad", np.degrees)
    with pytest.raises(RunFormatError, match="degrees") as e:
        load_run(p)
    assert e.value.column == "phi_odo_rad"


def test_phi_in_degrees_detected_in_groundtruth(tmp_path):
    p = _make(tmp_path, turn=4.0)
    _rewrite_csv(p / "groundtruth.csv", lambda L: [L[0]] + [
        ",".join(l.split(",")[:3] + [repr(np.degrees(float(l.split(",")[3])))]) for l in L[1:]])
    with pytest.raises(RunFormatError, match="degrees") as e:
        load_run(p)
    assert e.value.column == "phi_rad"


def test_multi_turn_and_wrapped_heading_is_not_a_false_alarm(tmp_path):
    # a long spin: heading reaches many turns; a wrapped copy in ground truth jumps by 2*pi
    p = _make(tmp_path, n=1500, turn=30.0, speed=0.0)
    run = load_run(p)
    assert np.ptp(run.telemetry["phi_odo_rad"]) > 4 * np.pi
    gt = run.groundtruth
    wrapped = (gt["phi_rad"] + np.pi) % (2 * np.pi) - np.pi
    os.remove(p / "groundtruth.csv")
    write_groundtruth(p, gt["t_s"], gt["x_m"], gt["y_m"], wrapped)
    load_run(p)  # no error


def test_other_wrong_units(tmp_path):
    p = _make(tmp_path, name="mm")
    _rewrite_csv(p / "groundtruth.csv", lambda L: [L[0]] + [
        ",".join([l.split(",")[0]] + [repr(1000 * float(v)) for v in l.split(",")[1:3]]
                 + [l.split(",")[3]]) for l in L[1:]])
    with pytest.raises(RunFormatError, match="millimetres"):
        load_run(p)
    p = _make(tmp_path, name="pct")
    _rewrite_csv(p / "telemetry.csv", lambda L: [L[0]] + [
        ",".join(c if i != L[0].split(",").index("pwm_r") else "30" for i, c in
                 enumerate(l.split(","))) for l in L[1:]])
    with pytest.raises(RunFormatError, match="percent") as e:
        load_run(p)
    assert e.value.column == "pwm_r" and e.value.row == 1
    p = _make(tmp_path, name="rpm")
    _map_column(p / "telemetry.csv", "omega_l", lambda w: w * 60 / (2 * np.pi))
    with pytest.raises(RunFormatError, match="rpm") as e:
        load_run(p)
    assert e.value.column == "omega_l"
    with pytest.raises(RunFormatError, match="robot.b.*wrong units"):
        _make(tmp_path, name="bmm", meta={"robot": {"b": 105.0}})


def test_parameters_disagree(tmp_path):
    a = load_run(_make(tmp_path, name="a"))
    b = load_run(_make(tmp_path, name="b", meta={"robot": {"mu_k": 0.3}}))
    c = load_run(_make(tmp_path, name="c", meta={"experiment": "other", "torque_clamp": True}))
    runfmt.check_compatible([a, c])
    with pytest.raises(RunFormatError, match="disagree on 'robot.mu_k'") as e:
        runfmt.check_compatible([a, c, b])
    assert e.value.column == "robot.mu_k" and "b/meta.json" in e.value.file


def test_writer_streams_and_validates(tmp_path):
    cols = _columns(n=5)
    rows = [{c: cols[c][i] for c in cols} for i in range(5)]
    p = tmp_path / "w"
    with RunWriter(p, {"experiment": "stream"}) as w:
        w.write_row(dict(rows[0], extra_col=1.5))
        # flushed: the file already holds header + one row
        assert len(open(p / "telemetry.csv").read().splitlines()) == 2
        with pytest.raises(RunFormatError) as e:
            w.write_row(dict(rows[1], extra_col=float("nan")))
        assert e.value.row == 2 and e.value.column == "extra_col"
        with pytest.raises(RunFormatError, match="missing value"):
            w.write_row({k: v for k, v in rows[1].items() if k != "pwm_l"} | {"extra_col": 0})
        w.write_row(dict(rows[1], extra_col=2.0))
        with pytest.raises(RunFormatError, match="time does not increase"):
            w.write_row(dict(rows[0], extra_col=2.0))
        w.write_row(dict(rows[2], extra_col=3.0))
    run = load_run(p)
    assert run.telemetry["t_s"].size == 3
    np.testing.assert_array_equal(run.telemetry["extra_col"], [1.5, 2.0, 3.0])
    with pytest.raises(RunFormatError, match="refusing to overwrite"):
        RunWriter(p, {})


def test_writer_first_row_needs_required_columns(tmp_path):
    with RunWriter(tmp_path / "x", {}) as w:
        with pytest.raises(RunFormatError) as e:
            w.write_row({"t_s": 0.0})
        assert e.value.row == 1 and e.value.column == "enc_r"


def test_start_pose(tmp_path):
    p = _make(tmp_path, meta={"start_pose": [1.0, 2.0, 0.5]})
    assert load_run(p).start_pose == (1.0, 2.0, 0.5)
    with pytest.raises(RunFormatError, match="start_pose"):
        _make(tmp_path, name="bad", meta={"start_pose": [1.0, 2.0]})


@pytest.mark.parametrize("wrapped", ["telemetry", "groundtruth", "both"])
def test_heading_wrapped_in_one_file_and_unwrapped_in_the_other(tmp_path, wrapped):
    # the run format allows a wrapped or an unwrapped heading in both files; a 30 s spin (about 25 turns)
    cols = _columns(n=1500, turn=30.0, speed=0.0)
    wrap = lambda a: (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    g = {"t_s": cols["t_s"][::2] + 0.001, "x_m": cols["x_odo_m"][::2],
         "y_m": cols["y_odo_m"][::2], "phi_rad": cols["phi_odo_rad"][::2]}
    if wrapped in ("telemetry", "both"):
        cols["phi_odo_rad"] = wrap(cols["phi_odo_rad"])
    if wrapped in ("groundtruth", "both"):
        g["phi_rad"] = wrap(g["phi_rad"])
    runfmt.write_run(tmp_path / "r", {}, cols, g)
    run = load_run(tmp_path / "r")  # no "degrees instead of radians?"
    assert np.ptp(np.unwrap(run.groundtruth["phi_rad"])) > 8 * np.pi


def test_heading_in_degrees_still_detected_when_the_other_file_is_wrapped(tmp_path):
    cols = _columns(n=300, turn=4.0)
    g = {"t_s": cols["t_s"][::2] + 0.001, "x_m": cols["x_odo_m"][::2],
         "y_m": cols["y_odo_m"][::2], "phi_rad": np.degrees(cols["phi_odo_rad"][::2])}
    cols["phi_odo_rad"] = (cols["phi_odo_rad"] + np.pi) % (2 * np.pi) - np.pi
    runfmt.write_run(tmp_path / "r", {}, cols, g)
    with pytest.raises(RunFormatError, match="degrees") as e:
        load_run(tmp_path / "r")
    assert e.value.column == "phi_rad"
