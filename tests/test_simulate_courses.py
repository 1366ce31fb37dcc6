"""Courses that come back to places already seen: closure of the loop, overlap at the revisit,
scenes whose repeated parts really are repeated, determinism from the seed.

Sensors are kept small (16 rings × 360 columns; a 720-beam laser) so the file runs in seconds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg._core import KdTree

LIDAR = sim.LidarModel.uniform(16, -15.0, 15.0, 360, 100.0, range_sigma=0.02)
LASER = sim.LaserModel.preset("laser_360")


def near_fraction(reference: np.ndarray, query: np.ndarray, radius: float) -> float:
    """Fraction of ``query`` points within ``radius`` of a ``reference`` point."""
    _, sq = KdTree(np.ascontiguousarray(reference)).nearest(np.ascontiguousarray(query))
    return float(np.mean(np.sqrt(sq) < radius))


# --- 3D block loop --------------------------------------------------------------------------
def test_block_loop_closes_every_lap_and_has_the_stated_length() -> None:
    course = sim.block_loop(seed=0, lap_length=300.0, laps=2, speed=10.0)
    start = course.trajectory.pose_at(0.0)
    lap = float(course.pass_start_times[1])
    assert lap == pytest.approx(30.0, abs=1e-9)
    assert course.length == pytest.approx(600.0, abs=1e-9)
    assert course.num_scans(10.0) == 600
    for t in (lap, course.trajectory.end_time):
        err = (start.inverse() @ course.trajectory.pose_at(t)).as_vector()
        assert np.abs(err[:3]).max() < 1e-9  # metres
        assert np.abs(err[3:]).max() < 1e-12  # radians
    # Flat, at sensor height, constant speed, and inside the scene's road (no façade hit).
    times = np.arange(0.0, lap, 0.1)
    xyz = np.array([p.translation for p in course.trajectory.poses_at(times)])
    np.testing.assert_allclose(xyz[:, 2], 1.73, atol=1e-12)
    np.testing.assert_allclose(np.hypot(*np.diff(xyz[:, :2], axis=0).T), 1.0, atol=1e-3)


@pytest.mark.parametrize("seed", range(4))
def test_the_smallest_block_still_has_its_pedestrians(seed: int) -> None:
    """A 120 m lap leaves straights of ~7.6 m, shorter than a pedestrian's 15 m walk (this
    raised numpy's "high - low < 0" before): they walk the whole straight instead."""
    course = sim.block_loop(seed=seed, lap_length=120.0, num_pedestrians=6)
    assert course.scene.labels.count("person") == 6
    end = course.trajectory.pose_at(course.trajectory.end_time)
    err = (course.trajectory.pose_at(0.0).inverse() @ end).as_vector()
    assert np.abs(err).max() < 1e-9


def test_block_loop_yaw_rate_ramps_into_corners() -> None:
    course = sim.block_loop(seed=0, transition=0.5)
    rates = course.trajectory.twists[:, 5]
    # No jump in yaw rate larger than one ramp step (an eighth of the corner's rate).
    assert np.abs(np.diff(rates)).max() <= rates.max() / 8 + 1e-12
    plain = sim.block_loop(seed=0, transition=0.0)
    assert np.abs(np.diff(plain.trajectory.twists[:, 5])).max() > 0.5


def test_second_lap_sweeps_overlap_the_first_lap() -> None:
    course = sim.block_loop(seed=0)
    lap = float(course.pass_start_times[1])
    for t in (3.0, 21.0):
        first = sim.simulate_sweep(course.scene, LIDAR, course.trajectory, start_time=t)
        again = sim.simulate_sweep(
            course.scene, LIDAR, course.trajectory, start_time=t + lap + 0.03, scan_index=1
        )
        dist = np.linalg.norm(first.pose.translation - again.pose.translation)
        assert dist == pytest.approx(0.3, abs=1e-9)
        world_first = first.pose.apply(first.points_deskewed)
        world_again = again.pose.apply(again.points_deskewed)
        # measured 0.98; sparse far returns 0.3 m apart miss their counterpart
        assert near_fraction(world_first, world_again, 0.45) > 0.95


def test_revisits_pairs_are_a_lap_apart() -> None:
    course = sim.block_loop(seed=0)
    times = np.arange(0.0, 60.0, 1.0)
    pairs = course.revisits(times, radius=3.0, min_time_gap=20.0)
    assert pairs == [(i, i + 30) for i in range(30)]


def _twin_sweeps(course: sim.Course) -> tuple[sim.LidarSweep, sim.LidarSweep]:
    lidar = sim.LidarModel.uniform(16, -15.0, 15.0, 360, 100.0, range_sigma=0.0)
    pose = course.trajectory.pose_at(2.0)
    assert isinstance(pose, SE3)
    quarter = SE3.from_vector([0.0, 0.0, 0.0, 0.0, 0.0, math.pi / 2])
    return (
        sim.simulate_sweep(course.scene, lidar, pose),
        sim.simulate_sweep(course.scene, lidar, quarter @ pose),
    )


def test_symmetric_block_gives_the_same_sweep_a_quarter_turn_away() -> None:
    kwargs = {"lap_length": 250.0, "aspect": 1.0, "num_pedestrians": 0, "num_moving_cars": 0}
    course = sim.block_loop(seed=1, symmetry=4, **kwargs)  # type: ignore[arg-type]
    assert len(course.repeated_frames) == 4
    a, b = _twin_sweeps(course)
    np.testing.assert_array_equal(a.status_image, b.status_image)
    both = np.isfinite(a.range_image)
    assert both.mean() > 0.9
    np.testing.assert_allclose(a.range_image[both], b.range_image[both], atol=1e-6)
    # The same drive around an ordinary block: a quarter-turn away is another place.
    plain = sim.block_loop(seed=1, **kwargs)  # type: ignore[arg-type]
    assert plain.repeated_frames == ()
    a, b = _twin_sweeps(plain)
    both = np.isfinite(a.range_image) & np.isfinite(b.range_image)
    assert np.mean(np.abs(a.range_image - b.range_image)[both] < 0.05) < 0.6  # measured 0.30


def test_half_turn_symmetry_and_its_argument_checks() -> None:
    course = sim.block_loop(seed=3, symmetry=2, num_pedestrians=0, num_moving_cars=0)
    rows = course.scene.primitives
    spheres = rows[rows[:, 0] == 3.0][:, 1:4]
    turned = spheres * np.array([-1.0, -1.0, 1.0])  # a half-turn about the z axis
    gap = np.linalg.norm(turned[:, None, :] - spheres[None, :, :], axis=2).min(axis=1)
    assert gap.max() < 1e-9
    with pytest.raises(ValueError, match="aspect: symmetry=4 needs a square block"):
        sim.block_loop(symmetry=4, aspect=0.5)
    with pytest.raises(ValueError, match="symmetry: must be 1, 2 or 4"):
        sim.block_loop(symmetry=3)
    with pytest.raises(ValueError, match=r"lap_length: 100\.0 m leaves no straights"):
        sim.block_loop(lap_length=100.0)
    with pytest.raises(ValueError, match="corner_radius: must exceed road_half_width"):
        sim.block_loop(corner_radius=5.0)


def test_block_loop_is_reproducible_from_its_seed() -> None:
    a, b, c = sim.block_loop(seed=5), sim.block_loop(seed=5), sim.block_loop(seed=6)
    np.testing.assert_array_equal(a.scene.primitives, b.scene.primitives)
    np.testing.assert_array_equal(a.trajectory.twists, b.trajectory.twists)
    assert a.scene.primitives.shape != c.scene.primitives.shape or not np.array_equal(
        a.scene.primitives, c.scene.primitives
    )
    sa = sim.simulate_sweep(a.scene, LIDAR, a.trajectory, start_time=1.0, seed=2)
    sb = sim.simulate_sweep(b.scene, LIDAR, b.trajectory, start_time=1.0, seed=2)
    np.testing.assert_array_equal(sa.points, sb.points)


# --- 2D room tour ---------------------------------------------------------------------------
def test_room_tour_returns_to_its_start_through_the_same_rooms() -> None:
    course = sim.room_tour(seed=0)
    start, end = course.trajectory.pose_at(0.0), course.trajectory.end_pose()
    err = (start.inverse() @ end).as_vector()
    assert np.abs(err).max() < 1e-9
    t_return = float(course.pass_start_times[1])
    times = np.arange(0.0, course.duration, 0.25)
    pairs = course.revisits(times, radius=0.3, min_time_gap=20.0)
    # Every room is revisited: some outbound place inside it is within 0.3 m of a return one.
    frames = [SE2.from_vector([i * 6.0, 1.2, 0.0]) for i in range(4)]
    frames += [SE2.from_vector([(i + 1) * 6.0, -1.2, math.pi]) for i in range(4)]
    xy = np.array([course.trajectory.pose_at(times[i]).translation for i, _ in pairs])
    for f in frames:
        local = f.inverse().apply(xy)
        inside = (local[:, 0] > 0) & (local[:, 0] < 6.0) & (local[:, 1] > 0.5)
        assert inside.any()
    assert all(times[i] < t_return <= times[j] for i, j in pairs)
    # ... and the scans there overlap.
    i, j = pairs[len(pairs) // 3]
    first = sim.simulate_scan(course.scene, LASER, course.trajectory, start_time=times[i])
    again = sim.simulate_scan(
        course.scene, LASER, course.trajectory, start_time=times[j], scan_index=1
    )
    overlap = near_fraction(
        first.pose.apply(first.points_deskewed), again.pose.apply(again.points_deskewed), 0.1
    )
    assert overlap > 0.9


def test_identical_rooms_give_near_identical_scans() -> None:
    spot = SE2.from_vector([3.0, 1.5, 0.3])  # in a room's frame

    def agreement(course: sim.Course, frames: tuple[SE2, ...]) -> float:
        a = sim.simulate_scan(course.scene, LASER, frames[1] @ spot)
        b = sim.simulate_scan(course.scene, LASER, frames[6] @ spot)  # across the corridor
        return float(np.mean(np.abs(a.ranges - b.ranges) < 0.1))

    twins = sim.room_tour(seed=0, identical_rooms=True)
    frames = twins.repeated_frames
    assert len(frames) == 8 and all(isinstance(f, SE2) for f in frames)
    assert agreement(twins, frames) > 0.98  # type: ignore[arg-type]  # measured 1.0
    plain = sim.room_tour(seed=0)
    assert agreement(plain, frames) < 0.8  # type: ignore[arg-type]  # measured 0.6


def test_room_tour_checks_its_arguments() -> None:
    with pytest.raises(ValueError, match="visit: room 8 does not exist"):
        sim.room_tour(visit=(0, 8))
    with pytest.raises(ValueError, match=r"room_depth: must be >= 4\.0"):
        sim.room_tour(room_depth=3.0)
    one = sim.room_tour(seed=0, visit=(2,))
    assert one.length < sim.room_tour(seed=0).length
    # Reproducible from the seed, different across seeds.
    a, b, c = sim.room_tour(seed=7), sim.room_tour(seed=7), sim.room_tour(seed=8)
    np.testing.assert_array_equal(a.scene.primitives, b.scene.primitives)
    np.testing.assert_array_equal(a.trajectory.knot_times, b.trajectory.knot_times)
    assert not np.array_equal(a.trajectory.knot_times, c.trajectory.knot_times)


def test_ring_corridor_is_one_lap_closed_at_its_start_and_checks_its_arguments() -> None:
    course = sim.ring_corridor(seed=0, overlap=10.0)
    # One lap of the 40 x 24 m ring's centreline (corners cut by 0.8 m arcs) and 10 m more.
    lap = 2 * (40.0 - 2.4 + 24.0 - 2.4) - 4 * 0.8 * (2 - math.pi / 2) + 10.0
    assert course.length == pytest.approx(lap, abs=1e-9)
    back = course.trajectory.pose_at(float(course.pass_start_times[1]))
    np.testing.assert_allclose(back.as_vector(), [20.0, 1.2, 0.0], atol=1e-9)
    # The only revisits are the last 10 m over the first ones, a lap apart.
    times = np.arange(0.0, course.duration, 1.0)
    pairs = course.revisits(times, radius=0.5, min_time_gap=20.0)
    assert pairs and all(times[i] < 17.0 and times[j] > 190.0 for i, j in pairs)
    # The corridor is 2.4 m wide wherever the robot drives: nothing stands in it.
    scan = sim.simulate_scan(course.scene, LASER, course.trajectory, start_time=100.0)
    assert np.hypot(*scan.points.T).min() > 1.1
    with pytest.raises(ValueError, match="width, depth: the inner block needs >= 4 m"):
        sim.ring_corridor(depth=8.0)
    with pytest.raises(ValueError, match=r"overlap: must be <= 17\.6"):
        sim.ring_corridor(overlap=20.0)
    a, b = sim.ring_corridor(seed=3), sim.ring_corridor(seed=4)
    assert not np.array_equal(a.scene.primitives, b.scene.primitives)


# --- trajectory through waypoints -----------------------------------------------------------
def test_through_waypoints_is_exact_at_the_ends_and_smooth() -> None:
    points = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [4.0, 0.5]])
    traj = sim.Trajectory.through_waypoints(points, speed=1.0, turn_radius=0.5, final_heading=0.0)
    end = traj.end_pose()
    assert isinstance(end, SE2)
    np.testing.assert_allclose(end.as_vector(), [4.0, 0.5, 0.0], atol=1e-12)
    # The 90° corner is an arc of 0.5 m: the path passes r(√2 − 1) inside the corner point.
    times = np.linspace(0.0, traj.end_time, 20001)
    xy = np.array([p.translation for p in traj.poses_at(times)])
    assert np.hypot(*(xy - [4.0, 0.0]).T).min() == pytest.approx(0.5 * (math.sqrt(2) - 1), abs=1e-3)
    # The U-turn at (4, 3) is made on the spot: there the twist has no translation.
    spins = traj.twists[traj.twists[:, 0] == 0]
    assert spins.shape[0] == 2 and np.all(np.abs(spins[:, 2]) == pytest.approx(0.8))
    # Position continuous (speed bounded by 1 m/s between samples).
    step = np.hypot(*np.diff(xy, axis=0).T) / np.diff(times)
    assert step.max() < 1.0 + 1e-6


def test_through_waypoints_refuses_bad_input() -> None:
    with pytest.raises(ValueError, match="waypoints: points 1 and 2 coincide"):
        sim.Trajectory.through_waypoints([[0, 0], [1, 0], [1, 0]])
    with pytest.raises(ValueError, match="waypoints: contains NaN"):
        sim.Trajectory.through_waypoints([[0, 0], [np.nan, 0]])
    with pytest.raises(ValueError, match=r"waypoints: expected shape \(K, 2\)"):
        sim.Trajectory.through_waypoints([[0, 0]])
    with pytest.raises(ValueError, match="speed: must be > 0"):
        sim.Trajectory.through_waypoints([[0, 0], [1, 0]], speed=0.0)


# --- as a sequence ---------------------------------------------------------------------------
def test_loop_sequences_open_from_a_sim_spec() -> None:
    from scanreg.io import open_sequence
    from scanreg.io.sequences import SimulatedSequence

    seq = open_sequence("sim:loop,lap_length=250,laps=2")
    assert isinstance(seq, SimulatedSequence) and seq.course is not None
    assert len(seq) == 500  # the whole 500 m drive at 10 m/s, 10 sweeps a second
    # Truth relative to the first sweep: a lap later the sensor is back at the identity.
    np.testing.assert_allclose(seq.ground_truth[250], np.eye(4), atol=1e-9)
    assert seq.course.revisits(seq.stamps[::50], radius=1.0, min_time_gap=20.0) == [
        (i, i + 5) for i in range(5)
    ]
    trap = open_sequence("sim:loop-repeated,frames=2")
    assert isinstance(trap, SimulatedSequence) and trap.course is not None
    assert len(trap) == 2 and len(trap.course.repeated_frames) == 4
    assert trap[1].points.shape[1] == 3
    with pytest.raises(ValueError, match="ramp, weave: not supported on sim:loop"):
        open_sequence("sim:loop,ramp=2")


def test_wheel_odometry_draws_the_stated_noise_and_refuses_non_poses() -> None:
    """Increments of a straight 1 m step: the along / across / heading spreads are 5 cm,
    2 cm and 1°/m + 1e-4 rad (+ the 1 mm floors), within sampling error."""
    wheel_odometry = sim.wheel_odometry
    truth = [SE2.from_vector([float(k), 0.0, 0.0]) for k in range(4001)]
    steps = wheel_odometry(truth, 3)
    assert steps[0] is None and len(steps) == len(truth)
    v = np.array([s.log() for s in steps[1:] if s is not None])
    expected = [0.051, 0.021, math.radians(1.0) + 1e-4]
    assert np.std(v, axis=0) == pytest.approx(expected, rel=0.05)
    assert np.mean(v[:, 0]) == pytest.approx(1.0, abs=0.005)
    assert wheel_odometry(truth[:5], 3) == wheel_odometry(truth[:5], np.random.default_rng(3))
    with pytest.raises(TypeError, match="truth: expected a sequence of SE2"):
        wheel_odometry([np.eye(3)], 0)  # type: ignore[list-item]
