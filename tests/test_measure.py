"""The core's overlap and normal-noise measurements against plain NumPy references (the
formulas they replaced in Python): equal to round-off."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scanreg
from scanreg import SE2, SE3, _core
from scanreg.degeneracy import correspondence_normal_noise, normal_noise, sampled_normals


def _cloud(dim: int, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # Noisy planes / lines so that normals are meaningful.
    pts = rng.uniform(-5, 5, size=(n, dim))
    pts[: n // 2, -1] = 0.02 * rng.normal(size=n // 2)
    return np.ascontiguousarray(pts)


def _ref_sampled_normals(points: np.ndarray, k: int, max_points: int) -> tuple:
    n = points.shape[0]
    idx = np.arange(0, n, max(1, n // max_points))
    nb, _ = _core.KdTree(points).knn(np.ascontiguousarray(points[idx]), min(k, n))
    hood = points[nb]
    centred = hood - hood.mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("mki,mkj->mij", centred, centred))
    return idx, vecs[:, :, 0]


def _ref_target_noise(points: np.ndarray, normals: np.ndarray, tree: _core.KdTree) -> tuple:
    valid = np.flatnonzero(np.einsum("ij,ij->i", normals, normals) > 0.25)
    sample = valid[:: max(1, valid.size // 2000)]
    idx, _ = tree.knn(np.ascontiguousarray(points[sample]), 2)
    nj = normals[idx[:, 1]]
    ok = np.einsum("ij,ij->i", nj, nj) > 0.25
    cos = np.abs(np.einsum("ij,ij->i", normals[sample][ok], nj[ok]))
    sin2 = 1.0 - np.minimum(cos, 1.0) ** 2
    return 0.5 * np.mean(sin2), 0.5 * np.median(sin2)


@pytest.mark.parametrize("dim", [2, 3])
def test_prepare_reads_the_normal_noise_off_its_own_neighbour_searches(dim: int) -> None:
    # ``prepare`` measures the noise from the normals' k-NN lists (their second entry), not a
    # second 2-NN search: the same numbers, duplicated points (distance ties) included.
    rng = np.random.default_rng(3)
    for n in (40, 2500):
        pts = rng.normal(size=(n, dim))
        m = len(pts[1::7])
        pts[0 : 7 * m : 7] = pts[1::7]
        for drop_linear in (False, dim == 3):
            target = scanreg.prepare(pts, normals=True, drop_linear=drop_linear)
            assert target.normals is not None
            want = normal_noise(target.points, target.normals, target.index)
            assert "normal_noise" in target.__dict__  # measured by prepare itself
            np.testing.assert_array_equal(target.normal_noise, want)


@pytest.mark.parametrize("dim", [2, 3])
def test_normal_noise_matches_numpy(dim: int) -> None:
    pts = _cloud(dim, 3000, 1)
    idx, nrm = sampled_normals(pts, 10, 1500)
    ref_idx, ref_nrm = _ref_sampled_normals(pts, 10, 1500)
    np.testing.assert_array_equal(idx, ref_idx)
    cos = np.abs(np.einsum("ij,ij->i", nrm, ref_nrm))  # sign is arbitrary
    np.testing.assert_allclose(cos, 1.0, atol=1e-9)

    target = scanreg.prepare(pts, normals=True, num_neighbors=10)
    assert target.normals is not None
    got = normal_noise(target.points, target.normals, target.index)
    np.testing.assert_allclose(
        got, _ref_target_noise(target.points, target.normals, target.index), rtol=1e-12
    )
    assert target.normal_noise == got

    # Between the sampled source normals and the target's, under a small rotation.
    rot = SE2.from_vector([0, 0, 0.01]) if dim == 2 else SE3.exp([0, 0, 0, 0.01, 0, 0.02])
    corr = np.where(np.arange(len(idx)) % 3 == 0, -1, idx).astype(np.int64)
    got_var = correspondence_normal_noise(nrm, target.normals, rot.rotation, corr)
    i = np.flatnonzero(corr >= 0)
    ns, nt = nrm[i] @ rot.rotation.T, target.normals[corr[i]]
    ok = (np.einsum("ij,ij->i", ns, ns) > 0.25) & (np.einsum("ij,ij->i", nt, nt) > 0.25)
    sin2 = np.sort(1.0 - np.minimum(np.abs(np.einsum("ij,ij->i", ns[ok], nt[ok])), 1.0) ** 2)
    want = np.mean(sin2[: int(0.9 * sin2.size)]) / (2.0 * (dim - 1))
    assert got_var == pytest.approx(want, rel=1e-12)
    assert math.isnan(correspondence_normal_noise(nrm[:5], target.normals, rot.rotation, corr[:5]))


@pytest.mark.parametrize("dim", [2, 3])
def test_overlap_statistics_match_numpy(dim: int) -> None:
    tgt = _cloud(dim, 2000, 2)
    src = _cloud(dim, 5000, 3)  # above the core's parallel threshold
    pose = SE2.from_vector([0.1, -0.2, 0.05]) if dim == 2 else SE3.exp([0.1, 0, 0.2, 0, 0.05, 0])
    tree = _core.KdTree(tgt)
    found, mean, median, rmse, trimmed, within = _core.overlap_statistics(
        tree, src, pose.as_matrix(), 0.3
    )
    idx, d2 = tree.nearest(pose.apply(src), 0.3)
    dist = np.sqrt(d2[idx >= 0])
    assert found == dist.size > 0
    kept = np.sort(dist)[: math.ceil(0.9 * dist.size)]
    want = (dist.mean(), np.median(dist), np.sqrt(np.mean(dist**2)), np.sqrt(np.mean(kept**2)))
    np.testing.assert_allclose((mean, median, rmse, trimmed), want, rtol=1e-12)
    # The tight count of the same pass equals a search with that gate (default: the gate).
    tight = _core.overlap_statistics(tree, src, pose.as_matrix(), 0.3, within=0.1)[5]
    alone = _core.overlap_statistics(tree, src, pose.as_matrix(), 0.1)[0]
    assert within == found and tight == alone == np.count_nonzero(dist <= 0.1) < found
    none = _core.overlap_statistics(tree, src + 1e3, pose.as_matrix(), 0.3)
    assert none[0] == 0 and none[5] == 0 and all(math.isnan(v) for v in none[1:5])


@pytest.mark.parametrize("dim", [2, 3])
def test_overlap_from_the_registrations_certificates_is_the_searched_one(dim: int) -> None:
    # The verdict's overlap answers its queries from the registration's search certificates:
    # the same statistics to the bit, at the result's pose and off it, at other gates; an
    # outcome computed against another index is refused.
    tgt = _cloud(dim, 3000, 4)
    truth = (
        SE2.from_vector([0.05, -0.03, 0.02])
        if dim == 2
        else SE3.exp([0.05, 0, -0.03, 0, 0.01, 0.02])
    )
    src = np.ascontiguousarray(truth.inverse().apply(tgt) + 0.005)
    target = scanreg.prepare(tgt)
    out = _core.register_icp(
        src,
        target.index,
        np.eye(dim + 1),
        "point_to_point",
        "none",
        1.0,
        0.5,
        30,
        1e-6,
        1e-6,
        "gauss_newton",
        10,
    )
    # Converged: its final evaluation re-used the last search's correspondences.
    assert out.stop_reason == "converged"
    pose = out.pose
    moved = pose.copy()
    moved[0, dim] += 0.002
    for at in (pose, moved):
        for gate in (0.5, 0.1, 2.0):
            plain = _core.overlap_statistics(target.index, src, at, gate, within=gate / 3)
            fast = _core.overlap_statistics(
                target.index, src, at, gate, within=gate / 3, outcome=out
            )
            assert fast == plain
    other = _core.KdTree(tgt)
    with pytest.raises(ValueError, match="certificates"):
        _core.overlap_statistics(other, src, pose, 0.5, outcome=out)
