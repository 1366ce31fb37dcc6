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
import functools
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from . import _core, budget
from ._validate import FloatArray, as_matrix, as_points, check_finite_points
from ._validate import build as _build
from ._validate import frozen as _frozen
from ._validate import readonly as _readonly
from .basin import probe_basin
from .degeneracy import (
    Degeneracy,
    analyse_degeneracy,
    correspondence_normal_noise,
    rotation_levers,
    sampled_normals,
)
from .local_map import LocalMap
from .preprocess import DEFAULT_K, check_k, positive_int, voxel_downsample
from .quality import (
    Conditioning,
    block_from_inverse,
    censi_from_inverse,
    conditioning,
    covariance_upper_bound,
    information_from_covariance,
    least_squares_covariance,
    sandwich_covariance,
)
from .robust import check_kernel
from .target import PreparedTarget, prepare
from .transform import SE2, SE3, as_pose, pose_class
from .verdict import QualityReport, Verdict, VerdictThresholds, _assess_checked, judge

Method = Literal["point_to_point", "point_to_plane", "point_to_line", "gicp"]
Optimizer = Literal["gauss_newton", "levenberg_marquardt"]
StopReason = Literal[
    "converged", "max_iterations", "too_few_correspondences", "diverged", "degenerate"
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
        for name in ("degeneracy_aware", "extrapolate"):
            value = getattr(self, name)
            if not isinstance(value, bool):
                raise TypeError(f"{name}: expected a bool, got {type(value).__name__}")


_DEFAULT_SETTINGS = RegistrationSettings()
_DEFAULT_THRESHOLDS = VerdictThresholds()

#: Pairs whose source and target normals agree less than this (``|cos|``, about 5.7°) are the
#: ones the model-error term leaves out (``CovarianceEstimates.model_shift``): on the simulated
#: street, keeping ``≥ 0.95 / 0.99 / 0.995`` left −1.23 / −0.66 / −0.42 cm of its −2.5 cm
#: point-to-plane bias (``benchmarks/street_bias_normals.py``).
MIN_NORMAL_AGREEMENT = 0.995

_PLANAR = ("point_to_plane", "point_to_line")
#: The point-to-plane/line method of each dimension (point-to-point's reference estimate).
_PLANE_METHOD = {2: "point_to_line", 3: "point_to_plane"}


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
class CovarianceEstimates:
    """Every covariance kind at the final pose, ``(dof, dof)`` over the tangent ``δ``
    (translation first, right perturbation, source frame); all ``inf`` when not determined."""

    #: σ̂²(JᵀWJ)⁻¹, or the M-estimator sandwich under a kernel.
    hessian: FloatArray
    #: Censi's closed form with per-coordinate point noise ``point_variance``.
    censi: FloatArray
    #: Cluster-robust sandwich over ``num_blocks`` spatial blocks of ``block_size``.
    block: FloatArray
    #: ``censi`` ∨ ``block``, with the prior variance along degenerate directions, plus
    #: ``model_shift`` as ``δδᵀ``.
    calibrated: FloatArray
    #: Variance of each coordinate of a source or target point used by ``censi`` (units²).
    point_variance: float
    #: Variance of a target normal's direction per tangent axis used by ``censi`` (rad²),
    #: measured between the two scans (point-to-plane/line; 0 otherwise).
    normal_variance: float
    block_size: float
    num_blocks: int
    #: The prior used along degenerate directions (``init_covariance``, or the gate's).
    prior: FloatArray
    #: ``(dof,)`` model-error term of ``calibrated``: how far the estimate would move (one
    #: Gauss–Newton step at the final correspondences, a sample of them) under the
    #: point-to-plane/line objective of the pairs whose source and target normals agree
    #: (``|n_s·n_t| ≥ MIN_NORMAL_AGREEMENT``). Point-to-plane/line: the step with those pairs
    #: minus the step with all sampled pairs (the shift the disagreeing pairs cause).
    #: Point-to-point: the offset to the point-to-plane/line estimate re-solved from its pose
    #: (and ``calibrated`` is that estimate's plus ``δδᵀ``); if that re-solve fails, the
    #: agreeing step itself. Zeros for GICP, without target normals, or with too few agreeing
    #: pairs; never along weak directions. See ``docs/calibration.md``.
    model_shift: FloatArray


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
    its owner), a raw-array target (its index would stay pinned by the result) and
    ``degeneracy_aware`` the analysis runs within the call.
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
    #: cost, a minimum); ``max_iterations``; ``too_few_correspondences`` (fewer than
    #: ``min_correspondences`` inside the gate — the pose is where it stopped);
    #: ``diverged``: a step was non-finite or implausibly large (over ten times the gate, or
    #: over 90°: a near-singular ``JᵀJ``), the pose before it is returned; ``degenerate``:
    #: ``JᵀJ`` singular, the correspondences do not determine the pose.
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
    timing: RegistrationTiming
    settings: RegistrationSettings = field(repr=False)
    #: The trust analysis behind the properties below, computed on first access (once,
    #: thread-safe) for a PreparedTarget — within the call otherwise.
    _trust: _LazyTrust = field(repr=False, compare=False, kw_only=True)

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
    points = as_points(target, "target", dim=dim)
    if settings.voxel_size is not None:
        points = voxel_downsample(points, settings.voxel_size).points
    # Normals for every method when there are enough points: the degeneracy analysis uses the
    # plane information.
    if len(points) < dim + 1 and not (want_normals or want_covs):
        return prepare(points, normals=False)
    k = check_k(min(settings.num_neighbors, len(points)), len(points), dim)
    return prepare(points, normals=True, covariances=want_covs, num_neighbors=k)


def _pose_from_core(out: Any, dim: int) -> SE2 | SE3:
    """The core's pose, its rotation projected onto SO(D) as ``from_matrix`` does, without
    re-validating what the core built (finite, homogeneous, not a reflection). In 2D the
    binding has projected it (closed form) and checked it orthonormal: its read-only arrays
    are adopted as they are (a 2D scan registers in ~0.2 ms; numpy's fixed costs showed)."""
    if dim == 2:
        return SE2._wrap(out.rotation, out.translation)
    r = out.rotation
    err = float(np.abs(r.T @ r - np.eye(dim)).max())
    if err > 1e-6:  # a core bug, never the user's input
        raise ValueError(f"pose: not orthonormal (max |RᵀR - I| = {err:.2e})")
    u, _, vt = np.linalg.svd(r)
    return SE3._adopt(u @ vt, np.array(out.translation))


def _length_scale(points: FloatArray) -> float:
    """RMS distance of the points from their centroid (the conditioning's rotation lever)."""
    centred = points - points.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))


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
        error uniform within ``±δ``).
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
    if s.voxel_size is not None or (method_eff == "gicp" and source_covariances is None):
        # Downsampled or given covariances here first; otherwise register_icp's own scan
        # refuses a NaN/inf with the same message.
        check_finite_points(src, "source")
    pose0 = pose_class(dim).identity() if init is None else as_pose(init, "init", dim)

    t0 = time.perf_counter()
    prepared = _prepared_target(target, dim, method_eff, s)
    t_target = time.perf_counter() - t0

    t0 = time.perf_counter()
    if s.voxel_size is not None:
        src = voxel_downsample(src, s.voxel_size).points
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

    given_prior = None
    if init_covariance is not None:
        given_prior = _checked_init_covariance(init_covariance, dof)
    if thresholds is not None and not isinstance(thresholds, VerdictThresholds):
        raise TypeError(f"thresholds: expected VerdictThresholds, got {type(thresholds).__name__}")

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

    def run(
        projector: FloatArray | None,
        start: SE2 | SE3 = pose0,
        method: str = method_eff,
        max_iterations: int = s.max_iterations,
    ) -> Any:
        # By position, in the binding's order (17 keywords cost 0.7 µs a call).
        return _core.register_icp(
            src,
            index,
            start.as_matrix(),  # init_pose
            method,
            s.kernel,
            k_scale,  # kernel_scale
            s.max_correspondence_distance,
            max_iterations,
            s.translation_tolerance,
            s.rotation_tolerance,
            s.optimizer,
            min_corr,  # min_correspondences
            s.num_threads,
            source_covariances,
            t_normals if method in _PLANAR and not is_map else None,  # target_normals
            t_covs if method == "gicp" and not is_map else None,  # target_covariances
            True,  # iterate
            projector,  # step_projector
            s.extrapolate,
        )

    th = _DEFAULT_THRESHOLDS if thresholds is None else thresholds

    projector0 = None
    if step_projector is not None:
        projector0 = as_matrix(step_projector, "step_projector", (dof, dof))
    out = run(projector0)
    # The projector the solve ran with (rebound below by the degeneracy-aware solve): the
    # point-to-point analysis's reference solve reads it through its closure.
    held: FloatArray | None = projector0

    # The trust analysis (covariances, degeneracy, conditioning, overlap, verdict) runs on first
    # access when the target is a PreparedTarget the caller holds anyway: reading only the pose
    # then costs the ICP. Not when the solve needs it (degeneracy-aware), when the target can
    # change under it (a LocalMap is updated in place by its owner), nor for a raw-array target,
    # whose index and normals were built for this call alone: a result kept unread would pin
    # them (megabytes per result in a pose graph's list of loop closures).
    lazy = isinstance(target, PreparedTarget) and not s.degeneracy_aware
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
        "thresholds": th,
        "plane_solve": (
            (lambda start: run(held, start, _PLANE_METHOD[dim]))
            if method_eff == "point_to_point" and _has_normals(prepared)
            else None
        ),
        "solve": lambda start, iterations: run(held, start, max_iterations=iterations),
    }
    # Built here only when the solve needs it; a lazy analysis builds it on first use.
    ctx: _TrustInputs | dict[str, Any] = ctx_fields
    first: _CorrespondenceAnalysis | None = None
    if s.degeneracy_aware:
        ctx = _build(_TrustInputs, ctx_fields)
        first = _correspondence_analysis(ctx, out)
        if first.degeneracy.degenerate and len(out.correspondences):
            held = np.ascontiguousarray(np.eye(dof) - first.degeneracy.weak_projector())
            out = run(held)
            # The weak directions are the first solve's: the second is held along them.
            first = dataclasses.replace(
                _correspondence_analysis(ctx, out),
                degeneracy=first.degeneracy,
                valley=_valley_moment(
                    lambda start: run(held, start),
                    _pose_from_core(out, dim),
                    first.degeneracy,
                    ctx.prior,
                    s.max_correspondence_distance,
                ),
            )

    t0 = time.perf_counter()
    pose = _pose_from_core(out, dim)
    hessian = out.hessian  # the core's own fresh array, read-only: no copy needed
    n_corr = out.num_correspondences  # the core's ints and floats are Python's already
    sigma2 = _residual_variance(out, components, s.kernel, dof)
    stop: StopReason = out.stop_reason
    trust = _LazyTrust(ctx, out, pose, hessian, sigma2, first)
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
            "iterations": out.iterations,
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
            "timing": timing,
            "settings": s,
            "_trust": trust,
        },
    )


@dataclass(frozen=True)
class _TrustInputs:
    """What the trust analysis of one :func:`register` call reads (none of it the caller's
    mutable arrays: a lazy analysis runs after the call has returned)."""

    source: FloatArray
    target: PreparedTarget | LocalMap
    target_points: Any
    target_normals: Any
    target_covariances: Any
    source_covariances: Any
    method: str
    settings: RegistrationSettings
    kernel_scale: float
    components: int
    #: Checked (and copied) ``init_covariance``, or None for the gate-wide prior.
    init_covariance: FloatArray | None
    start: SE2 | SE3
    thresholds: VerdictThresholds
    #: Point-to-point with target normals: ``solve(pose)``, the core's point-to-plane/line
    #: registration from ``pose`` (held along the weak directions where the solve was), for
    #: ``calibrated`` (:func:`_via_plane_reference`); None otherwise.
    plane_solve: Any = None
    #: ``solve(start, max_iterations)``: the registration's own solve from another start (held
    #: where it was),
    #: for the verdict's wrong-basin probe (:mod:`scanreg.basin`).
    solve: Any = None

    @functools.cached_property
    def levers(self) -> FloatArray:
        return rotation_levers(self.source, int(self.source.shape[1]))

    @functools.cached_property
    def prior(self) -> FloatArray:
        """The covariance of the initial guess (see :func:`register`)."""
        if self.init_covariance is not None:
            return self.init_covariance
        dim, levers = int(self.source.shape[1]), self.levers
        gate = self.settings.max_correspondence_distance
        g = gate if math.isfinite(gate) else float(np.sqrt(np.mean(levers**2)))
        # ICP converges only from within about a gate of the truth: the error is taken as
        # uniform within ±δ per axis (the least informative law with that bound), variance δ²/3.
        return np.diag(np.concatenate([np.full(dim, g**2), (g / levers) ** 2])) / 3.0

    @functools.cached_property
    def beam_phase_variance(self) -> float:
        """2D: ``Δα²/12`` (rad²) for the source's median angular step ``Δα`` between
        neighbouring points as seen from its origin (the sensor); 0 in 3D.

        Two scans sample the same objects at different beam phases: where an object's edge or
        a corner falls between two beams is known only to a beam step, and the estimate's
        heading takes up that quantisation — a uniform error over one step about the sensor,
        ``θ`` alone in the tangent (the source origin). No model at the final pose sees it.
        Measured on real split-beam pairs (even beams against odd ones, exact truth,
        ``benchmarks/covariance_calibration.py --split-beam``): RMS heading error 0.32° at a
        1° step (MbICP halves) and 0.68° at 2° (Intel halves), against Δα/√12 = 0.29° and
        0.58°, where the covariance claimed 0.08° and 0.45°.
        """
        if self.source.shape[1] != 2 or len(self.source) < 3:
            return 0.0
        angles = np.sort(np.arctan2(self.source[:, 1], self.source[:, 0]))
        steps = np.diff(angles)
        steps = steps[steps > 1e-9]
        if not len(steps):
            return 0.0
        step = float(np.median(steps))
        return step * step / 12.0

    @functools.cached_property
    def source_normals(self) -> tuple[Any, FloatArray]:
        """Normals of a sample of the source, ``(indices, normals)``: once per call, even when
        the degeneracy-aware solve analyses twice."""
        n, dim = self.source.shape
        return sampled_normals(self.source, check_k(min(self.settings.num_neighbors, n), n, dim))

    @functools.cached_property
    def block_size(self) -> float:
        if self.settings.block_size is not None:
            return self.settings.block_size
        block = 2.0 * self.settings.max_correspondence_distance
        if math.isfinite(block):
            return block
        return float(np.sqrt(np.mean(self.levers**2))) / 5.0


@dataclass(frozen=True)
class _CorrespondenceAnalysis:
    """Censi's and the block meats at the final correspondences, the scene's degeneracy and
    the noise levels measured from the residuals and normals."""

    censi: Any
    degeneracy: Degeneracy
    point_variance: float
    normal_variance: float
    #: ``(all, agreeing)`` point-to-plane/line systems ``(H, g, count)`` of the sampled
    #: pairs, or None.
    agreement: tuple[Any, Any] | None
    #: The degeneracy-aware solve's :func:`_valley_moment`, or None.
    valley: FloatArray | None = None


@dataclass(frozen=True)
class _Trust:
    covariance: FloatArray
    information: FloatArray
    conditioning: Conditioning
    covariances: CovarianceEstimates
    degeneracy: Degeneracy
    quality: QualityReport
    verdict: Verdict
    seconds: float


class _LazyTrust:
    """The trust analysis of one registration, computed once on first use (thread-safe)."""

    __slots__ = ("_args", "_lock", "_value")

    def __init__(
        self,
        ctx: _TrustInputs | dict[str, Any],
        out: Any,
        pose: SE2 | SE3,
        hessian: FloatArray,
        sigma2: float,
        first: _CorrespondenceAnalysis | None,
    ) -> None:
        self._args: tuple[Any, ...] | None = (ctx, out, pose, hessian, sigma2, first)
        self._lock = threading.Lock()
        self._value: _Trust | None = None

    def get(self) -> _Trust:
        value = self._value
        if value is None:
            with self._lock:
                if self._value is None:
                    assert self._args is not None
                    ctx, *rest = self._args
                    if isinstance(ctx, dict):  # its fields, as register() gathered them
                        ctx = _build(_TrustInputs, ctx)
                    self._value = _trust(ctx, *rest)
                    self._args = None  # the source, target and core outcome can go
                value = self._value
        return value

    def __getstate__(self) -> _Trust:
        return self.get()

    def __setstate__(self, value: _Trust) -> None:
        self._args = None
        self._lock = threading.Lock()
        self._value = value


def _correspondence_analysis(ctx: _TrustInputs, out: Any) -> _CorrespondenceAnalysis:
    s, src, prepared, method = ctx.settings, ctx.source, ctx.target, ctx.method
    dim = int(src.shape[1])
    dof = 3 if dim == 2 else 6
    # The target's own normal noise needs its k-d tree: not measured on a map.
    eps2, eps2_typical = (
        prepared.normal_noise
        if isinstance(prepared, PreparedTarget) and prepared.normals is not None
        else (math.nan, math.nan)
    )
    corr = np.asarray(out.correspondences)
    tp, tn, tc = ctx.target_points, ctx.target_normals, ctx.target_covariances
    if isinstance(prepared, LocalMap):
        # A map's rows are gathered for the matched ids only (a few thousand, not the storage).
        used = corr >= 0
        ids, compact = np.unique(corr[used], return_inverse=True)
        tp, tn, tc = prepared.native.gather(np.ascontiguousarray(ids, dtype=np.int64))
        corr = np.full(corr.shape, -1, dtype=np.int64)
        corr[used] = compact
    normal_var = 0.0
    agreement = None
    if method != "gicp" and len(src) > dim and tn is not None:
        # Normals of a sample of the source, to measure the normal noise between the two scans
        # (Censi's normal term) and which pairs' normals disagree (the model-error term); the
        # registration itself does not use them.
        sample, sample_normals = ctx.source_normals
        if method != "point_to_point":
            normal_var = correspondence_normal_noise(
                sample_normals, tn, out.pose[:dim, :dim], corr[sample]
            )
            normal_var = normal_var if math.isfinite(normal_var) else 0.0
        ha, ga, na, hk, gk, nk = _core.normal_agreement_systems(
            sample,
            sample_normals,
            src,
            tp,
            tn,
            corr,
            out.pose,
            MIN_NORMAL_AGREEMENT,
            kernel=s.kernel,
            kernel_scale=ctx.kernel_scale,
        )
        agreement = ((ha, ga, na), (hk, gk, nk))
    # Unit variances: the meats scale linearly and are combined once the point noise is known
    # from the residuals of this very analysis.
    ana = _core.censi_analysis(
        src,
        tp,
        out.pose,
        corr,
        method=method,
        kernel=s.kernel,
        kernel_scale=ctx.kernel_scale,
        source_variance=1.0,
        target_variance=1.0,
        block_size=max(ctx.block_size, 1e-9),
        normal_variance=1.0,
        target_normals=tn,
        source_covariances=ctx.source_covariances,
        target_covariances=tc if method == "gicp" else None,
        num_threads=s.num_threads,
    )
    if ana.num_plane_correspondences > dof:
        deg = analyse_degeneracy(
            np.array(ana.plane_information),
            ana.num_plane_correspondences,
            dim,
            ctx.levers,
            normal_noise=eps2,
            typical_normal_noise=eps2_typical,
        )
    else:
        deg = analyse_degeneracy(
            np.array(ana.hessian),
            max(ana.num_correspondences, 1),
            dim,
            ctx.levers,
            normal_noise=eps2,
            typical_normal_noise=eps2_typical,
            basis="hessian",
        )
    return _CorrespondenceAnalysis(
        censi=ana,
        degeneracy=deg,
        point_variance=_point_variance(out, ana, method, dim, dof),
        normal_variance=normal_var,
        agreement=agreement,
    )


def _covariance_estimates(
    ctx: _TrustInputs,
    out: Any,
    pose: SE2 | SE3,
    hessian: FloatArray,
    sigma2: float,
    corr: _CorrespondenceAnalysis,
) -> CovarianceEstimates:
    """Every covariance kind of one outcome (:class:`CovarianceEstimates`), from its
    correspondence analysis ``corr``."""
    s = ctx.settings
    dof = 3 if ctx.source.shape[1] == 2 else 6
    deg = corr.degeneracy
    try:
        if s.kernel == "none":
            cov = least_squares_covariance(hessian, sigma2)
        else:
            m_eff = ctx.components * float(out.irls_weight_sum)
            cov = sandwich_covariance(hessian, np.array(out.score_outer), m_eff, dof)
        if not np.isfinite(cov).all():
            raise np.linalg.LinAlgError("non-finite covariance")
    except np.linalg.LinAlgError:
        cov = np.full((dof, dof), np.inf)
    estimates = _estimates(
        cov,
        corr.censi,
        deg,
        ctx.prior,
        corr.point_variance,
        corr.normal_variance,
        ctx.block_size,
        dof,
        (ctx.start.inverse() @ pose).log(),  # type: ignore[operator]
        _model_shift(corr.agreement, deg, ctx.method, dof),
        corr.valley,
        ctx.beam_phase_variance,
    )
    if ctx.plane_solve is not None:
        estimates = _via_plane_reference(ctx, pose, corr, estimates, dof)
    return estimates


def _trust(
    ctx: _TrustInputs,
    out: Any,
    pose: SE2 | SE3,
    hessian: FloatArray,
    sigma2: float,
    first: _CorrespondenceAnalysis | None,
) -> _Trust:
    t0 = time.perf_counter()
    s, src = ctx.settings, ctx.source
    dim = int(src.shape[1])
    dof = 3 if dim == 2 else 6
    corr = first if first is not None else _correspondence_analysis(ctx, out)
    deg = corr.degeneracy
    estimates = _covariance_estimates(ctx, out, pose, hessian, sigma2, corr)
    chosen = getattr(estimates, s.covariance)
    info = (
        information_from_covariance(chosen) if np.isfinite(chosen).all() else np.zeros((dof, dof))
    )
    cond = conditioning(hessian, dim, _length_scale(src))
    th = ctx.thresholds
    stop = str(out.stop_reason)
    # The verdict reads the same eigen-analysis unless it asks for another weak ratio.
    checked = _assess_checked(
        pose,
        src,
        ctx.target,
        start=ctx.start,
        gate=float(s.max_correspondence_distance) if th.overlap_gate is None else th.overlap_gate,
        thresholds=th,
        conditioning=cond,
        converged=stop == "converged",
        stop_reason=stop,
        degeneracy=deg,
        hints=None if isinstance(ctx.target, LocalMap) else out.correspondences,
        prior=ctx.prior,
    )
    if checked.verdict.accepted and th.probes_basin(dim) and ctx.solve is not None:
        # Only a result every other check accepts is probed: the restarts cost about as much
        # as the rest of the analysis in 2D, and cannot turn a rejection into an acceptance.
        index = ctx.target.native if isinstance(ctx.target, LocalMap) else ctx.target.index
        probe = probe_basin(
            ctx.solve,
            index,
            src,
            pose,
            chosen,
            float(s.max_correspondence_distance),
            stop_ratio=th.basin_wrong_ratio,
            cover_ratio=th.basin_ambiguous_ratio,
            target_points=ctx.target_points,
        )
        report = dataclasses.replace(checked.report, basin=probe)
        checked = dataclasses.replace(checked, report=report, verdict=judge(report, th))
        if probe.covered:
            # Part of the calibrated covariance: alternatives in the same basin it must cover.
            chosen = _readonly(_psd(chosen + probe.growth))
            info = information_from_covariance(chosen)
            if s.covariance == "calibrated":
                estimates = dataclasses.replace(estimates, calibrated=chosen)
    return _Trust(
        covariance=chosen,
        information=_readonly(info),
        conditioning=cond,
        covariances=estimates,
        degeneracy=deg,
        quality=checked.report,
        verdict=checked.verdict,
        seconds=time.perf_counter() - t0,
    )


def _residual_variance(out: Any, components: int, kernel: str, dof: int) -> float:
    """σ̂² of the core's outcome: the residual sum of squares over ``m − dof`` scalar
    residuals (``m`` IRLS-weighted under a kernel); NaN with too few."""
    if kernel == "none":
        m = components * float(out.num_correspondences)
        return float(out.sum_squares / (m - dof)) if m > dof else math.nan
    m = components * float(out.irls_weight_sum)
    return float(out.irls_sum_squares / (m - dof)) if m > dof else math.nan


def _has_normals(target: PreparedTarget | LocalMap) -> bool:
    if isinstance(target, LocalMap):
        return target.attributes == "normals"
    return target.normals is not None


def _via_plane_reference(
    ctx: _TrustInputs,
    pose: SE2 | SE3,
    corr: _CorrespondenceAnalysis,
    estimates: CovarianceEstimates,
    dof: int,
) -> CovarianceEstimates:
    """Point-to-point's ``calibrated``: the point-to-plane/line estimate's, plus the offset
    between the two as ``δδᵀ`` (``model_shift``).

    Two scans sample a surface at different places; point-to-point pairs each point with a
    neighbour up to half a spacing along the surface and settles where those offsets balance,
    a bias no noise model at its pose sees (its ``censi`` and ``block`` are 10× over-confident
    in the simulated room). The point-to-plane/line estimate does not carry it (its own
    ``calibrated`` is consistent there). So: re-solve point-to-plane/line from the
    point-to-point pose (held where the solve was), analyse that as any registration (the
    same start, so the same drift and prior along weak directions), and add the offset
    ``log(T̂⁻¹ T̂_plane)`` on the well-determined subspace. The error is that offset plus the
    reference's error. If the re-solve fails, the one-step estimate stays.
    """
    out = ctx.plane_solve(pose)
    if str(out.stop_reason) not in ("converged", "max_iterations"):
        return estimates
    dim = int(ctx.source.shape[1])
    ref_ctx = dataclasses.replace(ctx, method=_PLANE_METHOD[dim], components=1, plane_solve=None)
    ref_corr = _correspondence_analysis(ref_ctx, out)
    if ctx.settings.degeneracy_aware:  # the solve's weak directions and valley, as register's
        ref_corr = dataclasses.replace(ref_corr, degeneracy=corr.degeneracy, valley=corr.valley)
    ref_pose = _pose_from_core(out, dim)
    sigma2 = _residual_variance(out, 1, ctx.settings.kernel, dof)
    ref = _covariance_estimates(ref_ctx, out, ref_pose, out.hessian, sigma2, ref_corr)
    cal = np.asarray(ref.calibrated)
    if not np.isfinite(cal).all():
        return estimates
    s_inv = corr.degeneracy.scaling()
    u = corr.degeneracy.strong_basis()
    offset = (pose.inverse() @ ref_pose).log() / s_inv  # type: ignore[operator]
    shift = (u @ (u.T @ offset)) * s_inv
    return dataclasses.replace(
        estimates,
        calibrated=_readonly(_psd(cal + np.outer(shift, shift))),
        model_shift=_frozen(shift),
    )


def _checked_init_covariance(init_covariance: Any, dof: int) -> FloatArray | None:
    """``init_covariance`` checked, as a copy (the analysis may read it after the call)."""
    if init_covariance is None:
        return None
    p = np.array(init_covariance, dtype=np.float64)
    if p.shape != (dof, dof):
        raise ValueError(f"init_covariance: expected shape ({dof}, {dof}), got {p.shape}")
    if not np.isfinite(p).all() or not np.allclose(p, p.T, rtol=1e-9, atol=1e-12):
        raise ValueError("init_covariance: must be finite and symmetric")
    if np.linalg.eigvalsh(p)[0] < 0:
        raise ValueError("init_covariance: must be positive semi-definite")
    return p


def _point_variance(out: Any, ana: Any, method: str, dim: int, dof: int) -> float:
    """Noise variance of one coordinate of a point, half of the residual variance (source and
    target points are equally noisy).

    Point-to-plane/line: along the normal, ``Σ (nᵀe)² / (n - dof)`` — the noise its residual
    feels. Point-to-point and GICP: ``Σ |e|² / (D n - dof)``, the along-surface sampling
    offsets included. For GICP the normal-only estimate was measured too
    (``docs/calibration.md``): consistent in 2D but 4× over-confident in the 3D street and
    tunnel, where the along-surface offsets are part of the error; the Euclidean one errs on
    the safe side (over-cautious in the degenerate 2D/3D scenes).
    """
    n_plane = int(ana.num_plane_correspondences)
    if method in ("point_to_plane", "point_to_line") and n_plane > dof:
        return float(ana.plane_sum_squares / (n_plane - dof)) / 2.0
    n = int(out.num_correspondences)
    return float(out.sum_squared_distances / max(dim * n - dof, 1)) / 2.0


def _estimates(
    hessian_cov: FloatArray,
    ana: Any,
    deg: Degeneracy,
    prior: FloatArray,
    point_variance: float,
    normal_variance: float,
    block: float,
    dof: int,
    drift: FloatArray,
    shift: FloatArray,
    valley: FloatArray | None,
    sampling: float = 0.0,
) -> CovarianceEstimates:
    bad = np.full((dof, dof), np.inf)
    h = np.array(ana.hessian)
    meat = point_variance * (np.array(ana.source_meat) + np.array(ana.target_meat))
    meat = meat + normal_variance * np.array(ana.normal_meat)
    try:
        h_inv = np.linalg.inv(h)
        censi = censi_from_inverse(h_inv, meat)
        blk = block_from_inverse(h_inv, np.array(ana.block_meat), int(ana.num_blocks))
        if not (np.isfinite(censi).all() and np.isfinite(blk).all()):
            raise np.linalg.LinAlgError("non-finite covariance")
        calibrated = covariance_upper_bound(censi, blk)
    except np.linalg.LinAlgError:
        censi = blk = calibrated = bad
    if deg.degenerate and np.isfinite(calibrated).all():
        # The tilt of the weak axis comes from the target's normal noise; on a map (not
        # measured there) from the noise between the two scans.
        eps2 = deg.normal_noise if math.isfinite(deg.normal_noise) else normal_variance
        calibrated = _with_prior_along_weak(calibrated, deg, prior, drift, eps2, valley)
    calibrated = calibrated + np.outer(shift, shift)
    if sampling > 0.0 and np.isfinite(calibrated).all():
        # 2D: the beams' angular phase (see _TrustInputs.beam_phase_variance).
        calibrated = calibrated.copy()
        calibrated[2, 2] += sampling
    censi, blk, calibrated = _psd(censi), _psd(blk), _psd(calibrated)
    return CovarianceEstimates(
        hessian=_readonly(_psd(hessian_cov)),
        censi=_readonly(censi),
        block=_readonly(blk),
        calibrated=_readonly(calibrated),
        point_variance=float(point_variance),
        normal_variance=float(normal_variance),
        block_size=float(block),
        num_blocks=int(ana.num_blocks),
        prior=_frozen(prior),
        model_shift=_frozen(shift),
    )


def _psd(cov: FloatArray) -> FloatArray:
    """``cov`` with round-off negative eigenvalues set to zero (a noise-free fit leaves
    variances of ±1e-54: a negative one would make its standard deviation NaN)."""
    if not np.isfinite(cov).all():
        return cov
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    if vals[0] >= 0.0:
        return cov
    out: FloatArray = (vecs * np.maximum(vals, 0.0)) @ vecs.T
    return out


def _model_shift(agreement: Any, deg: Degeneracy, method: str, dof: int) -> FloatArray:
    """The model-error shift of :class:`CovarianceEstimates` (``model_shift``).

    Each step is solved on the well-constrained subspace only (scaled coordinates, the weak
    directions left out: along them the covariance is the prior's, and a step there is not
    determined). Too few agreeing pairs (``< 10 dof``) or a singular system: zeros.
    """
    zero = np.zeros(dof)
    if agreement is None:
        return zero
    (h_all, g_all, _), (h_ok, g_ok, n_ok) = agreement
    if n_ok < 10 * dof:
        return zero
    t = deg.scaling()[:, None] * deg.strong_basis()  # tangent directions of the strong subspace

    def step(h: Any, g: Any) -> FloatArray:
        c = np.linalg.solve(t.T @ np.asarray(h) @ t, -(t.T @ np.asarray(g)))
        out: FloatArray = t @ c
        return out

    try:
        shift = step(h_ok, g_ok)
        if method != "point_to_point":
            shift = shift - step(h_all, g_all)
    except np.linalg.LinAlgError:
        return zero
    return shift if np.isfinite(shift).all() else zero


def _valley_moment(
    solve: Any, pose: SE2 | SE3, deg: Degeneracy, prior: FloatArray, gate: float
) -> FloatArray:
    """How the well-determined coordinates follow the held weak ones, over the prior's range.

    The degeneracy-aware solve holds the weak coordinates at the initial guess and solves the
    rest *for that value*. Where the truth lies elsewhere along the axis (by ``σ_w``, the
    prior's), the rest would have come out differently: as the held value moves, the matched
    points and their normals change (a corridor's lateral estimate follows the along-axis
    one by ~0.008 m/m, ``benchmarks/corridor_coupling.py``), which no linearisation at the
    final pose sees. Measured by solving again, held, from ``±h`` along each weak direction
    (``h = min(σ_w, gate / 2)``, inside the basin): the second moment of where the strong
    coordinates land, per unit ``h²`` and times ``σ_w²`` (scaled coordinates, strong subspace;
    a linear coupling and a curved valley alike). A held solve that fails is left out.
    """
    s_inv = deg.scaling()
    w = deg.weak_basis()
    dof = s_inv.size
    dim = 2 if dof == 3 else 3
    u = deg.strong_basis()
    prior_s = prior / np.outer(s_inv, s_inv)
    out = np.zeros((dof, dof))
    inverse = pose.inverse()
    for i in range(w.shape[1]):
        var = float(w[:, i] @ prior_s @ w[:, i])
        h = math.sqrt(var)
        if math.isfinite(gate):
            h = min(h, gate / 2.0)
        if not h > 0.0:
            continue
        for sign in (1.0, -1.0):
            held = solve(pose @ type(pose).exp(sign * h * w[:, i] * s_inv))  # type: ignore[operator]
            if str(held.stop_reason) not in ("converged", "max_iterations"):
                continue
            e = (inverse @ _pose_from_core(held, dim)).log() / s_inv  # type: ignore[operator]
            e_u = u @ (u.T @ e)
            out += 0.5 * var * np.outer(e_u, e_u) / h**2
    return out


def _with_prior_along_weak(
    cov: FloatArray,
    deg: Degeneracy,
    prior: FloatArray,
    drift: FloatArray,
    normal_noise: float,
    valley: FloatArray | None = None,
) -> FloatArray:
    """Replace the data's say along the weak directions by the prior's.

    In scaled coordinates with ``W`` the weak eigenvectors and ``U`` the strong ones: the
    well-determined part is the data's covariance of ``U``-coordinates *given* the weak ones
    (``(Uᵀ Λ U)⁻¹``, ``Λ = cov⁻¹``): the solve fixes (aware) or drifts (not aware) along ``W``
    and solves the rest for that value. Along ``W`` the variance is the prior's plus the
    square of the solve's own move along ``W`` (``drift``, tangent ``log(start⁻¹ · pose)``:
    the data do not determine it; zero when held). ``W`` is itself estimated from noisy
    normals: an error of ``σ_w`` along the true axis shows as ``σ_w · tilt_j`` along each
    ``u_j`` (:meth:`Degeneracy.tilt_variances`) or, for a translation, as its rotation rows
    (:func:`_axis_cover`), added there.
    With the degeneracy-aware solve, ``valley`` (:func:`_valley_moment`) is added as well.
    """
    s_inv = deg.scaling()
    w = deg.weak_basis()
    dof = s_inv.size
    u = deg.strong_basis()
    # scaled covariance: δ_s = S δ
    cov_s = cov / np.outer(s_inv, s_inv)
    prior_s = prior / np.outer(s_inv, s_inv)
    if not u.shape[1]:
        strong = np.zeros((dof, dof))
    else:
        try:
            strong = u @ np.linalg.inv(u.T @ np.linalg.inv(cov_s) @ u) @ u.T
        except np.linalg.LinAlgError:
            # A singular data covariance (a noise-free fit: zero residuals): its conditional
            # cannot be formed; the marginal U Uᵀ Σ U Uᵀ covers it (and is 0 when Σ is).
            strong = u @ (u.T @ cov_s @ u) @ u.T
    weak_prior = w.T @ prior_s @ w
    d_w = w.T @ (np.asarray(drift) / s_inv)
    weak_prior = weak_prior + np.outer(d_w, d_w)
    var_w = np.diag(weak_prior)
    tilt = deg.tilt_variances(normal_noise)  # (weak, strong)
    weak = w @ weak_prior @ w.T
    for i in range(w.shape[1]):
        weak = weak + var_w[i] * _axis_cover(w[:, i], u, tilt[i])
    if valley is not None:
        weak = weak + valley
    out = (strong + weak) * np.outer(s_inv, s_inv)
    return np.asarray(0.5 * (out + out.T), dtype=np.float64)


def _axis_cover(w: FloatArray, u: FloatArray, tilt: FloatArray) -> FloatArray:
    """Where a unit error along the true weak axis lands in the strong subspace, for the
    estimated axis ``w`` (scaled coordinates): the second moment, ``(dof, dof)``.

    ``w`` is estimated from noisy normals; an error ``a`` along the true axis ``w*`` shows
    across ``w`` as ``a · Uᵀ (w* − w)``. In general ``w*`` is ``w`` tilted at random towards
    each ``u_j`` by ``tilt_j`` (:meth:`Degeneracy.tilt_variances`). A weak direction that is
    mostly translation (``|t|² ≥ 1/2``) is taken to be a surface symmetry — a corridor, a
    tunnel, a plane: exactly a translation, ``w* = (t*, 0)``. Its rotation rows are then a
    known deviation, not noise: biased normals put them there (the ring pattern in a
    tunnel: −0.6 to −1.0 mrad of pitch per metre along the axis in every realisation,
    ``docs/calibration.md``), and only the translation rows keep the random tilt.
    """
    dof = w.size
    dim = 2 if dof == 3 else 3
    cover = u @ np.diag(tilt) @ u.T
    t = w[:dim]
    if float(t @ t) < 0.5:
        return cover
    rows = np.zeros((dof, dof))
    rows[:dim, :dim] = np.eye(dim)
    cover = u @ (u.T @ rows @ cover @ rows @ u) @ u.T
    v = np.zeros(dof)
    v[:dim] = t / np.linalg.norm(t)
    d = u @ (u.T @ (v - w))
    out: FloatArray = cover + np.outer(d, d)
    return out


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
