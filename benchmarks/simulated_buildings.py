"""2D mapping's defaults on simulated buildings and sensors they were not chosen on.

The room tour of the demo (``scanreg.simulate.room_tour``: a corridor with rooms on both sides,
every room visited on the way out and again on the way back) varied one thing at a time: a
larger building, look-alike rooms, larger rooms, three times the wheel noise, slower scans,
faster driving, a 360° laser (with its beams' times, as a LaserScan's ``time_increment`` gives
them, and without), no odometry at all. Each run is read as a LaserScan bag would be (a
:class:`scanreg.io.ScanLog`: the simulated ranges, the wheels' odometry at each stamp) and
mapped by ``run_mapping`` with the default ``MappingConfig``; scored against the simulator's
exact truth (ATE: RMS position error, with the first poses aligned — the map's frame is its first
scan's — and, in parentheses, after the best rigid alignment, evo's usual reading, which does not
charge the whole map for its first scan's own error). Loops "off": accepted loops whose
error against the truth is beyond their own information's 99.9 % χ² bound (3 dof). Self-check:
``check_map``'s verdict and contradicted fraction, without the truth.

Run: ``.venv/bin/python benchmarks/simulated_buildings.py [--seeds 0 1] [--variants ...]``
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.eval import absolute_trajectory_error
from scanreg.io import Trajectory
from scanreg.io.rosbag import RosLaserScan
from scanreg.io.scan_log import ScanLog
from scanreg.pipeline import MappingConfig, check_map, run_mapping

CHI2_3DOF_999 = 16.266


@dataclass(frozen=True)
class Variant:
    """One change from the demo's tour (two rooms a side, SICK LMS200-like, 5 Hz, wheels)."""

    course: dict[str, Any] = field(default_factory=dict)
    laser: str = "sick_lms200"
    rate: float = 5.0
    beam_times: bool = True
    wheel_noise: float = 1.0
    odometry: bool = True
    #: ``room_tour`` or ``ring_corridor`` (one lap round bare corridors, closed at the end).
    kind: str = "room_tour"
    #: The wheels' distances × this (a wheel radius mis-set: drift the noise model hides).
    wheel_scale: float = 1.0


VARIANTS: dict[str, Variant] = {
    "demo tour": Variant(),
    "4 rooms a side": Variant(course={"rooms_per_side": 4}),
    "look-alike rooms": Variant(course={"identical_rooms": True}),
    "rooms 9 × 7 m, corridor 4 m": Variant(
        course={"room_width": 9.0, "room_depth": 7.0, "corridor_width": 4.0}
    ),
    "wheel noise × 3": Variant(wheel_noise=3.0),
    "3 Hz": Variant(rate=3.0),
    "1.5 m/s": Variant(course={"speed": 1.5, "turn_rate": 1.5}),
    "360° laser, 0.1 s sweep": Variant(laser="laser_360"),
    "360° laser, no beam times": Variant(laser="laser_360", beam_times=False),
    "no odometry": Variant(odometry=False),
    "ring corridor, 361 beams": Variant(kind="ring_corridor", laser="laser_361"),
    "ring corridor, wheels 3 % long": Variant(
        kind="ring_corridor", laser="laser_361", wheel_scale=1.03
    ),
}


def _wheels(truth: list[SE2], seed: int, noise: float, scale: float = 1.0) -> list[SE2]:
    """The wheels' odometry ``T_odom_base`` at each scan (``noise`` × the simulator's, the
    distances × ``scale``)."""
    steps = sim.wheel_odometry(truth, seed + 7)
    odometry = [SE2.identity()]
    for a, b, step in zip(truth[:-1], truth[1:], steps[1:], strict=True):
        assert step is not None
        true = (a.inverse() @ b).log()
        measured = true + noise * (step.log() - true)
        measured[:2] *= scale
        odometry.append(odometry[-1] @ SE2.exp(measured))
    return odometry


def tour(v: Variant, seed: int) -> tuple[ScanLog, list[SE2]]:
    if v.kind == "ring_corridor":
        course = sim.ring_corridor(seed=seed, **v.course)
    else:
        course = sim.room_tour(seed=seed, **{"rooms_per_side": 2, **v.course})
    laser = sim.LaserModel.preset(v.laser)
    run = sim.simulate_run(
        course.scene, laser, course.trajectory,
        num_scans=course.num_scans(v.rate), scan_rate=v.rate, seed=seed,
    )  # fmt: skip
    truth = [run.poses[0].inverse() @ p for p in run.poses]
    increment = laser.time_increment if v.beam_times else 0.0

    def message(k: int, scan: Any) -> RosLaserScan:
        return RosLaserScan(
            kind="sensor_msgs/LaserScan", ranges=scan.ranges, angles=scan.angles,
            max_range=laser.max_range, laser_pose=None, odometry_pose=None,
            timestamp=k / v.rate, logger_timestamp=k / v.rate, range_min=laser.min_range,
            time_increment=increment, scan_time=1 / v.rate,
        )  # fmt: skip

    scans = tuple(message(k, s) for k, s in enumerate(run.scans))
    odometry: list[SE2 | None] = (
        list(_wheels(truth, seed, v.wheel_noise, v.wheel_scale))
        if v.odometry
        else [None] * len(scans)
    )
    stamps = np.arange(len(scans)) / v.rate
    return ScanLog("sim", scans, stamps, tuple(odometry), SE2.identity()), truth  # type: ignore[arg-type]


def _ate(poses: Any, truth: list[SE2]) -> str:
    err = [np.linalg.norm((t.inverse() @ p).translation) for p, t in zip(poses, truth, strict=True)]
    first = float(np.sqrt(np.mean(np.square(err))))
    fitted = absolute_trajectory_error(
        Trajectory.from_poses(list(poses)), Trajectory.from_poses(truth)
    ).translation.rmse
    return f"{first:.3f} ({fitted:.3f})"


def _loops_off(res: Any, truth: list[SE2]) -> int:
    off = 0
    for r in res.accepted_loops:
        e = (r.match.measured.inverse() @ (truth[r.submap_scan].inverse() @ truth[r.scan])).log()
        off += float(e @ np.asarray(r.match.information) @ e) > CHI2_3DOF_999
    return off


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = parser.parse_args()
    print(
        "| variant | seed | scans | odometry ATE (m) | map ATE (m) | loops (off) "
        "| self-check | CPU s |"
    )
    print("|---|---:|---:|---:|---:|---|---|---:|")
    clock: Callable[[], float] = time.process_time
    for name in args.variants:
        for seed in args.seeds:
            log, truth = tour(VARIANTS[name], seed)
            t0 = clock()
            res = run_mapping(log, MappingConfig())
            cpu = clock() - t0
            check = check_map(res)
            verdict = "consistent" if check.consistent else "**INCONSISTENT**"
            loops = f"{len(res.accepted_loops)} ({_loops_off(res, truth)})"
            print(
                f"| {name} | {seed} | {len(truth)} | {_ate(res.odometry_poses, truth)} "
                f"| {_ate(res.poses, truth)} | {loops} | {verdict}, "
                f"{check.contradiction_fraction:.1%} | {math.ceil(cpu)} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
