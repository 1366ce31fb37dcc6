"""Is the reported covariance calibrated? Monte Carlo NEES on simulated scenes with exact truth.

For each scene and method: R realisations of two independent scans taken from poses A and B
(B = A moved by a small known step, fresh noise and sampling each time); register source (A)
to target (B) from the identity; error ``δ = log(T_est⁻¹ T_true)`` in scanreg's tangent
convention; ``NEES = δᵀ Σ⁻¹ δ``. A calibrated covariance gives mean NEES ≈ dof (3 in 2D, 6
in 3D), inside the printed 95 % band. "ratio" is mean NEES / dof: > 1 over-confident.

    .venv/bin/python benchmarks/covariance_calibration.py [--realisations 200] [--quick]

Scenes: 2D square room, 2D long corridor (degenerate along x), 3D street, 3D tunnel
(degenerate along x). The median error along x is printed too, to show what degeneracy does.
"""

from __future__ import annotations

import argparse
import os
import statistics
from collections.abc import Callable
from dataclasses import dataclass

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.quality import nees_band


@dataclass(frozen=True)
class Scene:
    name: str
    dim: int
    scan: Callable[[object, int], np.ndarray]  # (pose, seed) -> points in the sensor frame
    pose_a: SE2 | SE3
    step: SE2 | SE3  # T_A_B


def _scenes() -> list[Scene]:
    laser = sim.LaserModel.preset("laser_360")
    lidar = sim.LidarModel.preset("vlp16")
    room, corridor = sim.square_room(5.0), sim.corridor(length=200.0, width=3.0)
    street, tunnel = sim.street(seed=4), sim.tunnel()

    def scan2d(scene: object) -> Callable[[object, int], np.ndarray]:
        return lambda pose, seed: np.ascontiguousarray(
            sim.simulate_scan(scene, laser, pose, seed=seed).points  # type: ignore[arg-type]
        )

    def sweep3d(scene: object) -> Callable[[object, int], np.ndarray]:
        def run(pose: object, seed: int) -> np.ndarray:
            pts = sim.simulate_sweep(scene, lidar, pose, seed=seed).points  # type: ignore[arg-type]
            return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(pts), 0.3).points

        return run

    step2 = SE2.from_vector([0.3, 0.1, np.deg2rad(2.0)])
    step3 = SE3.from_vector([0.5, 0.1, 0.0, 0.0, 0.0, np.deg2rad(2.0)])
    return [
        Scene("2D room", 2, scan2d(room), SE2.from_vector([0.5, 0.3, 0.3]), step2),
        Scene("2D corridor", 2, scan2d(corridor), SE2.from_vector([100.0, 0.0, 0.0]), step2),
        Scene("3D street", 3, sweep3d(street), SE3.from_vector([0, 1.75, 1.73, 0, 0, 0]), step3),
        Scene("3D tunnel", 3, sweep3d(tunnel), SE3.from_vector([0, 0, 1.8, 0, 0, 0]), step3),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realisations", type=int, default=200)
    parser.add_argument("--quick", action="store_true", help="20 realisations (a smoke run)")
    args = parser.parse_args()
    reps = 20 if args.quick else args.realisations
    methods = ["point_to_point", "point_to_plane", "gicp"]
    print(f"{reps} realisations per row; mean NEES / dof > 1 means over-confident\n")
    print(
        f"{'scene':<12} {'method':<15} {'mean NEES':>10} {'95% band':>15} {'ratio':>7} "
        f"{'med |δx|':>9} {'med σx':>9} {'weakest direction (last run)'}"
    )
    for scene in _scenes():
        dof = 3 if scene.dim == 2 else 6
        lo, hi = nees_band(dof, reps)
        pose_b = scene.pose_a @ scene.step  # type: ignore[operator]
        truth = scene.step.inverse()  # T_target_source = T_B_A
        for method in methods:
            nees, dx, sx = [], [], []
            weakest = ""
            for k in range(reps):
                src = scene.scan(scene.pose_a, 2 * k)
                tgt = scene.scan(pose_b, 2 * k + 1)
                target = scanreg.prepare(tgt, covariances=method == "gicp")
                res = scanreg.register(src, target, method=method, max_correspondence_distance=1.0)
                d = (res.pose.inverse() @ truth).log()
                nees.append(float(d @ res.information @ d))
                dx.append(abs(d[0]))
                sx.append(float(np.sqrt(res.covariance[0, 0])))
                weakest = res.conditioning.weakest.description
            mean = float(np.mean(nees))
            print(
                f"{scene.name:<12} {method:<15} {mean:10.2f} {lo:7.2f}–{hi:<7.2f} "
                f"{mean / dof:7.2f} {statistics.median(dx):9.4f} {statistics.median(sx):9.4f} "
                f"{weakest}"
            )


if __name__ == "__main__":
    main()
