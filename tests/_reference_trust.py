"""The trust arithmetic as the Python package computed it before it moved into the core
(``scanreg_core::trust``): the independent reference ``tests/test_trust_core.py`` compares the
core's numbers with. Not part of the package; the per-correspondence sums (``_core.censi_analysis``,
``_core.normal_agreement_systems``, the normal noise) are the core's in both.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scanreg import _core
from scanreg._validate import FloatArray
from scanreg._validate import frozen as _frozen
from scanreg._validate import readonly as _readonly
from scanreg.degeneracy import Degeneracy, correspondence_normal_noise
from scanreg.local_map import LocalMap
from scanreg.quality import (
    WeakDirection,
    covariance_upper_bound,
    describe_direction,
    least_squares_covariance,
    sandwich_covariance,
    unit_directions,
)
from scanreg.target import PreparedTarget
from scanreg.transform import SE2, SE3
from scanreg.trust import MIN_NORMAL_AGREEMENT, PLANE_METHOD, CovarianceEstimates, pose_from_core

DEFAULT_MIN_CONSTRAINT = 0.03
# With the linear neighbourhoods known and left out: this floor, or 20 correspondences' worth.
DETERMINED_MIN_CONSTRAINT = 0.01
MIN_FACING = 20.0
DEFAULT_NOISE_FACTOR = 6.0
MEDIAN_CHI2_1 = 0.4549364231195728
HIDDEN_NOISE_GAIN = 6.0
MAX_NOISE_TO_STEP = 0.46


@dataclass(frozen=True)
class CorrespondenceAnalysis:
    censi: Any
    degeneracy: Degeneracy
    point_variance: float
    normal_variance: float
    agreement: tuple[Any, Any] | None
    valley: FloatArray | None = None
    sampling: tuple[FloatArray, FloatArray] | None = None
    #: Analysed at the degeneracy-aware solve's held pose (the first solve's weak directions).
    held: bool = False


def censi_from_inverse(h_inv: FloatArray, meat: FloatArray) -> FloatArray:
    cov = h_inv @ meat @ h_inv
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


def block_from_inverse(h_inv: FloatArray, block_meat: FloatArray, num_blocks: int) -> FloatArray:
    g = max(int(num_blocks), 2)
    cov = (g / (g - 1.0)) * h_inv @ block_meat @ h_inv
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


def levers(ctx: Any) -> FloatArray:
    return rotation_levers(ctx.source, int(ctx.source.shape[1]))


def prior(ctx: Any) -> FloatArray:
    if ctx.init_covariance is not None:
        return np.asarray(ctx.init_covariance)
    dim, lev = int(ctx.source.shape[1]), levers(ctx)
    gate = ctx.settings.max_correspondence_distance
    g = gate if math.isfinite(gate) else float(np.sqrt(np.mean(lev**2)))
    out: FloatArray = np.diag(np.concatenate([np.full(dim, g**2), (g / lev) ** 2])) / 3.0
    return out


def block_size(ctx: Any) -> float:
    if ctx.settings.block_size is not None:
        return float(ctx.settings.block_size)
    block = 2.0 * ctx.settings.max_correspondence_distance
    if math.isfinite(block):
        return float(block)
    return float(np.sqrt(np.mean(levers(ctx) ** 2))) / 5.0


def beam_phase_variance(ctx: Any) -> float:
    src = ctx.source
    if src.shape[1] != 2 or len(src) < 3:
        return 0.0
    angles = np.sort(np.arctan2(src[:, 1], src[:, 0]))
    steps = np.diff(angles)
    steps = steps[steps > 1e-9]
    if not len(steps):
        return 0.0
    step = float(np.median(steps))
    return step * step / 12.0


def sampling_system(
    src: FloatArray,
    corr: Any,
    rotation: FloatArray,
    max_step: float,
    tn: Any,
    tc: Any,
) -> tuple[FloatArray, FloatArray, float, float] | None:
    """2D: ``(H, M)`` of the source's beam phase (``scanreg_core::trust::scene``), the mean
    step along the surfaces and the surface noise from the bends (NaN: fewer than 3)."""
    n = len(src)
    if src.shape[1] != 2 or n < 3 or (tn is None and tc is None):
        return None
    order = np.argsort(np.arctan2(src[:, 1], src[:, 0]), kind="stable")
    h, m, count = np.zeros((3, 3)), np.zeros((3, 3)), 0
    along, bends = 0.0, []
    for k in range(1, n - 1):
        i = order[k]
        j = int(corr[i])
        if j < 0:
            continue
        if tn is not None:
            nt = np.asarray(tn[j], dtype=np.float64)
        else:
            _, vecs = np.linalg.eigh(np.asarray(tc[j], dtype=np.float64))
            nt = vecs[:, 0]
        if not np.isfinite(nt).all():
            continue
        mm = rotation.T @ nt
        step = 0.5 * (src[order[k + 1]] - src[order[k - 1]])
        back = float(np.hypot(*(src[i] - src[order[k - 1]])))
        ahead = float(np.hypot(*(src[order[k + 1]] - src[i])))
        if min(back, ahead) > max_step:
            continue
        e = float(mm @ step)
        along += abs(float(mm[1] * step[0] - mm[0] * step[1]))
        bend = 0.5 * (src[order[k + 1]] + src[order[k - 1]]) - src[i]
        bends.append(float(mm @ bend) ** 2)
        p = src[i]
        jac = np.array([mm[0], mm[1], -mm[0] * p[1] + mm[1] * p[0]])
        h += np.outer(jac, jac)
        m += np.outer(jac, jac) * e * e
        count += 1
    if count < 3:
        return None
    noise = float(np.median(bends)) / MEDIAN_CHI2_1 / 1.5 if len(bends) >= 3 else math.nan
    return h, m, along / count, noise


def hidden_noise_variance(
    src: FloatArray,
    tp: FloatArray,
    tn: FloatArray,
    corr: Any,
    pose: FloatArray,
    step: float,
    surface_noise: float,
) -> float:
    """2D point-to-line: ``a σ̂⁴/h²`` (``scanreg_core::trust::association``)."""
    used = np.asarray(corr) >= 0
    if not (math.isfinite(step) and step > 0.0) or used.sum() < 3:
        return 0.0
    j = np.asarray(corr)[used]
    moved = src[used] @ pose[:2, :2].T + pose[:2, 2]
    r = ((moved - tp[j]) * tn[j]).sum(axis=1)
    r2 = r[np.isfinite(r)] ** 2
    if len(r2) < 3:
        return 0.0
    noise = float(np.sort(r2)[len(r2) // 2]) / MEDIAN_CHI2_1 / 2.0
    if surface_noise < noise:
        noise = surface_noise
    return HIDDEN_NOISE_GAIN * noise * min(noise / step**2, MAX_NOISE_TO_STEP)


def sampling_covariance(h: FloatArray, m: FloatArray, deg: Degeneracy) -> FloatArray | None:
    """``¼ T A⁻¹ (Tᵀ M T) A⁻¹ Tᵀ`` on the strong subspace (``A = Tᵀ H T``)."""
    t = deg.scaling()[:, None] * deg.strong_basis()
    try:
        a_inv = np.linalg.inv(t.T @ h @ t)
    except np.linalg.LinAlgError:
        return None
    out = t @ a_inv @ (t.T @ m @ t) @ a_inv @ t.T * 0.25
    out = 0.5 * (out + out.T)
    return out if np.isfinite(out).all() else None


def length_scale(points: FloatArray) -> float:
    centred = points - points.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))


def residual_variance(out: Any, components: int, kernel: str, dof: int) -> float:
    if kernel == "none":
        m = components * float(out.num_correspondences)
        return float(out.sum_squares / (m - dof)) if m > dof else math.nan
    m = components * float(out.irls_weight_sum)
    return float(out.irls_sum_squares / (m - dof)) if m > dof else math.nan


def rotation_levers(points: FloatArray, dim: int) -> FloatArray:
    """RMS distance of ``points`` from each rotation axis through the origin (≥ 1e-9)."""
    sq = points**2
    if dim == 2:
        levers = np.array([np.sqrt(np.mean(sq.sum(axis=1)))])
    else:
        total = sq.sum(axis=1)
        levers = np.sqrt(np.array([np.mean(total - sq[:, a]) for a in range(3)]))
    out: FloatArray = np.maximum(levers, 1e-9)
    return out


def analyse_degeneracy(
    information: FloatArray,
    count: int,
    dim: int,
    levers: FloatArray,
    *,
    normal_noise: float = float("nan"),
    typical_normal_noise: float = float("nan"),
    min_constraint: float = DEFAULT_MIN_CONSTRAINT,
    noise_factor: float = DEFAULT_NOISE_FACTOR,
    basis: str = "plane_information",
    removed_normal_noise: float = float("nan"),
) -> Degeneracy:
    """Name the weak directions of ``information`` (``Σ JᵀJ`` over ``count`` correspondences)."""
    dof = information.shape[0]
    s_inv = np.concatenate([np.ones(dim), 1.0 / np.asarray(levers, dtype=np.float64)])
    g = 0.5 * (information + information.T) * np.outer(s_inv, s_inv) / max(count, 1)
    vals, vecs = np.linalg.eigh(g)
    vals = np.maximum(vals, 0.0)  # with normal noise removed the estimate can dip below 0
    threshold = float(min_constraint)
    if np.isfinite(typical_normal_noise):
        threshold = max(threshold, noise_factor * float(typical_normal_noise))
    top = max(float(vals[-1]), 1e-300)
    length = float(np.sqrt(np.mean(np.asarray(levers) ** 2)))

    # Back to metres / radians, unit length in metres-equivalent.
    units = unit_directions(vecs, s_inv, norm_scale=s_inv)

    def direction(i: int) -> WeakDirection:
        v = units[:, i]
        return WeakDirection(
            vector=_frozen(v),
            ratio=float(vals[i] / top),
            description=describe_direction(v, dim, length),
        )

    directions = tuple(direction(i) for i in range(dof))
    weak = tuple(d for d, lam in zip(directions, vals, strict=True) if lam < threshold)
    return Degeneracy(
        information=_frozen(g),
        levers=_frozen(np.asarray(levers, dtype=np.float64)),
        eigenvalues=_frozen(vals),
        directions=directions,
        weak_directions=weak,
        threshold=threshold,
        normal_noise=float(normal_noise),
        typical_normal_noise=float(typical_normal_noise),
        basis=basis,
        num_correspondences=int(count),
        removed_normal_noise=float(removed_normal_noise),
    )


def noise_removed_information(
    src: FloatArray,
    tn: FloatArray,
    corr: Any,
    pose: FloatArray,
    sample: Any,
    normals: FloatArray,
    linear: Any = None,
) -> tuple[FloatArray, float]:
    """``(ε² Σ Aᵀ(I − m mᵀ)A, ε²)`` over the correspondences with a target normal (not a
    ``linear`` one), ``ε²`` half the mean squared sine per tangent axis between the sampled
    source normals (rotated) and their target normals; ``(0, nan)`` with 6 or fewer such
    pairs (3D)."""
    r = pose[:3, :3]
    corr = np.asarray(corr)
    nt = np.zeros(src.shape)
    has = corr >= 0
    nt[has] = tn[corr[has]]
    plane = has & (np.sum(nt**2, axis=1) >= 0.25)
    if linear is not None:
        plane[has] &= ~np.asarray(linear)[corr[has]]
    ns = np.full(src.shape, np.nan)
    ns[np.asarray(sample)] = normals
    ns = ns @ r.T
    pair = plane & np.isfinite(ns).all(axis=1) & (np.sum(np.nan_to_num(ns) ** 2, axis=1) >= 0.25)
    if pair.sum() <= 6:
        return np.zeros((6, 6)), math.nan
    cos = np.sum(ns[pair] * nt[pair], axis=1)
    eps2 = float(np.sum(np.maximum(1.0 - cos**2, 0.0)) / (pair.sum() * 4.0))
    p = src[plane]
    m = nt[plane] @ r  # Rᵀn per row
    z = np.zeros(len(p))
    skew = np.stack(
        [
            np.stack([z, -p[:, 2], p[:, 1]], axis=1),
            np.stack([p[:, 2], z, -p[:, 0]], axis=1),
            np.stack([-p[:, 1], p[:, 0], z], axis=1),
        ],
        axis=1,
    )
    a = np.concatenate([np.broadcast_to(np.eye(3), (len(p), 3, 3)), -skew], axis=2)
    j = np.einsum("kij,ki->kj", a, m)
    noise = np.einsum("kij,kil->jl", a, a) - j.T @ j
    return eps2 * noise, eps2


def correspondence_analysis(ctx: Any, out: Any) -> CorrespondenceAnalysis:
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
    # The target's linear neighbourhoods (their normals are guesses), known for its own normals.
    linear = (
        prepared.linear
        if isinstance(prepared, PreparedTarget) and tn is not None and tn is prepared.normals
        else None
    )
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
        block_size=max(block_size(ctx), 1e-9),
        normal_variance=1.0,
        target_normals=tn,
        source_covariances=ctx.source_covariances,
        target_covariances=tc
        if method == "gicp" or (method == "point_to_point" and dim == 3)
        else None,
        num_threads=s.num_threads,
        target_linear=linear,
    )
    if method == "gicp" and linear is not None:
        # GICP's own systems, over every pair and over the pairs whose target neighbourhood is
        # not linear (the model-error term; the core's sums).
        agreement = (
            (ana.hessian, ana.score, ana.num_correspondences),
            (ana.determined_hessian, ana.determined_score, ana.num_determined_pairs),
        )
    n_det = ana.num_determined_correspondences
    if n_det > dof:
        info, removed = np.array(ana.plane_information), math.nan
        if dim == 3 and method != "gicp" and tn is not None:
            sample, sample_normals = ctx.source_normals
            fake, removed = noise_removed_information(
                src, tn, corr, out.pose, sample, sample_normals, linear
            )
            info = info - fake
        deg = analyse_degeneracy(
            info,
            n_det,
            dim,
            levers(ctx),
            normal_noise=eps2,
            typical_normal_noise=eps2_typical,
            removed_normal_noise=removed,
            min_constraint=DEFAULT_MIN_CONSTRAINT
            if linear is None
            else max(DETERMINED_MIN_CONSTRAINT, MIN_FACING / n_det),
        )
    else:
        deg = analyse_degeneracy(
            np.array(ana.hessian),
            max(ana.num_correspondences, 1),
            dim,
            levers(ctx),
            normal_noise=eps2,
            typical_normal_noise=eps2_typical,
            basis="hessian",
        )
    ratio = _density_ratio(ctx)
    system = sampling_system(
        src,
        corr,
        np.asarray(out.pose)[:dim, :dim],
        0.5 * float(s.max_correspondence_distance),
        tn,
        tc,
    )
    hidden = 0.0
    if system is not None and tn is not None and method in ("point_to_plane", "point_to_line"):
        hidden = hidden_noise_variance(
            src,
            np.asarray(tp),
            np.asarray(tn),
            corr,
            np.asarray(out.pose),
            system[2] * ratio,
            system[3],
        )
    return CorrespondenceAnalysis(
        censi=ana,
        degeneracy=deg,
        point_variance=_point_variance(out, ana, method, dim, dof) + hidden,
        normal_variance=normal_var,
        agreement=agreement,
        sampling=_scaled(None if system is None else system[:2], ratio),
    )


def _median_spacing(points: FloatArray) -> float:
    """Median distance to the nearest other point, by brute force."""
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    return float(np.sqrt(np.median(d2.min(axis=1))))


def _density_ratio(ctx: Any) -> float:
    """The target's point spacing over the source's, at most 1 (``TrustInputs``)."""
    target = getattr(ctx.target, "points", None)
    if target is None or len(target) < 2 or len(ctx.source) < 2:
        return 1.0
    source = _median_spacing(np.asarray(ctx.source))
    return min(1.0, _median_spacing(np.asarray(target)) / source) if source > 0 else 1.0


def _scaled(
    system: tuple[FloatArray, FloatArray] | None, ratio: float
) -> tuple[FloatArray, FloatArray] | None:
    return None if system is None else (system[0], system[1] * ratio**2)


def _covariance_estimates(
    ctx: Any,
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
    ana = corr.censi
    determined = _held_determined(corr, ctx.method, dof)
    estimates = _estimates(
        cov,
        ana,
        deg,
        prior(ctx),
        float(ana.determined_plane_sum_squares / (ana.num_determined_correspondences - dof)) / 2.0
        if determined
        else corr.point_variance,
        corr.normal_variance,
        block_size(ctx),
        dof,
        (ctx.start.inverse() @ pose).log(),  # type: ignore[operator]
        _model_shift(corr.agreement, deg, ctx.method, dof),
        corr.valley,
        beam_phase_variance(ctx),
        corr.sampling,
        determined_blocks=determined,
    )
    if ctx.plane_solve is not None:
        estimates = _via_plane_reference(ctx, pose, corr, estimates, dof)
    return estimates


def _held_determined(corr: CorrespondenceAnalysis, method: str, dof: int) -> bool:
    """GICP at a held pose with a target that flags its linear neighbourhoods: the point
    variance (along the normal) and the block scores over the determined pairs only."""
    ana = corr.censi
    return (
        corr.held
        and method == "gicp"
        and bool(ana.linear_known)
        and int(ana.num_determined_correspondences) > dof
        and int(ana.num_determined_blocks) > 0
    )


def _via_plane_reference(
    ctx: Any,
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

    Point-to-plane/line and GICP: along the normal, ``Σ (nᵀe)² / (n - dof)`` — the noise
    their residual feels. Point-to-point: ``Σ |e|² / (D n - dof)``, the along-surface sampling
    offsets included.
    """
    n_plane = int(ana.num_plane_correspondences)
    along_normal = method in ("point_to_plane", "point_to_line", "gicp")
    if along_normal and n_plane > dof:
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
    sampling_system: tuple[FloatArray, FloatArray] | None = None,
    *,
    determined_blocks: bool = False,
) -> CovarianceEstimates:
    bad = np.full((dof, dof), np.inf)
    h = np.array(ana.hessian)
    meat = point_variance * (np.array(ana.source_meat) + np.array(ana.target_meat))
    meat = meat + normal_variance * np.array(ana.normal_meat)
    try:
        h_inv = np.linalg.inv(h)
        censi = censi_from_inverse(h_inv, meat)
        if determined_blocks:
            blk = block_from_inverse(
                h_inv, np.array(ana.determined_block_meat), int(ana.num_determined_blocks)
            )
        else:
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
    if np.isfinite(calibrated).all():
        # 2D: the beams' phase (see TrustInputs.sampling_system; without target normals the
        # beam-phase heading variance).
        term = None if sampling_system is None else sampling_covariance(*sampling_system, deg)
        if term is not None:
            calibrated = calibrated + term
        elif sampling_system is None and sampling > 0.0:
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
