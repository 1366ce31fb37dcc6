"""Is the reported covariance calibrated? Monte Carlo NEES on simulated scenes with exact truth.

For each scene and method: R realisations of two independent scans taken from poses A and B
(B = A moved by a small known step, fresh range noise, dropouts and sampling each time);
register source (A) to target (B); error ``δ = log(T_est⁻¹ T_true)`` in scanreg's tangent
convention; ``NEES = δᵀ Σ⁻¹ δ`` for every covariance kind of the result. A calibrated
covariance gives mean NEES ≈ dof (3 in 2D, 6 in 3D), inside the printed 95 % band.

Two protocols:

* ``identity``: registered from the identity, default settings (the gate-wide prior is used
  along degenerate directions); ``identity-aware``: the same with ``degeneracy_aware=True``;
* ``prior``: the initial guess is drawn around the truth from a motion prior
  ``P = diag(0.1² m², …, (1°)², …)``, passed as ``init_covariance``, with
  ``degeneracy_aware=True`` (the estimate keeps the prior along weak directions).

``--randomise-pose``: the sensor pose A is moved per realisation by a uniform offset of
±0.15 m in x and y and ±0.05 rad (±2.9°) of yaw (the step A→B, hence the truth, is unchanged).
Without it every realisation sees the scene from the same pose: the voxel grid falls on the
same place of every wall and a corridor is exactly along the sensor's x axis, so one
configuration is sampled 200 times; with it the grid's phase and the scene's heading are part
of the sampling, as they are for a robot.

    .venv/bin/python benchmarks/covariance_calibration.py [--realisations 200] [--quick]
        [--methods point_to_plane gicp] [--scenes "2D room" ...] [--json out.json]
        [--drop-linear] [--randomise-pose]

Scenes: 2D square room, 2D long corridor (degenerate along x), 3D street, 3D tunnel
(degenerate along x). Also printed: how often each scene was flagged degenerate.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from dataclasses import dataclass

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.quality import nees_band

KINDS = ("hessian", "censi", "block", "calibrated")


@dataclass(frozen=True)
class Scene:
    name: str
    dim: int
    scan: Callable[[object, int], np.ndarray]  # (pose, seed) -> points in the sensor frame
    pose_a: SE2 | SE3
    step: SE2 | SE3  # T_A_B


def scenes() -> list[Scene]:
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


def scene_named(name: str) -> tuple[Scene, SE2 | SE3, SE2 | SE3]:
    """The scene ``name``, the target's pose ``B = A · step`` and the truth ``T_B_A``."""
    scene = next(s for s in scenes() if s.name == name)
    return scene, scene.pose_a @ scene.step, scene.step.inverse()  # type: ignore[operator]


def motion_prior(dim: int) -> np.ndarray:
    dof = 3 if dim == 2 else 6
    return np.diag([0.1**2] * dim + [np.deg2rad(1.0) ** 2] * (dof - dim))


def sensor_pose(scene: Scene, k: int, randomise: bool) -> SE2 | SE3:
    """Pose A of realisation ``k``: the scene's, or moved by ±0.15 m in x, y and ±0.05 rad
    of yaw (seeded by ``k``)."""
    if not randomise:
        return scene.pose_a
    rng = np.random.default_rng(20_000 + k)
    x, y, yaw = rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(-0.05, 0.05)
    if scene.dim == 2:
        return scene.pose_a @ SE2.from_vector([x, y, yaw])  # type: ignore[operator]
    return scene.pose_a @ SE3.from_vector([x, y, 0.0, 0.0, 0.0, yaw])  # type: ignore[operator]


def run_scene(
    scene: Scene,
    method: str,
    reps: int,
    protocol: str,
    drop_linear: bool = False,
    randomise_pose: bool = False,
) -> dict[str, object]:
    """Mean NEES per covariance kind over ``reps`` realisations (seeded: realisation k uses
    scan seeds 2k, 2k+1 and init seed k)."""
    dof = 3 if scene.dim == 2 else 6
    truth = scene.step.inverse()  # T_target_source = T_B_A
    prior = motion_prior(scene.dim)
    nees: dict[str, list[float]] = {k: [] for k in KINDS}
    flagged = 0
    weak_names: dict[str, int] = {}
    abs_err = []
    for k in range(reps):
        pose_a = sensor_pose(scene, k, randomise_pose)
        src = scene.scan(pose_a, 2 * k)
        tgt = scene.scan(pose_a @ scene.step, 2 * k + 1)  # type: ignore[operator]
        target = scanreg.prepare(tgt, covariances=method == "gicp", drop_linear=drop_linear)
        if protocol == "prior":
            rng = np.random.default_rng(10_000 + k)
            init = truth @ type(truth).exp(rng.multivariate_normal(np.zeros(dof), prior))  # type: ignore[operator]
            res = scanreg.register(
                src,
                target,
                method=method,  # type: ignore[arg-type]
                init=init,
                init_covariance=prior,
                max_correspondence_distance=1.0,
                degeneracy_aware=True,
            )
        else:
            res = scanreg.register(
                src,
                target,
                method=method,  # type: ignore[arg-type]
                max_correspondence_distance=1.0,
                degeneracy_aware=protocol == "identity-aware",
            )
        d = (res.pose.inverse() @ truth).log()  # type: ignore[operator]
        abs_err.append(np.abs(d))
        assert res.covariances is not None and res.degeneracy is not None
        for kind in KINDS:
            cov = getattr(res.covariances, kind)
            try:
                nees[kind].append(float(d @ np.linalg.solve(cov, d)))
            except np.linalg.LinAlgError:
                nees[kind].append(float("inf"))
        if res.degeneracy.degenerate:
            flagged += 1
            for w in res.degeneracy.weak_directions:
                weak_names[w.description] = weak_names.get(w.description, 0) + 1
    lo, hi = nees_band(dof, reps)
    return {
        "scene": scene.name,
        "method": method,
        "protocol": protocol,
        "randomised_pose": randomise_pose,
        "realisations": reps,
        "dof": dof,
        "band": [lo, hi],
        "mean_nees": {k: float(np.mean(v)) for k, v in nees.items()},
        "flagged": flagged,
        "weak_directions": weak_names,
        "median_abs_error": np.median(np.array(abs_err), axis=0).tolist(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--realisations", type=int, default=200)
    parser.add_argument("--quick", action="store_true", help="20 realisations (a smoke run)")
    parser.add_argument(
        "--methods", nargs="+", default=["point_to_point", "point_to_plane", "gicp"]
    )
    parser.add_argument("--scenes", nargs="+", default=None)
    parser.add_argument("--protocols", nargs="+", default=["identity", "prior"])
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    parser.add_argument(
        "--drop-linear",
        action="store_true",
        help="targets without normals at linear 3D neighbourhoods (scanreg.prepare)",
    )
    parser.add_argument(
        "--randomise-pose",
        action="store_true",
        help="move the sensor per realisation (±0.15 m, ±2.9° yaw; see the docstring)",
    )
    parser.add_argument(
        "--markdown-from", default=None, help="only print the table of a --json file"
    )
    args = parser.parse_args()
    if args.markdown_from:
        with open(args.markdown_from) as f:
            print(markdown_table(json.load(f)))
        return
    reps = 20 if args.quick else args.realisations
    rows = []
    print(f"{reps} realisations per row; mean NEES (dof: 3 in 2D, 6 in 3D)\n")
    print(
        f"{'scene':<12} {'method':<15} {'protocol':<9} {'band':>13} "
        + " ".join(f"{k:>10}" for k in KINDS)
        + "  flagged  weak directions"
    )
    for scene in scenes():
        if args.scenes and scene.name not in args.scenes:
            continue
        for method in args.methods:
            for protocol in args.protocols:
                row = run_scene(
                    scene, method, reps, protocol, args.drop_linear, args.randomise_pose
                )
                rows.append(row)
                lo, hi = row["band"]  # type: ignore[misc]
                means = row["mean_nees"]
                print(
                    f"{scene.name:<12} {method:<15} {protocol:<9} {lo:6.2f}–{hi:<6.2f} "
                    + " ".join(f"{means[k]:10.3g}" for k in KINDS)  # type: ignore[index]
                    + f"  {row['flagged']:>3}/{reps}  {row['weak_directions']}",
                    flush=True,
                )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    print("\n" + markdown_table(rows))


def markdown_table(rows: list[dict[str, object]]) -> str:
    """The rows as the table of ``docs/calibration.md``."""
    out = [
        "| scene | method | protocol | 95 % band | hessian | censi | block | **calibrated** "
        "| calibrated / dof | flagged degenerate |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        lo, hi = row["band"]  # type: ignore[misc]
        means: dict[str, float] = row["mean_nees"]  # type: ignore[assignment]
        dof = int(row["dof"])  # type: ignore[call-overload]
        cal = means["calibrated"]
        ratio = cal / dof
        mark = "in band" if lo <= cal <= hi else ("in ×2" if 0.5 <= ratio <= 2.0 else None)
        judged = f"{ratio:.2f} ({mark})" if mark else f"{ratio:.2f} ✗"
        names: dict[str, int] = row["weak_directions"]  # type: ignore[assignment]
        flagged = f"{row['flagged']}/{row['realisations']}"
        if names:
            top, count = max(names.items(), key=lambda kv: kv[1])
            flagged += f" {top} ×{count}" + (", …" if len(names) > 1 else "")
        cells = [f"{means[k]:.3g}" for k in KINDS if k != "calibrated"]
        out.append(
            f"| {row['scene']} | {row['method']} | {row['protocol']} | {lo:.2f}–{hi:.2f} | "
            + " | ".join(cells)
            + f" | **{cal:.3g}** | {judged} | {flagged} |"
        )
    return "\n".join(out)


if __name__ == "__main__":
    main()
