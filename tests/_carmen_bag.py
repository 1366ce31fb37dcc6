"""A CARMEN log written as a ROS bag by rosbags' own writer (not scanreg's), as a robot would
have recorded it: ``/scan`` (sensor_msgs/LaserScan, frame ``laser``) from the laser lines,
``/odom`` (nav_msgs/Odometry odom → base_link) from the ``ODOM`` lines, each at its own stamp,
and ``/tf_static`` (base_link → laser: the mounting given). Used by tests and benchmarks."""

from __future__ import annotations

import math
from decimal import Decimal
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scanreg.io import CarmenLog


def _ns(seconds: float) -> int:
    """Nanoseconds of a logged decimal time, exactly (a recorder stores integers)."""
    return round(Decimal(repr(seconds)) * 10**9)


def _time(ts: Any, seconds: float) -> Any:
    ns = _ns(seconds)
    return ts.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def _header(ts: Any, ros1: bool, seconds: float, frame: str) -> Any:
    extra = {"seq": 0} if ros1 else {}
    return ts.types["std_msgs/msg/Header"](stamp=_time(ts, seconds), frame_id=frame, **extra)


def _quaternion(ts: Any, yaw: float) -> Any:
    return ts.types["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
    )


def _odometry(ts: Any, ros1: bool, seconds: float, pose: Any) -> Any:
    t = ts.types
    x, y, yaw = (float(v) for v in pose)
    vec3 = t["geometry_msgs/msg/Vector3"]
    return t["nav_msgs/msg/Odometry"](
        header=_header(ts, ros1, seconds, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=_quaternion(ts, yaw),
            ),
            covariance=np.zeros(36),
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=vec3(x=0, y=0, z=0), angular=vec3(x=0, y=0, z=0)
            ),
            covariance=np.zeros(36),
        ),
    )


def _odometry_lines(log: CarmenLog, scans: tuple[Any, ...]) -> list[tuple[int, float, Any]]:
    """``(file line, stamp, [x, y, θ])`` of the odometry a recorder would have received
    while ``scans`` were: the ``ODOM`` messages between the first and the last scan's lines
    and the one on either side (so that every scan has odometry around it); a log without
    ``ODOM`` lines (the hospital's ``ROBOTLASER1``: the odometry inside each laser line) gives
    each scan's own odometry fields at its stamp."""
    odom = log.odometry
    if len(odom) == 0:
        return [
            (s.line, s.timestamp, s.odometry_pose) for s in scans if s.odometry_pose is not None
        ]
    if len(odom.lines) != len(odom):
        raise ValueError("log: its ODOM messages carry no line numbers (read it with read_scans)")
    lines = np.asarray(odom.lines)
    lo = max(int(np.searchsorted(lines, scans[0].line)) - 1, 0)
    hi = min(int(np.searchsorted(lines, scans[-1].line)) + 1, len(lines))
    return [(int(lines[k]), float(odom.timestamps[k]), odom.poses[k]) for k in range(lo, hi)]


def write_carmen_bag(
    log: CarmenLog,
    path: Path,
    *,
    kind: str = "mcap",
    laser: str = "FLASER",
    mounting: tuple[float, float, float] = (0.0, 0.0, 0.0),
    max_scans: int | None = None,
    first: int = 0,
    odometry: bool = True,
    tf_static: bool = True,
) -> Path:
    """Write the ``laser`` lines of ``log`` (``max_scans`` from the ``first``) as a bag of ``kind``
    (``"ros1"``, ``"sqlite3"`` or ``"mcap"``): each laser line a LaserScan and each ``ODOM`` line
    an Odometry message (:func:`_odometry_lines`; none when ``odometry`` is false), stamped
    with the line's own timestamp and received at the line's place in the file (the bag's
    order is the file's, whatever the stamps say)."""
    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    if "tf2_msgs/msg/TFMessage" not in ts.types:  # rosbags' Noetic store has no tf2_msgs
        text = "geometry_msgs/TransformStamped[] transforms"
        ts.register(get_types_from_msg(text, "tf2_msgs/msg/TFMessage"))
    scans = log.laser(laser)[first:][:max_scans]
    t = ts.types
    vec3 = t["geometry_msgs/msg/Vector3"]
    static = t["tf2_msgs/msg/TFMessage"](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=_header(ts, ros1, scans[0].timestamp, "base_link"),
                child_frame_id="laser",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=vec3(x=mounting[0], y=mounting[1], z=0.3),
                    rotation=_quaternion(ts, mounting[2]),
                ),
            )
        ]
    )
    events: list[tuple[int, str, float, Any]] = [(s.line, "/scan", s.timestamp, s) for s in scans]
    if odometry:
        events += [(line, "/odom", when, pose) for line, when, pose in _odometry_lines(log, scans)]
    events.sort(key=lambda e: (e[0], e[1]))  # file order (a laser line's own fields: odom first)
    messages: list[tuple[str, int, Any]] = []
    received = 0
    for _, topic, when, item in events:
        # receive times follow the file, a microsecond apart at least
        received = max(_ns(when), received + 1000)
        if topic == "/odom":
            messages.append((topic, received, _odometry(ts, ros1, when, item)))
            continue
        s = item
        n = len(s.ranges)
        step = float(s.angles[1] - s.angles[0]) if n > 1 else 0.0
        messages.append(
            (
                "/scan",
                received,
                t["sensor_msgs/msg/LaserScan"](
                    header=_header(ts, ros1, s.timestamp, "laser"),
                    angle_min=float(s.angles[0]),
                    angle_max=float(s.angles[-1]),
                    angle_increment=step,
                    time_increment=0.0,
                    scan_time=0.0,
                    range_min=0.0,
                    range_max=float(s.max_range),
                    ranges=np.asarray(s.ranges, dtype=np.float32),
                    intensities=np.zeros(0, np.float32),
                ),
            )
        )
    types = {
        "/scan": "sensor_msgs/msg/LaserScan",
        "/odom": "nav_msgs/msg/Odometry",
        "/tf_static": "tf2_msgs/msg/TFMessage",
    }
    if tf_static:
        messages.insert(0, ("/tf_static", messages[0][1], static))
    return write_messages(path, kind, ts, [(types[k], k, when, m) for k, when, m in messages])


def write_messages(
    path: Path, kind: str, ts: Any, messages: list[tuple[str, str, int, Any]]
) -> Path:
    """Write ``(msgtype, topic, receive_time_ns, message)`` in this order as a bag of ``kind``
    (``"ros1"``: ``path.bag``; ``"sqlite3"`` / ``"mcap"``: the bag folder ``path``)."""
    types = {topic: msgtype for msgtype, topic, _, _ in messages}
    if kind == "ros1":
        path = path.with_suffix(".bag")
        with Writer1(path) as w1:
            conns1 = {k: w1.add_connection(k, m, typestore=ts) for k, m in types.items()}
            for msgtype, topic, when, msg in messages:
                w1.write(conns1[topic], when, ts.serialize_ros1(msg, msgtype))
        return path
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    with Writer2(path, version=9, storage_plugin=plugin) as w2:
        conns2 = {k: w2.add_connection(k, m, typestore=ts) for k, m in types.items()}
        for msgtype, topic, when, msg in messages:
            w2.write(conns2[topic], when, ts.serialize_cdr(msg, msgtype))
    return path
