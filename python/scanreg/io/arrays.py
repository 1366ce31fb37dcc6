"""Simple point formats: KITTI ``.bin``, NumPy ``.npy``/``.npz``, and CSV / XYZ text."""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._common import (
    CloudLike,
    FileFormatError,
    PathLike,
    PointCloud,
    check_writable_cloud,
    cloud_from_columns,
)

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


# --- KITTI Velodyne .bin --------------------------------------------------------------------
def read_kitti_bin(path: PathLike) -> PointCloud:
    """Read a KITTI Velodyne scan: little-endian float32 records ``x y z reflectance``.

    Returns a cloud with ``points`` (N, 3) in the Velodyne frame (metres) and ``intensity``
    (reflectance in [0, 1]).
    """
    p = Path(path)
    raw = p.read_bytes()
    if not raw:
        raise FileFormatError(p, "empty file")
    if len(raw) % 16:
        raise FileFormatError(
            p, f"size {len(raw)} bytes is not a multiple of 16 (float32 x y z reflectance)"
        )
    table = np.frombuffer(raw, dtype="<f4").reshape(-1, 4)
    return PointCloud(points=table[:, :3], intensity=table[:, 3])


def write_kitti_bin(path: PathLike, cloud: CloudLike) -> None:
    """Write ``x y z intensity`` as float32 records (intensity 0 when the cloud has none)."""
    cloud = check_writable_cloud(cloud, "KITTI .bin")
    table = np.zeros((len(cloud), 4), dtype="<f4")
    table[:, :3] = cloud.points
    if cloud.intensity is not None:
        table[:, 3] = cloud.intensity
    Path(path).write_bytes(table.tobytes())


# --- NumPy ----------------------------------------------------------------------------------
def _cloud_from_array(path: Path, arr: NDArray[Any]) -> PointCloud:
    if arr.dtype.names:
        if arr.ndim != 1:
            raise FileFormatError(path, f"structured array must be 1-D, got shape {arr.shape}")
        columns = {name: np.asarray(arr[name]) for name in arr.dtype.names}
        return cloud_from_columns(path, columns, min_dim=2)
    if arr.dtype.kind not in "fiu":
        raise FileFormatError(path, f"expected a numeric array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] not in (2, 3, 4):
        raise FileFormatError(
            path, f"expected shape (N, 2), (N, 3) or (N, 4) [x y z intensity], got {arr.shape}"
        )
    if arr.shape[1] == 4:
        return PointCloud(points=arr[:, :3], intensity=arr[:, 3])
    return PointCloud(points=arr)


def _load(path: Path) -> Any:
    """``np.load`` from an in-memory copy (no file handle outlives the call)."""
    try:
        return np.load(io.BytesIO(path.read_bytes()), allow_pickle=False)
    except OSError:
        raise
    except Exception as exc:  # numpy's header parser raises many types on corrupt input
        raise FileFormatError(path, f"cannot load: {type(exc).__name__}: {exc}") from None


def read_npy(path: PathLike) -> PointCloud:
    """Read an ``.npy`` array: ``(N, 2)``, ``(N, 3)``, ``(N, 4)`` (x y z intensity) or a
    structured array with fields x, y, [z] and any others (intensity, ring, t, …)."""
    p = Path(path)
    arr = _load(p)
    if not isinstance(arr, np.ndarray):
        raise FileFormatError(p, "not an .npy array")
    return _cloud_from_array(p, arr)


def read_npz(path: PathLike) -> PointCloud:
    """Read an ``.npz`` archive with a ``points`` array (N, 2|3) and optional per-point arrays
    (``intensity``, ``ring``, ``time``, others kept in ``fields``)."""
    p = Path(path)
    archive = _load(p)
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise FileFormatError(p, "not an .npz archive")
    with archive:
        try:
            arrays = {key: archive[key] for key in archive.files}
        except Exception as exc:  # corrupt members: zip, CRC or npy header errors
            raise FileFormatError(p, f"cannot load: {type(exc).__name__}: {exc}") from None
    if "points" not in arrays:
        raise FileFormatError(p, f"no 'points' array (arrays: {', '.join(arrays) or 'none'})")
    points = arrays.pop("points")
    if points.ndim != 2 or points.shape[1] not in (2, 3) or points.dtype.kind not in "fiu":
        raise FileFormatError(p, f"'points' must be a numeric (N, 3) array, got {points.shape}")
    columns: dict[str, NDArray[Any]] = {
        a: points[:, i] for i, a in enumerate("xyz"[: points.shape[1]])
    }
    for key, value in arrays.items():
        if value.ndim == 0 or value.shape[0] != points.shape[0] or value.dtype.kind not in "fiub":
            raise FileFormatError(p, f"array {key!r} is not one numeric value per point")
        columns[key] = value
    return cloud_from_columns(p, columns, min_dim=2)


def write_npy(path: PathLike, cloud: CloudLike) -> None:
    """Write the points as a float64 ``(N, D)`` array — or, if the cloud has per-point fields,
    as a structured array with fields x, y, [z], intensity, ring, time, … (float64; ring int64)."""
    cloud = check_writable_cloud(cloud, "npy", dim3=False)
    extra = cloud.named_fields()
    if not extra:
        np.save(path, cloud.points, allow_pickle=False)
        return
    if any(a.ndim != 1 for a in extra.values()):
        raise ValueError("cloud: .npy stores scalar fields only; use .npz for (N, k) fields")
    axes = "xyz"[: cloud.dim]
    dtype = [(a, "<f8") for a in axes] + [(k, v.dtype.str) for k, v in extra.items()]
    recs = np.zeros(len(cloud), dtype=dtype)
    for i, a in enumerate(axes):
        recs[a] = cloud.points[:, i]
    for k, v in extra.items():
        recs[k] = v
    np.save(path, recs, allow_pickle=False)


def write_npz(path: PathLike, cloud: CloudLike) -> None:
    """Write ``points`` and every per-point field as arrays of an uncompressed ``.npz``."""
    cloud = check_writable_cloud(cloud, "npz", dim3=False)
    arrays: dict[str, Any] = {"points": cloud.points, **cloud.named_fields()}
    with Path(path).open("wb") as fh:
        np.savez(fh, allow_pickle=False, **arrays)


# --- text: CSV and XYZ ----------------------------------------------------------------------
def _split(line: str, comma: bool) -> list[str]:
    return [w.strip() for w in line.split(",")] if comma else line.split()


def read_text(path: PathLike) -> PointCloud:
    """Read points from CSV (``.csv``: comma separated) or XYZ/TXT (whitespace separated) text.

    A first line of names (``x,y,z,intensity`` or ``# x y z intensity``) names the columns;
    without one the columns are x y [z] [intensity] and any further ones ``column_<k>``.
    Other ``#`` / ``//`` lines are comments.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(p, "not a text file (invalid UTF-8)") from None
    if not text.strip():
        raise FileFormatError(p, "empty file")
    comma = p.suffix.lower() == ".csv"
    names: list[str] | None = None
    rows: list[list[str]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        is_comment = stripped.startswith(("#", "//"))
        if not rows and names is None:
            words = [w.lower() for w in _split(stripped.lstrip("#/ "), comma)]
            if {"x", "y"} <= set(words) and all(_NAME.match(w) for w in words):
                names = [
                    w if w in ("x", "y", "z") else o
                    for w, o in zip(words, _split(stripped.lstrip("#/ "), comma), strict=True)
                ]
                continue
        if is_comment:
            continue
        rows.append(_split(stripped, comma))
        if len(rows[-1]) != len(rows[0]):
            raise FileFormatError(
                p, f"line {number}: {len(rows[-1])} values, previous lines have {len(rows[0])}"
            )
    width = len(rows[0]) if rows else (len(names) if names else 3)
    try:
        table = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    except ValueError as exc:
        raise FileFormatError(p, f"bad number: {exc}") from None
    if names is None:
        if width < 2:
            raise FileFormatError(p, f"need at least 2 columns (x y), got {width}")
        names = ["x", "y", "z", "intensity"][:width] + [f"column_{k}" for k in range(4, width)]
    if len(names) != width:
        raise FileFormatError(p, f"header names {len(names)} columns, data has {width}")
    if len(set(names)) != len(names):
        raise FileFormatError(p, "header repeats a column name")
    columns = {name: table[:, i] for i, name in enumerate(names)}
    return cloud_from_columns(p, columns, min_dim=2)


def _write_text(path: PathLike, cloud: PointCloud, sep: str, header_prefix: str) -> None:
    fields = cloud.named_fields()
    if any(a.ndim != 1 for a in fields.values()):
        raise ValueError("cloud: text formats store scalar fields only; use .npz")
    names = list("xyz"[: cloud.dim]) + list(fields)
    cols = [cloud.points[:, i] for i in range(cloud.dim)] + list(fields.values())
    lines = [header_prefix + sep.join(names)]
    lines += [
        sep.join(str(int(c[i])) if c.dtype.kind == "i" else repr(float(c[i])) for c in cols)
        for i in range(len(cloud))
    ]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_csv(path: PathLike, cloud: CloudLike) -> None:
    """Write a header line ``x,y,z,<fields>`` and one comma-separated line per point."""
    _write_text(path, check_writable_cloud(cloud, "CSV", dim3=False), ",", "")


def write_xyz(path: PathLike, cloud: CloudLike) -> None:
    """Write a comment header ``# x y z <fields>`` and one space-separated line per point."""
    _write_text(path, check_writable_cloud(cloud, "XYZ", dim3=False), " ", "# ")
