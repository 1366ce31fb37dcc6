"""Simulated scans: ray casting (in the Rust core) of a sensor model in a scene along a
trajectory.

Frames and times
----------------
* Each beam fires at its own timestamp from the sensor pose at that instant
  (``trajectory.pose_at(t)``): when the sensor moves during a scan, the scan is
  motion-distorted, exactly as a real driver's output.
* ``points`` are what a driver reports: each point in the sensor frame **at its own
  timestamp**, stacked as if they shared one frame.
* ``points_deskewed`` are the same measurements expressed in the sensor frame at the
  ``reference_time`` using the true motion (a perfect deskew).
* ``pose`` is ``T_world_sensor`` at ``reference_time``: the sweep start by default
  (``reference="start"``), or its middle/end. With it, ``pose.apply(points_deskewed)`` are the
  world coordinates of the measured points.
* Noise: each beam's range error is Gaussian with the model's ``range_sigma`` along the beam;
  a beam that hits a surface in range is dropped with ``dropout_probability``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .. import _core
from .._validate import FloatArray
from ..transform import SE2, SE3
from ._checks import count, finite, positive
from ._checks import seed as check_seed
from .scene import Scene
from .sensors import LaserModel, LidarModel
from .trajectory import Trajectory

#: Beam status codes (``status`` arrays).
VALID, NO_RETURN, DROPOUT, TOO_CLOSE = 0, 1, 2, 3

Reference = Literal["start", "middle", "end"]
IntArray = Any  # NDArray of an integer dtype


def _frozen(a: Any) -> Any:
    out = np.ascontiguousarray(a)
    out.setflags(write=False)
    return out


def _noise_seed(seed: int, scan_index: int) -> int:
    """A 64-bit key per (seed, scan): scans of a run are independent and reproducible."""
    state = np.random.SeedSequence(seed, spawn_key=(scan_index,)).generate_state(2, np.uint32)
    return int(state[0]) | (int(state[1]) << 32)


@dataclass(frozen=True, eq=False)
class LaserScan:
    """One simulated 2D scan (LaserScan-like; see the module docs for frames and times)."""

    #: ``(B,)`` beam angles in the sensor frame (rad).
    angles: FloatArray
    #: ``(B,)`` ranges as a log records them: the measurement for valid beams, ``max_range``
    #: for no return (as the CARMEN logs do), 0.0 for dropouts and too-close readings.
    ranges: FloatArray
    #: ``(B,)`` uint8 codes: ``VALID``, ``NO_RETURN``, ``DROPOUT``, ``TOO_CLOSE``.
    status: IntArray
    #: ``(B,)`` firing time of each beam (s).
    timestamps: FloatArray
    #: ``(B,)`` exact distance to the first surface; ``inf`` if none within ``max_range``.
    true_ranges: FloatArray
    #: ``(B,)`` row of the scene primitive hit, -1 for none.
    primitive_index: IntArray
    #: ``(B,)`` whether the beam hit a moving object (a dynamic outlier).
    dynamic: IntArray
    #: ``(M, 2)`` valid returns, each in the sensor frame at its own timestamp.
    points: FloatArray
    #: ``(M, 2)`` the same, in the sensor frame at ``reference_time`` (true motion).
    points_deskewed: FloatArray
    #: ``(M,)`` beam index of each point.
    point_beams: IntArray
    #: ``T_world_sensor`` at ``reference_time``.
    pose: SE2
    start_time: float
    reference_time: float
    max_range: float

    @property
    def valid(self) -> IntArray:
        """``(B,)`` bool mask of valid beams."""
        return self.status == VALID


@dataclass(frozen=True, eq=False)
class LidarSweep:
    """One simulated sweep of a spinning LiDAR (see the module docs for frames and times).

    Per-point arrays hold the valid returns only, in firing order (column by column, ring 0
    first within a column); the ``(rings, columns)`` images hold every beam.
    """

    #: ``(M, 3)`` points, each in the sensor frame at its own timestamp (motion-distorted).
    points: FloatArray
    #: ``(M, 3)`` the same, in the sensor frame at ``reference_time`` (true motion).
    points_deskewed: FloatArray
    #: ``(M,)`` firing time of each point (s).
    timestamps: FloatArray
    #: ``(M,)`` ring (laser) index.
    rings: IntArray
    #: ``(M,)`` column (azimuth step) index.
    columns: IntArray
    #: ``(M,)`` measured ranges.
    ranges: FloatArray
    #: ``(M,)`` exact ranges.
    true_ranges: FloatArray
    #: ``(M,)`` row of the scene primitive hit.
    primitive_index: IntArray
    #: ``(M,)`` whether the point lies on a moving object.
    dynamic: IntArray
    #: ``(R, C)`` measured range per beam, NaN where invalid.
    range_image: FloatArray
    #: ``(R, C)`` uint8 status per beam.
    status_image: IntArray
    #: ``T_world_sensor`` at ``reference_time``.
    pose: SE3
    start_time: float
    end_time: float
    reference_time: float

    @property
    def num_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def relative_timestamps(self) -> FloatArray:
        """Timestamps normalised to ``[0, 1)`` over the sweep (as deskew code often wants)."""
        out: FloatArray = (self.timestamps - self.start_time) / (self.end_time - self.start_time)
        return out


def _as_trajectory(motion: Any, dim: int, start_time: float) -> Trajectory:
    cls = SE2 if dim == 2 else SE3
    if isinstance(motion, Trajectory):
        if motion.dim != dim:
            raise ValueError(f"trajectory: expected a {dim}D trajectory, got {motion.dim}D")
        return motion
    if isinstance(motion, cls):
        return Trajectory.stationary(motion, start_time=start_time)
    raise TypeError(
        f"trajectory: expected a Trajectory or {cls.__name__}, got {type(motion).__name__}"
    )


def _reference_time(reference: str, start: float, end: float) -> float:
    times = {"start": start, "middle": 0.5 * (start + end), "end": end}
    if reference not in times:
        raise ValueError(f"reference: expected 'start', 'middle' or 'end', got {reference!r}")
    return times[reference]


def _check_scene(scene: Any, dim: int) -> Scene:
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a Scene, got {type(scene).__name__}")
    if scene.dim != dim:
        raise ValueError(f"scene: a {dim}D sensor needs a {dim}D scene, got {scene.dim}D")
    return scene


def _cast(
    scene: Scene,
    trajectory: Trajectory,
    directions: FloatArray,
    offsets: FloatArray,
    start_time: float,
    reference_time: float,
    model: LaserModel | LidarModel,
    noise_seed: int,
) -> Any:
    knots, poses, twists = trajectory.as_3d_segments()
    return _core.cast_rays(
        scene.primitives_at(start_time),
        directions,
        offsets,
        start_time=start_time,
        knot_times=knots,
        knot_poses=poses,
        twists=twists,
        reference_time=reference_time,
        min_range=model.min_range,
        max_range=model.max_range,
        range_sigma=model.range_sigma,
        dropout_probability=model.dropout_probability,
        seed=noise_seed,
    )


def simulate_scan(
    scene: Scene,
    laser: LaserModel,
    trajectory: Trajectory | SE2,
    *,
    start_time: float = 0.0,
    seed: int = 0,
    scan_index: int = 0,
    reference: Reference = "start",
) -> LaserScan:
    """Simulate one 2D scan starting at ``start_time`` (s).

    ``trajectory`` is a 2D :class:`Trajectory` or a fixed ``SE2`` (``T_world_sensor``).
    The noise is keyed by ``(seed, scan_index)``.
    """
    if not isinstance(laser, LaserModel):
        raise TypeError(f"laser: expected a LaserModel, got {type(laser).__name__}")
    scene = _check_scene(scene, 2)
    t0 = finite(start_time, "start_time")
    traj = _as_trajectory(trajectory, 2, t0)
    t_ref = _reference_time(reference, t0, t0 + laser.scan_duration)
    angles = laser.angles
    offsets: FloatArray = np.arange(laser.num_beams, dtype=np.float64) * laser.time_increment
    dirs = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    key = _noise_seed(check_seed(seed), count(scan_index, "scan_index", 0))
    out = _cast(scene, traj, dirs, offsets, t0, t_ref, laser, key)
    status = np.asarray(out.status)
    valid = status == VALID
    ranges = np.where(valid, out.range, np.where(status == NO_RETURN, laser.max_range, 0.0))
    hit = np.asarray(out.hit)
    dynamic = (hit >= 0) & scene.dynamic[np.maximum(hit, 0)]
    pose = traj.pose_at(t_ref)
    assert isinstance(pose, SE2)
    return LaserScan(
        angles=_frozen(angles),
        ranges=_frozen(ranges),
        status=_frozen(status),
        timestamps=_frozen(t0 + offsets),
        true_ranges=_frozen(out.true_range),
        primitive_index=_frozen(hit),
        dynamic=_frozen(dynamic),
        points=_frozen(out.points[valid, :2]),
        points_deskewed=_frozen(out.points_reference[valid, :2]),
        point_beams=_frozen(np.flatnonzero(valid)),
        pose=pose,
        start_time=t0,
        reference_time=t_ref,
        max_range=laser.max_range,
    )


@functools.lru_cache(maxsize=8)
def _lidar_beams(lidar: LidarModel) -> tuple[FloatArray, FloatArray]:
    """Unit directions ``(R·C, 3)`` and firing offsets ``(R·C,)`` in firing order: column by
    column, every ring of a column at the same instant. Cached: models are immutable."""
    el = np.asarray(lidar.elevations)
    az = lidar.azimuths
    r, c = lidar.num_rings, lidar.num_columns
    cos_el = np.cos(el)
    dirs = np.empty((c, r, 3))
    dirs[:, :, 0] = np.cos(az)[:, None] * cos_el[None, :]
    dirs[:, :, 1] = np.sin(az)[:, None] * cos_el[None, :]
    dirs[:, :, 2] = np.sin(el)[None, :]
    return _frozen(dirs.reshape(-1, 3)), _frozen(np.repeat(lidar.column_times, r))


def simulate_sweep(
    scene: Scene,
    lidar: LidarModel,
    trajectory: Trajectory | SE3,
    *,
    start_time: float = 0.0,
    seed: int = 0,
    scan_index: int = 0,
    reference: Reference = "start",
) -> LidarSweep:
    """Simulate one LiDAR sweep (one revolution) starting at ``start_time`` (s).

    ``trajectory`` is a 3D :class:`Trajectory` or a fixed ``SE3`` (``T_world_sensor``).
    The noise is keyed by ``(seed, scan_index)``.
    """
    if not isinstance(lidar, LidarModel):
        raise TypeError(f"lidar: expected a LidarModel, got {type(lidar).__name__}")
    scene = _check_scene(scene, 3)
    t0 = finite(start_time, "start_time")
    traj = _as_trajectory(trajectory, 3, t0)
    t1 = t0 + lidar.sweep_duration
    t_ref = _reference_time(reference, t0, t1)
    r, c = lidar.num_rings, lidar.num_columns
    dirs, offsets = _lidar_beams(lidar)
    key = _noise_seed(check_seed(seed), count(scan_index, "scan_index", 0))
    out = _cast(scene, traj, dirs, offsets, t0, t_ref, lidar, key)
    status = np.asarray(out.status)
    valid = status == VALID
    idx = np.flatnonzero(valid)
    hit = np.asarray(out.hit)[idx]
    pose = traj.pose_at(t_ref)
    assert isinstance(pose, SE3)
    return LidarSweep(
        points=_frozen(out.points[idx]),
        points_deskewed=_frozen(out.points_reference[idx]),
        timestamps=_frozen(t0 + offsets[idx]),
        rings=_frozen(idx % r),
        columns=_frozen(idx // r),
        ranges=_frozen(out.range[idx]),
        true_ranges=_frozen(out.true_range[idx]),
        primitive_index=_frozen(hit),
        dynamic=_frozen(scene.dynamic[hit]),
        range_image=_frozen(np.asarray(out.range).reshape(c, r).T),
        status_image=_frozen(status.reshape(c, r).T),
        pose=pose,
        start_time=t0,
        end_time=t1,
        reference_time=t_ref,
    )


@dataclass(frozen=True, eq=False)
class SimulatedRun:
    """A sequence of scans along a trajectory, with the ground truth."""

    scene: Scene
    sensor: LaserModel | LidarModel
    trajectory: Trajectory
    scans: tuple[LaserScan, ...] | tuple[LidarSweep, ...]
    #: ``T_world_sensor`` of each scan at its reference time (``scan.pose``).
    poses: tuple[SE2, ...] | tuple[SE3, ...]
    #: ``(S,)`` scan start times (s).
    start_times: FloatArray


def simulate_run(
    scene: Scene,
    sensor: LaserModel | LidarModel,
    trajectory: Trajectory,
    *,
    num_scans: int,
    scan_rate: float = 10.0,
    seed: int = 0,
    reference: Reference = "start",
) -> SimulatedRun:
    """``num_scans`` scans starting at ``trajectory.start_time``, ``1 / scan_rate`` apart
    (for a LiDAR the rate is its rotation rate: sweeps are back to back)."""
    n = count(num_scans, "num_scans")
    if isinstance(sensor, LidarModel):
        period = sensor.sweep_duration
    elif isinstance(sensor, LaserModel):
        period = 1.0 / positive(scan_rate, "scan_rate")
    else:
        raise TypeError(f"sensor: expected a LaserModel or LidarModel, got {type(sensor).__name__}")
    if not isinstance(trajectory, Trajectory):
        raise TypeError(f"trajectory: expected a Trajectory, got {type(trajectory).__name__}")
    times = trajectory.start_time + period * np.arange(n)
    scans: list[Any] = []
    for k, t in enumerate(times):
        if isinstance(sensor, LidarModel):
            scans.append(
                simulate_sweep(
                    scene,
                    sensor,
                    trajectory,
                    start_time=float(t),
                    seed=seed,
                    scan_index=k,
                    reference=reference,
                )
            )
        else:
            scans.append(
                simulate_scan(
                    scene,
                    sensor,
                    trajectory,
                    start_time=float(t),
                    seed=seed,
                    scan_index=k,
                    reference=reference,
                )
            )
    return SimulatedRun(
        scene=scene,
        sensor=sensor,
        trajectory=trajectory,
        scans=tuple(scans),
        poses=tuple(s.pose for s in scans),
        start_times=_frozen(times),
    )
