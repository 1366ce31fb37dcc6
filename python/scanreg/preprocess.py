"""Preprocessing of 2D/3D point clouds: voxel grid, random subsampling, crops, outlier removal,
normals and covariances by k-NN PCA. Every per-point loop runs in the Rust core, in parallel,
with results that do not depend on the number of threads.

Filters return a frozen dataclass with the kept ``points`` and, for each, the row ``indices``
of the input it came from, so per-point attributes (intensity, time stamps) can follow.
A filter that would leave **no point** raises ``ValueError`` naming the filter and its
settings, instead of returning an empty cloud that fails later far from the cause.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from . import _core, budget
from ._validate import FloatArray, as_matrix, as_points, check_flag, positive
from ._validate import readonly as _readonly

IndexArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

VoxelKeep = Literal["centroid", "first"]
Regularization = Literal["plane", "normalized_min_eig", "none"]

#: Default neighbourhood size for normals, covariances and statistical outlier removal.
DEFAULT_K = 20


_INTS = (int, np.integer)  # a tuple once: `int | np.integer` builds a union at every call


def positive_int(value: Any, name: str, *, minimum: int = 1) -> int:
    """An ``int`` (not bool) ``>= minimum``."""
    if isinstance(value, bool) or not isinstance(value, _INTS):
        raise TypeError(f"{name}: expected an int, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name}: must be >= {minimum}, got {value}")
    return int(value)


def _finite(value: Any, name: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {value}")
    return v


@dataclass(frozen=True)
class Filtered:
    """Points kept by a filter.

    ``points[j] == input[indices[j]]``; ``indices`` is increasing.
    """

    #: ``(M, D)`` kept points (a copy; read-only).
    points: FloatArray
    #: ``(M,)`` row of each kept point in the input.
    indices: IndexArray
    #: Number of input points.
    num_input: int

    @property
    def num_kept(self) -> int:
        return int(self.indices.shape[0])

    @property
    def num_removed(self) -> int:
        return self.num_input - self.num_kept


@dataclass(frozen=True)
class VoxelDownsampled:
    """One point per occupied voxel of a grid with cell ``voxel_size`` (cells
    ``floor(p / voxel_size)``, aligned with the origin of the points' frame)."""

    #: ``(M, D)``: the centroid of each voxel's points (``keep="centroid"``) or its point with
    #: the lowest input index (``keep="first"``). Read-only.
    points: FloatArray
    #: ``(M,)`` lowest input index in each voxel, increasing (voxels in order of first appearance).
    indices: IndexArray
    #: ``(M,)`` number of input points in each voxel.
    counts: IndexArray
    voxel_size: float
    #: Which point stands for a voxel: ``"centroid"`` or ``"first"``.
    keep: str
    num_input: int

    @property
    def num_kept(self) -> int:
        return int(self.indices.shape[0])


@dataclass(frozen=True)
class StatisticalOutliers(Filtered):
    """:class:`Filtered` plus the statistic each point was judged by."""

    #: ``(N,)`` per input point: mean distance to its ``num_neighbors`` nearest other points.
    mean_distances: FloatArray
    #: Points with ``mean_distances <= threshold`` were kept.
    threshold: float


@dataclass(frozen=True)
class Normals:
    """Unit normals by k-NN PCA, oriented towards ``viewpoint`` (``n · (viewpoint - p) >= 0``).

    Where a neighbourhood is degenerate (all points coincide, or in 3D all collinear) the normal
    is undefined: ``valid`` is False there and the normal is the zero vector. With
    ``drop_linear`` (off by default) the same holds where a 3D neighbourhood is *linear* — a
    LiDAR ring, a pole, an edge: its "normal" is any direction across the line, picked by the
    noise (rule: Demantké et al. 2011, ``a1D`` the largest dimensionality feature). In a
    simulated street it cuts point-to-plane's error along the road 4×; on the real outdoor pair
    it improves translation but costs 0.1–0.6° of rotation, hence off
    (``docs/calibration.md``, "Linear neighbourhoods").
    """

    #: ``(N, D)`` unit normals (zero rows where not ``valid``). Read-only.
    normals: FloatArray
    #: ``(N,)`` whether the point has a normal: its neighbourhood spanned a line (2D) / plane
    #: (3D), and was not linear (3D, with ``drop_linear``).
    valid: BoolArray
    #: Points without a normal (``~valid``), the linear ones included.
    num_invalid: int
    num_neighbors: int
    viewpoint: FloatArray
    #: Of ``num_invalid``, the points left out because their 3D neighbourhood is linear.
    num_linear: int = 0


@dataclass(frozen=True)
class Covariances:
    """Per-point ``(D, D)`` covariances by k-NN PCA, regularised for GICP.

    ``regularization``:
    ``"plane"`` (default; Segal et al. 2009) — eigenvalues replaced by ``(ε, 1, 1)`` (3D) or
    ``(ε, 1)`` (2D), eigenvectors kept: a unit disc/segment of thickness ``ε`` along the normal;
    ``"normalized_min_eig"`` — eigenvalues divided by the largest and clamped below at ``ε``;
    ``"none"`` — the raw sample covariance ``(1/num_neighbors) Σ (q - q̄)(q - q̄)ᵀ`` (m²).
    Degenerate neighbourhoods (``valid`` False) get the identity.
    """

    #: ``(N, D, D)`` symmetric covariances. Read-only.
    covariances: FloatArray
    valid: BoolArray
    num_invalid: int
    num_neighbors: int
    regularization: str
    epsilon: float


def _nonempty(kept: IndexArray, what: str) -> None:
    if kept.shape[0] == 0:
        raise ValueError(f"points: no point left after {what}")


def _filtered(points: FloatArray, kept: IndexArray) -> Filtered:
    return Filtered(
        points=_readonly(points[kept]),
        indices=_readonly(kept),
        num_input=int(points.shape[0]),
    )


def _voxel_centroids(points: FloatArray, voxel_size: float) -> FloatArray:
    """``voxel_downsample(points, voxel_size).points`` for points the caller has checked already
    (finite, ``(N, D)`` float64, C-contiguous; ``voxel_size`` validated): ``register`` on a raw
    KITTI sweep scanned its 120k points for NaN twice more on the way."""
    out: FloatArray = _readonly(_core.voxel_downsample(points, voxel_size, "centroid")[0])
    return out


def voxel_downsample(
    points: FloatArray, voxel_size: float, *, keep: VoxelKeep = "centroid"
) -> VoxelDownsampled:
    """Voxel-grid downsampling: one point per occupied voxel.

    Parameters
    ----------
    points : (N, 2) or (N, 3) float64, N >= 1
    voxel_size : float
        Edge of the cubic (square) cells, in the points' units; finite, > 0.
    keep : {"centroid", "first"}
        Which point stands for a voxel (not a cost function, hence not ``method``):
        ``"centroid"``: the mean of each voxel's points. ``"first"``: the voxel's point with the
        lowest input index (an actual measured point; deterministic).
    """
    pts = as_points(points, "points")
    if budget.LIMIT is not None:
        budget.check("voxel_downsample: points", len(pts), ("voxel_downsample",))
    size = positive(voxel_size, "voxel_size")
    if keep not in ("centroid", "first"):
        raise ValueError(f"keep: unknown {keep!r}; expected 'centroid' or 'first'")
    out, idx, counts = _core.voxel_downsample(pts, size, keep)
    return VoxelDownsampled(
        points=_readonly(out),
        indices=_readonly(idx),
        counts=_readonly(counts),
        voxel_size=size,
        keep=keep,
        num_input=int(pts.shape[0]),
    )


def random_subsample(
    points: FloatArray,
    n: int | None = None,
    *,
    fraction: float | None = None,
    seed: int = 0,
) -> Filtered:
    """Keep ``n`` points (or ``round(fraction · N)``, at least 1) drawn uniformly without
    replacement; the same ``seed`` gives the same subset on every platform. Kept points stay in
    input order."""
    pts = as_points(points, "points")
    total = int(pts.shape[0])
    if (n is None) == (fraction is None):
        raise ValueError("n: give exactly one of n or fraction")
    if n is not None:
        count = positive_int(n, "n")
        if count > total:
            raise ValueError(f"n: is {count} but points has only {total} points")
    else:
        f = _finite(fraction, "fraction")
        if not 0.0 < f <= 1.0:
            raise ValueError(f"fraction: must be in (0, 1], got {fraction}")
        count = max(1, round(f * total))
    s = positive_int(seed, "seed", minimum=0)
    if s >= 2**64:
        raise ValueError(f"seed: must be < 2**64, got {seed}")
    kept = _core.random_subsample_indices(total, count, s)
    return _filtered(pts, kept)


def crop_range(
    points: FloatArray, min_distance: float = 0.0, max_distance: float = math.inf
) -> Filtered:
    """Keep the points whose distance from the origin of their frame (the sensor, for a scan in
    the sensor frame) is in ``[min_distance, max_distance]``. Raises ``ValueError`` if none is."""
    pts = as_points(points, "points")
    kept = _core.crop_range(pts, float(min_distance), float(max_distance))
    _nonempty(kept, f"crop_range(min_distance={min_distance}, max_distance={max_distance})")
    return _filtered(pts, kept)


def crop_box(points: FloatArray, min_corner: Any, max_corner: Any) -> Filtered:
    """Keep the points inside the axis-aligned box ``min_corner <= p <= max_corner`` (per axis,
    inclusive; ``±inf`` leaves an axis open). Raises ``ValueError`` if none is inside."""
    pts = as_points(points, "points")
    dim = int(pts.shape[1])
    lo = np.array(min_corner, dtype=np.float64)
    hi = np.array(max_corner, dtype=np.float64)
    for name, c in (("min_corner", lo), ("max_corner", hi)):
        if c.shape != (dim,):
            raise ValueError(f"{name}: expected shape ({dim},), got {c.shape}")
        if np.isnan(c).any():
            raise ValueError(f"{name}: contains NaN")
    kept = _core.crop_box(pts, lo, hi)
    _nonempty(kept, f"crop_box(min_corner={lo.tolist()}, max_corner={hi.tolist()})")
    return _filtered(pts, kept)


def remove_statistical_outliers(
    points: FloatArray, *, num_neighbors: int = DEFAULT_K, std_ratio: float = 2.0
) -> StatisticalOutliers:
    """Statistical outlier removal (Rusu et al. 2008).

    For each point, ``d_i`` = mean distance to its ``num_neighbors`` nearest *other* points; keep
    the points with ``d_i <= mean(d) + std_ratio · std(d)`` (sample standard deviation over all
    points).
    Needs ``1 <= num_neighbors < N``.
    """
    pts = as_points(points, "points")
    kk = positive_int(num_neighbors, "num_neighbors")
    if kk >= pts.shape[0]:
        raise ValueError(
            f"num_neighbors: is {kk} but needs to be < the number of points ({pts.shape[0]})"
        )
    ratio = _finite(std_ratio, "std_ratio")
    kept, mean_d, thr = _core.KdTree(pts).statistical_outliers(kk, ratio)
    _nonempty(kept, f"remove_statistical_outliers(num_neighbors={kk}, std_ratio={ratio})")
    return StatisticalOutliers(
        points=_readonly(pts[kept]),
        indices=_readonly(kept),
        num_input=int(pts.shape[0]),
        mean_distances=_readonly(mean_d),
        threshold=float(thr),
    )


def remove_radius_outliers(
    points: FloatArray, *, radius: float, min_neighbors: int = 2
) -> Filtered:
    """Keep the points with at least ``min_neighbors`` other points within ``radius``
    (inclusive)."""
    pts = as_points(points, "points")
    r = positive(radius, "radius")
    m = positive_int(min_neighbors, "min_neighbors")
    kept = _core.KdTree(pts).radius_outliers(r, m)
    _nonempty(kept, f"remove_radius_outliers(radius={r}, min_neighbors={m})")
    return _filtered(pts, kept)


def check_k(k: Any, n: int, dim: int) -> int:
    """``dim <= k <= n`` for a PCA neighbourhood of ``k`` points (the point itself included);
    errors name the public argument, ``num_neighbors``."""
    kk = positive_int(k, "num_neighbors")
    if kk < dim:
        raise ValueError(f"num_neighbors: must be >= {dim} to fit a normal in {dim}D, got {kk}")
    if kk > n:
        raise ValueError(f"num_neighbors: is {kk} but points has only {n} points")
    return kk


def as_viewpoint(viewpoint: Any, dim: int) -> FloatArray:
    """The viewpoint normals face; ``None`` is the origin (the sensor, in the sensor frame)."""
    if viewpoint is None:
        return np.zeros(dim)
    return as_matrix(viewpoint, "viewpoint", (dim,))


def check_regularization(regularization: Any, epsilon: Any) -> float:
    if regularization not in ("plane", "normalized_min_eig", "none"):
        raise ValueError(
            f"regularization: unknown {regularization!r}; "
            "expected 'plane', 'normalized_min_eig' or 'none'"
        )
    return positive(epsilon, "epsilon")


def estimate_normals(
    points: FloatArray,
    *,
    num_neighbors: int = DEFAULT_K,
    viewpoint: Any = None,
    drop_linear: bool = False,
) -> Normals:
    """Unit normals from the ``num_neighbors`` nearest neighbours (the point itself included): the
    eigenvector of the smallest eigenvalue of the neighbourhood covariance, flipped to face
    ``viewpoint`` (default: the origin). In 2D, the normal of the local line. ``drop_linear``:
    no normal where a 3D neighbourhood is linear (see :class:`Normals`; no effect in 2D)."""
    pts = as_points(points, "points")
    dim = int(pts.shape[1])
    kk = check_k(num_neighbors, int(pts.shape[0]), dim)
    vp = as_viewpoint(viewpoint, dim)
    drop = check_flag(drop_linear, "drop_linear")
    normals, _, spans, linear = _core.KdTree(pts).local_geometry(
        kk, vp, normals=True, drop_linear=drop
    )
    assert normals is not None
    if not drop:
        linear = np.zeros_like(linear)  # flagged, but their normals kept
    valid = spans & ~linear
    return Normals(
        normals=_readonly(normals),
        valid=_readonly(valid),
        num_invalid=int((~valid).sum()),
        num_neighbors=kk,
        viewpoint=_readonly(vp),
        num_linear=int(linear.sum()),
    )


def estimate_covariances(
    points: FloatArray,
    *,
    num_neighbors: int = DEFAULT_K,
    regularization: Regularization = "plane",
    epsilon: float = 1e-3,
) -> Covariances:
    """Per-point covariances from the ``num_neighbors`` nearest neighbours, regularised as GICP
    needs (see :class:`Covariances`)."""
    pts = as_points(points, "points")
    dim = int(pts.shape[1])
    kk = check_k(num_neighbors, int(pts.shape[0]), dim)
    eps = check_regularization(regularization, epsilon)
    _, covs, valid, _ = _core.KdTree(pts).local_geometry(
        kk, np.zeros(dim), normals=False, regularization=regularization, epsilon=eps
    )
    assert covs is not None
    return Covariances(
        covariances=_readonly(covs),
        valid=_readonly(valid),
        num_invalid=int((~valid).sum()),
        num_neighbors=kk,
        regularization=regularization,
        epsilon=eps,
    )
