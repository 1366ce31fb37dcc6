"""Absolute trajectory error (ATE / evo's APE)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.trajectory import Trajectory
from . import _poses
from ._stats import ErrorStatistics
from .align import Similarity, align, associate


@dataclass(frozen=True)
class AbsoluteTrajectoryError:
    """ATE after aligning the estimate to the reference.

    Attributes
    ----------
    translation : ErrorStatistics
        ``|t_ref_i - t_est_i|`` in metres (reference units), per associated pose.
    rotation_deg : ErrorStatistics
        Angle of ``inv(R_ref_i) R_est_i`` in degrees.
    alignment : Similarity
        The transform applied to the estimate (identity for ``alignment="none"``).
    aligned : Trajectory
        The associated estimate after alignment, in the reference frame.
    """

    translation: ErrorStatistics
    rotation_deg: ErrorStatistics
    alignment: Similarity
    aligned: Trajectory


def absolute_trajectory_error(
    estimate: Trajectory,
    reference: Trajectory,
    *,
    alignment: str = "se3",
    max_time_difference: float = 0.01,
) -> AbsoluteTrajectoryError:
    """Absolute trajectory error of ``estimate`` against ``reference``.

    Parameters
    ----------
    estimate, reference : Trajectory
        Poses ``T_world_body``. Paired by timestamp (nearest within ``max_time_difference``
        seconds) when both have timestamps, otherwise by index (equal lengths required).
    alignment : "se3" (default, Umeyama without scale), "sim3" (with scale; for monocular
        estimates) or "none".
    """
    for name, value in (("estimate", estimate), ("reference", reference)):
        if not isinstance(value, Trajectory):
            raise TypeError(f"{name}: expected Trajectory, got {type(value).__name__}")
    ref, est = associate(reference, estimate, max_difference=max_time_difference)
    aligned, sim = align(ref, est, alignment)
    error = _poses.relative(ref.poses, aligned.poses)
    return AbsoluteTrajectoryError(
        translation=ErrorStatistics.from_errors(np.linalg.norm(error[:, :3, 3], axis=1)),
        rotation_deg=ErrorStatistics.from_errors(np.degrees(_poses.rotation_angle(error))),
        alignment=sim,
        aligned=aligned,
    )
