"""Write a run's results as a ROS 2 bag (mcap or sqlite3) that RViz 2 and Foxglove play.

No ROS install is needed: messages are serialised by the ``rosbags`` package (the ``ros``
extra, ``pip install 'scanreg[ros]'``), which also writes the storage.

>>> write_run_bag("run.mcap", stamps, poses, covariances=covs, scans=clouds, map_points=m)

What is written (topic names and frame ids are configurable, :class:`BagTopics`,
:class:`BagFrames`):

* ``/scanreg/odometry`` — ``nav_msgs/msg/Odometry`` per frame (odom → sensor);
* ``/scanreg/pose`` — ``geometry_msgs/msg/PoseWithCovarianceStamped`` per frame (map);
* ``/tf`` — ``tf2_msgs/msg/TFMessage`` per frame: map → odom → sensor;
* ``/scanreg/scan`` — ``sensor_msgs/msg/PointCloud2`` per frame (when ``scans``);
* ``/scanreg/map`` — ``sensor_msgs/msg/PointCloud2`` once, at the last stamp (``map_points``);
* ``/scanreg/grid`` — ``nav_msgs/msg/OccupancyGrid`` once (when ``grid``);
* ``/scanreg/path`` — ``nav_msgs/msg/Path`` once, at the last stamp;
* ``/scanreg/loop_closures`` — ``visualization_msgs/msg/MarkerArray`` once (when ``loops``).

The map, grid, path and loop topics are offered *transient local* (latched), so a viewer that
starts late still gets them.

Frames and covariance
---------------------
``poses`` are ``T_map_sensor``; ``odometry_poses`` (default: ``poses``) are
``T_odom_sensor``, so ``/tf`` carries ``T_map_odom = T_map_sensor · T_odom_sensor⁻¹`` (the
identity for plain odometry; the loop-closure correction after mapping) and
``T_odom_sensor``. Covariances are scanreg's (right perturbation, body frame, translation
first) and are converted to ROS's (parent frame, rotation about the parent's fixed axes) by
:func:`scanreg.interop.covariance_to_ros` — ``Σ_ros = J Σ Jᵀ`` with ``J = diag(R, R)``. The
twist of ``nav_msgs/Odometry`` is in the child (sensor) frame, ``log(T_prev_curr)/Δt``, with
covariance ``Σ/Δt²`` (Σ is in the body frame already; it is the frame's uncertainty given
the map, not the map's own error). A covariance that is not finite (the first frame, a
failed registration) is written as ``unknown_variance`` on the diagonal, the way ROS nodes
say "not measured" to ``robot_localization``.

Errors
------
Bad input (an invalid ROS 2 topic name, a frame id with a leading ``/``, mismatched
lengths, non-finite points) raises ``ValueError``/``TypeError`` naming the argument before
anything is written; an unwritable destination raises ``PermissionError`` /
``FileNotFoundError`` naming it. The bag is written under a temporary name next to the
destination and renamed on success, so a failure never leaves a half-written bag.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .._validate import FloatArray
from ..transform import SE2, SE3
from ._common import PathLike, PointCloud
from .rosbag import _rosbags
from .trajectory import rotation_to_quaternion

#: Storage by the destination's suffix; a path without one is a ROS 2 bag folder.
BAG_STORAGES = {".mcap": "mcap", ".db3": "sqlite3"}
#: What a non-finite covariance is written as (m², rad² on the diagonal).
UNKNOWN_VARIANCE = 1e6

#: Indices of ``x, y, rotation about Z`` in the 6-D tangent (and in ROS's 6×6).
ROS_PLANAR_INDICES = (0, 1, 5)
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: rmw's limit on a fully qualified topic name (255 minus the DDS prefix "rt").
_MAX_TOPIC_LENGTH = 253


def check_topic_name(name: Any, argument: str = "topic") -> str:
    """A valid fully qualified ROS 2 topic name, or ``ValueError`` naming what is wrong.

    The rules are those of ``rmw_validate_full_topic_name``: starts with ``/``, tokens
    separated by single ``/`` made of letters, digits and ``_`` that do not start with a
    digit, no trailing ``/``, at most 253 characters. A relative name (``scan``) is taken in
    the root namespace (``/scan``), as a node without a namespace would publish it.
    """
    if not isinstance(name, str):
        raise TypeError(f"{argument}: expected a str, got {type(name).__name__}")
    full = name if name.startswith("/") else "/" + name
    problem = None
    if name in ("", "/"):
        problem = "is empty"
    elif len(full) > _MAX_TOPIC_LENGTH:
        problem = f"is longer than {_MAX_TOPIC_LENGTH} characters"
    elif full.endswith("/"):
        problem = "ends with '/'"
    elif "//" in full:
        problem = "contains '//'"
    else:
        for token in full[1:].split("/"):
            if not _TOKEN.fullmatch(token):
                bad = "starts with a digit" if token[:1].isdigit() else "has characters other "
                if not token[:1].isdigit():
                    bad += "than letters, digits and '_'"
                problem = f"token {token!r} {bad}"
                break
    if problem:
        raise ValueError(f"{argument}: {name!r} is not a valid ROS 2 topic name ({problem})")
    return full


def check_frame_id(name: Any, argument: str) -> str:
    """A tf2 frame id: non-empty, no leading ``/`` (tf2 in ROS 2 refuses it), no spaces."""
    if not isinstance(name, str):
        raise TypeError(f"{argument}: expected a str, got {type(name).__name__}")
    if not name or name.startswith("/") or any(c.isspace() for c in name):
        raise ValueError(
            f"{argument}: {name!r} is not a valid tf2 frame id "
            "(non-empty, no leading '/', no whitespace)"
        )
    return name


@dataclass(frozen=True)
class BagFrames:
    """tf2 frame ids: ``map → odom → sensor``."""

    map: str = "map"
    odom: str = "odom"
    sensor: str = "lidar"

    def __post_init__(self) -> None:
        names = [check_frame_id(getattr(self, f.name), f"frames.{f.name}") for f in fields(self)]
        if len(set(names)) != len(names):
            raise ValueError(f"frames: the three frame ids must differ, got {names}")


@dataclass(frozen=True)
class BagTopics:
    """Topic names (relative names are put in the root namespace)."""

    odometry: str = "/scanreg/odometry"
    pose: str = "/scanreg/pose"
    tf: str = "/tf"
    scan: str = "/scanreg/scan"
    map: str = "/scanreg/map"
    grid: str = "/scanreg/grid"
    path: str = "/scanreg/path"
    loop_closures: str = "/scanreg/loop_closures"

    def __post_init__(self) -> None:
        names = []
        for f in fields(self):
            full = check_topic_name(getattr(self, f.name), f"topics.{f.name}")
            object.__setattr__(self, f.name, full)
            names.append(full)
        if len(set(names)) != len(names):
            raise ValueError(f"topics: every topic name must differ, got {names}")


@dataclass(frozen=True)
class LoopClosure:
    """A loop closure between frames ``source`` and ``target`` (indices into ``poses``)."""

    source: int
    target: int
    accepted: bool = True


@dataclass(frozen=True)
class BagGrid:
    """A 2D occupancy grid for ``nav_msgs/OccupancyGrid`` (what RViz's Map display shows).

    ``probability[row, col]`` in ``[0, 1]`` (NaN: unknown), row ``0`` at ``origin`` and rows
    along +y, columns along +x — the layout of :class:`scanreg.io.occupancy.OccupancyGrid`,
    so ``BagGrid(g.probability, g.resolution, g.origin)`` converts one.
    """

    probability: FloatArray
    #: Cell edge (m).
    resolution: float
    #: World ``(x, y)`` of the lower-left corner of cell ``(0, 0)``.
    origin: tuple[float, float]

    def __post_init__(self) -> None:
        p = np.array(self.probability, dtype=np.float64)
        if p.ndim != 2 or 0 in p.shape:
            raise ValueError(f"grid.probability: expected a non-empty (H, W) array, got {p.shape}")
        known = p[np.isfinite(p)]
        if np.isinf(p).any() or (known.size and (known.min() < 0 or known.max() > 1)):
            raise ValueError("grid.probability: must be in [0, 1] or NaN (unknown)")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"grid.resolution: must be finite and > 0, got {self.resolution}")
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 2 or not np.isfinite(origin).all():
            raise ValueError(f"grid.origin: expected finite (x, y), got {self.origin!r}")
        object.__setattr__(self, "probability", p)
        object.__setattr__(self, "origin", origin)

    def ros_data(self) -> Any:
        """Row-major ``int8``: occupancy in percent, ``-1`` unknown (the message's layout)."""
        p = self.probability
        out = np.full(p.shape, -1, dtype=np.int8)
        known = np.isfinite(p)
        out[known] = np.round(100 * p[known]).astype(np.int8)
        return out.reshape(-1)


@dataclass(frozen=True)
class BagSummary:
    """What :func:`write_run_bag` wrote: the path, storage and messages per topic."""

    path: Path
    storage: str
    messages: dict[str, int]


# --------------------------------------------------------------------------- validation


def _embed_planar(mats: FloatArray) -> FloatArray:
    """``(K, 3, 3)`` SE(2) matrices → ``(K, 4, 4)`` at ``z = 0``, yaw about Z."""
    out = np.tile(np.eye(4), (len(mats), 1, 1))
    out[:, :2, :2] = mats[:, :2, :2]
    out[:, :2, 3] = mats[:, :2, 2]
    return out


def _poses(value: Any, name: str, count: int | None) -> FloatArray:
    if isinstance(value, Sequence) and value and isinstance(value[0], (SE2, SE3)):
        mats = np.array([p.as_matrix() for p in value])
    else:
        mats = np.array(value, dtype=np.float64)
    if mats.ndim == 3 and mats.shape[1:] == (3, 3):
        for k, m in enumerate(mats):
            if not np.allclose(m[2], [0, 0, 1]):
                raise ValueError(f"{name}[{k}]: last row must be [0, 0, 1]")
        mats = _embed_planar(mats)
    if mats.ndim != 3 or mats.shape[1:] != (4, 4):
        raise ValueError(
            f"{name}: expected (K, 4, 4) or (K, 3, 3) poses or a list of SE3/SE2, got {mats.shape}"
        )
    if count is not None and len(mats) != count:
        raise ValueError(f"{name}: expected {count} poses (one per stamp), got {len(mats)}")
    if not np.isfinite(mats).all():
        raise ValueError(f"{name}: holds NaN or inf")
    for k, m in enumerate(mats):
        SE3.from_matrix(m)  # refuses a non-rigid pose, naming the problem
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError(f"{name}[{k}]: last row must be [0, 0, 0, 1]")
    return mats


def _covariances(value: Any, name: str, count: int) -> FloatArray | None:
    if value is None:
        return None
    covs = np.array(value, dtype=np.float64)
    if covs.shape == (count, 3, 3):
        # planar [ρx, ρy, θ] → the 6-D tangent's x, y and rotation about Z; z, roll and pitch
        # exactly known (0), as AMCL and slam_toolbox publish a planar pose
        full = np.zeros((count, 6, 6))
        idx = np.array(ROS_PLANAR_INDICES)
        full[:, idx[:, None], idx[None, :]] = covs
        return full
    if covs.shape != (count, 6, 6):
        raise ValueError(
            f"{name}: expected shape ({count}, 6, 6) or ({count}, 3, 3), got {covs.shape}"
        )
    return covs


def _cloud(value: Any, name: str) -> tuple[FloatArray, FloatArray | None]:
    intensity = None
    if isinstance(value, PointCloud):
        pts, intensity = value.points, value.intensity
    else:
        pts = np.asarray(value, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[1] == 2:  # a 2D scan or map: in the plane z = 0
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3) or (N, 2), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError(f"{name}: holds NaN or inf points (use PointCloud.finite())")
    return pts, intensity


def _loops(value: Any, count: int) -> list[LoopClosure]:
    out = []
    for k, item in enumerate(value):
        loop = item if isinstance(item, LoopClosure) else LoopClosure(*item)
        for end in (loop.source, loop.target):
            if not isinstance(end, (int, np.integer)) or not 0 <= end < count:
                raise ValueError(f"loops[{k}]: frame index {end!r} is not in [0, {count})")
        out.append(loop)
    return out


def _storage(path: Path, storage: str | None) -> str:
    by_suffix = BAG_STORAGES.get(path.suffix.lower())
    if storage is None:
        return by_suffix or "mcap"
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"storage: expected 'mcap' or 'sqlite3', got {storage!r}")
    if by_suffix is not None and by_suffix != storage:
        raise ValueError(f"storage: {storage!r} does not match the file name {path.name!r}")
    return storage


def check_bag_destination(path: PathLike, *, overwrite: bool = False) -> Path:
    """Check that a bag can be written at ``path`` before doing any work.

    Raises ``FileNotFoundError`` (no parent folder), ``PermissionError`` (parent not writable)
    or ``FileExistsError`` (exists and ``overwrite`` is False), each naming the path.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{p}: cannot write a bag there: no folder {parent}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"{p}: cannot write a bag there: folder {parent} is not writable")
    if p.exists() and not overwrite:
        raise FileExistsError(f"{p}: exists (pass overwrite=True to replace it)")
    if p.exists() and p.is_dir() != (p.suffix.lower() not in BAG_STORAGES):
        raise FileExistsError(f"{p}: exists and is a {'folder' if p.is_dir() else 'file'}")
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        # never replace a folder that is not a bag (e.g. the run's own output folder)
        raise FileExistsError(f"{p}: exists and is not a ROS 2 bag folder (no metadata.yaml)")
    return p


# --------------------------------------------------------------------------- messages


class _Messages:
    """Message constructors over one rosbags typestore."""

    def __init__(self) -> None:
        rosbags = _rosbags()
        self.store = rosbags.typesys.get_typestore(rosbags.typesys.Stores.LATEST)
        self.t = self.store.types

    def time(self, ns: int) -> Any:
        return self.t["builtin_interfaces/msg/Time"](
            sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000
        )

    def header(self, ns: int, frame: str) -> Any:
        return self.t["std_msgs/msg/Header"](stamp=self.time(ns), frame_id=frame)

    def pose(self, m: FloatArray) -> Any:
        t = self.t
        q = rotation_to_quaternion(m[:3, :3])
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
            orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )

    def transform(self, ns: int, parent: str, child: str, m: FloatArray) -> Any:
        t = self.t
        q = rotation_to_quaternion(m[:3, :3])
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )

    def pointcloud2(self, ns: int, frame: str, pts: FloatArray, intensity: Any) -> Any:
        names = ["x", "y", "z"] + ([] if intensity is None else ["intensity"])
        rec = np.empty(len(pts), dtype=[(n, "<f4") for n in names])
        for i, axis in enumerate("xyz"):
            rec[axis] = pts[:, i]
        if intensity is not None:
            rec["intensity"] = intensity
        field = self.t["sensor_msgs/msg/PointField"]
        return self.t["sensor_msgs/msg/PointCloud2"](
            header=self.header(ns, frame),
            height=1,
            width=len(pts),
            fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(names)],
            is_bigendian=False,
            point_step=4 * len(names),
            row_step=4 * len(names) * len(pts),
            data=np.frombuffer(rec.tobytes(), dtype=np.uint8),
            is_dense=True,
        )

    def loop_markers(
        self, ns: int, frame: str, positions: FloatArray, loops: list[LoopClosure]
    ) -> Any:
        t = self.t
        markers = []
        for index, (label, accepted, rgba) in enumerate(
            (("accepted", True, (0.1, 0.8, 0.2, 1.0)), ("rejected", False, (0.9, 0.1, 0.1, 1.0)))
        ):
            chosen = [lp for lp in loops if lp.accepted == accepted]
            points = [
                t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2])
                for lp in chosen
                for p in (positions[lp.source], positions[lp.target])
            ]
            marker = t["visualization_msgs/msg/Marker"](
                header=self.header(ns, frame),
                ns=f"loop_closures_{label}",
                id=index,
                type=5,  # LINE_LIST: one segment per pair of points
                action=0 if points else 2,  # ADD, or DELETE an empty list
                pose=self.pose(np.eye(4)),
                scale=t["geometry_msgs/msg/Vector3"](x=0.15, y=0.0, z=0.0),
                color=t["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
                lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
                frame_locked=True,
                points=points,
                colors=[],
                texture_resource="",
                texture=t["sensor_msgs/msg/CompressedImage"](
                    header=self.header(ns, frame), format="", data=np.zeros(0, np.uint8)
                ),
                uv_coordinates=[],
                text="",
                mesh_resource="",
                mesh_file=t["visualization_msgs/msg/MeshFile"](
                    filename="", data=np.zeros(0, np.uint8)
                ),
                mesh_use_embedded_materials=False,
            )
            markers.append(marker)
        return t["visualization_msgs/msg/MarkerArray"](markers=markers)


def _ros_covariance(pose: SE3, cov: FloatArray | None, unknown: float) -> FloatArray:
    from ..interop import covariance_to_ros

    if cov is None or not np.isfinite(cov).all():
        return np.diag(np.full(6, unknown)).reshape(36)
    out: FloatArray = covariance_to_ros(pose, cov).reshape(36)
    return out


def _latched_qos() -> list[Any]:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    never = QosTime(sec=0, nsec=0)
    return [
        Qos(
            history=QosHistory.KEEP_LAST,
            depth=1,
            reliability=QosReliability.RELIABLE,
            durability=QosDurability.TRANSIENT_LOCAL,
            deadline=never,
            lifespan=never,
            liveliness=QosLiveliness.AUTOMATIC,
            liveliness_lease_duration=never,
            avoid_ros_namespace_conventions=False,
        )
    ]


# --------------------------------------------------------------------------- writer


def write_run_bag(
    path: PathLike,
    stamps: Any,
    poses: Any,
    *,
    covariances: Any = None,
    odometry_poses: Any = None,
    odometry_covariances: Any = None,
    scans: Sequence[Any] | None = None,
    scan_frame: Literal["sensor", "map"] = "sensor",
    map_points: Any = None,
    grid: BagGrid | None = None,
    loops: Sequence[Any] = (),
    frames: BagFrames | None = None,
    topics: BagTopics | None = None,
    storage: str | None = None,
    unknown_variance: float = UNKNOWN_VARIANCE,
    overwrite: bool = False,
) -> BagSummary:
    """Write a run (poses, covariances, scans, map, loop closures) as a ROS 2 bag.

    Parameters
    ----------
    path
        ``run.mcap`` (one MCAP file, what Foxglove opens), ``run.db3`` (one sqlite3 file), or
        a folder name without one of those suffixes (a ROS 2 bag folder with
        ``metadata.yaml``, what ``ros2 bag play`` takes; storage from ``storage``, default
        mcap).
    stamps : (K,) seconds, non-decreasing, >= 0
        Frame times (header stamps and bag receive times).
    poses : (K, 4, 4) or list of SE3 — or (K, 3, 3) / list of SE2
        ``T_map_sensor`` per frame; planar poses are placed at ``z = 0`` with their yaw.
    covariances : (K, 6, 6) or (K, 3, 3), optional
        scanreg covariances of ``poses`` (body frame; see the module docstring); a planar
        3×3 over ``[ρx, ρy, θ]`` goes to x, y and rotation about Z, the rest 0 (as AMCL).
    odometry_poses, odometry_covariances : optional
        ``T_odom_sensor`` and their covariances; default ``poses`` and ``covariances``
        (plain odometry: ``map = odom``).
    scans : K clouds, optional
        ``(N, 3)`` (or 2D ``(N, 2)``, at ``z = 0``) arrays or
        :class:`~scanreg.io.PointCloud` (intensity kept) in the sensor
        frame, written on the scan topic in the ``sensor`` frame (tf places them), or
        transformed into the ``map`` frame when ``scan_frame="map"``.
    map_points : (M, 3), (M, 2) or PointCloud, optional
        The map in the map frame, written once at the last stamp.
    grid : BagGrid, optional
        A 2D occupancy grid (map frame), written once at the last stamp.
    loops : sequence of (source, target[, accepted]) or :class:`LoopClosure`
        Drawn as line segments between the two frames' positions in the map frame.
    frames, topics
        Frame ids and topic names (:class:`BagFrames`, :class:`BagTopics`).
    storage : "mcap" | "sqlite3", optional
        Defaults from the suffix (mcap for a folder).
    unknown_variance : float
        Diagonal written for a covariance that is not finite.
    overwrite : bool
        Replace an existing bag at ``path`` (only once the new one is complete).
    """
    frames = BagFrames() if frames is None else frames
    topics = BagTopics() if topics is None else topics
    if not isinstance(frames, BagFrames):
        raise TypeError(f"frames: expected BagFrames, got {type(frames).__name__}")
    if not isinstance(topics, BagTopics):
        raise TypeError(f"topics: expected BagTopics, got {type(topics).__name__}")
    if scan_frame not in ("sensor", "map"):
        raise ValueError(f"scan_frame: expected 'sensor' or 'map', got {scan_frame!r}")
    if not (np.isfinite(unknown_variance) and unknown_variance > 0):
        raise ValueError(f"unknown_variance: must be finite and > 0, got {unknown_variance}")
    times = np.asarray(stamps, dtype=np.float64)
    if times.ndim != 1 or len(times) == 0:
        raise ValueError(f"stamps: expected shape (K,) with K >= 1, got {times.shape}")
    if not np.isfinite(times).all() or times.min() < 0 or (np.diff(times) < 0).any():
        raise ValueError("stamps: must be finite, >= 0 and non-decreasing (seconds)")
    count = len(times)
    map_poses = _poses(poses, "poses", count)
    map_covs = _covariances(covariances, "covariances", count)
    odo_poses = (
        map_poses if odometry_poses is None else _poses(odometry_poses, "odometry_poses", count)
    )
    odo_covs = (
        map_covs
        if odometry_covariances is None
        else _covariances(odometry_covariances, "odometry_covariances", count)
    )
    clouds = None
    if scans is not None:
        if len(scans) != count:
            raise ValueError(f"scans: expected {count} clouds (one per stamp), got {len(scans)}")
        clouds = [_cloud(s, f"scans[{k}]") for k, s in enumerate(scans)]
    the_map = None if map_points is None else _cloud(map_points, "map_points")
    if grid is not None and not isinstance(grid, BagGrid):
        raise TypeError(f"grid: expected a BagGrid, got {type(grid).__name__}")
    loop_list = _loops(loops, count)
    p = Path(os.fspath(path))
    kind = _storage(p, storage)
    check_bag_destination(p, overwrite=overwrite)

    msgs = _Messages()
    ns = np.round(times * 1e9).astype(np.int64)
    written: dict[str, int] = {}
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{p.name}.partial-", dir=p.parent))
    except OSError as exc:  # e.g. a read-only or virtual file system
        raise PermissionError(f"{p}: cannot write a bag there: {exc.strerror}") from None
    try:
        bag_dir = staging / (p.stem if p.suffix.lower() in BAG_STORAGES else p.name)
        _write(
            bag_dir, kind, msgs, ns, map_poses, map_covs, odo_poses, odo_covs, clouds,
            scan_frame, the_map, grid, loop_list, frames, topics, unknown_variance, written,
        )  # fmt: skip
        _move_into_place(bag_dir, kind, p)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return BagSummary(path=p, storage=kind, messages=written)


def _move_into_place(bag_dir: Path, kind: str, dest: Path) -> None:
    if dest.suffix.lower() in BAG_STORAGES:
        inner = bag_dir / f"{bag_dir.name}{'.mcap' if kind == 'mcap' else '.db3'}"
        os.replace(inner, dest)  # atomic on one file system; replaces an old file
        return
    old = None
    if dest.exists():  # a folder cannot be replaced atomically: set the old one aside first
        old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
        dest.rename(old)
    bag_dir.rename(dest)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _write(
    bag_dir: Path,
    kind: str,
    msgs: _Messages,
    ns: Any,
    map_poses: FloatArray,
    map_covs: FloatArray | None,
    odo_poses: FloatArray,
    odo_covs: FloatArray | None,
    clouds: list[tuple[FloatArray, FloatArray | None]] | None,
    scan_frame: str,
    the_map: tuple[FloatArray, FloatArray | None] | None,
    grid: BagGrid | None,
    loops: list[LoopClosure],
    frames: BagFrames,
    topics: BagTopics,
    unknown: float,
    written: dict[str, int],
) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    t = msgs.t
    store = msgs.store
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(bag_dir, version=9, storage_plugin=plugin)
    writer.open()
    try:
        conns: dict[str, Any] = {}

        def add(topic: str, msgtype: str, latched: bool = False) -> None:
            qos = _latched_qos() if latched else ()
            conns[topic] = writer.add_connection(
                topic, msgtype, typestore=store, offered_qos_profiles=qos
            )
            written[topic] = 0

        def put(topic: str, stamp: int, msg: Any) -> None:
            writer.write(conns[topic], int(stamp), store.serialize_cdr(msg, msg.__msgtype__))
            written[topic] += 1

        add(topics.odometry, "nav_msgs/msg/Odometry")
        add(topics.pose, "geometry_msgs/msg/PoseWithCovarianceStamped")
        add(topics.tf, "tf2_msgs/msg/TFMessage")
        if clouds is not None:
            add(topics.scan, "sensor_msgs/msg/PointCloud2")
        if the_map is not None:
            add(topics.map, "sensor_msgs/msg/PointCloud2", latched=True)
        if grid is not None:
            add(topics.grid, "nav_msgs/msg/OccupancyGrid", latched=True)
        add(topics.path, "nav_msgs/msg/Path", latched=True)
        if loops:
            add(topics.loop_closures, "visualization_msgs/msg/MarkerArray", latched=True)

        vector3 = t["geometry_msgs/msg/Vector3"]
        for k, stamp in enumerate(ns):
            odo = SE3.from_matrix(odo_poses[k])
            cov_odo = _ros_covariance(odo, None if odo_covs is None else odo_covs[k], unknown)
            twist = np.zeros(6)
            twist_cov = np.diag(np.full(6, unknown))
            dt = 1e-9 * float(stamp - ns[k - 1]) if k else 0.0
            if dt > 0:
                twist = SE3.from_matrix(np.linalg.inv(odo_poses[k - 1]) @ odo_poses[k]).log() / dt
                body = None if odo_covs is None else odo_covs[k]
                if body is not None and np.isfinite(body).all():
                    twist_cov = body / dt**2  # child frame = body frame: no rotation
            put(
                topics.odometry,
                stamp,
                t["nav_msgs/msg/Odometry"](
                    header=msgs.header(stamp, frames.odom),
                    child_frame_id=frames.sensor,
                    pose=t["geometry_msgs/msg/PoseWithCovariance"](
                        pose=msgs.pose(odo_poses[k]), covariance=cov_odo
                    ),
                    twist=t["geometry_msgs/msg/TwistWithCovariance"](
                        twist=t["geometry_msgs/msg/Twist"](
                            linear=vector3(x=twist[0], y=twist[1], z=twist[2]),
                            angular=vector3(x=twist[3], y=twist[4], z=twist[5]),
                        ),
                        covariance=np.ascontiguousarray(twist_cov).reshape(36),
                    ),
                ),
            )
            pose_map = SE3.from_matrix(map_poses[k])
            cov_map = _ros_covariance(pose_map, None if map_covs is None else map_covs[k], unknown)
            put(
                topics.pose,
                stamp,
                t["geometry_msgs/msg/PoseWithCovarianceStamped"](
                    header=msgs.header(stamp, frames.map),
                    pose=t["geometry_msgs/msg/PoseWithCovariance"](
                        pose=msgs.pose(map_poses[k]), covariance=cov_map
                    ),
                ),
            )
            map_odom = map_poses[k] @ np.linalg.inv(odo_poses[k])
            put(
                topics.tf,
                stamp,
                t["tf2_msgs/msg/TFMessage"](
                    transforms=[
                        msgs.transform(stamp, frames.map, frames.odom, map_odom),
                        msgs.transform(stamp, frames.odom, frames.sensor, odo_poses[k]),
                    ]
                ),
            )
            if clouds is not None:
                pts, inten = clouds[k]
                frame = frames.sensor
                if scan_frame == "map":
                    pts = pts @ map_poses[k][:3, :3].T + map_poses[k][:3, 3]
                    frame = frames.map
                put(topics.scan, stamp, msgs.pointcloud2(stamp, frame, pts, inten))
        last = int(ns[-1])
        if the_map is not None:
            put(topics.map, last, msgs.pointcloud2(last, frames.map, *the_map))
        if grid is not None:
            origin = np.eye(4)
            origin[:2, 3] = grid.origin
            height, width = grid.probability.shape
            info = t["nav_msgs/msg/MapMetaData"](
                map_load_time=msgs.time(last),
                resolution=float(grid.resolution),
                width=width,
                height=height,
                origin=msgs.pose(origin),
            )
            put(
                topics.grid,
                last,
                t["nav_msgs/msg/OccupancyGrid"](
                    header=msgs.header(last, frames.map), info=info, data=grid.ros_data()
                ),
            )
        put(
            topics.path,
            last,
            t["nav_msgs/msg/Path"](
                header=msgs.header(last, frames.map),
                poses=[
                    t["geometry_msgs/msg/PoseStamped"](
                        header=msgs.header(int(s), frames.map), pose=msgs.pose(m)
                    )
                    for s, m in zip(ns, map_poses, strict=True)
                ],
            ),
        )
        if loops:
            marks = msgs.loop_markers(last, frames.map, map_poses[:, :3, 3], loops)
            put(topics.loop_closures, last, marks)
    finally:
        writer.close()


__all__ = [
    "BAG_STORAGES",
    "UNKNOWN_VARIANCE",
    "BagFrames",
    "BagGrid",
    "BagSummary",
    "BagTopics",
    "LoopClosure",
    "check_bag_destination",
    "check_frame_id",
    "check_topic_name",
    "write_run_bag",
]
