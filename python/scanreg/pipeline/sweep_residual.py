"""What a deskew leaves: the loop covariance term of 2D sweeps undone with the wheels' motion.

A laser with per-beam times is deskewed with the wheels' increment from its scan to the next
(:meth:`scanreg.io.ScanLog.swept_points`): return ``i``, measured ``t_i`` after the stamp, is
moved back by the fraction ``s_i = t_i / Δt`` of that increment, as if the robot moved at a
constant rate. That increment's error as the sweep's motion, ``ε ~ N(0, Σ)`` — the wheels'
own (their noise model, calibrated on the run) and the rate's change from the interval before
(:func:`deskew_error`: a corner's turn that ends within the interval, the larger part on
the simulated tours) — is then left in the scan: return ``i`` sits off by
``s_i (ε_θ p_i^⊥ + ε_v)`` — the distortion of a sweep that was
not deskewed (:attr:`scanreg.RegistrationSettings.sweep_motion`) with the error in place of the
motion, random rather than known, and measured from the sweep's start (its rigid part moves
the scan as a whole, as a pose error does).

In a point-to-line match the residual of return ``i`` then changes by ``s_i J_iᵀ ε`` (``J_i``
its Jacobian over the pose's right perturbation), so to first order the estimate moves by
``−A⁻¹ B ε``, ``A = Σ J_i J_iᵀ``, ``B = Σ s_i J_i J_iᵀ``: covariance ``A⁻¹ B Σ Bᵀ A⁻¹``. A
target point of a submap, laid in by node ``n`` from its own deskewed scan, changes its
residual by ``−(s_j − s̄_n) J'_jᵀ ε_n`` (``J'_j`` over node ``n``'s right perturbation): the
mean ``s̄_n ε_n``, a rigid move of the scan, went into node ``n``'s pose when the odometry
matched the scan to its map, and that pose is where the submap lays the scan; independent
errors, one ``A⁻¹ C_n Σ_n C_nᵀ A⁻¹`` per node. The anchor's pose is the submap's frame: its own
rigid part moves the whole submap, ``s̄_a² Σ_a`` carried to the loop's right perturbation
(on the simulated room tour, a corner's anchor 47 mrad off turned every loop into it).

The sums over the points (``A``, ``B``, each ``C_n``) are the core's
(``_core.sweep_residual_sums``); the 3×3 algebra on them is here.

A single scan's 720 beams at 2 cm pin a match to millimetres; the deskew's error at a corner
is tens of mrad, centimetres at a few metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _core
from .._validate import FloatArray
from ..preprocess import IndexArray
from ..target import PreparedTarget
from ..transform import SE2

#: Directions of ``A`` weaker than this fraction of its strongest are left out of ``A⁻¹`` (a
#: corridor's axis: the match does not measure it, and the loop's information drops it).
_WEAK = 1e-6


@dataclass(frozen=True)
class DeskewedSweep:
    """One scan deskewed with a motion whose error is known: each point's time as a fraction
    of the interval that motion spans, and the covariance of the motion's error (3×3, right
    perturbation ``[ρx, ρy, θ]``)."""

    fractions: FloatArray
    covariance: FloatArray


@dataclass(frozen=True)
class SubmapSweeps:
    """The deskewed sweeps behind a submap's points: per point the slot of the node that laid
    it in (``-1``: not deskewed) and its fraction; per slot that node's pose in the submap's
    frame, its :attr:`DeskewedSweep.covariance` and its scan's mean fraction; the anchor's slot
    (``-1``: the anchor was not deskewed)."""

    slots: IndexArray
    fractions: FloatArray
    poses: tuple[SE2, ...]
    covariances: FloatArray
    mean_fractions: FloatArray
    anchor: int


def deskew_error(increment: SE2, before: SE2 | None, wheels: FloatArray) -> FloatArray:
    """The covariance (3×3) of the error of ``increment``, the motion a scan was deskewed with
    at a constant rate over the interval, as the sweep's motion: the wheels' own error
    (``wheels``, their noise model's covariance of the increment) and, with the previous
    interval's motion at its rate over this one (``before``), the rate's change: the sweep,
    at the interval's start, may have moved at any rate between the two (a corner's turn
    that ends within the interval: the constant rate misses the most there), taken as
    uniform from this interval's (the deskew's) to the previous one's: second moment
    ``δ δᵀ / 3``, ``δ = log(before) − log(increment)``."""
    out = np.array(wheels, dtype=np.float64)
    if before is not None:
        delta = before.log() - increment.log()
        out += np.outer(delta, delta) / 3.0
    return out


def submap_sweeps(
    anchor: int,
    nodes: list[int],
    relative: list[SE2],
    sizes: list[int],
    kept: IndexArray | None,
    sweeps: dict[int, DeskewedSweep],
) -> SubmapSweeps | None:
    """The :class:`SubmapSweeps` of a submap stacked from ``nodes`` (``sizes[k]`` points each,
    laid in at ``relative[k]`` in node ``anchor``'s frame), of which ``kept`` (the voxel grid's
    first input index per kept point; None: all) were kept; None when none of its nodes was
    deskewed."""
    if not any(n in sweeps for n in nodes):
        return None
    slots = np.concatenate([np.full(size, k) for k, size in enumerate(sizes)])
    fractions = np.concatenate(
        [
            sweeps[n].fractions if n in sweeps else np.zeros(size)
            for n, size in zip(nodes, sizes, strict=True)
        ]
    )
    covariances = np.array(
        [sweeps[n].covariance if n in sweeps else np.zeros((3, 3)) for n in nodes]
    )
    slots[np.isin(slots, [k for k, n in enumerate(nodes) if n not in sweeps])] = -1
    if kept is not None:
        slots, fractions = slots[kept], fractions[kept]
    means = np.array([float(np.mean(sweeps[n].fractions)) if n in sweeps else 0.0 for n in nodes])
    return SubmapSweeps(
        slots=slots.astype(np.int64),
        fractions=np.asarray(fractions, dtype=np.float64),
        poses=tuple(relative),
        covariances=covariances,
        mean_fractions=means,
        anchor=nodes.index(anchor) if anchor in nodes and anchor in sweeps else -1,
    )


def sweep_covariance(
    source: FloatArray,
    source_sweep: DeskewedSweep | None,
    target: PreparedTarget,
    target_sweeps: SubmapSweeps | None,
    pose: SE2,
    gate: float,
) -> FloatArray | None:
    """The covariance (3×3, right perturbation of ``pose`` = ``T_target_source``) the deskews'
    residual gives a point-to-line match of ``source`` to ``target`` at ``pose`` (module
    docstring), over the source points with a target point within ``gate``; None with fewer
    than 3 such points, nothing deskewed, or a target without normals."""
    if (source_sweep is None and target_sweeps is None) or target.normals is None:
        return None
    idx, _ = target.index.nearest(np.ascontiguousarray(pose.apply(source)), gate)
    sweeps = target_sweeps
    sums = _core.sweep_residual_sums(
        np.ascontiguousarray(source, dtype=np.float64),
        np.asarray(idx, dtype=np.int64),
        np.asarray(target.points),
        np.asarray(target.normals),
        pose.as_matrix(),
        None if source_sweep is None else source_sweep.fractions,
        None if sweeps is None else sweeps.slots,
        None if sweeps is None else sweeps.fractions,
        None if sweeps is None else np.array([p.as_matrix() for p in sweeps.poses]),
        None if sweeps is None else sweeps.mean_fractions,
    )
    if sums is None:
        return None
    _, information, source_sum, node_sums = sums
    vals, vecs = np.linalg.eigh(information)
    keep = vals > _WEAK * vals[-1]
    a_inv = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    spread = np.zeros((3, 3))
    if source_sweep is not None and source_sum is not None:
        spread += source_sum @ source_sweep.covariance @ source_sum.T
    if sweeps is not None and node_sums is not None:
        for c, cov in zip(node_sums, sweeps.covariances, strict=True):
            spread += c @ cov @ c.T
    out: FloatArray = a_inv @ spread @ a_inv
    if sweeps is not None and sweeps.anchor >= 0:
        a = sweeps.anchor
        frame = sweeps.mean_fractions[a] ** 2 * sweeps.covariances[a]
        ad = pose.inverse().adjoint()  # (the anchor's frame moved: a left perturbation)
        out = out + ad @ frame @ ad.T
    return 0.5 * (out + out.T)


__all__ = [
    "DeskewedSweep",
    "SubmapSweeps",
    "deskew_error",
    "submap_sweeps",
    "sweep_covariance",
]
