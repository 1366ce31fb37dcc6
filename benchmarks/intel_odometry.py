"""2D scan-to-map odometry (scanreg.pipeline.Odometry2D) on the Intel subset, Kümmerle relations.

Rows: raw wheel odometry, scan-to-scan (correlative + point-to-line, as in
``intel_scan_to_scan.py``) and scan-to-map with the ICP and the correlative front end, both
with the wheel-odometry prior. Relations metric: mean ± std of the translational (m) and
rotational (deg) relation error, on the local (|t2 − t1| < 60 s), long-range and all relations;
and scans per second of the odometry.

Run: ``.venv/bin/python benchmarks/intel_odometry.py [--data ../shared/data]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from intel_scan_to_scan import LOCAL_SECONDS, _subset, scan_to_scan, trajectory
from scanreg import SE2
from scanreg.eval.relations import read_relations, relation_error
from scanreg.io import read_carmen
from scanreg.pipeline import Odometry2D, OdometryConfig2D


def scan_to_map(log: Any, config: OdometryConfig2D) -> tuple[list[SE2], float, int]:
    """Poses, seconds per scan and the number of rejected frames."""
    points = [s.to_points(0.1, 40.0) for s in log.scans]
    odo = Odometry2D(config)
    poses = []
    rejected = 0
    t0 = time.perf_counter()
    for k, pts in enumerate(points):
        prior = None if k == 0 else log.motion_prior(k - 1, k)
        frame = odo.step(pts, stamp=log.scans[k].timestamp, prior=prior)
        poses.append(frame.pose)
        rejected += not frame.verdict.accepted
    return poses, (time.perf_counter() - t0) / len(points), rejected


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    args = parser.parse_args()
    folder = args.data / "carmen-intel"
    log = read_carmen(folder / "intel_gfs_subset_clf_timestamps.clf")
    relations = read_relations(folder / "intel_gfs_subset.relations")
    rows: list[tuple[str, list[SE2], float, str]] = []
    rows.append(("raw odometry", [SE2.from_vector(v) for v in log.odometry_poses()], 0.0, ""))
    poses, per_scan = scan_to_scan(log, refine="point_to_line")
    rows.append(("scan-to-scan correlative + point-to-line", poses, per_scan, ""))
    configs = {
        "scan-to-map, ICP front end": OdometryConfig2D(front_end="icp"),
        "scan-to-map, correlative + ICP (Cauchy, 50 keyframes)": OdometryConfig2D(
            front_end="correlative", kernel="cauchy", max_keyframes=50
        ),
    }
    for name, config in configs.items():
        poses, per_scan, rejected = scan_to_map(log, config)
        rows.append((name, poses, per_scan, f"{rejected}"))
    print(f"Intel subset: {len(log)} scans, {len(relations)} relations")
    local = np.abs(relations.t2 - relations.t1) < LOCAL_SECONDS
    subsets = {"local": local, "long-range": ~local, "all": np.ones(len(relations), bool)}
    print("| method | relations | n | translation (m) | rotation (deg) | scans/s | rejected |")
    print("|---|---|---|---|---|---|---|")
    for name, poses, per_scan, rejected in rows:
        traj = trajectory(poses, log.timestamps)
        rate = f"{1.0 / per_scan:.0f}" if per_scan > 0 else "–"
        for label, mask in subsets.items():
            err = relation_error(traj, _subset(relations, mask))
            t, r = err.translation, err.rotation_deg
            print(
                f"| {name} | {label} | {len(err.used)} | {t.mean:.3f} ± {t.std:.3f} | "
                f"{r.mean:.2f} ± {r.std:.2f} | {rate} | {rejected} |"
            )


if __name__ == "__main__":
    main()
