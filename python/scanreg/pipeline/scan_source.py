"""Where the 2D pipelines get their scans: a CARMEN log or a LaserScan bag, as one
:class:`~scanreg.io.ScanLog` (scans, stamps, wheel odometry at each stamp, laser mounting).

>>> scans = open_scan_log("intel.clf.bz2")                       # CARMEN
>>> scans = open_scan_log("run.mcap", scan_topic="/scan")        # ROS 2 bag
>>> scans.points(0, 0.1, 40.0), scans.prior(1), scans.stamps[0]  # base frame

A CARMEN log's mounting is :func:`~scanreg.pipeline.mapping.laser_mounting` (the hospital
log's ``ROBOTLASER1`` lines: the laser 0.22 m ahead of the robot; the identity where the
laser and odometry poses are not one fixed offset apart): its scans go to the robot's frame,
where the odometry is.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..io import read_scans
from ..io._common import PathLike
from ..io.carmen import CarmenLog
from ..io.scan_log import ScanLog, laser_pose_argument
from ..io.sequences import BAG_SUFFIXES
from .odometry_timing import settle_odometry


def _carmen_scan_log(
    log: CarmenLog,
    *,
    kind: str | None,
    max_scans: int | None,
    latency: float | None,
    min_range: float,
    max_range: float,
) -> ScanLog:
    from .mapping import _scan_odometry, laser_mounting

    kinds = [s.kind for s in log.scans]
    if not kinds:
        raise ValueError(f"log: {log.path} holds no laser scan")
    chosen = kind if kind is not None else ("FLASER" if "FLASER" in kinds else kinds[0])
    indices = [i for i, k in enumerate(kinds) if k == chosen]
    if not indices:
        raise ValueError(f"kind: the log has no {chosen!r} scans (it has {sorted(set(kinds))})")
    if max_scans is not None:
        if max_scans < 1:
            raise ValueError(f"max_scans: must be >= 1, got {max_scans}")
        indices = indices[:max_scans]
    scans = tuple(log.scans[i] for i in indices)
    wheel, applied = _scan_odometry(log, indices, latency, min_range, max_range)
    mounting = laser_mounting(log, indices)
    with_odometry = any(s.odometry_pose is not None for s in scans)
    return ScanLog(
        path=log.path,
        scans=scans,
        stamps=np.array([s.timestamp for s in scans], dtype=np.float64),
        odometry=tuple(wheel),
        T_base_laser=mounting,
        base_frame="robot" if with_odometry else "laser",
        laser_frame="laser",
        odometry_source="none"
        if not any(w is not None for w in wheel)
        else f"CARMEN {chosen} odometry fields / ODOM",
        laser_latency=applied,
    )


def scan_log(
    source: CarmenLog | ScanLog,
    *,
    kind: str | None = None,
    max_scans: int | None = None,
    latency: float | None = None,
    min_range: float = 0.1,
    max_range: float = 40.0,
    laser_pose: Any = None,
) -> ScanLog:
    """``source`` as a :class:`~scanreg.io.ScanLog`, at most ``max_scans`` scans.

    A CARMEN log: the scans of message ``kind`` (default ``FLASER`` if present, else the
    first kind in the log), in file order; the wheel odometry at each scan's time
    (:func:`~scanreg.pipeline.mapping.scan_odometry` with ``latency``, ``min_range``,
    ``max_range``); the mounting from its lines
    (:func:`~scanreg.pipeline.mapping.laser_mounting`). A ScanLog read from a bag: its
    odometry messages paired with its scans the same way
    (:func:`~scanreg.pipeline.odometry_timing.settle_odometry`, the same arguments).
    ``laser_pose`` (``[x, y, θ]``) overrides the mounting of either.
    """
    override = laser_pose_argument(laser_pose)
    if isinstance(source, ScanLog):
        if kind is not None:
            raise ValueError("kind: only for a CARMEN log (a ScanLog holds one laser stream)")
        out = settle_odometry(
            source.head(max_scans), latency=latency, min_range=min_range, max_range=max_range
        )
    elif isinstance(source, CarmenLog):
        out = _carmen_scan_log(
            source,
            kind=kind,
            max_scans=max_scans,
            latency=latency,
            min_range=min_range,
            max_range=max_range,
        )
    else:
        raise TypeError(f"log: expected a CarmenLog or a ScanLog, got {type(source).__name__}")
    if override is not None:
        out = dataclasses.replace(out, T_base_laser=override, mirrored=False)
    return out


def is_bag(path: PathLike) -> bool:
    """Whether ``path`` names a ROS bag (``.bag``, ``.db3``, ``.mcap`` or a bag folder)."""
    p = Path(path)
    return p.suffix.lower() in BAG_SUFFIXES or (p / "metadata.yaml").is_file()


def open_scan_log(
    path: PathLike,
    *,
    kind: str | None = None,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    laser_pose: Any = None,
    max_scans: int | None = None,
    latency: float | None = None,
    min_range: float = 0.1,
    max_range: float = 40.0,
) -> ScanLog:
    """Read a CARMEN log or a LaserScan bag as a :class:`~scanreg.io.ScanLog` (see
    :func:`scan_log` and :func:`~scanreg.io.laserscan_bag.read_laserscan_bag`)."""
    if is_bag(path):
        from ..io.laserscan_bag import read_laserscan_bag

        if kind is not None:
            raise ValueError("kind: only for a CARMEN log (a bag's stream is its scan_topic)")
        bag = read_laserscan_bag(
            path,
            scan_topic=scan_topic,
            odom_topic=odom_topic,
            laser_pose=laser_pose,
            max_scans=max_scans,
        )
        return scan_log(bag, latency=latency, min_range=min_range, max_range=max_range)
    for name, value in (("scan_topic", scan_topic), ("odom_topic", odom_topic)):
        if value is not None:
            raise ValueError(f"{name}: only for a ROS bag, not {path}")
    return scan_log(
        read_scans(path),
        kind=kind,
        max_scans=max_scans,
        latency=latency,
        min_range=min_range,
        max_range=max_range,
        laser_pose=laser_pose,
    )


__all__ = ["is_bag", "open_scan_log", "scan_log"]
