"""Scan simulator: 2D lasers and spinning 3D LiDARs in constructed scenes, with exact truth.

The test instrument for scanreg: every scene, trajectory and noise draw is reproducible from a
seed, and the hard cases (long corridors, tunnels, moving people, motion distortion) are a
parameter away. Ray casting runs in the Rust core, parallel over beams, with per-beam noise
streams so the output does not depend on the thread count. Scanned objects
(:mod:`scanreg.simulate.objects`: a knot, a blob, a figurine seen from one side) are sampled
from their surfaces directly, and a 2D scene's outlines by :func:`surface_samples` (a
map-like cloud, every side of every object sampled).

Example::

    import scanreg
    from scanreg import simulate as sim

    scene = sim.floor_plan(seed=1)
    start = scanreg.SE2.from_vector([1.0, 0.0, 0.0])
    traj = sim.Trajectory.from_speed_and_yaw_rate(1.0, 0.0, duration=5.0, start=start)
    run = sim.simulate_run(scene, sim.LaserModel.preset("sick_lms200"), traj, num_scans=20)
    run.scans[3].points, run.poses[3]      # (M, 2) points, SE2 T_world_sensor

Conventions: poses are ``T_world_sensor`` (``SE2``/``SE3``); sensor frame x forward, y left,
z up; see :mod:`scanreg.simulate.scan` for which frame and time each output is in.
"""

from .courses import Course, block_loop, ring_corridor, room_tour
from .objects import ObjectShape, blob, figurine, object_view, trefoil_knot
from .scan import (
    DROPOUT,
    NO_RETURN,
    TOO_CLOSE,
    VALID,
    LaserScan,
    LidarSweep,
    SimulatedRun,
    simulate_run,
    simulate_scan,
    simulate_sweep,
)
from .scene import Scene, SceneBuilder, corridor, floor_plan, square_room, street, tunnel
from .sensors import LASER_PRESETS, LIDAR_PRESETS, LaserModel, LidarModel
from .surfaces import surface_samples
from .trajectory import Trajectory
from .wheel import wheel_odometry

__all__ = [
    "DROPOUT",
    "LASER_PRESETS",
    "LIDAR_PRESETS",
    "NO_RETURN",
    "TOO_CLOSE",
    "VALID",
    "Course",
    "LaserModel",
    "LaserScan",
    "LidarModel",
    "LidarSweep",
    "ObjectShape",
    "Scene",
    "SceneBuilder",
    "SimulatedRun",
    "Trajectory",
    "blob",
    "block_loop",
    "corridor",
    "figurine",
    "floor_plan",
    "object_view",
    "ring_corridor",
    "room_tour",
    "simulate_run",
    "simulate_scan",
    "simulate_sweep",
    "square_room",
    "street",
    "surface_samples",
    "trefoil_knot",
    "tunnel",
    "wheel_odometry",
]
