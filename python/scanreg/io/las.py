"""LAS / LAZ point clouds (ASPRS LAS 1.2–1.4) through ``laspy``, LAZ through ``lazrs``.

Needs the ``las`` extra: ``pip install 'scanreg[las]'`` (imported only when a file is read or
written).

>>> cloud = read_las("sweep.laz")                   # PointCloud: intensity, time, fields
>>> write_las("map.laz", cloud, scale=0.001, offset=(500000, 5000000, 0), crs_wkt=wkt)
>>> read_las_header("map.laz").offset, read_las_header("map.laz").crs_wkt

What crosses over
-----------------
* coordinates: stored as ``int32`` ``X = round((x - offset) / scale)`` per axis, so a value on
  the grid (a multiple of ``scale`` from ``offset``) reads back as the same float64, and any
  other value within ``scale / 2``. The default ``offset`` is the cloud's minimum, floored to
  a whole metre, so UTM-sized coordinates (500 000, 5 000 000 m) fit at millimetre scale; a
  cloud too large for the chosen scale is refused, never wrapped.
* ``intensity``: the standard ``uint16`` field when every value is an integer in
  ``[0, 65535]``; otherwise (KITTI reflectance in ``[0, 1]``) a ``float64`` extra-bytes field
  ``reflectance``, read back as ``intensity``.
* ``time``: GPS time (``float64`` seconds), in the point formats that have it (1, 3, 5, 6–10);
  read as None when every point's is 0 (a file written without times).
  :class:`~scanreg.io.FolderSequence` makes absolute GPS times relative to the sweep's first
  point for deskewing.
* ``fields["return_number"]``, ``["number_of_returns"]``, ``["classification"]``: the standard
  fields (checked to be integers in range); ``ring`` and any other field: extra bytes.

A file whose point format or version laspy does not know raises
:class:`~scanreg.io.FileFormatError` naming it. Writes go to a temporary file in the same
folder, renamed on success: a failure never leaves a partial file.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray
from ._common import CloudLike, FileFormatError, PathLike, PointCloud, check_writable_cloud
from ._las_checks import COMPRESSION_BITS, POINT_FORMAT_BYTE, check_las_file

#: Standard integer fields taken from ``PointCloud.fields`` → (their LAS range).
STANDARD_FIELDS = {
    "return_number": (0, 15),
    "number_of_returns": (0, 15),
    "classification": (0, 255),
}
#: Point formats written with GPS time; the default is 6 (LAS 1.4, 15 returns, GPS time).
DEFAULT_POINT_FORMAT = 6
#: Default coordinate resolution (m).
DEFAULT_SCALE = 0.001
_INT32 = (-(2**31), 2**31 - 1)


def _laspy() -> Any:
    try:
        import laspy
    except ImportError:
        raise ImportError(
            "LAS/LAZ files need the 'laspy' and 'lazrs' packages: pip install 'scanreg[las]'"
        ) from None
    return laspy


def _laz_backend(laspy: Any) -> Any:
    try:
        import lazrs  # noqa: F401
    except ImportError:
        raise ImportError(
            "LAZ files need the 'lazrs' package: pip install 'scanreg[las]'"
        ) from None
    return laspy.LazBackend.Lazrs


@dataclass(frozen=True)
class LasHeaderInfo:
    """What a LAS header says about its points (see :func:`read_las_header`)."""

    version: str
    point_format: int
    point_count: int
    #: ``(3,)`` metres per integer unit and ``(3,)`` offsets (m).
    scale: FloatArray
    offset: FloatArray
    #: ``(3,)`` bounding box as the header records it.
    mins: FloatArray
    maxs: FloatArray
    #: The OGC WKT of the coordinate reference system, when the file has one.
    crs_wkt: str | None
    compressed: bool
    #: Names of the per-point dimensions (standard and extra bytes).
    dimensions: tuple[str, ...]


def _open_error(path: Path, exc: Exception) -> FileFormatError:
    """The reader's error, named: an unknown point format is read from the header itself
    (laspy's own message is the bare number)."""
    with path.open("rb") as fh:
        head = fh.read(POINT_FORMAT_BYTE + 1)
    if head[:4] == b"LASF" and len(head) > POINT_FORMAT_BYTE:
        fmt = head[POINT_FORMAT_BYTE] & ~COMPRESSION_BITS & 0xFF
        if fmt > 10:
            return FileFormatError(
                path, f"unknown LAS point format {fmt} (LAS 1.4 defines formats 0-10)"
            )
    elif head[:4] != b"LASF":
        return FileFormatError(path, "not a LAS/LAZ file (no 'LASF' signature)")
    return FileFormatError(path, f"cannot read as LAS/LAZ: {type(exc).__name__}: {exc}")


def _panic_error(path: Path, exc: BaseException) -> BaseException:
    """A Rust panic inside lazrs arrives as pyo3's ``PanicException``, a ``BaseException``
    (not an ``Exception``): named like any other refusal; anything else (KeyboardInterrupt)
    passes through."""
    if type(exc).__name__ != "PanicException":
        return exc
    return FileFormatError(path, f"cannot read as LAS/LAZ: lazrs panicked: {exc}")


def _check_exists(path: PathLike) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file")
    if p.stat().st_size == 0:
        raise FileFormatError(p, "empty file")
    check_las_file(p)
    return p


def _wkt(header: Any) -> str | None:
    for vlr in [*header.vlrs, *(getattr(header, "evlrs", None) or [])]:
        text = getattr(vlr, "string", None)
        if type(vlr).__name__ == "WktCoordinateSystemVlr" and text:
            return str(text).rstrip("\x00")
    return None


def read_las_header(path: PathLike) -> LasHeaderInfo:
    """The header of a LAS/LAZ file: version, point format, count, scale/offset, CRS."""
    laspy = _laspy()
    p = _check_exists(path)
    try:
        with laspy.open(p) as reader:
            h = reader.header
            dims = tuple(h.point_format.dimension_names)
            return LasHeaderInfo(
                version=f"{h.version.major}.{h.version.minor}",
                point_format=int(h.point_format.id),
                point_count=int(h.point_count),
                scale=np.array(h.scales, dtype=np.float64),
                offset=np.array(h.offsets, dtype=np.float64),
                mins=np.array(h.mins, dtype=np.float64),
                maxs=np.array(h.maxs, dtype=np.float64),
                crs_wkt=_wkt(h),
                compressed=bool(h.are_points_compressed),
                dimensions=dims,
            )
    except Exception as exc:  # laspy raises its own, struct, value and lazrs errors
        raise _open_error(p, exc) from None
    except BaseException as exc:
        raise _panic_error(p, exc) from None


def read_las(path: PathLike) -> PointCloud:
    """A LAS/LAZ file as a :class:`~scanreg.io.PointCloud` (see the module docstring)."""
    laspy = _laspy()
    p = _check_exists(path)
    try:
        las = laspy.read(p)
    except Exception as exc:  # laspy raises its own, struct, value and lazrs errors
        raise _open_error(p, exc) from None
    except BaseException as exc:
        raise _panic_error(p, exc) from None
    # A float field of a damaged file may hold signalling NaNs: NaN either way, read as NaN
    # (numpy warns "invalid value" on their casts and reductions; found by fuzz/).
    try:
        with np.errstate(invalid="ignore"):
            return _cloud_of(p, las)
    except FileFormatError:
        raise
    except (ValueError, KeyError, IndexError) as exc:  # laspy's, on a damaged extra-bytes VLR
        raise FileFormatError(p, f"cannot read as LAS/LAZ: {type(exc).__name__}: {exc}") from None


def _cloud_of(p: Path, las: Any) -> PointCloud:
    dims = set(las.point_format.dimension_names)
    extra = list(las.point_format.extra_dimension_names)
    points = np.column_stack(
        [np.asarray(las.x, np.float64), np.asarray(las.y, np.float64), np.asarray(las.z)]
    ).astype(np.float64)
    intensity = np.asarray(las.intensity, dtype=np.float64) if "intensity" in dims else None
    time = np.asarray(las.gps_time, dtype=np.float64) if "gps_time" in dims else None
    if time is not None and len(time) and not time.any():
        time = None  # a format with the field, written without times: zero is not a time
    ring: NDArray[Any] | None = None  # PointCloud casts it to int64
    fields: dict[str, FloatArray] = {}
    for name in STANDARD_FIELDS:
        fields[name] = np.asarray(las[name], dtype=np.float64)
    for name in extra:
        values = np.asarray(las[name], dtype=np.float64)
        if values.ndim != 1:
            continue  # multi-valued extra bytes have no PointCloud slot
        if name == "reflectance":
            intensity = values  # a float intensity that did not fit the uint16 field
        elif name == "ring":
            ring = values  # PointCloud casts it, refusing NaN or fractions by name
        else:
            fields[name] = values
    try:
        return PointCloud(points=points, intensity=intensity, ring=ring, time=time, fields=fields)
    except (ValueError, TypeError) as exc:
        raise FileFormatError(p, str(exc)) from None


def _as_triple(value: Any, name: str) -> FloatArray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: must be finite, got {value!r}")
    return arr


def _integers(values: Any, name: str, lo: int, hi: int) -> Any:
    arr = np.asarray(values, dtype=np.float64)
    if not (np.isfinite(arr).all() and (arr == np.round(arr)).all()):
        raise ValueError(f"cloud: fields[{name!r}] must hold integers for LAS")
    if arr.size and (arr.min() < lo or arr.max() > hi):
        raise ValueError(f"cloud: fields[{name!r}] must be in [{lo}, {hi}] for LAS")
    return arr


def write_las(
    path: PathLike,
    cloud: CloudLike,
    *,
    scale: float | Sequence[float] = DEFAULT_SCALE,
    offset: Sequence[float] | None = None,
    crs_wkt: str | None = None,
    point_format: int = DEFAULT_POINT_FORMAT,
    compress: bool | None = None,
) -> None:
    """Write ``cloud`` (3D) as LAS, or LAZ when ``path`` ends in ``.laz`` (or ``compress``).

    Parameters
    ----------
    scale : float or (3,), metres per integer unit
        The coordinate resolution (default 1 mm).
    offset : (3,), optional
        Subtracted before quantising; default: the cloud's minimum floored to whole metres.
        Give a fixed one (e.g. the UTM zone's false easting/northing area) to make many files
        share one grid.
    crs_wkt : str, optional
        The OGC WKT of the coordinate reference system (e.g. a UTM zone's), stored in the
        WKT VLR with the header's WKT bit set (LAS 1.4 point formats 6–10).
    point_format : int
        LAS point data record format, 0–10 (default 6).
    """
    laspy = _laspy()
    cloud = check_writable_cloud(cloud, "LAS")
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if point_format not in range(11) or isinstance(point_format, bool):
        raise ValueError(f"point_format: expected a LAS point format 0-10, got {point_format!r}")
    if crs_wkt is not None and (not isinstance(crs_wkt, str) or not crs_wkt.strip()):
        raise ValueError("crs_wkt: expected a non-empty OGC WKT string")
    if crs_wkt is not None and point_format < 6:
        raise ValueError("crs_wkt: a WKT CRS needs a LAS 1.4 point format (6-10)")
    scales = _as_triple(scale, "scale")
    if (scales <= 0).any():
        raise ValueError(f"scale: must be > 0, got {scale!r}")
    pts = cloud.points
    if not np.isfinite(pts).all():
        raise ValueError("cloud: holds NaN or inf points (use cloud.finite())")
    if offset is None:
        offsets = np.floor(pts.min(axis=0)) if len(pts) else np.zeros(3)
    else:
        offsets = _as_triple(offset, "offset")
    quantised = np.round((pts - offsets) / scales)
    if quantised.size and (quantised.min() < _INT32[0] or quantised.max() > _INT32[1]):
        raise ValueError(
            f"scale: coordinates span {np.ptp(pts, axis=0).max():.6g} m around offset "
            f"{offsets.tolist()}; at scale {scales.tolist()} they overflow LAS's int32 — "
            "use a coarser scale or an offset near the points"
        )
    version = "1.4" if point_format >= 6 else "1.2" if point_format <= 3 else "1.3"
    header = laspy.LasHeader(version=version, point_format=point_format)
    header.scales = scales
    header.offsets = offsets
    dims = set(header.point_format.dimension_names)
    intensity = cloud.intensity
    as_standard_intensity = intensity is None or bool(
        (intensity == np.round(intensity)).all()
        and (len(intensity) == 0 or (intensity.min() >= 0 and intensity.max() <= 65535))
    )
    extras: dict[str, Any] = {}
    if intensity is not None and not as_standard_intensity:
        extras["reflectance"] = intensity
    if cloud.ring is not None:
        extras["ring"] = cloud.ring.astype(np.float64)
    for name, values in cloud.fields.items():
        if name not in STANDARD_FIELDS:
            extras[name] = values
    if cloud.time is not None and "gps_time" not in dims:
        raise ValueError(
            f"point_format: format {point_format} has no GPS time for cloud.time "
            "(use 1, 3, 5 or 6-10)"
        )
    for name in extras:
        if name in dims or len(name.encode()) > 32:
            raise ValueError(f"cloud: field {name!r} cannot be an extra LAS dimension")
        kind = np.uint16 if name == "ring" else np.float64
        header.add_extra_dims([laspy.ExtraBytesParams(name=name, type=kind)])
    if crs_wkt is not None:
        header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(crs_wkt))
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.X = quantised[:, 0].astype(np.int32)
    las.Y = quantised[:, 1].astype(np.int32)
    las.Z = quantised[:, 2].astype(np.int32)
    if intensity is not None and as_standard_intensity:
        las.intensity = intensity.astype(np.uint16)
    if cloud.time is not None:
        las.gps_time = cloud.time
    for name, (lo, hi) in STANDARD_FIELDS.items():
        if name != "classification" and point_format < 6:
            hi = 7  # three bits before LAS 1.4's formats
        elif name == "classification" and point_format < 6:
            hi = 31
        if name in cloud.fields:
            las[name] = _integers(cloud.fields[name], name, lo, hi).astype(np.uint8)
        elif name != "classification":
            las[name] = np.ones(len(pts), dtype=np.uint8)  # single returns: a valid file
    for name, values in extras.items():
        if name == "ring":
            las[name] = _integers(values, "ring", 0, 65535).astype(np.uint16)
        else:
            las[name] = values
    las.update_header()
    compressed = p.suffix.lower() == ".laz" if compress is None else bool(compress)
    backend = _laz_backend(laspy) if compressed else None

    def write(dest: str) -> None:
        # a stream: laspy decides compression from a path's suffix, and ours is a temp name
        with open(dest, "wb") as stream:
            las.write(stream, do_compress=compressed, laz_backend=backend)

    _atomic_write(p, write)


def _atomic_write(path: Path, write: Any) -> None:
    parent = path.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"{path}: cannot write there: no folder {parent}")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=parent)
    except OSError as exc:
        raise PermissionError(f"{path}: cannot write there: {exc.strerror}") from None
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_laz(path: PathLike, cloud: CloudLike, **options: Any) -> None:
    """:func:`write_las` with LAZ compression (the registry's ``.laz`` writer)."""
    write_las(path, cloud, **{"compress": True, **options})


def relative_gps_time(time: FloatArray | None) -> FloatArray | None:
    """Per-point GPS times (seconds) made relative to the sweep's first point when they are
    absolute (GPS week seconds or adjusted standard GPS time: beyond one sweep's length,
    2 s); relative times (as scanreg writes them) are kept."""
    if time is None or time.size == 0:
        return time
    first = float(np.min(time))
    if first > 2.0:
        out: FloatArray = time - first
        return out
    return time


__all__ = [
    "DEFAULT_POINT_FORMAT",
    "DEFAULT_SCALE",
    "STANDARD_FIELDS",
    "LasHeaderInfo",
    "read_las",
    "read_las_header",
    "relative_gps_time",
    "write_las",
    "write_laz",
]
