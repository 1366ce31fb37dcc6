"""Scanned objects: points sampled from closed surfaces a few decimetres across, seen from one
side, with exact truth.

An object scan (a turntable, a hand-held scanner) is a partial view: the surface facing the
sensor, sampled densely, with millimetre noise. ``object_view`` keeps the points whose outward
normal faces the viewpoint (back faces culled; an object's parts hiding each other are not
modelled), so two views from different sides overlap partially.

Example::

    from scanreg import simulate as sim

    knot = sim.trefoil_knot(size=0.2)
    front = sim.object_view(knot, [1.0, 0.0, 0.3], num_points=30_000, noise=0.002, seed=1)
    side = sim.object_view(knot, [0.0, 1.0, 0.3], num_points=30_000, noise=0.002, seed=2)

Shapes are parametric surfaces ``p(u, v)`` on the unit square, sampled uniformly by area
(rejection on ``|p_u × p_v|``), centred on their bounding box and scaled so that its longest side
is ``size``. None of them has a rotational symmetry, so every view has one true pose.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray, frozen
from ._checks import count, non_negative, positive
from ._checks import seed as check_seed

__all__ = ["ObjectShape", "blob", "figurine", "object_view", "trefoil_knot"]

#: ``(u, v) -> (points, core)``: ``(N, 3)`` surface points and, for each, a point inside the
#: surface nearby (a tube's axis, a blob's centre) that tells outward from inward.
Surface = Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]

#: Step of the finite differences that give the surface's tangents (parameter units).
_STEP = 1e-5


@dataclass(frozen=True, eq=False)
class ObjectShape:
    """A closed surface to sample (build with :func:`trefoil_knot`, :func:`blob`,
    :func:`figurine`)."""

    name: str
    #: Length of the bounding box's longest side (units of the points).
    size: float
    #: The surface's parts (one for a knot or a blob; a figurine's ellipsoids).
    _parts: tuple[Surface, ...]
    #: Above each part's largest area element: the rejection sampling's bound.
    _peaks: FloatArray
    #: Fraction of the draws the rejection keeps (all parts together).
    _acceptance: float
    #: Scale and offset that centre the raw surface's bounding box and give it ``size``.
    _scale: float
    _offset: FloatArray

    def sample(self, num_points: int, seed: int = 0) -> tuple[FloatArray, FloatArray]:
        """``(points, normals)``: ``num_points`` points uniform by area and their outward unit
        normals, both ``(N, 3)``."""
        n = count(num_points, "num_points")
        rng = np.random.default_rng(check_seed(seed))
        pts, nrm = _area_sample(self._parts, self._peaks, self._acceptance, n, rng)
        return frozen(pts * self._scale + self._offset), frozen(nrm)


def _candidates(
    surface: Surface, m: int, peak: float, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """The points of ``m`` uniform draws of ``(u, v)`` kept with probability ``|p_u × p_v| /
    peak`` (and on the surface: ``core`` finite), and their outward normals."""
    u, v = rng.uniform(size=m), rng.uniform(size=m)
    p, core = surface(u, v)
    cross = _tangent_cross(surface, u, v, p)
    area = np.linalg.norm(cross, axis=1)
    keep = (rng.uniform(size=m) * peak < area) & np.isfinite(core).all(axis=1)
    normal = cross[keep] / area[keep, None]
    outward = np.einsum("ij,ij->i", normal, p[keep] - core[keep]) >= 0
    return p[keep], normal * np.where(outward, 1.0, -1.0)[:, None]


def _tangent_cross(surface: Surface, u: FloatArray, v: FloatArray, p: FloatArray) -> FloatArray:
    """``p_u × p_v`` by forward differences (``p``: the surface at ``(u, v)``)."""
    du = (surface(u + _STEP, v)[0] - p) / _STEP
    dv = (surface(u, v + _STEP)[0] - p) / _STEP
    return np.cross(du, dv)


def _area_sample(
    parts: tuple[Surface, ...],
    peaks: FloatArray,
    acceptance: float,
    n: int,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """``n`` points uniform by area over ``parts`` (unscaled) and their normals."""
    pts_out: list[FloatArray] = []
    nrm_out: list[FloatArray] = []
    kept = 0
    while kept < n:
        # Draws per part in proportion to its bound: every part then keeps points at the
        # same density per unit area.
        wanted = int(1.1 * (n - kept) / acceptance) + 100
        draws = rng.multinomial(wanted, peaks / peaks.sum())
        for surface, peak, m in zip(parts, peaks, draws, strict=True):
            p, nrm = _candidates(surface, int(m), float(peak), rng)
            pts_out.append(p)
            nrm_out.append(nrm)
            kept += len(p)
    order = rng.permutation(kept)[:n]
    return np.concatenate(pts_out)[order], np.concatenate(nrm_out)[order]


def _shape(name: str, parts: tuple[Surface, ...], size: Any) -> ObjectShape:
    s = positive(size, "size")
    # Fixed draws: the same shape every time.
    rng = np.random.default_rng(0)
    peaks, areas = [], []
    for surface in parts:
        u, v = rng.uniform(size=20_000), rng.uniform(size=20_000)
        area = np.linalg.norm(_tangent_cross(surface, u, v, surface(u, v)[0]), axis=1)
        # Not the maximum: the differences are wrong within a step of a pole (a sphere's
        # sqrt(1 - z²)), and one such spike made the rejection keep a point in thousands.
        peaks.append(1.2 * float(np.quantile(area, 0.999)))
        areas.append(float(area.mean()))
    peak_array = np.array(peaks)
    acceptance = sum(areas) / float(peak_array.sum())
    pts, _ = _area_sample(parts, peak_array, acceptance, 20_000, rng)
    lo, hi = pts.min(0), pts.max(0)
    scale = s / float((hi - lo).max())
    offset = frozen(-0.5 * (lo + hi) * scale)
    return ObjectShape(name, s, parts, frozen(peak_array), acceptance, scale, offset)


def trefoil_knot(size: float = 0.2) -> ObjectShape:
    """A tube along the trefoil knot ``(sin t + 2 sin 2t, cos t − 2 cos 2t, −sin 3t)``.

    The standard knot is unchanged by turns of 120° about its axis and of 180° about three
    axes across it; its tube here swells once along the knot (radius 0.3 of the knot's unit,
    0.55 at the swelling), so that it is not: a small, noisy scan of a symmetric knot has no
    single true pose.
    """

    def surface(u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        t, phi = 2 * math.pi * u, 2 * math.pi * v
        c = np.column_stack(
            [np.sin(t) + 2 * np.sin(2 * t), np.cos(t) - 2 * np.cos(2 * t), -np.sin(3 * t)]
        )
        d1 = np.column_stack(
            [np.cos(t) + 4 * np.cos(2 * t), -np.sin(t) + 4 * np.sin(2 * t), -3 * np.cos(3 * t)]
        )
        d2 = np.column_stack(
            [-np.sin(t) - 8 * np.sin(2 * t), -np.cos(t) + 8 * np.cos(2 * t), 9 * np.sin(3 * t)]
        )
        tangent = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
        normal = d2 - np.einsum("ij,ij->i", d2, tangent)[:, None] * tangent
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        binormal = np.cross(tangent, normal)
        radius = 0.3 + 0.25 * np.exp((np.cos(t - 0.5) - 1) / 0.15)
        ring = np.cos(phi)[:, None] * normal + np.sin(phi)[:, None] * binormal
        return c + radius[:, None] * ring, c

    return _shape("trefoil_knot", (surface,), size)


def blob(size: float = 0.2, seed: int = 0, bumps: int = 6) -> ObjectShape:
    """An organic blob: a sphere whose radius swells and dips smoothly with direction (a sum of
    ``bumps`` random low-frequency lobes, ``seed`` picks them), a pebble or a potato."""
    rng = np.random.default_rng(check_seed(seed))
    k = count(bumps, "bumps")
    axes = rng.normal(size=(k, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    freq = rng.uniform(1.0, 3.0, size=k)
    amp = rng.uniform(0.05, 0.12, size=k)
    phase = rng.uniform(0, 2 * math.pi, size=k)
    stretch = np.array([1.0, rng.uniform(0.7, 0.9), rng.uniform(0.55, 0.75)])

    def surface(u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        z = 2 * u - 1
        az = 2 * math.pi * v
        r_xy = np.sqrt(np.clip(1 - z * z, 0, None))
        d = np.column_stack([r_xy * np.cos(az), r_xy * np.sin(az), z])
        r = 1 + (amp * np.cos(freq * np.einsum("ij,kj->ik", d, axes) * math.pi + phase)).sum(1)
        return d * r[:, None] * stretch, np.zeros_like(d)

    return _shape("blob", (surface,), size)


#: The figurine's parts: centre, semi-axes and a turn about z (radians) of each ellipsoid.
_FIGURINE = (
    ((0.0, 0.0, 0.0), (1.0, 0.62, 0.55), 0.0),  # body
    ((0.95, 0.15, 0.55), (0.45, 0.38, 0.36), 0.3),  # head
    ((1.05, 0.32, 1.05), (0.12, 0.07, 0.42), 0.3),  # ear
    ((0.95, -0.05, 1.0), (0.11, 0.07, 0.38), -0.2),  # ear, shorter and tilted
    ((-1.0, -0.1, 0.25), (0.22, 0.2, 0.2), 0.0),  # tail
    ((0.45, 0.35, -0.5), (0.3, 0.16, 0.12), 0.5),  # front paw
    ((-0.55, -0.3, -0.48), (0.36, 0.2, 0.14), -0.3),  # hind paw
)


def figurine(size: float = 0.2) -> ObjectShape:
    """A sitting animal made of seven ellipsoids (body, head, two unequal ears, tail, two
    paws), their union's surface: smooth parts meeting at creases, no symmetry."""
    frames = [(np.array(c), np.array(a), _turn_z(t)) for c, a, t in _FIGURINE]

    def part(i: int) -> Surface:
        centre, axes, rot = frames[i]

        def surface(u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
            z = 2 * u - 1
            az = 2 * math.pi * v
            r_xy = np.sqrt(np.clip(1 - z * z, 0, None))
            unit = np.column_stack([r_xy * np.cos(az), r_xy * np.sin(az), z])
            pts = np.einsum("ij,kj->ik", unit * axes, rot) + centre
            core = np.broadcast_to(centre, pts.shape).copy()
            # A point inside another part is not on the union's surface.
            for j, (c, a, r) in enumerate(frames):
                if j != i:
                    local = np.einsum("ij,jk->ik", pts - c, r) / a
                    core[np.einsum("ij,ij->i", local, local) < 1] = np.nan
            return pts, core

        return surface

    return _shape("figurine", tuple(part(i) for i in range(len(frames))), size)


def _turn_z(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def object_view(
    shape: ObjectShape,
    viewpoint: Any,
    num_points: int,
    *,
    noise: float = 0.0,
    seed: int = 0,
) -> FloatArray:
    """``(num_points, 3)`` points of ``shape`` whose outward normal faces ``viewpoint`` (a
    direction from the object's centre: the sensor far away along it), each moved by isotropic
    Gaussian noise of ``noise`` (standard deviation per axis, units of the points)."""
    if not isinstance(shape, ObjectShape):
        raise TypeError(f"shape: expected ObjectShape, got {type(shape).__name__}")
    direction = np.asarray(viewpoint, dtype=np.float64)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)):
        raise ValueError(f"viewpoint: expected 3 finite numbers, got {viewpoint!r}")
    length = float(np.linalg.norm(direction))
    if length == 0:
        raise ValueError("viewpoint: must not be the zero vector")
    n = count(num_points, "num_points")
    sigma = non_negative(noise, "noise")
    rng = np.random.default_rng(check_seed(seed))
    eye = direction / length * 3 * shape.size
    kept: list[FloatArray] = []
    total = 0
    while total < n:
        # Draws spawn from one generator: one view is one reproducible stream.
        pts, nrm = shape.sample(max(2 * (n - total), 1000), int(rng.integers(2**63)))
        facing = np.einsum("ij,ij->i", nrm, eye - pts) > 0
        kept.append(pts[facing])
        total += int(facing.sum())
    out = np.concatenate(kept)[:n]
    return frozen(out + rng.normal(scale=sigma, size=out.shape) if sigma > 0 else out)
