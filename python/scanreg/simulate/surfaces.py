"""Points sampled along a 2D scene's outlines: a cloud that is not one scan from one viewpoint.

A map, a merged submap or a drawing's walls sample every side of every object, the far side of
an obstacle and the wall behind it included; no scan from one place does. These are the clouds
the 2D covariance's sampling model has to recognise (``scanreg_core::trust::scene``).
"""

from __future__ import annotations

import math

import numpy as np

from .._validate import FloatArray
from ._checks import non_negative, positive
from ._checks import seed as check_seed
from .scene import BOX, CYLINDER, WALL, Scene


def _segments(scene: Scene) -> list[tuple[FloatArray, FloatArray]]:
    """The scene's outlines as straight segments ``(a, b)``: walls, box sides, and circles as
    64-gons."""
    out: list[tuple[FloatArray, FloatArray]] = []
    for row in scene.primitives:
        kind = float(row[0])
        if kind == WALL:
            out.append((np.array(row[1:3]), np.array(row[3:5])))
        elif kind == BOX:
            c, h, yaw = np.array(row[1:3]), np.array(row[4:6]), float(row[7])
            rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
            corners = [c + rot @ (h * s) for s in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            out.extend((corners[i], corners[(i + 1) % 4]) for i in range(4))
        elif kind == CYLINDER:
            c, r = np.array(row[1:3]), float(row[5])
            a = np.linspace(0.0, 2 * math.pi, 65)
            ring = c + r * np.c_[np.cos(a), np.sin(a)]
            out.extend((ring[i], ring[i + 1]) for i in range(64))
        else:
            raise ValueError(f"scene: a 2D outline has walls, boxes and circles, not kind {kind}")
    return out


#: The most points one call draws (on average): a spacing far below the outline's scale is a
#: mistake, not a cloud (1e-9 m along a floor plan asked for 24 billion).
_MAX_POINTS = 20_000_000


def surface_samples(
    scene: Scene, spacing: float, *, noise: float = 0.0, seed: int = 0
) -> FloatArray:
    """``(N, 2)`` points drawn uniformly along every outline of a 2D ``scene`` (walls, every
    side of every box, circles), one per ``spacing`` metres on average, each moved by
    isotropic Gaussian ``noise`` (m). Reproducible from ``seed``; in the scene's frame, in
    outline order (no sweep)."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a Scene, got {type(scene).__name__}")
    if scene.dim != 2:
        raise ValueError(f"scene: must be 2D, got dim {scene.dim}")
    step = positive(spacing, "spacing")
    sigma = non_negative(noise, "noise")
    rng = np.random.default_rng(check_seed(seed))
    segments = _segments(scene)
    length = sum(float(np.hypot(*(b - a))) for a, b in segments)
    if length / step > _MAX_POINTS:
        raise ValueError(
            f"spacing: {step:g} m over {length:.1f} m of outline is more than "
            f"{_MAX_POINTS:,} points; use a coarser spacing"
        )
    parts = []
    for a, b in segments:
        count = int(rng.poisson(float(np.hypot(*(b - a))) / step))
        t = rng.uniform(0.0, 1.0, count)
        parts.append(a + t[:, None] * (b - a))
    pts = np.vstack(parts) if parts else np.zeros((0, 2))
    out: FloatArray = np.ascontiguousarray(pts + rng.normal(0.0, sigma, pts.shape))
    return out
