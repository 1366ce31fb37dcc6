"""Normalised errors of scanreg's covariances on real LiDAR data (KITTI 00, frames 0–15).

Two kinds of pairs, because the ground truth of these 16 demo frames is doubtful except for
the last pairs (see the data README):

* ``gt``: consecutive frames 12→13, 13→14, 14→15 against ``poses.txt`` (truth good to a few cm);
* ``constructed``: each frame k against itself moved by a known pose ``T`` (0.8 m forward, 0.5 m
  sideways, 1° yaw), each copy a different random half of the points, voxelised after moving (so
  the two samplings differ, as between real scans) — real geometry, exact truth.

Prints, per pair kind and covariance kind, the mean NEES and the per-axis RMS of the normalised
error ``δ_i / σ_i`` (1 = calibrated).

    .venv/bin/python benchmarks/kitti_calibration.py [--data /work/shared/data]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE3, io

KINDS = ("hessian", "censi", "block", "calibrated")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--data", default=os.environ.get("SCANREG_DATA", "/work/shared/data"))
    parser.add_argument("--method", default="point_to_plane")
    args = parser.parse_args()
    seq = Path(args.data) / "kitti-odometry-00-frames-000-015"
    scans = [io.read_points(p).finite().points for p in sorted((seq / "velodyne").glob("*.bin"))]
    calib = io.read_kitti_calib(seq / "calib.txt")
    tr = calib.T_cam0_velo.as_matrix()
    gt = np.linalg.inv(tr) @ io.read_kitti_poses(seq / "poses.txt").poses @ tr
    voxel = 0.5

    def vox(p: np.ndarray) -> np.ndarray:
        return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(p), voxel).points

    rows: dict[str, list[tuple[np.ndarray, object]]] = {"gt": [], "constructed": []}
    for k in (12, 13, 14):
        truth = SE3.from_matrix(np.linalg.inv(gt[k]) @ gt[k + 1])  # T_k_(k+1)
        target = scanreg.prepare(vox(scans[k]), covariances=args.method == "gicp")
        res = scanreg.register(
            vox(scans[k + 1]), target, method=args.method, init=truth @ SE3.from_vector(
                [0.1, 0.0, 0.0, 0.0, 0.0, 0.0]), max_correspondence_distance=1.5,
        )  # fmt: skip
        rows["gt"].append(((res.pose.inverse() @ truth).log(), res))  # type: ignore[operator]
    rng = np.random.default_rng(0)
    truth = SE3.from_vector([0.8, 0.5, 0.0, 0.0, 0.0, np.deg2rad(1.0)])  # T_target_source
    for k in range(len(scans)):
        pts = scans[k]
        half = rng.permutation(len(pts))
        src = vox(pts[half[: len(pts) // 2]])
        tgt = vox(truth.apply(pts[half[len(pts) // 2 :]]))
        target = scanreg.prepare(tgt, covariances=args.method == "gicp")
        res = scanreg.register(src, target, method=args.method, max_correspondence_distance=1.5)
        rows["constructed"].append(((res.pose.inverse() @ truth).log(), res))  # type: ignore[operator]
    print(f"method {args.method}, voxel {voxel} m; per-axis RMS of δ_i/σ_i (x y z roll pitch yaw)")
    for name, items in rows.items():
        flagged = sum(1 for _, r in items if r.degeneracy.degenerate)  # type: ignore[attr-defined]
        print(f"\n{name}: {len(items)} pairs, flagged degenerate {flagged}, "
              f"NEES 95% band {scanreg.quality.nees_band(6, len(items))}")  # fmt: skip
        for kind in KINDS:
            nees, z = [], []
            for d, r in items:
                cov = getattr(r.covariances, kind)  # type: ignore[attr-defined]
                nees.append(float(d @ np.linalg.solve(cov, d)))
                z.append(d / np.sqrt(np.diag(cov)))
            zr = np.sqrt(np.mean(np.array(z) ** 2, axis=0))
            print(
                f"  {kind:>10}: mean NEES {np.mean(nees):9.3g}   z-RMS "
                + " ".join(f"{v:6.2f}" for v in zr)
            )


if __name__ == "__main__":
    main()
