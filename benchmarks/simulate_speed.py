"""Speed of the scan simulator: median wall time per 2D scan and per 3D sweep.

    .venv/bin/python benchmarks/simulate_speed.py [--repeats 20]

Each row simulates the same scan ``repeats`` times (after one warm-up) along a moving
trajectory, so motion distortion and moving objects are included; times are end-to-end
``simulate_scan``/``simulate_sweep`` calls (ray casting in Rust plus the Python wrapping).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

from scanreg import SE2, SE3
from scanreg import simulate as sim


def median_ms(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    out = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    office = sim.floor_plan(seed=0)
    street = sim.street(seed=0)
    tunnel = sim.tunnel()
    t2 = sim.Trajectory.from_speed_and_yaw_rate(
        1.0, 0.2, duration=10.0, start=SE2.from_vector([1.0, 0.0, 0.0])
    )
    t3 = sim.Trajectory.from_speed_and_yaw_rate(
        10.0, 0.05, duration=10.0, dim=3, start=SE3.from_vector([0.0, 1.75, 1.73, 0, 0, 0])
    )
    cases: list[tuple[str, str, Callable[[], Any]]] = []
    for name in ("sick_lms200", "laser_360"):
        laser = sim.LaserModel.preset(name)
        cases.append(
            (
                f"2D {name}",
                f"floor_plan ({office.num_primitives} prims)",
                lambda laser=laser: sim.simulate_scan(office, laser, t2, start_time=1.0),
            )
        )
    for name in ("hdl64", "hdl32", "vlp16"):
        lidar = sim.LidarModel.preset(name)
        cases.append(
            (
                f"3D {name}",
                f"street ({street.num_primitives} prims)",
                lambda lidar=lidar: sim.simulate_sweep(street, lidar, t3, start_time=1.0),
            )
        )
    hdl64 = sim.LidarModel.preset("hdl64")
    cases.append(
        (
            "3D hdl64",
            "tunnel (2 prims)",
            lambda: sim.simulate_sweep(tunnel, hdl64, t3, start_time=1.0),
        )
    )

    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, "
        f"Python {platform.python_version()}, repeats {args.repeats}"
    )
    print("| sensor | scene | beams | valid points | median ms | points / s |")
    print("|---|---|---:|---:|---:|---:|")
    for sensor, scene_name, fn in cases:
        ms, out = median_ms(fn, args.repeats)
        beams = out.status.size if hasattr(out, "angles") else out.status_image.size
        points = out.points.shape[0]
        print(
            f"| {sensor} | {scene_name} | {beams} | {points} | {ms:.2f} | {points / ms * 1e3:.3g} |"
        )


if __name__ == "__main__":
    main()
