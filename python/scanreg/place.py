"""Place recognition for 3D loop-closure candidates: Scan Context (Kim & Kim, IROS 2018).

A keyframe's cloud, in its sensor frame (z up), is summarised by a ``num_rings × num_sectors``
polar grid of the highest point per bin (:class:`ScanContext`). A :class:`PlaceDatabase`
holds the keyframes' descriptors; :meth:`PlaceDatabase.query` shortlists the
``num_candidates`` entries nearest by ring key (each ring's mean: unchanged by yaw) and ranks
them by the Scan Context distance — the mean cosine distance of sector columns, minimised over
every column shift — which also estimates the yaw between the two scans. Descriptors and the
search run in the Rust core.

A candidate is only a hypothesis: verify it by registration before adding a loop edge (a
scene with repeated structure gives confident wrong candidates; see
:func:`scanreg.simulate.block_loop` with ``symmetry=4``)::

    from scanreg import place
    db = place.PlaceDatabase()                       # 20 rings × 60 sectors, 80 m
    for k, points in enumerate(keyframe_clouds):     # (N, 3), sensor frame, z up
        desc = db.describe(points)
        for c in db.query(desc, top_k=3, exclude_recent=50, max_distance=0.3):
            guess = c.initial_guess                   # SE3 yaw of T_candidate_query
            ...  # register points to keyframe c.key's cloud from `guess`, judge the result
        db.add(desc, key=k)

Distances are in ``[0, 2]`` (0: the same up to the heights' scale); the paper accepts loops
below about 0.1–0.2, after verification.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, as_points
from .transform import SE3

__all__ = ["PlaceCandidate", "PlaceDatabase", "ScanContext"]


def _count(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: expected an int, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name}: must be >= {minimum}, got {value}")
    return int(value)


def _real(value: Any, name: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise TypeError(f"{name}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or (positive and v <= 0):
        raise ValueError(f"{name}: must be finite{' and > 0' if positive else ''}, got {value}")
    return v


@dataclass(frozen=True, eq=False)
class ScanContext:
    """The Scan Context of one cloud (build with :meth:`from_points`)."""

    #: ``(num_rings, num_sectors)`` read-only: per polar bin, the highest ``z + height_offset``
    #: of its points (0 if empty). Ring ``i`` spans ``[i, i+1) · max_radius / num_rings`` m;
    #: sector ``j`` azimuths ``[-π + jΔ, -π + (j+1)Δ)``, ``Δ = 2π / num_sectors``.
    descriptor: FloatArray
    #: ``(num_rings,)`` each ring's mean over its sectors (yaw-invariant).
    ring_key: FloatArray
    max_radius: float
    height_offset: float

    def __post_init__(self) -> None:
        # Built by from_points the arrays are already right; a hand-made one is checked here
        # so that a malformed descriptor fails by name, not inside a query.
        desc = self.descriptor
        if not (
            isinstance(desc, np.ndarray)
            and desc.dtype == np.float64
            and desc.ndim == 2
            and desc.flags.c_contiguous
        ):
            desc = np.ascontiguousarray(np.asarray(desc, dtype=np.float64))
            if desc.ndim != 2:
                raise ValueError(f"descriptor: expected shape (rings, sectors), got {desc.shape}")
        if desc.shape[0] < 1 or desc.shape[1] < 3:
            raise ValueError(f"descriptor: need >= 1 ring and >= 3 sectors, got {desc.shape}")
        if not (np.isfinite(desc).all() and (desc >= 0).all()):
            raise ValueError("descriptor: values must be finite and >= 0")
        key = np.asarray(self.ring_key, dtype=np.float64)
        if key.shape != (desc.shape[0],):
            raise ValueError(f"ring_key: expected shape ({desc.shape[0]},), got {key.shape}")
        for arr, field in ((desc, "descriptor"), (key, "ring_key")):
            if arr.flags.writeable:
                arr = arr.copy()
                arr.setflags(write=False)
            object.__setattr__(self, field, arr)
        object.__setattr__(self, "max_radius", _real(self.max_radius, "max_radius", positive=True))
        object.__setattr__(self, "height_offset", _real(self.height_offset, "height_offset"))

    @classmethod
    def from_points(
        cls,
        points: Any,
        *,
        num_rings: int = 20,
        num_sectors: int = 60,
        max_radius: float = 80.0,
        height_offset: float = 2.0,
    ) -> ScanContext:
        """Describe ``points`` ``(N, 3)`` float64, in the sensor frame with z up (m).

        ``height_offset`` (m) is added to z so the ground under a sensor that high registers
        as a low return; points at or below ``-height_offset`` count as empty, points at
        ``hypot(x, y) >= max_radius`` are left out. Defaults are the paper's (20 × 60, 80 m).
        Raises ValueError naming ``points`` for an empty cloud or a NaN/inf coordinate.
        """
        pts = as_points(points, "points", dim=3)
        rings = _count(num_rings, "num_rings", 1)
        sectors = _count(num_sectors, "num_sectors", 3)
        radius = _real(max_radius, "max_radius", positive=True)
        offset = _real(height_offset, "height_offset")
        desc, key = _core.scan_context(pts, rings, sectors, radius, offset)
        desc.setflags(write=False)
        key.setflags(write=False)
        return cls(desc, key, radius, offset)

    @property
    def num_rings(self) -> int:
        return int(self.descriptor.shape[0])

    @property
    def num_sectors(self) -> int:
        return int(self.descriptor.shape[1])

    @property
    def sector_angle(self) -> float:
        """Azimuthal width of a sector (rad): the yaw's resolution before refinement."""
        return 2.0 * math.pi / self.num_sectors

    @property
    def occupancy(self) -> float:
        """Fraction of bins with a return (a nearly empty descriptor matches poorly)."""
        return float(np.count_nonzero(self.descriptor)) / self.descriptor.size

    def distance(self, candidate: ScanContext) -> tuple[float, float]:
        """``(distance, yaw)`` of this scan against ``candidate``: the Scan Context distance
        (``[0, 2]``; 1 when no sector has returns in both) and the yaw of
        ``T_candidate_this`` (rad, in ``(-π, π]``; whole sectors refined by a parabola)."""
        _check_layout(candidate, self, "candidate")
        dist, yaw, _ = _core.scan_context_distance(self.descriptor, candidate.descriptor)
        return dist, yaw


def _check_layout(desc: Any, like: ScanContext, name: str) -> ScanContext:
    if not isinstance(desc, ScanContext):
        raise TypeError(f"{name}: expected a ScanContext, got {type(desc).__name__}")
    if desc.descriptor.shape != like.descriptor.shape or (desc.max_radius, desc.height_offset) != (
        like.max_radius,
        like.height_offset,
    ):
        raise ValueError(
            f"{name}: layout {desc.descriptor.shape}, max_radius {desc.max_radius}, "
            f"height_offset {desc.height_offset} differs from {like.descriptor.shape}, "
            f"{like.max_radius}, {like.height_offset}"
        )
    return desc


@dataclass(frozen=True)
class PlaceCandidate:
    """One retrieved place: the database entry ``key`` may be where the query was taken."""

    #: The key the entry was added with.
    key: Hashable
    #: Insertion index in the database.
    index: int
    #: Scan Context distance (lower is more alike; see :meth:`ScanContext.distance`).
    distance: float
    #: Estimated yaw of ``T_candidate_query`` (rad).
    yaw: float
    #: Distance of the ring keys (the shortlist's criterion).
    ring_key_distance: float

    @property
    def initial_guess(self) -> SE3:
        """``T_candidate_query`` as far as the descriptor knows it: the yaw, no translation —
        a starting point for registering the query cloud to the candidate's."""
        return SE3.from_vector([0.0, 0.0, 0.0, 0.0, 0.0, self.yaw])


class PlaceDatabase:
    """Keyframe descriptors in insertion order, queried for the places a new scan may revisit.

    All descriptors share one layout (``num_rings × num_sectors``, ``max_radius``,
    ``height_offset``); :meth:`describe` builds them with it. Not for concurrent ``add`` from
    several threads with ``query`` relying on a fixed ``len``; otherwise thread-safe.
    """

    def __init__(
        self,
        *,
        num_rings: int = 20,
        num_sectors: int = 60,
        max_radius: float = 80.0,
        height_offset: float = 2.0,
    ) -> None:
        self.num_rings = _count(num_rings, "num_rings", 1)
        self.num_sectors = _count(num_sectors, "num_sectors", 3)
        self.max_radius = _real(max_radius, "max_radius", positive=True)
        self.height_offset = _real(height_offset, "height_offset")
        self._index = _core.ScanContextIndex(self.num_rings, self.num_sectors)
        self._keys: list[Hashable] = []
        self._layout = ScanContext(
            np.zeros((self.num_rings, self.num_sectors)),
            np.zeros(self.num_rings),
            self.max_radius,
            self.height_offset,
        )

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def keys(self) -> tuple[Hashable, ...]:
        """The keys in insertion order."""
        return tuple(self._keys)

    def describe(self, points: Any) -> ScanContext:
        """:meth:`ScanContext.from_points` with this database's layout."""
        return ScanContext.from_points(
            points,
            num_rings=self.num_rings,
            num_sectors=self.num_sectors,
            max_radius=self.max_radius,
            height_offset=self.height_offset,
        )

    def add(self, descriptor: ScanContext, key: Hashable) -> int:
        """Append ``descriptor`` under ``key`` (any hashable: a keyframe index, a stamp);
        returns its insertion index."""
        _check_layout(descriptor, self._layout, "descriptor")
        if not isinstance(key, Hashable):
            raise TypeError(f"key: expected a hashable value, got {type(key).__name__}")
        index = int(self._index.add(descriptor.descriptor))
        self._keys.append(key)
        return index

    def query(
        self,
        descriptor: ScanContext,
        top_k: int = 1,
        *,
        exclude_recent: int = 0,
        num_candidates: int = 10,
        max_distance: float | None = None,
    ) -> tuple[PlaceCandidate, ...]:
        """The ``top_k`` best places for ``descriptor``, best (lowest distance) first.

        ``exclude_recent``: ignore the most recently added entries (the scans just before
        this one always look alike; exclude them by count, e.g. the last 30 s of keyframes).
        ``num_candidates``: how many entries the ring key shortlists for the full comparison
        (the paper's 10). ``max_distance``: drop candidates farther than this. Fewer than
        ``top_k`` come back when fewer qualify (none from an empty database).
        """
        _check_layout(descriptor, self._layout, "descriptor")
        k = _count(top_k, "top_k", 1)
        recent = _count(exclude_recent, "exclude_recent", 0)
        shortlist = _count(num_candidates, "num_candidates", 1)
        limit = math.inf if max_distance is None else _real(max_distance, "max_distance")
        idx, dist, yaw, key_dist = self._index.query(
            descriptor.descriptor, shortlist, k, recent, limit
        )
        return tuple(
            PlaceCandidate(
                key=self._keys[int(i)],
                index=int(i),
                distance=float(d),
                yaw=float(y),
                ring_key_distance=float(r),
            )
            for i, d, y, r in zip(idx, dist, yaw, key_dist, strict=True)
        )
