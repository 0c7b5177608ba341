"""``ddrobot import``: ROS bags (ROS 1, ROS 2 sqlite3, ROS 2 MCAP) written with rosbags' own
writers from runs of the truth simulator are imported back into run folders; the imported run
matches the original within the resampling, and the analyzer reaches the same verdict and
parameters; bad bags and maps are exit 2 with the topic and message index."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

import _bags  # noqa: E402

from host_tools import runfmt, truth  # noqa: E402
from host_tools.__main__ import main as cli  # noqa: E402

LINE = {"kind": "line", "accel": 1.0, "cruise": 0.6}
EFFECTS = "motor_back_emf,axle_coulomb,wheel_radius"
FORMATS = {"ros1": "run.bag", "sqlite3": "run_sqlite3", "mcap": "run_mcap"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("truth")
    return {"null": truth.simulate_run(d / "null", LINE, None, duration_s=1.5, seed=4),
            "bemf": truth.simulate_run(d / "bemf", LINE, {"motor_back_emf": {"ke_ratio": 1.2}},
                                       duration_s=1.5, seed=3)}


def _import(run, tmp_path, fmt, odom_every=2, **kw):
    bag = _bags.write_bag(run, tmp_path / FORMATS[fmt], fmt, odom_every=odom_every, **kw)
    mp = _bags.write_map(run, tmp_path / "map.json")
    out = tmp_path / f"imported_{fmt}"
    rc = cli(["import", str(bag), "--map", str(mp), "--out", str(out)])
    return rc, out


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_imported_run_matches_the_original(runs, tmp_path, fmt):
    rc, out = _import(runs["bemf"], tmp_path, fmt)
    assert rc == 0
    a, b = runfmt.load_run(runs["bemf"]), runfmt.load_run(out)
    assert b.meta["source"] == "rosbag" and b.meta["robot"] == a.meta["robot"]
    assert b.meta["reference"] == a.meta["reference"]
    for c in a.telemetry:  # sampled on the frames: exact; odometry every other frame: resampled,
        # within the largest change from one frame to the next (linear between its neighbours)
        odo = c.endswith(("_odo_m", "_odo_rad"))
        tol = float(np.max(np.abs(np.diff(a.telemetry[c])))) if odo else 0.0
        np.testing.assert_allclose(b.telemetry[c], a.telemetry[c], atol=tol + 1e-12, rtol=0,
                                   err_msg=c)
    # the odometry really was resampled: between its samples it differs a little
    assert np.max(np.abs(b.telemetry["x_odo_m"] - a.telemetry["x_odo_m"])) > 0
    for c in ("t_s", "x_m", "y_m"):
        np.testing.assert_allclose(b.groundtruth[c], a.groundtruth[c], atol=1e-12, err_msg=c)
    dphi = np.angle(np.exp(1j * (b.groundtruth["phi_rad"] - a.groundtruth["phi_rad"])))
    assert np.max(np.abs(dphi)) < 1e-9


def _analyze(run, out):
    rc = cli(["analyze", str(run), "--out", str(out), "--jobs", "1", "--effects", EFFECTS,
              "--no-plots"])
    assert rc == 0
    return json.loads((out / "report.json").read_text())


@pytest.mark.parametrize("case,fmt", [("null", "mcap"), ("bemf", "mcap"), ("bemf", "ros1")])
def test_imported_run_analyzes_to_the_same_verdict(runs, tmp_path, case, fmt):
    rc, out = _import(runs[case], tmp_path, fmt)
    assert rc == 0
    want = _analyze(runs[case], tmp_path / "rep_original")
    got = _analyze(out, tmp_path / "rep_imported")
    assert got["verdict"] == want["verdict"]
    assert want["verdict"] == ("no_mismatch" if case == "null" else "explained")
    assert [s["effect"] for s in got["selected"]] == [s["effect"] for s in want["selected"]]
    for sw, sg in zip(want["selected"], got["selected"]):
        for k, v in sw["params"].items():
            assert sg["params"][k] == pytest.approx(v, rel=0.01), k


def _bad(capsys, rc, *words):
    err = capsys.readouterr().err
    assert rc == 2, err
    for w in words:
        assert w in err, err
    assert "Traceback" not in err


def test_non_monotonic_stamp_names_topic_and_index(runs, tmp_path, capsys):
    def back(topic, i, st):  # message 7 of the wheel positions goes back in time
        return st - 100_000_000 if topic == "joints" and i == 7 else st
    rc, out = _import(runs["null"], tmp_path, "mcap", mutate=back)
    _bad(capsys, rc, "/joint_states", "message 7", "does not increase")
    assert not (out / "telemetry.csv").exists()


def test_missing_topic_is_bad_input(runs, tmp_path, capsys):
    rc, out = _import(runs["null"], tmp_path, "ros1", skip_topics=("odom",))
    _bad(capsys, rc, "/odom", "not in the bag")
    assert not (out / "telemetry.csv").exists()


def test_missing_bag_and_a_file_that_is_no_bag(runs, tmp_path, capsys):
    mp = _bags.write_map(runs["null"], tmp_path / "map.json")
    rc = cli(["import", str(tmp_path / "none.bag"), "--map", str(mp), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "none.bag: does not exist")
    (tmp_path / "text.bag").write_text("not a bag\n")
    rc = cli(["import", str(tmp_path / "text.bag"), "--map", str(mp), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "text.bag: not a readable ROS 1 or ROS 2 bag")
    bag = _bags.write_bag(runs["null"], tmp_path / "ros1.bag", "ros1")
    renamed = bag.rename(tmp_path / "ros1_no_suffix")
    rc = cli(["import", str(renamed), "--map", str(mp), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "its name must end in .bag")


def test_a_pose_that_is_not_finite_names_topic_and_index(runs, tmp_path, capsys):
    rc, out = _import(runs["null"], tmp_path, "mcap", odom_every=1, nan_odom=9)
    _bad(capsys, rc, "/odom", "message 9", "not finite")
    assert not out.exists()


def test_unknown_type_is_bad_input(runs, tmp_path, capsys):
    bag = _bags.write_bag(runs["null"], tmp_path / "b", "sqlite3")
    # the wheel positions mapped to the odometry topic: an Odometry is not a JointState
    mp = _bags.write_map(runs["null"], tmp_path / "map.json",
                         wheel_positions={"topic": "/odom", "right": "a", "left": "b"})
    rc = cli(["import", str(bag), "--map", str(mp), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "/odom", "nav_msgs/msg/Odometry", "sensor_msgs/msg/JointState")


def test_missing_joint_names_message(runs, tmp_path, capsys):
    bag = _bags.write_bag(runs["null"], tmp_path / "b", "mcap")
    mp = _bags.write_map(runs["null"], tmp_path / "map.json",
                         wheel_positions={"topic": "/joint_states", "right": "wheel_right_joint",
                                          "left": "left_wheel"})
    rc = cli(["import", str(bag), "--map", str(mp), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "/joint_states", "message 0", "left_wheel")


def test_bad_map_is_bad_input(runs, tmp_path, capsys):
    bag = _bags.write_bag(runs["null"], tmp_path / "b", "mcap")
    mp = tmp_path / "map.yaml"
    mp.write_text("wheel_positions: {topic: /joint_states\n  commands: [\n")
    rc = cli(["import", str(bag), "--map", str(mp), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "map.yaml", "line")
    mp2 = _bags.write_map(runs["null"], tmp_path / "m2.json", wheel_speed={"topic": "/x"})
    rc = cli(["import", str(bag), "--map", str(mp2), "--out", str(tmp_path / "o")])
    _bad(capsys, rc, "unknown key", "wheel_speed")


def test_voltage_commands_and_differentiated_speeds(runs, tmp_path):
    """A map with voltages instead of duties, and joint states without velocities."""
    run = runfmt.load_run(runs["null"])
    bag = _bags.write_bag(runs["null"], tmp_path / "b", "mcap")
    m = _bags.mapping(run)
    sv = run.meta["motor"]["supply_v"]
    # the duty topic read as volts: the imported duty is divided by the supply voltage
    m["commands"] = {"voltage": m["commands"]["duty"], "effort": m["commands"]["effort"]}
    (tmp_path / "m.json").write_text(json.dumps(m))
    out = tmp_path / "o"
    assert cli(["import", str(bag), "--map", str(tmp_path / "m.json"), "--out", str(out)]) == 0
    b = runfmt.load_run(out)
    np.testing.assert_allclose(b.telemetry["pwm_r"], run.telemetry["pwm_r"] / sv, rtol=1e-12)
    assert b.meta["import"]["omega"] == "JointState velocity"
    assert math.isfinite(b.meta["import"]["t0_unix_s"])


def test_the_documented_map_and_topics_are_the_code(tmp_path):
    """docs/interop.md's mapping example is accepted by the importer, names every key it
    knows, and its topic table is the export's."""
    import re
    from pathlib import Path

    from host_tools.interop import messages, rosbag_import
    doc = (Path(__file__).resolve().parents[3] / "docs" / "interop.md").read_text()
    example = re.search(r"```yaml\n(.*?)```", doc, re.S).group(1)
    (tmp_path / "map.yaml").write_text(example)
    m = rosbag_import.load_map(str(tmp_path / "map.yaml"))
    assert set(m) == rosbag_import.MAP_KEYS
    rows = re.findall(r"^\| `(/[a-z_/]+)` \| `([a-zA-Z.]+)`", doc, re.M)
    assert rows == [(t.name, t.schema) for t in messages.TOPICS.values()]


def test_telemetry_period_is_the_frames_spacing(runs, tmp_path):
    run = runfmt.load_run(runs["null"])
    bag = _bags.write_bag(runs["null"], tmp_path / "b", "mcap")
    m = _bags.mapping(run)
    del m["periods_s"]
    (tmp_path / "m.json").write_text(json.dumps(m))
    assert cli(["import", str(bag), "--map", str(tmp_path / "m.json"), "--out",
                str(tmp_path / "o")]) == 0
    got = runfmt.load_run(tmp_path / "o").meta["periods_s"]["telemetry"]
    assert got == pytest.approx(float(np.median(np.diff(run.telemetry["t_s"]))), abs=1e-9)


@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_undecodable_message_names_topic_and_index(runs, tmp_path, capsys, fmt):
    rc, out = _import(runs["null"], tmp_path, fmt, truncate=("odom", 4))
    _bad(capsys, rc, "/odom", "message 4", "cannot decode")
    assert not (out / "telemetry.csv").exists()


def test_external_pose_from_an_odometry_topic(runs, tmp_path):
    """The external pose may be a nav_msgs/Odometry (e.g. a motion-capture bridge)."""
    run = runfmt.load_run(runs["null"])
    bag = _bags.write_bag(runs["null"], tmp_path / "b.bag", "ros1", skip_topics=("pose",))
    mp = _bags.write_map(runs["null"], tmp_path / "m.json", pose={"topic": "/odom"})
    assert cli(["import", str(bag), "--map", str(mp), "--out", str(tmp_path / "o")]) == 0
    gt = runfmt.load_run(tmp_path / "o").groundtruth
    np.testing.assert_allclose(gt["t_s"], run.telemetry["t_s"], atol=1e-12)
    np.testing.assert_allclose(gt["x_m"], run.telemetry["x_odo_m"])
    np.testing.assert_allclose(gt["phi_rad"], run.telemetry["phi_odo_rad"], atol=1e-12)
