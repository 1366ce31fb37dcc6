"""2D occupancy grids: built from posed scans, written as ROS ``map_server`` maps and PNG.

:func:`occupancy_grid` traces every beam from the sensor to its return: the cells it crosses
count a miss, the cell of the return a hit; a cell's occupancy is ``hits / (hits + misses)``
(unknown when no beam reached it). Beams are sampled at the cell size, the samples of many
scans at a time handled as arrays.

:func:`write_map` writes the ROS ``map_server`` pair — ``NAME.pgm`` (binary P5, row 0 at the
top: +y up; occupied 0, free 254, unknown 205) and ``NAME.yaml`` (``image``, ``resolution``,
``origin`` = the world pose ``[x, y, yaw]`` of the lower-left pixel, ``negate: 0``,
``occupied_thresh``, ``free_thresh``) — and the same image as ``NAME.png``.
"""

from __future__ import annotations

import math
import re
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray, as_points
from ..transform import SE2, as_pose
from ._common import FileFormatError, PathLike

#: Pixel values (ROS map_server, trinary, ``negate: 0``): p = (255 − v) / 255.
OCCUPIED, FREE, UNKNOWN = 0, 254, 205


@dataclass(frozen=True)
class OccupancyGrid:
    """``probability[row, col]`` (row = y, from ``origin`` upwards; NaN = unknown)."""

    probability: FloatArray
    resolution: float
    #: World coordinates of the lower-left corner of cell ``(0, 0)``.
    origin: tuple[float, float]
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196

    def image(self) -> NDArray[np.uint8]:
        """The map_server image: occupied 0, free 254, unknown 205; row 0 at the top."""
        p = self.probability
        img = np.full(p.shape, UNKNOWN, dtype=np.uint8)
        known = np.isfinite(p)
        img[known & (p > self.occupied_thresh)] = OCCUPIED
        img[known & (p < self.free_thresh)] = FREE
        flipped: NDArray[np.uint8] = np.ascontiguousarray(img[::-1])
        return flipped


def occupancy_grid(
    poses: Sequence[SE2] | Sequence[FloatArray],
    scans: Sequence[FloatArray],
    *,
    resolution: float = 0.05,
    padding: float = 1.0,
    chunk: int = 50,
) -> OccupancyGrid:
    """Occupancy from scans (``(N, 2)`` points in the sensor frame) at ``poses``
    (``T_world_scan``; the sensor at the scan origin)."""
    if len(poses) != len(scans):
        raise ValueError(f"poses, scans: expected the same length, got {len(poses)}, {len(scans)}")
    if not poses:
        raise ValueError("scans: no scan to build a map from")
    if not resolution > 0:
        raise ValueError(f"resolution: must be > 0, got {resolution!r}")
    se2 = [as_pose(p, f"poses[{i}]", 2) for i, p in enumerate(poses)]  # SE2 or 3x3 matrices
    world = [p.apply(as_points(s, f"scans[{i}]", dim=2, min_points=0)) for i, (p, s) in
             enumerate(zip(se2, scans, strict=True))]  # fmt: skip
    origins = np.array([p.translation for p in se2])
    every = np.vstack([origins, *world])
    lo = every.min(axis=0) - padding
    hi = every.max(axis=0) + padding
    shape = (int(np.ceil((hi[1] - lo[1]) / resolution)), int(np.ceil((hi[0] - lo[0]) / resolution)))
    hits = np.zeros(shape[0] * shape[1], dtype=np.int64)
    misses = np.zeros_like(hits)

    def cells(xy: FloatArray) -> NDArray[np.int64]:
        ij = np.floor((xy - lo) / resolution).astype(np.int64)
        ij[:, 0] = np.clip(ij[:, 0], 0, shape[1] - 1)
        ij[:, 1] = np.clip(ij[:, 1], 0, shape[0] - 1)
        out: NDArray[np.int64] = ij[:, 1] * shape[1] + ij[:, 0]
        return out

    for start in range(0, len(world), chunk):
        ends = world[start : start + chunk]
        if not any(len(e) for e in ends):
            continue
        o = np.vstack(
            [np.repeat(origins[start + i][None], len(e), axis=0) for i, e in enumerate(ends)]
        )
        e = np.vstack(ends)
        np.add.at(hits, cells(e), 1)
        d = e - o
        length = np.linalg.norm(d, axis=1)
        # Samples every cell size along each beam, stopping one cell short of the return.
        steps = np.maximum(np.floor(length / resolution).astype(np.int64) - 1, 0)
        ray = np.repeat(np.arange(len(e)), steps)
        first = np.cumsum(steps) - steps
        k = np.arange(int(steps.sum())) - np.repeat(first, steps)
        frac = (k + 0.5) * resolution / np.maximum(length[ray], 1e-12)
        samples = o[ray] + d[ray] * frac[:, None]
        np.add.at(misses, cells(samples), 1)
    total = hits + misses
    with np.errstate(invalid="ignore", divide="ignore"):
        prob = np.where(total > 0, hits / np.maximum(total, 1), np.nan)
    return OccupancyGrid(
        probability=prob.reshape(shape), resolution=float(resolution), origin=(lo[0], lo[1])
    )


def _png(image: NDArray[np.uint8]) -> bytes:
    """An 8-bit greyscale PNG (filter 0 on every row)."""
    h, w = image.shape
    raw = b"".join(b"\x00" + image[r].tobytes() for r in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(raw, 6))
        + chunk(b"IEND", b"")
    )


def write_map(folder: PathLike, grid: OccupancyGrid, name: str = "map") -> dict[str, Path]:
    """Write ``NAME.pgm``, ``NAME.yaml`` (ROS map_server) and ``NAME.png`` into ``folder``."""
    out = Path(folder)
    if not out.is_dir():
        raise FileNotFoundError(f"folder: {out} does not exist")
    img = grid.image()
    pgm = out / f"{name}.pgm"
    h, w = img.shape
    pgm.write_bytes(f"P5\n{w} {h}\n255\n".encode("ascii") + img.tobytes())
    yaml = out / f"{name}.yaml"
    yaml.write_text(
        f"image: {pgm.name}\n"
        f"resolution: {grid.resolution:.6g}\n"
        f"origin: [{grid.origin[0]:.6f}, {grid.origin[1]:.6f}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {grid.occupied_thresh:.6g}\n"
        f"free_thresh: {grid.free_thresh:.6g}\n",
        encoding="utf-8",
    )
    png = out / f"{name}.png"
    png.write_bytes(_png(img))
    return {"pgm": pgm, "yaml": yaml, "png": png}


#: Largest map.yaml read (a map_server YAML is a few lines: a bigger file is not one).
MAX_YAML_BYTES = 1 << 20
#: The PGM header: magic, width, height, maxval, each after whitespace or ``#`` comments.
#: One whitespace byte per repetition: ``(?:\s+|…)+`` backtracked exponentially on a run of
#: newlines that ended in no number (found by fuzz/: seconds for a 261-byte file).
_GAP = rb"(?:\s|#[^\n]*\n)+"
_NUMBER = rb"(\d{1,9})"
_PGM_HEADER = re.compile(rb"P5" + _GAP + _NUMBER + _GAP + _NUMBER + _GAP + rb"(\d{1,5})\s")


def _regular_file(path: Path, field: str, owner: Path) -> Path:
    """``path`` when it is a regular file: a map may name any path, and ``/dev/zero`` or a
    FIFO would be read forever."""
    try:
        regular = path.is_file()
    except (OSError, ValueError):  # a NUL byte, a name too long
        regular = False
    if not regular:
        raise FileFormatError(owner, f"{field}: {path} is not a readable file")
    return path


def read_pgm(path: PathLike) -> NDArray[np.uint8]:
    """A binary (P5) 8-bit PGM as :func:`write_map` and ROS ``map_server`` write it (row 0
    at the top; ``#`` comments allowed in the header). Width and height are checked against
    the bytes the file holds before anything is allocated."""
    p = Path(path)
    _regular_file(p, "path", p)
    size = p.stat().st_size
    with p.open("rb") as fh:
        head = fh.read(1024)
        m = _PGM_HEADER.match(head)
        if m is None:
            raise FileFormatError(p, "not a binary PGM (P5: magic, width, height, maxval)")
        width, height, maxval = (int(t) for t in m.groups())
        if maxval != 255:
            raise FileFormatError(p, f"maxval {maxval}: only 8-bit PGM (maxval 255) is read")
        if width == 0 or height == 0:
            raise FileFormatError(p, f"empty image ({width} x {height} pixels)")
        if width * height > size - m.end():
            raise FileFormatError(
                p,
                f"truncated: width {width} x height {height} needs {width * height} bytes, "
                f"{size - m.end()} follow the header",
            )
        fh.seek(m.end())
        body = fh.read(width * height)
    if len(body) != width * height:  # the file shrank while being read
        raise FileFormatError(p, f"truncated ({len(body)} of {width * height} pixel bytes)")
    return np.frombuffer(body, dtype=np.uint8).reshape(height, width).copy()


def _yaml_fields(path: Path) -> dict[str, str]:
    """``key: value`` lines of a map_server YAML (the flat subset map_server writes)."""
    _regular_file(path, "path", path)
    with path.open("rb") as fh:
        raw = fh.read(MAX_YAML_BYTES + 1)
    if len(raw) > MAX_YAML_BYTES:
        raise FileFormatError(path, f"larger than {MAX_YAML_BYTES} bytes: not a map_server YAML")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(path, "not a text file (invalid UTF-8)") from None
    # The value is stripped here, not by the pattern: a lazy ``(.+?)[ \t]*$`` went quadratic
    # on a long run of blanks inside a value (3.5 s for 16 000 spaces, hours for 1 MB).
    fields = {
        m.group(1): m.group(2).strip()
        for m in re.finditer(r"^[ \t]*(\w+)[ \t]*:(.*)$", text, flags=re.MULTILINE)
    }
    return {key: value for key, value in fields.items() if value}


def _finite(path: Path, field: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise FileFormatError(path, f"{field}: expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise FileFormatError(path, f"{field}: expected a finite number, got {text!r}")
    return value


@dataclass(frozen=True)
class _MapHeader:
    """A ``map.yaml``'s fields, the ones both readers need checked."""

    fields: dict[str, str]
    resolution: float
    origin: list[float]
    occupied: float
    free: float
    image: Path


def _map_header(yaml_path: Path) -> _MapHeader:
    fields = _yaml_fields(yaml_path)
    missing = [k for k in ("image", "resolution", "origin") if k not in fields]
    if missing:
        raise FileFormatError(yaml_path, f"lacks {', '.join(missing)} (not a map_server map)")
    resolution = _finite(yaml_path, "resolution", fields["resolution"])
    if resolution <= 0:
        raise FileFormatError(yaml_path, f"resolution: must be > 0, got {resolution}")
    parts = fields["origin"].strip("[]").split(",")
    if len(parts) != 3:
        raise FileFormatError(yaml_path, f"origin: expected [x, y, yaw], got {fields['origin']!r}")
    origin = [_finite(yaml_path, "origin", v) for v in parts]
    occupied = _finite(yaml_path, "occupied_thresh", fields.get("occupied_thresh", "0.65"))
    free = _finite(yaml_path, "free_thresh", fields.get("free_thresh", "0.196"))
    if not (0.0 <= occupied <= 1.0 and 0.0 <= free <= 1.0):
        raise FileFormatError(
            yaml_path, f"occupied_thresh {occupied}, free_thresh {free}: must be in [0, 1]"
        )
    name = fields["image"].strip("'\"")
    image = _regular_file(yaml_path.parent / name, "image", yaml_path)
    return _MapHeader(fields, resolution, origin, occupied, free, image)


def read_map_server(path: PathLike) -> tuple[FloatArray, float]:
    """Occupied cells of a ROS ``map_server`` map (``map.yaml`` and the PGM image it names)
    as ``(M, 2)`` points in the map frame (cell centres), and the resolution.

    A cell is occupied when its occupancy ``p`` (``(255 − v)/255``, or ``v/255`` with
    ``negate: 1``) exceeds ``occupied_thresh``. The origin's yaw rotates the grid about the
    origin, as ``map_server`` defines it. Only binary PGM (``P5``) images are read. A field
    that is missing or out of range raises :class:`FileFormatError` naming the file and the
    field.
    """
    yaml_path = Path(path)
    head = _map_header(yaml_path)
    resolution, origin, occupied = head.resolution, head.origin, head.occupied
    negate = head.fields.get("negate", "0").lower()
    if negate not in ("0", "1", "true", "false"):
        raise FileFormatError(yaml_path, f"negate: expected 0 or 1, got {negate!r}")
    image = read_pgm(head.image)
    height, width = image.shape
    if not math.isfinite(resolution * (width + height) + abs(origin[0]) + abs(origin[1])):
        raise FileFormatError(yaml_path, f"resolution: {resolution} m over {width} x {height} "
                              "cells overflows the map's coordinates")  # fmt: skip
    value = image.astype(np.float64) / 255.0
    p = value if negate in ("1", "true") else 1.0 - value
    rows, cols = np.nonzero(p > occupied)
    # Row 0 of the image is the top: y grows upwards from the last row.
    local = np.c_[(cols + 0.5) * resolution, (height - 1 - rows + 0.5) * resolution]
    c, s = math.cos(origin[2]), math.sin(origin[2])
    pts = local @ np.array([[c, s], [-s, c]]) + np.array(origin[:2])
    return np.ascontiguousarray(pts), resolution


def read_occupancy_grid(path: PathLike) -> OccupancyGrid:
    """A map :func:`write_map` wrote (``map.yaml`` and its PGM) as an :class:`OccupancyGrid`:
    the image is trinary, so occupied cells read back as 1, free as 0, unknown as NaN (the
    probabilities themselves are not in the file). The origin's yaw must be 0 (as
    :func:`write_map` writes it)."""
    yaml_path = Path(path)
    head = _map_header(yaml_path)
    origin = head.origin
    if origin[2] != 0.0:
        raise FileFormatError(yaml_path, f"origin: a rotated grid (yaw {origin[2]}) is not read")
    image = read_pgm(head.image)[::-1]
    prob = np.full(image.shape, np.nan)
    prob[image == OCCUPIED] = 1.0
    prob[image == FREE] = 0.0
    return OccupancyGrid(prob, head.resolution, (origin[0], origin[1]), head.occupied, head.free)


def occupied_points(grid: OccupancyGrid) -> FloatArray:
    """The centres of the cells of ``grid`` above its ``occupied_thresh``, ``(M, 2)`` in the
    world frame (what :func:`read_map_server` reads from the written map)."""
    rows, cols = np.nonzero(np.nan_to_num(grid.probability, nan=0.0) > grid.occupied_thresh)
    pts = np.c_[(cols + 0.5) * grid.resolution, (rows + 0.5) * grid.resolution]
    return np.ascontiguousarray(pts + np.asarray(grid.origin, dtype=np.float64))
