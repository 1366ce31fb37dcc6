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
import dataclasses
import math
import os

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.pipeline import Odometry2D, OdometryConfig2D

CHI2_999 = 16.266
#: Seconds between the two scans of a pair.
SCAN_INTERVAL = 0.2
TARGET_TOO = True


def run(rate_deg: float, sweep: float, guard: bool, seeds: int, trials: int, modelled: bool) -> str:
    laser = _laser(sweep)
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
            # The motion over one sweep, from the motion between the scans (what an odometry's
            # prediction gives): both scans were swept while turning alike.
            swept = tuple(truth.log() * (sweep / SCAN_INTERVAL)) if modelled else None
            res = scanreg.register(
                scans[1].points,
                scanreg.prepare(scans[0].points, normals=True),
                method="point_to_line",
                init=truth,
                never_worse_than_start=guard,
                sweep_motion=swept,
                target_sweep_motion=swept if TARGET_TOO else None,
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
        f"| {rate_deg:g} | {rate_deg * sweep:.2f} | {'on' if guard else 'off'} | "
        f"{'yes' if modelled else 'no'} | {len(err)} | "
        f"{100 * np.median(err[:, 0]):.2f} | {np.median(err[:, 1]):.2f} | "
        f"{np.percentile(err[:, 1], 90):.2f} | {accepted_wrong} | {len(nees)} | "
        f"{np.mean(nees):.1f} | {sum(x > CHI2_999 for x in nees)} |"
    )


def odometry(rate_deg: float, sweep: float, seeds: int, modelled: bool) -> str:
    """``Odometry2D`` over a turning drive (the rate swinging ±``rate_deg`` °/s with a 4 s
    period, 0.3 m/s, scans 0.1 s apart, the wheels' exact relative motion as the prior): mean
    NEES of each frame's error relative to the previous frame's (truth vs estimate) against
    the frame's covariance, over the frames turning faster than half the peak rate; and
    against the frame's covariance plus the previous frame's (the step's, were the two
    frames' errors independent; a previous frame without a finite covariance adds none)."""
    laser = _laser(sweep)
    cfg = OdometryConfig2D(sweep_duration=sweep if modelled else 0.0)
    nees, turning, errors, nees_both = [], 0, [], []
    for seed in range(seeds):
        scene = sim.floor_plan(seed=seed, num_people=0)
        rng = np.random.default_rng(seed)
        start = SE2.from_vector([rng.uniform(3, 7), rng.uniform(3, 5), rng.uniform(-3, 3)])
        path = sim.Trajectory.from_speed_and_yaw_rate(
            0.3,
            0.0,
            duration=4.2,
            start=start,
            yaw_rate_amplitude=math.radians(rate_deg),
            yaw_rate_period=4.0,
        )
        run = sim.simulate_run(
            scene, laser, path, num_scans=40, scan_rate=10.0, seed=seed, reference="middle"
        )
        odo = Odometry2D(cfg)
        prev, prev_cov = None, np.zeros((3, 3))
        for k, scan in enumerate(run.scans):
            wheels = None if k == 0 else run.poses[k - 1].inverse() @ run.poses[k]
            frame = odo.step(scan.points, prior=wheels, stamp=float(run.start_times[k]))
            if k > 0 and prev is not None and frame.verdict.accepted:
                true_step = run.poses[k - 1].inverse() @ run.poses[k]
                est_step = prev.inverse() @ frame.pose
                e = (est_step.inverse() @ true_step).log()  # type: ignore[operator]
                if abs(true_step.angle) > 0.5 * math.radians(rate_deg) * 0.1:
                    turning += 1
                    errors.append(math.degrees(abs(float(e[2]))))
                    nees.append(float(e @ np.linalg.solve(frame.covariance, e)))
                    both = frame.covariance + prev_cov
                    nees_both.append(float(e @ np.linalg.solve(both, e)))
            prev = frame.pose
            finite = np.isfinite(frame.covariance).all()
            prev_cov = np.array(frame.covariance) if finite else np.zeros((3, 3))
    return (
        f"| {rate_deg:g} | {rate_deg * sweep:.2f} | {'yes' if modelled else 'no'} | {turning} "
        f"| {np.median(errors):.2f} | {np.mean(nees):.1f} | {sum(x > CHI2_999 for x in nees)} "
        f"| {np.mean(nees_both):.1f} | {sum(x > CHI2_999 for x in nees_both)} |"
    )


def _laser(sweep: float) -> sim.LaserModel:
    """The ``laser_361`` preset with its beams ``sweep`` apart end to end."""
    laser = sim.LaserModel.preset("laser_361")
    return dataclasses.replace(laser, time_increment=sweep / (laser.num_beams - 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", type=float, default=0.0267)
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument(
        "--odometry", action="store_true", help="Odometry2D over turning drives instead"
    )
    args = parser.parse_args()
    if args.odometry:
        print(
            "| peak rate (°/s) | ωT (°) | sweep_duration | turning frames "
            "| median heading error (°) | mean NEES | outside "
            "| mean NEES, previous frame's covariance added | outside |"
        )
        print("|---|---|---|---:|---:|---:|---:|---:|---:|")
        for rate in (90.0, 250.0):
            for modelled in (False, True):
                print(odometry(rate, args.sweep, args.seeds, modelled), flush=True)
        return
    print(
        "| rate (°/s) | ωT (°) | guard | sweep_motion | pairs | median error (cm) "
        "| median heading error (°) | p90 heading (°) | accepted and wrong | accepted "
        "| mean NEES | outside |"
    )
    print("|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for rate in (0.0, 90.0, 250.0):
        for modelled in (False, True):
            if rate == 0.0 and modelled:
                continue  # nothing to model
            print(run(rate, args.sweep, True, args.seeds, args.trials, modelled), flush=True)


if __name__ == "__main__":
    main()
