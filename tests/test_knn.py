"""Neighbour search: k-d tree and voxel index against brute force; the prepared target."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import scanreg
from hypothesis import given, settings
from hypothesis import strategies as st


def brute_d2(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    diff = queries[:, None, :] - points[None, :, :]
    return (diff * diff).sum(axis=2)


@st.composite
def clouds(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    dim = draw(st.sampled_from([2, 3]))
    n = draw(st.integers(1, 120))
    m = draw(st.integers(0, 30))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    if draw(st.booleans()):
        # Integer lattice: many exact ties and duplicate points.
        pts = rng.integers(-3, 4, (n, dim)).astype(np.float64)
        qs = rng.integers(-4, 5, (m, dim)).astype(np.float64)
    else:
        pts = rng.normal(0, 2, (n, dim))
        qs = rng.normal(0, 2, (m, dim))
    return pts, qs


@settings(max_examples=60, deadline=None)
@given(clouds(), st.floats(0.0, 4.0))
def test_nearest_matches_brute_force(data: tuple[np.ndarray, np.ndarray], gate: float) -> None:
    pts, qs = data
    target = scanreg.prepare(pts, normals=False)
    d2 = brute_d2(pts, qs)
    res = target.nearest(qs)  # no gate
    if len(qs):
        np.testing.assert_allclose(res.squared_distances, d2.min(axis=1), rtol=1e-12, atol=0)
        # The returned index is one of the (possibly tied) nearest points.
        np.testing.assert_allclose(
            d2[np.arange(len(qs)), res.indices], d2.min(axis=1), rtol=1e-12, atol=0
        )
    gated = target.nearest(qs, gate)
    inside = d2.min(axis=1) <= gate * gate if len(qs) else np.zeros(0, bool)
    np.testing.assert_array_equal(gated.found, inside)
    assert np.all(gated.indices[~inside] == -1)
    assert np.all(np.isinf(gated.squared_distances[~inside]))


@settings(max_examples=60, deadline=None)
@given(clouds(), st.integers(1, 10), st.floats(0.0, 3.0))
def test_knn_and_radius_match_brute_force(
    data: tuple[np.ndarray, np.ndarray], k: int, radius: float
) -> None:
    pts, qs = data
    k = min(k, len(pts))
    target = scanreg.prepare(pts, normals=False)
    d2 = brute_d2(pts, qs)
    nb = target.knn(qs, k)
    assert nb.indices.shape == (len(qs), k)
    np.testing.assert_allclose(nb.squared_distances, np.sort(d2, axis=1)[:, :k], rtol=1e-12)
    for i in range(len(qs)):
        np.testing.assert_allclose(d2[i, nb.indices[i]], nb.squared_distances[i], rtol=1e-12)
        assert len(set(nb.indices[i].tolist())) == k
    rn = target.radius(qs, radius)
    for i in range(len(qs)):
        want = np.flatnonzero(d2[i] <= radius * radius)
        # Sorted by (distance, index): lexsort by distance then index.
        want = want[np.lexsort((want, d2[i, want]))]
        np.testing.assert_array_equal(rn.row(i), want)


def test_results_do_not_depend_on_thread_count() -> None:
    """Same input, same bits, whether 1 or many Python threads query concurrently (the GIL is
    released) and whatever rayon's pool size (checked in Rust with explicit pools)."""
    rng = np.random.default_rng(3)
    pts = rng.normal(0, 5, (3000, 3))
    qs = rng.normal(0, 5, (2000, 3))
    target = scanreg.prepare(pts, covariances=True)
    ref = target.nearest(qs, 1.0)
    out: list[scanreg.target.Nearest] = []

    def work() -> None:
        out.append(target.nearest(qs, 1.0))

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(out) == 4
    for r in out:
        np.testing.assert_array_equal(r.indices, ref.indices)
        np.testing.assert_array_equal(r.squared_distances, ref.squared_distances)


def test_prepared_target_is_immutable() -> None:
    pts = np.random.default_rng(0).normal(size=(50, 3))
    target = scanreg.prepare(pts, covariances=True, num_neighbors=8)
    assert target.points is not pts and np.array_equal(target.points, pts)
    assert target.normals is not None and target.covariances is not None
    assert target.covariances.shape == (50, 3, 3)
    for a in (target.points, target.normals, target.covariances):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 0.0
    with pytest.raises(AttributeError):
        target.num_neighbors = 3  # type: ignore[misc]
    pts[0] = 99.0  # the caller's array is not shared
    assert not np.array_equal(target.points[0], pts[0])


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda t: t.nearest(np.zeros((2, 2)), 1.0), r"query_points: expected shape \(N, 3\)"),
        (lambda t: t.nearest(np.full((2, 3), np.nan), 1.0), "query_points: point 0"),
        (lambda t: t.nearest(np.zeros((2, 3)), -1.0), "max_distance"),
        (lambda t: t.nearest(np.zeros((2, 3)), float("nan")), "max_distance"),
        (lambda t: t.knn(np.zeros((2, 3)), 0), "num_neighbors: must be >= 1"),
        (lambda t: t.knn(np.zeros((2, 3)), 11), "num_neighbors: is 11"),
        (lambda t: t.radius(np.zeros((2, 3)), -0.5), "radius"),
    ],
)
def test_hostile_queries(call: object, match: str) -> None:
    target = scanreg.prepare(np.random.default_rng(1).normal(size=(10, 3)), normals=False)
    with pytest.raises(ValueError, match=match):
        call(target)  # type: ignore[operator]


def test_hostile_prepare() -> None:
    with pytest.raises(ValueError, match="points: is empty"):
        scanreg.prepare(np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"points: expected shape"):
        scanreg.prepare(np.zeros((5, 4)))
    with pytest.raises(TypeError, match="points: expected real numbers"):
        scanreg.prepare(np.zeros((5, 3), np.complex128))
    with pytest.raises(ValueError, match="points: point 2 has a non-finite"):
        scanreg.prepare(np.array([[0.0, 0, 0], [1, 0, 0], [np.inf, 0, 0]]))
    with pytest.raises(ValueError, match="num_neighbors: is 30 but points has only 5"):
        scanreg.prepare(np.random.default_rng(0).normal(size=(5, 3)), num_neighbors=30)
    with pytest.raises(ValueError, match="regularization"):
        scanreg.prepare(np.zeros((5, 3)), regularization="bogus")  # type: ignore[arg-type]
