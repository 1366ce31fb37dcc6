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
``DEFAULT_KEYPOINTS`` keypoints, the FPFH radius is five voxels and the noise bound one voxel,
so a hand-held object scan and a street scan both work without flags.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, as_points
from .preprocess import voxel_downsample
from .register import RegistrationResult, register
from .transform import SE3
from .verdict import Verdict, VerdictThresholds

#: Keypoints the default voxel aims at for the larger cloud: the descriptor match is a brute
#: force over both keypoint sets (quadratic), and about this many kept the 3DMatch pair's
#: correct matches (a 5 cm voxel, as the benchmark's own protocol uses).
DEFAULT_KEYPOINTS = 5000
#: Smallest clique (mutually consistent correspondences) a hypothesis needs to be accepted:
#: pairs with no overlap (KITTI crops 10-24 m apart, a 3DMatch fragment against a street scan)
#: gave chance cliques of 7-12, correct pairs 80-800 (3DMatch, simulated street, KITTI).
DEFAULT_MIN_INLIERS = 15
#: Least fraction of the source within the gate of the target after refinement (the verdict's
#: overlap): partial views overlap far less than successive scans, so below the local default.
DEFAULT_MIN_OVERLAP = 0.3

#: A second, differing accepted hypothesis with at least this fraction of the best one's
#: overlap makes the result ambiguous.
AMBIGUITY_RATIO = 0.9

NO_ALIGNMENT = "no reliable alignment"


@dataclass(frozen=True)
class GlobalHypothesis:
    """One candidate pose, from one clique of consistent correspondences."""

    #: ``T_target_source`` after GICP refinement (the robust solve's when refinement failed).
    pose: SE3
    #: ``T_target_source`` from the robust solve, before refinement.
    initial_pose: SE3
    #: Correspondences within the noise bound at ``initial_pose`` (of all matched pairs).
    num_inliers: int
    #: Size of the clique it was solved from.
    clique_size: int
    #: ``(6, 6)`` covariance of the refined pose (right perturbation, translation first).
    covariance: FloatArray
    verdict: Verdict
    #: The GICP refinement, or ``None`` when ``refine=False``.
    refinement: RegistrationResult | None = field(repr=False)


@dataclass(frozen=True)
class GlobalRegistrationResult:
    """Result of :func:`register_global`."""

    #: The candidates, best first (accepted before rejected, then by overlap after
    #: refinement, then by inlier count).
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


def default_voxel_size(source: FloatArray, target: FloatArray, keypoints: int) -> float:
    """The voxel at which the larger of the two clouds keeps about ``keypoints`` points.

    A geometric bisection between a thousandth and a fifth of the bounding-box diagonal (12
    voxel-grid passes): the count falls monotonically with the voxel, and it follows the
    point density, not only the extent (a street scan is dense near the sensor).
    """
    pts = np.concatenate([source, target])
    diag = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    if diag <= 0:
        raise ValueError("source, target: all points coincide; nothing to register")
    big = source if len(source) >= len(target) else target
    lo, hi = math.log(diag / 1000), math.log(diag / 5)
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        n = len(voxel_downsample(big, math.exp(mid)).points)
        if n > keypoints:
            lo = mid
        else:
            hi = mid
    return math.exp(hi)


def _overlap(h: GlobalHypothesis) -> float:
    q = h.refinement.quality if h.refinement is not None else None
    return q.overlap if q is not None else 0.0


def _rotation_angle(a: SE3, b: SE3) -> float:
    r = a.rotation.T @ b.rotation
    return float(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0)))


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
        :data:`DEFAULT_KEYPOINTS` keypoints.
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
    voxel = (
        default_voxel_size(src, tgt, DEFAULT_KEYPOINTS)
        if voxel_size is None
        else _positive(voxel_size, "voxel_size")
    )
    radius = 5.0 * voxel if feature_radius is None else _positive(feature_radius, "feature_radius")
    beta = voxel if noise_bound is None else _positive(noise_bound, "noise_bound")

    match = _core.register_global(
        src,
        tgt,
        voxel_size=voxel,
        feature_radius=radius,
        noise_bound=beta,
        max_hypotheses=int(max_hypotheses),
    )

    # Refinement on clouds at half the keypoint voxel: finer than the keypoints (so the pose
    # improves on them), coarse enough to keep GICP fast on a dense scan.
    if refine:
        src_fine = voxel_downsample(src, 0.5 * voxel).points
        tgt_fine = voxel_downsample(tgt, 0.5 * voxel).points
    gate = 2.0 * voxel
    hyps: list[GlobalHypothesis] = []
    refined: list[RegistrationResult] = []
    for pose_m, clique, inliers in zip(
        match.poses, match.clique_sizes, match.num_inliers, strict=True
    ):
        initial = SE3.from_matrix(pose_m)
        reasons: list[str] = []
        if clique < min_inliers:
            reasons.append(f"clique of {clique} consistent matches < {min_inliers}")
        res: RegistrationResult | None = None
        cov = np.full((6, 6), np.inf)
        pose = initial
        if refine:
            # Disjoint cliques of one scene often agree on the pose (KITTI: all three within
            # a few cm): a start already inside an earlier refinement's gate would converge
            # to it, so that refinement is reused instead of run again.
            res = next(
                (
                    r
                    for r in refined
                    if np.linalg.norm(r.pose.translation - initial.translation) < 0.5 * gate
                    and _rotation_angle(r.pose, initial) < math.radians(2.0)  # type: ignore[arg-type]
                ),
                None,
            )
            if res is None:
                res = register(
                    src_fine,
                    tgt_fine,
                    method="gicp",
                    init=initial,
                    max_correspondence_distance=gate,
                    thresholds=thresholds,
                )
                refined.append(res)
            pose = res.pose  # type: ignore[assignment]
            cov = res.covariance
            verdict = res.verdict
            if verdict is not None and not verdict.accepted:
                reasons.extend(verdict.reasons)
            moved = float(np.linalg.norm(pose.translation - initial.translation))
            if moved > gate:
                reasons.append(f"refinement moved {moved:.3g} > gate {gate:.3g} from the solve")
        hyps.append(
            GlobalHypothesis(
                pose=pose,
                initial_pose=initial,
                num_inliers=int(inliers),
                clique_size=int(clique),
                covariance=cov,
                verdict=Verdict(not reasons, tuple(reasons)),
                refinement=res,
            )
        )
    # Accepted first; among those the one explaining most of the source, then by inliers.
    hyps.sort(key=lambda h: (not h.verdict.accepted, -_overlap(h), -h.num_inliers))

    reasons_out: list[str] = []
    if not hyps:
        reasons_out = [
            NO_ALIGNMENT,
            f"no clique of >= 3 consistent matches among "
            f"{len(match.correspondences)} correspondences",
        ]
    elif not hyps[0].verdict.accepted:
        reasons_out = [NO_ALIGNMENT, *(f"best hypothesis: {r}" for r in hyps[0].verdict.reasons)]
    else:
        best = hyps[0]
        best_overlap = _overlap(best)
        for other in hyps[1:]:
            if not other.verdict.accepted:
                continue
            dt = float(np.linalg.norm(other.pose.translation - best.pose.translation))
            da = math.degrees(_rotation_angle(other.pose, best.pose))
            # A differing pose that also passes is a rival only if it explains nearly as much
            # of the source (a street seen turned by 180° passes the verdict with less overlap).
            if (dt > gate or da > 5.0) and _overlap(other) >= AMBIGUITY_RATIO * best_overlap:
                reasons_out = [
                    NO_ALIGNMENT,
                    f"ambiguous: hypotheses {dt:.3g} apart and {da:.1f} deg apart both pass "
                    f"(overlap {_overlap(other):.2f} vs {best_overlap:.2f})",
                ]
                break
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
    )
