"""Whether the scan itself pins a 2D result along a direction the degeneracy analysis finds weak.

The analysis (:mod:`scanreg.degeneracy`) calls a direction weak when fewer than the equivalent
of ``threshold`` (3 %) of the correspondences face it, judged from the normals' squared
components. In a corridor with a door frame, a corner, clutter or the corridor's end in view, a
few points may still hold the pose: moved along the corridor past the tight gate, the result
loses them.

:func:`weak_fit_loss` measures that directly: the pose moved along each weak direction by
:data:`PIN_SHIFTS_GATES` gates each way, and the least fraction of the source it loses from the
tight gate (:data:`scanreg.basin.TIGHT_GATE_FRACTION` of the gate) of the target's *surface*
at any of those shifts. A result in a bare corridor loses next to nothing somewhere along it; a
result left off along the corridor gains towards the true pose (a negative loss). The verdict
(:func:`scanreg.verdict.judge`) does not name a weak direction whose loss reaches the analysis's
own threshold as a fraction of the source, and measures it only for a result no other check
rejects. The covariance is left as it is (the prior along the direction): the rule only lifts
that one rejection, and the wrong-basin probe then runs on the result like on any other
accepted one.

Why the surface and not the target's points: where the target's samples are further apart than
the tight gate (walls seen at a grazing angle or far away), whether a source point lies within
the tight gate of a *point* depends on where the two scans' beams happened to fall. Counted
that way the loss "pinned" 42 of 93 weak results in featureless simulated corridors (one
0.16 m off) — beam coincidence. A source point counts here when it lies across the nearest
target point's line within the tight gate and along it within that point's sample spacing (a
point between two sparse samples of a wall counts wherever it falls between them): sliding along
a wall keeps every point, moving past a door frame's reveal, a corner or a wall's end loses
those that fall off it. (Counting only points whose nearest target point has another within the
tight gate removed the coincidence as well, but also the sparse samples' share of real features,
and its count changed along a corridor with the target's sampling density: on the Kümmerle
relation pairs of ``benchmarks/wrong_start.py`` the best-fitting shift along the weak direction
lay within 0.1 gate of the relation for 8 % of the correct Freiburg Intel results rejected as
degenerate, against 90 % counted on the surface.)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from ._validate import FloatArray, as_points
from .basin import TIGHT_GATE_FRACTION
from .degeneracy import Degeneracy
from .target import PreparedTarget
from .transform import SE2

#: The shifts along a weak direction (fractions of the gate, each way): from 1.5 tight gates
#: (every point facing the direction has left the tight gate, while a better pose just beyond
#: it is still sampled) to one gate (about the gate-wide prior's 1.7σ).
PIN_SHIFTS_GATES = (0.15, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)


def weak_fit_loss(
    target: PreparedTarget, source: Any, pose: SE2, degeneracy: Degeneracy, gate: float
) -> tuple[float, ...] | None:
    """For each weak direction of ``degeneracy`` (2D), the least fraction of ``source`` lost
    from the tight gate when ``pose`` moves along it by :data:`PIN_SHIFTS_GATES` gates either
    way (a move that shifts a typical point by that much: the scaled eigenvector), or None
    without a weak direction or a finite gate. A source point counts when it lies within the
    tight gate of the surface the target samples (:func:`_surface_fits`): sliding along a wall
    keeps it, moving against a surface that faces the direction does not.
    ``target``: a 2D :class:`~scanreg.PreparedTarget`."""
    src = as_points(source, "source", dim=2)
    if not isinstance(target, PreparedTarget):
        raise TypeError(f"target: expected PreparedTarget, got {type(target).__name__}")
    if target.dim != 2:
        raise ValueError(f"target: must be 2D, got {target.dim}D")
    if not isinstance(pose, SE2):
        raise TypeError(f"pose: expected SE2, got {type(pose).__name__}")
    if not isinstance(degeneracy, Degeneracy):
        raise TypeError(f"degeneracy: expected Degeneracy, got {type(degeneracy).__name__}")
    if degeneracy.information.shape != (3, 3):
        raise ValueError(f"degeneracy: is not 2D (information {degeneracy.information.shape})")
    g = float(gate)
    if math.isnan(g) or g <= 0:
        raise ValueError(f"gate: must be > 0, got {gate}")
    return _weak_fit_loss(target, src, pose, degeneracy, g)


def _weak_fit_loss(
    target: Any, source: FloatArray, pose: SE2, degeneracy: Degeneracy, gate: float
) -> tuple[float, ...] | None:
    """:func:`weak_fit_loss` on inputs already checked (the verdict's); None also for a target
    that is not a :class:`~scanreg.PreparedTarget` (a local map: not measured)."""
    nw = len(degeneracy.weak_directions)
    if (
        nw == 0
        or not (math.isfinite(gate) and gate > 0)
        or source.shape[0] == 0
        or not isinstance(target, PreparedTarget)
    ):
        return None
    tight = TIGHT_GATE_FRACTION * gate
    n = float(source.shape[0])
    matrix = pose.as_matrix()
    steps = degeneracy.weak_basis() * degeneracy.scaling()[:, None]
    # The pose itself, then each weak direction's shifts: one search over all of them.
    shifts = [sign * k * gate for k in PIN_SHIFTS_GATES for sign in (1.0, -1.0)]
    matrices = [matrix] + [
        matrix @ _exp_matrix(shift * steps[:, i]) for i in range(nw) for shift in shifts
    ]
    fits = _surface_fits(target, source, tight, SURFACE_REACH_GATES * gate, matrices)
    here, moved = int(fits[0]), fits[1:].reshape(nw, len(shifts))
    return tuple((here - int(best)) / n for best in moved.max(axis=1))


#: How far from its nearest target point (fractions of the gate) a source point may lie and
#: still be counted on the surface between that point and its neighbour: samples further apart
#: than twice this do not sample one surface.
SURFACE_REACH_GATES = 0.3
#: A source point between two samples of a surface is at most half their spacing from the
#: nearer along it; this much of the spacing allows for uneven sampling.
_ALONG_SPACING = 0.6


def _surface_fits(
    target: PreparedTarget,
    source: FloatArray,
    tight: float,
    reach: float,
    matrices: list[FloatArray],
) -> npt.NDArray[np.int64]:
    """For each of ``matrices``, how many of ``source`` moved by it lie within ``tight`` of the
    surface the target samples: across the nearest target point's line (its normal) by at most
    ``tight``, and along it no further than that point's sample spacing allows
    (:data:`_ALONG_SPACING` of the distance to its nearest neighbour, at least ``tight``) — a
    point between two sparse samples of a wall counts wherever it falls between them. Where a
    normal is not valid the plain distance to the point is taken; without normals, only target
    points with another within ``tight`` are counted on."""
    m = np.asarray(matrices, dtype=np.float64)
    moved = source[None] @ m[:, :2, :2].transpose(0, 2, 1) + m[:, None, :2, 2]
    idx, _ = target.index.nearest(np.ascontiguousarray(moved.reshape(-1, 2)), reach)
    found = idx >= 0
    near = idx[found]
    offset = moved.reshape(-1, 2)[found] - target.points[near]
    dist2 = np.einsum("ij,ij->i", offset, offset)
    spacing = target._sample_spacing()[near]
    if target.normals is None:
        # No line to measure across: a point counts only within the tight gate of a target
        # point that has another within it (where beams falling elsewhere cannot matter).
        on = (dist2 <= tight * tight) & (spacing <= tight)
    else:
        normal = target.normals[near]
        across = np.einsum("ij,ij->i", offset, normal)
        valid = np.einsum("ij,ij->i", normal, normal) > 0.5
        across = np.where(valid, np.abs(across), np.sqrt(dist2))
        along2 = np.where(valid, np.maximum(dist2 - across * across, 0.0), 0.0)
        limit = np.maximum(tight, _ALONG_SPACING * spacing)
        on = (across <= tight) & (along2 <= limit * limit)
    counted = np.zeros(idx.shape[0], dtype=bool)
    counted[found] = on
    out: npt.NDArray[np.int64] = counted.reshape(len(m), -1).sum(axis=1)
    return out


def _exp_matrix(v: FloatArray) -> FloatArray:
    """``SE2.exp(v).as_matrix()`` in closed form (a tenth of its cost, 14 times a result)."""
    x, y, th = (float(c) for c in v)
    c, s = math.cos(th), math.sin(th)
    if abs(th) < 1e-9:
        a, b = 1.0 - th * th / 6.0, 0.5 * th
    else:
        a, b = s / th, (1.0 - c) / th
    return np.array([[c, -s, a * x - b * y], [s, c, b * x + a * y], [0.0, 0.0, 1.0]])


def pinned(loss: tuple[float, ...] | None, degeneracy: Degeneracy) -> tuple[bool, ...]:
    """Which weak directions of ``degeneracy`` the scan pins (``loss``, from
    :func:`weak_fit_loss`, at least the analysis's threshold); all False when ``loss`` is None
    (not measured)."""
    if not isinstance(degeneracy, Degeneracy):
        raise TypeError(f"degeneracy: expected Degeneracy, got {type(degeneracy).__name__}")
    nw = len(degeneracy.weak_directions)
    if loss is None:
        return (False,) * nw
    values = np.asarray(loss, dtype=np.float64).reshape(-1).tolist()
    if len(values) != nw:
        raise ValueError(f"loss: expected {nw} values (one per weak direction), got {len(values)}")
    if not all(math.isfinite(x) for x in values):
        raise ValueError(f"loss: must be finite, got {tuple(values)}")
    return tuple(bool(x >= degeneracy.threshold) for x in values)
