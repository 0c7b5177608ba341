"""``ddrobot export``: a run (and its analysis) as MCAP, read back with the ``mcap`` reader;
topics, schemas, message counts and values are checked against the run folder and report.json."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import runfmt, truth  # noqa: E402
from host_tools.__main__ import main as cli  # noqa: E402

LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    run = truth.simulate_run(d / "bemf", LINE, {"motor_back_emf": {"ke_ratio": 1.2}},
                             duration_s=1.5, seed=3)
    other = truth.simulate_run(d / "other", {**LINE, "cruise": 0.4},
                               {"motor_back_emf": {"ke_ratio": 1.2}}, duration_s=1.5, seed=5)
    assert cli(["analyze", str(run), str(other), "--out", str(d / "rep"), "--jobs", "1",
                "--effects", "motor_back_emf,axle_coulomb", "--no-plots"]) == 0
    return d, run, d / "rep"


def _read(path):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
    with open(path, "rb") as fh:
        r = make_reader(fh, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = r.get_summary()
        info = {c.topic: (summary.schemas[c.schema_id], c.message_encoding,
                          summary.statistics.channel_message_counts[c.id])
                for c in summary.channels.values()}
        msgs: dict[str, list] = {}
        for schema, ch, m in r.iter_messages():
            msgs.setdefault(ch.topic, []).append(m)
        dec = DecoderFactory()
        decoded = {}
        for topic, (schema, enc, _) in info.items():
            if enc == "json":
                decoded[topic] = [json.loads(m.data) for m in msgs[topic]]
            else:
                f = dec.decoder_for(enc, schema)
                decoded[topic] = [f(m.data) for m in msgs[topic]]
    return info, msgs, decoded


def _yaw(q):
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def test_export_with_report(analysed, tmp_path):
    d, run_dir, rep_dir = analysed
    out = tmp_path / "run.mcap"
    assert cli(["export", str(run_dir), "--report", str(rep_dir), "--out", str(out)]) == 0
    run = runfmt.load_run(run_dir)
    rep = json.loads((rep_dir / "report.json").read_text())
    info, raw, msgs = _read(out)
    n, g = run.telemetry["t_s"].size, run.groundtruth["t_s"].size
    windows = [m for m in rep["mismatch"] if m["run"] == "bemf"]
    spans = [m for m in rep["localization"] if m["run"] == "bemf"]
    assert windows and len(windows) < len(rep["mismatch"])  # the other run's are left out
    want = {"/telemetry": ("ddrobot.Telemetry", "json", n),
            "/odometry/pose": ("foxglove.PoseInFrame", "protobuf", n),
            "/odometry/tf": ("foxglove.FrameTransform", "protobuf", n),
            "/groundtruth/pose": ("foxglove.PoseInFrame", "protobuf", g),
            "/groundtruth/tf": ("foxglove.FrameTransform", "protobuf", g),
            "/analysis/summary": ("ddrobot.AnalysisSummary", "json", 1),
            "/analysis/mismatch": ("ddrobot.MismatchWindow", "json", len(windows)),
            "/analysis/mismatch_active": ("ddrobot.MismatchActive", "json", n)}
    if spans:
        want["/analysis/localization"] = ("ddrobot.MismatchSpan", "json", len(spans))
    series = _series_rows(rep_dir, rep, 0)
    for c, rows in series.items():
        want[f"/analysis/series/{c}"] = ("ddrobot.SeriesSample", "json", len(rows))
    assert {t: (s.name, e, c) for t, (s, e, c) in info.items()} == want
    for t, (s, e, _) in info.items():
        assert s.encoding == ("protobuf" if e == "protobuf" else "jsonschema")
    # telemetry: every column, every frame, at the frame's board time
    tel = msgs["/telemetry"]
    for c, col in run.telemetry.items():
        np.testing.assert_array_equal([m[c] for m in tel], col, err_msg=c)
    assert [m.log_time for m in raw["/telemetry"]] == [round(t * 1e9) for t in run.telemetry["t_s"]]
    # odometry and ground truth poses in the world frame
    od = msgs["/odometry/pose"]
    assert all(p.frame_id == "world" for p in od)
    np.testing.assert_allclose([p.pose.position.x for p in od], run.telemetry["x_odo_m"])
    np.testing.assert_allclose([_yaw(p.pose.orientation) for p in od],
                               np.angle(np.exp(1j * run.telemetry["phi_odo_rad"])), atol=1e-12)
    gp, gtf = msgs["/groundtruth/pose"], msgs["/groundtruth/tf"]
    np.testing.assert_allclose([p.pose.position.y for p in gp], run.groundtruth["y_m"])
    np.testing.assert_allclose([t.translation.x for t in gtf], run.groundtruth["x_m"])
    assert {(t.parent_frame_id, t.child_frame_id) for t in gtf} == {("world", "base_link")}
    np.testing.assert_allclose([_yaw(t.rotation) for t in gtf],
                               np.angle(np.exp(1j * run.groundtruth["phi_rad"])), atol=1e-12)
    assert [p.timestamp.seconds * 10**9 + p.timestamp.nanos for p in gp] == \
        [round(t * 1e9) for t in run.groundtruth["t_s"]]
    # the analyzer's findings for this run on the same timeline
    s = msgs["/analysis/summary"][0]
    assert s["verdict"] == rep["verdict"] and s["run"] == "bemf"
    assert [x["effect"] for x in s["selected"]] == [x["effect"] for x in rep["selected"]]
    got = [(m["channel"], m["t_start_s"], m["t_end_s"], m["rms"]) for m in msgs["/analysis/mismatch"]]
    assert sorted(got) == sorted((w["channel"], w["t_start_s"], w["t_end_s"], w["rms"])
                                 for w in windows)
    act = msgs["/analysis/mismatch_active"]
    w0 = windows[0]
    for t, a in zip(run.telemetry["t_s"], act):
        inside = any(w["channel"] == w0["channel"] and w["t_start_s"] <= t <= w["t_end_s"]
                     for w in windows)
        assert a[w0["channel"]] == int(inside)
    assert any(a[w0["channel"]] for a in act) and not all(a[w0["channel"]] for a in act)
    assert all(a["any"] == max(v for k, v in a.items() if k != "any") for a in act)


def _series_rows(rep_dir, rep, k):
    """series/<run>.csv of the report's k-th run, by channel."""
    import csv
    with open(rep_dir / rep["series"][k], newline="") as fh:
        out: dict[str, list] = {}
        for r in csv.DictReader(fh):
            out.setdefault(r["channel"], []).append(r)
    return out


def _num(v: str):
    return None if v == "" else float(v)


def test_export_carries_the_analyzers_series_on_the_runs_timeline(analysed, tmp_path):
    """The nominal and updated simulations, the residuals and the noise band of every channel
    (the report's series/<run>.csv) as /analysis/series/<channel>, at the samples' times."""
    d, run_dir, rep_dir = analysed
    out = tmp_path / "run.mcap"
    assert cli(["export", str(run_dir), "--report", str(rep_dir), "--out", str(out)]) == 0
    rep = json.loads((rep_dir / "report.json").read_text())
    info, raw, msgs = _read(out)
    series = _series_rows(rep_dir, rep, 0)
    assert {"omega_r", "x_m", "current_l_a", "tau_cmd_r"} <= set(series)
    for c, rows in series.items():
        topic = f"/analysis/series/{c}"
        assert [m.log_time for m in raw[topic]] == [round(float(r["t_s"]) * 1e9) for r in rows]
        for k in ("recording", "nominal", "updated", "residual_nominal", "residual_updated",
                  "band", "noise_floor"):
            assert [m[k] for m in msgs[topic]] == [_num(r[k]) for r in rows], (c, k)
        assert [m["in_mismatch_window"] for m in msgs[topic]] == \
            [int(r["in_mismatch_window"]) for r in rows]
    om = msgs["/analysis/series/omega_r"]
    assert all(m["updated"] is not None for m in om)      # back-EMF selected: an update
    assert any(m["in_mismatch_window"] for m in om)
    # the other run's series are not in this run's file
    other = _series_rows(rep_dir, rep, 1)
    assert [m["recording"] for m in om] != [_num(r["recording"]) for r in other["omega_r"]]


def test_export_without_report_or_groundtruth(analysed, tmp_path):
    d, run_dir, _ = analysed
    bare = tmp_path / "bare"
    run = runfmt.load_run(run_dir)
    runfmt.write_run(bare, run.meta, run.telemetry)
    out = tmp_path / "bare.mcap"
    assert cli(["export", str(bare), "--out", str(out)]) == 0
    info, _, _ = _read(out)
    assert set(info) == {"/telemetry", "/odometry/pose", "/odometry/tf"}


def test_bad_inputs_are_exit_2(analysed, tmp_path, capsys):
    d, run_dir, rep_dir = analysed
    assert cli(["export", str(tmp_path / "nope"), "--out", str(tmp_path / "x.mcap")]) == 2
    assert "nope" in capsys.readouterr().err
    # a report of other runs
    (tmp_path / "rep").mkdir()
    rep = json.loads((rep_dir / "report.json").read_text())
    rep["runs"] = ["somewhere/else"]
    (tmp_path / "rep" / "report.json").write_text(json.dumps(rep))
    assert cli(["export", str(run_dir), "--report", str(tmp_path / "rep"),
                "--out", str(tmp_path / "x.mcap")]) == 2
    assert "not one of the report's runs" in capsys.readouterr().err
    (tmp_path / "rep" / "report.json").write_text("{\n  \"format\": ")
    assert cli(["export", str(run_dir), "--report", str(tmp_path / "rep"),
                "--out", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert "report.json: line 2" in err and "Traceback" not in err
    assert not (tmp_path / "x.mcap").exists()


def test_malformed_report_entries_are_bad_input(analysed, tmp_path, capsys):
    d, run_dir, rep_dir = analysed
    rep = json.loads((rep_dir / "report.json").read_text())
    del rep["mismatch"][2]["t_end_s"]
    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "report.json").write_text(json.dumps(rep))
    out = tmp_path / "x.mcap"
    assert cli(["export", str(run_dir), "--report", str(tmp_path / "rep"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "mismatch[2]: t_end_s missing" in err and "Traceback" not in err
    assert not out.exists() and not (tmp_path / "x.mcap.part").exists()
