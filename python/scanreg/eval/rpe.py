"""Relative pose error (RPE), with pairs chosen by frame count or by travelled distance."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..io.trajectory import Trajectory
from . import _poses
from ._stats import ErrorStatistics
from .align import associate


@dataclass(frozen=True)
class RelativePoseError:
    """RPE over pose pairs ``(i, j)``.

    Attributes
    ----------
    translation : ErrorStatistics
        ``|trans(E_ij)|`` in metres, with ``E_ij = inv(inv(Q_i) Q_j) · inv(P_i) P_j``
        (``Q`` reference, ``P`` estimate).
    rotation_deg : ErrorStatistics
        Rotation angle of ``E_ij`` in degrees.
    pairs : (K, 2) int64
        Indices ``(i, j)`` into the associated trajectories.
    """

    translation: ErrorStatistics
    rotation_deg: ErrorStatistics
    pairs: NDArray[np.int64]


def pairs_by_frames(n: int, delta: int, *, all_pairs: bool = False) -> NDArray[np.int64]:
    """``(i, i + delta)`` for every ``i`` (all_pairs) or every ``delta``-th ``i``."""
    if delta < 1:
        raise ValueError(f"delta: must be >= 1 frame, got {delta}")
    starts = np.arange(0, n - delta, 1 if all_pairs else delta)
    return np.column_stack([starts, starts + delta]).astype(np.int64)


def pairs_by_distance(
    positions: NDArray[np.float64], delta: float, *, all_pairs: bool = False, tolerance: float = 0.0
) -> NDArray[np.int64]:
    """Pose pairs separated by ``delta`` metres of path length.

    Consecutive mode (default): walk the path, mark an index each time the distance
    travelled since the last mark reaches ``delta`` (the first mark is the first index where
    it does so from the start), and pair consecutive marks — the pairs do not overlap.

    All-pairs mode: for every ``i``, the later index whose path distance from ``i`` is closest
    to ``delta``, kept if it is within ``tolerance`` metres of it.
    """
    if not delta > 0:
        raise ValueError(f"delta: must be > 0 metres, got {delta}")
    dist = _poses.path_lengths(positions)
    if all_pairs:
        rows = []
        for i in range(len(dist) - 1):
            ahead = dist[i + 1 :] - dist[i]
            k = int(np.argmin(np.abs(ahead - delta)))
            if abs(ahead[k] - delta) <= tolerance:
                rows.append((i, i + 1 + k))
        return np.array(rows, dtype=np.int64).reshape(-1, 2)
    steps = np.diff(dist, prepend=0.0)
    marks, travelled = [], 0.0
    for i, step in enumerate(steps):
        travelled += float(step)
        if travelled >= delta:
            marks.append(i)
            travelled = 0.0
    return np.array(list(itertools.pairwise(marks)), dtype=np.int64).reshape(-1, 2)


def relative_pose_error(
    estimate: Trajectory,
    reference: Trajectory,
    *,
    delta: float = 1,
    unit: str = "frames",
    all_pairs: bool = False,
    tolerance: float = 0.0,
    path_from: str = "reference",
    max_time_difference: float = 0.01,
) -> RelativePoseError:
    """Relative pose error of ``estimate`` against ``reference`` (no alignment needed).

    Parameters
    ----------
    delta : separation of the pairs, in frames (``unit="frames"``, an integer) or in metres of
        path length (``unit="meters"``; see :func:`pairs_by_distance`).
    all_pairs : every start index instead of non-overlapping consecutive pairs.
    tolerance : metres; with ``unit="meters"`` and ``all_pairs`` the largest accepted
        difference between a pair's path distance and ``delta``.
    path_from : "reference" (default) or "estimate": whose path length selects the pairs with
        ``unit="meters"``. The evo result archives in scanreg's test data (evo of 2018) were
        computed with the estimate's path; use ``path_from="estimate"`` to reproduce them.
    """
    for name, value in (("estimate", estimate), ("reference", reference)):
        if not isinstance(value, Trajectory):
            raise TypeError(f"{name}: expected Trajectory, got {type(value).__name__}")
    ref, est = associate(reference, estimate, max_difference=max_time_difference)
    if unit == "frames":
        if int(delta) != delta:
            raise ValueError(f"delta: must be a whole number of frames, got {delta}")
        pairs = pairs_by_frames(len(ref), int(delta), all_pairs=all_pairs)
    elif unit in ("meters", "m"):
        if path_from not in ("reference", "estimate"):
            raise ValueError(f"path_from: expected 'reference' or 'estimate', got {path_from!r}")
        path = ref.positions if path_from == "reference" else est.positions
        pairs = pairs_by_distance(path, float(delta), all_pairs=all_pairs, tolerance=tolerance)
    else:
        raise ValueError(f"unit: expected 'frames' or 'meters', got {unit!r}")
    if len(pairs) == 0:
        raise ValueError(f"delta: {delta} {unit} leaves no pose pairs in {len(ref)} poses")
    i, j = pairs[:, 0], pairs[:, 1]
    q_rel = _poses.relative(ref.poses[i], ref.poses[j])
    p_rel = _poses.relative(est.poses[i], est.poses[j])
    error = _poses.relative(q_rel, p_rel)
    pairs.setflags(write=False)
    return RelativePoseError(
        translation=ErrorStatistics.from_errors(np.linalg.norm(error[:, :3, 3], axis=1)),
        rotation_deg=ErrorStatistics.from_errors(np.degrees(_poses.rotation_angle(error))),
        pairs=pairs,
    )
