"""2D scans that say when each beam was measured (a ``sensor_msgs/LaserScan``'s
``time_increment``) are deskewed before they are mapped: a 360° laser at 5 Hz on a simulated
room tour, read as a LaserScan bag reads (:class:`scanreg.io.ScanLog` of ``RosLaserScan``),
against the simulator's exact truth; and the online path (``Odometry2D.step(...,
timestamps=)``) against :func:`scanreg.deskew` itself."""

from __future__ import annotations

import dataclasses
from functools import cache
from typing import Any

import numpy as np
import pytest
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.deskew import deskew, velocity_from_motion
from scanreg.io.rosbag import RosLaserScan
from scanreg.io.scan_log import ScanLog
from scanreg.pipeline import MappingConfig
from scanreg.pipeline.odometry2d import Odometry2D

RATE = 5.0


@cache
def _tour(beam_times: bool) -> tuple[ScanLog, tuple[SE2, ...]]:
    """One room on each side of a corridor toured with ``laser_360`` (720 beams, a 0.1 s
    sweep) at 5 Hz, wheel odometry at each scan's stamp; ``beam_times=False``: the same
    scans with ``time_increment`` 0 (as a driver that does not fill it in)."""
    course = sim.room_tour(seed=0, rooms_per_side=1)
    laser = sim.LaserModel.preset("laser_360")
    run = sim.simulate_run(
        course.scene, laser, course.trajectory,
        num_scans=course.num_scans(RATE), scan_rate=RATE, seed=0,
    )  # fmt: skip
    truth = tuple(run.poses[0].inverse() @ p for p in run.poses)
    odometry = [SE2.identity()]
    for step in sim.wheel_odometry(list(truth), 7)[1:]:
        assert step is not None
        odometry.append(odometry[-1] @ step)
    increment = laser.time_increment if beam_times else 0.0
    scans = tuple(_message(s, k / RATE, laser, increment) for k, s in enumerate(run.scans))
    stamps = np.arange(len(scans)) / RATE
    log = ScanLog("sim", scans, stamps, tuple(odometry), SE2.identity(), odometry_source="sim")
    return log, truth  # type: ignore[return-value]


def _message(scan: Any, stamp: float, laser: sim.LaserModel, increment: float) -> RosLaserScan:
    return RosLaserScan(
        kind="sensor_msgs/LaserScan", ranges=scan.ranges, angles=scan.angles,
        max_range=laser.max_range, laser_pose=None, odometry_pose=None, timestamp=stamp,
        logger_timestamp=stamp + 0.1, range_min=laser.min_range, time_increment=increment,
        scan_time=1 / RATE,
    )  # fmt: skip


def _ate(poses: tuple[SE2, ...], truth: tuple[SE2, ...]) -> float:
    err = [np.linalg.norm((t.inverse() @ p).translation) for p, t in zip(poses, truth, strict=True)]
    return float(np.sqrt(np.mean(np.square(err))))


def test_swept_points_undo_the_sweep_with_the_wheels() -> None:
    log, truth = _tour(True)
    course = sim.room_tour(seed=0, rooms_per_side=1)
    # A scan on a turn: its returns as the simulator has them at the sweep's start.
    k = 15
    run = sim.simulate_run(
        course.scene, sim.LaserModel.preset("laser_360"), course.trajectory,
        num_scans=k + 1, scan_rate=RATE, seed=0,
    )  # fmt: skip
    exact = run.scans[k].points_deskewed
    raw = log.points(k)
    points, times = log.swept_points(k)
    assert times is None and points.shape == raw.shape == exact.shape
    turn = abs((truth[k].inverse() @ truth[k + 1]).angle)
    assert turn > 0.3, turn  # (the scan is taken while turning 1.6 rad/s)
    # Measured: 0.90 m raw, 0.012 m deskewed by the noisy wheels (at up to 30 m).
    assert np.abs(raw - exact).max() > 0.5
    assert np.abs(points - exact).max() < 0.03
    # The last scan has no next odometry: its times are left to the pipeline's prediction.
    last = len(log) - 1
    points, times = log.swept_points(last)
    np.testing.assert_array_equal(points, log.points(last))
    assert times is not None and times[0] == pytest.approx(log.stamps[last])
    assert np.all(np.diff(times) > 0) and times[-1] - times[0] < 0.1
    # No beam times: the points as read, nothing to deskew.
    flat, _ = _tour(False)
    points, times = flat.swept_points(k)
    assert times is None
    np.testing.assert_array_equal(points, flat.points(k))


@pytest.mark.slow
def test_a_360_laser_maps_when_its_sweeps_are_undone() -> None:
    pytest.importorskip("gtsam")
    from scanreg.pipeline import run_mapping

    errors = {}
    for beam_times in (True, False):
        log, truth = _tour(beam_times)
        res = run_mapping(log, MappingConfig())
        errors[beam_times] = _ate(res.poses, truth)
    # Measured: 0.012 m with the beams' times, 0.053 m without (each sweep 0.1 s long,
    # turning up to ~1.9 rad/s).
    assert errors[True] < 0.02 and errors[False] > 2 * errors[True], errors


def test_odometry_deskews_online_with_its_prediction() -> None:
    log, _ = _tour(True)
    odo = Odometry2D()
    k = 60
    times = [log.stamps[j] + log.point_times(j) for j in (k - 1, k)]
    first = odo.step(log.points(k - 1), timestamps=times[0], stamp=log.stamps[k - 1])
    # The first scan: no motion known yet, kept as it is.
    np.testing.assert_array_equal(first.deskewed, log.points(k - 1))
    prior = log.prior(k)
    assert prior is not None
    frame = odo.step(log.points(k), timestamps=times[1], prior=prior, stamp=log.stamps[k])
    # The prior's motion spread over the time since the previous scan, to this stamp.
    velocity = velocity_from_motion(prior, log.stamps[k] - log.stamps[k - 1])
    expected = deskew(log.points(k), times[1], velocity, reference_time=log.stamps[k])
    np.testing.assert_allclose(frame.deskewed, expected, rtol=0, atol=1e-12)
    assert Odometry2D().step(log.points(k)).deskewed is None
    with pytest.raises(ValueError, match="stamp: required with timestamps"):
        Odometry2D().step(log.points(k), timestamps=times[1])
    with pytest.raises(ValueError, match=rf"timestamps: expected shape \({len(times[1])},\)"):
        Odometry2D().step(log.points(k), timestamps=times[1][:-1], stamp=1.0)
    bad = times[1].copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="timestamps: contains NaN or inf"):
        Odometry2D().step(log.points(k), timestamps=bad, stamp=1.0)


def test_mapper_keeps_the_deskewed_scan_and_refuses_bad_times() -> None:
    pytest.importorskip("gtsam")
    from scanreg.pipeline.mapping import Mapper

    log, _ = _tour(True)
    mapper = Mapper(MappingConfig())
    for j in (59, 60):
        times = log.stamps[j] + log.point_times(j)
        tracked = mapper.track(log.points(j), times, prior=log.prior(j), stamp=log.stamps[j])
        mapper.integrate(tracked)
    # The second scan was deskewed (it turned): the node-to-be keeps those points.
    assert np.abs(tracked.points - log.points(60)).max() > 0.05
    with pytest.raises(ValueError, match="stamp: required with timestamps"):
        mapper.track(log.points(61), log.point_times(61))
    # A stamp out of order (a corrupted log) is taken as instantaneous, not refused.
    late = mapper.track(log.points(61), log.point_times(61), stamp=0.0)
    np.testing.assert_array_equal(late.points, log.points(61))
    assert dataclasses.is_dataclass(late)
