"""Do the default verdict thresholds separate good registrations from bad ones?

Simulated pairs (2D L-shaped room, 2D office floor plan, 3D street; fresh noise and sampling
per pair) in four situations, each registered with default settings (``max_correspondence_distance``
1.0 m) and judged with the default :class:`~scanreg.VerdictThresholds` (``max_inlier_rmse`` set by
``--rmse-fraction``):

* ``good``: initial guess within 0.2 m / 2° of the truth;
* ``far init``: initial guess 1.5–3 m / 10–30° off (ICP lands in a wrong minimum or stops);
* ``low overlap``: the target keeps only a 30 % slice of its points;
* ``wrong place``: the target is a scan taken 6–10 m away (a false loop closure).

A registration counts as *correct* when its error is below 0.1 m and 1°. Printed per
situation: how many were correct, how many accepted, and the accepted-but-wrong count (false
accepts) and rejected-but-correct count (false rejects), plus the quantiles of overlap and
inlier RMSE that the thresholds cut.

    .venv/bin/python benchmarks/verdict_thresholds.py [--pairs 40] [--rmse-fraction 0.25] \
        [--markdown]

``--markdown`` prints the table of ``benchmarks/README.md`` (the top reasons and the notes on
the wrong registrations follow it).
"""

from __future__ import annotations

import argparse
import os
from collections import Counter

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument(
        "--rmse-fraction",
        type=float,
        default=0.5,
        help="max_inlier_rmse as a fraction of the 1 m gate (default 0.5, the library default)",
    )
    parser.add_argument(
        "--markdown", action="store_true", help="print the table as benchmarks/README.md shows it"
    )
    args = parser.parse_args()
    thresholds = scanreg.VerdictThresholds(max_inlier_rmse=args.rmse_fraction * 1.0)
    laser = sim.LaserModel.preset("laser_360")
    lidar = sim.LidarModel.preset("vlp16")
    scenes = {
        # An L-shaped room: a square one is ambiguous by 90° and the basin probe rejects it.
        "2D L-room": (
            2,
            sim.SceneBuilder(2)
            .polyline([(-5, -5), (5, -5), (5, 1), (1, 1), (1, 5), (-5, 5)], closed=True)
            .build(),
            SE2.from_vector([-1.5, -1.0, 0.3]),
        ),
        "2D office": (2, sim.floor_plan(seed=1), None),
        "3D street": (3, sim.street(seed=4), SE3.from_vector([0, 1.75, 1.73, 0, 0, 0])),
    }
    rng = np.random.default_rng(0)

    def scan(dim: int, scene: object, pose: object, seed: int) -> np.ndarray:
        if dim == 2:
            return np.ascontiguousarray(sim.simulate_scan(scene, laser, pose, seed=seed).points)  # type: ignore[arg-type]
        pts = sim.simulate_sweep(scene, lidar, pose, seed=seed).points  # type: ignore[arg-type]
        return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(pts), 0.3).points

    notes: list[str] = []  # with --markdown: printed after the table, which they would break
    if args.markdown:
        print(
            "| scene | situation | pairs | correct | accepted | false accepts | false rejects "
            "| overlap q10/q50/q90 | inlier RMSE (m) q10/q50/q90 |"
        )
        print("|---|---|---:|---:|---:|---:|---:|---|---|")
    else:
        print(
            f"{'scene':<10} {'situation':<12} {'n':>3} {'correct':>7} {'accepted':>8} "
            f"{'false acc':>9} {'false rej':>9}  overlap q10/q50/q90   RMSE q10/q50/q90  "
            "top reasons"
        )
    for name, (dim, scene, pose_a) in scenes.items():
        if pose_a is None:  # the office: a point in its corridor
            pose_a = SE2.from_vector([6.0, 0.0, 0.0])
        dof = 3 if dim == 2 else 6
        cls = SE2 if dim == 2 else SE3
        for situation in ("good", "far init", "low overlap", "wrong place"):
            stats = Counter()
            overlaps, rmses, reasons = [], [], Counter()
            wrong_pts = []
            for k in range(args.pairs):
                step_v = np.zeros(dof)
                step_v[:2] = rng.uniform(-0.3, 0.3, 2)
                step_v[-1] = np.deg2rad(rng.uniform(-3, 3))
                step = cls.from_vector(step_v)
                pose_b = pose_a @ step  # type: ignore[operator]
                if situation == "wrong place":
                    off = np.zeros(dof)
                    ang = rng.uniform(0, 2 * np.pi)
                    off[:2] = rng.uniform(6, 10) * np.array([np.cos(ang), np.sin(ang)])
                    pose_b = pose_b @ cls.from_vector(off)
                src = scan(dim, scene, pose_a, 2 * k)
                tgt = scan(dim, scene, pose_b, 2 * k + 1)
                if situation == "low overlap":
                    key = tgt[:, 0] if k % 2 else tgt[:, 1]
                    lo = np.quantile(key, 0.35)
                    tgt = np.ascontiguousarray(tgt[(key >= lo) & (key <= np.quantile(key, 0.65))])
                truth = step.inverse()
                err_v = np.zeros(dof)
                if situation == "far init":
                    ang = rng.uniform(0, 2 * np.pi)
                    err_v[:2] = rng.uniform(1.5, 3.0) * np.array([np.cos(ang), np.sin(ang)])
                    err_v[-1] = np.deg2rad(rng.uniform(10, 30)) * rng.choice([-1, 1])
                else:
                    err_v[:2] = rng.normal(0, 0.1, 2)
                    err_v[-1] = np.deg2rad(rng.normal(0, 1.0))
                init = truth @ cls.from_vector(err_v)  # type: ignore[operator]
                res = scanreg.register(
                    src, tgt, init=init, max_correspondence_distance=1.0, thresholds=thresholds
                )
                d = (res.pose.inverse() @ truth).log()  # type: ignore[operator]
                correct = (
                    situation != "wrong place"
                    and np.linalg.norm(d[:dim]) < 0.1
                    and np.linalg.norm(d[dim:]) < np.deg2rad(1.0)
                )
                assert res.verdict is not None and res.quality is not None
                acc = res.verdict.accepted
                stats["n"] += 1
                stats["correct"] += correct
                stats["accepted"] += acc
                stats["false_acc"] += acc and not correct
                stats["false_rej"] += (not acc) and correct
                overlaps.append(res.quality.overlap)
                rmses.append(res.quality.residual_rmse)
                if not correct:
                    wrong_pts.append((res.quality.overlap, res.quality.residual_rmse))
                for r in res.verdict.reasons:
                    reasons[r.split(" ")[0]] += 1
            oq = np.nanquantile(overlaps, [0.1, 0.5, 0.9])
            rq = np.nanquantile(np.array(rmses, dtype=float), [0.1, 0.5, 0.9])
            quantiles = (
                f"{oq[0]:.2f}/{oq[1]:.2f}/{oq[2]:.2f}",
                f"{rq[0]:.3f}/{rq[1]:.3f}/{rq[2]:.3f}",
            )
            top = dict(reasons.most_common(3))
            if args.markdown:
                print(
                    f"| {name} | {situation} | {stats['n']} | {stats['correct']} | "
                    f"{stats['accepted']} | {stats['false_acc']} | {stats['false_rej']} | "
                    f"{quantiles[0]} | {quantiles[1]} |",
                    flush=True,
                )
                notes.append(f"{name}, {situation}: top reasons {top}")
            else:
                print(
                    f"{name:<10} {situation:<12} {stats['n']:>3} {stats['correct']:>7} "
                    f"{stats['accepted']:>8} {stats['false_acc']:>9} {stats['false_rej']:>9}  "
                    f"{quantiles[0]}       {quantiles[1]}  {top}",
                    flush=True,
                )
            if wrong_pts and situation != "low overlap":
                w = np.array(wrong_pts)
                note = (
                    f"wrong ones: overlap max {np.nanmax(w[:, 0]):.2f}, "
                    f"RMSE min {np.nanmin(w[:, 1]):.3f}; of those with overlap >= 0.5, "
                    f"RMSE min {np.nanmin(np.where(w[:, 0] >= 0.5, w[:, 1], np.inf)):.3f}"
                )
                if args.markdown:
                    notes.append(f"{name}, {situation}: {note}")
                else:
                    print(f"{'':<10} {'':<12} {note}")
    for note in notes:
        print(note)


if __name__ == "__main__":
    main()
