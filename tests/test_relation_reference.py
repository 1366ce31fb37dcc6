"""What the Freiburg relations are worth as truth, judged by the scans alone
(benchmarks/relation_breakdown.py; benchmarks/README.md, "relation_breakdown.py").

Scan t2 laid on scan t1 at a relation and at the raw wheel odometry's relative pose: the mean
distance of scan t2's far returns (8–40 m, the heading's witness) to scan t1's, each capped.
The wheels never saw a scan, so a relation they beat is not the truth there. On Intel the
relations beat the wheels almost everywhere; on the hospital the wheels beat the relations
more often than the reverse — the reason the hospital's relation error is not read as our
map's error alone."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
import scanreg
from conftest import data_dir
from scanreg import SE2
from scanreg.eval.relations import read_relations
from scanreg.io import read_scans

FILES = {
    "intel": ("intel.clf.bz2", "intel.relations"),
    "hospital": ("fr-clinic_robotlaser.clf.bz2", "fr-clinic.relations"),
}
#: Every EVERY-th local relation (under 100 s apart) is judged.
EVERY = 10
FAR, MAX_RANGE, CAP, MARGIN = 8.0, 40.0, 0.3, 0.001


def _far_distance(target: Any, far: np.ndarray, pose: SE2, mount: SE2) -> float:
    """Mean distance (capped) of the far returns ``far`` of scan t2, laid at the robot's
    relative ``pose``, to scan t1 (``target``)."""
    laid = np.ascontiguousarray((mount.inverse() @ pose @ mount).apply(far))
    near, dist = target.index.nearest(laid, CAP)
    return float(np.where(np.asarray(near) >= 0, np.asarray(dist), CAP).mean())


@cache
def _judged(name: str) -> tuple[int, int, int]:
    """(judged, wheels better by MARGIN, relation better by MARGIN) over the sample."""
    folder = data_dir("freiburg-slam-benchmark")
    log_file, relations_file = FILES[name]
    lasers = [s for s in read_scans(folder / log_file).scans if s.kind in ("FLASER", "ROBOTLASER1")]
    relations = read_relations(folder / relations_file)
    index = {s.timestamp: k for k, s in enumerate(lasers)}
    first: Any = lasers[0]
    # Relations and wheels are of the robot; the scans of the laser (the hospital's 0.22 m ahead).
    mount = first.odometry_se2.inverse() @ first.laser_se2
    local = np.flatnonzero(relations.t2 - relations.t1 < 100.0)[::EVERY]
    judged = wheels_better = relation_better = 0
    for k in local:
        a, b = index[float(relations.t1[k])], index[float(relations.t2[k])]
        far = lasers[b].to_points(FAR, MAX_RANGE)
        if len(far) < 20:
            continue
        target = scanreg.prepare(lasers[a].to_points(0.1, MAX_RANGE))
        m = relations.poses[k]
        relation = SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])
        wheels = lasers[a].odometry_se2.inverse() @ lasers[b].odometry_se2
        at_relation = _far_distance(target, far, relation, mount)
        at_wheels = _far_distance(target, far, wheels, mount)
        judged += 1
        wheels_better += at_wheels < at_relation - MARGIN
        relation_better += at_relation < at_wheels - MARGIN
    return judged, wheels_better, relation_better


def test_intel_relations_beat_the_wheels() -> None:
    # Measured on the sample: 17 judged (Intel's rooms give few far returns), the relation
    # better on 15, the wheels on none (every local relation: 83 % against 8 %).
    judged, wheels_better, relation_better = _judged("intel")
    assert judged >= 15
    assert relation_better >= 0.8 * judged
    assert wheels_better <= 0.1 * judged


def test_hospital_wheels_beat_the_relations() -> None:
    # Measured on the sample: 256 judged, the wheels better on 132 (52 %), the relation on 55
    # (21 %); over every local relation with far returns (2569): 53 % against 20 %.
    judged, wheels_better, relation_better = _judged("hospital")
    assert judged >= 250
    assert wheels_better >= 0.47 * judged
    assert relation_better <= 0.25 * judged
    assert wheels_better >= 2 * relation_better
