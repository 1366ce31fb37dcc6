"""How noisy a scanned surface is, and whether the noise leaves its shape resolved.

:func:`surface_noise` fits the covariance of neighbourhoods of growing size (the k nearest
points, k doubling) around sampled points and reads three regimes from its eigenvalues
``λ₁ ≥ λ₂ ≥ λ₃`` (medians over the samples):

* below the noise a neighbourhood is a ball: ``λ₂ / λ₃`` about 1;
* once it is several noise widths across it is a noisy disc: ``λ₂`` grows as the radius
  squared (``r² / 4``) while ``λ₃`` stays at the noise variance ``σ²``;
* wider still the surface's curvature lifts ``λ₃`` as the radius to the fourth and the ratio
  falls.

The ratio peaks where the noise has stopped mattering and the curvature has not started: there
``λ₃`` is ``σ²`` plus at most as much curvature (an estimate of ``σ`` within about √2 on a
smooth surface), and the peak itself, the *flatness*, says how wide a patch the surface keeps
flat above its noise (``r ≈ 2σ √flatness``). A flatness of a few means the surface bends within
a few noise widths (a tube 5 mm thick under 2-3 mm of noise): what a scan of it shows depends
on the side it was seen from, and two views from different sides no longer share one shape.

:func:`denoise` removes most of that noise across the surface: each point is moved along its
local normal onto the plane fitted to its neighbours within a few ``σ̂`` (a moving-plane
projection, in the Rust core). Two noisy views aligned by their denoised clouds are far less
biased than by the raw ones (``benchmarks/global_objects.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, as_points

#: At most this many points of the cloud (evenly spaced, not averaged: averaging would hide the
#: noise) make the neighbourhoods, around this many of them.
NOISE_POINTS = 4000
NOISE_QUERIES = 200
#: Neighbourhoods of the k nearest points, k doubling from the first to the last: k-NN rather
#: than a radius so that a LiDAR scan, dense near its sensor and sparse far away, is measured
#: at the same number of points everywhere. 10 points make a covariance; 640 of the 4000 span a
#: sixth of an object's view, past where the curvature shows on every object we measured.
NEIGHBOURS = (10, 20, 40, 80, 160, 320, 640)

#: :func:`denoise` fits each point's plane over its neighbours within this many ``σ̂``, at
#: most :data:`DENOISE_NEIGHBOURS` of them (the nearest; on a dense scan the radius holds
#: thousands). On the 0.1 and 0.2 m objects of ``benchmarks/global_objects.py`` (seed 41, two
#: views 60° apart, 1-3 mm noise), GICP started at the truth ended 0.1-3.6° / 0.1-3.0 mm from
#: it on the raw clouds and 0.01-1.3° / 0.04-2.3 mm on clouds denoised at 4 σ̂ (at 30 nearest
#: neighbours, no radius: 0.05-2.1° / 0.04-2.8 mm).
DENOISE_RADIUS_SIGMAS = 4.0
DENOISE_NEIGHBOURS = 200


@dataclass(frozen=True)
class SurfaceNoise:
    """What :func:`surface_noise` measured."""

    #: Spread across the surface (units of the points): the root of the median smallest
    #: eigenvalue at the flattest scale. 0 when nothing could be measured.
    sigma: float
    #: Median distance to the farthest of the neighbours at the flattest scale.
    radius: float
    #: Median ``λ₂ / λ₃`` there: how far the surface stays flat above its noise
    #: (``radius ≈ 2 σ √flatness`` on a flat patch). ``inf`` on noise-free planes.
    flatness: float


def surface_noise(points: Any) -> SurfaceNoise:
    """The noise and flatness of a scanned surface (module docs), from neighbourhoods of
    :data:`NEIGHBOURS` points around :data:`NOISE_QUERIES` samples."""
    pts = as_points(points, "points", dim=3, min_points=NEIGHBOURS[0])
    cloud = np.ascontiguousarray(pts[:: max(1, len(pts) // NOISE_POINTS)])
    tree = _core.KdTree(cloud)
    queries = np.ascontiguousarray(cloud[:: max(1, len(cloud) // NOISE_QUERIES)])
    best = SurfaceNoise(0.0, 0.0, 0.0)
    # One search for the widest scale; its rows are sorted, so each narrower one is a prefix.
    widest, widest_d2 = tree.knn(queries, max(k for k in NEIGHBOURS if k <= len(cloud)))
    for k in NEIGHBOURS:
        if k > len(cloud):
            break
        index, d2 = widest[:, :k], widest_d2[:, :k]
        local = cloud[index]  # (queries, k, 3)
        centred = local - local.mean(axis=1, keepdims=True)
        cov = np.matmul(centred.transpose(0, 2, 1), centred) / k
        eig = np.linalg.eigvalsh(cov)
        smallest = max(float(np.median(eig[:, 0])), 0.0)
        middle = float(np.median(eig[:, 1]))
        flatness = middle / smallest if smallest > 0 else math.inf
        if flatness > best.flatness:
            radius = float(np.sqrt(np.median(d2[:, -1])))
            best = SurfaceNoise(math.sqrt(smallest), radius, flatness)
    return best


def denoise(points: Any, noise: SurfaceNoise | None = None) -> FloatArray:
    """``points`` each moved along its local normal onto the plane of its neighbours (at most
    :data:`DENOISE_NEIGHBOURS` within :data:`DENOISE_RADIUS_SIGMAS` ``σ̂``), ``σ̂`` from
    ``noise`` (default: :func:`surface_noise` of ``points``). A copy of ``points`` when
    ``σ̂`` is 0 (nothing measured, or a noise-free plane); points with too few neighbours stay."""
    pts = as_points(points, "points", dim=3, min_points=NEIGHBOURS[0])
    if noise is None:
        noise = surface_noise(pts)
    elif not isinstance(noise, SurfaceNoise):
        raise TypeError(f"noise: expected SurfaceNoise, got {type(noise).__name__}")
    if not noise.sigma > 0:
        return np.array(pts)
    k = min(DENOISE_NEIGHBOURS, len(pts))
    return _core.KdTree(pts).project_to_local_planes(k, DENOISE_RADIUS_SIGMAS * noise.sigma)
