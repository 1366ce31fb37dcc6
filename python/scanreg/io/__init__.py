"""Readers and writers for point clouds, trajectories and pose graphs.

One registry per kind of content, keyed by file extension (lower case). Adding a format is
one function and one entry here; logs that hold many scans (CARMEN: :func:`read_scans`) have a
``SCAN_SOURCES`` registry of the same shape. ROS 1/2 bags (``sensor_msgs/LaserScan`` and
``PointCloud2``): :func:`read_bag_scans`, :func:`read_bag_clouds`, :func:`list_topics`
(module :mod:`scanreg.io.rosbag`, needs the ``ros`` extra); a 2D LaserScan bag with its
odometry and tf as the 2D pipelines read it, a :class:`ScanLog`: :func:`read_laserscan_bag`
(module :mod:`scanreg.io.laserscan_bag`); a run written as a ROS 2 bag:
:func:`write_run_bag` (module :mod:`scanreg.io.rosbag_write`). LAS/LAZ (``.las``/``.laz``
in the registries, module :mod:`scanreg.io.las`, needs the ``las`` extra) keep intensity,
GPS time and returns.
Sequences of sweeps (KITTI folders, folders of point files, bags, ``sim:street``):
:func:`open_sequence` (module :mod:`scanreg.io.sequences`); per-frame tables and pose lists:
:func:`write_rows`, :func:`write_poses` (module :mod:`scanreg.io.tables`).

>>> cloud = read_points("scan.pcd")          # dispatches on the extension
>>> write_points("scan.ply", cloud)

Every reader raises :class:`FileFormatError` (a ``ValueError``) naming the file and the
problem when the file is empty, truncated, corrupt or inconsistent with its header.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from ._common import CloudLike, FileFormatError, PathLike, PointCloud, as_cloud
from .arrays import (
    read_kitti_bin,
    read_npy,
    read_npz,
    read_text,
    write_csv,
    write_kitti_bin,
    write_npy,
    write_npz,
    write_xyz,
)
from .carmen import CarmenLog, LaserScan, Odometry, read_carmen
from .g2o import PoseGraph, PoseGraphEdge, g2o_information, read_g2o, write_g2o
from .las import LasHeaderInfo, read_las, read_las_header, write_las, write_laz
from .laserscan_bag import read_laserscan_bag
from .pcd import read_pcd, write_pcd
from .ply import read_ply, write_ply
from .rosbag import (
    BagCloud,
    BagTopic,
    RosLaserScan,
    list_topics,
    read_bag_clouds,
    read_bag_scans,
)
from .rosbag_write import BagFrames, BagGrid, BagTopics, LoopClosure, write_run_bag
from .scan_log import OdometryStream, ScanLog
from .sequences import (
    FolderSequence,
    KittiSequence,
    RosbagSequence,
    ScanSequence,
    SequenceFrame,
    SimulatedSequence,
    describe_sequence,
    open_sequence,
)
from .tables import (
    lidar_to_camera_poses,
    read_jsonl,
    write_csv_rows,
    write_jsonl,
    write_poses,
    write_rows,
    write_run_outputs,
)
from .trajectory import (
    KittiCalibration,
    Trajectory,
    read_kitti_calib,
    read_kitti_poses,
    read_times,
    read_tum,
    write_kitti_poses,
    write_tum,
)

#: Point-cloud readers by extension.
READERS: dict[str, Callable[[PathLike], PointCloud]] = {
    ".pcd": read_pcd,
    ".ply": read_ply,
    ".las": read_las,
    ".laz": read_las,
    ".bin": read_kitti_bin,
    ".npy": read_npy,
    ".npz": read_npz,
    ".csv": read_text,
    ".xyz": read_text,
    ".txt": read_text,
}

#: Point-cloud writers by extension (keyword options go to the writer).
WRITERS: dict[str, Callable[..., None]] = {
    ".pcd": write_pcd,
    ".ply": write_ply,
    ".las": write_las,
    ".laz": write_laz,
    ".bin": write_kitti_bin,
    ".npy": write_npy,
    ".npz": write_npz,
    ".csv": write_csv,
    ".xyz": write_xyz,
    ".txt": write_xyz,
}

#: Trajectory readers/writers by format name (extensions are ambiguous: both are ``.txt``).
TRAJECTORY_READERS: dict[str, Callable[[PathLike], Trajectory]] = {
    "kitti": read_kitti_poses,
    "tum": read_tum,
}
TRAJECTORY_WRITERS: dict[str, Callable[[PathLike, Trajectory], None]] = {
    "kitti": write_kitti_poses,
    "tum": write_tum,
}


#: Readers of files that hold many scans, by extension (``.log.gz``: the two last suffixes).
SCAN_SOURCES: dict[str, Callable[[PathLike], CarmenLog]] = {
    ".log": read_carmen,
    ".clf": read_carmen,
    ".log.gz": read_carmen,
    ".clf.gz": read_carmen,
    ".log.bz2": read_carmen,
    ".clf.bz2": read_carmen,
}


def _lookup(table: dict[str, Any], key: str, what: str, path: PathLike) -> Any:
    try:
        return table[key]
    except KeyError:
        known = ", ".join(sorted(table))
        raise ValueError(f"{path}: no {what} for {key!r} (known: {known})") from None


def read_points(path: PathLike) -> PointCloud:
    """Read a point cloud, choosing the reader from the extension (see :data:`READERS`)."""
    reader = _lookup(READERS, Path(path).suffix.lower(), "point-cloud reader", path)
    cloud: PointCloud = reader(path)
    return cloud


def write_points(path: PathLike, cloud: CloudLike, **options: Any) -> None:
    """Write a point cloud, choosing the writer from the extension (see :data:`WRITERS`).

    ``cloud`` is a :class:`PointCloud` or the points alone: an ``(N, 3)`` array-like (any
    real dtype, nested lists). ``(N, 2)`` points go to the formats that hold 2D (``.csv``,
    ``.xyz``, ``.txt``, ``.npy``, ``.npz``); the 3D formats refuse them by name.
    """
    writer = _lookup(WRITERS, Path(path).suffix.lower(), "point-cloud writer", path)
    writer(path, cloud, **options)


def read_scans(path: PathLike) -> CarmenLog:
    """Read a log of scans, choosing the reader from the extension (see :data:`SCAN_SOURCES`)."""
    suffixes = Path(path).suffixes
    key = (
        "".join(suffixes[-2:]).lower()
        if suffixes[-1:] in ([".gz"], [".bz2"])
        else Path(path).suffix.lower()
    )
    log: CarmenLog = _lookup(SCAN_SOURCES, key, "scan reader", path)(path)
    return log


def read_trajectory(path: PathLike, format: str) -> Trajectory:
    """Read a trajectory in ``format`` ``"kitti"`` or ``"tum"``."""
    reader = _lookup(TRAJECTORY_READERS, format, "trajectory reader", path)
    trajectory: Trajectory = reader(path)
    return trajectory


def write_trajectory(path: PathLike, trajectory: Trajectory, format: str) -> None:
    """Write a trajectory in ``format`` ``"kitti"`` or ``"tum"``."""
    _lookup(TRAJECTORY_WRITERS, format, "trajectory writer", path)(path, trajectory)


__all__ = [
    "READERS",
    "SCAN_SOURCES",
    "TRAJECTORY_READERS",
    "TRAJECTORY_WRITERS",
    "WRITERS",
    "BagCloud",
    "BagFrames",
    "BagGrid",
    "BagTopic",
    "BagTopics",
    "CarmenLog",
    "FileFormatError",
    "FolderSequence",
    "KittiCalibration",
    "KittiSequence",
    "LasHeaderInfo",
    "LaserScan",
    "LoopClosure",
    "Odometry",
    "OdometryStream",
    "PointCloud",
    "PoseGraph",
    "PoseGraphEdge",
    "RosLaserScan",
    "RosbagSequence",
    "ScanLog",
    "ScanSequence",
    "SequenceFrame",
    "SimulatedSequence",
    "Trajectory",
    "as_cloud",
    "describe_sequence",
    "g2o_information",
    "lidar_to_camera_poses",
    "list_topics",
    "open_sequence",
    "read_bag_clouds",
    "read_bag_scans",
    "read_carmen",
    "read_g2o",
    "read_jsonl",
    "read_kitti_bin",
    "read_kitti_calib",
    "read_kitti_poses",
    "read_las",
    "read_las_header",
    "read_laserscan_bag",
    "read_npy",
    "read_npz",
    "read_pcd",
    "read_ply",
    "read_points",
    "read_scans",
    "read_text",
    "read_times",
    "read_trajectory",
    "read_tum",
    "write_csv",
    "write_csv_rows",
    "write_g2o",
    "write_jsonl",
    "write_kitti_bin",
    "write_kitti_poses",
    "write_las",
    "write_laz",
    "write_npy",
    "write_npz",
    "write_pcd",
    "write_ply",
    "write_points",
    "write_poses",
    "write_rows",
    "write_run_bag",
    "write_run_outputs",
    "write_trajectory",
    "write_tum",
    "write_xyz",
]
