"""Whether the scan itself pins a 2D result along a direction the degeneracy analysis finds weak.

The analysis (:mod:`scanreg.degeneracy`) calls a direction weak when fewer than the equivalent
of ``threshold`` (3 %) of the correspondences face it, judged from the normals' squared
components. In a corridor with a door frame, a corner or the corridor's end in view, a few
points do face it, and they hold the pose: moved along the corridor past the tight gate, the
result loses them. On the Kümmerle relation pairs of the Freiburg Intel and ACES logs
(``benchmarks/wrong_start.py``) the degeneracy check was what rejected most correct results
(316 and 319 of them for it alone), many from starts 0.6 m off along that very direction,
brought back by those few points.

:func:`weak_fit_loss` measures that directly: the pose moved along each weak direction by
:data:`PIN_SHIFTS_GATES` gates each way, and the least fraction of the source it loses from the
tight gate (:data:`scanreg.basin.TIGHT_GATE_FRACTION` of the gate) at any of those shifts. A
result in a bare corridor loses next to nothing somewhere along it; a result left off along the
corridor gains towards the true pose (a negative loss). The verdict
(:func:`scanreg.verdict.judge`) does not name a weak direction whose loss reaches the analysis's
own threshold as a fraction of the source — the scan holds it as firmly as the floor asks of the
normals — and measures it only for a result no other check rejects. The covariance is left as it
is (the prior along the direction): the rule only lifts that one rejection, and the wrong-basin
probe then runs on the result like on any other accepted one.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, as_points
from .basin import TIGHT_GATE_FRACTION
from .degeneracy import Degeneracy
from .transform import SE2

#: The shifts along a weak direction (fractions of the gate, each way): from 1.5 tight gates
#: (every point facing the direction has left the tight gate, while a better pose just beyond
#: it is still sampled) to one gate (about the gate-wide prior's 1.7σ). On the five 2D logs of
#: wrong_start.py a first shift of 0.1 gate (the tight gate itself) kept most facing points
#: inside (Freiburg Intel correct accepted 86.2 → 77.5 %), one of 0.2 gate let 8 more ACES results
#: 0.15-0.3 m off be accepted (accepted and wrong 40 → 48).
PIN_SHIFTS_GATES = (0.15, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)


def weak_fit_loss(
    index: Any, source: Any, pose: SE2, degeneracy: Degeneracy, gate: float
) -> tuple[float, ...] | None:
    """For each weak direction of ``degeneracy`` (2D), the least fraction of ``source`` lost
    from the tight gate when ``pose`` moves along it by :data:`PIN_SHIFTS_GATES` gates either
    way (a move that shifts a typical point by that much: the scaled eigenvector), or None
    without a weak direction or a finite gate. ``index``: the target's search
    (``PreparedTarget.index``)."""
    src = as_points(source, "source", dim=2)
    if not isinstance(pose, SE2):
        raise TypeError(f"pose: expected SE2, got {type(pose).__name__}")
    if not isinstance(degeneracy, Degeneracy):
        raise TypeError(f"degeneracy: expected Degeneracy, got {type(degeneracy).__name__}")
    if degeneracy.information.shape != (3, 3):
        raise ValueError(f"degeneracy: is not 2D (information {degeneracy.information.shape})")
    g = float(gate)
    if math.isnan(g) or g <= 0:
        raise ValueError(f"gate: must be > 0, got {gate}")
    return _weak_fit_loss(index, src, pose, degeneracy, g)


def _weak_fit_loss(
    index: Any, source: FloatArray, pose: SE2, degeneracy: Degeneracy, gate: float
) -> tuple[float, ...] | None:
    """:func:`weak_fit_loss` on inputs already checked (the verdict's)."""
    nw = len(degeneracy.weak_directions)
    if nw == 0 or not (math.isfinite(gate) and gate > 0) or source.shape[0] == 0:
        return None
    tight = TIGHT_GATE_FRACTION * gate
    n = float(source.shape[0])
    matrix = pose.as_matrix()
    # Each query stops at the first target point inside the tight gate (a count, no distances).
    here = _core.count_within(index, source, matrix, tight)
    steps = degeneracy.weak_basis() * degeneracy.scaling()[:, None]
    out = []
    for i in range(nw):
        best = -1
        for k in PIN_SHIFTS_GATES:
            for sign in (1.0, -1.0):
                moved = matrix @ _exp_matrix(sign * k * gate * steps[:, i])
                best = max(best, _core.count_within(index, source, moved, tight))
        out.append((here - best) / n)
    return tuple(out)


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
    nw = len(degeneracy.weak_directions)
    if loss is None:
        return (False,) * nw
    values = np.asarray(loss, dtype=np.float64).tolist()
    if len(values) != nw:
        raise ValueError(f"loss: expected {nw} values (one per weak direction), got {len(values)}")
    return tuple(bool(x >= degeneracy.threshold) for x in values)
