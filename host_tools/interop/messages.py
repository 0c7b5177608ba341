"""Run data as Foxglove messages: the one table of the topics this project publishes
(MCAP export and live view) and the conversions of rows and poses into messages.

Poses and transforms use Foxglove's well-known schemas (``foxglove.PoseInFrame``,
``foxglove.FrameTransform``, protobuf encoded); their schema definitions come from the
``foxglove-sdk`` package.  Telemetry rows and the analyzer's findings are JSON messages with a
JSON schema derived from the columns.  Times: a message's log time is the run's board time
``t_s`` in nanoseconds (the run starts near 0; Foxglove shows it as seconds after 1970-01-01),
and each message's ``timestamp`` field carries the same time.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Mapping

WORLD = "world"
BASE_GT = "base_link"          # the robot's axle centre as the external measurement sees it
BASE_ODO = "base_link_odom"    # the same point as the robot's own odometry estimates it


@dataclass(frozen=True)
class Topic:
    name: str
    schema: str          # schema name: foxglove.* (protobuf) or ddrobot.* (JSON)
    what: str


TOPICS = {t.name: t for t in (
    Topic("/telemetry", "ddrobot.Telemetry", "every telemetry.csv column, one message per frame"),
    Topic("/odometry/pose", "foxglove.PoseInFrame", "odometry pose of the axle centre (x_odo_m, "
          "y_odo_m, phi_odo_rad) in the world frame, one per frame"),
    Topic("/odometry/tf", "foxglove.FrameTransform", f"{WORLD} -> {BASE_ODO} from the odometry, "
          "one per frame"),
    Topic("/groundtruth/pose", "foxglove.PoseInFrame", "ground-truth pose (groundtruth.csv) in "
          "the world frame, one per row; a row without phi_rad has the identity orientation"),
    Topic("/groundtruth/tf", "foxglove.FrameTransform", f"{WORLD} -> {BASE_GT} from the ground "
          "truth, one per row"),
    Topic("/analysis/summary", "ddrobot.AnalysisSummary", "report.json's verdict, selected "
          "effects (value and 1-sigma), fit errors; one message at the first frame"),
    Topic("/analysis/mismatch", "ddrobot.MismatchWindow", "one message per mismatch window of "
          "this run (report.json 'mismatch'), at the window's start"),
    Topic("/analysis/mismatch_active", "ddrobot.MismatchActive", "per frame: 1 for each channel "
          "inside one of its mismatch windows, else 0 (a step plot on the timeline)"),
    Topic("/analysis/localization", "ddrobot.MismatchSpan", "one message per merged mismatch "
          "span of this run (report.json 'localization'), at its start"),
)}

# The analyzer's per-sample series (series/<run>.csv of a report folder): one topic per channel,
# SERIES_PREFIX + the channel's name (e.g. /analysis/series/omega_r), so not in TOPICS.
SERIES_PREFIX = "/analysis/series/"
SERIES = Topic(SERIES_PREFIX + "<channel>", "ddrobot.SeriesSample", "per sample of one channel "
               "(the report's series/<run>.csv): recording, nominal and updated replay, their "
               "residuals, the noise band, the replay window and whether the sample is in a "
               "mismatch window")


def topic_info(name: str) -> Topic:
    """The :class:`Topic` of a topic name (a series topic's is :data:`SERIES`)."""
    if name in TOPICS:
        return TOPICS[name]
    if name.startswith(SERIES_PREFIX) and len(name) > len(SERIES_PREFIX):
        return SERIES
    raise KeyError(name)


LIVE_TOPICS = ("/telemetry", "/odometry/pose", "/odometry/tf")


def ns(t_s: float) -> int:
    return int(round(float(t_s) * 1e9))


def _timestamp(t_s: float):
    from foxglove.messages import Timestamp
    n = ns(t_s)
    return Timestamp(sec=n // 1_000_000_000, nsec=n % 1_000_000_000)


def _yaw(phi_rad: float):
    from foxglove.messages import Quaternion
    if not math.isfinite(phi_rad):
        return Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    return Quaternion(x=0.0, y=0.0, z=math.sin(phi_rad / 2), w=math.cos(phi_rad / 2))


def pose_in_frame(t_s: float, x_m: float, y_m: float, phi_rad: float) -> bytes:
    from foxglove.messages import Pose, PoseInFrame, Vector3
    return PoseInFrame(timestamp=_timestamp(t_s), frame_id=WORLD,
                       pose=Pose(position=Vector3(x=float(x_m), y=float(y_m), z=0.0),
                                 orientation=_yaw(float(phi_rad)))).encode()


def frame_transform(t_s: float, child: str, x_m: float, y_m: float, phi_rad: float) -> bytes:
    from foxglove.messages import FrameTransform, Vector3
    return FrameTransform(timestamp=_timestamp(t_s), parent_frame_id=WORLD, child_frame_id=child,
                          translation=Vector3(x=float(x_m), y=float(y_m), z=0.0),
                          rotation=_yaw(float(phi_rad))).encode()


def well_known_schema(name: str) -> tuple[str, str, bytes]:
    """(name, encoding, data) of a foxglove.* schema, from foxglove-sdk."""
    from foxglove import messages
    s = getattr(messages, name.split(".", 1)[1]).get_schema()
    return s.name, s.encoding, bytes(s.data)


def json_schema(name: str, fields: Mapping[str, str]) -> tuple[str, str, bytes]:
    """A JSON schema of an object with these fields (field -> JSON type)."""
    props = {k: {"type": v} if v != "number" else {"type": ["number", "null"]}
             for k, v in fields.items()}
    doc = {"title": name, "type": "object", "properties": props}
    return name, "jsonschema", json.dumps(doc).encode()


def schema_for(topic: str, fields: Mapping[str, str] | None = None) -> tuple[str, str, bytes]:
    """(name, encoding, data) of a topic's schema; JSON topics need their ``fields``."""
    name = topic_info(topic).schema
    if name.startswith("foxglove."):
        return well_known_schema(name)
    return json_schema(name, fields or {})


def message_encoding(schema_encoding: str) -> str:
    return "protobuf" if schema_encoding == "protobuf" else "json"


def _plain(v: Any) -> Any:
    """A value as JSON: numpy scalars as numbers, NaN/inf as null."""
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def json_message(obj: Mapping[str, Any]) -> bytes:
    return json.dumps(_plain(dict(obj)), allow_nan=False).encode()


def row_fields(row: Mapping[str, Any]) -> dict[str, str]:
    """JSON types of a telemetry row's columns (numbers, or strings for text columns)."""
    return {k: ("string" if isinstance(v, str) else "number") for k, v in row.items()}
