"""Scanned objects sampled from surfaces: size, uniform area density, outward normals, views."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scanreg import simulate as sim
from scanreg.simulate.objects import _shape


@pytest.mark.parametrize("make", [sim.trefoil_knot, sim.blob, sim.figurine])
def test_a_shape_has_its_size_and_outward_unit_normals(make) -> None:  # type: ignore[no-untyped-def]
    shape = make(size=0.3)
    pts, nrm = shape.sample(20_000, seed=4)
    assert pts.shape == nrm.shape == (20_000, 3)
    extent = pts.max(0) - pts.min(0)
    assert extent.max() == pytest.approx(0.3, rel=0.01)
    np.testing.assert_allclose(pts.max(0) + pts.min(0), 0.0, atol=0.005)  # centred
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-9)
    # Outward: a step along the normal leaves the nearest surface behind it, so going out
    # by 1 mm takes a point farther from the centre more often than not, never inward for
    # the blob (a star-shaped surface: its normal always has a positive radial part).
    radial = np.einsum("ij,ij->i", nrm, pts)
    if shape.name == "blob":
        assert (radial > 0).all()
    else:
        assert (radial > 0).mean() > 0.6
    assert not pts.flags.writeable


def test_samples_are_uniform_by_area() -> None:
    # A sphere parametrised by polar angle: uniform (u, v) would crowd the poles (area element
    # sin θ); by area, the band |z| < r/2 holds half of the points (Archimedes).
    def sphere(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta, phi = math.pi * u, 2 * math.pi * v
        pts = np.column_stack(
            [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
        )
        return pts, np.zeros_like(pts)

    shape = _shape("sphere", (sphere,), 0.2)
    pts, nrm = shape.sample(40_000, seed=1)
    share = float(np.mean(np.abs(pts[:, 2]) < 0.05))
    assert share == pytest.approx(0.5, abs=0.01), share  # uniform (u, v) gives 1/3
    np.testing.assert_allclose(np.einsum("ij,ij->i", nrm, pts / 0.1), 1.0, atol=1e-3)
    # Two draws with the same seed are the same; another seed differs.
    again, _ = shape.sample(40_000, seed=1)
    np.testing.assert_array_equal(pts, again)
    assert not np.array_equal(pts, shape.sample(40_000, seed=2)[0])


def test_a_view_keeps_the_side_facing_its_viewpoint() -> None:
    shape = sim.figurine(size=0.2)
    front = sim.object_view(shape, [1.0, 0.0, 0.0], 10_000, seed=3)
    back = sim.object_view(shape, [-1.0, 0.0, 0.0], 10_000, seed=3)
    assert front.shape == (10_000, 3)
    # The far side of each view is missing: the front view has few points with x < -0.05
    # (the body's back), which the back view is full of (its head, at x > 0, faces both).
    assert np.mean(front[:, 0] < -0.05) < 0.05 < 0.2 < np.mean(back[:, 0] < -0.05)
    assert front[:, 0].mean() > 0.02 > -0.02 > back[:, 0].mean()
    noisy = sim.object_view(shape, [1.0, 0.0, 0.0], 10_000, seed=3, noise=0.002)
    # The same draw moved by the noise: its per-axis spread is the noise.
    assert np.std(noisy - front) == pytest.approx(0.002, rel=0.05)


def test_bad_arguments_are_named() -> None:
    knot = sim.trefoil_knot()
    with pytest.raises(ValueError, match="viewpoint: must not be the zero vector"):
        sim.object_view(knot, [0, 0, 0], 100)
    with pytest.raises(ValueError, match="viewpoint: expected 3 finite numbers"):
        sim.object_view(knot, [1, math.nan, 0], 100)
    with pytest.raises(ValueError, match="noise: must be >= 0"):
        sim.object_view(knot, [1, 0, 0], 100, noise=-1.0)
    with pytest.raises(TypeError, match="shape: expected ObjectShape"):
        sim.object_view("knot", [1, 0, 0], 100)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="size: must be > 0"):
        sim.blob(size=0.0)
    with pytest.raises(ValueError, match="num_points: must be >= 1"):
        knot.sample(0)
