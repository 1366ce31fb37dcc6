"""The trust analysis of a registration: covariances, degeneracy, conditioning, overlap and the
verdict, from the solver's outcome (:func:`scanreg.register` calls it; :mod:`scanreg.register`
keeps the solve).

It reads the core's outcome (the final correspondences, ``JᵀWJ``, the scores) and the inputs
the call kept (:class:`TrustInputs`), and may run **extra solves** through the callbacks the
call hands it — never the solver directly:

* ``plane_solve(start)``: reading ``covariance`` after a point-to-point registration whose
  target has normals runs one point-to-plane/line registration from its pose (the
  ``calibrated`` covariance is that estimate's plus the offset between the two);
* ``solve(start, iterations)``: the 2D verdict's wrong-basin probe (:mod:`scanreg.basin`)
  restarts the registration's own solve around the result;
* the degeneracy-aware solve (``degeneracy_aware=True``) measures its valley with two held
  solves per weak direction (:func:`valley_moment`, called by ``register`` itself).

The per-correspondence arithmetic (Censi's meats, the block sandwich, the normal agreement)
runs in the core; here the ≤ 6×6 matrices are combined.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _core
from ._validate import FloatArray
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
from .preprocess import check_k
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
from .target import PreparedTarget
from .transform import SE2, SE3
from .verdict import QualityReport, Verdict, VerdictThresholds, _assess_checked, judge

if TYPE_CHECKING:
    from .register import RegistrationSettings

#: Pairs whose source and target normals agree less than this (``|cos|``, about 5.7°) are the
#: ones the model-error term leaves out (``CovarianceEstimates.model_shift``): on the simulated
#: street, keeping ``≥ 0.95 / 0.99 / 0.995`` left −1.23 / −0.66 / −0.42 cm of its −2.5 cm
#: point-to-plane bias (``benchmarks/street_bias_normals.py``).
MIN_NORMAL_AGREEMENT = 0.995


#: The point-to-plane/line method of each dimension (point-to-point's reference estimate).
PLANE_METHOD = {2: "point_to_line", 3: "point_to_plane"}


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


def pose_from_core(out: Any, dim: int) -> SE2 | SE3:
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


@dataclass(frozen=True)
class TrustInputs:
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
class CorrespondenceAnalysis:
    """Censi's and the block meats at the final correspondences, the scene's degeneracy and
    the noise levels measured from the residuals and normals."""

    censi: Any
    degeneracy: Degeneracy
    point_variance: float
    normal_variance: float
    #: ``(all, agreeing)`` point-to-plane/line systems ``(H, g, count)`` of the sampled
    #: pairs, or None.
    agreement: tuple[Any, Any] | None
    #: The degeneracy-aware solve's :func:`valley_moment`, or None.
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


class LazyTrust:
    """The trust analysis of one registration, computed once on first use (thread-safe)."""

    __slots__ = ("_args", "_lock", "_value")

    def __init__(
        self,
        ctx: TrustInputs | dict[str, Any],
        out: Any,
        pose: SE2 | SE3,
        hessian: FloatArray,
        sigma2: float,
        first: CorrespondenceAnalysis | None,
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
                        ctx = _build(TrustInputs, ctx)
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


def correspondence_analysis(ctx: TrustInputs, out: Any) -> CorrespondenceAnalysis:
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
    return CorrespondenceAnalysis(
        censi=ana,
        degeneracy=deg,
        point_variance=_point_variance(out, ana, method, dim, dof),
        normal_variance=normal_var,
        agreement=agreement,
    )


def _covariance_estimates(
    ctx: TrustInputs,
    out: Any,
    pose: SE2 | SE3,
    hessian: FloatArray,
    sigma2: float,
    corr: CorrespondenceAnalysis,
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
    ctx: TrustInputs,
    out: Any,
    pose: SE2 | SE3,
    hessian: FloatArray,
    sigma2: float,
    first: CorrespondenceAnalysis | None,
) -> _Trust:
    t0 = time.perf_counter()
    s, src = ctx.settings, ctx.source
    dim = int(src.shape[1])
    dof = 3 if dim == 2 else 6
    corr = first if first is not None else correspondence_analysis(ctx, out)
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


def residual_variance(out: Any, components: int, kernel: str, dof: int) -> float:
    """σ̂² of the core's outcome: the residual sum of squares over ``m − dof`` scalar
    residuals (``m`` IRLS-weighted under a kernel); NaN with too few."""
    if kernel == "none":
        m = components * float(out.num_correspondences)
        return float(out.sum_squares / (m - dof)) if m > dof else math.nan
    m = components * float(out.irls_weight_sum)
    return float(out.irls_sum_squares / (m - dof)) if m > dof else math.nan


def has_normals(target: PreparedTarget | LocalMap) -> bool:
    if isinstance(target, LocalMap):
        return target.attributes == "normals"
    return target.normals is not None


def _via_plane_reference(
    ctx: TrustInputs,
    pose: SE2 | SE3,
    corr: CorrespondenceAnalysis,
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
    ref_ctx = dataclasses.replace(ctx, method=PLANE_METHOD[dim], components=1, plane_solve=None)
    ref_corr = correspondence_analysis(ref_ctx, out)
    if ctx.settings.degeneracy_aware:  # the solve's weak directions and valley, as register's
        ref_corr = dataclasses.replace(ref_corr, degeneracy=corr.degeneracy, valley=corr.valley)
    ref_pose = pose_from_core(out, dim)
    sigma2 = residual_variance(out, 1, ctx.settings.kernel, dof)
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
        # 2D: the beams' angular phase (see TrustInputs.beam_phase_variance).
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


def valley_moment(
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
            e = (inverse @ pose_from_core(held, dim)).log() / s_inv  # type: ignore[operator]
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
    With the degeneracy-aware solve, ``valley`` (:func:`valley_moment`) is added as well.
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


__all__ = ["MIN_NORMAL_AGREEMENT", "CovarianceEstimates"]
