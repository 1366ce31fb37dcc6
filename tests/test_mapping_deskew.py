"""2D scans that say when each beam was measured (a ``sensor_msgs/LaserScan``'s
``time_increment``) are deskewed before they are mapped: a 360° laser at 5 Hz on a simulated
room tour, read as a LaserScan bag reads (:class:`scanreg.io.ScanLog` of ``RosLaserScan``),
against the simulator's exact truth; and the online path (``Odometry2D.step(...,
timestamps=)``) against :func:`scanreg.deskew` itself."""

from __future__ import annotations

import dataclasses
import json
import math
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _sim_scan_log import RATE, ate, tour_log
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.deskew import deskew, velocity_from_motion
from scanreg.io.scan_log import ScanLog
from scanreg.pipeline import MappingConfig
from scanreg.pipeline.odometry2d import Odometry2D


@cache
def _tour(beam_times: bool) -> tuple[ScanLog, tuple[SE2, ...]]:
    """``laser_360`` (720 beams, a 0.1 s sweep) with the wheels' odometry."""
    return tour_log(0, "laser_360", beam_times=beam_times, odometry=True)


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
        errors[beam_times] = ate(res.poses, truth)
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


def _write_bag(path: Path, odometry: bool) -> Path:
    """The tour as a robot would have recorded it, written by rosbags' own writer: ``/scan``
    (LaserScan with ``time_increment``, float32 ranges), ``/odom`` (the wheels, at each scan's
    stamp) unless ``odometry`` is false, ``/tf_static`` (the laser at the base's origin)."""
    pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'scanreg[ros]')")
    from _carmen_bag import _header, _odometry, _quaternion, write_messages
    from rosbags.typesys import Stores, get_typestore

    log, _ = _tour(True)
    ts = get_typestore(Stores.LATEST)
    t = ts.types
    vec3 = t["geometry_msgs/msg/Vector3"]
    static = t["tf2_msgs/msg/TFMessage"](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=_header(ts, False, 0.0, "base_link"),
                child_frame_id="laser",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=vec3(x=0.0, y=0.0, z=0.3), rotation=_quaternion(ts, 0.0)
                ),
            )
        ]
    )
    messages: list[tuple[str, str, int, Any]] = [
        ("tf2_msgs/msg/TFMessage", "/tf_static", 0, static)
    ]
    for k, scan in enumerate(log.scans):
        stamp = float(log.stamps[k])
        when = round(stamp * 1e9) + 100_000_000  # received once its 0.1 s sweep is over
        if odometry:
            pose = log.odometry[k]
            assert pose is not None
            odom = _odometry(ts, False, stamp, pose.as_vector())
            messages.append(("nav_msgs/msg/Odometry", "/odom", when - 1, odom))
        msg = t["sensor_msgs/msg/LaserScan"](
            header=_header(ts, False, stamp, "laser"),
            angle_min=float(scan.angles[0]), angle_max=float(scan.angles[-1]),
            angle_increment=float(scan.angles[1] - scan.angles[0]),
            time_increment=float(scan.time_increment), scan_time=1 / RATE,
            range_min=float(scan.range_min), range_max=float(scan.max_range),
            ranges=np.asarray(scan.ranges, dtype=np.float32),
            intensities=np.zeros(0, np.float32),
        )  # fmt: skip
        messages.append(("sensor_msgs/msg/LaserScan", "/scan", when, msg))
    return write_messages(path, "mcap", ts, messages)


@pytest.mark.slow
def test_a_360_laser_bag_maps_deskewed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`scanreg map` on the bag: its scans' time_increment read, each sweep undone by the
    wheels; `scanreg odometry` on the bag without /odom runs on its own prediction."""
    pytest.importorskip("gtsam")
    from scanreg.cli import EXIT_OK, main

    _, truth = _tour(True)
    bag = _write_bag(tmp_path / "tour", odometry=True)
    out = tmp_path / "map"
    assert main(["map", str(bag), "-o", str(out), "--json", "--no-plots"]) == EXIT_OK
    result = json.loads(capsys.readouterr().out)
    assert result["self_check"]["consistent"], result["self_check"]
    tum = np.loadtxt(out / "poses_tum.txt")
    np.testing.assert_allclose(tum[:, 0], np.arange(len(truth)) / RATE, atol=1e-6)
    poses = tuple(SE2.from_vector([r[1], r[2], 2 * math.atan2(r[6], r[7])]) for r in tum)
    # Measured: 0.012 m, as from the ScanLog above (0.053 m without the beams' times).
    assert ate(poses, truth) < 0.02, ate(poses, truth)
    # No /odom: constant velocity, each scan deskewed with the last motion.
    bare = _write_bag(tmp_path / "bare", odometry=False)
    odo = tmp_path / "odo"
    assert main(["odometry", str(bare), "-o", str(odo), "--json", "--no-plots"]) == EXIT_OK
    capsys.readouterr()
    tum = np.loadtxt(odo / "poses_tum.txt")
    poses = tuple(SE2.from_vector([r[1], r[2], 2 * math.atan2(r[6], r[7])]) for r in tum)
    # Every scan has its pose. (Without odometry this tour's 1.6 rad/s corners are lost:
    # measured 2.35 m ATE; a motion of nearly a half-turn made the widened search ask for
    # more than every heading, which the correlative search refused, before its clamp.)
    assert len(poses) == len(truth)


def test_scan_log_refuses_a_scan_index_it_does_not_hold() -> None:
    log, _ = _tour(True)
    with pytest.raises(IndexError, match=rf"k: scan {len(log)} out of range for {len(log)} scans"):
        log.swept_points(len(log))
    with pytest.raises(TypeError, match="k: expected an int scan index, got float"):
        log.point_times(1.0)  # type: ignore[arg-type]
    # From the end, as a sequence's: the last scan (no next odometry: its times returned).
    points, times = log.swept_points(-1)
    np.testing.assert_array_equal(points, log.points(len(log) - 1))
    assert times is not None and times[0] == pytest.approx(log.stamps[-1])
