"""A simulated room tour as a LaserScan bag gives it to the 2D pipelines (a
:class:`scanreg.io.ScanLog` of ``RosLaserScan``), with its exact truth; used by the tests of
deskewing and of runs without odometry."""

from __future__ import annotations

from typing import Any

import numpy as np
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.io.rosbag import RosLaserScan
from scanreg.io.scan_log import ScanLog

RATE = 5.0


def tour_log(
    seed: int, laser_name: str, *, beam_times: bool, odometry: bool
) -> tuple[ScanLog, tuple[SE2, ...]]:
    """One room on each side of a corridor (``simulate.room_tour``) toured at 5 Hz: the scans
    with ``time_increment`` (``beam_times``; else 0, as a driver that does not fill it in),
    the wheels' odometry at each stamp (``odometry``; else none), and ``T_first_scan`` of each
    scan as the truth."""
    course = sim.room_tour(seed=seed, rooms_per_side=1)
    laser = sim.LaserModel.preset(laser_name)
    run = sim.simulate_run(
        course.scene, laser, course.trajectory,
        num_scans=course.num_scans(RATE), scan_rate=RATE, seed=seed,
    )  # fmt: skip
    truth: tuple[SE2, ...] = tuple(run.poses[0].inverse() @ p for p in run.poses)  # type: ignore[misc]
    poses: list[SE2 | None] = [None] * len(truth)
    if odometry:
        poses = [SE2.identity()]
        for step in sim.wheel_odometry(list(truth), seed + 7)[1:]:
            assert step is not None
            poses.append(poses[-1] @ step)  # type: ignore[operator]
    increment = laser.time_increment if beam_times else 0.0
    scans = tuple(_message(s, k / RATE, laser, increment) for k, s in enumerate(run.scans))
    stamps = np.arange(len(scans)) / RATE
    return ScanLog("sim", scans, stamps, tuple(poses), SE2.identity()), truth  # type: ignore[arg-type]


def _message(scan: Any, stamp: float, laser: sim.LaserModel, increment: float) -> RosLaserScan:
    return RosLaserScan(
        kind="sensor_msgs/LaserScan", ranges=scan.ranges, angles=scan.angles,
        max_range=laser.max_range, laser_pose=None, odometry_pose=None, timestamp=stamp,
        logger_timestamp=stamp + 0.1, range_min=laser.min_range, time_increment=increment,
        scan_time=1 / RATE,
    )  # fmt: skip


def ate(poses: Any, truth: Any) -> float:
    """RMS position error (m) of ``poses`` against ``truth``, both from the first scan's frame."""
    err = [np.linalg.norm((t.inverse() @ p).translation) for p, t in zip(poses, truth, strict=True)]
    return float(np.sqrt(np.mean(np.square(err))))
