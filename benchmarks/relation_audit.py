"""Which Kümmerle relations do the scans themselves contradict? An audit of the reference.

A relation error is only as good as the relation. For every relation of a Freiburg log (Intel,
ACES, the hospital ``fr-clinic`` in ``../shared/data/freiburg-slam-benchmark``) and a mapped
trajectory (``poses_tum.txt`` as ``scanreg map`` or ``freiburg_mapping.py --output`` write it),
scan t2 is laid onto scan t1 twice: at the relation and at the trajectory's relative pose, and
the fraction of scan t2's points within ``--within`` of a point of scan t1 is counted at each
(raw points, 0.1–40 m). A relation is *contradicted by the scans* when the trajectory's pose
explains at least 10 points in 100 more of scan t2 and at least twice the fraction the relation
does; the estimate is *contradicted* in the mirrored case. Printed per log: how many of each, the
mean relation error over all relations, over the contradicted ones and over the rest.

    .venv/bin/python benchmarks/relation_audit.py --poses OUT/hospital/poses_tum.txt \
        --log hospital [--within 0.05]

Nothing here changes the benchmark's figure: it says how much of it the reference may own.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import scanreg
from scanreg import SE2
from scanreg.eval.relations import Relations, read_relations
from scanreg.io import read_scans, read_trajectory

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
FILES = {
    "intel": ("intel.clf.bz2", "intel.relations"),
    "aces": ("aces.clf.bz2", "aces.relations"),
    "hospital": ("fr-clinic_robotlaser.clf.bz2", "fr-clinic.relations"),
}
#: The ranges each scan's points are read between (m).
MIN_RANGE, MAX_RANGE = 0.1, 40.0
#: A pose "explains more" of a scan by at least this fraction, and by this factor.
MARGIN, FACTOR = 0.10, 2.0


def planar(matrix: np.ndarray) -> SE2:
    """The planar part of a 4×4 pose."""
    return SE2.from_vector([matrix[0, 3], matrix[1, 3], math.atan2(matrix[1, 0], matrix[0, 0])])


def freiburg_log(name: str) -> tuple[list[Any], Relations, dict[float, int], SE2]:
    """Log ``name``'s laser scans, its relations, each scan's index by its timestamp, and the
    laser's mounting on the robot: relations and mapped poses are of the robot, the scans in
    the laser's frame (the hospital's laser is 0.22 m ahead of the robot's centre; Intel's and
    ACES' at it)."""
    log_file, relations_file = FILES[name]
    folder = DATA / "freiburg-slam-benchmark"
    log = read_scans(folder / log_file)
    relations = read_relations(folder / relations_file)
    lasers = [s for s in log.scans if s.kind in ("FLASER", "ROBOTLASER1")]
    index = {s.timestamp: k for k, s in enumerate(lasers)}
    first = lasers[0]
    assert first.odometry_se2 is not None and first.laser_se2 is not None
    return lasers, relations, index, first.odometry_se2.inverse() @ first.laser_se2


def audit(name: str, poses_file: Path, within: float) -> None:
    lasers, relations, index, mount = freiburg_log(name)
    estimate = read_trajectory(poses_file, "tum")
    assert estimate.timestamps is not None
    mapped = {
        float(t): planar(np.asarray(p))
        for t, p in zip(estimate.timestamps, estimate.poses, strict=True)
    }

    points: dict[int, np.ndarray] = {}
    targets: dict[int, scanreg.PreparedTarget] = {}

    def scan(k: int) -> np.ndarray:
        if k not in points:
            points[k] = lasers[k].to_points(MIN_RANGE, MAX_RANGE)
        return points[k]

    def explained(source: int, target: int, pose: SE2) -> float:
        if target not in targets:
            targets[target] = scanreg.prepare(scan(target))
        near, _ = targets[target].index.nearest(
            np.ascontiguousarray(pose.apply(scan(source))), within
        )
        return float((np.asarray(near) >= 0).mean())

    errors, by_relation, by_estimate = [], [], []
    for k in range(len(relations)):
        t1, t2 = float(relations.t1[k]), float(relations.t2[k])
        if t1 not in index or t2 not in index or t1 not in mapped or t2 not in mapped:
            continue
        relation = planar(relations.poses[k])
        ours = mapped[t1].inverse() @ mapped[t2]
        errors.append(float(np.linalg.norm((relation.inverse() @ ours).translation)))
        a, b = index[t1], index[t2]
        at_relation = explained(b, a, mount.inverse() @ relation @ mount)
        at_ours = explained(b, a, mount.inverse() @ ours @ mount)
        by_relation.append(at_ours >= at_relation + MARGIN and at_ours >= FACTOR * at_relation)
        by_estimate.append(at_relation >= at_ours + MARGIN and at_relation >= FACTOR * at_ours)
    err = np.array(errors)
    bad_ref, bad_ours = np.array(by_relation), np.array(by_estimate)
    rest = ~bad_ref & ~bad_ours

    def mean(mask: np.ndarray) -> str:
        return f"{err[mask].mean():.4f}" if mask.any() else "–"

    print(
        f"| {name} | {len(err)} | {mean(np.ones_like(rest))} | {bad_ref.sum()} | {mean(bad_ref)} "
        f"| {bad_ours.sum()} | {mean(bad_ours)} | {mean(rest)} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", choices=sorted(FILES), required=True)
    parser.add_argument("--poses", type=Path, required=True, help="a TUM trajectory")
    parser.add_argument("--within", type=float, default=0.05, help="m (default 0.05)")
    args = parser.parse_args()
    print(
        "| log | relations | mean error (m) | contradicted by the scans | their mean | "
        "estimate contradicted | its mean | mean over the rest |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    audit(args.log, args.poses, args.within)


if __name__ == "__main__":
    main()
