"""PCD (Point Cloud Library) files: ``DATA ascii``, ``binary`` and ``binary_compressed``.

Layout (PCD v0.7): a text header (``FIELDS``, ``SIZE``, ``TYPE``, ``COUNT``, ``WIDTH``,
``HEIGHT``, ``VIEWPOINT``, ``POINTS``, ``DATA``) then the points — one text line per point,
packed records (array of structs), or for ``binary_compressed`` two little-endian uint32
(compressed and uncompressed size) and an LZF stream that expands to one column per field
(struct of arrays). Fields named ``_`` are padding.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from .. import _core
from ._common import (
    CloudLike,
    FileFormatError,
    PathLike,
    PointCloud,
    check_writable_cloud,
    cloud_from_columns,
)

#: A header longer than this is not a PCD header (stops runaway reads of binary garbage).
MAX_HEADER_BYTES = 1 << 16
_TYPES = {(t, size): f"{t.lower()}{size}" for t in "IU" for size in (1, 2, 4, 8)}
_TYPES.update({("F", 4): "f4", ("F", 8): "f8"})
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS")


def _parse_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], str, int]:
    """Header entries, the DATA kind and the offset of the first data byte."""
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0 or end > MAX_HEADER_BYTES:
            raise FileFormatError(path, "no DATA line in the header (truncated or not a PCD file)")
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise FileFormatError(
                path, "header contains non-ASCII bytes (not a PCD file)"
            ) from None
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if key == "DATA":
            if len(values) != 1 or values[0] not in ("ascii", "binary", "binary_compressed"):
                raise FileFormatError(path, f"unsupported DATA {' '.join(values)!r}")
            return header, values[0], pos
        if key not in _KEYS:
            if not header:
                raise FileFormatError(path, f"not a PCD file (starts with {line[:40]!r})")
            raise FileFormatError(path, f"unknown header line {line[:60]!r}")
        if key in header:
            raise FileFormatError(path, f"header repeats {key}")
        header[key] = values


def _header_int(path: Path, header: dict[str, list[str]], key: str, default: int | None) -> int:
    if key not in header:
        if default is None:
            raise FileFormatError(path, f"header has no {key}")
        return default
    values = header[key]
    if len(values) != 1 or not values[0].isdigit():
        raise FileFormatError(path, f"{key} must be one non-negative integer, got {values}")
    return int(values[0])


def _layout(
    path: Path, header: dict[str, list[str]]
) -> tuple[list[str], list[str], list[int], int]:
    """Field names, numpy type codes, counts and the point count, all validated."""
    names = header.get("FIELDS")
    if not names:
        raise FileFormatError(path, "header has no FIELDS")
    n = len(names)
    sizes, types = header.get("SIZE", []), header.get("TYPE", [])
    counts = header.get("COUNT", ["1"] * n)
    for key, vals in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(vals) != n:
            raise FileFormatError(path, f"{key} has {len(vals)} entries for {n} FIELDS")
    codes, counts_int = [], []
    for name, size, typ, count in zip(names, sizes, types, counts, strict=True):
        if not size.isdigit() or (typ.upper(), int(size)) not in _TYPES:
            raise FileFormatError(path, f"field {name}: unsupported TYPE {typ} SIZE {size}")
        if not count.isdigit() or int(count) < 1:
            raise FileFormatError(path, f"field {name}: COUNT must be a positive integer")
        codes.append(_TYPES[(typ.upper(), int(size))])
        counts_int.append(int(count))
    width = _header_int(path, header, "WIDTH", None)
    height = _header_int(path, header, "HEIGHT", 1)
    points = _header_int(path, header, "POINTS", width * height)
    if points != width * height:
        raise FileFormatError(path, f"POINTS {points} != WIDTH {width} x HEIGHT {height}")
    for axis in ("x", "y", "z"):
        if axis in names and counts_int[names.index(axis)] != 1:
            raise FileFormatError(path, f"field {axis} must have COUNT 1")
    return list(names), codes, counts_int, points


def _columns(path: Path, names: list[str], arrays: list[NDArray[Any]]) -> dict[str, NDArray[Any]]:
    cols: dict[str, NDArray[Any]] = {}
    for name, arr in zip(names, arrays, strict=True):
        if name == "_":
            continue
        if name in cols:
            raise FileFormatError(path, f"field {name} appears twice")
        cols[name] = arr
    return cols


def read_pcd(path: PathLike) -> PointCloud:
    """Read a PCD file (ascii, binary or binary_compressed).

    Returns
    -------
    PointCloud
        ``points`` (N, 3) from fields x y z; ``intensity``, ``ring``, ``time`` from their usual
        names; every other field in ``fields``.

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the problem: bad header, counts that do not match the data,
        truncated or corrupt data, unparsable numbers.
    """
    p = Path(path)
    raw = p.read_bytes()
    if not raw:
        raise FileFormatError(p, "empty file")
    header, kind, offset = _parse_header(p, raw)
    names, codes, counts, n = _layout(p, header)
    body = memoryview(raw)[offset:]
    itemsizes = [np.dtype(c).itemsize * k for c, k in zip(codes, counts, strict=True)]
    record = sum(itemsizes)
    arrays: list[NDArray[Any]] = []
    if kind == "ascii":
        arrays = _read_ascii(p, bytes(body), codes, counts, n)
    elif kind == "binary":
        if len(body) < n * record:
            raise FileFormatError(
                p, f"truncated: {n} points need {n * record} data bytes, file has {len(body)}"
            )
        dtype = np.dtype(
            {
                "names": [f"f{i}" for i in range(len(names))],
                "formats": [
                    (("<" + c), (k,)) if k > 1 else "<" + c
                    for c, k in zip(codes, counts, strict=True)
                ],
            }
        )
        recs = np.frombuffer(body, dtype=dtype, count=n)
        arrays = [np.array(recs[f"f{i}"]) for i in range(len(names))]
    else:
        arrays = _read_compressed(p, body, codes, counts, itemsizes, n)
    return cloud_from_columns(p, _columns(p, names, arrays))


def _read_ascii(
    path: Path, body: bytes, codes: list[str], counts: list[int], n: int
) -> list[NDArray[Any]]:
    width = sum(counts)
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError:
        raise FileFormatError(path, "ascii data contains non-ASCII bytes") from None
    rows = [line.split() for line in text.splitlines() if line.strip()]
    if len(rows) != n:
        raise FileFormatError(path, f"header declares {n} points, ascii data has {len(rows)} lines")
    for i, row in enumerate(rows):
        if len(row) != width:
            raise FileFormatError(path, f"point {i}: {len(row)} values, expected {width}")
    try:
        table = np.array(rows, dtype=np.float64).reshape(n, width)
    except ValueError as exc:
        raise FileFormatError(path, f"bad number in ascii data: {exc}") from None
    arrays, col = [], 0
    for code, k in zip(codes, counts, strict=True):
        block = table[:, col : col + k]
        col += k
        if code[0] in "iu" and not (np.isfinite(block).all() and (block == np.round(block)).all()):
            raise FileFormatError(path, f"integer field holds non-integer values near column {col}")
        arrays.append(block[:, 0].copy() if k == 1 else block.copy())
    return arrays


def _read_compressed(
    path: Path,
    body: memoryview,
    codes: list[str],
    counts: list[int],
    itemsizes: list[int],
    n: int,
) -> list[NDArray[Any]]:
    if len(body) < 8:
        raise FileFormatError(path, "truncated: binary_compressed data has no size words")
    compressed, uncompressed = (int(v) for v in np.frombuffer(body[:8], dtype="<u4"))
    if compressed > len(body) - 8:
        raise FileFormatError(
            path, f"truncated: {compressed} compressed bytes declared, {len(body) - 8} present"
        )
    expected = n * sum(itemsizes)
    if uncompressed != expected:
        raise FileFormatError(
            path, f"uncompressed size {uncompressed} does not match {n} points ({expected} bytes)"
        )
    if n == 0:
        return [
            np.zeros((0, k) if k > 1 else 0, dtype=c) for c, k in zip(codes, counts, strict=True)
        ]
    try:
        data = _core.lzf_decompress(bytes(body[8 : 8 + compressed]), expected)
    except ValueError as exc:
        raise FileFormatError(path, f"corrupt compressed data: {exc}") from None
    arrays, start = [], 0
    for code, k, size in zip(codes, counts, itemsizes, strict=True):
        column = np.frombuffer(data, dtype="<" + code, count=n * k, offset=start)
        arrays.append(column.copy() if k == 1 else column.reshape(n, k).copy())
        start += n * size
    return arrays


def write_pcd(
    path: PathLike,
    cloud: CloudLike,
    *,
    data: Literal["binary", "ascii", "binary_compressed"] = "binary",
    precision: Literal["float32", "float64"] = "float32",
) -> None:
    """Write a PCD v0.7 file.

    Parameters
    ----------
    cloud : PointCloud with 3D points
    data : "binary" (default), "ascii" or "binary_compressed" (LZF)
    precision : "float32" (default; what most tools expect) or "float64", for the coordinates,
        intensity and extra fields. ``ring`` is written as uint16 (int32 if out of range) and
        ``time`` always as float64 (absolute times need it).
    """
    cloud = check_writable_cloud(cloud, "PCD")
    if data not in ("binary", "ascii", "binary_compressed"):
        raise ValueError(f"data: expected 'binary', 'ascii' or 'binary_compressed', got {data!r}")
    if precision not in ("float32", "float64"):
        raise ValueError(f"precision: expected 'float32' or 'float64', got {precision!r}")
    real = "<f4" if precision == "float32" else "<f8"
    columns: list[tuple[str, NDArray[Any]]] = [
        (a, cloud.points[:, i].astype(real)) for i, a in enumerate("xyz")
    ]
    for name, arr in cloud.named_fields().items():
        if name == "ring":
            fits = arr.size == 0 or (arr.min() >= 0 and arr.max() < 2**16)
            columns.append((name, arr.astype("<u2" if fits else "<i4")))
        elif name == "time":
            columns.append((name, arr.astype("<f8")))
        else:
            columns.append((name, arr.astype(real)))
    n = len(cloud)
    lines = ["# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7"]
    lines.append("FIELDS " + " ".join(name for name, _ in columns))
    lines.append("SIZE " + " ".join(str(a.dtype.itemsize) for _, a in columns))
    lines.append(
        "TYPE " + " ".join({"f": "F", "i": "I", "u": "U"}[a.dtype.kind] for _, a in columns)
    )
    lines.append("COUNT " + " ".join(str(1 if a.ndim == 1 else a.shape[1]) for _, a in columns))
    lines += [f"WIDTH {n}", "HEIGHT 1", "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {n}", f"DATA {data}"]
    head = ("\n".join(lines) + "\n").encode("ascii")
    flat = [a.reshape(n, 1) if a.ndim == 1 else a for _, a in columns]
    if data == "ascii":
        text = "\n".join(
            " ".join(_fmt(v, a.dtype.kind) for a in flat for v in a[i]) for i in range(n)
        )
        Path(path).write_bytes(head + text.encode("ascii") + (b"\n" if n else b""))
        return
    if data == "binary":
        dtype = np.dtype([(f"f{i}", a.dtype, (a.shape[1],)) for i, a in enumerate(flat)])
        recs = np.zeros(n, dtype=dtype)
        for i, a in enumerate(flat):
            recs[f"f{i}"] = a
        Path(path).write_bytes(head + recs.tobytes())
        return
    raw = b"".join(np.ascontiguousarray(a).tobytes() for a in flat)
    packed = _core.lzf_compress(raw)
    sizes = np.array([len(packed), len(raw)], dtype="<u4").tobytes()
    Path(path).write_bytes(head + sizes + packed)


def _fmt(v: Any, kind: str) -> str:
    return str(int(v)) if kind in "iu" else repr(float(v))
