"""A local map for LiDAR odometry: a bounded voxel hash of points, updated in place.

Each voxel of side ``voxel_size`` keeps at most ``max_points_per_voxel`` points, none closer
than ``min_spacing`` to another of its voxel (the first, well-spread observations win); voxels
farther than a range from the sensor are evicted. Inserting a frame touches only its voxels, so
the map is never rebuilt — the structure KISS-ICP made standard, here with per-point normals or
covariances stored beside the points, so point-to-plane and GICP can match against it.

:func:`scanreg.register` accepts a :class:`LocalMap` as its target. Thread-safe: registrations
read it concurrently; an update waits for them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from . import _core, budget
from ._validate import FloatArray, as_points, readonly
from .preprocess import BoolArray, positive_int

Attributes = Literal["none", "normals", "covariances", "voxel_covariances"]
ATTRIBUTES: tuple[str, ...] = ("none", "normals", "covariances", "voxel_covariances")


@dataclass(frozen=True)
class MapNearest:
    """Nearest map point of each query within a gate."""

    #: ``(N, D)`` the nearest map point (rows of NaN where none within the gate).
    points: FloatArray
    #: ``(N,)`` squared distances (``inf`` where none).
    squared_distances: FloatArray

    @property
    def found(self) -> BoolArray:
        out: BoolArray = np.isfinite(self.squared_distances)
        return out


class LocalMap:
    """A voxel-hash point map (see the module docstring).

    Parameters
    ----------
    dim
        2 or 3.
    voxel_size
        Voxel side (units of the points), > 0.
    max_points_per_voxel
        Capacity of a voxel, 1..1024.
    min_spacing
        A new point closer than this to a point of its voxel is dropped; default
        ``voxel_size / sqrt(max_points_per_voxel)`` (the spacing at which a full voxel's points
        would tile one face).
    attributes
        What each point carries: ``"none"`` (point-to-point), ``"normals"`` (point-to-plane /
        line) or ``"covariances"`` (GICP); :meth:`insert` then requires exactly those. Or
        ``"voxel_covariances"`` (GICP): the map computes them itself, each voxel's points'
        covariance regularised as a plane and shared by its points (as in VGICP), refreshed for
        the voxels an insertion touches — no per-point neighbour search.
    """

    def __init__(
        self,
        dim: int = 3,
        voxel_size: float = 1.0,
        max_points_per_voxel: int = 20,
        min_spacing: float | None = None,
        attributes: Attributes = "none",
    ) -> None:
        if dim not in (2, 3) or isinstance(dim, bool):
            raise ValueError(f"dim: must be 2 or 3, got {dim!r}")
        cap = positive_int(max_points_per_voxel, "max_points_per_voxel")
        v = float(voxel_size)
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"voxel_size: must be finite and > 0, got {voxel_size!r}")
        spacing = v / math.sqrt(cap) if min_spacing is None else float(min_spacing)
        if attributes not in ATTRIBUTES:
            raise ValueError(
                f"attributes: unknown {attributes!r}; expected one of {', '.join(ATTRIBUTES)}"
            )
        self._native = _core.LocalMap(dim, v, cap, spacing, attributes)
        self.min_spacing = spacing

    @property
    def native(self) -> _core.LocalMap:
        """The core object (what :func:`scanreg.register` hands to the core)."""
        return self._native

    @property
    def dim(self) -> int:
        return self._native.dim

    @property
    def voxel_size(self) -> float:
        return self._native.voxel_size

    @property
    def max_points_per_voxel(self) -> int:
        return self._native.max_points_per_voxel

    @property
    def attributes(self) -> str:
        return self._native.attributes

    @property
    def num_voxels(self) -> int:
        return self._native.num_voxels

    def __len__(self) -> int:
        return len(self._native)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        # Pickled as its settings and contents: re-inserting the points (with what they carry)
        # in the order of points() rebuilds every voxel with the same points in the same order
        # (they already respect the spacing and the capacity), hence the same answers.
        settings = (self.dim, self.voxel_size, self.max_points_per_voxel, self.min_spacing)
        stored = self.attributes in ("normals", "covariances")
        contents = (
            self.points(),
            self.normals() if stored else None,
            self.covariances() if self.attributes == "covariances" else None,
        )
        return (_rebuild_local_map, (*settings, self.attributes, *contents))

    def __repr__(self) -> str:
        return (
            f"LocalMap(dim={self.dim}, voxel_size={self.voxel_size}, points={len(self)}, "
            f"voxels={self.num_voxels}, attributes={self.attributes!r})"
        )

    def insert(self, points: Any, normals: Any = None, covariances: Any = None) -> int:
        """Add world-frame points (and their normals or covariances, as the map stores).
        Returns how many were kept; validates everything before changing the map."""
        pts = as_points(points, "points", dim=self.dim, min_points=0)
        if budget.LIMIT is not None:
            budget.check("LocalMap.insert: points", len(pts), ("local_map",))
        nrm = None if normals is None else as_points(normals, "normals", dim=self.dim, min_points=0)
        cov = None
        if covariances is not None:
            cov = np.ascontiguousarray(covariances, dtype=np.float64)
        return self._native.insert(pts, nrm, cov)

    def clear(self) -> None:
        """Remove every point (the settings stay)."""
        self._native = _core.LocalMap(
            self.dim, self.voxel_size, self.max_points_per_voxel, self.min_spacing, self.attributes
        )

    def remove_far(self, center: Any, max_distance: float) -> int:
        """Evict every voxel whose first point is farther than ``max_distance`` from
        ``center``; returns the number of points removed."""
        c = np.ascontiguousarray(center, dtype=np.float64).reshape(-1)
        return self._native.remove_far(c, float(max_distance))

    def points(self) -> FloatArray:
        """``(N, D)`` a copy of the map's points, in a deterministic order."""
        out: FloatArray = readonly(self._native.points())
        return out

    def normals(self) -> FloatArray | None:
        """Normals in the order of :meth:`points` (``None`` unless the map stores them)."""
        n = self._native.normals()
        return None if n is None else readonly(n)

    def covariances(self) -> FloatArray | None:
        """Covariances in the order of :meth:`points` (``None`` unless the map stores them)."""
        c = self._native.covariances()
        return None if c is None else readonly(c)

    def nearest(self, query_points: Any, max_distance: float) -> MapNearest:
        """Nearest map point of each query within ``max_distance`` (finite). Exact."""
        q = as_points(query_points, "query_points", dim=self.dim, min_points=0)
        pts, d2 = self._native.nearest(q, float(max_distance))
        return MapNearest(points=readonly(pts), squared_distances=readonly(d2))


def _rebuild_local_map(
    dim: int,
    voxel_size: float,
    max_points_per_voxel: int,
    min_spacing: float,
    attributes: Attributes,
    points: FloatArray,
    normals: FloatArray | None,
    covariances: FloatArray | None,
) -> LocalMap:
    out = LocalMap(dim, voxel_size, max_points_per_voxel, min_spacing, attributes)
    if len(points):
        out.insert(points, normals=normals, covariances=covariances)
    return out
