"""Vectorised operations on stacks of homogeneous 4×4 poses (N, 4, 4)."""

from __future__ import annotations

import numpy as np

from .._validate import FloatArray


def inverse(poses: FloatArray) -> FloatArray:
    """Inverse of rigid poses using ``Rᵀ`` (exact for rotations)."""
    out = np.zeros_like(poses)
    rt = np.swapaxes(poses[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, poses[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def relative(a: FloatArray, b: FloatArray) -> FloatArray:
    """``inv(a) @ b`` for stacks of poses: ``b`` expressed in the frame of ``a``."""
    out: FloatArray = inverse(a) @ b
    return out


def rotation_angle(poses: FloatArray) -> FloatArray:
    """Rotation angle in radians, in ``[0, π]``, of each pose.

    ``atan2(|sin θ|, cos θ)`` from the skew and trace parts of ``R``: accurate near 0 and π,
    where ``arccos((tr R - 1) / 2)`` loses half the digits.
    """
    r = poses[..., :3, :3]
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    sin = np.linalg.norm(skew, axis=-1) / 2.0
    out: FloatArray = np.arctan2(sin, cos)
    return out


def path_lengths(positions: FloatArray) -> FloatArray:
    """Accumulated distance along the path, starting at 0: shape (N,)."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    out: FloatArray = np.concatenate([[0.0], np.cumsum(steps)])
    return out
