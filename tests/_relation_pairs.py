"""Freiburg Kümmerle relations as registration pairs, shared by the tests of the guard, the
refinement and the verdict (tests/test_slide.py, tests/test_pinned.py): scan t2 against scan
t1, the relation as truth (the laser sits at the robot's centre on Intel and ACES)."""

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


@cache
def relation_log(name: str) -> tuple[Any, Any, dict[float, int]]:
    """The log ``name`` (``intel``, ``aces``), its relations and each laser scan's index by
    its timestamp."""
    folder = data_dir("freiburg-slam-benchmark")
    log = read_scans(folder / f"{name}.clf.bz2")
    relations = read_relations(folder / f"{name}.relations")
    stamps = {s.timestamp: i for i, s in enumerate(log.scans) if s.kind == "FLASER"}
    return log, relations, stamps


def relation_pair(name: str, k: int) -> tuple[np.ndarray, Any, SE2]:
    """Relation ``k``: scan t2 (source), scan t1 prepared (target), the relation pose."""
    log, relations, stamps = relation_log(name)
    i1, i2 = stamps[float(relations.t1[k])], stamps[float(relations.t2[k])]
    m = relations.poses[k]
    relation = SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])
    source = log.scans[i2].to_points(0.1, 40.0)
    target = scanreg.prepare(log.scans[i1].to_points(0.1, 40.0), normals=True)
    return source, target, relation


def pose_error(pose: Any, truth: SE2) -> tuple[float, float]:
    """Translation (m) and rotation (°) of ``pose`` from ``truth``."""
    err = (pose.inverse() @ truth).log()
    return float(np.hypot(err[0], err[1])), math.degrees(abs(float(err[2])))
