"""A weak 2D result moved along its weak direction to where the scan fits it, and pins it.

Point-to-point and GICP have no refinement in the basin and no hold: in a corridor their
results stop wherever the solve ran out of pull along the axis, and the verdict rejects them
as degenerate unless the scan pins them there (:mod:`scanreg.pinned`). Yet a door frame, a
corner or the corridor's end in view often fits the scan at one place along the axis: the
tight-gate count on the target's *surface* (:func:`scanreg.pinned._surface_fits`, the pin's own
count and its one nearest-neighbour call in the core) along the weak direction peaks there.

:func:`weak_shift` reads that profile — the pose moved by :data:`SHIFT_STEP_GATES` steps out to
:data:`SHIFT_REACH_GATES` gates each way along each weak direction — and returns the middle of
the best-fitting run of shifts when it fits more of the source than the result does *and* the
scan pins the moved pose (its loss along the weak directions reaches the analysis's threshold,
the verdict's own test). A move that would leave the result degenerate is not made: along a
corridor the scans do not determine, the solve's coordinate is as good as another, and such
moves only traded one rejected pose for another (on the Kümmerle relation pairs of
``benchmarks/wrong_start.py`` they made more rejected results correct and a few correct ones
wrong, at ACES' corridors where the scans fit 0.2 m off the relation better). The verdict then
judges the moved pose as usual; the covariance is the analysis's at the moved pose (the prior
along the weak direction).

The margin: requiring the best shift to fit 3 % more of the scan (the pin's threshold), 1 %
more, or any more was compared with the pin required, on the Freiburg Intel, ACES and hospital
relations, the Intel subset and MbICP (``benchmarks/wrong_start.py``): each log accepted the
most correct results with "any more" and none more wrong, so with any one log left out the
others choose it, and it holds on the log left out: the pin is what makes a move safe, not the
margin. A result the scan already pins where it is is left there: the verdict accepts it as
it is, and moved to the middle of its best-fitting run it lay further from the relation (61
accepted Freiburg Intel results, a median 1.8 → 5.3 cm off). The step: 0.025 gate read about
the same (Freiburg Intel 88.9 against 89.4 % of the correct results accepted, the Intel subset
86.3 against 85.9 %), the newly accepted results a median 2.1 against 2.7 cm off, at twice the
profile's cost.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._validate import FloatArray
from .basin import TIGHT_GATE_FRACTION
from .degeneracy import Degeneracy
from .pinned import (
    PIN_SHIFTS_GATES,
    SURFACE_REACH_GATES,
    _exp_matrix,
    _surface_fits,
    _weak_fit_loss,
    pinned,
)
from .target import PreparedTarget
from .transform import SE2

#: The profile's step along a weak direction (fraction of the gate; every shift of the pin's
#: :data:`~scanreg.pinned.PIN_SHIFTS_GATES` lies on it) ...
SHIFT_STEP_GATES = 0.05
#: ... and how far it reaches each way (the gate-wide prior's 1.7σ: where ICP converges from).
SHIFT_REACH_GATES = 1.0


def weak_shift(
    target: PreparedTarget,
    source: FloatArray,
    pose: FloatArray,
    degeneracy: Degeneracy,
    gate: float,
) -> FloatArray | None:
    """The pose matrix ``pose`` moved along one weak direction of ``degeneracy`` to the middle
    of the run of shifts that fit the most of ``source`` within the tight gate of the target's
    surface, when that is more than ``pose`` fits and the scan pins the moved pose
    (:func:`scanreg.pinned.pinned`, with ``degeneracy``'s directions); else None. Inputs
    already checked (the registration's): a 2D prepared target, a finite gate."""
    nw = len(degeneracy.weak_directions)
    n = source.shape[0]
    if nw == 0 or n == 0:
        return None
    steps = degeneracy.weak_basis() * degeneracy.scaling()[:, None]
    count = round(SHIFT_REACH_GATES / SHIFT_STEP_GATES)
    ks = np.asarray([k for k in range(-count, count + 1) if k != 0])
    shifts = ks * (SHIFT_STEP_GATES * gate)
    tangents = (steps.T[:, None, :] * shifts[None, :, None]).reshape(-1, 3)
    matrices = [pose, *(pose @ _exp_matrices(tangents))]
    fits = _surface_fits(
        target, source, TIGHT_GATE_FRACTION * gate, SURFACE_REACH_GATES * gate, matrices
    )
    here = int(fits[0])
    gains = fits[1:].reshape(nw, len(shifts)) - here
    # Pinned where it is (the pin's shifts lie on this grid): the verdict accepts it there.
    at_pin = np.isin(np.abs(ks), np.round(np.asarray(PIN_SHIFTS_GATES) / SHIFT_STEP_GATES))
    if (-gains[:, at_pin].max(axis=1) >= degeneracy.threshold * n).all():
        return None
    best = int(gains.max())
    if best < 1:
        return None
    # Where the best fit is a plateau (every point within the tight gate over a run of
    # shifts), its middle: the nearest run of the nearest direction holding it.
    i, j = min(zip(*np.nonzero(gains == best), strict=True), key=lambda ij: abs(ks[ij[1]]))
    lo = hi = int(j)
    while lo > 0 and gains[i, lo - 1] == best and ks[lo - 1] * ks[j] > 0:
        lo -= 1
    while hi + 1 < len(ks) and gains[i, hi + 1] == best and ks[hi + 1] * ks[j] > 0:
        hi += 1
    middle = 0.5 * (ks[lo] + ks[hi]) * SHIFT_STEP_GATES * gate
    out: FloatArray = pose @ _exp_matrix(middle * steps[:, i])
    # Only where the scan pins it there (the verdict's own test, :mod:`scanreg.pinned`): a
    # move that leaves the result degenerate changes nothing the verdict accepts, and along
    # a corridor the scans do not determine, the start's coordinate is as good as any.
    loss = _weak_fit_loss(target, source, SE2.from_matrix(out), degeneracy, gate)
    if not all(pinned(loss, degeneracy)):
        return None
    return out


def _exp_matrices(v: FloatArray) -> FloatArray:
    """``(m, 3, 3)``: :func:`scanreg.pinned._exp_matrix` of each row of ``v`` (m, 3) at once."""
    x, y, th = v[:, 0], v[:, 1], v[:, 2]
    c, s = np.cos(th), np.sin(th)
    small = np.abs(th) < 1e-9
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th * th / 6.0, s / safe)
    b = np.where(small, 0.5 * th, (1.0 - c) / safe)
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = c, -s, a * x - b * y
    out[:, 1, 0], out[:, 1, 1], out[:, 1, 2] = s, c, b * x + a * y
    out[:, 2, 2] = 1.0
    return out


#: The screen's floor (:func:`maybe_weak_2d`): over three times the analysis's own (0.03), so
#: that the normals' noise, which the analysis removes first, cannot hide a weak translation.
SCREEN_FLOOR = 0.1


def maybe_weak_2d(correspondences: Any, normals: FloatArray) -> bool:
    """A screen before the analysis: do the target normals at ``correspondences`` (indices,
    ``-1`` for none) leave some translation with less than :data:`SCREEN_FLOOR` of them facing
    it (the smallest eigenvalue of their mean ``n nᵀ``)? A few µs; the analysis decides."""
    corr = np.asarray(correspondences)
    used = corr[corr >= 0]
    if used.size == 0:
        return False
    nn = normals[used]
    m = nn.T @ nn / float(used.size)
    return bool(np.linalg.eigvalsh(m)[0] < SCREEN_FLOOR)
