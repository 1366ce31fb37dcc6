"""The scan simulator against analytic geometry, known motion and stated noise.

Every assertion compares with a closed-form value (ray–primitive distance, constant-velocity
displacement, configured σ) with a stated tolerance, so each one can fail.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scanreg import SE2, SE3
from scanreg import simulate as sim


def room_laser(**kwargs: Any) -> sim.LaserModel:
    base: dict[str, Any] = {
        "num_beams": 720,
        "angle_min": -math.pi,
        "angle_increment": math.pi / 360,
        "max_range": 50.0,
        "range_sigma": 0.0,
    }
    base.update(kwargs)
    return sim.LaserModel(**base)


def box_distance_2d(origin: np.ndarray, directions: np.ndarray, half: float) -> np.ndarray:
    """Distance from a point inside the square [-half, half]² to its boundary along each ray."""
    with np.errstate(divide="ignore"):
        tx = np.where(directions[:, 0] > 0, half - origin[0], -half - origin[0]) / directions[:, 0]
        ty = np.where(directions[:, 1] > 0, half - origin[1], -half - origin[1]) / directions[:, 1]
    tx = np.where(np.isfinite(tx) & (tx > 0), tx, np.inf)
    ty = np.where(np.isfinite(ty) & (ty > 0), ty, np.inf)
    return np.minimum(tx, ty)


# --- analytic ranges ------------------------------------------------------------------------
def test_square_room_from_centre_is_half_width_over_cosine() -> None:
    scan = sim.simulate_scan(sim.square_room(4.0), room_laser(), SE2.identity())
    a = scan.angles
    expected = 4.0 / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a)))
    assert np.all(scan.status == sim.VALID)
    np.testing.assert_allclose(scan.true_ranges, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(scan.ranges, expected, rtol=0, atol=1e-9)
    # Points are ranges along the beams, in the sensor frame.
    np.testing.assert_allclose(np.hypot(*scan.points.T), expected, atol=1e-9)


def test_square_room_from_an_offset_rotated_pose() -> None:
    pose = SE2.from_vector([1.0, -0.5, 0.3])
    scan = sim.simulate_scan(sim.square_room(4.0), room_laser(), pose)
    world_dirs = np.column_stack([np.cos(scan.angles + 0.3), np.sin(scan.angles + 0.3)])
    expected = box_distance_2d(np.array([1.0, -0.5]), world_dirs, 4.0)
    np.testing.assert_allclose(scan.true_ranges, expected, atol=1e-9)
    # In the world frame every point lies on the room boundary.
    world = scan.pose.apply(scan.points)
    np.testing.assert_allclose(np.abs(world).max(axis=1), 4.0, atol=1e-9)


def test_ground_plane_at_known_height() -> None:
    lidar = sim.LidarModel.uniform(16, -15.0, 15.0, 360, 100.0, range_sigma=0.0)
    scene = sim.SceneBuilder(3).ground(0.0).build()
    sweep = sim.simulate_sweep(scene, lidar, SE3.from_vector([5.0, 2.0, 1.73, 0, 0, 0]))
    el = np.asarray(lidar.elevations)
    down = el < 0
    # Rings looking down see the ground at 1.73 / sin(-el); the others see nothing.
    assert np.all(sweep.status_image[~down] == sim.NO_RETURN)
    expected = 1.73 / np.sin(-el[down])
    np.testing.assert_allclose(
        sweep.range_image[down], expected[:, None] * np.ones((1, 360)), atol=1e-9
    )
    np.testing.assert_allclose(sweep.points[:, 2], -1.73, atol=1e-9)


def test_cylinder_box_and_sphere_ranges() -> None:
    scene = (
        sim.SceneBuilder(3)
        .cylinder(10.0, 0.0, 0.5, -5.0, 5.0)
        .box((0.0, 8.0, 0.0), (2.0, 2.0, 2.0), yaw=math.pi / 4)
        .sphere((-6.0, 0.0, 0.0), 1.5)
        .build()
    )
    lidar = sim.LidarModel((0.0,), 4, 100.0, range_sigma=0.0)  # azimuths -180°, -90°, 0°, 90°
    sweep = sim.simulate_sweep(scene, lidar, SE3.identity())
    img = sweep.range_image[0]
    assert img[0] == pytest.approx(6.0 - 1.5, abs=1e-9)  # sphere behind
    assert math.isnan(img[1])  # -90°: nothing
    assert img[2] == pytest.approx(10.0 - 0.5, abs=1e-9)  # cylinder ahead
    assert img[3] == pytest.approx(8.0 - math.sqrt(2.0), abs=1e-9)  # box corner (yaw 45°)
    assert list(sweep.primitive_index) == [2, 0, 1]


def test_moving_person_is_flagged_and_seen_where_it_is() -> None:
    # A person walking towards the sensor along -x at 1 m/s, starting 10 m ahead.
    scene = sim.SceneBuilder(2).person(10.0, 0.0, (-8.0, 0.0), speed=1.0).build()
    laser = room_laser(num_beams=3, angle_min=-0.01, angle_increment=0.01)
    traj = SE2.identity()
    first = sim.simulate_scan(scene, laser, traj, start_time=0.0)
    later = sim.simulate_scan(scene, laser, traj, start_time=2.0)
    assert first.true_ranges[1] == pytest.approx(10.0 - 0.25, abs=1e-9)
    assert later.true_ranges[1] == pytest.approx(8.0 - 0.25, abs=1e-9)
    assert first.dynamic.all()
    # It turns back at the end of its path (8 m): at t = 12 s it is 4 m back from there.
    back = sim.simulate_scan(scene, laser, traj, start_time=12.0)
    assert back.true_ranges[1] == pytest.approx(2.0 + 4.0 - 0.25, abs=1e-9)


# --- motion distortion ----------------------------------------------------------------------
def test_2d_motion_distortion_matches_constant_velocity() -> None:
    # Wall at x = 10; sensor drives at 4 m/s towards it; beam i fires at i ms.
    scene = sim.SceneBuilder(2).wall((10.0, -20.0), (10.0, 20.0)).build()
    laser = room_laser(num_beams=101, angle_min=-0.05, angle_increment=0.001, time_increment=1e-3)
    traj = sim.Trajectory.constant_velocity(SE2.identity(), [4.0, 0.0], 0.0, duration=1.0)
    scan = sim.simulate_scan(scene, laser, traj)
    t = scan.timestamps
    expected = (10.0 - 4.0 * t) / np.cos(scan.angles)
    np.testing.assert_allclose(scan.ranges, expected, atol=1e-9)
    # The raw points are distorted (x = 10 - v t); deskewed to the start frame they are not.
    np.testing.assert_allclose(scan.points[:, 0], 10.0 - 4.0 * t, atol=1e-9)
    np.testing.assert_allclose(scan.points_deskewed[:, 0], 10.0, atol=1e-9)


def test_3d_motion_distortion_and_reference_time() -> None:
    scene = sim.SceneBuilder(3).wall((20.0, -50.0), (20.0, 50.0), -10.0, 10.0).build()
    lidar = sim.LidarModel((0.0,), 360, 100.0, rotation_rate=10.0, range_sigma=0.0)
    v, w = 15.0, 0.4
    traj = sim.Trajectory.constant_velocity(SE3.identity(), [v, 0, 0], [0, 0, w], duration=1.0)
    sweep = sim.simulate_sweep(scene, lidar, traj, start_time=0.2)
    assert sweep.timestamps.min() >= 0.2 and sweep.timestamps.max() < 0.3
    # The column looking straight ahead (azimuth 0, index 180) fires at t = 0.25.
    ahead = np.flatnonzero(sweep.columns == 180)[0]
    pose = traj.pose_at(0.25)
    heading = pose.rotation[:, 0]
    expected = (20.0 - pose.translation[0]) / heading[0]
    assert sweep.ranges[ahead] == pytest.approx(expected, abs=1e-9)
    # Every point, moved to the world with its own firing pose, lies on the wall.
    world = np.array(
        [
            traj.pose_at(t).apply(p[None])[0]
            for t, p in zip(sweep.timestamps, sweep.points, strict=True)
        ]
    )
    np.testing.assert_allclose(world[:, 0], 20.0, atol=1e-9)
    # Deskewed points agree with the reference pose, whichever reference is chosen.
    np.testing.assert_allclose(sweep.pose.apply(sweep.points_deskewed)[:, 0], 20.0, atol=1e-9)
    end = sim.simulate_sweep(scene, lidar, traj, start_time=0.2, reference="end")
    assert end.reference_time == pytest.approx(0.3)
    assert end.pose.is_close(traj.pose_at(0.3), atol=1e-12)
    np.testing.assert_allclose(
        end.pose.apply(end.points_deskewed), sweep.pose.apply(sweep.points_deskewed), atol=1e-9
    )
    np.testing.assert_allclose(end.points, sweep.points, atol=0)


# --- trajectories ---------------------------------------------------------------------------
def test_constant_yaw_rate_is_an_exact_arc() -> None:
    v, w = 2.0, 0.25
    traj = sim.Trajectory.from_speed_and_yaw_rate(v, w, duration=10.0)
    for t in (0.0, 1.0, 3.7, 10.0):
        x, y, th = traj.pose_at(t).as_vector()
        r = v / w
        assert x == pytest.approx(r * math.sin(w * t), abs=1e-12)
        assert y == pytest.approx(r * (1 - math.cos(w * t)), abs=1e-12)
        assert th == pytest.approx(w * t, abs=1e-12)


def test_weaving_trajectory_is_continuous_and_keeps_speed() -> None:
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        5.0, 0.0, duration=6.0, dim=3, yaw_rate_amplitude=0.3, yaw_rate_period=4.0, step=0.05
    )
    assert len(traj.knot_poses) == 120
    ts = np.linspace(0.0, 6.0, 601)
    pos = np.array([p.translation for p in traj.poses_at(ts)])
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    # Chords of arcs of length 0.05 m: within 1e-6 of the arc length.
    np.testing.assert_allclose(step, 5.0 * 0.01, atol=1e-6)
    assert np.ptp(pos[:, 1]) > 0.5  # it does weave
    np.testing.assert_allclose(pos[:, 2], 0.0, atol=1e-12)


# --- reproducibility ------------------------------------------------------------------------
def test_same_seed_same_output_different_seed_different() -> None:
    laser = sim.LaserModel.preset("sick_lms200")
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        1.0, 0.1, duration=3.0, start=SE2.from_vector([1.0, 0.0, 0.0])
    )
    a = sim.simulate_run(sim.floor_plan(seed=3), laser, traj, num_scans=3, seed=7)
    b = sim.simulate_run(sim.floor_plan(seed=3), laser, traj, num_scans=3, seed=7)
    c = sim.simulate_run(sim.floor_plan(seed=3), laser, traj, num_scans=3, seed=8)
    for x, y, z in zip(a.scans, b.scans, c.scans, strict=True):
        assert np.array_equal(x.ranges, y.ranges) and np.array_equal(x.status, y.status)
        assert not np.array_equal(x.ranges, z.ranges)
    # Scans of a run differ from each other (independent noise, moving sensor).
    assert not np.array_equal(a.scans[0].ranges, a.scans[1].ranges)
    # Scene generators: same seed same scene, different seed different scene.
    assert np.array_equal(sim.street(seed=1).primitives, sim.street(seed=1).primitives)
    assert not np.array_equal(sim.floor_plan(seed=1).primitives, sim.floor_plan(seed=2).primitives)


# --- noise, dropouts, limits ----------------------------------------------------------------
def test_range_noise_matches_sigma() -> None:
    sigma = 0.05
    laser = room_laser(range_sigma=sigma)
    errors = np.concatenate(
        [
            (s.ranges - s.true_ranges)[s.valid]
            for s in (
                sim.simulate_scan(sim.square_room(5.0), laser, SE2.identity(), seed=1, scan_index=k)
                for k in range(10)
            )
        ]
    )
    n = errors.size
    assert n == 7200
    # Relative standard error of a sample std is 1/sqrt(2n) = 0.83 %: allow 4 % (~5 SE).
    assert abs(errors.std(ddof=1) / sigma - 1.0) < 0.04
    # Mean: standard error σ/sqrt(n) = 0.0006 m; allow 5 SE.
    assert abs(errors.mean()) < 5 * sigma / math.sqrt(n)
    # Gaussian: about 4.55 % beyond 2σ (binomial SE 0.25 %).
    assert abs(np.mean(np.abs(errors) > 2 * sigma) - 0.0455) < 0.0125


def test_dropouts_max_range_and_too_close() -> None:
    half = 5.0
    laser = room_laser(max_range=6.0, min_range=0.5, dropout_probability=0.2)
    scans = [
        sim.simulate_scan(sim.square_room(half), laser, SE2.identity(), scan_index=k)
        for k in range(5)
    ]
    status = np.concatenate([s.status for s in scans])
    true = np.concatenate([s.true_ranges for s in scans])
    ranges = np.concatenate([s.ranges for s in scans])
    # Beyond max range (the corners at up to 7.07 m): no return, logged as max_range.
    far = ~np.isfinite(true)
    assert far.sum() > 0
    assert np.all(status[far] == sim.NO_RETURN) and np.all(ranges[far] == 6.0)
    in_range = ~far
    dropped = status[in_range] == sim.DROPOUT
    # Binomial: p = 0.2 over ~2900 beams, SE 0.0074; allow 5 SE.
    assert abs(dropped.mean() - 0.2) < 0.037
    assert np.all(ranges[in_range][dropped] == 0.0)
    # Too close: the sensor next to a wall.
    near = sim.simulate_scan(sim.square_room(half), laser, SE2.from_vector([4.7, 0.0, 0.0]))
    assert near.status[near.angles.size // 2] == sim.TOO_CLOSE  # beam at 0 rad: wall 0.3 m away
    assert near.ranges[near.angles.size // 2] == 0.0
    assert near.points.shape[0] == np.count_nonzero(near.valid)


# --- presets, street, tunnel ----------------------------------------------------------------
def test_presets() -> None:
    carmen = sim.LaserModel.preset("sick_lms200")
    assert carmen.num_beams == 180 and carmen.max_range == 80.0
    assert carmen.angle_increment == pytest.approx(math.radians(1.0))
    assert sim.LaserModel.preset("laser_360").field_of_view > math.radians(359)
    rings = {name: sim.LidarModel.preset(name).num_rings for name in ("hdl64", "hdl32", "vlp16")}
    assert rings == {"hdl64": 64, "hdl32": 32, "vlp16": 16}
    assert sim.LidarModel.preset("hdl64").num_beams == 115_200
    with pytest.raises(ValueError, match="name: unknown LiDAR preset 'hdl128'"):
        sim.LidarModel.preset("hdl128")


def test_street_sweep_has_about_100k_points_and_consistent_labels() -> None:
    scene = sim.street(seed=0)
    lidar = sim.LidarModel.preset("hdl64")
    start = SE3.from_vector([0.0, 1.75, 1.73, 0, 0, 0])
    traj = sim.Trajectory.from_speed_and_yaw_rate(10.0, 0.0, duration=1.0, dim=3, start=start)
    sweep = sim.simulate_sweep(scene, lidar, traj, seed=0)
    assert 80_000 < sweep.num_points <= 115_200
    labels = {scene.labels[i] for i in np.unique(sweep.primitive_index)}
    assert {"ground", "facade", "pole", "car", "vegetation"} <= labels
    rel = sweep.relative_timestamps
    assert rel.min() >= 0.0 and rel.max() < 1.0
    np.testing.assert_allclose(sweep.timestamps, sweep.columns * (0.1 / 1800), atol=1e-12)
    # Ranges are consistent with the points (the points lie along their beams).
    np.testing.assert_allclose(np.linalg.norm(sweep.points, axis=1), sweep.ranges, atol=1e-9)


def test_tunnel_is_closed_around_the_sensor() -> None:
    scene = sim.tunnel(length=400.0, width=10.0, height=6.0)
    sweep = sim.simulate_sweep(
        scene, sim.LidarModel.preset("vlp16"), SE3.from_vector([0, 0, 1.5, 0, 0, 0])
    )
    world = sweep.pose.apply(sweep.points_deskewed)
    on_wall = np.isclose(np.abs(world[:, 1]), 5.0, atol=0.2)
    on_floor_or_ceiling = np.isclose(world[:, 2], 0.0, atol=0.2) | np.isclose(
        world[:, 2], 6.0, atol=0.2
    )
    assert np.all(on_wall | on_floor_or_ceiling)
    assert on_wall.sum() > 1000 and (world[:, 2] > 5.8).sum() > 1000  # walls and ceiling seen


# --- hostile input --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("build", "exc", "message"),
    [
        (lambda: room_laser(num_beams=-3), ValueError, "num_beams: must be >= 1"),
        (lambda: room_laser(num_beams=True), TypeError, "num_beams"),
        (lambda: room_laser(num_beams=10.0), TypeError, "num_beams"),
        (lambda: room_laser(max_range=float("nan")), ValueError, "max_range: must be finite"),
        (lambda: room_laser(min_range=60.0), ValueError, "min_range: must be < max_range"),
        (lambda: room_laser(range_sigma=-0.1), ValueError, "range_sigma: must be >= 0"),
        (lambda: room_laser(dropout_probability=1.5), ValueError, "dropout_probability"),
        (
            lambda: room_laser(angle_increment=0.1),
            ValueError,
            "angle_increment: .* exceed a full turn",
        ),
        (lambda: sim.LidarModel((), 100, 50.0), ValueError, "elevations"),
        (lambda: sim.LidarModel((0.0,), 0, 50.0), ValueError, "num_columns: must be >= 1"),
        (lambda: sim.LidarModel.uniform(0, -10, 10, 100, 50.0), ValueError, "num_rings"),
        (lambda: sim.LidarModel((0.0,), 10, 50.0, rotation_rate=0.0), ValueError, "rotation_rate"),
        (lambda: sim.LidarModel((2.0,), 10, 50.0), ValueError, "elevations: must be in"),
        (
            lambda: sim.Trajectory.from_speed_and_yaw_rate(float("nan"), 0.0, duration=1.0),
            ValueError,
            "speed: must be finite",
        ),
        (
            lambda: sim.Trajectory.from_speed_and_yaw_rate(1.0, 0.0, duration=-1.0),
            ValueError,
            "duration: must be > 0",
        ),
        (lambda: sim.floor_plan(seed=-1), ValueError, "seed: must be >= 0"),
        (lambda: sim.square_room(0.0), ValueError, "half_width: must be > 0"),
        (lambda: sim.SceneBuilder(2).circle(0.0, 0.0, -1.0), ValueError, "radius: must be > 0"),
        (lambda: sim.SceneBuilder(3).wall((0, 0), (0, 0)), ValueError, "zero length"),
        (lambda: sim.SceneBuilder(3).ground().moving((1.0, 0.0), 1.0), ValueError, "moving"),
    ],
)
def test_hostile_construction_is_refused(build: Any, exc: type[Exception], message: str) -> None:
    with pytest.raises(exc, match=message):
        build()


def test_hostile_simulation_calls_are_refused() -> None:
    room, laser = sim.square_room(3.0), room_laser()
    lidar = sim.LidarModel((0.0,), 8, 50.0)
    with pytest.raises(ValueError, match="scene: a 3D sensor needs a 3D scene"):
        sim.simulate_sweep(room, lidar, SE3.identity())
    with pytest.raises(TypeError, match="trajectory: expected a Trajectory or SE2"):
        sim.simulate_scan(room, laser, SE3.identity())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="reference: expected"):
        sim.simulate_scan(room, laser, SE2.identity(), reference="later")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="start_time: must be finite"):
        sim.simulate_scan(room, laser, SE2.identity(), start_time=float("inf"))
    with pytest.raises(ValueError, match="seed: must be >= 0"):
        sim.simulate_scan(room, laser, SE2.identity(), seed=-5)
    with pytest.raises(ValueError, match="num_scans: must be >= 1"):
        traj = sim.Trajectory.stationary(SE2.identity())
        sim.simulate_run(room, laser, traj, num_scans=0)
    with pytest.raises(ValueError, match="scan_rate: must be > 0"):
        sim.simulate_run(
            room, laser, sim.Trajectory.stationary(SE2.identity()), num_scans=2, scan_rate=-1.0
        )
    with pytest.raises(TypeError, match="scan_rate: expected a real number"):
        sim.simulate_run(
            room, laser, sim.Trajectory.stationary(SE2.identity()), num_scans=2, scan_rate="fast"
        )  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="laser: expected a LaserModel"):
        sim.simulate_scan(room, lidar, SE2.identity())  # type: ignore[arg-type]


def test_native_caster_refuses_bad_tables() -> None:
    from scanreg import _core

    eye = np.eye(4).reshape(1, 16)
    kwargs: dict[str, Any] = {
        "start_time": 0.0,
        "knot_times": np.array([0.0, 1.0]),
        "knot_poses": eye,
        "twists": np.zeros((1, 6)),
        "reference_time": 0.0,
        "min_range": 0.0,
        "max_range": 10.0,
        "range_sigma": 0.0,
        "dropout_probability": 0.0,
        "seed": 0,
    }
    dirs, times = np.array([[1.0, 0.0, 0.0]]), np.zeros(1)
    bad = np.zeros((1, _core.SIMULATE_PRIMITIVE_COLUMNS))
    bad[0, 0] = 7.0
    with pytest.raises(ValueError, match="primitives: row 0: unknown kind 7"):
        _core.cast_rays(bad, dirs, times, **kwargs)
    with pytest.raises(ValueError, match=r"primitives: expected shape \(N, 11\)"):
        _core.cast_rays(np.zeros((1, 5)), dirs, times, **kwargs)
    with pytest.raises(ValueError, match="directions: direction 0 is not a finite unit vector"):
        _core.cast_rays(np.zeros((0, 11)), np.array([[np.nan, 0.0, 0.0]]), times, **kwargs)
    with pytest.raises(ValueError, match="knot_times: must be strictly increasing"):
        _core.cast_rays(
            np.zeros((0, 11)), dirs, times, **{**kwargs, "knot_times": np.array([1.0, 0.0])}
        )
    with pytest.raises(ValueError, match="directions: array is not C-contiguous"):
        _core.cast_rays(np.zeros((0, 11)), np.asfortranarray(np.eye(3)), np.zeros(3), **kwargs)


def test_demo_simulated_section_reports_consistent_statistics() -> None:
    from scanreg.demo import simulated_runs

    office, street = simulated_runs(seed=0)
    assert office.num_scans == 20 and street.num_scans == 5
    # 20 scans x ~180 returns (σ = 0.01): std within 10 %; 5 x ~114k (σ = 0.02): within 2 %.
    assert abs(office.range_error_std / 0.01 - 1) < 0.1
    assert abs(street.range_error_std / 0.02 - 1) < 0.02
    assert office.dynamic_fraction > 0 and street.max_distortion > 0.5
    assert dict(street.hits_by_label)["ground"] > 0


def test_the_cli_offers_every_laser_preset() -> None:
    from scanreg.pipeline.commands import SENSORS_2D

    assert tuple(sim.LASER_PRESETS) == SENSORS_2D
    laser = sim.LaserModel.preset("laser_361")
    assert laser.num_beams == 361 and laser.field_of_view == pytest.approx(math.pi)
    assert laser.scan_duration == pytest.approx(0.0267)
