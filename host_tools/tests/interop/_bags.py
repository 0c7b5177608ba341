"""Test helper: a run folder written as a ROS bag (ROS 1, ROS 2 sqlite3 or ROS 2 MCAP) with
rosbags' own writers, and the mapping file that reads it back (docs/rosbag-import.md)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from host_tools import runfmt

TOPICS = {"joints": "/joint_states", "duty": "/wheel_duty", "effort": "/wheel_effort",
          "odom": "/odom", "pose": "/mocap/pose", "current": "/motor_current"}


T0_NS = 1_700_000_000_000_000_000  # the bags' stamp of the run's t_s = 0


def mapping(run: runfmt.Run) -> dict:
    """The map of the bags made by :func:`write_bag`, with the run's parameters and the meta.json
    keys the analyzer replays with (reference, clamp, periods, ...)."""
    meta = {k: v for k, v in run.meta.items()
            if k not in ("format", "robot", "motor", "encoder_ppr", "periods_s", "source")}
    return {"format": "ddrobot-bag-map/1",
            "wheel_positions": {"topic": TOPICS["joints"], "right": "wheel_right_joint",
                                "left": "wheel_left_joint"},
            "commands": {"duty": {"topic": TOPICS["duty"], "right": 0, "left": 1},
                         "effort": {"topic": TOPICS["effort"], "right": "wheel_right_joint",
                                    "left": "wheel_left_joint", "field": "effort"}},
            "odometry": {"topic": TOPICS["odom"]},
            "pose": {"topic": TOPICS["pose"]},
            "current": {"topic": TOPICS["current"], "right": 0, "left": 1},
            "robot": run.meta["robot"], "motor": run.meta["motor"],
            "encoder_ppr": run.meta["encoder_ppr"], "periods_s": run.meta["periods_s"],
            "meta": meta, "time_zero_ns": T0_NS}


def write_bag(run_dir, bag_path, fmt: str, t0_ns: int = T0_NS,
              mutate=None, odom_every: int = 1, skip_topics=(), truncate=None,
              nan_odom: int | None = None) -> Path:
    """Write the run as a bag of format ``ros1``, ``sqlite3`` or ``mcap``.  ``mutate(topic, i,
    stamp_ns) -> stamp_ns`` may change a header stamp (to make bad bags; the bag's receive
    times stay in order); the odometry is published
    on every ``odom_every``-th frame only (so the import must resample it); topics named (keys
    of TOPICS) in ``skip_topics`` are left out; ``truncate=(key, i)`` cuts the i-th message of
    that topic to 3 bytes (an undecodable message); the odometry of frame ``nan_odom`` gets
    x = NaN."""
    from rosbags.typesys import Stores, get_typestore
    run = runfmt.load_run(run_dir)
    tel, gt, ppr = run.telemetry, run.groundtruth, int(run.meta["encoder_ppr"])
    ts = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]

    def hdr(stamp):
        return Header(seq=0, stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9),
                      frame_id="world") if fmt == "ros1" else \
            Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="world")

    def quat(phi):
        return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(phi / 2),
                                                 w=math.cos(phi / 2))

    def point(x, y):
        return T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)

    def pose(x, y, phi):
        return T["geometry_msgs/msg/Pose"](position=point(x, y), orientation=quat(float(phi)))

    def multi(values):
        MA = T["std_msgs/msg/MultiArrayLayout"]
        return T["std_msgs/msg/Float64MultiArray"](layout=MA(dim=[], data_offset=0),
                                                   data=np.asarray(values, dtype=np.float64))

    names = ["wheel_right_joint", "wheel_left_joint"]
    z3 = np.zeros(36)
    msgs: list[tuple[int, str, str, object]] = []
    for i in range(tel["t_s"].size):
        st = t0_ns + int(round(float(tel["t_s"][i]) * 1e9))
        s = {k: (mutate(k, i, st) if mutate else st) for k in TOPICS}
        th = [float(tel[c][i]) * 2 * math.pi / ppr for c in ("enc_r", "enc_l")]
        msgs.append((st, TOPICS["joints"], "sensor_msgs/msg/JointState",
                     T["sensor_msgs/msg/JointState"](
                         header=hdr(s["joints"]), name=names, position=np.array(th),
                         velocity=np.array([tel["omega_r"][i], tel["omega_l"][i]], dtype=float),
                         effort=np.array([], dtype=float))))
        msgs.append((st, TOPICS["effort"], "sensor_msgs/msg/JointState",
                     T["sensor_msgs/msg/JointState"](
                         header=hdr(s["effort"]), name=names, position=np.array([], dtype=float),
                         velocity=np.array([], dtype=float),
                         effort=np.array([tel["tau_cmd_r"][i], tel["tau_cmd_l"][i]], dtype=float))))
        msgs.append((st, TOPICS["duty"], "std_msgs/msg/Float64MultiArray",
                     multi([tel["pwm_r"][i], tel["pwm_l"][i]])))
        if "current_r_a" in tel:
            msgs.append((st, TOPICS["current"], "std_msgs/msg/Float64MultiArray",
                         multi([tel["current_r_a"][i], tel["current_l_a"][i]])))
        PWC = T["geometry_msgs/msg/PoseWithCovariance"]
        TWC = T["geometry_msgs/msg/TwistWithCovariance"]
        V3 = T["geometry_msgs/msg/Vector3"]
        if i % odom_every and i != tel["t_s"].size - 1:
            continue
        x_odo = float("nan") if nan_odom == i else tel["x_odo_m"][i]
        msgs.append((st, TOPICS["odom"], "nav_msgs/msg/Odometry", T["nav_msgs/msg/Odometry"](
            header=hdr(s["odom"]), child_frame_id="base_link",
            pose=PWC(pose=pose(x_odo, tel["y_odo_m"][i], tel["phi_odo_rad"][i]),
                     covariance=z3),
            twist=TWC(twist=T["geometry_msgs/msg/Twist"](linear=V3(x=0.0, y=0.0, z=0.0),
                                                          angular=V3(x=0.0, y=0.0, z=0.0)),
                      covariance=z3))))
    if gt is not None:
        for i in range(gt["t_s"].size):
            st = t0_ns + int(round(float(gt["t_s"][i]) * 1e9))
            sh = mutate("pose", i, st) if mutate else st
            msgs.append((st, TOPICS["pose"], "geometry_msgs/msg/PoseStamped",
                         T["geometry_msgs/msg/PoseStamped"](
                             header=hdr(sh), pose=pose(gt["x_m"][i], gt["y_m"][i],
                                                       gt["phi_rad"][i]))))
    msgs = [m for m in msgs if m[1] not in {TOPICS[k] for k in skip_topics}]
    msgs.sort(key=lambda m: m[0])  # stable: bag order = frame order
    bag_path = Path(bag_path)
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer
        w = Writer(bag_path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        w = Writer(bag_path, version=9, storage_plugin=StoragePlugin.MCAP if fmt == "mcap"
                   else StoragePlugin.SQLITE3)
    with w:
        conns = {}
        for _, topic, typ, _m in msgs:
            if topic not in conns:
                conns[topic] = (w.add_connection(topic, typ, typestore=ts), typ)
        seen: dict[str, int] = {}
        for st, topic, typ, m in msgs:
            c, _ = conns[topic]
            data = ts.serialize_ros1(m, typ) if fmt == "ros1" else ts.serialize_cdr(m, typ)
            k = seen[topic] = seen.get(topic, -1) + 1
            if truncate is not None and TOPICS[truncate[0]] == topic and truncate[1] == k:
                data = bytes(data)[:3]
            w.write(c, st, data)
    return bag_path


def write_map(run_dir, path, **changes) -> Path:
    m = mapping(runfmt.load_run(run_dir))
    m.update(changes)
    Path(path).write_text(json.dumps(m, indent=1))
    return Path(path)
