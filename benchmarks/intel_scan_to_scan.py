"""2D scan-to-scan odometry on the Intel lab (carmen-intel), evaluated with Kümmerle relations.

The 902-scan subset ``intel_gfs_subset_clf_timestamps.clf`` carries the original intel.clf
timestamps and raw wheel odometry; ``intel_gfs_subset.relations`` holds the 90 relations
evaluable on it. Compared (relations metric: mean ± std of translational/rotational error):

* raw wheel odometry;
* scan-to-scan correlative matching (branch and bound, window around the odometry prior);
* correlative followed by point-to-line ICP (``scanreg.register``) or NDT (``scanreg.match_ndt``)
  from the correlative pose.

Run: ``.venv/bin/python benchmarks/intel_scan_to_scan.py [--data ../shared/data]``.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import scanreg
from scanreg import SE2
from scanreg.eval.relations import Relations, read_relations, relation_error
from scanreg.io import Trajectory, read_carmen

#: Relations closer in time than this are "local" (consecutive stretches of the log).
LOCAL_SECONDS = 60.0


def _subset(relations: Relations, mask: Any) -> Relations:
    return Relations(t1=relations.t1[mask], t2=relations.t2[mask], poses=relations.poses[mask])


def _matrix3d(pose: SE2) -> Any:
    m = np.eye(4)
    m[:2, :2] = pose.rotation
    m[:2, 3] = pose.translation
    return m


def trajectory(poses: list[SE2], stamps: Any) -> Trajectory:
    return Trajectory(poses=np.array([_matrix3d(p) for p in poses]), timestamps=stamps)


def scan_to_scan(
    log: Any,
    *,
    refine: str | None,
    resolution: float = 0.05,
    window: tuple[float, float, float] = (0.3, 0.3, math.radians(10)),
    min_range: float = 0.1,
    max_range: float = 40.0,
) -> tuple[list[SE2], float]:
    """Chain T_world_scan from consecutive matches; returns the poses and seconds per scan."""
    points = [s.to_points(min_range, max_range) for s in log.scans]
    poses = [SE2.identity()]
    t0 = time.perf_counter()
    for k in range(1, len(points)):
        prior = log.motion_prior(k - 1, k)
        res = scanreg.match_correlative(
            points[k],
            points[k - 1],
            init=prior,
            window=window,
            resolution=resolution,
            search="branch_and_bound",
        )
        pose = res.pose
        if refine == "ndt":
            ndt = scanreg.match_ndt(points[k], points[k - 1], init=pose, cell_size=1.0)
            step = ndt.pose.as_vector() - pose.as_vector()
            if ndt.converged and np.hypot(step[0], step[1]) < 3 * resolution:
                pose = ndt.pose
        if refine == "point_to_line":
            icp = scanreg.register(
                points[k],
                points[k - 1],
                method="point_to_line",
                init=pose,
                max_correspondence_distance=3 * resolution,
                kernel="huber",
            )
            step = icp.pose.as_vector() - pose.as_vector()
            # Keep the refinement only if it stays within a few cells of the correlative pose.
            if icp.converged and np.hypot(step[0], step[1]) < 3 * resolution:
                assert isinstance(icp.pose, SE2)
                pose = icp.pose
        poses.append(poses[-1] @ pose)
    return poses, (time.perf_counter() - t0) / max(len(points) - 1, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    args = parser.parse_args()
    folder = args.data / "carmen-intel"
    log = read_carmen(folder / "intel_gfs_subset_clf_timestamps.clf")
    relations = read_relations(folder / "intel_gfs_subset.relations")
    stamps = log.timestamps
    rows = []
    odom = [SE2.from_vector(v) for v in log.odometry_poses()]
    rows.append(("raw odometry", odom, 0.0))
    variants: tuple[tuple[str, str | None], ...] = (
        ("scan-to-scan correlative", None),
        ("correlative + point-to-line", "point_to_line"),
        ("correlative + NDT", "ndt"),
    )
    for name, refine in variants:
        poses, per_scan = scan_to_scan(log, refine=refine)
        rows.append((name, poses, per_scan))
    print(f"Intel subset: {len(log)} scans, {len(relations)} relations")
    # 69 local relations (|t2 − t1| < LOCAL_SECONDS) and 21 long-range/loop ones (> 300 s).
    local = np.abs(relations.t2 - relations.t1) < LOCAL_SECONDS
    subsets = {"all": np.ones(len(relations), bool), "local": local, "long-range": ~local}
    print("| method | relations | n | translation (m) | rotation (deg) | ms/scan |")
    print("|---|---|---|---|---|---|")
    for name, poses, per_scan in rows:
        traj = trajectory(poses, stamps)
        for label, mask in subsets.items():
            err = relation_error(traj, _subset(relations, mask))
            t, r = err.translation, err.rotation_deg
            print(
                f"| {name} | {label} | {len(err.used)} | {t.mean:.3f} ± {t.std:.3f} | "
                f"{r.mean:.2f} ± {r.std:.2f} | {per_scan * 1e3:.1f} |"
            )


if __name__ == "__main__":
    main()
