"""The KITTI odometry benchmark metric (Geiger et al., CVPR 2012, devkit ``evaluate_odometry``).

For every start frame (every ``step`` frames) and every segment length ``L``, the end frame
is the first one whose ground-truth path distance from the start exceeds ``L``; the error of
the segment is ``E = inv(inv(Q_a) Q_b) · inv(P_a) P_b``, reported as ``|t_E| / L`` and
``angle(R_E) / L``. The benchmark numbers are the means over all segments of all lengths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray
from ..io.trajectory import Trajectory
from . import _poses

#: The benchmark's segment lengths in metres.
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


@dataclass(frozen=True)
class KittiOdometryError:
    """KITTI segment errors.

    Attributes
    ----------
    translation_percent : float
        Mean over segments of ``100 · |t_E| / L``.
    rotation_deg_per_m : float
        Mean over segments of ``angle(R_E) / L`` in degrees per metre.
    lengths : (L,) float64
        The segment lengths evaluated (metres).
    translation_percent_by_length, rotation_deg_per_m_by_length : (L,) float64
        The same means per length (NaN where no segment of that length fits).
    segments : (S, 3) float64
        One row per segment: start index, length (m), and ``|t_E| / L``; with
        ``segment_rotation`` (S,) ``angle(R_E) / L`` in rad/m.
    """

    translation_percent: float
    rotation_deg_per_m: float
    lengths: FloatArray
    translation_percent_by_length: FloatArray
    rotation_deg_per_m_by_length: FloatArray
    segments: FloatArray
    segment_rotation: FloatArray


def kitti_odometry_error(
    estimate: Trajectory,
    reference: Trajectory,
    *,
    lengths: tuple[float, ...] = KITTI_LENGTHS,
    step: int = 10,
) -> KittiOdometryError:
    """The KITTI odometry metric of ``estimate`` against ``reference`` (paired by index).

    Parameters
    ----------
    lengths : segment lengths in metres; the default is the benchmark's 100…800 m. Short
        sequences need short segments (e.g. ``(5.0, 10.0)``).
    step : start frames are taken every ``step`` frames (benchmark: 10).
    """
    if len(estimate) != len(reference):
        raise ValueError(
            f"estimate, reference: need equal lengths, got {len(estimate)} and {len(reference)}"
        )
    if step < 1:
        raise ValueError(f"step: must be >= 1, got {step}")
    lens = np.array(lengths, dtype=np.float64)
    if lens.ndim != 1 or lens.size == 0 or not (lens > 0).all():
        raise ValueError(f"lengths: expected positive segment lengths, got {lengths}")
    dist = _poses.path_lengths(reference.positions)
    rows: list[tuple[int, float]] = []
    ends: list[int] = []
    for first in range(0, len(reference), step):
        for length in lens:
            # first frame whose path distance from `first` exceeds the segment length
            last = int(np.searchsorted(dist, dist[first] + length, side="right"))
            if last < len(reference):
                rows.append((first, float(length)))
                ends.append(last)
    if not rows:
        raise ValueError(
            f"lengths: no segment of {lengths} m fits in a {dist[-1]:.1f} m reference path"
        )
    a = np.array([r[0] for r in rows])
    b = np.array(ends)
    seg_len = np.array([r[1] for r in rows])
    error = _poses.relative(
        _poses.relative(reference.poses[a], reference.poses[b]),
        _poses.relative(estimate.poses[a], estimate.poses[b]),
    )
    t_err = np.linalg.norm(error[:, :3, 3], axis=1) / seg_len
    r_err = _poses.rotation_angle(error) / seg_len
    by_t = np.full(lens.size, np.nan)
    by_r = np.full(lens.size, np.nan)
    for k, length in enumerate(lens):
        sel: NDArray[np.bool_] = seg_len == length
        if sel.any():
            by_t[k] = 100.0 * t_err[sel].mean()
            by_r[k] = np.degrees(r_err[sel].mean())
    return KittiOdometryError(
        translation_percent=float(100.0 * t_err.mean()),
        rotation_deg_per_m=float(np.degrees(r_err.mean())),
        lengths=lens,
        translation_percent_by_length=by_t,
        rotation_deg_per_m_by_length=by_r,
        segments=np.column_stack([a, seg_len, t_err]),
        segment_rotation=r_err,
    )
