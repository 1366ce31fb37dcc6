"""A ROS 1 or ROS 2 bag holding ``sensor_msgs/LaserScan`` as a :class:`~scanreg.io.ScanLog`.

What is read, besides the scans (:func:`~scanreg.io.rosbag.iter_bag_scans`):

* **the laser's mounting** ``T_base_laser``: the chain of transforms from the base frame to
  the scans' ``frame_id`` on ``/tf_static`` (or, when a static transform is republished there,
  on ``/tf``; its first value), projected onto the plane. A laser mounted upside down (its z
  axis pointing down) is mirrored; one tilted by more than 10° is refused. ``laser_pose``
  overrides whatever the bag says.
* **the wheel odometry** ``T_odom_base`` at each scan's stamp, interpolated (linearly, the
  heading along the shorter arc) between the two messages around it, from a
  ``nav_msgs/Odometry`` topic or, without one, from the ``/tf`` transforms odom → base.
  A scan between two messages more than 1 s apart, or outside them, gets none. No odometry
  at all is fine: the pipelines then predict each scan by constant velocity. The messages
  themselves are kept as :attr:`~scanreg.io.ScanLog.odometry_stream` (stamps and receive
  times): the pipelines pair them with the scans as they do a CARMEN log's
  (:func:`scanreg.pipeline.odometry_timing.settle_odometry`: each scan's last odometry when
  the two arrive together, else the stream at each stamp less the laser's latency).
* **the base frame**: the Odometry messages' ``child_frame_id``, else the child of the
  ``odom`` frame on ``/tf``, else ``base_link`` / ``base_footprint`` when the tf tree links it
  to the laser, else the laser's own frame (identity mounting).

Each scan keeps its header stamp (the bag's receive time when every header stamp is zero).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..transform import SE2
from ._common import FileFormatError, PathLike
from .rosbag import (
    LASER_SCAN,
    _check_path,
    _deserialised,
    _is_ros1,
    _Ros1Bag,
    _ros2_connections,
    _stamp,
    iter_bag_scans,
)
from .scan_log import OdometryStream, ScanLog, laser_pose_argument

ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: Frames taken as the robot's base when nothing else names it, in this order.
BASE_FRAMES = ("base_link", "base_footprint")
#: Odometry is interpolated only between messages less than this apart (s).
MAX_ODOMETRY_GAP = 1.0
#: A laser tilted more than this off the vertical is refused (its scan is not planar).
MAX_TILT = math.radians(10.0)


def _frame(name: str) -> str:
    return name.lstrip("/")


def bag_topics(path: PathLike) -> set[tuple[str, str]]:
    """The bag's ``(topic, msgtype)`` pairs, read from its index (no message is read)."""
    p = _check_path(path)
    if _is_ros1(p):
        return {(c.topic, c.msgtype) for c in _Ros1Bag(p)._all_connections()}
    return {(c.topic, c.msgtype) for c, _ in _ros2_connections(p)}


def is_laserscan_bag(path: PathLike) -> bool:
    """Whether ``path`` is a bag with a LaserScan topic and no PointCloud2 topic."""
    types = {m for _, m in bag_topics(path)}
    return LASER_SCAN in types and "sensor_msgs/msg/PointCloud2" not in types


def _pick_topic(
    path: Path, topics: set[tuple[str, str]], topic: str | None, msgtype: str, argument: str
) -> str | None:
    """The ``msgtype`` topic to read (None when the bag has none and none was asked for)."""
    name = msgtype.replace("/msg/", "/")
    if topic is not None:
        if not isinstance(topic, str):
            raise TypeError(f"{argument}: expected a str, got {type(topic).__name__}")
        types = {m for t, m in topics if t == topic}
        if not types:
            known = ", ".join(sorted({t for t, _ in topics})) or "none"
            raise ValueError(f"{argument}: {path} has no topic {topic!r} (topics: {known})")
        if msgtype not in types:
            raise ValueError(f"{argument}: {topic!r} in {path} is {sorted(types)[0]}, not {name}")
        return topic
    matching = sorted({t for t, m in topics if m == msgtype})
    if len(matching) > 1:
        option = "--" + argument.replace("_", "-")
        raise ValueError(
            f"{argument}: {path} has several {name} topics ({', '.join(matching)}); "
            f"choose one ({option})"
        )
    return matching[0] if matching else None


# --------------------------------------------------------------------------- transforms


@dataclass(frozen=True)
class _Transform:
    stamp: float
    parent: str
    child: str
    matrix: FloatArray  # 4x4, T_parent_child
    received: float = 0.0  # the bag's receive time (s)


def _quaternion_matrix(x: float, y: float, z: float, w: float) -> FloatArray:
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        raise ValueError("rotation: zero quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _pose_matrix(position: Any, orientation: Any) -> FloatArray:
    m = np.eye(4)
    m[:3, :3] = _quaternion_matrix(
        float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w)
    )
    m[:3, 3] = [float(position.x), float(position.y), float(position.z)]
    return m


def _planar(m: FloatArray) -> SE2:
    """The planar part of a 4x4 pose: translation x, y and the heading of its x axis."""
    return SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])


def _read_tf(path: Path, topics: set[tuple[str, str]], topic: str) -> list[_Transform]:
    if (topic, TF_MESSAGE) not in topics:
        return []
    out = []
    for _, received, msg, index in _deserialised(path, topic, TF_MESSAGE):
        for t in msg.transforms:
            try:
                matrix = _pose_matrix(t.transform.translation, t.transform.rotation)
            except ValueError as exc:
                raise FileFormatError(path, f"{topic} message {index}: {exc}") from None
            if not np.isfinite(matrix).all():
                raise FileFormatError(path, f"{topic} message {index}: non-finite transform")
            parent, child = _frame(str(t.header.frame_id)), _frame(t.child_frame_id)
            out.append(_Transform(_stamp(t), parent, child, matrix, received * 1e-9))
    return out


def _chain(transforms: Iterable[_Transform], start: str, goal: str) -> FloatArray | None:
    """``T_start_goal`` through the tree of (first-seen) transforms, or None if unlinked."""
    edges: dict[str, list[tuple[str, FloatArray]]] = {}
    seen: set[tuple[str, str]] = set()
    for t in transforms:
        if (t.parent, t.child) in seen:
            continue
        seen.add((t.parent, t.child))
        edges.setdefault(t.parent, []).append((t.child, t.matrix))
        inverse = np.asarray(np.linalg.inv(t.matrix), dtype=np.float64)
        edges.setdefault(t.child, []).append((t.parent, inverse))
    reached: dict[str, FloatArray] = {start: np.eye(4)}
    queue = [start]
    while queue:
        frame = queue.pop(0)
        for nxt, m in edges.get(frame, []):
            if nxt not in reached:
                reached[nxt] = reached[frame] @ m
                queue.append(nxt)
    return reached.get(goal)


def _mounting(path: Path, transforms: list[_Transform], base: str, laser: str) -> tuple[SE2, bool]:
    """``T_base_laser`` projected onto the plane, and whether the laser is upside down."""
    if base == laser:
        return SE2.identity(), False
    m = _chain(transforms, base, laser)
    if m is None:
        raise ValueError(
            f"laser_pose: {path} has no transform from {base!r} to the scans' frame {laser!r} "
            "on /tf_static or /tf; give the laser's mounting (--laser-pose x y θ)"
        )
    z = m[:3, 2]  # the laser's z axis in the base frame
    tilt = math.acos(min(abs(float(z[2])), 1.0))
    if tilt > MAX_TILT:
        raise ValueError(
            f"laser_pose: the laser frame {laser!r} is tilted {math.degrees(tilt):.1f}° off the "
            f"vertical of {base!r}: its scans are not in the base's plane"
        )
    return _planar(m), bool(z[2] < 0)


# --------------------------------------------------------------------------- odometry


def _read_odometry(path: Path, topic: str) -> tuple[OdometryStream, str, str]:
    """The messages of a nav_msgs/Odometry topic, its ``frame_id`` and ``child_frame_id``."""
    stamps, rows, received = [], [], []
    parent = child = ""
    for _, when, msg, index in _deserialised(path, topic, ODOMETRY):
        try:
            m = _pose_matrix(msg.pose.pose.position, msg.pose.pose.orientation)
        except ValueError as exc:
            raise FileFormatError(path, f"{topic} message {index}: {exc}") from None
        if not np.isfinite(m).all():
            raise FileFormatError(path, f"{topic} message {index}: non-finite pose")
        stamps.append(_stamp(msg))
        rows.append(_planar(m).as_vector())
        received.append(when * 1e-9)
        parent, child = parent or _frame(msg.header.frame_id), child or _frame(msg.child_frame_id)
    stream = OdometryStream(np.array(stamps), np.array(rows).reshape(-1, 3), np.array(received))
    return stream, parent, child


def interpolate_poses(
    stamps: FloatArray, poses: FloatArray, at: FloatArray, max_gap: float = MAX_ODOMETRY_GAP
) -> list[SE2 | None]:
    """``[x, y, θ]`` poses timed ``stamps`` at the times ``at``: linear in position, the
    heading along the shorter arc, between the two poses around each time when they are at
    most ``max_gap`` apart (a time equal to a pose's stamp takes that pose); None elsewhere."""
    order = np.argsort(stamps, kind="stable")
    t, p = np.asarray(stamps)[order], np.asarray(poses)[order]
    out: list[SE2 | None] = []
    for s in np.asarray(at, dtype=np.float64):
        hi = int(np.searchsorted(t, s, side="left"))
        if hi < len(t) and t[hi] == s:
            out.append(SE2.from_vector(p[hi]))
            continue
        lo = hi - 1
        if lo < 0 or hi >= len(t) or not t[hi] - t[lo] <= max_gap:
            out.append(None)
            continue
        a = (s - t[lo]) / (t[hi] - t[lo])
        turn = math.atan2(math.sin(p[hi, 2] - p[lo, 2]), math.cos(p[hi, 2] - p[lo, 2]))
        xy = p[lo, :2] + a * (p[hi, :2] - p[lo, :2])
        out.append(SE2.from_vector([xy[0], xy[1], p[lo, 2] + a * turn]))
    return out


# --------------------------------------------------------------------------- public


def read_laserscan_bag(
    path: PathLike,
    *,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    laser_pose: Any = None,
    max_scans: int | None = None,
) -> ScanLog:
    """Read a bag's ``sensor_msgs/LaserScan`` run (see the module docstring).

    Parameters
    ----------
    scan_topic, odom_topic : str, optional
        Needed when the bag has several LaserScan / Odometry topics (the error names them).
    laser_pose : [x, y, θ] or SE2, optional
        ``T_base_laser``, instead of the bag's tf.
    max_scans : int, optional
        Read only the first ``max_scans`` scans.
    """
    p = _check_path(path)
    topics = bag_topics(p)
    chosen = _pick_topic(p, topics, scan_topic, LASER_SCAN, "scan_topic")
    if chosen is None:
        known = ", ".join(f"{t} ({m})" for t, m in sorted(topics)) or "none"
        raise ValueError(f"{p}: no sensor_msgs/LaserScan topic (topics: {known})")
    override = laser_pose_argument(laser_pose)
    if max_scans is not None and (
        isinstance(max_scans, bool) or not isinstance(max_scans, int) or max_scans < 1
    ):
        raise ValueError(f"max_scans: must be an integer >= 1, got {max_scans!r}")
    scans = tuple(itertools.islice(iter_bag_scans(p, chosen), max_scans))
    if not scans:
        raise ValueError(f"scan_topic: {chosen!r} in {p} holds no message")
    laser = _frame(scans[0].frame_id) or "laser"
    stamps = np.array([s.timestamp for s in scans])
    if (stamps == 0).all():
        stamps = np.array([s.logger_timestamp for s in scans])

    static = _read_tf(p, topics, "/tf_static")
    dynamic = _read_tf(p, topics, "/tf")
    odom = _pick_topic(p, topics, odom_topic, ODOMETRY, "odom_topic")
    base: str | None = None
    odometry: list[SE2 | None] = [None] * len(scans)
    stream: OdometryStream | None = None
    source = "none"
    if odom is not None:
        read, _, child = _read_odometry(p, odom)
        base = child or None
        if len(read):
            stream = read
            source = f"{ODOMETRY.replace('/msg/', '/')} {odom}"
    else:
        # odom → base on /tf: the transforms whose parent is named odom
        moving = [t for t in dynamic if t.parent.rsplit("/", 1)[-1] == "odom"]
        children = sorted({t.child for t in moving})
        if children:
            base = next((c for c in children if c in BASE_FRAMES), children[0])
            ours = [t for t in moving if t.child == base]
            stream = OdometryStream(
                np.array([t.stamp for t in ours]),
                np.array([_planar(t.matrix).as_vector() for t in ours]),
                np.array([t.received for t in ours]),
            )
            source = f"tf {ours[0].parent} → {base}"
    if stream is not None:
        odometry = interpolate_poses(stream.stamps, stream.poses, stamps)
    # The mounting: static transforms first, then /tf's (not the moving odom edge).
    tree = static + [t for t in dynamic if t.child != base or base is None]
    if base is None:
        base = next((b for b in BASE_FRAMES if _chain(tree, b, laser) is not None), laser)
    if override is not None:
        mounting, mirrored = override, False
    else:
        mounting, mirrored = _mounting(p, tree, base, laser)
    return ScanLog(
        path=p,
        scans=scans,
        stamps=stamps,
        odometry=tuple(odometry),
        T_base_laser=mounting,
        mirrored=mirrored,
        base_frame=base,
        laser_frame=laser,
        odometry_source=source,
        odometry_stream=stream,
    )


__all__ = [
    "BASE_FRAMES",
    "MAX_ODOMETRY_GAP",
    "ODOMETRY",
    "TF_MESSAGE",
    "bag_topics",
    "interpolate_poses",
    "is_laserscan_bag",
    "read_laserscan_bag",
]
