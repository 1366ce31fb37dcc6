"""Is there another pose that explains the scan as well as the result does?

A local registration converges to the minimum of the basin it started in. Started in the
wrong one (a start turned by 50°, a room whose walls repeat every 90°), it can converge with
high fitness, a small residual and a covariance of a few degrees while it is 40–80° off:
nothing measured *at* the result tells. :func:`probe_basin` looks *around* it: it restarts the
same registration (same method, gate, kernel; the core's solve, no analysis) from the result
turned by ±45°, ±90°, ±135°, 180° about the source origin and moved by half the gate along each
axis, and compares how much of the source each distinct outcome explains against the result:
the fraction of source points with a target point within a tight gate (a tenth of the
registration's gate — at the full gate a wrong pose on a cluttered scan still finds a
neighbour for most points).

An outcome is *distinct* when it lies outside the result's own covariance (χ² at 99.9 %) and
more than half the tight gate or 1° away: an alternative the covariance already covers is the
same answer. A distinct outcome *near* the result (within half the gate and 10°) that
explains about as much is the same basin with a wider floor than the covariance says (on real
split-beam pairs restarts land 1–2° away where the covariance claims 0.1°): the covariance
grows to cover it (``BasinProbe.growth``). A *far* one decides the verdict
(:func:`scanreg.verdict.judge`): ``"wrong basin: …"`` when it explains clearly more of the scan,
``"ambiguous: …"`` when about as much (a square room turned by 90°, a corridor turned by 180°):
a Gaussian cannot cover two poses 90° apart.

Measured (``benchmarks/wrong_start.py``, ``benchmarks/README.md``): on real Intel pairs from
starts turned by up to ±70° and moved by 0.6 m, the restarts separate wrong from correct
results at the tight gate (147 of 259 accepted wrong results flagged, 1 of 273 correct ones);
at the registration's own gate they do not (26 correct flagged for 118 wrong). In 3D the default
verdict already rejected every wrong start of the benchmark (KITTI and the outdoor pair from
30°/60° do not converge within the iteration budget), so the probe — a dozen 3D solves — runs
only in 2D by default (``VerdictThresholds.basin_probe``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray
from ._validate import frozen as _frozen
from .quality import covariance_upper_bound
from .transform import SE2, SE3

#: Yaw offsets of the restarts (degrees), about the source origin.
RESTART_YAWS_DEG: tuple[float, ...] = (45.0, -45.0, 90.0, -90.0, 180.0, 135.0, -135.0)
#: Outcomes within this rotation (and half the gate) of the result are in its basin: when they
#: explain about as much, the covariance grows to cover them instead of rejecting.
NEAR_ROTATION_DEG = 10.0
#: Iterations of each restart: enough to leave the result's basin for another (an outcome
#: stopped at ``max_iterations`` still counts: it explains the scan as well as it does).
#: Measured against 10 (``benchmarks/wrong_start.py``): Intel accepted-and-outside with the
#: reference's error added 5 → 0 of ~680, correct accepted 75.1 → 75.4 %, the call's cost
#: 4.5× → 4.0× the probe-off call.
RESTART_ITERATIONS = 6
#: The correlative start (2D): cell and blur as a fraction of the gate, translation half-width
#: in gates, heading step in degrees.
CORRELATIVE_START = True
CORRELATIVE_CELL_FRACTION = 0.2
CORRELATIVE_WINDOW_GATES = 2.0
CORRELATIVE_ANGLE_DEG = 2.0
CORRELATIVE_MAX_POINTS = 64
#: The tight gate as a fraction of the registration's gate.
TIGHT_GATE_FRACTION = 0.1
#: χ²(dof) at 99.9 %: an alternative inside this Mahalanobis distance is the same answer.
CHI2_999 = {3: 16.266, 6: 22.458}


@dataclass(frozen=True)
class BasinProbe:
    """What :func:`probe_basin` found (units of the points; angles in radians)."""

    #: Fraction of source points within ``gate`` of a target point at the result.
    overlap: float
    #: The tight gate.
    gate: float
    #: The best distinct restart outcome, or None when every restart came back to the result
    #: (or failed).
    alternative: SE2 | SE3 | None
    #: Its fraction within ``gate`` (0 without one).
    alternative_overlap: float
    #: ``log(pose⁻¹ · alternative)`` (tangent, right perturbation), zeros without one.
    offset: FloatArray
    #: Restarts run (fewer than offered when one found a wrong basin) and how many ended at
    #: a distinct pose.
    restarts: int
    distinct: int
    #: Near distinct outcomes (within half the gate and ``NEAR_ROTATION_DEG``) explaining
    #: about as much as the result, and the ``(dof, dof)`` growth of the covariance that
    #: covers them (added to the result's covariance; zeros when none).
    covered: int
    growth: FloatArray
    seconds: float

    @property
    def ratio(self) -> float:
        """``alternative_overlap / overlap`` (0 without an alternative)."""
        if self.alternative is None:
            return 0.0
        return self.alternative_overlap / self.overlap if self.overlap > 0 else math.inf

    def describe(self) -> str:
        """The alternative in words, e.g. ``"a pose 0.41 m and 89.7° away"``."""
        dim = 2 if self.offset.size == 3 else 3
        rot = abs(float(self.offset[2])) if dim == 2 else float(np.linalg.norm(self.offset[3:]))
        return (
            f"a pose {float(np.linalg.norm(self.offset[:dim])):.2f} m and "
            f"{math.degrees(rot):.1f}° away explains {self.alternative_overlap:.0%} of the "
            f"source within {self.gate:.3g} against {self.overlap:.0%} here"
        )


def restart_offsets(dim: int, gate: float) -> list[SE2 | SE3]:
    """The restarts' offsets from the result (right-multiplied), most useful first (on the
    Intel and MbICP benchmark pairs ±45° found the most alternatives, then ±90°, then a
    half-gate move forward): turns about the source origin and, when the gate is finite,
    half-gate moves along each horizontal axis."""
    h = gate / 2.0 if math.isfinite(gate) else 0.0
    steps = [(0.0, 0.0, d) for d in RESTART_YAWS_DEG[:4]]
    steps += [(h, 0.0, 0.0)] if h else []
    steps += [(0.0, 0.0, d) for d in RESTART_YAWS_DEG[4:]]
    steps += [(-h, 0.0, 0.0), (0.0, h, 0.0), (0.0, -h, 0.0)] if h else []
    out: list[SE2 | SE3] = []
    for dx, dy, deg in steps:
        a = math.radians(deg)
        out.append(
            SE2.from_vector([dx, dy, a])
            if dim == 2
            else SE3.from_vector([dx, dy, 0.0, 0.0, 0.0, a])
        )
    return out


def _correlative_start(
    pose: SE2 | SE3, source: FloatArray, target_points: FloatArray, gate: float
) -> SE2:
    """2D: the best pose of a coarse correlative search (the core's branch and bound) over
    every heading and ±2 gates of translation around ``pose``: a start in the right basin
    when the result is turned *and* moved (the turns and half-gate moves of the restarts
    reach one or the other). Cells of a fifth of the gate, blur the same, 2° steps."""
    res = CORRELATIVE_CELL_FRACTION * gate
    grid = _core.CorrelativeGrid(target_points, res, res, 6)
    centre = pose.as_vector()
    n = math.ceil(CORRELATIVE_WINDOW_GATES * gate / res)
    step = math.radians(CORRELATIVE_ANGLE_DEG)
    # The search only has to land in the right basin: every k-th point is enough.
    stride = max(1, len(source) // CORRELATIVE_MAX_POINTS)
    match = grid.search(
        np.ascontiguousarray(source[::stride]),
        (float(centre[0]), float(centre[1]), float(centre[2])),
        n,
        n,
        math.ceil(math.pi / step),
        step,
        "branch_and_bound",
        0,
    )
    return SE2.from_vector(np.asarray(match.pose))


def _fraction(index: Any, source: FloatArray, pose: SE2 | SE3, gate: float) -> float:
    found = _core.overlap_statistics(index, source, pose.as_matrix(), gate)[0]
    return float(found) / float(source.shape[0])


def probe_basin(
    solve: Callable[[SE2 | SE3, int], Any],
    index: Any,
    source: FloatArray,
    pose: SE2 | SE3,
    covariance: FloatArray,
    gate: float,
    *,
    stop_ratio: float = math.inf,
    cover_ratio: float = math.inf,
    target_points: FloatArray | None = None,
) -> BasinProbe:
    """Restart ``solve`` (``(start, max_iterations) -> core outcome``, the registration's own
    solve) around ``pose`` (see the module docstring).

    ``index`` is the target's k-d tree or map, ``source`` the registered source points,
    ``covariance`` the result's ``(dof, dof)`` covariance (non-finite: only the fixed
    distances decide what is distinct), ``gate`` the registration's gate. A *near* distinct
    outcome explaining at least ``cover_ratio`` times the result's fraction is covered
    (``growth``); the best *far* one is reported (``alternative``). The restarts stop at the
    first far alternative explaining more than ``stop_ratio`` times the result (the verdict's
    wrong-basin ratio: the result is rejected whatever the rest would find).
    """
    t0 = time.perf_counter()
    dim = pose.DIM
    dof = 3 if dim == 2 else 6
    tight = TIGHT_GATE_FRACTION * gate if math.isfinite(gate) else math.inf
    if not math.isfinite(tight):
        # An infinite gate: three times the median distance to the target at the result.
        med = _core.overlap_statistics(index, source, pose.as_matrix(), math.inf)[2]
        tight = 3.0 * float(med) if math.isfinite(med) and med > 0 else 1.0
    near_move = 0.5 * gate if math.isfinite(gate) else 5.0 * tight
    here = _fraction(index, source, pose, tight)
    cov = np.asarray(covariance, dtype=np.float64)
    finite = bool(np.isfinite(cov).all())
    info = np.linalg.pinv(cov, hermitian=True) if finite else None
    cover = cov
    inverse = pose.inverse()
    best: tuple[float, SE2 | SE3, FloatArray] | None = None
    distinct = 0
    covered = 0
    starts: list[SE2 | SE3] = []
    if (
        CORRELATIVE_START
        and dim == 2
        and target_points is not None
        and math.isfinite(gate)
        and len(target_points)
    ):
        starts.append(_correlative_start(pose, source, target_points, gate))
    starts += [pose @ offset for offset in restart_offsets(dim, gate)]  # type: ignore[operator]
    ran = 0
    for start in starts:
        ran += 1
        out = solve(start, RESTART_ITERATIONS)
        if str(out.stop_reason) not in ("converged", "max_iterations"):
            continue
        m = np.asarray(out.pose)
        alt: SE2 | SE3 = SE2.from_matrix(m) if dim == 2 else SE3.from_matrix(m, atol=1e-6)
        e = (inverse @ alt).log()  # type: ignore[operator]
        moved = float(np.linalg.norm(e[:dim]))
        turned = abs(float(e[2])) if dim == 2 else float(np.linalg.norm(e[3:]))
        if moved <= 0.5 * tight and turned <= math.radians(1.0):
            continue
        if info is not None and float(e @ info @ e) <= CHI2_999[dof]:
            continue
        distinct += 1
        f = _fraction(index, source, alt, tight)
        if moved <= near_move and turned <= math.radians(NEAR_ROTATION_DEG):
            if finite and f >= cover_ratio * here:
                # The same basin, its floor wider than the covariance says: cover the
                # alternative (the smallest covariance covering both).
                cover = covariance_upper_bound(cover, cov + np.outer(e, e))
                covered += 1
            continue
        if best is None or f > best[0]:
            best = (f, alt, e)
        if here > 0 and f > stop_ratio * here:
            break
    return BasinProbe(
        overlap=here,
        gate=tight,
        alternative=None if best is None else best[1],
        alternative_overlap=0.0 if best is None else best[0],
        offset=np.zeros(dof) if best is None else best[2],
        restarts=ran,
        distinct=distinct,
        covered=covered,
        growth=_frozen(0.5 * ((cover - cov) + (cover - cov).T))
        if finite
        else _frozen(np.zeros((dof, dof))),
        seconds=time.perf_counter() - t0,
    )
