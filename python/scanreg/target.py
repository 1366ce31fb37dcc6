"""A prepared registration target: the neighbour index, normals and covariances, built once.

``prepare(points)`` is the expensive part of matching against a fixed cloud (a map, or the
target of many registrations from different initial guesses); the result is immutable, so one
``PreparedTarget`` can be shared by many threads. Queries release the GIL.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import _core, budget
from ._validate import FloatArray, as_points, build, check_flag
from ._validate import readonly as _readonly
from .correlative import CorrelativeGrid, prepare_correlative
from .degeneracy import normal_noise
from .preprocess import (
    DEFAULT_K,
    BoolArray,
    IndexArray,
    Regularization,
    as_viewpoint,
    check_k,
    check_regularization,
    positive_int,
)


def _gate(value: Any, name: str) -> float:
    v = float(value)
    if math.isnan(v) or v < 0:
        raise ValueError(f"{name}: must be >= 0 (inf for no limit), got {value}")
    return v


@dataclass(frozen=True)
class Nearest:
    """Nearest target point of each query point, within a gate.

    ``indices[i] == -1`` and ``squared_distances[i] == inf`` where query ``i`` has no target
    point within the gate.
    """

    #: ``(M,)`` target row of the nearest point, or -1.
    indices: IndexArray
    #: ``(M,)`` squared Euclidean distance (units²), or inf.
    squared_distances: FloatArray

    @property
    def found(self) -> BoolArray:
        """``(M,)`` whether a target point was within the gate."""
        out: BoolArray = self.indices >= 0
        return out

    @property
    def num_found(self) -> int:
        return int((self.indices >= 0).sum())


@dataclass(frozen=True)
class Neighbors:
    """``num_neighbors`` nearest target points of each query point, each row sorted by
    (distance, index)."""

    #: ``(M, num_neighbors)`` target rows.
    indices: NDArray[np.int64]
    #: ``(M, num_neighbors)`` squared distances, non-decreasing along each row.
    squared_distances: FloatArray


@dataclass(frozen=True)
class RadiusNeighbors:
    """All target points within a radius, in compressed rows: the neighbours of query ``i`` are
    ``indices[offsets[i]:offsets[i+1]]``, sorted by (distance, index)."""

    offsets: IndexArray
    indices: IndexArray
    squared_distances: FloatArray

    def row(self, i: int) -> IndexArray:
        """Target rows within the radius of query ``i``."""
        out: IndexArray = self.indices[self.offsets[i] : self.offsets[i + 1]]
        return out


def median_spacing(index: _core.KdTree, points: FloatArray) -> float:
    """Median distance from each of ``points`` (the points ``index`` holds) to its nearest
    other point; NaN with fewer than 2 points."""
    if len(points) < 2:
        return math.nan
    _, d2 = index.knn(points, 2)
    return float(np.sqrt(np.median(d2[:, 1])))


@dataclass(frozen=True, eq=False)
class PreparedTarget:
    """A target cloud with its k-d tree and (optionally) normals and covariances.

    Build with :func:`prepare`. Immutable and thread-safe; reuse it across registrations.
    """

    #: ``(N, D)`` the target points (a read-only copy).
    points: FloatArray
    #: The native k-d tree (``scanreg._core.KdTree``); registration code passes it to the core.
    index: _core.KdTree
    #: ``(N, D)`` unit normals facing ``viewpoint`` (zero where not ``valid`` and, with
    #: ``drop_linear``, where a 3D neighbourhood is linear), or None.
    normals: FloatArray | None
    #: ``(N, D, D)`` regularised covariances (identity where not ``valid``), or None.
    covariances: FloatArray | None
    #: ``(N,)`` whether each point's neighbourhood was non-degenerate (None if neither normals
    #: nor covariances were computed).
    valid: BoolArray | None
    #: Neighbourhood size used for normals/covariances.
    num_neighbors: int
    regularization: str
    epsilon: float
    #: ``(N,)`` 3D: whether each point's neighbourhood is linear (a sparse LiDAR's ring, a
    #: pole, an edge), so that its normal is a guess about the line; the degeneracy analysis
    #: leaves those correspondences out (:mod:`scanreg.degeneracy`). None in 2D, without
    #: normals, or when not known (normals computed elsewhere).
    linear: BoolArray | None = None

    @property
    def dim(self) -> int:
        return int(self.points.shape[1])

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @functools.cached_property
    def normal_noise(self) -> tuple[float, float]:
        """``(ε̂², ε̃²)`` of the normals (:func:`scanreg.degeneracy.normal_noise`), measured on
        first use and kept: every registration against this target reads it. Needs normals."""
        if self.normals is None:
            raise ValueError("normal_noise: this target has no normals")
        return normal_noise(self.points, self.normals, self.index)

    @functools.cached_property
    def spacing(self) -> float:
        """Median distance from a target point to its nearest other point: how densely the
        target samples its surfaces (a map merged from many scans more densely than one scan).
        Measured on first use and kept; NaN with fewer than 2 points."""
        return median_spacing(self.index, self.points)

    @functools.cached_property
    def _symmetry(self) -> float:
        """How much the walls look the same turned by 90°, 180° or 270°
        (:func:`scanreg.basin.orientation_symmetry` of the points and normals): the wrong-basin
        screen reads it on every probed result against this target. Needs normals."""
        from .basin import orientation_symmetry  # basin imports this module

        assert self.normals is not None
        return orientation_symmetry(self.points, self.normals)

    def _probe_grid(self, resolution: float) -> _core.CorrelativeGrid:
        """2D: the wrong-basin probe's coarse correlative grid of these points at
        ``resolution`` (its blur the same, :mod:`scanreg.basin`), built on first use and kept:
        every probe against this target with the same gate reads the same grid (one build was
        about half of a correlative start's cost). Not pickled: rebuilt on demand."""
        grids: dict[float, _core.CorrelativeGrid] = self.__dict__.setdefault("_grids", {})
        grid = grids.get(resolution)
        if grid is None:
            # Two threads may both build it; either grid is the same.
            grid = grids[resolution] = _core.CorrelativeGrid(self.points, resolution, resolution, 6)
        return grid

    def _start_grid(self, resolution: float) -> CorrelativeGrid:
        """2D: the correlative grid a stated start's window is searched on
        (:mod:`scanreg.start_search`), built on first use and kept for every registration
        against this target with the same gate. Not pickled: rebuilt on demand."""
        grids: dict[float, CorrelativeGrid] = self.__dict__.setdefault("_start_grids", {})
        grid = grids.get(resolution)
        if grid is None:
            grid = grids[resolution] = prepare_correlative(self.points, resolution=resolution)
        return grid

    def _sample_spacing(self) -> NDArray[np.float64]:
        """Each point's distance to its nearest other point (how finely the target samples its
        surface there; :mod:`scanreg.pinned`), found by one search of its points on first use
        and kept. Not pickled: recomputed on demand."""
        spacing: NDArray[np.float64] | None = self.__dict__.get("_spacing")
        if spacing is None:
            _, d2 = self.index.knn(self.points, 2)  # the first is the point itself
            nearest = np.asarray(d2, dtype=np.float64).reshape(len(self.points), -1)[:, -1]
            spacing = self.__dict__["_spacing"] = np.sqrt(nearest)
        return spacing

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_grids", None)  # the core's grids do not pickle; rebuilt when read
        state.pop("_start_grids", None)
        state.pop("_spacing", None)
        return state

    def nearest(self, query_points: FloatArray, max_distance: float = math.inf) -> Nearest:
        """Nearest target point of each query point within ``max_distance`` (not squared;
        inclusive). Exact; ties go to a fixed, reproducible point."""
        q = as_points(query_points, "query_points", dim=self.dim, min_points=0)
        idx, d2 = self.index.nearest(q, _gate(max_distance, "max_distance"))
        return Nearest(indices=_readonly(idx), squared_distances=_readonly(d2))

    def knn(self, query_points: FloatArray, num_neighbors: int) -> Neighbors:
        """The ``num_neighbors`` nearest target points of each query point
        (``1 <= num_neighbors <= N``)."""
        q = as_points(query_points, "query_points", dim=self.dim, min_points=0)
        kk = positive_int(num_neighbors, "num_neighbors")
        if kk > len(self):
            raise ValueError(f"num_neighbors: is {kk} but the target has only {len(self)} points")
        idx, d2 = self.index.knn(q, kk)
        return Neighbors(indices=_readonly(idx), squared_distances=_readonly(d2))

    def radius(self, query_points: FloatArray, radius: float) -> RadiusNeighbors:
        """All target points within ``radius`` (inclusive) of each query point."""
        q = as_points(query_points, "query_points", dim=self.dim, min_points=0)
        r = float(radius)
        if not math.isfinite(r) or r < 0:
            raise ValueError(f"radius: must be finite and >= 0, got {radius}")
        off, idx, d2 = self.index.radius(q, r)
        return RadiusNeighbors(
            offsets=_readonly(off), indices=_readonly(idx), squared_distances=_readonly(d2)
        )


def prepare(
    points: FloatArray,
    *,
    normals: bool = True,
    covariances: bool = False,
    num_neighbors: int = DEFAULT_K,
    viewpoint: Any = None,
    regularization: Regularization = "plane",
    epsilon: float = 1e-3,
    drop_linear: bool = False,
) -> PreparedTarget:
    """Build a reusable registration target.

    Parameters
    ----------
    points : (N, 2) or (N, 3) float64, N >= 1
        The target cloud (already downsampled as wanted; it is copied).
    normals : bool
        Compute unit normals (point-to-plane / point-to-line), facing ``viewpoint``.
    covariances : bool
        Compute GICP covariances, regularised by ``regularization`` / ``epsilon``
        (see :class:`scanreg.preprocess.Covariances`).
    num_neighbors : int
        Neighbourhood size for normals and covariances (the point itself included),
        ``D <= num_neighbors <= N``.
    viewpoint : (D,) array or None
        Normals face this point; default the origin (the sensor, for a scan in its own frame).
    drop_linear : bool
        In 3D, no normal (zero: the point never corresponds under point-to-plane) where the
        neighbourhood is linear — a LiDAR ring, a pole, an edge — whose normal the noise picks
        (see :class:`scanreg.preprocess.Normals`: it removes a bias of sparse ring scans in
        simulation, and costs rotation accuracy on a real pair, hence off). Covariances are
        unaffected.
    """
    pts = as_points(points, "points", finite=False)  # the k-d tree's build refuses NaN/inf
    if budget.LIMIT is not None:
        parts = ("index",) + ("normals",) * bool(normals) + ("covariances",) * bool(covariances)
        budget.check("prepare: points", len(pts), parts)
    dim = int(pts.shape[1])
    index = _core.KdTree(pts)
    kk = positive_int(num_neighbors, "num_neighbors")
    nrm = cov = valid = linear = None
    noise = None
    spacing = None
    eps = check_regularization(regularization, epsilon)
    if normals or covariances:
        kk = check_k(kk, int(pts.shape[0]), dim)
        vp = as_viewpoint(viewpoint, dim)
        # The normals' noise and, in 2D, the points' spacing (what every registration's analysis
        # reads) from the same neighbour searches, instead of a second search on first use.
        nrm, cov, valid, linear, noise, spacing = index.local_geometry_noise(
            kk,
            vp,
            normals=bool(normals),
            regularization=regularization if covariances else None,
            epsilon=eps,
            drop_linear=check_flag(drop_linear, "drop_linear"),
        )
        if nrm is None or dim != 3:
            linear = None
        for a in (nrm, cov, valid, linear):
            if a is not None:
                a.setflags(write=False)
    target = build(
        PreparedTarget,
        {
            "points": index.points,  # a fresh read-only copy
            "index": index,
            "normals": nrm,
            "covariances": cov,
            "valid": valid,
            "num_neighbors": kk,
            "regularization": regularization,
            "epsilon": eps,
            "linear": linear,
        },
    )
    if nrm is not None and noise is not None:
        # Where functools.cached_property keeps its value: the first read returns it.
        target.__dict__["normal_noise"] = (float(noise[0]), float(noise[1]))
    if spacing is not None and dim == 2:  # measured in 2D only (the 2D analysis reads it)
        target.__dict__["spacing"] = float(spacing)
    return target


def prepared_from_normals(
    index: _core.KdTree,
    normals: FloatArray,
    valid: BoolArray,
    num_neighbors: int,
    normal_noise: tuple[float, float] | None = None,
    spacing: float | None = None,
) -> PreparedTarget:
    """A :class:`PreparedTarget` (normals, no covariances) from a tree and normals computed
    elsewhere — a map maintained incrementally (:class:`scanreg._core.KeyframeMap`) — with
    the defaults of :func:`prepare`; the caller vouches that row ``i`` of ``normals`` is the
    normal of ``index``'s point ``i``, and that ``normal_noise`` and ``spacing`` (when given)
    are what :attr:`PreparedTarget.normal_noise` and :attr:`PreparedTarget.spacing` would
    measure."""
    if normals.shape != (len(index), index.dim) or valid.shape != (len(index),):
        raise ValueError(
            f"normals: expected shape ({len(index)}, {index.dim}) and valid ({len(index)},), "
            f"got {normals.shape} and {valid.shape}"
        )
    target = build(
        PreparedTarget,
        {
            "points": index.points,
            "index": index,
            "normals": normals,
            "covariances": None,
            "valid": valid,
            "num_neighbors": int(num_neighbors),
            "regularization": "plane",
            "epsilon": 1e-3,
            "linear": None,
        },
    )
    if normal_noise is not None:
        # Where functools.cached_property keeps its value: the first read returns it.
        target.__dict__["normal_noise"] = (float(normal_noise[0]), float(normal_noise[1]))
    if spacing is not None:
        target.__dict__["spacing"] = float(spacing)
    return target
