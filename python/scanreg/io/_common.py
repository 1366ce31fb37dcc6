"""What every reader shares: the ``PointCloud`` result and the ``FileFormatError`` it raises."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validate import FloatArray, as_points

PathLike = str | os.PathLike[str]

#: Per-point time is stored under many names; all of them become ``PointCloud.time``.
TIME_NAMES = ("t", "time", "timestamp", "timestamps", "offset_time", "time_offset")
#: Names read as ``PointCloud.intensity``.
INTENSITY_NAMES = ("intensity", "i", "reflectance", "remission", "reflectivity")
RING_NAMES = ("ring", "laser_id", "line", "channel")


class FileFormatError(ValueError):
    """A file is corrupt, truncated or not in the format its extension claims.

    The message always starts with the file name.
    """

    def __init__(self, path: PathLike, problem: str) -> None:
        # a Path as it is: Path(Path) parses it again (8 % of a refused ROS 1 bag, by fuzz/)
        self.path = path if isinstance(path, Path) else Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def canonical_field(name: str) -> str:
    """Map a field name to ``"intensity"``, ``"ring"``, ``"time"`` or itself.

    Case-insensitive; CloudCompare's ``scalar_`` prefix is ignored (``scalar_intensity``).
    """
    low = name.lower()
    if low.startswith("scalar_"):
        low = low[len("scalar_") :]
    if low in INTENSITY_NAMES:
        return "intensity"
    if low in RING_NAMES:
        return "ring"
    if low in TIME_NAMES:
        return "time"
    return name


def _readonly(a: NDArray[Any]) -> NDArray[Any]:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def _integral(arr: NDArray[Any]) -> bool:
    """Whole numbers that an int64 holds: NaN, inf or a value past ±2⁶³ would be cast to an
    arbitrary integer (numpy's "invalid value encountered in cast"), never silently."""
    limit = 2.0**63
    return bool(
        np.isfinite(arr).all() and (arr == np.round(arr)).all() and (np.abs(arr) < limit).all()
    )


def _per_point(value: Any, name: str, n: int, dtype: type[np.generic]) -> NDArray[Any] | None:
    if value is None:
        return None
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name}: expected a numeric array, got dtype {arr.dtype}")
    if arr.ndim == 0 or arr.shape[0] != n:
        raise ValueError(f"{name}: expected one value per point ({n},...), got {arr.shape}")
    if dtype is np.int64 and arr.dtype.kind == "f" and not _integral(arr):
        raise ValueError(f"{name}: expected integer values")
    if dtype is np.int64 and arr.dtype.kind == "u" and arr.size and int(arr.max()) >= 2**63:
        raise ValueError(f"{name}: values past the int64 range")
    return _readonly(_as_float64(arr) if dtype is np.float64 else np.array(arr, dtype=dtype))


def _as_float64(arr: NDArray[Any]) -> NDArray[Any]:
    """A copy as float64. A float32 signalling NaN (damaged files have them) warns "invalid
    value encountered in cast" on the widening; it is NaN either way, kept as NaN (found by
    fuzz/: PLY intensity, KITTI .bin points)."""
    with np.errstate(invalid="ignore"):
        return np.array(arr, dtype=np.float64)


@dataclass(frozen=True)
class PointCloud:
    """A point cloud as read from (or written to) a file.

    Attributes
    ----------
    points : (N, 3) float64 — or (N, 2) for 2D text/array files
        Coordinates in the sensor frame, in the file's unit (metres for LiDAR). Read-only.
        Non-finite rows (organised clouds mark missing returns with NaN) are kept; use
        :meth:`finite` to drop them.
    intensity : (N,) float64 or None
        Intensity / reflectance as stored (no rescaling).
    ring : (N,) int64 or None
        Laser (ring) index.
    time : (N,) float64 or None
        Per-point time, read from a field named t, time, timestamp, offset_time, …, in the
        file's own unit (seconds for most drivers; nanoseconds for Ouster ``t`` / Livox
        ``offset_time``).
    fields : mapping of str to (N,) or (N, k) float64
        Every other per-point field under its file name (e.g. ``normal_x``), read-only.
    """

    points: FloatArray
    intensity: FloatArray | None = None
    ring: NDArray[np.int64] | None = None
    time: FloatArray | None = None
    fields: Mapping[str, FloatArray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pts: Any = self.points
        if not isinstance(pts, np.ndarray):
            if pts is None or isinstance(pts, (str, bytes, Mapping)):
                raise TypeError(f"points: expected an (N, 3) array, got {type(pts).__name__}")
            try:  # nested lists, array-likes
                pts = np.asarray(pts)
            except (TypeError, ValueError):
                raise TypeError(
                    f"points: expected an (N, 3) array, got {type(self.points).__name__}"
                ) from None
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise ValueError(f"points: expected shape (N, 3) or (N, 2), got {pts.shape}")
        if pts.dtype.kind not in "fiu":
            raise TypeError(f"points: expected a real numeric array, got dtype {pts.dtype}")
        n = pts.shape[0]
        set_ = object.__setattr__
        set_(self, "points", _readonly(_as_float64(pts)))
        set_(self, "intensity", _per_point(self.intensity, "intensity", n, np.float64))
        set_(self, "ring", _per_point(self.ring, "ring", n, np.int64))
        set_(self, "time", _per_point(self.time, "time", n, np.float64))
        extras: dict[str, FloatArray] = {}
        for key, value in dict(self.fields).items():
            if not isinstance(key, str) or not key:
                raise TypeError(f"fields: keys must be non-empty strings, got {key!r}")
            if canonical_field(key) != key or key in ("x", "y", "z"):
                raise ValueError(f"fields: {key!r} belongs in its own attribute, not in fields")
            arr = _per_point(value, f"fields[{key!r}]", n, np.float64)
            assert arr is not None
            extras[key] = arr
        set_(self, "fields", MappingProxyType(extras))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def dim(self) -> int:
        """2 or 3."""
        return int(self.points.shape[1])

    def select(self, mask: NDArray[Any]) -> PointCloud:
        """The cloud restricted to ``points[mask]`` (a boolean mask or an index array)."""

        def take(a: NDArray[Any] | None) -> NDArray[Any] | None:
            return None if a is None else a[mask]

        return PointCloud(
            points=self.points[mask],
            intensity=take(self.intensity),
            ring=take(self.ring),
            time=take(self.time),
            fields={k: v[mask] for k, v in self.fields.items()},
        )

    def finite(self) -> PointCloud:
        """The cloud without points that have a NaN or infinite coordinate."""
        keep: NDArray[np.bool_] = np.asarray(np.isfinite(self.points).all(axis=1))
        return self.select(keep)

    def named_fields(self) -> dict[str, NDArray[Any]]:
        """Every per-point field other than the coordinates, by canonical name."""
        out: dict[str, NDArray[Any]] = {}
        if self.intensity is not None:
            out["intensity"] = self.intensity
        if self.ring is not None:
            out["ring"] = self.ring
        if self.time is not None:
            out["time"] = self.time
        out.update(self.fields)
        return out


def cloud_from_columns(
    path: PathLike,
    columns: Mapping[str, NDArray[Any]],
    *,
    min_dim: int = 3,
) -> PointCloud:
    """Assemble a cloud from named per-point columns (``x``, ``y``, [``z``], others).

    Names are mapped with :func:`canonical_field`; a column that maps to a name already taken
    stays in ``fields`` under its own name.
    """
    names = list(columns)
    axes = ["x", "y", "z"] if "z" in columns or min_dim == 3 else ["x", "y"]
    missing = [a for a in axes if a not in columns]
    if missing:
        raise FileFormatError(path, f"no {'/'.join(missing)} field (fields: {' '.join(names)})")
    for a in axes:
        if columns[a].ndim != 1:
            raise FileFormatError(path, f"field {a} must have one value per point")
    # A float32 signalling NaN in a file raises numpy's "invalid value" on the cast; it is
    # NaN either way (kept, like any NaN point; PointCloud.finite() drops them).
    with np.errstate(invalid="ignore"):
        points = np.stack([np.asarray(columns[a], dtype=np.float64) for a in axes], axis=1)
    named: dict[str, NDArray[Any]] = {}
    extras: dict[str, NDArray[Any]] = {}
    for name in names:
        if name in axes:
            continue
        canon = canonical_field(name)
        if canon in ("intensity", "ring", "time") and canon not in named:
            named[canon] = columns[name]
        else:
            key = name if canonical_field(name) == name else f"{name}_"
            extras[key] = columns[name]
    if "ring" in named:
        ring = np.asarray(named["ring"])
        if ring.dtype.kind == "f" and not _integral(ring):
            raise FileFormatError(path, "ring field holds non-integer values")
    return PointCloud(
        points=points,
        intensity=named.get("intensity"),
        ring=named.get("ring"),
        time=named.get("time"),
        fields=extras,
    )


#: What a writer takes: a :class:`PointCloud`, or the points alone as an ``(N, 3)`` or
#: ``(N, 2)`` array-like (numpy array of any real dtype, nested lists).
CloudLike = PointCloud | ArrayLike


def as_cloud(cloud: Any, name: str = "cloud") -> PointCloud:
    """``cloud`` as a :class:`PointCloud`: itself, or one made of an ``(N, 3)`` / ``(N, 2)``
    array-like of points (NaN kept: a writer that cannot store it says so)."""
    if isinstance(cloud, PointCloud):
        return cloud
    if cloud is None or isinstance(cloud, (str, bytes, os.PathLike, Mapping)):
        raise TypeError(
            f"{name}: expected a scanreg.io.PointCloud or an (N, 3) array of points, "
            f"got {type(cloud).__name__}"
        )
    return PointCloud(points=as_points(cloud, name, min_points=0, finite=False))


def check_writable_cloud(cloud: Any, fmt: str, *, dim3: bool = True) -> PointCloud:
    """The cloud a writer of ``fmt`` was given (:func:`as_cloud`), 3D unless ``dim3`` is
    False."""
    checked = as_cloud(cloud)
    if dim3 and checked.dim != 3:
        raise ValueError(
            f"cloud: {fmt} stores 3D points, got shape {checked.points.shape} "
            "(add a z column, e.g. np.c_[xy, np.zeros(len(xy))])"
        )
    return checked
