"""Global 3D registration: ``T_target_source`` with no initial guess.

``register_global(source, target)`` runs, in the Rust core (GIL released): a voxel grid of
keypoints per cloud, normals, FPFH descriptors (Rusu et al. 2009), correspondences by mutual
nearest neighbour in descriptor space, the maximum clique of the pairwise length-consistency
graph (as TEASER++ and KISS-Matcher prune) and a GNC-TLS rotation + translation solve (Yang et
al. 2020) per clique. Disjoint cliques give ranked hypotheses. Here, each hypothesis is refined
by our GICP (:func:`scanreg.register`) and judged by our verdict; the best accepted one is the
answer only if nothing else is as plausible.

When nothing is reliable the result says so — ``accepted`` is false, ``pose`` is ``None`` and
``reasons`` starts with ``"no reliable alignment"`` — rather than returning a guess.

Scale: by default the voxel is chosen so that the larger cloud keeps about
``DEFAULT_KEYPOINTS`` keypoints, but no less than :data:`MIN_VOXEL_SPACINGS` times the cloud's
own point spacing (a keypoint then averages several points, whatever the cloud's size); the
FPFH radius is five voxels and the noise bound one voxel. The refinement measures the noise of
its target's normals and, where millimetre noise on a small object makes them unreliable at the
library's neighbour count, fits them over more neighbours (:data:`NOISY_NORMALS`). So a scanned
object a few decimetres across, a room and a street all work without flags.

On such noisy clouds the answer (found and judged on the raw clouds) is refined once more on
both clouds denoised (:func:`scanreg.surface_noise.denoise`: each point projected onto the plane
of its neighbours within a few noise widths): the raw clouds' noise biases the pose. It is
refused when either denoised cloud's surface is still unresolved (:data:`MIN_FLATNESS`): two
views of a surface that bends within a few noise widths show different sides of a blur, and the
alignment of the blurs is biased by more than the pose's own uncertainty; and when the denoised
clouds fit looser than the raw ones at its pose (:data:`MIN_DENOISED_FIT`): the denoising then
changed the shapes. The geometry (the degeneracy test) is judged there too, not on the raw
normals, whose noise raises the test's bar above what right poses hold.

A refinement that cannot vouch for its own pose — it moved more than a gate from its clique's
solve, or its noisy normals read a weak direction — needs another, disjoint clique whose
refinement ends at the same pose: on noisy small objects a clique holds a handful of true
matches and its solve may lie tens of degrees from the truth it refines to.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, as_points
from .preprocess import DEFAULT_K, voxel_downsample
from .register import RegistrationResult, register
from .surface_noise import SurfaceNoise, denoise, surface_noise
from .target import prepare
from .transform import SE3
from .verdict import Verdict, VerdictThresholds

#: Keypoints the default voxel aims at for the larger cloud: every stage's cost grows with it,
#: and about this many kept the 3DMatch pair's correct matches (a 5 cm voxel, as the
#: benchmark's own protocol uses).
DEFAULT_KEYPOINTS = 5000
#: The default voxel is at least this many times the median nearest-neighbour spacing of the
#: larger cloud: each keypoint then averages several points (about nine on a surface). The
#: count alone leaves a keypoint for every two points of a 10⁴-point object scan; the
#: benchmark's rooms and streets hold 3.9 (3DMatch) to 23 (KITTI) spacings per voxel, so it
#: never binds there.
MIN_VOXEL_SPACINGS = 3.0
#: Query points (evenly spaced) that measure the spacing.
SPACING_SAMPLES = 2000
#: Smallest clique (mutually consistent correspondences) a hypothesis needs to be accepted:
#: pairs with no overlap (KITTI crops 10-24 m apart, a 3DMatch fragment against a street scan)
#: gave chance cliques of 7-12, correct pairs 80-800 (3DMatch, simulated street, KITTI).
DEFAULT_MIN_INLIERS = 15
#: Least fraction of the source within the gate of the target after refinement (the verdict's
#: overlap): partial views overlap far less than successive scans, so below the local default.
DEFAULT_MIN_OVERLAP = 0.3

#: Work budget of the maximum-clique search (bitset-word operations; the runner-ups get a
#: twentieth). A correct clique of 600-800 is never proven maximum within 50 M (the binding's
#: default, ~65 ms of CPU on the outdoor and KITTI pairs); 5 M stops at 555-773 instead of
#: 594-798 in a third of the time, the pose coming from GNC-TLS over either.
CLIQUE_SEARCH_BUDGET = 10_000_000

#: The refinement's clouds are gridded at this times the keypoint voxel: finer than the
#: keypoints, so the pose improves on them. On the benchmark's four sets 0.5 / 0.75 / 1.0 gave
#: rotation errors up to 0.003° / 0.005° / 0.010° and translation 2.5 / 1.5 / 10 mm (3DMatch
#: aside, 11 cm from its ground truth at all three), the refinement taking 1 / 0.5-0.7 / 0.4×
#: the time.
REFINE_VOXEL = 0.75

#: The refinement's target normals (and both clouds' covariances) are fitted over
#: :data:`NOISY_NORMALS_NEIGHBORS` neighbours instead of the library's when the typical
#: squared normal error ``ε̃²`` (:func:`scanreg.degeneracy.normal_noise`) measured at the
#: library's count is above this. The verdict's degeneracy test wants a direction's
#: information above ``6 ε̃²``, what noisy normals alone fake: rooms and streets measure
#: ε̃² 0.0000-0.0023 (the benchmark's 13 pairs), objects of 0.2 m with 2-3 mm noise 0.03-0.19,
#: which declared every pose of them degenerate (a direction needed 0.2-1.1).
NOISY_NORMALS = 0.008
#: Neighbours of the refinement's normals and covariances on noisy clouds (see above): on
#: those objects ε̃² fell three- to fivefold.
NOISY_NORMALS_NEIGHBORS = 50

#: Iterations the refinement may take. Rooms and streets converge well within the library's
#: 30; on millimetre-noisy objects GICP creeps along their weakest direction and 20-50 % of
#: the correct poses stopped there unconverged (and were refused) at 30.
REFINE_MAX_ITERATIONS = 100

#: A hypothesis whose overlap (within the refinement's gate) at the robust solve is below this
#: times the verdict's ``min_overlap`` is rejected without refinement.
SOLVE_OVERLAP_FACTOR = 0.5

#: Poses closer than this (degrees) and than the gate at the source centre are the same pose.
SAME_POSE_DEGREES = 5.0

#: A second, differing refined hypothesis (accepted or not) with at least this fraction of the
#: best one's close fraction makes the result ambiguous. On two views of small objects
#: (``benchmarks/global_objects.py``) the correct answers' differing runner-ups explained at
#: most 0.73 of theirs (a knot turned onto itself), the two wrong answers' 0.77 and 0.84 (a
#: 0.1 m blob turned by 132°, a knot's back view turned onto its front); 0.9 accepted both. The
#: benchmark's rooms and streets have no differing runner-up that is refined.
AMBIGUITY_RATIO = 0.75

#: Once a hypothesis is refined and accepted, a later one whose clique (its mutually
#: consistent correspondences) is smaller than this times the accepted one's is no rival and
#: is not refined: a scene that really admits two poses (a repetitive street, a symmetric
#: room) supports both with cliques of similar size, while the runner-ups of the benchmark's
#: pairs hold 0.26-0.48 of the answer's (a street turned by 180°, a 3DMatch clique that
#: converges onto the answer) and refining them was a third of the street's refinement time
#: and a twentieth of the 3DMatch call.
RIVAL_CLIQUE_RATIO = 0.5

#: An answer is refused when either denoised cloud's flatness (:func:`scanreg.surface_noise`:
#: median ``λ₂ / λ₃`` of its flattest neighbourhoods, ``≈ (r / 2σ)²`` for a flat patch of radius
#: ``r``) is below this: its surface stays flat over patches less than about 4.5 noise widths
#: across (``σ`` 1.3-3 mm on a 5 mm tube of a 0.1 m knot). Two views 60° apart of such a
#: surface, each started at the truth, refine 2-3 mm and up to 3.6° away from it on the raw
#: clouds (views from one side: within 0.3 mm), and the verdict accepted some
#: (``benchmarks/global_objects.py``, seed 41: every trial below 3.6 biased or borderline, every
#: one above 5.2 resolved; seed 7 alike). Denoised, the 0.1-0.2 m trials of seed 41 refined from
#: the truth within 2° / 1 % read 5.1-253, the four outside 3.2, 3.3, 4.7 and 5.3 (that one
#: refused by its verdict). Rooms, streets and the 3DMatch fragments read 9-7000 raw; it is
#: measured only when the refinement found the target's normals noisy (:data:`NOISY_NORMALS`),
#: which every object below 5 did and none of those did.
MIN_FLATNESS = 5.0

#: The answer refined on the denoised clouds is refused when their close fraction at its pose
#: is below this times the raw clouds' at the same pose. Denoising moves points across the
#: surface only, so two views of one shape, aligned, fit at least as closely as their raw
#: clouds did; a looser fit means it changed the shapes (a thin tube smoothed under a noise
#: estimate its curvature inflated), and the denoised pose is no better than the raw one.
#: ``benchmarks/global_objects.py``, seed 41 (where it was chosen): every right answer 1.01-
#: 1.24, the one wrong one (refused already) 0.82; seeds 7 and 3: right answers 0.94 and up,
#: wrong ones 0.64-0.80 (0.1-0.2 m knots accepted 5-6° off, two low-overlap pairs accepted
#: 176-178° off).
MIN_DENOISED_FIT = 0.9

NO_ALIGNMENT = "no reliable alignment"


@dataclass(frozen=True)
class GlobalHypothesis:
    """One candidate pose, from one clique of consistent correspondences.

    ``verdict`` and ``covariance`` come from the refinement's trust analysis, run on first
    access: :func:`register_global` runs it only for the hypotheses that decide the answer
    (the best accepted one and any rival that could make it ambiguous), so a runner-up that
    converged onto the answer costs its GICP solve only, and one whose clique is under
    :data:`RIVAL_CLIQUE_RATIO` of an accepted hypothesis' is not even refined.
    """

    #: ``T_target_source`` after GICP refinement (the robust solve's when refinement failed).
    pose: SE3
    #: ``T_target_source`` from the robust solve, before refinement.
    initial_pose: SE3
    #: Correspondences within the noise bound at ``initial_pose`` (of all matched pairs).
    num_inliers: int
    #: Size of the clique it was solved from.
    clique_size: int
    #: The GICP refinement, or ``None`` when ``refine=False`` or the clique was too small. It
    #: registered the source centred on its centroid ``c``: its ``pose`` is ``pose·Tr(c)``
    #: (its verdict, overlap and degeneracy do not depend on that frame; see ``_Refiner``).
    refinement: RegistrationResult | None = field(repr=False)
    #: Fraction of the refined (gridded) source within half a voxel of the target: the
    #: sharper overlap that ranks hypotheses and tells rivals apart (the verdict's overlap,
    #: at the two-voxel gate, is 0.86 for a street shifted by 5.7 m along itself, 0.93 at
    #: the truth). 0 when not refined.
    close_fraction: float = 0.0
    #: Reasons found outside the refinement's verdict (a small clique, a low overlap at the
    #: solve, a clique too small beside an accepted one's to be a rival, a refinement that
    #: moved too far or read a weak direction on noisy normals with no other clique's
    #: refinement at its pose): any of the first three means not refined.
    checks: tuple[str, ...] = ()
    #: ``Ad(Tr(c))``: moves the refinement's covariance (tangent at ``pose·Tr(c)``) to the
    #: tangent at ``pose``.
    adjoint: FloatArray = field(default_factory=lambda: np.eye(6), repr=False)

    @functools.cached_property
    def verdict(self) -> Verdict:
        """Accepted when the clique, the overlap at the solve, the refinement's own verdict
        and its move from the solve all pass (``refine=False``: the clique test alone)."""
        reasons: list[str] = []
        res = self.refinement
        if res is not None:
            verdict = res.verdict
            if verdict is not None and not verdict.accepted:
                reasons.extend(verdict.reasons)
        reasons.extend(self.checks)
        return Verdict(not reasons, tuple(reasons))

    @functools.cached_property
    def covariance(self) -> FloatArray:
        """``(6, 6)`` covariance of the refined pose (right perturbation, translation first);
        ``inf`` when not refined."""
        if self.refinement is None:
            return np.full((6, 6), np.inf)
        cov = np.array(self.refinement.covariance)
        if np.all(np.isfinite(cov)):
            cov = self.adjoint @ cov @ self.adjoint.T
            cov = 0.5 * (cov + cov.T)
        return cov


@dataclass(frozen=True)
class GlobalRegistrationResult:
    """Result of :func:`register_global`."""

    #: The candidates: the answer first when there is one (the first accepted in the order
    #: below), then by the fraction of the source they explain after refinement
    #: (``close_fraction``), then by inlier count.
    hypotheses: tuple[GlobalHypothesis, ...]
    accepted: bool
    #: Empty when accepted; otherwise ``"no reliable alignment"`` and why.
    reasons: tuple[str, ...]
    voxel_size: float
    feature_radius: float
    noise_bound: float
    num_source_keypoints: int
    num_target_keypoints: int
    num_correspondences: int
    time_s: float
    #: Wall seconds per stage, in pipeline order: ``voxel`` (choosing the voxel),
    #: ``keypoints``, ``descriptors``, ``matching``, ``pruning``, ``solve`` (the core's),
    #: ``refinement`` (GICP, including preparing its target once) and ``verdict``.
    stage_seconds: dict[str, float] = field(default_factory=dict)
    #: Process CPU seconds (every thread's) per stage, the same keys: on a shared machine the
    #: wall time also counts other jobs' turns.
    stage_cpu_seconds: dict[str, float] = field(default_factory=dict)
    #: The source's and the target's measured noise and flatness (:data:`MIN_FLATNESS`), or
    #: ``None`` when not measured: no hypothesis passed on its own, the refinement found the
    #: target's normals clean (:data:`NOISY_NORMALS`: resolved at its scale), or
    #: ``refine=False``.
    surface_noise: tuple[SurfaceNoise, SurfaceNoise] | None = None

    @property
    def best(self) -> GlobalHypothesis | None:
        """The accepted hypothesis, or ``None``."""
        return self.hypotheses[0] if self.accepted else None

    @property
    def pose(self) -> SE3 | None:
        """``T_target_source`` of the accepted hypothesis; ``None`` when none is reliable."""
        return self.hypotheses[0].pose if self.accepted else None

    @property
    def covariance(self) -> FloatArray | None:
        return self.hypotheses[0].covariance if self.accepted else None

    @property
    def verdict(self) -> Verdict:
        return Verdict(self.accepted, self.reasons)


def _positive(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise TypeError(f"{name}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: must be finite and > 0, got {value}")
    return v


#: :func:`default_voxel_size` stops once the voxel is known to this fraction (a keypoint count
#: within about twice that of the aim): finer only moves the voxel within the scatter of the
#: count itself (a few points in thousands between a cloud and its pre-gridded copy).
VOXEL_TOLERANCE = 0.005


def default_voxel_size(source: FloatArray, target: FloatArray, keypoints: int) -> float:
    """The voxel at which the larger of the two clouds keeps about ``keypoints`` points.

    A search between a thousandth and a fifth of the bounding-box diagonal for the smallest
    voxel that keeps at most ``keypoints`` (the count falls with the voxel, and it follows the
    point density, not only the extent: a street scan is dense near the sensor). The count
    goes as a power of the voxel (about ``v⁻²`` on surfaces), so the next voxel tried is
    interpolated in log-log between the bracket's ends (regula falsi with the Illinois
    correction, bisection as a fallback): 5-10 voxel-grid passes instead of a bisection's
    13 to a finer tolerance than :data:`VOXEL_TOLERANCE` needs. The passes run on the larger
    cloud already gridded at the smallest voxel, a tenth to a hundredth of its points on a
    LiDAR scan (a voxel's centroid moves by less than that small voxel, so the counts differ
    by a few points in thousands).
    """
    lo_all = np.minimum(source.min(0), target.min(0))
    hi_all = np.maximum(source.max(0), target.max(0))
    diag = float(np.linalg.norm(hi_all - lo_all))
    if diag <= 0:
        raise ValueError("source, target: all points coincide; nothing to register")
    big = source if len(source) >= len(target) else target
    lo, hi = math.log(diag / 1000), math.log(diag / 5)
    big = voxel_downsample(big, math.exp(lo)).points

    def excess(log_voxel: float) -> float:
        """log(count / keypoints): > 0 while the voxel is too small."""
        return math.log(len(voxel_downsample(big, math.exp(log_voxel)).points) / keypoints)

    f_lo = math.log(len(big) / keypoints)
    if f_lo <= 0:
        return math.exp(lo)
    f_hi = excess(hi)
    if f_hi > 0:
        return math.exp(hi)
    side = 0
    for _ in range(16):
        if hi - lo <= math.log1p(VOXEL_TOLERANCE):
            break
        x = hi - f_hi * (hi - lo) / (f_hi - f_lo)
        if not lo < x < hi:
            x = 0.5 * (lo + hi)
        f_x = excess(x)
        # Illinois: halve the value kept at the end that did not move twice running, so the
        # bracket closes from both sides (plain regula falsi creeps towards a step).
        if f_x > 0:
            lo, f_lo = x, f_x
            if side < 0:
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi = x, f_x
            if side > 0:
                f_lo *= 0.5
            side = 1
    return math.exp(hi)


def point_spacing(points: FloatArray) -> float:
    """Median distance from a point of ``points`` to its nearest neighbour (over
    :data:`SPACING_SAMPLES` evenly spaced points)."""
    step = max(1, len(points) // SPACING_SAMPLES)
    _, d2 = _core.KdTree(points).knn(np.ascontiguousarray(points[::step]), 2)
    return float(np.sqrt(np.median(d2[:, 1])))


def _overlap(h: GlobalHypothesis) -> float:
    return h.close_fraction


def _displacement(a: SE3, b: SE3, point: FloatArray) -> float:
    """How far ``point`` (source frame) lies between poses ``a`` and ``b``: at the source's
    centre this measures how far the cloud moved, whereas the poses' translations also move
    with a rotation about an origin that may lie metres outside the cloud (an RGB-D camera's)."""
    return float(
        np.linalg.norm(a.rotation @ point + a.translation - b.rotation @ point - b.translation)
    )


def _rotation_angle(a: SE3, b: SE3) -> float:
    r = a.rotation.T @ b.rotation
    return float(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0)))


class _Refiner:
    """GICP refinement of hypotheses against one target prepared once (k-d tree, normals for
    the degeneracy analysis, covariances), on clouds gridded at :data:`REFINE_VOXEL` times
    the keypoint voxel.

    The source is registered centred on its centroid ``c`` (pose ``T·Tr(c)``): the verdict's
    degeneracy analysis measures rotations about axes through the source's origin, and a
    fragment whose origin lies metres outside it (an RGB-D camera's, 0.65-3 m in front of it
    on the 3DMatch pair) then shows a rotation about the points' own centre as a weak
    "translation coupled with rotation" (0.008 < 0.03 there; 0.063 about the centroid, with the
    same pose). The covariance is moved back to the source origin's tangent.
    """

    def __init__(
        self,
        source: FloatArray,
        target: FloatArray,
        voxel: float,
        gate: float,
        thresholds: VerdictThresholds,
        centre: FloatArray,
        *,
        defer_degeneracy: bool = True,
    ) -> None:
        self.centroid = centre
        self.shift = SE3(np.eye(3), self.centroid)
        # ξ (tangent at T) = A ξ_c (tangent at T·Tr(c)), A = Ad(Tr(c)) = [[I, [c]×], [0, I]].
        c = self.centroid
        self.adjoint = np.eye(6)
        self.adjoint[:3, 3:] = [[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]]
        self._prepare(source, target, voxel)
        self.noisy_normals = self.noisy
        self.gate = gate
        self.close = 0.5 * voxel
        # No local basin probe: its restarts (yaw turns around the result) ask whether another
        # basin explains the scan better, which the hypotheses' own rival check below answers
        # over the whole search space; on 3DMatch they were a third of the refinement's time.
        # Nor the verdict's own motion test from the start: its gate-wide prior says the same
        # as the move check of register_global, which a confirming clique may overrule.
        self.thresholds = replace(thresholds, basin_probe=False, max_motion_chi2=math.inf)
        # Noisy normals: the verdict leaves the degeneracy out and register_global asks a
        # second clique to confirm a pose found degenerate (_confirmed).
        self.defers_degeneracy = (
            self.noisy and defer_degeneracy and self.thresholds.reject_degenerate
        )
        if self.defers_degeneracy:
            self.thresholds = replace(self.thresholds, reject_degenerate=False)
        self.done: list[tuple[SE3, RegistrationResult, float]] = []
        self.source_covariances: FloatArray | None = None

    def _prepare(self, source: FloatArray, target: FloatArray, voxel: float) -> None:
        """The gridded, centred source and the prepared target; normals over more neighbours
        when the library's count leaves them noisy (``noisy``)."""
        fine = voxel_downsample(source, REFINE_VOXEL * voxel).points
        self.source = np.ascontiguousarray(fine - self.centroid)
        target_fine = voxel_downsample(target, REFINE_VOXEL * voxel).points
        self.num_neighbors = min(DEFAULT_K, len(target_fine))
        self.target = prepare(
            target_fine, normals=True, covariances=True, num_neighbors=self.num_neighbors
        )
        self.noisy = bool(self.target.normal_noise[1] > NOISY_NORMALS)
        if self.noisy:
            # Normals over more neighbours, or the verdict reads the noise as missing
            # information.
            self.num_neighbors = min(NOISY_NORMALS_NEIGHBORS, len(target_fine))
            self.target = prepare(
                target_fine, normals=True, covariances=True, num_neighbors=self.num_neighbors
            )

    def _covariances(self) -> FloatArray:
        """The fine source's GICP covariances, as :func:`scanreg.register` computes them (the
        library's neighbour count, the target's regularisation), once for every hypothesis:
        they do not depend on the pose, and each refinement computed them anew (a third of
        its time on the 3DMatch pair)."""
        if self.source_covariances is None:
            reg = self.target.regularization
            _, covs, _, _ = _core.KdTree(self.source).local_geometry(
                min(self.num_neighbors, len(self.source)),
                np.zeros(3),
                normals=False,
                regularization="plane" if reg == "none" else reg,
                epsilon=self.target.epsilon,
            )
            self.source_covariances = np.asarray(covs)
        return self.source_covariances

    def close_at(self, pose: SE3) -> float:
        """Fraction of the (fine) source within half a voxel of the target at ``pose``."""
        moved = (pose @ self.shift).apply(self.source)
        return self.target.nearest(moved, self.close).num_found / len(moved)

    def overlap_at(self, pose: SE3) -> float:
        """Fraction of the (fine) source within the gate of the target at ``pose``."""
        moved = (pose @ self.shift).apply(self.source)
        return self.target.nearest(moved, self.gate).num_found / len(moved)

    def reused(self, initial: SE3) -> tuple[SE3, RegistrationResult, float] | None:
        """The earlier refinement that a start at ``initial`` is the same pose as, if any."""
        # Disjoint cliques of one scene often agree on the pose (KITTI: all three within a
        # few cm; the outdoor pair's runner-ups started 0.5-1 gate off and converged onto the
        # first): a start within the gate and SAME_POSE_DEGREES of an earlier refinement is
        # the same pose as far as the answer goes (not a rival), so that refinement is reused.
        for done in self.done:
            pose = done[0]
            if _displacement(pose, initial, self.centroid) < self.gate and _rotation_angle(
                pose, initial
            ) < math.radians(SAME_POSE_DEGREES):
                return done
        return None

    def refine(self, initial: SE3) -> tuple[SE3, RegistrationResult, float]:
        """``(pose, registration, close fraction)``: ``T_target_source``, the registration of
        the centred source (``pose·Tr(c)``; its trust analysis not run yet) and the fraction
        of that source within half a voxel of the target."""
        done = self.reused(initial)
        if done is not None:
            return done
        res = register(
            self.source,
            self.target,
            method="gicp",
            init=initial @ self.shift,
            source_covariances=self._covariances(),
            max_correspondence_distance=self.gate,
            max_iterations=REFINE_MAX_ITERATIONS,
            thresholds=self.thresholds,
        )
        moved = _se3(res.pose).apply(self.source)
        close = self.target.nearest(moved, self.close).num_found / len(moved)
        out = (_se3(res.pose) @ self.shift.inverse(), res, close)
        self.done.append(out)
        return out


class _Clock:
    """Wall and process-CPU stopwatch of one stage."""

    def __init__(self) -> None:
        self.wall = time.perf_counter()
        self.cpu = time.process_time()

    def lap(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall, time.process_time() - self.cpu

    def add_to(self, stage: str, wall: dict[str, float], cpu: dict[str, float]) -> None:
        w, c = self.lap()
        wall[stage] += w
        cpu[stage] += c


def _se3(pose: Any) -> SE3:
    assert isinstance(pose, SE3)
    return pose


def _unconfirmed(reasons: list[str]) -> list[str]:
    return [f"{r}, and no other clique's refinement confirms it" for r in reasons]


def _weak_directions(res: RegistrationResult) -> list[str]:
    """The refinement's weak directions as the verdict names them (none: not degenerate)."""
    deg = res.degeneracy
    if deg is None:
        return []
    return [
        f"degenerate on noisy normals: {weak.description} (constraint {lam:.2g} < "
        f"{deg.threshold:.2g})"
        for weak, lam in zip(deg.directions, deg.eigenvalues, strict=True)
        if lam < deg.threshold
    ]


def _confirmed(
    hyp: GlobalHypothesis, hyps: list[GlobalHypothesis], gate: float, centre: FloatArray
) -> bool:
    """Whether another (disjoint) clique's refinement ends at ``hyp``'s refined pose.

    Asked where the refinement cannot vouch for its own pose:

    * it moved more than a gate from its solve, so it did not stay where its clique put it.
      On its own that is a slide (a low-overlap pair's wrong clique refined onto another wrong
      pose). But on millimetre-noisy small objects the descriptors leave a correct clique with
      a handful of true matches, and its solve lies 10-80° from the truth it refines to
      (``benchmarks/global_objects.py``);
    * its normals are noisy (:data:`NOISY_NORMALS`) and the degeneracy test finds a weak
      direction: the test's bar is raised by that noise (6 ε̃², 0.07-0.34 on 0.1-0.2 m objects
      under 2-3 mm) above what a figurine's weakest direction holds on clean views
      (0.05-0.06), so it refuses right poses and wrong ones alike. The geometry is then judged
      on the denoised clouds (:func:`_polished`), where the normals resolve it.

    What makes such a pose trustworthy is independent evidence leading there too: another
    clique, disjoint from it, whose refinement ends at the same pose (within the gate and
    :data:`SAME_POSE_DEGREES`). A low-overlap figurine of 0.1 m whose back view was turned onto
    its front (179° off) was refused by nothing else: no other clique led there."""
    for other in hyps:
        if other is hyp or other.refinement is None:
            continue
        if _displacement(other.pose, hyp.pose, centre) < gate and _rotation_angle(
            other.pose, hyp.pose
        ) < math.radians(SAME_POSE_DEGREES):
            return True
    return False


def _polished(
    answer: GlobalHypothesis,
    clean: list[FloatArray],
    voxel: float,
    gate: float,
    thresholds: VerdictThresholds,
    centre: FloatArray,
    raw: _Refiner,
) -> tuple[GlobalHypothesis, list[str]]:
    """``answer`` refined again on the denoised ``clean`` source and target, and the reasons
    to refuse it (its verdict there, a move beyond the gate, or a looser fit than the ``raw``
    clouds' at the same pose: :data:`MIN_DENOISED_FIT`)."""
    pose, res, close = _Refiner(
        clean[0], clean[1], voxel, gate, thresholds, centre, defer_degeneracy=False
    ).refine(answer.pose)
    checks: list[str] = []
    raw_close = raw.close_at(pose)
    if close < MIN_DENOISED_FIT * raw_close:
        checks.append(
            f"denoised clouds fit looser than the raw ones at the same pose (close fraction "
            f"{close:.2f} < {MIN_DENOISED_FIT:g} x {raw_close:.2f}): denoising changed the "
            "surfaces, which then no longer share one shape"
        )
    moved = _displacement(pose, answer.pose, centre)
    if moved > gate:
        checks.append(
            f"refinement on the denoised clouds moved the source centre {moved:.3g} > gate "
            f"{gate:.3g}"
        )
    polished = replace(
        answer, pose=pose, refinement=res, close_fraction=close, checks=tuple(checks)
    )
    if polished.verdict.accepted:
        return polished, []
    return polished, [NO_ALIGNMENT, *(f"denoised: {r}" for r in polished.verdict.reasons)]


def register_global(
    source: Any,
    target: Any,
    *,
    voxel_size: float | None = None,
    feature_radius: float | None = None,
    noise_bound: float | None = None,
    max_hypotheses: int = 3,
    min_inliers: int = DEFAULT_MIN_INLIERS,
    refine: bool = True,
    thresholds: VerdictThresholds | None = None,
) -> GlobalRegistrationResult:
    """Estimate ``T_target_source`` with no initial guess, or say that none is reliable.

    Parameters
    ----------
    source, target
        ``(N, 3)`` / ``(M, 3)`` float64, C-contiguous, finite, in their own frames.
    voxel_size
        Keypoint grid (units of the points). ``None``: the larger cloud keeps about
        :data:`DEFAULT_KEYPOINTS` keypoints, but at least :data:`MIN_VOXEL_SPACINGS` times its
        median point spacing (:func:`point_spacing`).
    feature_radius
        FPFH neighbourhood radius; ``None``: ``5 * voxel_size``.
    noise_bound
        Largest distance of a correct keypoint match after alignment (β of the pruning and
        the TLS cost); ``None``: ``voxel_size``.
    max_hypotheses
        Disjoint cliques solved and verified at most.
    min_inliers
        A hypothesis from a smaller clique is rejected.
    refine
        Refine each hypothesis with GICP and judge it with the verdict (the covariance and the
        overlap come from there). ``False``: only the clique test, covariance ``inf``.
    thresholds
        The verdict's thresholds; default :class:`VerdictThresholds` with ``min_overlap``
        :data:`DEFAULT_MIN_OVERLAP`.

    Returns
    -------
    GlobalRegistrationResult
        ``accepted`` only if the best hypothesis passes every check and no differing
        hypothesis passes too (an ambiguous scene is reported, not decided).

    Raises
    ------
    TypeError, ValueError
        Malformed input, naming the argument; a cloud that keeps fewer than 10 keypoints at
        ``voxel_size`` ("source: too small for descriptors ...").
    """
    t0 = time.perf_counter()
    src = as_points(source, "source", dim=3)
    tgt = as_points(target, "target", dim=3)
    for name, cloud in (("source", src), ("target", tgt)):
        if len(cloud) < 10:
            raise ValueError(
                f"{name}: too small for descriptors: {len(cloud)} points (at least 10 needed)"
            )
    if isinstance(max_hypotheses, bool) or not isinstance(max_hypotheses, int | np.integer):
        raise TypeError(f"max_hypotheses: expected an int, got {type(max_hypotheses).__name__}")
    if max_hypotheses < 1:
        raise ValueError(f"max_hypotheses: must be >= 1, got {max_hypotheses}")
    if isinstance(min_inliers, bool) or not isinstance(min_inliers, int | np.integer):
        raise TypeError(f"min_inliers: expected an int, got {type(min_inliers).__name__}")
    if thresholds is None:
        thresholds = VerdictThresholds(min_overlap=DEFAULT_MIN_OVERLAP)
    elif not isinstance(thresholds, VerdictThresholds):
        raise TypeError(f"thresholds: expected VerdictThresholds, got {type(thresholds).__name__}")
    stages: dict[str, float] = {}
    cpu: dict[str, float] = {}
    clock = _Clock()
    if voxel_size is None:
        big = src if len(src) >= len(tgt) else tgt
        voxel = max(
            default_voxel_size(src, tgt, DEFAULT_KEYPOINTS),
            MIN_VOXEL_SPACINGS * point_spacing(big),
        )
    else:
        voxel = _positive(voxel_size, "voxel_size")
    stages["voxel"], cpu["voxel"] = clock.lap()
    radius = 5.0 * voxel if feature_radius is None else _positive(feature_radius, "feature_radius")
    beta = voxel if noise_bound is None else _positive(noise_bound, "noise_bound")

    match = _core.register_global(
        src,
        tgt,
        voxel_size=voxel,
        feature_radius=radius,
        noise_bound=beta,
        max_hypotheses=int(max_hypotheses),
        clique_search_budget=CLIQUE_SEARCH_BUDGET,
    )
    stages.update(match.stage_seconds)
    cpu.update(match.stage_cpu_seconds)
    stages["refinement"] = stages["verdict"] = cpu["refinement"] = cpu["verdict"] = 0.0

    gate = 2.0 * voxel
    centre = src.mean(axis=0)
    clock = _Clock()
    refiner = _Refiner(src, tgt, voxel, gate, thresholds, centre) if refine else None
    clock.add_to("refinement", stages, cpu)
    hyps: list[GlobalHypothesis] = []
    adjoint = refiner.adjoint if refiner is not None else np.eye(6)
    # The clique of the first refined hypothesis when the verdict accepts it (0: not accepted,
    # or none refined yet; after a rejected first one every hypothesis is refined, as before).
    leader = 0
    first_refined = True
    # Hypotheses whose own refinement cannot vouch for them, and why (see _confirmed).
    unvouched: dict[int, list[str]] = {}
    for pose_m, clique, inliers in zip(
        match.poses, match.clique_sizes, match.num_inliers, strict=True
    ):
        initial = SE3.from_matrix(pose_m)
        checks: list[str] = []
        res: RegistrationResult | None = None
        close = 0.0
        pose = initial
        if clique < min_inliers:
            # Rejected whatever GICP would make of it: not refined (a chance clique of a
            # no-overlap pair or the runner-up of a clear one; refining it cost as much as the
            # whole descriptor stage).
            checks.append(f"clique of {clique} consistent matches < {min_inliers}")
        elif (
            refiner is not None
            and clique < RIVAL_CLIQUE_RATIO * leader
            and refiner.reused(initial) is None
        ):
            # Too little support beside the accepted one to be a rival (its trust analysis
            # runs anyway: it is the answer unless a refined runner-up explains more).
            checks.append(
                f"clique of {clique} < {RIVAL_CLIQUE_RATIO:g} x the accepted hypothesis' "
                f"{leader}: no rival, not refined"
            )
        elif refiner is not None and (
            (start := refiner.overlap_at(initial)) < SOLVE_OVERLAP_FACTOR * thresholds.min_overlap
        ):
            # Refinement moves the source by at most a gate before it is refused, and from
            # this far below the verdict's overlap it does not get back in (a wrong clique
            # of the 3DMatch pair starts at 0.12 and ends at 0.17; the benchmark's correct
            # ones start at 0.5-0.97); refining it cost as much as the descriptor stage.
            checks.append(
                f"overlap {start:.2f} at the solve < "
                f"{SOLVE_OVERLAP_FACTOR * thresholds.min_overlap:.2f}"
            )
        elif refiner is not None:
            clock = _Clock()
            pose, res, close = refiner.refine(initial)
            clock.add_to("refinement", stages, cpu)
            moved = _displacement(pose, initial, centre)
            if moved > gate:
                unvouched[len(hyps)] = [
                    f"refinement moved the source centre {moved:.3g} > gate {gate:.3g} from "
                    "the solve"
                ]
            if refiner.defers_degeneracy:
                weak = _weak_directions(res)
                if weak:
                    unvouched.setdefault(len(hyps), []).extend(weak)
        hyp = GlobalHypothesis(
            pose=pose,
            initial_pose=initial,
            num_inliers=int(inliers),
            clique_size=int(clique),
            refinement=res,
            close_fraction=close,
            checks=tuple(checks),
            adjoint=adjoint,
        )
        hyps.append(hyp)
        if res is not None and first_refined:
            first_refined = False
            clock = _Clock()
            # One its own refinement cannot vouch for is judged once every hypothesis is
            # refined (see _confirmed).
            if len(hyps) - 1 not in unvouched and hyp.verdict.accepted:
                leader = int(clique)
            clock.add_to("verdict", stages, cpu)
    hyps = [
        replace(h, checks=(*h.checks, *_unconfirmed(unvouched[i])))
        if i in unvouched and not _confirmed(h, hyps, gate, centre)
        else h
        for i, h in enumerate(hyps)
    ]
    # Candidates by the fraction of the source they explain, then by inliers. The answer is
    # the first one accepted; a later one matters only as a rival (a differing pose that also
    # passes and explains nearly as much), so only those get the trust analysis here (its
    # basin restarts cost three GICP solves each: a third of the whole call on the street
    # pairs, for runner-ups that had converged onto the answer).
    hyps.sort(key=lambda h: (-_overlap(h), -h.num_inliers))
    clock = _Clock()
    best_at = next((i for i, h in enumerate(hyps) if h.verdict.accepted), None)
    reasons_out: list[str] = []
    if not hyps:
        reasons_out = [
            NO_ALIGNMENT,
            f"no clique of >= 3 consistent matches among "
            f"{len(match.correspondences)} correspondences",
        ]
    elif best_at is None:
        reasons_out = [NO_ALIGNMENT, *(f"best hypothesis: {r}" for r in hyps[0].verdict.reasons)]
    else:
        hyps.insert(0, hyps.pop(best_at))
        best = hyps[0]
        best_overlap = _overlap(best)
        for other in hyps[1:]:
            dt = _displacement(other.pose, best.pose, centre)
            da = math.degrees(_rotation_angle(other.pose, best.pose))
            # A differing pose is a rival if it explains nearly as much of the source within
            # half a voxel (a street seen turned by 180° or shifted along itself explains
            # less), whether or not its own verdict passes: a refusal of its refinement (not
            # converged, a weak direction) makes the answer no surer. A knot's back view
            # turned onto its front (views 150° apart) was answered wrongly while such a
            # runner-up explained 0.91 of the answer's share, refused for a weak direction.
            if (dt > gate or da > SAME_POSE_DEGREES) and _overlap(
                other
            ) >= AMBIGUITY_RATIO * best_overlap:
                reasons_out = [
                    NO_ALIGNMENT,
                    f"ambiguous: hypotheses {dt:.3g} apart and {da:.1f} deg apart both fit "
                    f"(close fraction {_overlap(other):.2f} vs {best_overlap:.2f})",
                ]
                break
    noise: tuple[SurfaceNoise, SurfaceNoise] | None = None
    if not reasons_out and refiner is not None and refiner.noisy_normals:
        # Only where the refinement found the target's normals noisy (normals that agree with
        # their neighbours' at the library's count say the surface is flat above its noise at
        # that scale already: rooms and streets, whose calls skip all this). The answer was
        # found and judged on the raw clouds; its pose is biased by their noise (two views
        # 60° apart of a 0.1 m object, refined from the truth, end up to 3.6° / 3 mm from
        # it), so it is refined again on both clouds denoised at the larger of their noises,
        # and the surface's resolution is judged on those.
        sigma = max(surface_noise(src).sigma, surface_noise(tgt).sigma)
        clean = [denoise(cloud, SurfaceNoise(sigma, 0.0, 0.0)) for cloud in (src, tgt)]
        noise = (surface_noise(clean[0]), surface_noise(clean[1]))
        flat = min(n.flatness for n in noise)
        if flat < MIN_FLATNESS:
            reasons_out = [
                NO_ALIGNMENT,
                f"surface not resolved: denoised, noise and curvature still spread it by "
                f"~{max(n.sigma for n in noise):.3g} at every scale "
                f"(flatness {flat:.2g} < {MIN_FLATNESS:g}); views from two sides differ by "
                "more than a pose",
            ]
        else:
            hyps[0], reasons_out = _polished(
                hyps[0], clean, voxel, gate, thresholds, centre, refiner
            )
    clock.add_to("verdict", stages, cpu)
    return GlobalRegistrationResult(
        hypotheses=tuple(hyps),
        accepted=not reasons_out,
        reasons=tuple(reasons_out),
        voxel_size=voxel,
        feature_radius=radius,
        noise_bound=beta,
        num_source_keypoints=int(match.num_source_descriptors),
        num_target_keypoints=int(match.num_target_descriptors),
        num_correspondences=len(match.correspondences),
        time_s=time.perf_counter() - t0,
        stage_seconds=stages,
        stage_cpu_seconds=cpu,
        surface_noise=noise,
    )
