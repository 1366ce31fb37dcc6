"""PLY (Stanford polygon) files: ``ascii``, ``binary_little_endian``, ``binary_big_endian``.

Only the ``vertex`` element is read (x, y, z and any scalar properties); every other element
(faces, edges, camera, …) is skipped by walking its records, list properties included.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

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

MAX_HEADER_BYTES = 1 << 16
_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass(frozen=True)
class _Property:
    name: str
    code: str  # numpy type code of the value (or of the list items)
    count_code: str | None = None  # list properties: type code of the length prefix


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: tuple[_Property, ...]


def _parse_header(path: Path, raw: bytes) -> tuple[str, list[_Element], int]:
    if not raw.startswith(b"ply"):
        raise FileFormatError(path, "not a PLY file (no 'ply' magic)")
    end = raw.find(b"end_header", 0, MAX_HEADER_BYTES)
    if end < 0:
        raise FileFormatError(path, "no end_header in the header (truncated or not a PLY file)")
    stop = raw.find(b"\n", end)
    if stop < 0:
        raise FileFormatError(path, "truncated after end_header")
    try:
        lines = raw[:end].decode("ascii").splitlines()[1:]
    except UnicodeDecodeError:
        raise FileFormatError(path, "header contains non-ASCII bytes") from None
    fmt: str | None = None
    elements: list[_Element] = []
    props: list[_Property] = []
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise FileFormatError(path, f"unsupported format line {line!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise FileFormatError(path, f"bad element line {line!r}")
            props = []
            elements.append(_Element(words[1], int(words[2]), ()))
        elif words[0] == "property":
            if not elements:
                raise FileFormatError(path, "property before any element")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _TYPES or words[3] not in _TYPES or _TYPES[words[2]][0] == "f":
                    raise FileFormatError(path, f"bad list property {line!r}")
                props.append(_Property(words[4], _TYPES[words[3]], _TYPES[words[2]]))
            elif len(words) == 3 and words[1] in _TYPES:
                props.append(_Property(words[2], _TYPES[words[1]]))
            else:
                raise FileFormatError(path, f"bad property line {line!r}")
            last = elements[-1]
            elements[-1] = _Element(last.name, last.count, tuple(props))
        else:
            raise FileFormatError(path, f"unknown header line {line!r}")
    if fmt is None:
        raise FileFormatError(path, "header has no format line")
    return fmt, elements, stop + 1


def read_ply(path: PathLike) -> PointCloud:
    """Read the ``vertex`` element of a PLY file (ascii or binary, either byte order).

    Returns
    -------
    PointCloud
        ``points`` (N, 3) from x y z; intensity (also ``scalar_intensity``), ring and time by
        their usual names; other scalar vertex properties in ``fields``.

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the problem (bad header, truncated body, bad numbers, …).
    """
    p = Path(path)
    raw = p.read_bytes()
    if not raw:
        raise FileFormatError(p, "empty file")
    fmt, elements, offset = _parse_header(p, raw)
    vertex = [e for e in elements if e.name == "vertex"]
    if len(vertex) != 1:
        raise FileFormatError(p, f"expected one vertex element, found {len(vertex)}")
    if any(prop.count_code for prop in vertex[0].properties):
        raise FileFormatError(p, "list properties in the vertex element are not supported")
    if fmt == "ascii":
        columns = _read_ascii(p, raw[offset:], elements)
    else:
        columns = _read_binary(p, memoryview(raw)[offset:], elements, _FORMATS[fmt])
    return cloud_from_columns(p, columns)


def _read_binary(
    path: Path, body: memoryview, elements: list[_Element], order: str
) -> dict[str, NDArray[Any]]:
    pos = 0
    for element in elements:
        if all(prop.count_code is None for prop in element.properties):
            dtype = np.dtype(
                [(f"p{i}", order + prop.code) for i, prop in enumerate(element.properties)]
            )
            size = element.count * dtype.itemsize
            if pos + size > len(body):
                raise FileFormatError(
                    path,
                    f"truncated: element {element.name} ({element.count} records) needs "
                    f"{size} bytes, {len(body) - pos} left",
                )
            if element.name == "vertex":
                recs = np.frombuffer(body, dtype=dtype, count=element.count, offset=pos)
                names = [prop.name for prop in element.properties]
                if len(set(names)) != len(names):
                    raise FileFormatError(path, "vertex element repeats a property name")
                return {
                    prop.name: recs[f"p{i}"].astype(prop.code)
                    for i, prop in enumerate(element.properties)
                }
            pos += size
        else:
            pos = _skip_records(path, body, pos, element, order)
    raise FileFormatError(path, "no vertex element")  # pragma: no cover - checked by caller


def _skip_records(path: Path, body: memoryview, pos: int, element: _Element, order: str) -> int:
    """Walk past an element with list properties (record sizes vary)."""
    for _ in range(element.count):
        for prop in element.properties:
            size = np.dtype(prop.code).itemsize
            if prop.count_code is None:
                pos += size
                continue
            lsize = np.dtype(prop.count_code).itemsize
            if pos + lsize > len(body):
                raise FileFormatError(path, f"truncated inside element {element.name}")
            length = int(np.frombuffer(body, dtype=order + prop.count_code, count=1, offset=pos)[0])
            if length < 0:
                raise FileFormatError(path, f"negative list length in element {element.name}")
            pos += lsize + length * size
        if pos > len(body):
            raise FileFormatError(path, f"truncated inside element {element.name}")
    return pos


def _read_ascii(path: Path, body: bytes, elements: list[_Element]) -> dict[str, NDArray[Any]]:
    try:
        lines = [ln for ln in body.decode("ascii").splitlines() if ln.strip()]
    except UnicodeDecodeError:
        raise FileFormatError(path, "ascii body contains non-ASCII bytes") from None
    start = 0
    for element in elements:
        if start + element.count > len(lines):
            raise FileFormatError(
                path,
                f"truncated: element {element.name} declares {element.count} lines, "
                f"{len(lines) - start} left",
            )
        if element.name != "vertex":
            start += element.count
            continue
        rows = [ln.split() for ln in lines[start : start + element.count]]
        width = len(element.properties)
        for i, row in enumerate(rows):
            if len(row) != width:
                raise FileFormatError(path, f"vertex {i}: {len(row)} values, expected {width}")
        try:
            table = np.array(rows, dtype=np.float64).reshape(element.count, width)
        except ValueError as exc:
            raise FileFormatError(path, f"bad number in vertex data: {exc}") from None
        return {prop.name: table[:, i].copy() for i, prop in enumerate(element.properties)}
    raise FileFormatError(path, "no vertex element")  # pragma: no cover - checked by caller


def write_ply(
    path: PathLike,
    cloud: CloudLike,
    *,
    data: Literal["binary_little_endian", "binary_big_endian", "ascii"] = "binary_little_endian",
    precision: Literal["float32", "float64"] = "float32",
) -> None:
    """Write the cloud as the ``vertex`` element of a PLY file.

    Coordinates, intensity and extra fields as ``float`` (or ``double`` with
    ``precision="float64"``), ``ring`` as ``int``, ``time`` as ``double``.
    """
    cloud = check_writable_cloud(cloud, "PLY")
    if data not in _FORMATS:
        raise ValueError(f"data: expected one of {sorted(_FORMATS)}, got {data!r}")
    if precision not in ("float32", "float64"):
        raise ValueError(f"precision: expected 'float32' or 'float64', got {precision!r}")
    for name, arr in cloud.fields.items():
        if arr.ndim != 1:
            raise ValueError(f"cloud: PLY stores scalar properties; field {name} is {arr.shape}")
    real = "f4" if precision == "float32" else "f8"
    cols: list[tuple[str, NDArray[Any]]] = [
        (a, cloud.points[:, i].astype(real)) for i, a in enumerate("xyz")
    ]
    for name, arr in cloud.named_fields().items():
        code = {"ring": "i4", "time": "f8"}.get(name, real)
        cols.append((name, arr.astype(code)))
    ply_type = {"f4": "float", "f8": "double", "i4": "int"}
    n = len(cloud)
    head = ["ply", f"format {data} 1.0", "comment written by scanreg", f"element vertex {n}"]
    head += [f"property {ply_type[a.dtype.str[1:]]} {name}" for name, a in cols]
    head.append("end_header")
    out = ("\n".join(head) + "\n").encode("ascii")
    if data == "ascii":
        body = "\n".join(
            " ".join(str(int(a[i])) if a.dtype.kind == "i" else repr(float(a[i])) for _, a in cols)
            for i in range(n)
        )
        Path(path).write_bytes(out + body.encode("ascii") + (b"\n" if n else b""))
        return
    order = _FORMATS[data]
    recs = np.zeros(n, dtype=[(f"p{i}", order + a.dtype.str[1:]) for i, (_, a) in enumerate(cols)])
    for i, (_, a) in enumerate(cols):
        recs[f"p{i}"] = a
    Path(path).write_bytes(out + recs.tobytes())
