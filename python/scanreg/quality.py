"""How far to trust an estimate: residual statistics, covariance and conditioning.

Everything here works on the small matrices the core returns (``JᵀJ`` is at most 6×6).
Covariances are over the right-perturbation tangent ``δ`` of :mod:`scanreg.transform`
(translation first, source frame): ``T_true = T_est @ exp(δ)``, ``δ ~ N(0, Σ)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._validate import FloatArray
from ._validate import frozen as _frozen

#: Below this ratio of the smallest to the largest *scaled* eigenvalue of ``JᵀJ`` the pose
#: is not determined at all (numerically singular): scanreg raises instead of returning it.
SINGULAR_RATIO = 1e-12

#: The verdict's weakness threshold for results that carry no :class:`~scanreg.Degeneracy`
#: (whose threshold is derived from the measured normal noise): the weakest scaled direction of
#: ``conditioning`` below this ratio of the best. A ratio r means the pose is 1/sqrt(r) times
#: less certain along that direction than along the best one; 1e-4 is 100×.
DEFAULT_WEAK_RATIO = 1e-4


@dataclass(frozen=True)
class ResidualStats:
    """Statistics of the residuals at the final pose.

    For point-to-point a residual is the distance ``|R p + t - q|``; for point-to-plane/line
    it is the signed distance ``nᵀ(R p + t - q)``. Units are those of the points.
    """

    count: int
    rmse: float
    mean_abs: float
    median_abs: float
    max_abs: float
    sum_squares: float
    robust_cost: float

    @classmethod
    def from_residuals(cls, residuals: FloatArray, robust_cost: float) -> ResidualStats:
        a = np.abs(residuals)
        return cls(
            count=int(a.size),
            rmse=float(np.sqrt(np.mean(a**2))),
            mean_abs=float(a.mean()),
            median_abs=float(np.median(a)),
            max_abs=float(a.max()),
            sum_squares=float(np.sum(a**2)),
            robust_cost=float(robust_cost),
        )


@dataclass(frozen=True)
class WeakDirection:
    """A poorly constrained direction of the pose, in tangent coordinates."""

    #: Unit tangent vector (translation first), in metres / radians.
    vector: FloatArray
    #: Scaled eigenvalue over the largest scaled eigenvalue (1 = as good as the best).
    ratio: float
    #: e.g. ``"translation along (1.00, 0.00, 0.00)"`` or ``"rotation about (0.00, 0.00, 1.00)"``.
    description: str


@dataclass(frozen=True)
class Conditioning:
    """Eigen-analysis of the information matrix ``JᵀJ``: numbers only. Which directions are
    weak — a verdict — is :class:`~scanreg.Degeneracy`'s to say (``result.degeneracy``).

    The raw eigenvalues mix units (m⁻² for translation, rad⁻² for rotation). The *scaled*
    analysis expresses rotation in metres at ``length_scale`` (the RMS distance of the points
    from their centroid), so its eigenvalue ratios do not depend on the choice of units.
    """

    #: Raw eigenvalues of ``JᵀJ``, ascending.
    eigenvalues: FloatArray
    #: Matching unit eigenvectors (columns), tangent coordinates.
    eigenvectors: FloatArray
    #: ``λmax / λmin`` of the raw ``JᵀJ`` (``inf`` when singular).
    condition_number: float
    length_scale: float
    #: Eigenvalues of ``S⁻¹ JᵀJ S⁻¹`` with ``S = diag(1.., L..)``, ascending.
    scaled_eigenvalues: FloatArray
    scaled_condition_number: float
    #: The least constrained direction (always reported; its ``ratio`` to the best).
    weakest: WeakDirection


def _fmt(v: list[float]) -> str:
    # round first and add 0.0 so that -0.001 prints as 0.00, not -0.00
    return "(" + ", ".join(f"{round(x, 2) + 0.0:.2f}" for x in v) + ")"


def _norm(v: list[float]) -> float:
    return math.sqrt(sum(x * x for x in v))


def describe_direction(vector: FloatArray, dim: int, length_scale: float) -> str:
    """Name a tangent direction: translation, rotation, or a coupling of both."""
    # Plain floats: a handful of numbers, where NumPy's per-call cost would dominate.
    values = [float(x) for x in vector]
    trans, rot = values[:dim], values[dim:]
    # Compare in metres: a rotation of φ moves points at the length scale by about L·φ.
    t_norm = _norm(trans)
    rot_norm = _norm(rot)
    r_norm = rot_norm * length_scale
    total = max(t_norm + r_norm, 1e-300)
    lead = trans if t_norm >= r_norm else rot
    largest = max(range(len(lead)), key=lambda i: abs(lead[i]))  # the first of equals
    sign = -1.0 if lead[largest] < 0 else 1.0  # report a canonical sign
    t_den = max(t_norm, 1e-300)
    t_txt = f"translation along {_fmt([sign * x / t_den for x in trans])}"
    if dim == 2:
        r_txt = "rotation (θ)"
    else:
        r_den = max(rot_norm, 1e-300)
        r_txt = f"rotation about {_fmt([sign * x / r_den for x in rot])}"
    if r_norm / total < 0.1:
        return t_txt
    if t_norm / total < 0.1:
        return r_txt
    first, second = (t_txt, r_txt) if t_norm >= r_norm else (r_txt, t_txt)
    return f"{first} coupled with {second}"


def unit_directions(
    vectors: FloatArray, s_inv: FloatArray, norm_scale: FloatArray | None = None
) -> FloatArray:
    """Columns of ``vectors`` (scaled eigenvectors) back in metres / radians (``× s_inv``),
    each divided by its norm (of the column ``/ norm_scale`` when given)."""
    v = vectors * s_inv[:, None]
    measured = v if norm_scale is None else v / norm_scale[:, None]
    out: FloatArray = v / np.sqrt(np.sum(measured * measured, axis=0))
    return out


def conditioning(
    hessian: FloatArray,
    dim: int,
    length_scale: float,
) -> Conditioning:
    """Eigen-analysis of ``JᵀJ`` (``hessian``) for a ``dim``-D pose."""
    dof = hessian.shape[0]
    h = 0.5 * (hessian + hessian.T)
    raw_vals, raw_vecs = np.linalg.eigh(h)
    length = max(float(length_scale), 1e-12)
    s_inv = np.ones(dof)
    s_inv[dim:] = 1.0 / length
    hs = h * np.outer(s_inv, s_inv)
    vals, vecs = np.linalg.eigh(hs)
    top = float(vals[-1])
    ratios = vals / top if top > 0 else np.zeros_like(vals)

    units = unit_directions(vecs, s_inv)

    def direction(i: int) -> WeakDirection:
        v = units[:, i]
        return WeakDirection(
            vector=_frozen(v),
            ratio=float(ratios[i]),
            description=describe_direction(v, dim, length),
        )

    weakest = direction(0)
    return Conditioning(
        eigenvalues=_frozen(raw_vals),
        eigenvectors=_frozen(raw_vecs),
        condition_number=float(raw_vals[-1] / raw_vals[0]) if raw_vals[0] > 0 else float("inf"),
        length_scale=length,
        scaled_eigenvalues=_frozen(vals),
        scaled_condition_number=float(1.0 / ratios[0]) if ratios[0] > 0 else float("inf"),
        weakest=weakest,
    )


def least_squares_covariance(hessian: FloatArray, sigma2: float) -> FloatArray:
    """``σ̂² (JᵀWJ)⁻¹``: the covariance of a least-squares estimate over the tangent ``δ``.

    Raises ``numpy.linalg.LinAlgError`` when ``hessian`` is singular.
    """
    cov = sigma2 * np.linalg.inv(hessian)
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


def sandwich_covariance(
    hessian: FloatArray, score_outer: FloatArray, effective_residuals: float, dof: int
) -> FloatArray:
    """M-estimator sandwich ``H⁻¹ (Σ ψψᵀ) H⁻¹ · m/(m - dof)`` (Huber 1981, §7.6).

    ``ψ = w k Jᵀr`` per residual block, ``m`` the effective number of scalar residuals (kernel
    weights summed), the factor a small-sample correction. Outliers a kernel only down-weights
    (Huber) still widen it, as they should. Raises ``numpy.linalg.LinAlgError`` when
    ``hessian`` is singular.
    """
    h_inv = np.linalg.inv(hessian)
    correction = effective_residuals / max(effective_residuals - dof, 1.0)
    cov = correction * h_inv @ score_outer @ h_inv
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


#: Eigenvalues of a covariance below this fraction of its largest are floored there when it is
#: inverted: round-off, not information (a plain inverse of such a matrix has entries of
#: ±1e90 and negative diagonals).
_MIN_RELATIVE_VARIANCE = 1e-14


def information_from_covariance(cov: FloatArray) -> FloatArray:
    """``cov⁻¹``, symmetric positive definite, or all-``inf`` for a zero (noise-free)
    covariance. A (near-)singular ``cov`` — a noise-free fit along some directions — gets
    its variances floored at ``1e-14`` of the largest first. A ``cov`` with infinite entries
    (undetermined directions) is inverted as it is; a NaN is refused."""
    try:
        cov = np.asarray(cov, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"cov: expected a matrix of numbers: {exc}") from None
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or cov.shape[0] == 0:
        raise ValueError(f"cov: expected a square (n, n) matrix with n >= 1, got shape {cov.shape}")
    if np.isnan(cov).any():
        raise ValueError("cov: contains NaN")
    if not np.isfinite(cov).all():
        try:
            return np.asarray(np.linalg.inv(cov), dtype=np.float64)
        except np.linalg.LinAlgError:
            return np.full_like(cov, np.inf)
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    top = float(vals[-1])
    if not top > 0.0:
        return np.full_like(cov, np.inf)
    if vals[0] > _MIN_RELATIVE_VARIANCE * top:
        return np.asarray(np.linalg.inv(cov), dtype=np.float64)
    floored = np.maximum(vals, _MIN_RELATIVE_VARIANCE * top)
    return np.asarray((vecs / floored) @ vecs.T, dtype=np.float64)


def chi2_quantile(dof: float, prob: float) -> float:
    """Quantile of the χ² distribution (Wilson–Hilferty; relative error < 1e-3 for dof >= 3).

    Used for NEES consistency bands without a SciPy dependency.
    """
    if not 0.0 < prob < 1.0:
        raise ValueError(f"prob: must be in (0, 1), got {prob}")
    if dof <= 0:
        raise ValueError(f"dof: must be > 0, got {dof}")
    z = _normal_quantile(prob)
    a = 2.0 / (9.0 * dof)
    return float(dof * (1.0 - a + z * np.sqrt(a)) ** 3)


def _normal_quantile(p: float) -> float:
    # Acklam's rational approximation (relative error < 1.2e-9).
    a = [
        -3.969683028665376e01,
        2.209460984245205e02,
        -2.759285104469687e02,
        1.383577518672690e02,
        -3.066479806614716e01,
        2.506628277459239e00,
    ]
    b = [
        -5.447609879822406e01,
        1.615858368580409e02,
        -1.556989798598866e02,
        6.680131188771972e01,
        -1.328068155288572e01,
    ]
    c = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e00,
        -2.549732539343734e00,
        4.374664141464968e00,
        2.938163982698783e00,
    ]
    d = [7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00, 3.754408661907416e00]
    lo = 0.02425
    if p < lo:
        q = np.sqrt(-2 * np.log(p))
        x = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / (
            (((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1
        )
    elif p > 1 - lo:
        q = np.sqrt(-2 * np.log(1 - p))
        x = -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / (
            (((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1
        )
    else:
        q = p - 0.5
        r = q * q
        x = (
            (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5])
            * q
            / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1)
        )
    return float(x)


def nees_band(dof: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided band for the *mean* NEES of ``trials`` consistent estimates of ``dof`` dims."""
    alpha = (1.0 - confidence) / 2.0
    n = dof * trials
    return chi2_quantile(n, alpha) / trials, chi2_quantile(n, 1.0 - alpha) / trials


def censi_covariance(hessian: FloatArray, meat: FloatArray) -> FloatArray:
    """Censi's closed form ``H⁻¹ (∂g/∂z) Σ_z (∂g/∂z)ᵀ H⁻¹`` from its middle term ``meat``.

    Raises ``numpy.linalg.LinAlgError`` when ``hessian`` is singular.
    """
    h_inv = np.linalg.inv(hessian)
    cov = h_inv @ meat @ h_inv
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


def block_covariance(hessian: FloatArray, block_meat: FloatArray, num_blocks: int) -> FloatArray:
    """Cluster-robust sandwich ``H⁻¹ (Σ_b ψ_b ψ_bᵀ) H⁻¹ · G/(G - 1)`` over ``G`` spatial blocks.

    ``ψ_b`` sums the per-correspondence scores of a block, so errors correlated inside a block
    (sampling, model error) count once per block instead of averaging out as ``1/N``
    (Liang & Zeger 1986; Cameron & Miller 2015, §II.C). Raises ``numpy.linalg.LinAlgError``
    when ``hessian`` is singular.
    """
    h_inv = np.linalg.inv(hessian)
    g = max(int(num_blocks), 2)
    cov = (g / (g - 1.0)) * h_inv @ block_meat @ h_inv
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


def covariance_upper_bound(a: FloatArray, b: FloatArray) -> FloatArray:
    """The smallest covariance ``C`` with ``C ⪰ a`` and ``C ⪰ b`` along the joint eigenbasis:
    ``a^{1/2} U max(1, Λ) Uᵀ a^{1/2}`` with ``U Λ Uᵀ`` the eigen-decomposition of
    ``a^{-1/2} b a^{-1/2}``. Either input may be singular only if the other is not.
    """
    vals, vecs = np.linalg.eigh(0.5 * (a + a.T))
    if vals[0] <= 0:
        vals2, vecs2 = np.linalg.eigh(0.5 * (b + b.T))
        if vals2[0] <= 0:
            return np.asarray(np.maximum(a, b), dtype=np.float64)
        a, b, vals, vecs = b, a, vals2, vecs2
    root = vecs * np.sqrt(vals)
    inv_root = vecs / np.sqrt(vals)
    w_vals, w_vecs = np.linalg.eigh(inv_root.T @ b @ inv_root)
    m = w_vecs * np.maximum(w_vals, 1.0) @ w_vecs.T
    out: FloatArray = root @ m @ root.T
    return np.asarray(0.5 * (out + out.T), dtype=np.float64)


def transform_covariance(covariance: FloatArray, adjoint: FloatArray) -> FloatArray:
    """``Ad Σ Adᵀ``: the covariance of ``Ad δ``.

    With ``Ad = pose.adjoint()`` this turns scanreg's right-perturbation covariance (source
    frame, ``T_true = T @ exp(δ)``) into the left-perturbation one (target frame,
    ``T_true = exp(ε) @ T``), the convention of e.g. GTSAM's ``BetweenFactor`` on the inverse
    or of an EKF over the target-frame pose. With ``Ad = X.adjoint()`` for a fixed transform
    ``X = T_source_sensor⁻¹`` it moves the tangent to another body frame.
    """
    ad = np.asarray(adjoint, dtype=np.float64)
    cov = np.asarray(covariance, dtype=np.float64)
    if ad.shape != cov.shape or ad.ndim != 2 or ad.shape[0] != ad.shape[1]:
        raise ValueError(f"adjoint: expected shape {cov.shape} to match covariance, got {ad.shape}")
    out: FloatArray = ad @ cov @ ad.T
    return np.asarray(0.5 * (out + out.T), dtype=np.float64)
