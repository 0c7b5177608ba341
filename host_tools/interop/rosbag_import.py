"""``ddrobot import BAG --map MAP --out RUN_DIR``: a ROS bag as a ``ddrun/1`` run folder.

BAG is a ROS 1 ``.bag`` file or a ROS 2 bag folder (sqlite3 or MCAP storage), read with the
pure-Python ``rosbags`` (no ROS install).  MAP (YAML or JSON, documented in
docs/rosbag-import.md) names the topics and fields:

    wheel_positions  sensor_msgs/JointState: joint names ``right``/``left``; their stamps are the
                     telemetry frames; position -> enc_* (``encoder_ppr`` counts per turn),
                     velocity (or, when a message has none, the difference of positions) -> omega_*
    commands         ``duty`` (or ``voltage``, divided by motor.supply_v) -> pwm_*, ``effort``
                     (N m) -> tau_cmd_*; each a JointState (joint names, ``field``) or a
                     std_msgs Float64/Float32MultiArray (``right``/``left`` are indices)
    odometry         nav_msgs/Odometry -> x_odo_m, y_odo_m, phi_odo_rad
    pose             geometry_msgs/PoseStamped or nav_msgs/Odometry -> groundtruth.csv (own rate)
    current          like a command source -> current_r_a, current_l_a (optional)
    robot, motor, encoder_ppr, periods_s, meta   the run's parameters and other meta.json keys
                     (periods_s.telemetry: the frames' median spacing unless given)
    time_zero_ns     the stamp (integer ns) that becomes t_s = 0, e.g. the start of the
                     experiment (default: the first wheel-position stamp)

Every source is resampled onto the frames: measured values linearly, commands held (the last
value sent); headings are unwrapped first.  A message's time is its header stamp, or the bag's
receive time for a message without a header.

Bad input — a mapped topic missing from the bag or empty, a topic of a type its role does not
accept, a joint or index missing from a message, stamps that do not increase, a map that
names unknown keys — is exit 2 with the topic and the message index (0-based, in the topic's
bag order).  Nothing is written then.
"""
from __future__ import annotations

import argparse
import logging
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from host_tools import runfmt
from host_tools.interop import _cli

log = logging.getLogger(__name__)

MAP_FORMAT = "ddrobot-bag-map/1"
JOINT_STATE = "sensor_msgs/msg/JointState"
MULTI_ARRAYS = ("std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float32MultiArray")
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
PAIR_TYPES = (JOINT_STATE,) + MULTI_ARRAYS
ROLES = {"wheel_positions": (JOINT_STATE,), "odometry": (ODOMETRY,),
         "pose": (POSE_STAMPED, ODOMETRY), "current": PAIR_TYPES}
COMMANDS = {"duty": PAIR_TYPES, "voltage": PAIR_TYPES, "effort": PAIR_TYPES}
MAP_KEYS = {"format", "wheel_positions", "commands", "odometry", "pose", "current", "robot",
            "motor", "encoder_ppr", "periods_s", "meta", "time_zero_ns"}


class ImportError_(Exception):
    """Bad input (exit 2): the message names the file, topic and message index."""


def _norm_type(t: str) -> str:
    """ROS 1 type names (sensor_msgs/JointState) in the ROS 2 form (sensor_msgs/msg/JointState)."""
    parts = t.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else t


def load_map(path: str) -> dict:
    import yaml
    text = _cli.read_text(path, ImportError_)
    try:
        m = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise ImportError_(f"{runfmt.display(path)}: {where}not YAML/JSON: "
                           f"{getattr(exc, 'problem', None) or exc}") from None
    if not isinstance(m, dict):
        raise ImportError_(f"{runfmt.display(path)}: the map is not a mapping of keys")
    unknown = sorted(set(m) - MAP_KEYS)
    if unknown:
        raise ImportError_(f"{runfmt.display(path)}: unknown key(s) {', '.join(unknown)}; "
                           f"known: {', '.join(sorted(MAP_KEYS))}")
    if m.get("format", MAP_FORMAT) != MAP_FORMAT:
        raise ImportError_(f"{runfmt.display(path)}: format must be {MAP_FORMAT}")
    for key in ("wheel_positions", "commands", "odometry"):
        if not isinstance(m.get(key), dict):
            raise ImportError_(f"{runfmt.display(path)}: '{key}' is required (a mapping)")
    cmds = m["commands"]
    unknown = sorted(set(cmds) - set(COMMANDS))
    if unknown:
        raise ImportError_(f"{runfmt.display(path)}: commands: unknown kind(s) "
                           f"{', '.join(unknown)}; known: duty, voltage, effort")
    if ("duty" in cmds) == ("voltage" in cmds):
        raise ImportError_(f"{runfmt.display(path)}: commands needs exactly one of duty and "
                           "voltage (the applied duty the analyzer replays)")
    for sec in [m["wheel_positions"], m["odometry"], *cmds.values()] + \
               [m[k] for k in ("pose", "current") if m.get(k) is not None]:
        if not isinstance(sec, dict) or not isinstance(sec.get("topic"), str):
            raise ImportError_(f"{runfmt.display(path)}: every source needs a 'topic'")
    return m


class _Bag:
    """The messages of the mapped topics: (time_s, message) lists per topic, in bag order."""

    def __init__(self, bag: str, topics: set[str]):
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
        self.path = bag
        self.types: dict[str, str] = {}
        self.msgs: dict[str, list] = {t: [] for t in topics}
        if not os.path.exists(bag):
            raise ImportError_(f"{runfmt.display(bag)}: does not exist (a ROS 1 .bag file, or a "
                               "ROS 2 bag folder or its .mcap file)")
        try:
            reader = AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            reader.open()
        except Exception as exc:  # rosbags raises its own errors for unreadable bags
            hint = ""
            if os.path.isfile(bag) and not bag.endswith(".bag"):
                with open(bag, "rb") as fh:
                    if fh.read(13) == b"#ROSBAG V2.0\n":
                        hint = " (a ROS 1 bag: its name must end in .bag)"
            raise ImportError_(f"{runfmt.display(bag)}: not a readable ROS 1 or ROS 2 bag: "
                               f"{exc}{hint}") from None
        try:
            conns = [c for c in reader.connections if c.topic in topics]
            for c in conns:
                self.types[c.topic] = _norm_type(c.msgtype)
            for c, t_ns, raw in reader.messages(connections=conns):
                try:
                    msg = reader.deserialize(raw, c.msgtype)
                except Exception as exc:  # a type rosbags cannot decode, a truncated message
                    raise ImportError_(f"{runfmt.display(bag)}: topic {c.topic}, message "
                                       f"{len(self.msgs[c.topic])}: cannot decode "
                                       f"{c.msgtype}: {exc}") from None
                self.msgs[c.topic].append((t_ns, msg))
        finally:
            reader.close()

    def need(self, topic: str, accepted: tuple[str, ...], role: str) -> list:
        if topic not in self.types:
            raise ImportError_(f"{runfmt.display(self.path)}: topic {topic} ({role}) is not in "
                               "the bag")
        if self.types[topic] not in accepted:
            raise ImportError_(f"{runfmt.display(self.path)}: topic {topic} ({role}) has type "
                               f"{self.types[topic]}; accepted: {', '.join(accepted)}")
        if not self.msgs[topic]:
            raise ImportError_(f"{runfmt.display(self.path)}: topic {topic} ({role}) has no "
                               "messages")
        return self.msgs[topic]


def _stamp(msg: Any, recv_ns: int) -> int:
    h = getattr(msg, "header", None)
    if h is not None:
        return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    return int(recv_ns)


def _show_ns(t_ns: int) -> str:
    t_ns = int(t_ns)
    return f"{'-' if t_ns < 0 else ''}{abs(t_ns) // 10**9}.{abs(t_ns) % 10**9:09d}"


def _times(bag: _Bag, topic: str, msgs: list) -> np.ndarray:
    t = np.array([_stamp(m, r) for r, m in msgs], dtype=np.int64)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ImportError_(f"{runfmt.display(bag.path)}: topic {topic}, message {i}: stamp "
                           f"{_show_ns(t[i])} s does not increase (previous "
                           f"{_show_ns(t[i - 1])} s)")
    return t


def _pair(bag: _Bag, topic: str, msgs: list, spec: Mapping, role: str,
          default_field: str) -> tuple[np.ndarray, np.ndarray]:
    """Right and left values of a JointState (joint names, ``field``) or a MultiArray
    (indices)."""
    kind = bag.types[topic]
    right, left = spec.get("right"), spec.get("left")
    field = spec.get("field", default_field)
    if right is None or left is None:
        raise ImportError_(f"map: {role} ({topic}) needs 'right' and 'left'")
    out = np.empty((len(msgs), 2))
    for i, (_, m) in enumerate(msgs):
        if kind == JOINT_STATE:
            names = list(m.name)
            vals = np.asarray(getattr(m, field, None) if field in ("position", "velocity",
                                                                   "effort") else None)
            if vals is None or vals.ndim == 0:
                raise ImportError_(f"map: {role} ({topic}): field must be position, velocity "
                                   "or effort")
            for j, jn in enumerate((right, left)):
                if jn not in names:
                    raise ImportError_(f"{runfmt.display(bag.path)}: topic {topic}, message {i}: "
                                       f"no joint named {jn} ({role}); joints: "
                                       f"{', '.join(names) or 'none'}")
                k = names.index(jn)
                if k >= vals.size:
                    raise ImportError_(f"{runfmt.display(bag.path)}: topic {topic}, message {i}: "
                                       f"joint {jn} has no {field} ({role})")
                out[i, j] = float(vals[k])
        else:
            data = np.asarray(m.data, dtype=float)
            for j, idx in enumerate((right, left)):
                if not isinstance(idx, int) or not 0 <= idx < data.size:
                    raise ImportError_(f"{runfmt.display(bag.path)}: topic {topic}, message {i}: "
                                       f"index {idx} is outside data[0:{data.size}] ({role})")
                out[i, j] = data[idx]
        bad = ~np.isfinite(out[i])
        if bad.any():
            raise ImportError_(f"{runfmt.display(bag.path)}: topic {topic}, message {i}: "
                               f"{('right', 'left')[int(np.flatnonzero(bad)[0])]} value is not a "
                               f"finite number ({role})")
    return out[:, 0], out[:, 1]


def _yaw(q) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def _pose_of(m: Any) -> tuple[float, float, float]:
    p = m.pose.pose if hasattr(m.pose, "pose") else m.pose  # Odometry: pose.pose
    return float(p.position.x), float(p.position.y), _yaw(p.orientation)


def _poses(bag: _Bag, topic: str, msgs: list, role: str) -> np.ndarray:
    """(x, y, heading) of each Odometry / PoseStamped message; bad input at the first one
    that is not finite."""
    xyz = np.array([_pose_of(mm) for _, mm in msgs], dtype=float).reshape(-1, 3)
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if bad.size:
        raise ImportError_(f"{runfmt.display(bag.path)}: topic {topic}, message {int(bad[0])}: "
                           f"the pose is not finite ({role})")
    return xyz


def _hold(t_src: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The last value at or before each of ``t`` (the first value before the first one)."""
    i = np.searchsorted(t_src, t, side="right") - 1
    return v[np.clip(i, 0, v.size - 1)]


def import_bag(bag_path: str, map_path: str, out: str) -> dict:
    """Read the bag, resample onto the wheel-position frames, write the run folder ``out``.
    Returns a summary (rows, ground-truth rows, time span)."""
    m = load_map(map_path)
    cmds = m["commands"]
    sources = {"wheel_positions": m["wheel_positions"], "odometry": m["odometry"],
               **{f"commands.{k}": v for k, v in cmds.items()},
               **{k: m[k] for k in ("pose", "current") if m.get(k) is not None}}
    if os.path.exists(os.path.join(out, "telemetry.csv")):
        raise ImportError_(f"--out {runfmt.display(out)} holds a recorded run; refusing to "
                           "overwrite it")
    bag = _Bag(bag_path, {s["topic"] for s in sources.values()})
    log.info("read %s: %s", runfmt.display(bag_path),
             ", ".join(f"{t} {len(v)} messages" for t, v in sorted(bag.msgs.items())))
    meta = {"format": runfmt.FORMAT, "source": "rosbag",
            "experiment": f"imported from the ROS bag {os.path.basename(os.path.normpath(bag_path))}"}
    for k in ("robot", "motor", "periods_s"):
        if m.get(k) is not None:
            meta[k] = dict(m[k])
    if m.get("encoder_ppr") is not None:
        meta["encoder_ppr"] = m["encoder_ppr"]
    for k, v in (m.get("meta") or {}).items():
        meta.setdefault(k, v)
    defaults = runfmt.validate_meta(dict(meta), map_path)  # the defaults filled in, checked
    ppr = int(defaults["encoder_ppr"])

    wp = sources["wheel_positions"]
    msgs = bag.need(wp["topic"], ROLES["wheel_positions"], "wheel_positions")
    t_ns = _times(bag, wp["topic"], msgs)
    t0 = m.get("time_zero_ns", int(t_ns[0]))
    if not isinstance(t0, int) or isinstance(t0, bool) or t0 > int(t_ns[0]):
        raise ImportError_(f"{runfmt.display(map_path)}: time_zero_ns must be an integer stamp "
                           f"in ns at or before the first wheel-position stamp {int(t_ns[0])}")
    t = (t_ns - t0) / 1e9
    th_r, th_l = _pair(bag, wp["topic"], msgs, wp, "wheel_positions", "position")
    has_vel = all(len(mm.velocity) == len(mm.name) for _, mm in msgs)
    if has_vel:
        w_r, w_l = _pair(bag, wp["topic"], msgs, {**wp, "field": "velocity"}, "wheel_positions",
                         "velocity")
    else:
        w_r, w_l = np.gradient(th_r, t), np.gradient(th_l, t)
    if "telemetry" not in (meta.get("periods_s") or {}) and t.size > 1:
        # the frames' own spacing, not the default of this project's firmware
        meta.setdefault("periods_s", {})["telemetry"] = round(float(np.median(np.diff(t))), 9)
    tel: dict[str, np.ndarray] = {
        "t_s": np.round(t, 9),
        "enc_r": np.round(th_r * ppr / (2 * math.pi)).astype(np.int64),
        "enc_l": np.round(th_l * ppr / (2 * math.pi)).astype(np.int64),
        "omega_r": w_r, "omega_l": w_l}

    def source_on_frames(key: str, accepted, default_field: str, hold: bool):
        spec = sources[key]
        ms = bag.need(spec["topic"], accepted, key)
        ts = (_times(bag, spec["topic"], ms) - t0) / 1e9
        r, l_ = _pair(bag, spec["topic"], ms, spec, key, default_field)
        f = _hold if hold else (lambda a, v, b: np.interp(b, a, v))
        return f(ts, r, t), f(ts, l_, t)

    notes = []
    if "duty" in cmds:
        tel["pwm_r"], tel["pwm_l"] = source_on_frames("commands.duty", COMMANDS["duty"],
                                                      "effort", True)
    else:
        v_r, v_l = source_on_frames("commands.voltage", COMMANDS["voltage"], "effort", True)
        sv = float(defaults["motor"]["supply_v"])
        tel["pwm_r"], tel["pwm_l"] = v_r / sv, v_l / sv
    if "effort" in cmds:
        tel["tau_cmd_r"], tel["tau_cmd_l"] = source_on_frames("commands.effort",
                                                              COMMANDS["effort"], "effort", True)
    else:
        tel["tau_cmd_r"] = tel["tau_cmd_l"] = np.zeros(t.size)
        notes.append("no effort command in the bag: tau_cmd_r/tau_cmd_l are 0 (the analyzer's "
                     "torque replay is meaningless for this run)")
    od = sources["odometry"]
    ms = bag.need(od["topic"], ROLES["odometry"], "odometry")
    ts = (_times(bag, od["topic"], ms) - t0) / 1e9
    xyz = _poses(bag, od["topic"], ms, "odometry")
    tel["x_odo_m"] = np.interp(t, ts, xyz[:, 0])
    tel["y_odo_m"] = np.interp(t, ts, xyz[:, 1])
    tel["phi_odo_rad"] = np.interp(t, ts, np.unwrap(xyz[:, 2]))
    if "current" in sources:
        tel["current_r_a"], tel["current_l_a"] = source_on_frames("current", ROLES["current"],
                                                                  "effort", False)
    gt = None
    if "pose" in sources:
        ps = sources["pose"]
        ms = bag.need(ps["topic"], ROLES["pose"], "pose")
        tg = (_times(bag, ps["topic"], ms) - t0) / 1e9
        g = _poses(bag, ps["topic"], ms, "pose")
        gt = {"t_s": np.round(tg, 9), "x_m": g[:, 0], "y_m": g[:, 1], "phi_rad": np.unwrap(g[:, 2])}
    meta["import"] = {"bag": os.path.abspath(bag_path), "map": os.path.abspath(map_path),
                      "t0_unix_s": t0 / 1e9, "frames_topic": wp["topic"],
                      "omega": "JointState velocity" if has_vel else "difference of positions",
                      "notes": notes}
    for n in notes:
        log.warning("%s", n)
    runfmt.write_run(out, meta, tel, gt)
    return {"rows": int(t.size), "groundtruth_rows": 0 if gt is None else int(gt["t_s"].size),
            "duration_s": float(t[-1]) if t.size else 0.0}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n")[0].split(": ", 1)[1].replace("``", "")
    p.epilog = ("The map's keys and an example: docs/rosbag-import.md. exit status: 0 done, "
                "2 bad input (the bag's topic and message index, or the map's problem).")
    p.add_argument("bag", metavar="BAG", help="ROS 1 .bag file, or ROS 2 bag folder (sqlite3 or "
                   "MCAP storage) or its .mcap file")
    p.add_argument("--map", required=True, metavar="MAP", help="mapping file (YAML or JSON): "
                   "topics and fields of wheel positions, commands, odometry, pose, current; "
                   "the robot's parameters")
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run folder to write "
                   "(must not hold a run)")


def main(args: argparse.Namespace) -> int:
    def action() -> str:
        s = import_bag(args.bag, args.map, args.out)
        return (f"{runfmt.display(args.out)}: {s['rows']} telemetry rows over "
                f"{s['duration_s']:.3f} s, {s['groundtruth_rows']} ground-truth rows")
    return _cli.run(action, (ImportError_, runfmt.RunFormatError), args.out)
