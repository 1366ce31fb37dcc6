"""Preprocessing: voxel grid, subsampling, crops, outliers, normals and covariances."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import scanreg
from hypothesis import given, settings
from hypothesis import strategies as st
from scanreg import preprocess as pp


def voxel_reference(points: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Independent numpy groupby: voxels ordered by first appearance."""
    keys = np.floor(points / size).astype(np.int64)
    _, first, inverse, counts = np.unique(
        keys, axis=0, return_index=True, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(first), points.shape[1]))
    np.add.at(sums, inverse, points)
    order = np.argsort(first)
    return (sums / counts[:, None])[order], first[order], counts[order]


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from([2, 3]),
    st.integers(1, 400),
    st.floats(0.05, 3.0),
    st.integers(0, 2**32 - 1),
)
def test_voxel_centroid_matches_numpy_groupby(dim: int, n: int, size: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    pts = rng.normal(0, 2, (n, dim))
    pts[: n // 4] = pts[n // 2 : n // 2 + n // 4]  # duplicates
    got = pp.voxel_downsample(pts, size)
    want_pts, want_first, want_counts = voxel_reference(pts, size)
    np.testing.assert_array_equal(got.indices, want_first)
    np.testing.assert_array_equal(got.counts, want_counts)
    np.testing.assert_allclose(got.points, want_pts, rtol=0, atol=1e-12)
    first = pp.voxel_downsample(pts, size, keep="first")
    np.testing.assert_array_equal(first.points, pts[want_first])
    assert got.counts.sum() == n


def test_random_subsample() -> None:
    pts = np.random.default_rng(0).normal(size=(1000, 3))
    a = pp.random_subsample(pts, 100, seed=7)
    assert a.num_kept == 100 and len(np.unique(a.indices)) == 100
    assert np.all(np.diff(a.indices) > 0)
    np.testing.assert_array_equal(a.points, pts[a.indices])
    np.testing.assert_array_equal(a.indices, pp.random_subsample(pts, 100, seed=7).indices)
    assert not np.array_equal(a.indices, pp.random_subsample(pts, 100, seed=8).indices)
    assert pp.random_subsample(pts, fraction=0.25, seed=1).num_kept == 250
    # Uniform: over many seeds every index is drawn about equally often.
    hits = np.zeros(50)
    small = pts[:50]
    for s in range(400):
        hits[pp.random_subsample(small, 10, seed=s).indices] += 1
    assert abs(hits.mean() - 80) < 1e-9 and hits.min() > 45 and hits.max() < 120


def test_crops() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform(-10, 10, (2000, 3))
    r = np.linalg.norm(pts, axis=1)
    c = pp.crop_range(pts, 2.0, 8.0)
    np.testing.assert_array_equal(c.indices, np.flatnonzero((r >= 2) & (r <= 8)))
    b = pp.crop_box(pts, [-1, -2, -np.inf], [3, 4, 0])
    inside = (pts[:, 0] >= -1) & (pts[:, 0] <= 3) & (pts[:, 1] >= -2) & (pts[:, 1] <= 4)
    inside &= pts[:, 2] <= 0
    np.testing.assert_array_equal(b.indices, np.flatnonzero(inside))
    np.testing.assert_array_equal(b.points, pts[inside])
    assert b.num_removed == 2000 - inside.sum()
    with pytest.raises(ValueError, match=r"points: no point left after crop_range"):
        pp.crop_range(pts, 100.0, 200.0)
    with pytest.raises(ValueError, match=r"points: no point left after crop_box"):
        pp.crop_box(pts, [20, 20, 20], [30, 30, 30])


def test_outlier_removal_removes_planted_outliers() -> None:
    rng = np.random.default_rng(2)
    inliers = rng.uniform(-1, 1, (3000, 3)) * [5, 5, 0.05]  # a noisy slab
    outliers = rng.uniform(-1, 1, (30, 3)) * 20 + [0, 0, 30]  # far, sparse
    pts = np.vstack([inliers, outliers])
    s = pp.remove_statistical_outliers(pts, num_neighbors=10, std_ratio=2.0)
    assert set(range(3000, 3030)).isdisjoint(s.indices.tolist())
    assert s.num_kept >= 2950  # at most ~1.7% of inliers lost
    assert np.all(s.mean_distances[s.indices] <= s.threshold)
    r = pp.remove_radius_outliers(pts, radius=0.5, min_neighbors=3)
    assert set(range(3000, 3030)).isdisjoint(r.indices.tolist())
    assert r.num_kept >= 2990


def _orthonormal(rng: np.random.Generator, dim: int) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    return q


@pytest.mark.parametrize("dim", [2, 3])
def test_normals_of_planes_and_lines(dim: int) -> None:
    """Points on a plane (3D) / line (2D) in a random pose: the analytic normal to 1e-9,
    facing the viewpoint."""
    rng = np.random.default_rng(10 + dim)
    basis = _orthonormal(rng, dim)
    normal = basis[:, 0]
    offset = 3.0
    coords = rng.uniform(-2, 2, (500, dim - 1))
    pts = offset * normal + coords @ basis[:, 1:].T
    for viewpoint, sign in ((np.zeros(dim), -1.0), (10 * normal, 1.0)):
        res = pp.estimate_normals(pts, num_neighbors=10, viewpoint=viewpoint)
        assert res.num_invalid == 0
        np.testing.assert_allclose(res.normals, np.tile(sign * normal, (500, 1)), atol=1e-9)
        facing = np.einsum("ij,ij->i", res.normals, viewpoint - pts)
        assert np.all(facing > 0)


@pytest.mark.parametrize("dim", [2, 3])
def test_normals_of_spheres_and_circles(dim: int) -> None:
    """Random samples of a unit sphere (circle): normals point inwards towards a viewpoint at
    the centre and match the radial direction to a median of 1° and at most 6° (random sampling
    leaves some neighbourhoods lopsided, which tilts the PCA plane on a curved surface)."""
    rng = np.random.default_rng(20 + dim)
    n = 4000 if dim == 3 else 800
    center = np.array([1.0, -2.0, 0.5][:dim])
    u = rng.normal(size=(n, dim))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = center + u
    res = pp.estimate_normals(pts, num_neighbors=10, viewpoint=center)
    cos = np.einsum("ij,ij->i", res.normals, -u)
    assert cos.min() > np.cos(np.deg2rad(6.0))
    assert np.median(cos) > np.cos(np.deg2rad(1.0))


@pytest.mark.parametrize("dim", [2, 3])
def test_covariance_regularisation_eigenvalues(dim: int) -> None:
    rng = np.random.default_rng(30 + dim)
    pts = rng.normal(size=(300, dim)) * np.array([3.0, 1.0, 0.2][:dim])
    plane = pp.estimate_covariances(pts, num_neighbors=12, regularization="plane", epsilon=1e-3)
    want = np.array([1e-3] + [1.0] * (dim - 1))
    ev = np.linalg.eigvalsh(plane.covariances)
    np.testing.assert_allclose(ev, np.tile(want, (300, 1)), atol=1e-12)
    # Its thin axis is the normal.
    normals = pp.estimate_normals(pts, num_neighbors=12).normals
    thin = np.einsum("ni,nij,nj->n", normals, plane.covariances, normals)
    np.testing.assert_allclose(thin, 1e-3, atol=1e-12)
    raw = pp.estimate_covariances(pts, num_neighbors=12, regularization="none")
    # Raw covariance of point 0's neighbourhood, computed independently.
    d2 = ((pts - pts[0]) ** 2).sum(axis=1)
    nb = pts[np.argsort(d2, kind="stable")[:12]]
    np.testing.assert_allclose(raw.covariances[0], np.cov(nb.T, bias=True), atol=1e-12)
    nme = pp.estimate_covariances(
        pts, num_neighbors=12, regularization="normalized_min_eig", epsilon=0.05
    )
    ev = np.linalg.eigvalsh(nme.covariances)
    np.testing.assert_allclose(ev[:, -1], 1.0, atol=1e-12)
    assert ev.min() >= 0.05 - 1e-12
    np.testing.assert_allclose(plane.covariances, np.swapaxes(plane.covariances, 1, 2))


def test_degenerate_neighbourhoods_are_flagged() -> None:
    line = np.outer(np.arange(20.0), [1.0, 2.0, -1.0])  # collinear in 3D: no plane normal
    res = pp.estimate_normals(line, num_neighbors=5)
    assert res.num_invalid == 20 and not res.valid.any()
    assert np.all(res.normals == 0.0)
    cov = pp.estimate_covariances(line, num_neighbors=5)
    np.testing.assert_array_equal(cov.covariances, np.tile(np.eye(3), (20, 1, 1)))


_DETERMINISM = """
import hashlib, json, numpy as np, scanreg
from scanreg import preprocess as pp
rng = np.random.default_rng(5)
pts = rng.normal(0, 4, (20000, 3))
h = hashlib.sha256()
v = pp.voxel_downsample(pts, 0.5)
h.update(v.points.tobytes()); h.update(v.indices.tobytes())
t = scanreg.prepare(v.points, covariances=True, num_neighbors=10)
h.update(t.normals.tobytes()); h.update(t.covariances.tobytes())
h.update(t.nearest(pts, 0.3).indices.tobytes())
h.update(pp.remove_statistical_outliers(pts, num_neighbors=8).indices.tobytes())
print(json.dumps(h.hexdigest()))
"""


def test_deterministic_across_thread_counts() -> None:
    digests = []
    for threads in ("1", "2", "5"):
        env = {**os.environ, "RAYON_NUM_THREADS": threads}
        out = subprocess.run(
            [sys.executable, "-c", _DETERMINISM], env=env, check=True, capture_output=True
        )
        digests.append(json.loads(out.stdout))
    assert digests[0] == digests[1] == digests[2]


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda p: pp.voxel_downsample(p, 0.0), ValueError, "voxel_size: must be finite and > 0"),
        (lambda p: pp.voxel_downsample(p, -1.0), ValueError, "voxel_size"),
        (lambda p: pp.voxel_downsample(p, float("nan")), ValueError, "voxel_size"),
        (lambda p: pp.voxel_downsample(p, 1e-300), ValueError, "voxel_size: .* too small"),
        (lambda p: pp.voxel_downsample(p, 1.0, keep="mean"), ValueError, "keep"),
        (
            lambda p: pp.estimate_normals(p, num_neighbors=0),
            ValueError,
            "num_neighbors: must be >= 1",
        ),
        (
            lambda p: pp.estimate_normals(p, num_neighbors=2),
            ValueError,
            "num_neighbors: must be >= 3",
        ),
        (lambda p: pp.estimate_normals(p, num_neighbors=11), ValueError, "num_neighbors: is 11"),
        (
            lambda p: pp.estimate_normals(p, num_neighbors=2.5),
            TypeError,
            "num_neighbors: expected an int",
        ),
        (
            lambda p: pp.estimate_normals(p, num_neighbors=5, viewpoint=[0, 0]),
            ValueError,
            "viewpoint",
        ),
        (lambda p: pp.estimate_covariances(p, num_neighbors=5, epsilon=0), ValueError, "epsilon"),
        (
            lambda p: pp.remove_statistical_outliers(p, num_neighbors=10),
            ValueError,
            "num_neighbors: is 10",
        ),
        (
            lambda p: pp.remove_statistical_outliers(p, num_neighbors=5, std_ratio=np.inf),
            ValueError,
            "std_ratio",
        ),
        (lambda p: pp.remove_radius_outliers(p, radius=0.0), ValueError, "radius"),
        (lambda p: pp.remove_radius_outliers(p, radius=1.0, min_neighbors=0), ValueError, "min_"),
        (lambda p: pp.random_subsample(p, 11), ValueError, "n: is 11"),
        (lambda p: pp.random_subsample(p), ValueError, "exactly one of n or fraction"),
        (lambda p: pp.random_subsample(p, fraction=1.5), ValueError, "fraction"),
        (lambda p: pp.random_subsample(p, 3, seed=-1), ValueError, "seed"),
        (lambda p: pp.crop_range(p, 5.0, 1.0), ValueError, "max_distance"),
        (lambda p: pp.crop_range(p, -1.0), ValueError, "min_distance"),
        (lambda p: pp.crop_box(p, [0, 0], [1, 1]), ValueError, "min_corner"),
        (lambda p: pp.crop_box(p, [1, 0, 0], [0, 1, 1]), ValueError, "max_corner"),
    ],
)
def test_hostile_arguments(call: object, exc: type, match: str) -> None:
    pts = np.random.default_rng(0).normal(size=(10, 3))
    with pytest.raises(exc, match=match):
        call(pts)  # type: ignore[operator]


@pytest.mark.parametrize(
    "fn",
    [
        lambda p: pp.voxel_downsample(p, 1.0),
        lambda p: pp.estimate_normals(p),
        lambda p: pp.crop_range(p),
        lambda p: pp.remove_statistical_outliers(p),
        lambda p: scanreg.prepare(p),
    ],
)
def test_hostile_points(fn: object) -> None:
    with pytest.raises(ValueError, match="points: is empty"):
        fn(np.zeros((0, 3)))  # type: ignore[operator]
    with pytest.raises(ValueError, match="points: point 1 has a non-finite"):
        fn(np.array([[0.0, 0, 0], [np.nan, 0, 0], [1, 1, 1]]))  # type: ignore[operator]
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 2\) or \(N, 3\)"):
        fn(np.zeros((10, 4)))  # type: ignore[operator]
    with pytest.raises(ValueError, match=r"points: expected shape"):
        fn(np.zeros(10))  # type: ignore[operator]


def test_drop_linear_leaves_lidar_rings_without_normals() -> None:
    """A thin strip (a LiDAR ring on a wall: every neighbourhood is a line) gets no normal with
    ``drop_linear``, a regular grid keeps its exact normal; 2D is unaffected; the flag is typed."""
    strip = np.array([[0.1 * i, 5.0 + 0.03 * (i % 2), 1.0] for i in range(40)])
    gx, gy = np.meshgrid(np.arange(10) * 0.1, np.arange(10) * 0.1)
    grid = np.column_stack([gx.ravel(), gy.ravel(), np.ones(100)])
    pts = np.vstack([strip, grid])
    kept = pp.estimate_normals(pts, num_neighbors=8)
    dropped = pp.estimate_normals(pts, num_neighbors=8, drop_linear=True)
    assert kept.num_linear == 0 and kept.num_invalid == 0
    assert not dropped.valid[:40].any() and np.all(dropped.normals[:40] == 0.0)
    interior = np.array([0 < i % 10 < 9 and 0 < i // 10 < 9 for i in range(100)])
    assert dropped.valid[40:][interior].all()
    np.testing.assert_allclose(np.abs(dropped.normals[40:][interior, 2]), 1.0, atol=1e-12)
    assert dropped.num_invalid == dropped.num_linear == int((~dropped.valid).sum()) >= 40
    target = scanreg.prepare(pts, num_neighbors=8, drop_linear=True)
    assert target.valid is not None and target.valid.all(), "valid still means non-degenerate"
    assert target.normals is not None and np.all(target.normals[:40] == 0.0)
    flat = np.column_stack([np.arange(30) * 0.1, 0.01 * (np.arange(30) % 2)])
    assert pp.estimate_normals(flat, num_neighbors=5, drop_linear=True).num_invalid == 0
    with pytest.raises(TypeError, match="drop_linear: expected a bool"):
        pp.estimate_normals(pts, num_neighbors=8, drop_linear=1)  # type: ignore[arg-type]
