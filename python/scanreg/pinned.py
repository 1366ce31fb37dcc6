"""Whether the scan itself pins a 2D result along a direction the degeneracy analysis finds weak.

The analysis (:mod:`scanreg.degeneracy`) calls a direction weak when fewer than the equivalent
of ``threshold`` (3 %) of the correspondences face it, judged from the normals' squared
components. In a corridor with a door frame, a corner, clutter or the corridor's end in view, a
few points may still hold the pose: moved along the corridor past the tight gate, the result
loses them.

:func:`weak_fit_loss` measures that directly: the pose moved along each weak direction by
:data:`PIN_SHIFTS_GATES` gates each way, and the least fraction of the source it loses from the
tight gate (:data:`scanreg.basin.TIGHT_GATE_FRACTION` of the gate) at any of those shifts,
counting only source points whose nearest target point is one where the target samples its
surface finer than the tight gate. A result in a bare corridor loses next to nothing somewhere
along it; a result left off along the corridor gains towards the true pose (a negative loss).
The verdict (:func:`scanreg.verdict.judge`) does not name a weak direction whose loss reaches
the analysis's own threshold as a fraction of the source, and measures it only for a result no
other check rejects. The covariance is left as it is (the prior along the direction): the rule
only lifts that one rejection, and the wrong-basin probe then runs on the result like on any
other accepted one.

Why only finely sampled target points: where the target's samples are further apart than the
tight gate (walls seen at a grazing angle or far away), whether a source point lies within the
gate of one depends on where the two scans' beams happened to fall, not on the surface. Counted
there too, the loss "pinned" 42 of 93 weak results in featureless simulated corridors (one
0.16 m off; ``docs/tutorial_pairwise.md``'s corridor accepted 0.1 m off), and on the Kümmerle
relation pairs of ``benchmarks/wrong_start.py``, whose two scans are often taken from nearly
the same place, it accepted 316 more correct results (Freiburg Intel 71.6 → 86.2 %, ACES 69.3
→ 76.6 %) and no wrong one: beam coincidence, which does not generalise to scans taken apart.
"""

from __future__ import annotations

import functools
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
    without a weak direction or a finite gate. Only source points whose nearest target point
    has another within the tight gate count (the target resolves the surface there: sliding
    along a wall keeps them, moving against a surface that faces the direction does not).
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
    fit = functools.partial(_dense_fit, target.index, source, target._finely_sampled(tight), tight)
    here = fit(matrix)
    steps = degeneracy.weak_basis() * degeneracy.scaling()[:, None]
    out = []
    for i in range(nw):
        best = -1
        for k in PIN_SHIFTS_GATES:
            for sign in (1.0, -1.0):
                best = max(best, fit(matrix @ _exp_matrix(sign * k * gate * steps[:, i])))
        out.append((here - best) / n)
    return tuple(out)


def _dense_fit(
    index: Any, source: FloatArray, dense: npt.NDArray[np.bool_], tight: float, matrix: FloatArray
) -> int:
    """How many of ``source`` at ``matrix`` have their nearest target point within ``tight``,
    that point one where the target samples its surface finer than ``tight``."""
    moved = source @ matrix[:2, :2].T + matrix[:2, 2]
    idx, _ = index.nearest(moved, tight)
    return int(np.count_nonzero(dense[idx[idx >= 0]]))


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
