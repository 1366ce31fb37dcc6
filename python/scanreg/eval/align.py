"""Trajectory association and alignment (Umeyama 1991)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..io.trajectory import Trajectory
from ..transform import SE3


@dataclass(frozen=True)
class Similarity:
    """``p_ref ≈ scale · R p_est + t``: the alignment applied to an estimated trajectory.

    ``pose`` is the rigid part ``T_ref_est`` (``R``, ``t``); ``scale`` is 1 for SE(3).
    """

    pose: SE3
    scale: float

    def apply(self, trajectory: Trajectory) -> Trajectory:
        """The trajectory mapped into the reference frame (positions scaled, then moved)."""
        r, t = self.pose.rotation, self.pose.translation
        poses = np.array(trajectory.poses)
        poses[:, :3, :3] = r @ poses[:, :3, :3]
        poses[:, :3, 3] = self.scale * poses[:, :3, 3] @ r.T + t
        return Trajectory(poses, trajectory.timestamps)


def umeyama(source: Any, target: Any, *, with_scale: bool) -> Similarity:
    """Least-squares similarity (or rigid) transform mapping ``source`` onto ``target``.

    Minimises ``Σ |target_i - (s R source_i + t)|²`` (Umeyama 1991, eqs. 34–43).

    Parameters
    ----------
    source, target : (N, 3) float arrays, N >= 3, paired row by row.
    with_scale : estimate ``s`` (Sim(3)) or fix it to 1 (SE(3)).
    """
    x = np.asarray(source, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"source, target: expected equal (N, 3) shapes, got {x.shape}, {y.shape}")
    if x.shape[0] < 3:
        raise ValueError(f"source: need at least 3 positions to align, got {x.shape[0]}")
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    sigma_x = float(np.mean(np.sum(xc**2, axis=1)))
    cov = yc.T @ xc / x.shape[0]
    u, d, vt = np.linalg.svd(cov)
    s = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2] = -1.0
    r = u @ np.diag(s) @ vt
    if with_scale:
        if sigma_x <= 0:
            raise ValueError("source: all positions coincide; the scale is undefined")
        scale = float(np.sum(d * s) / sigma_x)
    else:
        scale = 1.0
    t = my - scale * r @ mx
    return Similarity(SE3(r, t), scale)


def associate(
    reference: Trajectory, estimate: Trajectory, *, max_difference: float = 0.01
) -> tuple[Trajectory, Trajectory]:
    """Pair poses by timestamp: each estimate pose with the nearest reference pose.

    Pairs further apart than ``max_difference`` seconds are dropped; a reference pose is used
    at most once. Trajectories without timestamps must have equal lengths and are paired by
    index. Returns the matched ``(reference, estimate)``, equally long, in estimate order.
    """
    if reference.timestamps is None or estimate.timestamps is None:
        if len(reference) != len(estimate):
            raise ValueError(
                f"reference, estimate: without timestamps they must have equal lengths, "
                f"got {len(reference)} and {len(estimate)}"
            )
        return reference, estimate
    if not max_difference >= 0:
        raise ValueError(f"max_difference: must be >= 0, got {max_difference}")
    ref_t = reference.timestamps
    order = np.argsort(ref_t, kind="stable")
    sorted_t = ref_t[order]
    pos = np.searchsorted(sorted_t, estimate.timestamps)
    lo = np.clip(pos - 1, 0, len(sorted_t) - 1)
    hi = np.clip(pos, 0, len(sorted_t) - 1)
    pick = np.where(
        np.abs(sorted_t[lo] - estimate.timestamps) <= np.abs(sorted_t[hi] - estimate.timestamps),
        lo,
        hi,
    )
    diff = np.abs(sorted_t[pick] - estimate.timestamps)
    keep = diff <= max_difference
    ref_idx = order[pick]
    # a reference pose matched twice keeps only its first (closest-in-order) partner
    _, first = np.unique(np.where(keep, ref_idx, -1), return_index=True)
    unique_mask = np.zeros_like(keep)
    unique_mask[first] = True
    keep &= unique_mask
    if not keep.any():
        raise ValueError(f"reference, estimate: no timestamps match within {max_difference} s")
    est_idx = np.flatnonzero(keep)
    ref_sel = Trajectory(reference.poses[ref_idx[est_idx]], ref_t[ref_idx[est_idx]])
    est_sel = Trajectory(estimate.poses[est_idx], estimate.timestamps[est_idx])
    return ref_sel, est_sel


def align(
    reference: Trajectory, estimate: Trajectory, method: str
) -> tuple[Trajectory, Similarity]:
    """Align ``estimate`` to ``reference`` (already associated, equal lengths).

    ``method``: ``"se3"`` (rotation + translation), ``"sim3"`` (plus scale) or ``"none"``.
    """
    if method == "none":
        return estimate, Similarity(SE3.identity(), 1.0)
    if method not in ("se3", "sim3"):
        raise ValueError(f"alignment: expected 'se3', 'sim3' or 'none', got {method!r}")
    sim = umeyama(estimate.positions, reference.positions, with_scale=method == "sim3")
    return sim.apply(estimate), sim
