"""NDT-3D against our GICP and point-to-plane: accuracy, time, basin, and localization.

Run:

    RAYON_NUM_THREADS=2 .venv/bin/python benchmarks/ndt3d.py [--directions 3] [--frames 12]

1. Pairs: the outdoor pair against its reference, and KITTI 00 scans k -> k+1 (k = 0, 4, 8, 12)
   against the ground-truth poses (``poses.txt``, camera frame moved to the LiDAR by
   ``calib.txt``'s ``Tr``). Source and target gridded at 0.25 m; every method starts at the
   identity (KITTI: ~0.8 m of motion between scans) and gets <= 50 iterations. NDT: 1 m cells,
   two levels (2 m, 1 m), the target's Gaussians built once (not timed, as the ICP methods'
   prepared target is not); GICP / point-to-plane: gate 1 m, k = 20. Times are medians over
   three alternating rounds; the ratio column is NDT / it per pair (median over pairs).
2. Basin: the outdoor pair and KITTI 0 -> 1 from the reference perturbed by a yaw of 0-30° and
   a horizontal offset of 0-2 m (``--directions`` random directions per cell); success: within
   10 cm / 1° of the method's own estimate from the reference (KITTI's reference is good to
   only 0.1-0.2 m: its scans are not deskewed, and all three methods agree within 2 cm on a
   pose 0.12-0.19 m from it).
3. Localization: the simulated street (40 sweeps at 5 m/s, the prior map every third sweep,
   as ``tests/test_localizer.py``), :class:`scanreg.Localizer` from the truth at sweep 10 over
   ``--frames`` sweeps, ``method="ndt"`` against the default (GICP): error to the truth,
   accepted frames, time per frame.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "2")  # before scanreg starts its pool

import numpy as np
import scanreg
from scanreg import SE3, Localizer, OdometryConfig
from scanreg.io import read_points
from scanreg.io.sequences import SimulatedSequence
from scanreg.preprocess import voxel_downsample

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
VOXEL = 0.25
METHODS = ("ndt", "gicp", "point_to_plane")


def _errors(pose: Any, truth: SE3) -> tuple[float, float]:
    e = truth.inverse() @ pose
    return float(np.linalg.norm(e.translation)), math.degrees(float(e.angle))


def _kitti_pairs() -> list[tuple[str, np.ndarray, np.ndarray, SE3]]:
    root = DATA / "kitti-odometry-00-frames-000-015"
    calib = {
        line.split(":")[0]: np.array(line.split(":")[1].split(), dtype=float)
        for line in (root / "calib.txt").read_text().splitlines()
        if ":" in line
    }
    tr = np.eye(4)
    tr[:3] = calib["Tr"].reshape(3, 4)
    poses = np.loadtxt(root / "poses.txt").reshape(-1, 3, 4)

    def lidar_pose(k: int) -> np.ndarray:
        p = np.eye(4)
        p[:3] = poses[k]
        out: np.ndarray = np.linalg.inv(tr) @ p @ tr
        return out

    out = []
    for k in (0, 4, 8, 12):
        src = read_points(root / "velodyne" / f"{k + 1:06d}.bin").points
        tgt = read_points(root / "velodyne" / f"{k:06d}.bin").points
        truth = SE3.from_matrix(np.linalg.inv(lidar_pose(k)) @ lidar_pose(k + 1), atol=1e-4)
        out.append((f"kitti {k}->{k + 1}", src, tgt, truth))
    return out


def _pairs() -> list[tuple[str, np.ndarray, np.ndarray, SE3]]:
    root = DATA / "gicp-outdoor-scan-pair" / "small_gicp"
    ref = SE3.from_matrix(np.loadtxt(root / "T_target_source.txt"), atol=1e-4)
    outdoor = (
        "outdoor",
        read_points(root / "source.ply").points,
        read_points(root / "target.ply").points,
        ref,
    )
    return [outdoor, *_kitti_pairs()]


class _Targets:
    """Each method's prepared target for one pair (built once, outside the timing)."""

    def __init__(self, target: np.ndarray) -> None:
        self.ndt = scanreg.prepare_ndt(target, cell_size=1.0, levels=2)
        fine = voxel_downsample(target, VOXEL).points
        self.icp = scanreg.prepare(fine, normals=True, covariances=True, num_neighbors=20)

    def run(self, method: str, source: np.ndarray, init: SE3) -> SE3:
        if method == "ndt":
            pose = scanreg.match_ndt(source, self.ndt, init=init).pose
        else:
            pose = scanreg.register(
                source,
                self.icp,
                method=method,
                init=init,
                max_correspondence_distance=1.0,
                max_iterations=50,
            ).pose
        assert isinstance(pose, SE3)
        return pose


def accuracy(pairs: list[tuple[str, np.ndarray, np.ndarray, SE3]]) -> None:
    print("| pair | method | translation error m | rotation error ° | median time ms | NDT / it |")
    print("|---|---|---:|---:|---:|---:|")
    for name, src_raw, tgt, truth in pairs:
        src = voxel_downsample(src_raw, VOXEL).points
        targets = _Targets(tgt)
        times: dict[str, list[float]] = {m: [] for m in METHODS}
        poses: dict[str, SE3] = {}
        for round_ in range(3):
            order = METHODS[round_ % 3 :] + METHODS[: round_ % 3]
            for m in order:
                t0 = time.perf_counter()
                poses[m] = targets.run(m, src, SE3.identity())
                times[m].append(time.perf_counter() - t0)
        med = {m: statistics.median(v) for m, v in times.items()}
        for m in METHODS:
            et, er = _errors(poses[m], truth)
            print(
                f"| {name} | {m} | {et:.3f} | {er:.3f} | {1e3 * med[m]:.0f} "
                f"| {med['ndt'] / med[m]:.2f} |"
            )


def basin(pairs: list[tuple[str, np.ndarray, np.ndarray, SE3]], directions: int) -> None:
    yaws = (0.0, 10.0, 20.0, 30.0)
    offsets = (0.5, 1.0, 2.0)
    rng = np.random.default_rng(7)
    print("| pair | method | " + " | ".join(f"{y:.0f}°" for y in yaws) + " | all |")
    print("|---|---|" + "---:|" * (len(yaws) + 1))
    for name, src_raw, tgt, truth in pairs:
        src = voxel_downsample(src_raw, VOXEL).points
        targets = _Targets(tgt)
        starts = []
        for yaw in yaws:
            for off in offsets:
                for _ in range(directions):
                    a = rng.uniform(0, 2 * math.pi)
                    sign = rng.choice([-1.0, 1.0])
                    delta = SE3.from_vector(
                        [off * math.cos(a), off * math.sin(a), 0, 0, 0, sign * math.radians(yaw)]
                    )
                    starts.append((yaw, truth @ delta))
        for m in METHODS:
            own = targets.run(m, src, truth)
            ok: dict[float, list[bool]] = {y: [] for y in yaws}
            for yaw, start in starts:
                et, er = _errors(targets.run(m, src, start), own)
                ok[yaw].append(et < 0.1 and er < 1.0)
            cells = [f"{100 * np.mean(ok[y]):.0f}%" for y in yaws]
            total = 100 * np.mean([v for y in yaws for v in ok[y]])
            print(f"| {name} | {m} | " + " | ".join(cells) + f" | {total:.0f}% |")


def localization(frames: int) -> None:
    seq = SimulatedSequence("street", num_frames=40, speed=5.0)
    gt = seq.ground_truth_at("start")
    prior = np.ascontiguousarray(
        np.vstack(
            [
                (gt[k][:3, :3] @ seq.sweep(k).points_deskewed.T).T + gt[k][:3, 3]
                for k in range(0, 40, 3)
            ]
        )
    )
    k0 = 10
    sweeps = [seq.sweep(k).points_deskewed for k in range(k0, k0 + frames)]
    print(
        "| localizer | frames | accepted | median error m | max error m | median ° | ms / frame |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for method in ("registration", "ndt"):
        loc = Localizer(prior, OdometryConfig(deskew=False), initial_pose=gt[k0], method=method)
        errs, rots, acc, times = [], [], 0, []
        for i, pts in enumerate(sweeps):
            t0 = time.perf_counter()
            res = loc.step(pts)
            times.append(time.perf_counter() - t0)
            et, er = _errors(res.pose, SE3.from_matrix(gt[k0 + i]))
            errs.append(et)
            rots.append(er)
            acc += res.verdict.accepted
        label = "NDT (1 m, 2 levels)" if method == "ndt" else "GICP (default)"
        print(
            f"| {label} | {frames} | {acc} | {statistics.median(errs):.4f} | {max(errs):.4f} "
            f"| {statistics.median(rots):.4f} | {1e3 * statistics.median(times):.0f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--directions", type=int, default=3)
    ap.add_argument("--frames", type=int, default=12)
    args = ap.parse_args()
    print(f"RAYON_NUM_THREADS={os.environ['RAYON_NUM_THREADS']}")
    pairs = _pairs()
    accuracy(pairs)
    print()
    basin([pairs[0], pairs[1]], args.directions)
    print()
    localization(args.frames)


if __name__ == "__main__":
    main()
