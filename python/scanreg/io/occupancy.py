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

import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray, as_points
from ..transform import SE2
from ._common import PathLike

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
    poses: Sequence[SE2],
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
    world = [p.apply(as_points(s, f"scans[{i}]", dim=2, min_points=0)) for i, (p, s) in
             enumerate(zip(poses, scans, strict=True))]  # fmt: skip
    origins = np.array([p.translation for p in poses])
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


def read_pgm(path: PathLike) -> NDArray[np.uint8]:
    """A binary (P5) 8-bit PGM as written by :func:`write_map` (row 0 at the top)."""
    data = Path(path).read_bytes()
    parts = data.split(maxsplit=4)
    if len(parts) < 5 or parts[0] != b"P5" or parts[3] != b"255":
        raise ValueError(f"path: {path} is not an 8-bit binary PGM")
    w, h = int(parts[1]), int(parts[2])
    pixels = np.frombuffer(parts[4][: w * h], dtype=np.uint8)
    if pixels.size != w * h:
        raise ValueError(f"path: {path} is truncated")
    out: NDArray[np.uint8] = pixels.reshape(h, w).copy()
    return out
