"""Paired alignment: the rigid transform that best maps ``source[i]`` onto ``target[i]``.

Closed form first (Kabsch/Umeyama), then optionally Gauss–Newton on the manifold for
point-to-plane/line residuals or robust kernels, then covariance and conditioning.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from . import _core
from ._validate import FloatArray, as_points, as_weights, positive
from ._validate import frozen as _frozen
from .quality import (
    SINGULAR_RATIO,
    Conditioning,
    ResidualStats,
    conditioning,
    information_from_covariance,
    least_squares_covariance,
    sandwich_covariance,
)
from .robust import check_kernel, default_scale, robust_sigma
from .transform import SE2, SE3, as_pose, pose_class

Method = Literal["point_to_point", "point_to_plane", "point_to_line"]


@dataclass(frozen=True)
class PairedAlignment:
    """Result of :func:`align_paired`.

    ``pose`` is ``T_target_source`` (``p_T = R p_S + t``; times ``scale`` when estimated).
    ``covariance`` is over the right-perturbation tangent ``δ`` (translation first,
    source frame): ``T_true = pose @ exp(δ)``; see :mod:`scanreg.transform`.
    """

    pose: SE2 | SE3
    #: The Kabsch/Umeyama estimate before any refinement.
    closed_form_pose: SE2 | SE3
    #: Umeyama scale ``s`` (``p_T = s R p_S + t``); 1.0 unless ``with_scale=True``.
    scale: float
    #: The cost function: ``point_to_point``, ``point_to_plane`` or ``point_to_line``.
    method: str
    kernel: str
    #: Kernel scale used (in the points' units); ``nan`` for ``kernel="none"``.
    kernel_scale: float
    refined: bool
    #: Gauss–Newton iterations (0 when not refined).
    iterations: int
    converged: bool
    residuals: ResidualStats
    #: Number of scalar residuals ``m`` (``D·N`` point-to-point, ``N`` point-to-plane/line),
    #: counting only pairs with a positive weight.
    num_residuals: int
    dof: int
    #: Residual variance per coordinate: ``σ̂² = Σ w r² / (m - dof)`` for least squares;
    #: with a kernel, the square of the median-based robust scale (:mod:`scanreg.robust`).
    sigma2: float
    #: ``JᵀWJ`` at the final pose (user weights × kernel weights), tangent coordinates.
    hessian: FloatArray
    #: Least squares: ``σ̂² (JᵀWJ)⁻¹``. With a kernel: the M-estimator sandwich
    #: ``H⁻¹ (Σ ψ ψᵀ) H⁻¹ · m/(m - dof)`` with ``ψ = w k Jᵀr`` (Huber 1981, §7.6).
    covariance: FloatArray
    #: ``covariance⁻¹``, e.g. for a pose-graph edge.
    information: FloatArray
    conditioning: Conditioning

    @property
    def standard_deviations(self) -> FloatArray:
        """Square roots of the covariance diagonal (m, m[, m], rad[, rad, rad])."""
        out: FloatArray = np.sqrt(np.diag(self.covariance))
        return out


def _kabsch(
    source: FloatArray, target: FloatArray, weights: FloatArray | None, with_scale: bool
) -> tuple[FloatArray, FloatArray, float]:
    """Weighted Kabsch/Umeyama: ``R``, ``t``, ``s`` minimising ``Σ w |s R p + t - q|²``."""
    m = _core.paired_moments(source, target, weights)
    u, sv, vt = np.linalg.svd(m.cross_covariance)  # Σ w (p - p̄)(q - q̄)ᵀ = U S Vᵀ
    d = np.ones(len(sv))
    # det(R) = +1: flip the least significant axis when the best orthogonal map reflects.
    d[-1] = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag(d) @ u.T
    scale = 1.0
    if with_scale:
        if m.source_spread <= 0:
            raise ValueError("source: all points coincide; the scale is undetermined")
        scale = float(np.dot(sv, d) / m.source_spread)
    translation = m.target_mean - scale * rotation @ m.source_mean
    return rotation, translation, scale


def _length_scale(source: FloatArray, weights: FloatArray | None) -> float:
    """RMS distance of the (weighted) source points from their centroid."""
    w = np.ones(len(source)) if weights is None else weights
    centroid = (w @ source) / w.sum()
    return float(np.sqrt((w @ np.sum((source - centroid) ** 2, axis=1)) / w.sum()))


def align_paired(
    source: Any,
    target: Any,
    weights: Any = None,
    *,
    method: Method = "point_to_point",
    target_normals: Any = None,
    kernel: str = "none",
    kernel_scale: float | None = None,
    refine: bool | None = None,
    with_scale: bool = False,
    init: Any = None,
    max_iterations: int = 50,
    tolerance: float = 1e-10,
) -> PairedAlignment:
    """Estimate ``T_target_source`` from paired points ``source[i] ↔ target[i]``.

    Parameters
    ----------
    source, target
        ``(N, D)`` float64, C-contiguous, ``D`` = 2 or 3, in their own frames.
    weights
        Optional ``(N,)`` non-negative weights (inverse variances up to a common factor).
    method
        The cost function: ``"point_to_point"`` (default), or ``"point_to_plane"`` (3D) /
        ``"point_to_line"`` (2D), which need ``target_normals`` ``(N, D)`` (target frame;
        normalised here).
    kernel, kernel_scale
        Robust kernel (``none``, ``huber``, ``cauchy``, ``tukey``, ``geman_mcclure``,
        ``welsch``) applied by IRLS. ``kernel_scale=None`` estimates it from the residuals
        (see :mod:`scanreg.robust`), re-estimating until it settles.
    refine
        Run Gauss–Newton from the closed form (or ``init``). ``None``: only when needed
        (a kernel, or a point-to-plane/line method). Point-to-point least squares is
        already optimal in closed form.
    with_scale
        Also estimate a similarity scale (Umeyama). Closed form only.
    init
        Initial pose for refinement (``SE2``/``SE3`` or homogeneous matrix); default: the
        closed form.
    max_iterations, tolerance
        Gauss–Newton stops when ``|δ| < tolerance`` (metres / radians) or after
        ``max_iterations``.

    Raises
    ------
    TypeError, ValueError
        On malformed input, naming the argument; ``ValueError`` also when the geometry
        does not determine the pose (e.g. collinear 3D points), naming the free direction.
    """
    src = as_points(source, "source")
    dim = src.shape[1]
    tgt = as_points(target, "target", dim=dim)
    if tgt.shape[0] != src.shape[0]:
        raise ValueError(
            f"target: has {tgt.shape[0]} points but source has {src.shape[0]}; "
            "paired alignment needs one target point per source point"
        )
    w = None if weights is None else as_weights(weights, "weights", src.shape[0])
    n_used = src.shape[0] if w is None else int(np.count_nonzero(w))
    kernel = check_kernel(kernel)
    if method not in ("point_to_point", "point_to_plane", "point_to_line"):
        raise ValueError(
            f"method: unknown {method!r}; expected point_to_point, point_to_plane or point_to_line"
        )
    planar = method != "point_to_point"
    if planar:
        expected = "point_to_line" if dim == 2 else "point_to_plane"
        if method != expected:
            raise ValueError(f"method: {method!r} is for {5 - dim}D points; use {expected!r}")
        if target_normals is None:
            raise ValueError(f"target_normals: required for method {method!r}")
        normals = as_points(target_normals, "target_normals", dim=dim)
        if normals.shape[0] != src.shape[0]:
            raise ValueError(
                f"target_normals: expected {src.shape[0]} normals (one per target point), "
                f"got {normals.shape[0]}"
            )
        lengths = np.linalg.norm(normals, axis=1)
        if (lengths < 1e-12).any():
            raise ValueError(f"target_normals: normal {int(np.argmin(lengths))} has zero length")
        normals = np.ascontiguousarray(normals / lengths[:, None])
    else:
        if target_normals is not None:
            raise ValueError("target_normals: only used by point_to_plane/point_to_line")
        normals = None
    dof = 3 if dim == 2 else 6
    components = 1 if planar else dim
    # Enough scalar residuals to estimate both the pose and σ² (m > dof).
    min_pairs = dof // components + 1
    if n_used < min_pairs:
        raise ValueError(
            f"source: {method} in {dim}D needs at least {min_pairs} pairs with positive "
            f"weight, got {n_used}"
        )
    if kernel_scale is not None:
        kernel_scale = positive(kernel_scale, "kernel_scale")
    if max_iterations < 0:
        raise ValueError(f"max_iterations: must be >= 0, got {max_iterations}")
    tolerance = positive(tolerance, "tolerance")
    if with_scale and (planar or kernel != "none" or refine):
        raise ValueError("with_scale: only the closed form estimates a scale (no refinement)")

    rotation, translation, scale = _kabsch(src, tgt, w, with_scale)
    cls = pose_class(dim)
    closed = cls._unchecked(rotation, translation)
    do_refine = (planar or kernel != "none") if refine is None else bool(refine)
    pose: SE2 | SE3 = closed if init is None else as_pose(init, "init", dim)

    # Points as the residuals see them: a Umeyama scale is folded into the source.
    src_eff = src if scale == 1.0 else np.ascontiguousarray(src * scale)
    objective_core = "point_to_plane" if planar else "point_to_point"

    def linearize(at: SE2 | SE3, k_scale: float) -> Any:
        return _core.linearize_paired(
            src_eff,
            tgt,
            at.as_matrix(),
            objective=objective_core,
            kernel=kernel,
            kernel_scale=k_scale,
            weights=w,
            target_normals=normals,
        )

    iterations, converged = 0, not do_refine
    k_scale = kernel_scale if kernel_scale is not None else 1.0
    if do_refine:
        if kernel != "none" and kernel_scale is None:
            k_scale = default_scale(kernel, linearize(pose, 1.0).residuals, components)
        for _round in range(5):  # re-estimate an automatic kernel scale until it settles
            pose, its, converged = _gauss_newton(
                pose, lambda at, s=k_scale: linearize(at, s), max_iterations, tolerance
            )
            iterations += its
            if kernel == "none" or kernel_scale is not None:
                break
            new_scale = default_scale(kernel, linearize(pose, k_scale).residuals, components)
            settled = abs(new_scale - k_scale) <= 0.05 * k_scale
            k_scale = new_scale
            if settled:
                break

    final = linearize(pose, k_scale)
    hessian = np.array(final.hessian)
    length = _length_scale(src_eff, w)
    if length <= 1e-12 * (1.0 + float(np.abs(src_eff).max())):
        raise ValueError("source: all points coincide; the rotation is unobservable")
    cond = conditioning(hessian, dim, length)
    if cond.scaled_eigenvalues[0] <= SINGULAR_RATIO * cond.scaled_eigenvalues[-1]:
        raise ValueError(
            "source: the point geometry does not determine the pose: "
            f"{cond.weakest.description} is unobservable (e.g. collinear or coincident points)"
        )
    # Effective number of scalar residuals: pairs in use, down-weighted by the kernel.
    used = final.kernel_weights if w is None else final.kernel_weights[w > 0]
    m_eff = components * float(np.sum(used))
    num_residuals = components * n_used
    if kernel == "none":
        # Least squares: σ̂² = SSR / (m - dof), Σ = σ̂² (JᵀWJ)⁻¹.
        sigma2 = float(final.irls_sum_squares / (num_residuals - dof))
        cov = least_squares_covariance(hessian, sigma2)
    else:
        cov = sandwich_covariance(hessian, np.array(final.score_outer), m_eff, dof)
        # The noise level reported is the median-based robust scale, unmoved by outliers.
        sigma2 = (
            robust_sigma(final.residuals if w is None else final.residuals[w > 0], components) ** 2
        )
    info = information_from_covariance(cov)
    residuals = final.residuals if w is None else final.residuals[w > 0]
    return PairedAlignment(
        pose=pose,
        closed_form_pose=closed,
        scale=scale,
        method=method,
        kernel=kernel,
        kernel_scale=k_scale if kernel != "none" else float("nan"),
        refined=do_refine,
        iterations=iterations,
        converged=converged,
        residuals=ResidualStats.from_residuals(residuals, final.robust_cost),
        num_residuals=num_residuals,
        dof=dof,
        sigma2=sigma2,
        hessian=_frozen(hessian),
        covariance=_frozen(cov),
        information=_frozen(info),
        conditioning=cond,
    )


def _compose(a: SE2 | SE3, b: SE2 | SE3) -> SE2 | SE3:
    if isinstance(a, SE2) and isinstance(b, SE2):
        return a @ b
    if isinstance(a, SE3) and isinstance(b, SE3):
        return a @ b
    raise TypeError(f"cannot compose {type(a).__name__} with {type(b).__name__}")


def _gauss_newton(
    pose: SE2 | SE3,
    linearize: Any,
    max_iterations: int,
    tolerance: float,
) -> tuple[SE2 | SE3, int, bool]:
    """Gauss–Newton on the manifold (``T ← T @ exp(δ)``) with step halving on cost increase.

    The kernel weights are re-evaluated at each linearisation (IRLS).
    """
    lin = linearize(pose)
    for it in range(1, max_iterations + 1):
        h = np.array(lin.hessian)
        g = np.array(lin.gradient)
        try:
            step = -np.linalg.solve(h, g)
        except np.linalg.LinAlgError:
            step = -np.linalg.lstsq(h, g, rcond=None)[0]
        accepted = False
        for _ in range(20):
            candidate = _compose(pose, type(pose).exp(step))
            new = linearize(candidate)
            if new.robust_cost <= lin.robust_cost * (1 + 1e-12) + 1e-300:
                accepted = True
                break
            step = 0.5 * step
        if not accepted:  # no descent along the GN direction: we are at a minimum
            return pose, it, True
        pose, lin = candidate, new
        if float(np.linalg.norm(step)) < tolerance:
            return pose, it, True
    return pose, max_iterations, False
