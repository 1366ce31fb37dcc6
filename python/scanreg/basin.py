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

The restarts run only when cheap evidence doubts the basin (:func:`basin_doubts`: a low fit
margin, a move beyond 1σ of the start's covariance, symmetric walls, and on request in 2D a
look-alike pose along the least-determined translation): a result nothing doubts costs one
nearest-neighbour pass and a histogram. The whole restart path is one core call
(``_core.probe_restarts``): the correlative start, the solves (in waves of the pool's size,
each stopping as soon as it comes back to the result), and the comparison of each outcome
with the result as it ends — back, inside the covariance, or distinct with its offset and
tight-gate overlap —, no restart running after the first outcome that settles the verdict
(a far one explaining more than ``basin_wrong_ratio`` times the result). In 3D the restarts
are three yaw turns (90°, −90°, 180°) and the tight gate is at least the target's point
spacing (voxelised clouds).

Measured (``benchmarks/wrong_start.py``, ``benchmarks/README.md``): on real Intel pairs from
starts turned by up to ±70° and moved by 0.6 m, the restarts separate wrong from correct
results at the tight gate (147 of 259 accepted wrong results flagged, 1 of 273 correct ones);
at the registration's own gate they do not (26 correct flagged for 118 wrong).
"""

from __future__ import annotations

import functools
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
#: 3D: yaw turns only (about the sensor's vertical axis).
RESTART_YAWS_3D_DEG: tuple[float, ...] = (180.0, 90.0, -90.0)
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
#: in gates, heading step in degrees, source points searched (every k-th). The start only has
#: to land in the right basin for the restart's solve: 4° steps found the same verdicts on
#: every wrong_start.py record as 2° (Intel and MbICP; two covered NEES moved) at half the
#: search's cost (0.48 → 0.26 ms CPU on the restarted Intel pairs); 8°, or 32 points, let two
#: Intel pairs from a 60° start through (tests/test_basin.py; 6° passed, the edge: 4° is kept).
CORRELATIVE_START = True
CORRELATIVE_CELL_FRACTION = 0.3
CORRELATIVE_WINDOW_GATES = 2.0
CORRELATIVE_ANGLE_DEG = 4.0
CORRELATIVE_MAX_POINTS = 64
#: The tight gate as a fraction of the registration's gate.
TIGHT_GATE_FRACTION = 0.1
COS_1DEG = math.cos(math.radians(1.0))
#: A restart stops when it comes within this fraction of the "back" distances (half the tight
#: gate, 1°) of the result.
HOME_SHRINK = 0.9
#: ``_core.probe_restarts``'s kind of a distinct outcome (0 failed, 1 back at the
#: result, 2 inside its covariance).
_DISTINCT = 3
#: χ²(dof) at 99.9 %: an alternative inside this Mahalanobis distance is the same answer.
CHI2_999 = {3: 16.266, 6: 22.458}
#: A probe without restarts reports a zero offset and growth: read-only, shared.
_ZEROS = {dof: (_frozen(np.zeros(dof)), _frozen(np.zeros((dof, dof)))) for dof in (3, 6)}

#: The screen (:func:`basin_doubts`): the restarts run only when one of these cheap signals
#: doubts the basin. Measured on the wrong-start benchmark's Intel and MbICP results that the
#: restarts rejected and whose covariance did not cover their error (292 and 164): every one
#: fires at least one signal, against 10 of 180 Intel results started at the reference
#: (``benchmarks/wrong_start.py``, ``benchmarks/README.md``).
#: The fit margin — the fraction of the source within the tight gate minus the inlier RMS
#: distance in gates — below this. Either alone separates less: correct Intel results have a
#: tight fraction down to 0.3 (sparse beams on clutter) and an RMSE up to 0.32 gate, the wrong
#: ones accepted by every other check a tight fraction of 0.13 and an RMSE of 0.40 gate
#: (medians); with the motion test below, a margin of 0 leaves none of the 456 wrong ones out
#: and restarts 9 of 300 results started at the reference (0.05: 12).
DOUBT_FIT_MARGIN = 0.0
#: Translation or rotation from the start beyond this χ² of the start's covariance (a 1σ
#: move: a result that stayed near its start has no reason to doubt it).
DOUBT_MOTION_CHI2 = 1.0
#: Symmetric structure: the wall-orientation histogram's overlap with itself turned by 90°,
#: 180° or 270° above this (square room 0.98, closed corridor 0.99; Intel targets: median
#: 0.41 at 180°, largest 0.94; MbICP largest 0.96 at 180°, the simulated office 0.88).
DOUBT_SYMMETRY = 0.95
#: The along-axis look-alike (:func:`along_axis_lookalike`, 2D): the result moved along its
#: least-determined translation (the covariance's widest axis) by these multiples of the gate,
#: each way; the screen doubts when one explains at least ``DOUBT_LOOKALIKE_RATIO`` times as
#: much of the scan (tight gate) as the result. A corridor's doors and pillars repeat along
#: it: on the ACES loops a pose 2 m along the corridor explained 64 % of the scan against 48 %
#: (``benchmarks/freiburg_mapping.py``), where nothing else doubted the result.
LOOKALIKE_SHIFTS_GATES: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
DOUBT_LOOKALIKE_RATIO = 0.9


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
    #: The cheap evidence that called for the restarts (:func:`basin_doubts`); empty when it
    #: was all clear and no restart ran (``restarts == 0``).
    evidence: tuple[str, ...] = ()

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
    return list(_restart_offsets(dim, float(gate)))


@functools.lru_cache(maxsize=16)
def _offset_stacks(dim: int, gate: float) -> tuple[FloatArray, FloatArray]:
    """The rotations ``(K, D, D)`` and translations ``(K, D, 1)`` of the restart offsets."""
    offsets = _restart_offsets(dim, gate)
    rot = np.stack([o.rotation for o in offsets])
    trans = np.stack([o.translation for o in offsets])[..., None]
    rot.setflags(write=False)
    trans.setflags(write=False)
    return rot, trans


@functools.lru_cache(maxsize=16)
def _restart_offsets(dim: int, gate: float) -> tuple[SE2 | SE3, ...]:
    # Built once per gate (a registration loop keeps its gate): eleven poses from vectors
    # cost as much as the screen itself. The poses are immutable, so sharing them is safe.
    if dim == 3:
        # A 3D restart costs a registration's worth of iterations over thousands of points:
        # only the turns of the ambiguities a building or a street makes.
        return tuple(
            SE3.from_vector([0.0, 0.0, 0.0, 0.0, 0.0, math.radians(d)]) for d in RESTART_YAWS_3D_DEG
        )
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
    return tuple(out)


def orientation_symmetry(points: FloatArray, normals: FloatArray) -> float:
    """How much the scene's walls look the same turned by 90°, 180° or 270° (0–1): the
    circular autocorrelation, at those shifts, of the histogram of wall directions (normals
    turned toward the sensor at the origin; in 3D their horizontal part, walls only), weighted
    by the wall length each point stands for (its range in 2D: one beam step of arc; one voxel
    in 3D). A rotational ambiguity needs it near 1; it does not suffice (it ignores where the
    walls are), so it only calls for the restarts."""
    n = np.ascontiguousarray(normals, dtype=np.float64)
    p = np.ascontiguousarray(points, dtype=np.float64)
    if n.shape != p.shape or p.ndim != 2:
        raise ValueError(f"normals: expected the points' shape {p.shape}, got {n.shape}")
    if len(n) < 8:
        return 0.0
    # One pass in the core (``scanreg_core::symmetry``): 5° bins, one bin of tolerance.
    return float(_core.orientation_symmetry(p, n))


def _chi2(v: FloatArray, cov: FloatArray) -> float:
    """``vᵀ cov⁻¹ v`` (closed form up to 2×2); 0 for a singular ``cov``."""
    if len(v) == 1:
        c = float(cov[0, 0])
        return float(v[0]) ** 2 / c if c > 0 else 0.0
    if len(v) == 2:
        a, b, d = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
        det = a * d - b * b
        x, y = float(v[0]), float(v[1])
        return (d * x * x - 2.0 * b * x * y + a * y * y) / det if det > 0 else 0.0
    try:
        return float(v @ np.linalg.solve(cov, v))
    except np.linalg.LinAlgError:
        return 0.0


def along_axis_lookalike(
    index: Any, source: FloatArray, pose: SE2, covariance: FloatArray, tight: float, gate: float
) -> tuple[float, float]:
    """2D: ``(shift, fraction)`` of the best pose along the result's least-determined
    translation (the widest axis of the covariance's translation block), moved by
    ``LOOKALIKE_SHIFTS_GATES`` gates each way, and the fraction of the source it explains
    within ``tight``; ``(0, 0)`` without a finite gate or covariance. A dozen nearest-neighbour
    passes: cheap beside the restarts it may call for."""
    cov = np.asarray(covariance, dtype=np.float64)
    if not (math.isfinite(gate) and gate > 0 and np.isfinite(cov).all()):
        return 0.0, 0.0
    _, vecs = np.linalg.eigh(0.5 * (cov[:2, :2] + cov[:2, :2].T))
    matrix = pose.as_matrix()
    step = matrix[:2, :2] @ vecs[:, -1]  # a unit move along the axis, in the target frame
    n = float(source.shape[0])
    best = (0.0, 0.0)
    for k in LOOKALIKE_SHIFTS_GATES:
        for sign in (1.0, -1.0):
            d = sign * k * gate
            moved = matrix.copy()
            moved[:2, 2] += d * step
            f = float(_core.overlap_statistics(index, source, moved, tight)[0]) / n
            if f > best[1]:
                best = (d, f)
    return best


def basin_doubts(
    *,
    tight_overlap: float,
    inlier_rmse: float,
    gate: float,
    motion: FloatArray | None,
    prior: FloatArray | None,
    symmetry: float,
    lookalike: tuple[float, float] = (0.0, 0.0),
) -> tuple[str, ...]:
    """The cheap evidence that a result may sit in the wrong basin (see the ``DOUBT_*``
    constants), as readable lines; empty: none, the restarts are not needed.

    ``motion`` is ``log(start⁻¹ · pose)`` (tangent, translation first), ``prior`` the start's
    covariance over it, ``lookalike`` the best ``(shift, fraction)`` along the result's weakest
    translation (:func:`along_axis_lookalike`)."""
    out: list[str] = []
    margin = tight_overlap - (inlier_rmse / gate if math.isfinite(gate) and gate > 0 else 0.0)
    if not margin >= DOUBT_FIT_MARGIN:
        out.append(
            f"fit margin {margin:.2f} < {DOUBT_FIT_MARGIN} (tight overlap {tight_overlap:.2f}, "
            f"inlier RMSE {inlier_rmse:.3g})"
        )
    if motion is not None and prior is not None:
        dof = len(motion)
        d = 2 if dof == 3 else 3
        cov = np.asarray(prior, dtype=np.float64)
        for name, sl in (("translation", slice(0, d)), ("rotation", slice(d, dof))):
            chi2 = _chi2(motion[sl], cov[sl, sl])
            if chi2 > DOUBT_MOTION_CHI2:
                out.append(f"{name} from the start χ² {chi2:.3g} > {DOUBT_MOTION_CHI2}")
    if symmetry > DOUBT_SYMMETRY:
        out.append(f"symmetric walls {symmetry:.2f} > {DOUBT_SYMMETRY}")
    shift, fraction = lookalike
    if shift != 0.0 and fraction >= DOUBT_LOOKALIKE_RATIO * tight_overlap:
        out.append(
            f"look-alike {shift:+.3g} along the weakest axis explains {fraction:.2f} "
            f"(the result {tight_overlap:.2f})"
        )
    return tuple(out)


def _spacing(index: Any, points: FloatArray | None) -> float:
    """Median distance from a target point to its nearest other one (64 of them sampled; a
    local map's spacing), or 0 when unknown."""
    if isinstance(index, _core.LocalMap):
        # Its points are at least ``voxel / sqrt(capacity)`` apart (the default spacing).
        return float(index.voxel_size) / math.sqrt(float(index.max_points_per_voxel))
    if not isinstance(index, _core.KdTree) or points is None or len(points) < 2:
        return 0.0
    sample = np.ascontiguousarray(points[:: max(1, len(points) // 64)])
    _, dist2 = index.knn(sample, 2)  # squared distances; the first is the point itself
    d = np.sqrt(np.asarray(dist2, dtype=np.float64).reshape(len(sample), -1)[:, -1])
    d = d[np.isfinite(d)]
    return float(np.median(d)) if len(d) else 0.0


def _beyond(
    start: SE2 | SE3, covariance: FloatArray | None, dof: int
) -> Callable[[SE2 | SE3], bool] | None:
    """Whether a pose lies beyond χ² (99.9 %) of ``start`` under ``covariance`` (None when no
    usable covariance was stated)."""
    info = _stated_information(covariance, dof)
    if info is None:
        return None

    def beyond(pose: SE2 | SE3) -> bool:
        e = _relative_log(start, pose)
        return bool(float(e @ info @ e) > CHI2_999[dof])

    return beyond


def _stated_information(covariance: FloatArray | None, dof: int | None = None) -> FloatArray | None:
    """The pseudo-inverse of a stated ``(dof, dof)`` covariance (None when it is not one)."""
    if covariance is None:
        return None
    cov = np.asarray(covariance, dtype=np.float64)
    if (dof is not None and cov.shape != (dof, dof)) or not np.isfinite(cov).all():
        return None
    info = np.asarray(np.linalg.pinv(0.5 * (cov + cov.T), hermitian=True), dtype=np.float64)
    return info


def _relative_log(a: SE2 | SE3, b: SE2 | SE3) -> FloatArray:
    """``log(a⁻¹ · b)`` (in 2D from the matrices, without building the poses)."""
    if a.DIM == 2:
        ra, ta = a.rotation, a.translation
        rel = np.eye(3)
        rel[:2, :2] = ra.T @ b.rotation
        rel[:2, 2] = ra.T @ (np.asarray(b.translation) - ta)
        return _log2(rel)
    return (a.inverse() @ b).log()  # type: ignore[operator]


def _log2(m: FloatArray) -> FloatArray:
    """``SE2.from_matrix(m).log()`` in closed form (``ρ = V(θ)⁻¹ t``), without the checks."""
    theta = math.atan2(float(m[1, 0]), float(m[0, 0]))
    if abs(theta) < 1e-9:
        a, b = 1.0, 0.0
    else:
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta
    tx, ty, d = float(m[0, 2]), float(m[1, 2]), a * a + b * b
    return np.array([(a * tx + b * ty) / d, (a * ty - b * tx) / d, theta])


def tight_gate(
    index: Any, source: FloatArray, pose: SE2 | SE3, gate: float, target_points: FloatArray | None
) -> float:
    """The gate of the probe's overlaps (:data:`TIGHT_GATE_FRACTION` of ``gate``; in 3D at
    least the target's point spacing; with an infinite gate, three times the median distance
    to the target at ``pose``)."""
    tight = TIGHT_GATE_FRACTION * gate if math.isfinite(gate) else math.inf
    if not math.isfinite(tight):
        # An infinite gate: three times the median distance to the target at the result.
        med = _core.overlap_statistics(index, source, pose.as_matrix(), math.inf)[2]
        tight = 3.0 * float(med) if math.isfinite(med) and med > 0 else 1.0
    if pose.DIM == 3:
        # Voxel-downsampled clouds: a tenth of the gate is below the spacing of the points (0.5 m
        # voxels, 1 m gate), where even the right pose finds a neighbour for a fifth of them.
        tight = max(tight, _spacing(index, target_points))
    return tight


def _fraction(index: Any, source: FloatArray, pose: SE2 | SE3, gate: float) -> float:
    # Counted in the core, each query stopping at the first target point inside the gate.
    found = _core.count_within(index, source, pose.as_matrix(), gate)
    return float(found) / float(source.shape[0])


def probe_basin(
    solve: Callable[..., Any],
    index: Any,
    source: FloatArray,
    pose: SE2 | SE3,
    covariance: FloatArray,
    gate: float,
    *,
    stop_ratio: float = math.inf,
    cover_ratio: float = math.inf,
    target_points: FloatArray | None = None,
    screen: bool = False,
    lookalike_signal: bool = False,
    start: SE2 | SE3 | None = None,
    motion: FloatArray | None = None,
    prior: FloatArray | None = None,
    inlier_rmse: float = 0.0,
    target_normals: FloatArray | None = None,
    tight_overlap: tuple[float, float] | None = None,
    stated_prior: FloatArray | None = None,
    correlative_grid: Callable[[float], Any] | None = None,
    symmetry: float | None = None,
) -> BasinProbe:
    """Restart ``solve`` around ``pose`` (see the module docstring): the registration's own
    solve from several starts at once, ``(starts (K, D+1, D+1), max_iterations, probe=(...))
    -> (kinds, offsets, fractions, poses)``: the core's ``probe_restarts`` with the
    registration's settings, ``probe`` holding its arguments after them (the correlative
    start, the home a restart stops at, the comparison with the result and where to stop).

    ``index`` is the target's k-d tree or map, ``source`` the registered source points,
    ``covariance`` the result's ``(dof, dof)`` covariance (non-finite: only the fixed
    distances decide what is distinct), ``gate`` the registration's gate. A *near* distinct
    outcome explaining at least ``cover_ratio`` times the result's fraction is covered
    (``growth``); the best *far* one is reported (``alternative``). The restarts stop at the
    first far alternative explaining more than ``stop_ratio`` times the result (the verdict's
    wrong-basin ratio: the result is rejected whatever the rest would find).

    ``screen``: restart only when :func:`basin_doubts` finds a reason to, from ``start`` and
    its covariance ``prior``, the result's ``inlier_rmse`` within ``gate``, the tight overlap
    and the symmetry of ``target_points`` / ``target_normals`` (when given); otherwise the
    probe returns with no restart (``evidence`` empty). ``lookalike_signal``: also the 2D
    look-alike along the least-determined translation (:func:`along_axis_lookalike`) when the
    other signals are silent. ``motion``: ``log(start⁻¹ · pose)`` when the caller has it
    already (the registration's trust analysis does); ``tight_overlap``: ``(tight_gate(...),
    fraction of the source within it at pose)`` likewise (counted with the verdict's overlap).
    ``stated_prior``: the covariance the caller *stated* for ``start`` (``init_covariance``: a
    wheel odometry, an IMU): a far outcome beyond its χ² (99.9 %) from ``start`` is no rival —
    the measurement that gave the start rules it out (a tunnel turned by 180° explains the
    sweep as well, but the wheels say the vehicle did not turn). ``correlative_grid(resolution)``:
    the correlative start's grid of ``target_points`` when the target keeps one (built here
    otherwise); ``symmetry``: :func:`orientation_symmetry` of ``target_points`` /
    ``target_normals`` when the target keeps it (measured here otherwise).
    """
    t0 = time.perf_counter()
    dim = pose.DIM
    dof = 3 if dim == 2 else 6
    if tight_overlap is None:
        tight = tight_gate(index, source, pose, gate, target_points)
        here = _fraction(index, source, pose, tight)
    else:
        tight, here = tight_overlap
    near_move = 0.5 * gate if math.isfinite(gate) else 5.0 * tight
    evidence: tuple[str, ...] = ()
    lookalike = (0.0, 0.0)
    if screen:
        sym = (
            symmetry
            if symmetry is not None
            else orientation_symmetry(target_points, target_normals)
            if target_points is not None
            and target_normals is not None
            and np.shape(target_points) == np.shape(target_normals)
            else 0.0
        )
        doubts = functools.partial(
            basin_doubts,
            tight_overlap=here,
            inlier_rmse=inlier_rmse,
            gate=gate,
            motion=motion if motion is not None or start is None else _relative_log(start, pose),
            prior=prior,
            symmetry=sym,
        )
        evidence = doubts()
        if lookalike_signal and not evidence and isinstance(pose, SE2) and here > 0.0:
            # The dearest signal (a dozen neighbour passes) only where the others are silent.
            lookalike = along_axis_lookalike(
                index, source, pose, np.asarray(covariance, dtype=np.float64), tight, gate
            )
            evidence = doubts(lookalike=lookalike)
        if not evidence:
            # Nothing doubts the result (most calls): the shared read-only zeros.
            zero_offset, zero_growth = _ZEROS[dof]
            return BasinProbe(
                overlap=here,
                gate=tight,
                alternative=None,
                alternative_overlap=0.0,
                offset=zero_offset,
                restarts=0,
                distinct=0,
                covered=0,
                growth=zero_growth,
                seconds=time.perf_counter() - t0,
            )
    cov = np.asarray(covariance, dtype=np.float64)
    finite = bool(np.isfinite(cov).all())
    implausible = _beyond(start, stated_prior, dof) if start is not None else None
    cover = cov
    best: tuple[float, SE2 | SE3, FloatArray] | None = None
    distinct = 0
    covered = 0
    first: list[FloatArray] = []
    # The correlative start (2D) is searched in the core, first of the restarts.
    grid = None
    if (
        CORRELATIVE_START
        and dim == 2
        and target_points is not None
        and math.isfinite(gate)
        and len(target_points)
    ):
        res = CORRELATIVE_CELL_FRACTION * gate
        # ``grid_of(res)``: the same grid kept by the target (PreparedTarget._probe_grid).
        grid = (
            _core.CorrelativeGrid(target_points, res, res, 6)
            if correlative_grid is None
            else correlative_grid(res)
        )
    if lookalike[0] != 0.0 and any(e.startswith("look-alike") for e in evidence):
        # The look-alike itself first: the turns and half-gate moves may not reach it.
        _, vecs = np.linalg.eigh(0.5 * (cov[:2, :2] + cov[:2, :2].T))
        d = lookalike[0] * vecs[:, -1]
        first.append((pose @ SE2.from_vector([d[0], d[1], 0.0])).as_matrix())  # type: ignore[operator]
    offsets = _restart_offsets(dim, float(gate))
    # ``pose @ offset`` for every offset at once: the same products, stacked (a pose object
    # per start cost more than its restart's solve).
    rot, trans = _offset_stacks(dim, float(gate))
    starts = np.zeros((len(first) + len(offsets), dim + 1, dim + 1))
    for i, m in enumerate(first):
        starts[i] = m
    starts[len(first) :, :dim, :dim] = np.matmul(pose.rotation, rot)
    starts[len(first) :, :dim, dim] = np.matmul(pose.rotation, trans)[..., 0] + pose.translation
    starts[:, dim, dim] = 1.0
    near_turn = math.radians(NEAR_ROTATION_DEG)
    # The whole restart path in one core call (``_core.probe_restarts``): the correlative
    # start, then every restart, each compared with the result as it ends — back at it, inside
    # its covariance, or distinct with its offset and tight-gate overlap — and no restart
    # after the first far distinct outcome that settles the verdict (the loop below stops at
    # the same one). A restart that comes back to the result stops there (``home``): it has
    # answered, and would only refine the same pose; a shade inside the comparison's "back"
    # test, so that the rounding of the two never tells them apart.
    step = math.radians(CORRELATIVE_ANGLE_DEG)
    res = CORRELATIVE_CELL_FRACTION * gate if grid is not None else 1.0
    stated = None if implausible is None or stated_prior is None else start
    kinds, tangents, fractions, poses = solve(
        starts,
        RESTART_ITERATIONS,
        probe=(
            pose.as_matrix(),  # result
            HOME_SHRINK * 0.5 * tight,  # home_radius
            math.cos(HOME_SHRINK * math.radians(1.0)),  # home_cos_angle
            grid,
            max(1, len(source) // CORRELATIVE_MAX_POINTS),  # stride: every k-th point
            math.ceil(CORRELATIVE_WINDOW_GATES * gate / res) if grid is not None else 0,
            math.ceil(math.pi / step),  # ntheta
            step,
            tight,
            cov if finite else None,
            CHI2_999[dof],
            here,
            stop_ratio,
            near_move,
            near_turn,
            None if stated is None else stated.as_matrix(),  # implausible_start
            None if stated is None else _stated_information(stated_prior),
            CHI2_999[dof],
        ),
    )
    ran = len(kinds)
    kind = SE2 if dim == 2 else SE3
    for i, k in enumerate(kinds):
        if k != _DISTINCT:
            continue
        distinct += 1
        e = tangents[i]
        f = fractions[i]
        if dim == 2:
            moved, turned = math.hypot(e[0], e[1]), abs(float(e[2]))
        else:
            moved, turned = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
        if moved <= near_move and turned <= near_turn:
            if finite and f >= cover_ratio * here:
                # The same basin, its floor wider than the covariance says: cover the
                # alternative (the smallest covariance covering both).
                cover = covariance_upper_bound(cover, cov + np.outer(e, e))
                covered += 1
            continue
        if best is not None and f <= best[0] and implausible is None:
            continue  # neither the best so far nor a reason to stop (f <= best's)
        # The core's rotation is orthonormal: no check (from_matrix costs a solve's worth).
        m = poses[i]
        alt: SE2 | SE3 = kind._unchecked(m[:dim, :dim], m[:dim, dim])
        if implausible is not None and implausible(alt):
            continue
        if best is None or f > best[0]:
            best = (f, alt, np.array(e))
        if here > 0 and f > stop_ratio * here:
            ran = i + 1
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
        evidence=evidence,
    )
