"""Local registration: align a scan to a scan or a map from an initial guess (the ICP family).

``register(source, target)`` estimates ``T_target_source`` for ``(N, 2)`` or ``(N, 3)`` clouds.
The whole iteration loop runs in the Rust core (:mod:`scanreg._core`, GIL released): at each
iteration every source point is moved by the current pose, matched to its nearest target point
within ``max_correspondence_distance`` and linearised; the normal equations are summed in
parallel and solved for a right-perturbation step ``T ← T @ exp(δ)``. This module sets the
policy (method, kernel, stopping) and turns the returned ≤ 6×6 matrices into a covariance and
a conditioning report.

Methods
-------
``point_to_point``
    ``|R p + t - q|²`` (Besl & McKay 1992).
``point_to_plane`` / ``point_to_line``
    ``(nᵀ(R p + t - q))²`` with the target normal ``n`` (Chen & Medioni 1992); in 2D the "plane"
    is a line and both names mean the same. Target points without a valid normal (degenerate
    neighbourhood) never form a correspondence.
``gicp``
    ``dᵀ (C_q + R C_p Rᵀ)⁻¹ d`` with ``d = R p + t - q`` and the k-NN covariances of source and
    target, regularised as planes (Segal, Haehnel & Thrun 2009); in 2D the line-to-line analogue.

Bad input: NaN/inf points are refused (``ValueError`` naming the point), as are empty clouds,
mismatched dimensions and an ``init`` that is not a rigid transform. A registration that runs
out of correspondences returns ``converged=False`` with ``stop_reason="too_few_correspondences"``
and the pose it had reached — never a silently wrong "converged" pose.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from . import _core, budget
from ._validate import FloatArray, as_covariance, as_matrix, as_points, check_finite_points
from ._validate import build as _build
from ._validate import frozen as _frozen
from ._validate import replaced as _replaced
from .degeneracy import (
    MIN_CONSTRAINT_2D,
    Degeneracy,
    HeldSteps,
    _centroid_and_spread_2d,
    _weakest_about_centroid_2d,
    held_steps_2d,
)
from .local_map import LocalMap
from .preprocess import DEFAULT_K, _voxel_centroids, check_k, positive_int
from .quality import (
    Conditioning,
)
from .robust import check_kernel
from .slide import SlideCheck, _fit, guard_start, refine_in_basin, refined_objective
from .start_search import _searched_start
from .target import PreparedTarget, prepare
from .transform import SE2, SE3, as_pose, pose_class
from .trust import (
    PLANE_METHOD,
    CorrespondenceAnalysis,
    CovarianceEstimates,
    LazyTrust,
    TrustInputs,
    correspondence_analysis,
    has_normals,
    pose_from_core,
    residual_variance,
    valley_moment,
)
from .verdict import QualityReport, Verdict, VerdictThresholds

Method = Literal["point_to_point", "point_to_plane", "point_to_line", "gicp"]
Optimizer = Literal["gauss_newton", "levenberg_marquardt"]
StopReason = Literal[
    "converged", "max_iterations", "too_few_correspondences", "diverged", "degenerate", "slid"
]

CovarianceKind = Literal["calibrated", "hessian", "censi", "block"]

METHODS: tuple[str, ...] = ("point_to_point", "point_to_plane", "point_to_line", "gicp")
COVARIANCE_KINDS: tuple[str, ...] = ("calibrated", "hessian", "censi", "block")
OPTIMIZERS: tuple[str, ...] = ("gauss_newton", "levenberg_marquardt")


def _positive_float(value: Any, name: str, *, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise TypeError(f"{name}: expected a number, got {type(value).__name__}")
    v = float(value)
    if math.isnan(v) or v <= 0 or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{name}: must be {'> 0' if allow_inf else 'finite and > 0'}, got {value}")
    return v


#: One sweep of a target map: its sweep motion ``(vx, vy, ω)·T`` and its sensor's pose
#: ``(x, y, θ)`` in the target's frame (:attr:`RegistrationSettings.target_sweeps`).
SweptBy = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True)
class RegistrationSettings:
    """How :func:`register` runs. Frozen; validated on construction (errors name the field).

    Distances are in the points' units (metres below), angles in radians.
    """

    #: The gate: a source point corresponds to its nearest target point only if that is at
    #: most this far (after moving the source by the current pose).
    max_correspondence_distance: float = 1.0
    #: Upper bound on Gauss–Newton / LM steps.
    max_iterations: int = 30
    #: Converged when the last step's translation is below this (m) ...
    translation_tolerance: float = 1e-4
    #: ... and its rotation angle below this (rad).
    rotation_tolerance: float = 1e-4
    #: Robust kernel (``none``, ``huber``, ``cauchy``, ``tukey``, ``geman_mcclure``, ``welsch``),
    #: applied by IRLS to each correspondence's residual norm.
    kernel: str = "none"
    #: Kernel scale, in the residual's units: metres for point-to-point/plane, whitened
    #: (Mahalanobis, unitless) for GICP. ``None``: a third of ``max_correspondence_distance``
    #: for the point methods, 1.0 for GICP.
    kernel_scale: float | None = None
    #: ``gauss_newton`` (classic ICP: every step taken) or ``levenberg_marquardt`` (a step is
    #: taken only if it lowers the cost over the iteration's correspondences).
    optimizer: Optimizer = "gauss_newton"
    #: Threads for the registration loop; ``None``: the default pool (``RAYON_NUM_THREADS`` or
    #: all cores). Downsampling, normals and covariances computed here use the default pool.
    #: Results do not depend on it.
    num_threads: int | None = None
    #: If set, voxel-downsample (centroid) the source, and a raw-array target, to this cell
    #: size first. A :class:`~scanreg.PreparedTarget` is used as it is.
    voxel_size: float | None = None
    #: Neighbourhood size for normals / covariances computed here (a raw target; GICP source).
    num_neighbors: int = DEFAULT_K
    #: Stop (``too_few_correspondences``) below this many correspondences. ``None``: the least
    #: that determines the pose with residual left over (point-to-point and GICP: ``dof/D + 1``;
    #: point-to-plane/line: ``dof + 1``).
    min_correspondences: int | None = None
    #: Which estimate ``RegistrationResult.covariance`` reports (all are in
    #: ``RegistrationResult.covariances``): ``hessian`` σ̂²(JᵀWJ)⁻¹ (sandwich under a kernel);
    #: ``censi`` Censi's closed form (noise on source and target points, shared targets);
    #: ``block`` the cluster-robust sandwich over spatial blocks of ``block_size``;
    #: ``calibrated`` (default) the smallest covariance covering ``censi`` and ``block``, with
    #: the prior variance along degenerate directions. See ``docs/calibration.md``.
    covariance: CovarianceKind = "calibrated"
    #: Edge of the spatial blocks of the ``block`` covariance (units of the points); ``None``:
    #: twice ``max_correspondence_distance`` (a fifth of the source's RMS radius if infinite).
    block_size: float | None = None
    #: Degeneracy-aware solve: if the first solve finds weak directions
    #: (:mod:`scanreg.degeneracy`), solve again from ``init`` with every step restricted to the
    #: well-constrained directions (solution remapping, Zhang, Kaess & Singh 2016), so the
    #: estimate keeps the initial guess along the weak ones; their variance is the prior's.
    #: Then two more held solves per weak direction, from ±min(σ_w, gate/2) along it, measure
    #: how the rest of the pose follows the held value (the covariance's valley term): a
    #: degenerate aware call costs about four solves.
    degeneracy_aware: bool = False
    #: Point-to-point and point-to-plane/line under Gauss–Newton: when two successive small
    #: steps (moving the points by under a tenth of the gate) point the same way and shrink,
    #: stretch the next by the rest of their geometric series (at most 3×), kept only if the
    #: truncated cost there is no higher than where the step started (else the plain step is
    #: taken: safeguarded Besl & McKay 1992 acceleration). Point-to-point: fewer iterations
    #: (KITTI 20 → 11, the outdoor pair 17 → 10, 2D scans −11 to −21 %) at the same or a lower
    #: final cost, the basin of convergence the plain loop's to within 2 of 120 starts;
    #: point-to-plane: KITTI 7 → 6, outdoor 9 → 8 (0.88–0.92× the time), basin 61 → 62 %; 2D
    #: point-to-line: +2 % time, median error 11.5 → 11.1 mm on Intel pairs
    #: (``benchmarks/README.md``). ``False``: the textbook loop. GICP and LM ignore it.
    extrapolate: bool = True
    #: Never return a pose that explains the scan clearly worse than the start
    #: (:mod:`scanreg.slide`): when the solve ends with clearly fewer source points within a
    #: tenth of the gate than an ``init`` that fits well had, solve again from ``init`` with a
    #: fifth of the gate, and if that slides too return ``init`` itself
    #: (``stop_reason="slid"``, rejected by the verdict). Two nearest-neighbour passes per call;
    #: the re-solve only when the first slid (on Intel relation pairs started at the relation,
    #: 35 of 400). ``False``: the plain solve.
    never_worse_than_start: bool = True
    #: 2D scans without per-beam time, taken while the sensor moved: its motion over the
    #: source's sweep, ``(vx, vy, ω)·T`` (the body twist times the sweep's duration, translation
    #: first, the source frame; e.g. :func:`scanreg.deskew.velocity_from_motion` of the motion
    #: between scans times ``T``). ``calibrated`` then covers the estimate's shift that the
    #: sweep's distortion causes (each beam off by the motion between its time and the
    #: sweep's middle, its time read from its bearing; ``docs/calibration.md``). ``None``: the
    #: scans are taken as instantaneous (or deskewed, :func:`scanreg.deskew`).
    sweep_motion: tuple[float, float, float] | None = None
    #: The same for the target when it is one scan in its own frame swept while moving (two
    #: consecutive scans of a turning robot: much of the distortion is common and cancels);
    #: ``None``: the target is taken as undistorted (a deskewed scan).
    target_sweep_motion: tuple[float, float, float] | None = None
    #: Where the target's sensor was when it swept, ``(x, y, θ)`` in the target's frame (its
    #: bearings, hence its beams' times, are read from there, and its ``target_sweep_motion``
    #: is in that sensor's frame). ``None``: the target frame's origin (a scan in its own
    #: frame). For a map of several sweeps: ``target_sweeps``.
    target_sweep_origin: tuple[float, float, float] | None = None
    #: The target is a map that blends several sweeps (a local map's keyframes, each swept at
    #: its own rate and heading): ``((motion, origin), ...)``, each sweep's
    #: ``target_sweep_motion`` and ``target_sweep_origin``. Which of them laid the matched
    #: points is not known, so ``calibrated`` takes the mean of their distortion terms
    #: (``docs/calibration.md``); ``Odometry2D`` passes its window's keyframes. Not with
    #: ``target_sweep_motion`` (one sweep: pass it alone).
    target_sweeps: tuple[SweptBy, ...] | None = None
    #: 2D point-to-line with ``never_worse_than_start``, from an ``init`` that explains at least
    #: a fifth of the source within a tenth of the gate: refine inside the basin the solve
    #: chose (:func:`scanreg.slide.refine_in_basin`): two more solves with 0.3 of the gate and
    #: a Cauchy kernel, from ``init`` and from the solve's end; of ``init`` and the converged
    #: two, the pose with the least point-to-line residual truncated at a tenth of the gate is
    #: returned (evaluated with this gate and kernel; ties to ``init``; a source that is not
    #: one scan takes its covariance from the narrow objective there, :mod:`scanreg.trust`).
    #: On 400 Kümmerle relation pairs per log from the wheel odometry
    #: (``benchmarks/relation_pairs.py``):
    #: wrong results 22 → 6 (Intel), 15 → 7 (ACES), 137 → 53 (hospital), Karto's 6 / 7 / 58,
    #: for about 0.4 ms more a call. ``False``: the solve (and guard) alone.
    refine_in_basin: bool = True
    #: 2D, with a stated ``init_covariance`` whose 3σ reaches beyond half the gate (in
    #: translation, or in heading times the source's RMS radius): search that window first
    #: (capped at one gate and 30°) by correlative branch and bound on a grid of a tenth of
    #: the gate, penalised by the covariance as Karto's matcher penalises its own, and solve
    #: from its answer unless it lies on the window's edge (:mod:`scanreg.start_search`); the
    #: verdict still measures the motion from ``init``. Not with ``degeneracy_aware`` (which
    #: keeps ``init`` along the weak directions) or a ``step_projector``. Consecutive Radish
    #: scans from simulated wheels with their noise model stated
    #: (``benchmarks/relation_pairs.py``): see benchmarks/README.md. ``False``: solve from
    #: ``init``.
    search_start: bool = True
    #: With the refinement in the basin (above): when the result is degenerate — weak by the
    #: solve's own information about the source's centroid, evaluated there
    #: (:func:`scanreg.degeneracy.held_steps_2d`: the same in any frame), and by the trust
    #: analysis — solve again with the refinement's narrow objective and every step held
    #: along the weak directions (a corridor's axis), as ``degeneracy_aware`` does with the
    #: full objective, from the refined pose with its coordinates along them set back to
    #: ``init``'s (from ``init`` itself a wrong heading was kept too). The estimate then keeps
    #: ``init`` where the scans do not fix it (the source's centroid along the axis), with the
    #: variance the covariance already reports there (the prior's), plus the
    #: valley term (:func:`scanreg.trust.valley_moment`: two more held solves per weak
    #: direction); the analysis then runs within the call. On 400 Kümmerle relation pairs
    #: per log from the wheel odometry (``benchmarks/relation_pairs.py``): median error /
    #: wrong Intel 1.61 cm / 6 → 1.42 / 1 (Karto's matcher 1.41 / 6), ACES 2.88 / 7 → 2.70 / 3
    #: (3.00 / 7), hospital 4.97 / 53 → 4.93 / 49 (6.50 / 58); 0.87 → 1.00 ms a pair on Intel
    #: (a screen on every call, ~15 µs; on a degenerate result the analysis within the call
    #: and three held solves, ~1.1 ms). ``False``: the refined result as it is.
    hold_degenerate: bool = True

    def __post_init__(self) -> None:
        _positive_float(
            self.max_correspondence_distance, "max_correspondence_distance", allow_inf=True
        )
        positive_int(self.max_iterations, "max_iterations")
        _positive_float(self.translation_tolerance, "translation_tolerance")
        _positive_float(self.rotation_tolerance, "rotation_tolerance")
        if not isinstance(self.kernel, str):
            raise TypeError(f"kernel: expected a str, got {type(self.kernel).__name__}")
        check_kernel(self.kernel)
        if self.kernel_scale is not None:
            _positive_float(self.kernel_scale, "kernel_scale")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(
                f"optimizer: unknown {self.optimizer!r}; expected one of {', '.join(OPTIMIZERS)}"
            )
        if self.num_threads is not None:
            positive_int(self.num_threads, "num_threads")
        if self.voxel_size is not None:
            _positive_float(self.voxel_size, "voxel_size")
        positive_int(self.num_neighbors, "num_neighbors", minimum=2)
        if self.min_correspondences is not None:
            positive_int(self.min_correspondences, "min_correspondences")
        if self.covariance not in COVARIANCE_KINDS:
            raise ValueError(
                f"covariance: unknown {self.covariance!r}; expected one of "
                f"{', '.join(COVARIANCE_KINDS)}"
            )
        if self.block_size is not None:
            _positive_float(self.block_size, "block_size")
        for name in (
            "degeneracy_aware",
            "extrapolate",
            "never_worse_than_start",
            "refine_in_basin",
            "search_start",
            "hold_degenerate",
        ):
            value = getattr(self, name)
            if not isinstance(value, bool):
                raise TypeError(f"{name}: expected a bool, got {type(value).__name__}")
        for name in ("sweep_motion", "target_sweep_motion", "target_sweep_origin"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _sweep_motion(value, name))
        if self.target_sweeps is not None:
            object.__setattr__(self, "target_sweeps", _target_sweeps(self.target_sweeps))
            if self.target_sweep_motion is not None or self.target_sweep_origin is not None:
                raise ValueError(
                    "target_sweeps: not with target_sweep_motion / target_sweep_origin "
                    "(one sweep: pass it alone)"
                )


def _target_sweeps(value: Any) -> tuple[SweptBy, ...]:
    """``value`` as a non-empty tuple of ``(motion, origin)`` pairs, or an error naming
    ``target_sweeps``."""
    if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
        raise TypeError(f"target_sweeps: expected (motion, origin) pairs, got {value!r}")
    if len(value) == 0:
        raise ValueError("target_sweeps: expected at least one (motion, origin) pair")
    out = []
    for i, pair in enumerate(value):
        if isinstance(pair, str | bytes) or not hasattr(pair, "__len__") or len(pair) != 2:
            raise TypeError(f"target_sweeps[{i}]: expected a (motion, origin) pair, got {pair!r}")
        out.append(
            (
                _sweep_motion(pair[0], f"target_sweeps[{i}] motion"),
                _sweep_motion(pair[1], f"target_sweeps[{i}] origin"),
            )
        )
    return tuple(out)


def _sweep_motion(value: Any, name: str) -> tuple[float, float, float]:
    """``value`` as three finite floats (a 2D tangent or pose vector), or an error naming
    ``name``."""
    if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
        raise TypeError(f"{name}: expected three numbers, got {value!r}")
    try:
        out = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: expected three numbers, got {value!r}") from exc
    if out.shape != (3,):
        raise ValueError(f"{name}: expected 3 values, got shape {out.shape}")
    if not np.isfinite(out).all():
        raise ValueError(f"{name}: must be finite, got {value!r}")
    return (float(out[0]), float(out[1]), float(out[2]))


_DEFAULT_SETTINGS = RegistrationSettings()
_DEFAULT_THRESHOLDS = VerdictThresholds()

_PLANAR = ("point_to_plane", "point_to_line")

#: The core solve's arguments from ``method`` to ``target_covariances``, in the binding's
#: order (``_core.register_icp`` and ``_core.probe_restarts`` share them).
_SolverArgs = tuple[str, str, float, float, int, float, float, str, int, int | None, Any, Any, Any]


@dataclass(frozen=True)
class RegistrationTiming:
    """Wall-clock seconds spent in each stage of one :func:`register` call."""

    #: Downsampling and, for a raw target, its k-d tree and normals/covariances.
    target_preparation: float
    #: Source downsampling and (GICP) source covariances.
    source_preparation: float
    #: Each iteration (correspondences + linearisation + solve), in order.
    iterations: tuple[float, ...]
    #: The final evaluation at the returned pose (fitness, H, scores).
    final_evaluation: float
    #: Pose projection and, unless deferred to first access (a PreparedTarget), the trust
    #: analysis (covariances, degeneracy, conditioning, overlap, verdict).
    post_processing: float
    total: float

    @property
    def registration(self) -> float:
        """The core's iteration loop plus the final evaluation."""
        return float(sum(self.iterations)) + self.final_evaluation


@dataclass(frozen=True)
class RegistrationResult:
    """Result of :func:`register`.

    ``pose`` is ``T_target_source`` (``p_T = R p_S + t``). ``covariance`` is over the
    right-perturbation tangent ``δ`` (translation first, source frame): ``T_true = pose @ exp(δ)``.
    Everything below is evaluated at ``pose``: with the correspondences of the last search when
    the last step was below the tolerances (``converged``), else after a fresh search.

    The trust analysis (``covariance``, ``information``, ``conditioning``, ``covariances``,
    ``degeneracy``, ``quality``, ``verdict``) runs on first access of any of them, once, and
    is kept: reading only the pose costs the registration alone. It reads copies, never the
    caller's arrays, so it is the same whenever it runs. This holds for a
    :class:`~scanreg.PreparedTarget`; for a :class:`~scanreg.LocalMap` (updated in place by
    its owner), a raw-array target (its index would stay pinned by the result),
    ``degeneracy_aware`` and a refined 2D result that may be degenerate (``hold_degenerate``:
    the analysis decides whether it is held) the analysis runs within the call.
    """

    pose: SE2 | SE3
    #: The method as run (``point_to_plane`` reads ``point_to_line`` in 2D).
    method: str
    kernel: str
    #: Kernel scale used; ``nan`` for ``kernel="none"``.
    kernel_scale: float
    #: Steps computed.
    iterations: int
    #: ``stop_reason == "converged"``.
    converged: bool
    #: ``converged``: the last step was below both tolerances (under LM: no step lowered the
    #: cost, a minimum), or Gauss–Newton circled near a minimum among correspondence sets — its
    #: truncated cost repeating, or (3D) not below its best for three small steps (under 0.5 %
    #: of the gate each) — and the best iterate is returned; ``max_iterations``;
    #: ``too_few_correspondences`` (fewer than ``min_correspondences`` inside the gate — the
    #: pose is where it stopped);
    #: ``diverged``: a step was non-finite or implausibly large (over ten times the gate, or
    #: over 90°: a near-singular ``JᵀJ``), the pose before it is returned; ``degenerate``:
    #: ``JᵀJ`` singular, the correspondences do not determine the pose; ``slid``: the solve
    #: ended clearly worse than its start and so did a re-solve with a narrower gate: the pose
    #: is ``init``, evaluated there (``slide`` says by how much; the verdict rejects it).
    stop_reason: StopReason
    #: Source points with a correspondence inside the gate (and, for point-to-plane, a valid
    #: target normal) at ``pose``.
    num_correspondences: int
    #: Source points registered (after any downsampling).
    num_source_points: int
    #: The fraction of source points whose nearest target point is inside the gate at
    #: ``pose``, in [0, 1] (Open3D's fitness). It counts the points left without a factor
    #: because their target point has no normal — a linear 3D neighbourhood, see
    #: :func:`scanreg.prepare` — so it can exceed ``num_correspondences / num_source_points``.
    fitness: float
    #: RMS Euclidean distance ``|R p + t - q|`` over the correspondences (every method), or
    #: ``nan`` without any.
    inlier_rmse: float
    #: Final robust cost ``Σ ρ(|r|)`` over the correspondences.
    cost: float
    #: ``JᵀWJ`` at ``pose`` (kernel-weighted): the information matrix, tangent coordinates.
    hessian: FloatArray
    #: ``JᵀW r`` at ``pose`` (≈ 0 at a converged optimum).
    gradient: FloatArray
    #: Residual variance per scalar residual: ``Σ r² / (m - dof)`` (kernel: IRLS-weighted).
    sigma2: float
    #: The never-worse-than-the-start check (:mod:`scanreg.slide`): the fits at the start and
    #: the solve's end, and whether the pose is the solve's, a re-solve's from the start or the
    #: start's; None with ``never_worse_than_start=False``.
    slide: SlideCheck | None
    timing: RegistrationTiming
    settings: RegistrationSettings = field(repr=False)
    #: The trust analysis behind the properties below, computed on first access (once,
    #: thread-safe) for a PreparedTarget — within the call otherwise.
    _trust: LazyTrust = field(repr=False, compare=False, kw_only=True)

    @property
    def covariance(self) -> FloatArray:
        """The covariance of kind ``settings.covariance`` (default ``calibrated``: Censi ∨
        block sandwich, the prior along degenerate directions; ``docs/calibration.md``). The
        classic ``σ̂² (JᵀWJ)⁻¹`` is ``covariances.hessian``. All ``inf`` when not determined."""
        return self._trust.get().covariance

    @property
    def information(self) -> FloatArray:
        """``covariance⁻¹`` (all ``inf`` for a noise-free fit)."""
        return self._trust.get().information

    @property
    def conditioning(self) -> Conditioning:
        """Eigen-analysis of ``hessian`` with its weak directions named."""
        return self._trust.get().conditioning

    @property
    def covariances(self) -> CovarianceEstimates | None:
        """Every covariance kind; ``covariance`` is one of them (``settings.covariance``)."""
        return self._trust.get().covariances

    @property
    def degeneracy(self) -> Degeneracy | None:
        """Weak directions of the scene, named (:mod:`scanreg.degeneracy`)."""
        return self._trust.get().degeneracy

    @property
    def quality(self) -> QualityReport | None:
        """Overlap, residuals, motion from the initial guess, convergence
        (:mod:`scanreg.verdict`)."""
        return self._trust.get().quality

    @property
    def verdict(self) -> Verdict | None:
        """``verdict.accepted`` and the readable ``verdict.reasons``."""
        return self._trust.get().verdict

    @property
    def analysis_seconds(self) -> float:
        """Wall-clock seconds the trust analysis took (running it now if it has not run)."""
        return self._trust.get().seconds

    @property
    def standard_deviations(self) -> FloatArray:
        """Square roots of the covariance diagonal (m, m[, m], rad[, rad, rad])."""
        out: FloatArray = np.sqrt(np.diag(self.covariance))
        return out


_SETTING_NAMES = frozenset(f.name for f in dataclasses.fields(RegistrationSettings))


def _with_overrides(base: RegistrationSettings, overrides: dict[str, Any]) -> RegistrationSettings:
    if not _SETTING_NAMES.issuperset(overrides):
        unknown = sorted(set(overrides) - _SETTING_NAMES)
        raise TypeError(f"register: unknown setting(s) {', '.join(unknown)}")
    # A loop calling register(..., gate=...) with the same keywords validates them once. The
    # type is part of the key: True == 1 == 1.0 hash alike, but only some are valid. In the
    # caller's keyword order (no sort: a loop repeats its own order). The base is keyed by
    # identity (hashing a frozen dataclass hashes every field, at every call) and kept alive by
    # its entry, so its id cannot be reused while the entry exists.
    key = (id(base), *overrides.items(), *map(type, overrides.values()))
    try:
        hit = _OVERRIDDEN.get(key)
    except TypeError:  # an unhashable value: validated (and refused) by the constructor
        return dataclasses.replace(base, **overrides)
    if hit is not None and hit[0] is base:
        return hit[1]
    out = dataclasses.replace(base, **overrides)
    if len(_OVERRIDDEN) >= 64:
        _OVERRIDDEN.clear()
    _OVERRIDDEN[key] = (base, out)
    return out


_OVERRIDDEN: dict[tuple[Any, ...], tuple[RegistrationSettings, RegistrationSettings]] = {}


def _resolve_method(method: Any, dim: int) -> str:
    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; expected one of {', '.join(METHODS)}")
    if method == "point_to_line" and dim == 3:
        raise ValueError("method: 'point_to_line' is for 2D points; use 'point_to_plane' in 3D")
    if method == "point_to_plane" and dim == 2:
        return "point_to_line"
    return str(method)


@dataclass(frozen=True, slots=True)
class _Plan:
    """What :func:`register` derives from the settings, the method and the dimension alone,
    worked out once per combination: a loop registering scan after scan repeats them (with the
    trust inputs built lazily, the call's own Python on a 2D scan went from 10.4 to 9.7 µs)."""

    method: str  # as run
    dof: int
    #: Scalar residuals per correspondence.
    components: int
    min_correspondences: int
    #: The kernel's scale (1 without a kernel); NaN when it cannot be set (an infinite gate
    #: and no ``kernel_scale``: refused when the call reaches it).
    kernel_scale: float


def _plan(s: RegistrationSettings, method: Any, dim: int) -> _Plan:
    # Keyed by the settings' identity (kept alive by the entry), as in _with_overrides.
    key = (id(s), method, dim)
    try:
        hit = _PLANS.get(key)
    except TypeError:  # an unhashable method: refused by _resolve_method
        hit = None
    if hit is not None and hit[0] is s:
        return hit[1]
    method_eff = _resolve_method(method, dim)
    dof = 3 if dim == 2 else 6
    components = 1 if method_eff in _PLANAR else dim
    min_corr = s.min_correspondences
    if min_corr is None:
        min_corr = dof // components + 1
    if s.kernel == "none":
        k_scale = 1.0
    elif s.kernel_scale is not None:
        k_scale = s.kernel_scale
    else:
        k_scale = 1.0 if method_eff == "gicp" else s.max_correspondence_distance / 3.0
        if not math.isfinite(k_scale):
            k_scale = math.nan
    plan = _Plan(method_eff, dof, components, min_corr, k_scale)
    if len(_PLANS) >= 64:
        _PLANS.clear()
    _PLANS[key] = (s, plan)
    return plan


_PLANS: dict[tuple[Any, ...], tuple[RegistrationSettings, _Plan]] = {}


def _check_local_map(target: LocalMap, dim: int, method: str) -> LocalMap:
    if target.dim != dim:
        raise ValueError(f"target: a {target.dim}D LocalMap cannot register {dim}D source points")
    need = {
        "gicp": ("covariances", "voxel_covariances"),
        "point_to_plane": ("normals",),
        "point_to_line": ("normals",),
    }
    want = need.get(method)
    if want is not None and target.attributes not in want:
        raise ValueError(
            f"target: {method} needs a LocalMap that stores {' or '.join(want)}; "
            f"this one stores {target.attributes}"
        )
    return target


def _prepared_target(
    target: Any, dim: int, method: str, settings: RegistrationSettings
) -> PreparedTarget | LocalMap:
    want_normals = method in ("point_to_plane", "point_to_line")
    want_covs = method == "gicp"
    if isinstance(target, LocalMap):
        return _check_local_map(target, dim, method)
    if isinstance(target, PreparedTarget):
        if target.dim != dim:
            raise ValueError(
                f"target: a {target.dim}D PreparedTarget cannot register {dim}D source points"
            )
        if want_normals and target.normals is None:
            raise ValueError(
                f"target: {method} needs target normals; "
                "build it with prepare(points, normals=True)"
            )
        if want_covs and target.covariances is None:
            raise ValueError(
                "target: gicp needs target covariances; build it with "
                "prepare(points, covariances=True)"
            )
        return target
    # A voxel grid scans the points for NaN/inf itself (one scan of a raw sweep, not two).
    points = as_points(target, "target", dim=dim, finite=settings.voxel_size is None)
    if settings.voxel_size is not None:
        points = _voxel_checked(points, settings.voxel_size, "target")
    # Normals for every method when there are enough points: the degeneracy analysis uses the
    # plane information.
    if len(points) < dim + 1 and not (want_normals or want_covs):
        return prepare(points, normals=False)
    k = check_k(min(settings.num_neighbors, len(points)), len(points), dim)
    return prepare(points, normals=True, covariances=want_covs, num_neighbors=k)


def _voxel_checked(points: FloatArray, voxel_size: float, name: str) -> FloatArray:
    """``_voxel_centroids`` of points not yet scanned for NaN/inf: the core's grid scans them
    and refuses one with :func:`check_finite_points`'s message, here naming ``name`` (a raw
    KITTI sweep's 120k points were scanned twice)."""
    try:
        return _voxel_centroids(points, voxel_size)
    except ValueError as e:
        msg = str(e)
        if msg.startswith("points: "):
            raise ValueError(f"{name}: {msg.removeprefix('points: ')}") from None
        raise


#: The hold's screen (``hold_degenerate``): a refined 2D result whose own Hessian, moved to the
#: source's centroid, is weak nowhere below this many times the floor is not evaluated about
#: the centroid (on the 1 200 relation pairs of benchmarks/relation_pairs.py the two smallest
#: eigenvalues agree to 1e-13) ...
HOLD_SCREEN = 2.0
#: ... while the centroid lies within this many spreads of the source origin (farther, the
#: moved Hessian loses digits as the square of the ratio: tests/test_frames.py's 1e3-1e7 m).
HOLD_SCREEN_REACH = 100.0


def _held_start_2d(refined: FloatArray, start: FloatArray, centred: FloatArray) -> FloatArray:
    """Where the hold's solve starts: the ``refined`` pose moved along the weak directions
    only, as far as the ``start`` lies from it along them (both poses with the source about
    its centroid; ``centred`` is the held steps' projector ``I − P_w`` there). The start is
    read from the refined pose (its offset in the refined pose's axes, its turn), where the
    weak directions were found. Solved from the start itself the hold kept a wrong heading
    too: an Intel corridor pair started turned by 70° was refined to the reference's heading
    (92 % of the scan within 0.1 m), then held from the start at 63° off and 23 %."""
    rot = refined[:2, :2]
    turn = math.atan2(
        rot[0, 0] * start[1, 0] - rot[1, 0] * start[0, 0],
        rot[0, 0] * start[0, 0] + rot[1, 0] * start[1, 0],
    )
    towards = np.array([*(rot.T @ (start[:2, 2] - refined[:2, 2])), turn])
    return refined @ SE2.exp(towards - centred @ towards).as_matrix()


def _checked_init_covariance(init_covariance: Any, dof: int) -> FloatArray | None:
    """``init_covariance`` checked, as a copy (the analysis may read it after the call)."""
    if init_covariance is None:
        return None
    return as_covariance(init_covariance, "init_covariance", dof)


def _refined_evaluation(
    run: Callable[..., Any], returned: list[FloatArray], dof: int, s: RegistrationSettings
) -> Callable[[], tuple[Any, tuple[str, float]]]:
    """The refinement's narrow objective at ``returned[0]`` (the pose returned; the hold of a
    degenerate result replaces it), evaluated without moving when called (the trust analysis
    of a source that is not one scan reads it: :mod:`scanreg.trust`)."""
    narrow_gate, narrow_kernel = refined_objective(s.max_correspondence_distance)

    def evaluate() -> tuple[Any, tuple[str, float]]:
        at = run(
            np.zeros((dof, dof)),
            returned[0],
            max_iterations=1,
            gate=narrow_gate,
            kernel=narrow_kernel,
        )
        return at, narrow_kernel

    return evaluate


def register(
    source: Any,
    target: Any,
    *,
    method: Method = "point_to_plane",
    init: Any = None,
    settings: RegistrationSettings | None = None,
    source_covariances: Any = None,
    init_covariance: Any = None,
    thresholds: VerdictThresholds | None = None,
    step_projector: Any = None,
    **overrides: Any,
) -> RegistrationResult:
    """Estimate ``T_target_source`` aligning ``source`` to ``target`` from ``init``.

    Parameters
    ----------
    source
        ``(N, D)`` float64, C-contiguous, ``D`` = 2 or 3, in the source frame.
    target
        ``(M, D)`` float64 points in the target frame, a :class:`~scanreg.PreparedTarget`
        (reused as is: build it once with :func:`scanreg.prepare` for many registrations), or
        a :class:`~scanreg.LocalMap` (odometry's map, with the attributes the method needs).
        A raw array is prepared here (normals for point-to-plane/line, covariances for GICP).
    method
        ``point_to_point``, ``point_to_plane`` (3D; in 2D the same as ``point_to_line``),
        ``point_to_line`` (2D) or ``gicp``.
    init
        Initial ``T_target_source`` (``SE2``/``SE3`` or homogeneous matrix); default identity.
    source_covariances
        GICP only: ``(N, D, D)`` covariances of ``source`` when the caller has them already
        (computed here from ``num_neighbors`` neighbours otherwise).
    settings, **overrides
        A :class:`RegistrationSettings`, and/or its fields as keywords
        (``register(s, t, max_correspondence_distance=0.5)``); a misspelled field is a
        ``TypeError``.
    init_covariance
        ``(dof, dof)`` covariance of ``init`` over the tangent (the motion model's), used as
        the variance along degenerate directions. ``None``: a gate-wide prior,
        ``diag(δ², …, (δ/L_a)², …) / 3`` with ``δ = max_correspondence_distance`` and ``L_a``
        the rotation levers (ICP only converges from within about a gate of the truth: an
        error uniform within ``±δ``). In 2D a stated covariance whose 3σ reaches beyond half
        the gate also has its window searched before the solve (``search_start``).
    thresholds
        :class:`~scanreg.VerdictThresholds` for ``result.verdict``; default thresholds if
        ``None``.
    step_projector
        ``(dof, dof)`` matrix applied to every step (``δ ← P δ``): with ``P = I − V Vᵀ`` the
        estimate keeps ``init`` along the directions ``V`` the caller already knows are
        unobservable (the odometry's degeneracy-aware hold). ``None``: free steps.

    Raises
    ------
    TypeError, ValueError
        On malformed input, naming the argument.
    """
    t_start = time.perf_counter()
    source_attributes = source_covariances
    base = settings if settings is not None else _DEFAULT_SETTINGS
    if not isinstance(base, RegistrationSettings):
        raise TypeError(f"settings: expected RegistrationSettings, got {type(base).__name__}")
    s = _with_overrides(base, overrides) if overrides else base
    src = as_points(source, "source", finite=False)
    dim = src.shape[1]
    plan = _plan(s, method, dim)
    method_eff = plan.method
    if budget.LIMIT is not None:
        gicp = method_eff == "gicp" and source_covariances is None
        budget.check("register: source", len(src), ("source", "source_covariances")[: 1 + gicp])
    if s.voxel_size is None and method_eff == "gicp" and source_covariances is None:
        # Covariances are computed here first; otherwise register_icp's own scan (or the voxel
        # grid's, below) refuses a NaN/inf with the same message.
        check_finite_points(src, "source")
    # A composed guess carries round-off in its rotation; the core keeps whatever it is given.
    if init is None:
        pose0 = pose_class(dim).identity()
    else:
        pose0 = as_pose(init, "init", dim).orthonormalized()

    t0 = time.perf_counter()
    prepared = _prepared_target(target, dim, method_eff, s)
    t_target = time.perf_counter() - t0

    t0 = time.perf_counter()
    if s.voxel_size is not None:
        src = _voxel_checked(src, s.voxel_size, "source")
    source_covariances = None
    if source_attributes is not None:
        if method_eff != "gicp":
            raise ValueError("source_covariances: only used by method='gicp'")
        if s.voxel_size is not None:
            raise ValueError("source_covariances: cannot be combined with voxel_size")
        source_covariances = np.ascontiguousarray(source_attributes, dtype=np.float64)
        if source_covariances.shape != (len(src), dim, dim):
            raise ValueError(
                f"source_covariances: expected shape ({len(src)}, {dim}, {dim}), "
                f"got {source_covariances.shape}"
            )
    if method_eff == "gicp" and source_covariances is None:
        # A map's covariances were regularised by its builder: the source follows the
        # library default ("plane", 1e-3) unless a PreparedTarget says otherwise.
        reg, eps = "plane", 1e-3
        if isinstance(prepared, PreparedTarget):
            reg = "plane" if prepared.regularization == "none" else prepared.regularization
            eps = prepared.epsilon
        k = check_k(min(s.num_neighbors, len(src)), len(src), dim)
        _, source_covariances, _, _ = _core.KdTree(src).local_geometry(
            k, np.zeros(dim), normals=False, regularization=reg, epsilon=eps
        )
    t_source = time.perf_counter() - t0

    dof, components, min_corr, k_scale = (
        plan.dof,
        plan.components,
        plan.min_correspondences,
        plan.kernel_scale,
    )
    if k_scale != k_scale:  # NaN: see _Plan
        raise ValueError("kernel_scale: required with an infinite max_correspondence_distance")

    target_swept = s.target_sweep_motion is not None or s.target_sweeps is not None
    if dim != 2 and (s.sweep_motion is not None or target_swept):
        raise ValueError("sweep_motion: only 2D scans are modelled (deskew a 3D sweep instead)")
    if target_swept and isinstance(prepared, LocalMap):
        raise ValueError("target_sweep_motion: the target is a LocalMap, not one scan")

    given_prior = None
    if init_covariance is not None:
        given_prior = _checked_init_covariance(init_covariance, dof)
    if thresholds is not None and not isinstance(thresholds, VerdictThresholds):
        raise TypeError(f"thresholds: expected VerdictThresholds, got {type(thresholds).__name__}")
    # Where the solve starts: ``init``, or the best pose of its stated window when that reaches
    # beyond the solve's basin (scanreg.start_search). The verdict measures motion from init.
    solve_start = pose0
    if (
        s.search_start
        and dim == 2
        and given_prior is not None
        # A held solve keeps init along what it holds; so does the degeneracy-aware one.
        and step_projector is None
        and not s.degeneracy_aware
        and isinstance(prepared, PreparedTarget)
        and len(prepared.points)
    ):
        assert isinstance(pose0, SE2)
        searched = _searched_start(
            src, prepared._start_grid, pose0, given_prior, s.max_correspondence_distance
        )
        if searched is not None:
            solve_start = searched

    # A LocalMap carries its own normals/covariances (the core reads them under its lock); the
    # correspondence analysis reads the same id-indexed storage. A PreparedTarget passes its
    # arrays in.
    index: _core.KdTree | _core.LocalMap
    is_map = isinstance(prepared, LocalMap)
    t_points: Any = None
    t_normals: Any = None
    t_covs: Any = None
    if isinstance(prepared, LocalMap):
        index = prepared.native  # the analysis gathers the matched rows (target_rows below)
    else:
        index = prepared.index
        t_points, t_normals, t_covs = prepared.points, prepared.normals, prepared.covariances

    def solver_args(
        method: str,
        max_iterations: int,
        gate: float = s.max_correspondence_distance,
        kernel: tuple[str, float] = (s.kernel, k_scale),
    ) -> _SolverArgs:
        # The binding's arguments after the start(s) and before the step projector, by
        # position in its order (17 keywords cost 0.7 µs a call): one builder for the single
        # solve and the restarts.
        return (
            method,
            kernel[0],
            kernel[1],  # kernel_scale
            gate,  # max_correspondence_distance
            max_iterations,
            s.translation_tolerance,
            s.rotation_tolerance,
            s.optimizer,
            min_corr,  # min_correspondences
            s.num_threads,
            source_covariances,
            t_normals if method in _PLANAR and not is_map else None,  # target_normals
            t_covs if method == "gicp" and not is_map else None,  # target_covariances
        )

    def run(
        projector: FloatArray | None,
        start: SE2 | SE3 | FloatArray = solve_start,
        method: str = method_eff,
        max_iterations: int = s.max_iterations,
        gate: float = s.max_correspondence_distance,
        kernel: tuple[str, float] = (s.kernel, k_scale),
        source: FloatArray | None = None,
    ) -> Any:
        return _core.register_icp(
            src if source is None else source,
            index,
            start if isinstance(start, np.ndarray) else start.as_matrix(),  # init_pose
            *solver_args(method, max_iterations, gate, kernel),
            True,  # iterate
            projector,  # step_projector
            s.extrapolate,
        )

    def run_starts(
        projector: FloatArray | None,
        starts: FloatArray,
        max_iterations: int,
        probe: tuple[Any, ...],
    ) -> Any:
        # The wrong-basin probe's whole restart path in one core call: ``run`` from each of
        # ``starts`` (K, D+1, D+1), compared with the result as they end; ``probe`` holds
        # ``_core.probe_restarts``'s arguments after the solver's (scanreg.basin).
        return _core.probe_restarts(
            src,
            index,
            starts,  # init_poses
            *solver_args(method_eff, max_iterations),
            projector,  # step_projector
            s.extrapolate,
            *probe,
        )

    th = _DEFAULT_THRESHOLDS if thresholds is None else thresholds

    projector0 = None
    if step_projector is not None:
        projector0 = as_matrix(step_projector, "step_projector", (dof, dof))
    out = run(projector0)
    slide: SlideCheck | None = None
    if s.never_worse_than_start:
        out, slide = guard_start(
            out,
            index=index,
            source=src,
            start=solve_start,
            gate=s.max_correspondence_distance,
            target_points=t_points,
            solve_from_start=lambda gate: run(projector0, gate=gate),
            # One iteration whose every step is projected to zero: the outcome at the start,
            # with the correspondences the analysis reads (``iterate=False`` has none).
            evaluate_start=lambda: run(np.zeros((dof, dof)), max_iterations=1),
        )
        if s.refine_in_basin and dim == 2 and method_eff == "point_to_line":
            out, slide = refine_in_basin(
                out,
                slide,
                index=index,
                source=src,
                start=solve_start,
                gate=s.max_correspondence_distance,
                solve_narrow=lambda start, gate: run(
                    projector0, start, gate=gate, kernel=("cauchy", gate / 3.0)
                ),
                evaluate_at=lambda pose: run(np.zeros((dof, dof)), pose, max_iterations=1),
                residuals_at=lambda pose, gate: run(
                    np.zeros((dof, dof)), pose, max_iterations=1, gate=gate, kernel=("none", 1.0)
                ),
            )
    refined_at: Callable[[], tuple[Any, tuple[str, float]]] | None = None
    returned = [out.pose]
    if slide is not None and slide.refined_solve:
        refined_at = _refined_evaluation(run, returned, dof, s)

    # The projector the solve ran with (rebound below by the degeneracy-aware solve): the
    # point-to-point analysis's reference solve reads it through its closure.
    held: FloatArray | None = projector0

    # The trust analysis (covariances, degeneracy, conditioning, overlap, verdict) runs on first
    # access when the target is a PreparedTarget the caller holds anyway: reading only the pose
    # then costs the ICP. Not when the solve needs it (degeneracy-aware), when the target can
    # change under it (a LocalMap is updated in place by its owner), nor for a raw-array target,
    # whose index and normals were built for this call alone: a result kept unread would pin
    # them (megabytes per result in a pose graph's list of loop closures).
    # The refined 2D result held at the start along its weak directions when degenerate
    # (``hold_degenerate``): the analysis decides, so it runs within the call.
    hold_steps: HeldSteps | None = None
    to_centroid = np.eye(3)
    if s.hold_degenerate and slide is not None and slide.refined != "off":
        # Weak by the solve's own information about the source's centroid, evaluated there
        # (the core's Hessian about a far origin, moved to the centroid, loses its digits:
        # 1e7 m away the held poses were 1-4 µm apart; tests/test_frames.py asks 1e-6 m);
        # held only where the analysis finds the result degenerate too, so the covariance
        # reports the prior's variance along what is held.
        finite, (cx, cy), spread = _centroid_and_spread_2d(src)
        centroid = np.array([cx, cy])
        # Screened first on the solve's own Hessian (exact enough while the points lie within
        # a hundred spreads of their origin): clearly not weak there, not weak at all.
        screened = (
            math.hypot(cx, cy) <= HOLD_SCREEN_REACH * spread
            and out.num_correspondences > 0
            and _weakest_about_centroid_2d(out.hessian, (cx, cy), spread, out.num_correspondences)
            >= HOLD_SCREEN * MIN_CONSTRAINT_2D
        )
        if len(finite) and not screened:
            centred = np.ascontiguousarray(src - centroid)
            to_centroid = SE2.from_vector([*centroid, 0.0]).as_matrix()
            about = run(
                np.zeros((dof, dof)),
                np.asarray(out.pose) @ to_centroid,
                max_iterations=1,
                source=centred,
            )
            hold_steps = held_steps_2d(about.hessian, centred, about.num_correspondences)
    hold = hold_steps is not None
    aware = s.degeneracy_aware or hold
    lazy = isinstance(target, PreparedTarget) and not aware
    if lazy:
        # The analysis reads these later: never through a view of the caller's arrays.
        if src is source or (isinstance(source, np.ndarray) and np.may_share_memory(src, source)):
            src = src.copy()
        if (
            source_covariances is not None
            and source_attributes is not None
            and np.may_share_memory(source_covariances, source_attributes)
        ):
            source_covariances = source_covariances.copy()
    ctx_fields = {
        "source": src,
        "target": prepared,
        "target_points": t_points,
        "target_normals": t_normals,
        "target_covariances": t_covs,
        "source_covariances": source_covariances,
        "method": method_eff,
        "settings": s,
        "kernel_scale": k_scale,
        "components": components,
        "init_covariance": given_prior,
        "start": pose0,
        "solve_start": solve_start,
        "slide": slide,
        "thresholds": th,
        "plane_solve": (
            (lambda start: run(held, start, PLANE_METHOD[dim]))
            if method_eff == "point_to_point" and has_normals(prepared)
            else None
        ),
        "solve": lambda starts, iterations, probe: run_starts(held, starts, iterations, probe),
        "refined_objective": refined_at,
    }
    # Built here only when the solve needs it; a lazy analysis builds it on first use.
    ctx: TrustInputs | dict[str, Any] = ctx_fields
    first: CorrespondenceAnalysis | None = None
    if aware:
        ctx = _build(TrustInputs, ctx_fields)
        first = correspondence_analysis(ctx, out)
        # A start returned after a slide stays the start (rejected); a re-solve's narrower gate
        # is the held solve's too (at the full gate it would slide again).
        kept_start = slide is not None and slide.outcome == "start"
        gate = s.max_correspondence_distance
        kernel = (s.kernel, k_scale)
        if slide is not None and slide.outcome == "resolved":
            gate = slide.resolve_gate
        # The hold of a refined result solves the refinement's narrow objective (at the full
        # gate without a kernel the strong directions slide as the guard found; in the
        # simulated corridor the held L2 solve was so exact across the axis that the valley
        # term made it over-cautious: mean NEES 1.40 against 1.83 narrow, 40 realisations of
        # tests/test_trust.py's corridor).
        narrow = hold and not s.degeneracy_aware
        if narrow:
            gate, kernel = refined_objective(s.max_correspondence_distance)
        if first.degeneracy.degenerate and len(out.correspondences) and not kept_start:
            held = np.ascontiguousarray(np.eye(dof) - first.degeneracy.weak_projector())
            if narrow and hold_steps is not None:
                # Solved on the source about its centroid, where the projector is
                # hold_steps.centred: about a far origin the core's held step is singular (a
                # source 1e5 m from its origin stopped "degenerate" after one step).
                at = to_centroid @ SE2.from_vector([*hold_steps.centroid, 0.0]).as_matrix()
                centred_held = run(
                    hold_steps.centred,
                    _held_start_2d(
                        np.asarray(out.pose) @ at, solve_start.as_matrix() @ at, hold_steps.centred
                    ),
                    gate=gate,
                    kernel=kernel,
                    source=np.ascontiguousarray(src - at[:2, 2]),
                )
                again = centred_held
                if str(centred_held.stop_reason) == "converged":
                    back = np.asarray(centred_held.pose) @ np.linalg.inv(at)
                    # Evaluated with the registration's own gate and kernel, as the refinement
                    # returns its pose: the covariance and verdict read its pairs.
                    again = run(np.zeros((dof, dof)), back, max_iterations=1)
                # The valley's held solves run on the source as given: the projector over
                # its tangent (about its origin).
                cx, cy = at[0, 2], at[1, 2]
                origin_to = np.array([[1.0, 0.0, -cy], [0.0, 1.0, cx], [0.0, 0.0, 1.0]])
                origin_from = np.array([[1.0, 0.0, cy], [0.0, 1.0, -cx], [0.0, 0.0, 1.0]])
                held = np.ascontiguousarray(origin_from @ hold_steps.centred @ origin_to)
            else:
                again = run(held, gate=gate, kernel=kernel)
            if not narrow or str(again.stop_reason) == "converged":
                # The weak directions are the first solve's: the second is held along them.
                valley = valley_moment(
                    lambda start: run(held, start, gate=gate, kernel=kernel),
                    pose_from_core(again, dim),
                    first.degeneracy,
                    ctx.prior,
                    s.max_correspondence_distance,
                )
                if narrow:
                    returned[0] = again.pose
                    if slide is not None:
                        # The verdict's loose-fit check and the basin screen read the fit of
                        # the pose returned: the held one's, not the refinement's it replaced
                        # (a held solve may end worse than the refinement: tests/test_slide.py).
                        slide = dataclasses.replace(
                            slide,
                            held_fit=_fit(index, src, np.asarray(again.pose), slide.gate),
                        )
                        ctx = _replaced(ctx, slide=slide)  # built above with the old one
                out = again
                first = correspondence_analysis(ctx, out, held=first.degeneracy, valley=valley)

    t0 = time.perf_counter()
    pose = pose_from_core(out, dim)
    hessian = out.hessian  # the core's own fresh array, read-only: no copy needed
    n_corr = out.num_correspondences  # the core's ints and floats are Python's already
    sigma2 = residual_variance(out, components, s.kernel, dof)
    stop: StopReason = out.stop_reason
    if slide is not None and slide.outcome == "start":
        stop = "slid"  # evaluated at the start, not converged there
    trust = LazyTrust(ctx, out, pose, first)
    if not lazy:
        trust.get()
    t_post = time.perf_counter() - t0
    t_total = time.perf_counter() - t_start  # a lazy analysis is not counted (see its field)

    timing = _build(
        RegistrationTiming,
        {
            "target_preparation": t_target,
            "source_preparation": t_source,
            "iterations": out.iteration_seconds,
            "final_evaluation": out.final_evaluation_seconds,
            "post_processing": t_post,
            "total": t_total,
        },
    )
    return _build(
        RegistrationResult,
        {
            "pose": pose,
            "method": method_eff,
            "kernel": s.kernel,
            "kernel_scale": k_scale if s.kernel != "none" else math.nan,
            "iterations": (
                slide.refined_iterations
                if slide is not None and slide.refined != "off"
                else out.iterations
            ),
            "converged": stop == "converged",
            "stop_reason": stop,
            "num_correspondences": n_corr,
            "num_source_points": len(src),
            "fitness": out.num_in_gate / len(src),
            "inlier_rmse": math.sqrt(out.sum_squared_distances / n_corr) if n_corr else math.nan,
            "cost": out.cost,
            "hessian": hessian,
            "gradient": out.gradient,  # read-only, fresh
            "sigma2": sigma2,
            "slide": slide,
            "timing": timing,
            "settings": s,
            "_trust": trust,
        },
    )


@dataclass(frozen=True)
class SamplingCovariance:
    """Result of :func:`sampling_covariance`."""

    #: ``(dof, dof)`` sample covariance of the restarts' poses about ``reference`` (tangent,
    #: right perturbation); restarts that did not converge are left out.
    covariance: FloatArray
    #: The registration from ``init`` itself, about which the spread is measured.
    reference: RegistrationResult
    #: ``(R, dof)`` tangent offsets ``log(reference⁻¹ · pose_r)`` of the converged restarts.
    offsets: FloatArray
    #: Converged restarts over all restarts.
    converged_fraction: float


def sampling_covariance(
    source: Any,
    target: Any,
    *,
    method: Method = "point_to_plane",
    init: Any = None,
    init_covariance: Any = None,
    restarts: int = 20,
    seed: int = 0,
    settings: RegistrationSettings | None = None,
    **overrides: Any,
) -> SamplingCovariance:
    """Spread of the estimate over restarts from perturbed initial guesses.

    ``restarts`` registrations start from ``init @ exp(ξ)``, ``ξ ~ N(0, init_covariance)``
    (default: the gate-wide prior of :func:`register`), seeded by ``seed``. Their sample
    covariance about the registration from ``init`` shows how much the *optimiser* (basin,
    local minima, the degenerate drift) adds to the noise; it does not see the noise of the
    points themselves (each restart uses the same data), so compare it with, do not use it
    instead of, ``RegistrationResult.covariances``. ``restarts + 1`` registrations: costly.
    """
    count = positive_int(restarts, "restarts", minimum=2)
    prepared_target: PreparedTarget | LocalMap
    if isinstance(target, PreparedTarget | LocalMap):
        prepared_target = target
    else:
        base = settings if settings is not None else RegistrationSettings()
        merged = dataclasses.replace(base, **overrides) if overrides else base
        src_dim = as_points(source, "source").shape[1]
        prepared_target = _prepared_target(
            target, int(src_dim), _resolve_method(method, int(src_dim)), merged
        )
    reference = register(
        source,
        prepared_target,
        method=method,
        init=init,
        settings=settings,
        init_covariance=init_covariance,
        **overrides,
    )
    dim = reference.pose.DIM
    dof = 3 if dim == 2 else 6
    start = pose_class(dim).identity() if init is None else as_pose(init, "init", dim)
    prior = (
        reference.covariances.prior
        if reference.covariances is not None
        else np.eye(dof) * reference.settings.max_correspondence_distance**2
    )
    rng = np.random.default_rng(seed)
    offsets = []
    for _ in range(count):
        xi = rng.multivariate_normal(np.zeros(dof), prior)
        res = register(
            source,
            prepared_target,
            method=method,
            init=start @ type(start).exp(xi),  # type: ignore[operator]
            settings=settings,
            init_covariance=init_covariance,
            **overrides,
        )
        if res.converged:
            offsets.append((reference.pose.inverse() @ res.pose).log())  # type: ignore[operator]
    arr = np.array(offsets).reshape(-1, dof)
    cov = arr.T @ arr / max(len(arr) - 1, 1) if len(arr) >= 2 else np.full((dof, dof), np.nan)
    return SamplingCovariance(
        covariance=_frozen(cov),
        reference=reference,
        offsets=_frozen(arr),
        converged_fraction=len(arr) / count,
    )
