"""The relations metric of Kümmerle et al., "On measuring the accuracy of SLAM algorithms"
(Autonomous Robots 27, 2009).

A relation ``(t1, t2, δ*)`` is a reference relative pose ``δ* = inv(P*(t1)) P*(t2)`` (the
robot at ``t2`` in the frame of the robot at ``t1``). For an estimate ``P`` the relation error
is ``E = inv(δ*) · inv(P(t1)) P(t2)``; the metric reports its translational norm and rotation
angle, mean ± std over the relations (paper eq. 2 and its tables).

Relations files hold one relation per line: ``t1 t2 x y z roll pitch yaw`` (metres,
radians; ``R = Rz(yaw) Ry(pitch) Rx(roll)``). 2D files have ``z = roll = pitch = 0``; 2D
trajectories are evaluated embedded in the plane (``Trajectory.from_xyyaw``), which gives
exactly the SE(2) errors.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray
from ..io._common import FileFormatError, PathLike
from ..io.trajectory import Trajectory
from . import _poses
from ._stats import ErrorStatistics


def rpy_to_rotation(roll: FloatArray, pitch: FloatArray, yaw: FloatArray) -> FloatArray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` for arrays of angles (radians): shape (N, 3, 3)."""
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))  # fmt: skip
    r = np.empty((*np.shape(roll), 3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 0, 2] = (
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
    )
    r[..., 1, 0], r[..., 1, 1], r[..., 1, 2] = (
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
    )
    r[..., 2, 0], r[..., 2, 1], r[..., 2, 2] = -sp, cp * sr, cp * cr
    return r


@dataclass(frozen=True)
class Relations:
    """Reference relative poses: ``poses[k] = inv(P*(t1[k])) P*(t2[k])``, (M, 4, 4)."""

    t1: FloatArray
    t2: FloatArray
    poses: FloatArray

    def __len__(self) -> int:
        return int(self.t1.size)


def read_relations(path: PathLike) -> Relations:
    """Read a Kümmerle relations file (``t1 t2 x y z roll pitch yaw`` per line)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(p, "not a text file (invalid UTF-8)") from None
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) != 8:
            raise FileFormatError(p, f"line {number}: {len(words)} values, a relation has 8")
        try:
            values = [float(w) for w in words]
        except ValueError as exc:
            raise FileFormatError(p, f"line {number}: bad number: {exc}") from None
        if not np.isfinite(values).all():
            raise FileFormatError(p, f"line {number}: NaN or inf")
        rows.append(values)
    if not rows:
        raise FileFormatError(p, "no relations")
    table = np.array(rows)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :3] = rpy_to_rotation(table[:, 5], table[:, 6], table[:, 7])
    poses[:, :3, 3] = table[:, 2:5]
    return Relations(t1=table[:, 0].copy(), t2=table[:, 1].copy(), poses=poses)


@dataclass(frozen=True)
class RelationError:
    """Relation errors of an estimate.

    Attributes
    ----------
    translation : ErrorStatistics
        ``|t_E|`` per evaluated relation, metres (``mean ± std`` is the paper's number).
    rotation_deg : ErrorStatistics
        ``angle(R_E)`` per evaluated relation, degrees.
    used : (K,) int64
        Indices of the relations that were evaluated (both timestamps found).
    missing : int
        Relations skipped because a timestamp has no pose in the estimate.
    """

    translation: ErrorStatistics
    rotation_deg: ErrorStatistics
    used: NDArray[np.int64]
    missing: int


def _lookup(stamps: FloatArray, query: FloatArray, tolerance: float) -> NDArray[np.int64]:
    """Index of the pose at each query time, or -1 if none is within ``tolerance``."""
    order = np.argsort(stamps, kind="stable")
    s = stamps[order]
    pos = np.clip(np.searchsorted(s, query), 1, max(len(s) - 1, 1))
    lo = np.clip(pos - 1, 0, len(s) - 1)
    hi = np.clip(pos, 0, len(s) - 1)
    best = np.where(np.abs(s[lo] - query) <= np.abs(s[hi] - query), lo, hi)
    found = np.abs(s[best] - query) <= tolerance
    result: NDArray[np.int64] = np.where(found, order[best], -1).astype(np.int64)
    return result


def relation_error(
    estimate: Trajectory, relations: Relations, *, max_time_difference: float = 1e-4
) -> RelationError:
    """Kümmerle relation errors of ``estimate`` (which needs timestamps).

    A relation is evaluated when both its timestamps match an estimate pose within
    ``max_time_difference`` seconds (default 0.1 ms: relation files repeat the log's
    timestamps digit for digit, while neighbouring log messages can be 1 ms apart); the others
    are counted in ``missing``.
    """
    if not isinstance(estimate, Trajectory):
        raise TypeError(f"estimate: expected Trajectory, got {type(estimate).__name__}")
    if estimate.timestamps is None:
        raise ValueError("estimate: the relations metric needs timestamps")
    i = _lookup(estimate.timestamps, relations.t1, max_time_difference)
    j = _lookup(estimate.timestamps, relations.t2, max_time_difference)
    used = np.flatnonzero((i >= 0) & (j >= 0)).astype(np.int64)
    if used.size == 0:
        raise ValueError("relations: no relation has both timestamps in the estimate")
    delta = _poses.relative(estimate.poses[i[used]], estimate.poses[j[used]])
    error = _poses.relative(relations.poses[used], delta)
    return RelationError(
        translation=ErrorStatistics.from_errors(np.linalg.norm(error[:, :3, 3], axis=1)),
        rotation_deg=ErrorStatistics.from_errors(np.degrees(_poses.rotation_angle(error))),
        used=used,
        missing=int(len(relations) - used.size),
    )
