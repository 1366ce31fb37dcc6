"""Fast turns and a slow sweep: what the distortion of a 2D scan does to point-to-line and its
covariance, when the scans carry no per-beam time (issue 41, item 1's second half; not modelled
yet).

Simulated office rooms (``floor_plan(seed)``, no people), a 361-beam 180° laser whose sweep takes
``--sweep`` seconds (default 26.7 ms: a SICK LMS at 0.5°), on a robot driving at 0.3 m/s while
turning at 0, 90 and 250 °/s, scans 0.2 s apart. Each beam is cast from the pose at its own time
and reported in the frame of that instant (what a driver without deskewing gives). Truth: the
relative pose between the sweeps' middles. Scan 2 is registered to scan 1 with the default
point-to-line call from the truth, with and without the never-worse-than-the-start guard.
Printed per rate: median translation / heading error, 90th percentile heading error, accepted and
wrong (> 0.15 m or 2°), accepted, their mean NEES and how many lie outside χ²(3) at 99.9 %.

    .venv/bin/python benchmarks/sweep_distortion.py [--sweep 0.0267] [--seeds 6] [--trials 8]
"""

from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2
from scanreg import simulate as sim

CHI2_999 = 16.266


def run(rate_deg: float, sweep: float, guard: bool, seeds: int, trials: int) -> str:
    laser = sim.LaserModel(
        num_beams=361,
        angle_min=-math.pi / 2,
        angle_increment=math.radians(0.5),
        max_range=40.0,
        range_sigma=0.01,
        time_increment=sweep / 360,
    )
    errors = []
    accepted_wrong = 0
    nees = []
    for seed in range(seeds):
        scene = sim.floor_plan(seed=seed, num_people=0)
        rng = np.random.default_rng(seed)
        for t in range(trials):
            start = SE2.from_vector([rng.uniform(2, 8), rng.uniform(2, 6), rng.uniform(-3, 3)])
            path = sim.Trajectory.from_speed_and_yaw_rate(
                0.3, math.radians(rate_deg), duration=1.0, start=start
            )
            scans = [
                sim.simulate_scan(
                    scene,
                    laser,
                    path,
                    start_time=t0,
                    seed=seed,
                    scan_index=2 * t + i,
                    reference="middle",
                )
                for i, t0 in enumerate((0.2, 0.4))
            ]
            if min(len(s.points) for s in scans) < 100:
                continue
            truth = scans[0].pose.inverse() @ scans[1].pose
            res = scanreg.register(
                scans[1].points,
                scanreg.prepare(scans[0].points, normals=True),
                method="point_to_line",
                init=truth,
                never_worse_than_start=guard,
            )
            e = (res.pose.inverse() @ truth).log()  # type: ignore[operator]
            metres, degrees = float(np.hypot(e[0], e[1])), math.degrees(abs(float(e[2])))
            errors.append((metres, degrees))
            assert res.verdict is not None
            if res.verdict.accepted:
                accepted_wrong += metres > 0.15 or degrees > 2.0
                nees.append(float(e @ np.linalg.solve(res.covariance, e)))
    err = np.array(errors)
    return (
        f"| {rate_deg:g} | {rate_deg * sweep:.2f} | {'on' if guard else 'off'} | {len(err)} | "
        f"{100 * np.median(err[:, 0]):.2f} | {np.median(err[:, 1]):.2f} | "
        f"{np.percentile(err[:, 1], 90):.2f} | {accepted_wrong} | {len(nees)} | "
        f"{np.mean(nees):.1f} | {sum(x > CHI2_999 for x in nees)} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", type=float, default=0.0267)
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--trials", type=int, default=8)
    args = parser.parse_args()
    print(
        "| rate (°/s) | ωT (°) | guard | pairs | median error (cm) | median heading error (°) "
        "| p90 heading (°) | accepted and wrong | accepted | mean NEES | outside |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for rate in (0.0, 90.0, 250.0):
        for guard in (False, True):
            print(run(rate, args.sweep, guard, args.seeds, args.trials))


if __name__ == "__main__":
    main()
