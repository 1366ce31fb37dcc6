"""Trajectory evaluation: ATE, RPE, the KITTI odometry metric and Kümmerle relations."""

from __future__ import annotations

from ._stats import ErrorStatistics
from .align import Similarity, align, associate, umeyama
from .ate import AbsoluteTrajectoryError, absolute_trajectory_error
from .kitti import KITTI_LENGTHS, KittiOdometryError, kitti_odometry_error
from .relations import RelationError, Relations, read_relations, relation_error
from .rpe import RelativePoseError, pairs_by_distance, pairs_by_frames, relative_pose_error

__all__ = [
    "KITTI_LENGTHS",
    "AbsoluteTrajectoryError",
    "ErrorStatistics",
    "KittiOdometryError",
    "RelationError",
    "Relations",
    "RelativePoseError",
    "Similarity",
    "absolute_trajectory_error",
    "align",
    "associate",
    "kitti_odometry_error",
    "pairs_by_distance",
    "pairs_by_frames",
    "read_relations",
    "relation_error",
    "relative_pose_error",
    "umeyama",
]
