"""Is the 2D covariance calibrated on clouds that are not one scan from one viewpoint?

Issue 41, item 4. Three kinds of 2D pairs with exact truth, each registered with the default
point-to-line call from the identity (the truth a random step within ±0.2 m, ±3°):

* *walls*: a rectangular room 8 × 5 m with a 0.6 × 0.4 m obstacle, sampled uniformly along
  every outline (both sides of the obstacle seen: nothing occludes anything;
  :func:`scanreg.simulate.surface_samples`), 1 cm noise, two independent samplings, the frame's
  origin inside the room (``--spacing``: mean point spacing);
* *submaps*: two submaps of an office floor plan (``floor_plan``), each five ``sick_lms200``
  scans from a short path merged in its first scan's frame (the paths pass the same rooms
  from different places), registered to each other;
* *scans*: single scans of the same floor plans from two poses a small step apart.

Printed per kind: pairs, accepted, mean NEES of the default (``calibrated``) covariance and of
``censi`` and ``block`` over the accepted pairs (ideal 3), and the share of accepted pairs
outside χ²(3) at 99.9 %.

    .venv/bin/python benchmarks/cloud_covariance.py [--pairs 40] [--spacing 0.05]
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
KINDS = ("calibrated", "censi", "block")


def _truth(rng: np.random.Generator) -> SE2:
    lim = np.array([0.2, 0.2, math.radians(3.0)])
    return SE2.from_vector(rng.uniform(-lim, lim))


def walls(count: int, spacing: float) -> list[tuple]:
    room = (
        sim.SceneBuilder(2)
        .polyline([(0, 0), (8, 0), (8, 5), (0, 5)], closed=True)
        .box((5.0, 2.5), (0.6, 0.4), label="obstacle")
        .build()
    )
    rng = np.random.default_rng(1)
    out = []
    for k in range(count):
        frame = SE2.from_vector([rng.uniform(2.5, 4.0), rng.uniform(1.5, 3.5), 0.0])
        truth = _truth(rng)
        tgt = sim.surface_samples(room, spacing, noise=0.01, seed=2 * k)
        src = sim.surface_samples(room, spacing, noise=0.01, seed=2 * k + 1)
        out.append(
            (
                np.ascontiguousarray((frame @ truth).inverse().apply(src)),
                np.ascontiguousarray(frame.inverse().apply(tgt)),
                truth,
            )
        )
    return out


def _merged(scene: sim.Scene, poses: list[SE2], seed: int) -> np.ndarray:
    laser = sim.LaserModel.preset("sick_lms200")
    parts = []
    for i, pose in enumerate(poses):
        scan = sim.simulate_scan(scene, laser, pose, seed=seed, scan_index=i)
        parts.append((poses[0].inverse() @ pose).apply(scan.points))
    return np.ascontiguousarray(np.vstack(parts))


def submaps(count: int) -> list[tuple]:
    rng = np.random.default_rng(2)
    out = []
    for k in range(count):
        scene = sim.floor_plan(seed=k % 6, num_people=0)
        base = SE2.from_vector([rng.uniform(3, 7), rng.uniform(3, 5), rng.uniform(-3, 3)])

        def path(start: SE2, turn: float) -> list[SE2]:
            return [start @ SE2.from_vector([0.4 * i, 0.0, turn * i]) for i in range(5)]

        a = path(base, 0.3)
        b_start = base @ SE2.from_vector([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 0.5])
        b = path(b_start, -0.3)
        truth_ab = a[0].inverse() @ b[0]
        step = _truth(rng)
        # Submap B expressed in a frame `step` off submap A's: the truth is `step`, a small
        # step from the identity start.
        src = _merged(scene, b, seed=2 * k + 1)
        tgt = _merged(scene, a, seed=2 * k)
        moved = step.inverse() @ truth_ab
        out.append((np.ascontiguousarray(moved.apply(src)), tgt, step))
    return out


def scans(count: int) -> list[tuple]:
    rng = np.random.default_rng(3)
    laser = sim.LaserModel.preset("sick_lms200")
    out = []
    for k in range(count):
        scene = sim.floor_plan(seed=k % 6, num_people=0)
        pose = SE2.from_vector([rng.uniform(3, 7), rng.uniform(3, 5), rng.uniform(-3, 3)])
        truth = _truth(rng)
        tgt = sim.simulate_scan(scene, laser, pose, seed=k, scan_index=0).points
        src = sim.simulate_scan(scene, laser, pose @ truth, seed=k, scan_index=1).points
        out.append((np.ascontiguousarray(src), np.ascontiguousarray(tgt), truth))
    return out


def _nees(err: np.ndarray, cov: np.ndarray) -> float:
    """``errᵀ cov⁻¹ err`` over the covariance's eigenbasis; infinite for a non-finite one or an
    error along a direction it calls exact."""
    if not np.isfinite(cov).all():
        return math.inf
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    proj = vecs.T @ err
    tiny = vals <= 1e-15 * max(float(vals[-1]), 1e-300)
    if np.any(tiny & (np.abs(proj) > 1e-9)):
        return math.inf
    return float(np.sum(proj[~tiny] ** 2 / vals[~tiny]))


def row(name: str, pairs: list[tuple]) -> str:
    nees: dict[str, list[float]] = {k: [] for k in KINDS}
    accepted = 0
    for src, tgt, truth in pairs:
        res = scanreg.register(src, scanreg.prepare(tgt, normals=True), method="point_to_line")
        if res.verdict is None or not res.verdict.accepted:
            continue
        accepted += 1
        d = (res.pose.inverse() @ truth).log()  # type: ignore[operator]
        for k in KINDS:
            c = np.asarray(getattr(res.covariances, k))
            nees[k].append(_nees(d, c))
    if not accepted:
        return f"| {name} | {len(pairs)} | 0 | | | | |"
    cal = np.array(nees["calibrated"])
    return (
        f"| {name} | {len(pairs)} | {accepted} | **{np.mean(cal):.2f}** | "
        f"{np.mean(nees['censi']):.2f} | {np.mean(nees['block']):.2f} | "
        f"{np.mean(cal > CHI2_999):.0%} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument("--spacing", type=float, nargs="*", default=[0.1, 0.05, 0.02])
    args = parser.parse_args()
    print(
        "| cloud | pairs | accepted | mean NEES calibrated (default) | censi | block "
        "| outside 99.9 % |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for spacing in args.spacing:
        print(row(f"walls, {spacing:g} m spacing", walls(args.pairs, spacing)), flush=True)
    print(row("submaps (5 scans each)", submaps(args.pairs)), flush=True)
    print(row("single scans", scans(args.pairs)), flush=True)


if __name__ == "__main__":
    main()
