"""Global 3D registration (no initial guess): FPFH, the robust solve, real and simulated pairs,
and the refusals."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import scanreg
from conftest import data_dir
from scanreg import _core, global_registration, io
from scanreg import simulate as sim
from scanreg.global_registration import MIN_FLATNESS, NO_ALIGNMENT, register_global
from scanreg.surface_noise import SurfaceNoise, denoise, surface_noise
from scanreg.transform import SE3


def _errors(pose: SE3, truth: SE3) -> tuple[float, float]:
    r = pose.rotation.T @ truth.rotation
    angle = math.degrees(math.acos(float(np.clip((np.trace(r) - 1) / 2, -1, 1))))
    return angle, float(np.linalg.norm(pose.translation - truth.translation))


def _random_pose(rng: np.random.Generator, max_translation: float) -> SE3:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rotvec = axis * rng.uniform(-math.pi, math.pi)
    t = rng.uniform(-1, 1, size=3) * max_translation / math.sqrt(3)
    return SE3.from_vector(np.concatenate([t, rotvec]))


def _moved(points: np.ndarray, pose: SE3) -> np.ndarray:
    return np.ascontiguousarray(points @ pose.rotation.T + pose.translation)


# --- FPFH against a direct NumPy implementation -------------------------------------------


def _pair(p1, n1, p2, n2):  # type: ignore[no-untyped-def]
    d = p2 - p1
    length = np.linalg.norm(d)
    if length == 0:
        return None
    d = d / length
    a1, a2 = n1 @ d, n2 @ d
    if abs(a1) >= abs(a2):
        u, nt, phi = n1, n2, a1
    else:
        d = -d
        u, nt, phi = n2, n1, -a2
    v = np.cross(d, u)
    if np.linalg.norm(v) == 0:
        return None
    v = v / np.linalg.norm(v)
    w = np.cross(u, v)
    return math.atan2(w @ nt, u @ nt), v @ nt, phi


def _bin(x: float, lo: float, hi: float) -> int:
    return int(min(max(math.floor((x - lo) / (hi - lo) * 11), 0), 10))


def _fpfh_numpy(pts: np.ndarray, nrm: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
    n = len(pts)
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)
    nbrs = []
    for i in range(n):
        order = np.lexsort((np.arange(n), d2[i]))
        order = [j for j in order if j != i and d2[i, j] <= radius * radius][:max_nn]
        nbrs.append(order)
    spfh = np.zeros((n, 33))
    for i in range(n):
        feats = [f for j in nbrs[i] if (f := _pair(pts[i], nrm[i], pts[j], nrm[j])) is not None]
        for theta, alpha, phi in feats:
            spfh[i, _bin(theta, -math.pi, math.pi)] += 100 / len(feats)
            spfh[i, 11 + _bin(alpha, -1, 1)] += 100 / len(feats)
            spfh[i, 22 + _bin(phi, -1, 1)] += 100 / len(feats)
    out = np.zeros((n, 33))
    for i in range(n):
        w = np.array([1 / math.sqrt(d2[i, j]) for j in nbrs[i]])
        f = spfh[i] + (w[:, None] * spfh[nbrs[i]]).sum(0) / w.sum()
        for b in range(3):
            out[i, 11 * b : 11 * b + 11] = (
                f[11 * b : 11 * b + 11] * 100 / f[11 * b : 11 * b + 11].sum()
            )
    return out


def test_fpfh_equals_a_direct_numpy_implementation() -> None:
    rng = np.random.default_rng(3)
    # A bumpy surface: features spread over many bins (a plane would fill one bin each).
    xy = rng.uniform(-1, 1, size=(150, 2))
    pts = np.column_stack([xy, 0.3 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])])
    nrm = np.column_stack(
        [
            -0.9 * np.cos(3 * xy[:, 0]) * np.cos(2 * xy[:, 1]),
            0.6 * np.sin(3 * xy[:, 0]) * np.sin(2 * xy[:, 1]),
            np.ones(150),
        ]
    )
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    got, valid = _core.fpfh(pts, np.ascontiguousarray(nrm), radius=0.5, max_neighbors=20)
    want = _fpfh_numpy(pts, nrm, 0.5, 20)
    assert valid.all()
    assert got.shape == (150, 33)
    assert (want > 0).sum(1).min() >= 5  # not a degenerate histogram
    np.testing.assert_allclose(got, want, atol=2e-3)  # float32 output


# --- the robust solve ---------------------------------------------------------------------


def test_the_robust_solve_recovers_the_pose_with_95_percent_outliers() -> None:
    rng = np.random.default_rng(0)
    truth = _random_pose(rng, 10.0)
    src = rng.uniform(-20, 20, size=(1000, 3))
    tgt = rng.uniform(-20, 20, size=(1000, 3)) + truth.translation
    inl = rng.choice(1000, size=50, replace=False)
    tgt[inl] = _moved(src[inl], truth) + rng.normal(scale=0.02, size=(50, 3))
    m = _core.solve_correspondences(src, np.ascontiguousarray(tgt), noise_bound=0.1)
    best = SE3.from_matrix(m.poses[0])
    rot, trans = _errors(best, truth)
    assert rot < 0.3 and trans < 0.05, (rot, trans)
    assert 50 <= m.num_inliers[0] <= 52
    assert m.clique_sizes[0] >= 48
    # A chance clique among the outliers is far smaller than the true one.
    assert all(c < 20 for c in m.clique_sizes[1:])


# --- known transforms, arbitrary rotation -------------------------------------------------


def test_recovers_an_arbitrary_rotation_on_a_simulated_street() -> None:
    scene = sim.street(seed=2, length=120.0, num_pedestrians=0, num_moving_cars=0)
    lidar = sim.LidarModel.preset("hdl64")
    p_target = SE3.from_vector([0.0, 0.0, 1.8, 0.0, 0.0, 0.0])
    p_source = SE3.from_vector([6.0, 1.5, 1.8, 0.0, 0.0, 2.5])  # 143° of yaw
    tgt = sim.simulate_sweep(scene, lidar, p_target, seed=1).points
    src = sim.simulate_sweep(scene, lidar, p_source, seed=2, scan_index=1).points
    truth = p_target.inverse() @ p_source
    # and tilt the source by an arbitrary rotation about all three axes
    tilt = SE3.from_vector([1.0, -2.0, 0.5, 0.7, -0.4, 1.9])
    res = register_global(_moved(src, tilt), tgt)
    assert res.accepted, res.reasons
    assert res.pose is not None
    rot, trans = _errors(res.pose, truth @ tilt.inverse())
    assert rot < 0.05 and trans < 0.01, (rot, trans)  # measured 0.004°, 1.4 mm
    assert res.covariance is not None and np.all(np.isfinite(res.covariance))
    assert list(res.stage_seconds) == [
        "voxel",
        "keypoints",
        "descriptors",
        "matching",
        "pruning",
        "solve",
        "refinement",
        "verdict",
    ]
    assert sum(res.stage_seconds.values()) <= res.time_s


def test_a_sparse_vlp16_street_pair_is_accepted() -> None:
    # The same street pair seen by a VLP-16 (16 rings): the pose is as good as HDL-64's, and
    # the verdict accepts it. Its weakest direction, a rotation about a horizontal axis held
    # by the ground near the sensor, keeps 0.024 per correspondence once the rings' linear
    # neighbourhoods (whose fitted normals are guesses) are left out, over the 0.01 floor that
    # applies then (the simulated tunnel's axis keeps 0.003); the old floor of 0.03, set above
    # what those guesses fake, rejected it as degenerate.
    scene = sim.street(seed=2, length=120.0, num_pedestrians=0, num_moving_cars=0)
    lidar = sim.LidarModel.preset("vlp16")
    p_target = SE3.from_vector([0.0, 0.0, 1.8, 0.0, 0.0, 0.0])
    p_source = SE3.from_vector([6.0, 1.5, 1.8, 0.0, 0.0, 2.5])
    tgt = sim.simulate_sweep(scene, lidar, p_target, seed=1).points
    src = sim.simulate_sweep(scene, lidar, p_source, seed=2, scan_index=1).points
    tilt = SE3.from_vector([1.0, -2.0, 0.5, 0.7, -0.4, 1.9])
    res = register_global(_moved(src, tilt), tgt)
    assert res.accepted, res.reasons
    assert res.pose is not None
    rot, trans = _errors(res.pose, p_target.inverse() @ p_source @ tilt.inverse())
    assert rot < 0.1 and trans < 0.01, (rot, trans)  # measured 0.046°, 5.6 mm
    refinement = res.hypotheses[0].refinement
    assert refinement is not None and refinement.degeneracy is not None
    deg = refinement.degeneracy
    assert deg.threshold == pytest.approx(0.01) and not deg.degenerate
    assert 0.015 < deg.eigenvalues[0] < 0.03, deg.eigenvalues  # measured 0.0237
    # Fewer correspondences judged than matched: the rings' linear neighbourhoods left out.
    assert deg.num_correspondences < 0.95 * refinement.num_correspondences


def test_recovers_a_kitti_scan_moved_by_a_known_transform() -> None:
    path = data_dir("kitti-odometry-00-frames-000-015", "velodyne", "000000.bin")
    pts = np.ascontiguousarray(io.read_points(path).points)
    rng = np.random.default_rng(5)
    move = _random_pose(rng, 10.0)
    # Partial overlap (a 60 m window of each) and fresh noise on the source.
    src = pts[np.abs(pts[:, 0] - 8) < 30]
    tgt = np.ascontiguousarray(pts[np.abs(pts[:, 0] + 8) < 30])
    src = _moved(src + rng.normal(scale=0.02, size=src.shape), move)
    res = register_global(src, tgt)
    assert res.accepted, res.reasons
    assert res.pose is not None
    rot, trans = _errors(res.pose, move.inverse())
    assert rot < 0.3 and trans < 0.1, (rot, trans)


def test_3dmatch_pair_within_the_benchmark_criterion_before_refinement() -> None:
    folder = data_dir("3dmatch-fragment-pair")
    src = np.load(folder / "src.npy")
    ref = np.load(folder / "ref.npy")
    gt = SE3.from_matrix(np.load(folder / "gt.npy"), atol=1e-3)  # float32-rounded rotation
    res = register_global(src, ref)
    initial = max(res.hypotheses, key=lambda h: h.clique_size).initial_pose
    rot, trans = _errors(initial, gt)
    assert rot < 15 and trans < 0.3, (rot, trans)  # 3DMatch's criterion
    assert rot < 3 and trans < 0.05, (rot, trans)  # what we measured: 1.5°, 1.5-2.3 cm
    # Accepted after GICP: the refinement ends 11 cm from the ground truth (every ICP method
    # does, from the truth itself, and fits the data better there: 33 % of the source within
    # 2 cm against 26 % at the truth), and the degeneracy analysis about the source centroid
    # finds no weak direction (about the camera 2 m away it saw a false coupling).
    assert res.accepted, res.reasons
    assert res.pose is not None
    rot, trans = _errors(res.pose, gt)
    assert rot < 2 and trans < 0.15, (rot, trans)  # measured 1.4°, 11 cm
    # The answer comes first; the runner-ups could not make it ambiguous: one holds a clique
    # of 25 beside the answer's 73 (it converged onto the answer when refined), the other
    # starts at an overlap of 0.11. Neither is refined, so neither has a covariance.
    assert len(res.hypotheses) == 3
    assert all("verdict" not in vars(h) for h in res.hypotheses[1:])
    assert [h.verdict.accepted for h in res.hypotheses] == [True, False, False]
    assert [h.refinement is None for h in res.hypotheses] == [False, True, True]
    assert "no rival, not refined" in res.hypotheses[1].verdict.reasons[-1]
    assert res.hypotheses[1].clique_size < 0.5 * res.hypotheses[0].clique_size
    assert np.isinf(res.hypotheses[1].covariance).all()
    assert set(res.stage_cpu_seconds) == set(res.stage_seconds)
    assert all(v >= 0 for v in res.stage_cpu_seconds.values())


# --- failures reported as failures --------------------------------------------------------


def test_no_overlap_is_no_reliable_alignment() -> None:
    path = data_dir("kitti-odometry-00-frames-000-015", "velodyne", "000000.bin")
    pts = io.read_points(path).points
    src = np.ascontiguousarray(pts[pts[:, 0] > 12])
    tgt = np.ascontiguousarray(pts[pts[:, 0] < -12])
    res = register_global(_moved(src, SE3.from_vector([0, 0, 0, 0, 0, 1.0])), tgt)
    assert not res.accepted
    assert res.pose is None and res.covariance is None and res.best is None
    assert res.reasons[0] == NO_ALIGNMENT
    assert not res.verdict


def test_a_repeated_scene_is_ambiguous_not_decided() -> None:
    # The target holds the same street corner twice, 60 m apart (fresh noise on each copy):
    # the source fits both equally, so both poses come with cliques of similar size (measured
    # 166 and 150), both are refined (neither is below half the other's clique), both pass,
    # and the answer is "ambiguous", not a pick.
    scene = sim.street(seed=2, length=120.0, num_pedestrians=0, num_moving_cars=0)
    lidar = sim.LidarModel.preset("hdl64")
    pts = sim.simulate_sweep(scene, lidar, SE3.from_vector([0, 0, 1.8, 0, 0, 0]), seed=1).points
    corner = pts[np.linalg.norm(pts[:, :2], axis=1) < 15]
    corner = scanreg.preprocess.voxel_downsample(np.ascontiguousarray(corner), 0.1).points
    rng = np.random.default_rng(3)

    def noisy() -> np.ndarray:
        return corner + rng.normal(scale=0.01, size=corner.shape)

    tgt = np.ascontiguousarray(np.vstack([noisy(), noisy() + np.array([0.0, 60.0, 0.0])]))
    move = SE3.from_vector([2.0, 1.0, 0.3, 0.1, -0.05, 2.0])
    res = register_global(_moved(noisy(), move), tgt)
    assert not res.accepted and res.pose is None
    assert res.reasons[0] == NO_ALIGNMENT and res.reasons[1].startswith("ambiguous"), res.reasons
    truths = [move.inverse(), SE3.from_vector([0.0, 60.0, 0.0, 0.0, 0.0, 0.0]) @ move.inverse()]
    for truth in truths:
        found = [h for h in res.hypotheses if _errors(h.pose, truth)[1] < 0.05]
        assert found and all(h.refinement is not None for h in found), truth


def test_a_floor_is_no_reliable_alignment() -> None:
    rng = np.random.default_rng(1)
    floor = np.column_stack([rng.uniform(-10, 10, size=(20000, 2)), rng.normal(0, 0.01, 20000)])
    moved = _moved(floor, SE3.from_vector([1.0, 2.0, 0.0, 0.0, 0.0, 0.5]))
    res = register_global(moved, np.ascontiguousarray(floor))
    assert not res.accepted
    assert res.reasons[0] == NO_ALIGNMENT


def test_identical_clouds_give_the_identity() -> None:
    scene = sim.street(seed=4, length=80.0, num_pedestrians=0, num_moving_cars=0)
    pts = sim.simulate_sweep(
        scene, sim.LidarModel.preset("vlp16"), SE3.from_vector([0, 0, 1.8, 0, 0, 0])
    ).points
    res = register_global(pts, pts)
    assert res.accepted, res.reasons
    assert res.pose is not None
    rot, trans = _errors(res.pose, SE3.identity())
    assert rot < 0.05 and trans < 0.01


def test_bad_input_is_named() -> None:
    pts = np.random.default_rng(0).uniform(size=(500, 3))
    with pytest.raises(ValueError, match="source: too small for descriptors"):
        register_global(pts[:5].copy(), pts)
    with pytest.raises(ValueError, match="target: too small for descriptors"):
        register_global(pts, pts[:8].copy())
    with pytest.raises(ValueError, match="source: expected shape"):
        register_global(pts[:, :2].copy(), pts)
    with pytest.raises(ValueError, match="voxel_size: must be finite and > 0"):
        register_global(pts, pts, voxel_size=-1.0)
    with pytest.raises(TypeError, match="max_hypotheses"):
        register_global(pts, pts, max_hypotheses=1.5)  # type: ignore[arg-type]
    assert scanreg.register_global is register_global


# --- objects a few decimetres across ------------------------------------------------------


def _object_pair(
    shape: sim.ObjectShape, num_points: int, noise: float, views_deg: float, seed: int
) -> tuple[np.ndarray, np.ndarray, SE3]:
    """Two views of ``shape`` ``views_deg`` apart; the source turned by 120° about a random
    axis and shifted. Returns source, target and the truth ``T_target_source``."""
    rng = np.random.default_rng(seed)
    d_source = rng.normal(size=3)
    d_source /= np.linalg.norm(d_source)
    across = np.cross(d_source, rng.normal(size=3))
    across *= math.radians(views_deg) / np.linalg.norm(across)
    d_target = SE3.from_vector(np.concatenate([np.zeros(3), across])).rotation @ d_source
    src = sim.object_view(shape, d_source, num_points, noise=noise, seed=seed + 1)
    tgt = sim.object_view(shape, d_target, num_points, noise=noise, seed=seed + 2)
    axis = rng.normal(size=3)
    turn = axis / np.linalg.norm(axis) * math.radians(120)
    move = SE3.from_vector(np.concatenate([rng.uniform(-1, 1, 3) * shape.size, turn]))
    return _moved(src, move), np.ascontiguousarray(tgt), move.inverse()


def _centre_error(pose: SE3, truth: SE3, points: np.ndarray) -> float:
    centre = points.mean(axis=0)[None]
    return float(np.linalg.norm(pose.apply(centre) - truth.apply(centre)))


@pytest.mark.parametrize(
    ("make", "num_points", "noise"),
    [(sim.figurine, 30_000, 0.002), (sim.trefoil_knot, 20_000, 0.0015), (sim.blob, 50_000, 0.002)],
)
def test_an_object_of_20_cm_registers_from_a_120_degree_turn(make, num_points, noise) -> None:  # type: ignore[no-untyped-def]
    # Two views 60° apart of an object 0.2 m long, 2 mm of noise: main refused the figurine
    # as degenerate (its normals' noise, measured at 20 neighbours, set the bar at 0.2-1.1)
    # or unconverged, or for a refinement that moved more than a gate from a rough solve.
    shape = make(size=0.2)
    src, tgt, truth = _object_pair(shape, num_points, noise, 60.0, seed=7)
    res = register_global(src, tgt)
    assert res.accepted, res.reasons
    assert res.pose is not None
    rot, _ = _errors(res.pose, truth)
    assert rot < 2.0, rot
    assert _centre_error(res.pose, truth, src) < 0.002  # 1 % of the size
    # The voxel follows the object, not a street's: a few millimetres.
    assert 0.002 < res.voxel_size < 0.008, res.voxel_size


@pytest.mark.parametrize("seed", [13, 14])
def test_a_noisy_20_cm_figurine_registers_from_a_120_degree_turn(seed: int) -> None:
    # 2.5 mm of noise on a 0.2 m figurine: the refinement's normals stay noisy, which set the
    # degeneracy bar (6 ε̃², 0.083) above the figurine's weakest direction (0.056-0.08), so
    # every right pose was refused as degenerate; and seed 13's right cliques were solved 7°
    # and 21° from the truth, one refined 14 mm (1.6 gates) onto it and was refused for the
    # move although another clique's refinement ends there too. Both refused before; the
    # degeneracy is now judged on the denoised clouds and a move confirmed by a second clique
    # is no slide.
    src, tgt, truth = _object_pair(sim.figurine(size=0.2), 30_000, 0.0025, 60.0, seed=seed)
    res = register_global(src, tgt)
    assert res.accepted, res.reasons
    assert res.pose is not None
    assert _errors(res.pose, truth)[0] < 1.0
    assert _centre_error(res.pose, truth, src) < 0.001  # 0.5 % of the size
    degeneracy = res.hypotheses[0].refinement.degeneracy  # type: ignore[union-attr]
    assert degeneracy is not None and degeneracy.threshold < 0.02  # denoised normals


@pytest.mark.parametrize(
    ("make", "size", "seed"),
    [(sim.figurine, 0.2, 3), (sim.figurine, 0.2, 4), (sim.trefoil_knot, 0.1, 0)],
)
def test_an_object_seen_from_opposite_sides_is_not_answered_wrong(
    make: Callable[..., Any], size: float, seed: int
) -> None:
    # Views 150° apart share a sliver: refused, or right; never a confident wrong pose. The
    # figurine of seed 3 and the knot are the pairs whose back view turned by ~180° onto the
    # front is found by two disjoint cliques once the descriptors resolve the surface better
    # (normals over 60 keypoints instead of 30 on noisy clouds, or FPFH of the denoised
    # clouds): both were then accepted 176-180° off (benchmarks/README.md, global_objects.py).
    src, tgt, truth = _object_pair(make(size=size), 30_000, 0.002, 150.0, seed=seed)
    res = register_global(src, tgt)
    if res.accepted:
        assert res.pose is not None
        assert _errors(res.pose, truth)[0] < 2.0
        assert _centre_error(res.pose, truth, src) < 0.01 * size
    else:
        assert res.reasons[0] == NO_ALIGNMENT


def test_the_voxel_is_at_least_three_point_spacings() -> None:
    # 10⁴ points on a 0.2 m blob: about 5000 keypoints would leave two points per keypoint;
    # the voxel is three median spacings instead (measured here independently).
    shape = sim.blob(size=0.2, seed=2)
    pts = np.ascontiguousarray(sim.object_view(shape, [1.0, 0.0, 0.0], 10_000, noise=0.001))
    res = register_global(pts, pts, refine=False)
    _, d2 = _core.KdTree(pts).knn(pts, 2)
    spacing = float(np.median(np.sqrt(d2[:, 1])))
    assert res.voxel_size == pytest.approx(3 * spacing, rel=0.05)


# --- the clouds' own noise and whether it leaves the surface resolved ----------------------


def test_surface_noise_reads_the_noise_of_a_plane_and_its_flatness() -> None:
    # A 0.2 m square with 2 mm of noise across it (and a gentle bend, 0.5 m radius): the
    # noise is the thickness, within the estimate's stated √2 (curvature adds to it).
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.1, 0.1, size=(30_000, 2))
    z = (xy**2).sum(axis=1) / (2 * 0.5) + rng.normal(0, 0.002, size=len(xy))
    got = surface_noise(np.column_stack([xy, z]))
    assert 0.002 <= got.sigma < 0.002 * math.sqrt(2), got
    assert got.flatness > 20, got  # flat over many noise widths
    # Clean: the noise term vanishes and the flatness soars.
    clean = surface_noise(np.column_stack([xy, (xy**2).sum(axis=1) / (2 * 0.5)]))
    assert clean.sigma < 0.0005 and clean.flatness > 100, clean


def test_surface_noise_finds_a_thin_noisy_tube_unresolved() -> None:
    # A tube 5 mm in radius under 2.5 mm of noise bends within two noise widths: below
    # MIN_FLATNESS. The same tube at 0.3 mm of noise is resolved.
    rng = np.random.default_rng(4)
    t = rng.uniform(0, 0.2, size=40_000)
    phi = rng.uniform(0, math.pi, size=len(t))  # the half facing a viewer
    tube = np.column_stack([t, 0.005 * np.cos(phi), 0.005 * np.sin(phi)])
    noisy = surface_noise(tube + rng.normal(0, 0.0025, size=tube.shape))
    assert noisy.flatness < MIN_FLATNESS, noisy
    fine = surface_noise(tube + rng.normal(0, 0.0003, size=tube.shape))
    assert fine.flatness > MIN_FLATNESS, fine
    with pytest.raises(ValueError, match="points"):
        surface_noise(tube[:5].copy())


def test_denoise_removes_the_noise_across_a_surface_not_along_it() -> None:
    # The gently bent square of 2 mm noise above: projected onto local planes its points lie
    # within a fraction of the noise of the true surface, and each moved along the normal only
    # (its x, y barely change), so the sampling is kept.
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.1, 0.1, size=(30_000, 2))
    true_z = (xy**2).sum(axis=1) / (2 * 0.5)
    noisy = np.column_stack([xy, true_z + rng.normal(0, 0.002, size=len(xy))])
    out = denoise(noisy)
    assert out.shape == noisy.shape
    inner = np.abs(xy).max(axis=1) < 0.08  # away from the border, where the plane is one-sided
    off = out[inner, 2] - true_z[inner]
    assert np.sqrt(np.mean(off**2)) < 0.0005, np.sqrt(np.mean(off**2))  # was 0.002
    along = np.linalg.norm(out[inner, :2] - xy[inner], axis=1)  # the normal tilts 0.04-0.16
    assert np.median(along) < 0.0003 and np.percentile(along, 99) < 0.001
    # The flatness of the denoised surface is far above the raw one's.
    assert surface_noise(out).flatness > 4 * surface_noise(noisy).flatness
    # No noise measured: a copy, unchanged.
    same = denoise(noisy, SurfaceNoise(0.0, 0.0, 0.0))
    assert np.array_equal(same, noisy) and same is not noisy
    with pytest.raises(TypeError, match="noise: expected SurfaceNoise"):
        denoise(noisy, 0.002)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="points"):
        denoise(noisy[:5].copy())


def test_a_noisy_20_cm_knot_registers_from_a_120_degree_turn(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # A 0.2 m knot (its tube 9 mm thick) under 3 mm of noise, turned by 120°: main refused it
    # ("surface not resolved", flatness 3.5 < 5; refined on the raw clouds the best pose lay
    # 5 mm, 2.7 % of the size, from the truth). Refined again on both clouds denoised, and
    # judged on those, it is right.
    shape = sim.trefoil_knot(size=0.2)
    src, tgt, truth = _object_pair(shape, 30_000, 0.003, 60.0, seed=5)
    res = register_global(src, tgt)
    assert res.accepted, res.reasons
    assert res.pose is not None
    assert _errors(res.pose, truth)[0] < 2.0
    assert _centre_error(res.pose, truth, src) < 0.002  # 1 % of the size
    assert res.surface_noise is not None
    assert min(n.flatness for n in res.surface_noise) > MIN_FLATNESS
    # Without the denoising the clouds judged are the raw ones, and they are refused.
    monkeypatch.setattr(global_registration, "denoise", lambda points, noise: np.array(points))
    raw = register_global(src, tgt)
    assert not raw.accepted
    assert raw.reasons[0] == NO_ALIGNMENT
    assert "surface not resolved" in raw.reasons[1], raw.reasons


def test_a_polish_that_loosens_the_fit_is_refused(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # A 0.1 m knot (its tube ~4.5 mm thick) under 1.7 mm of noise: the noise estimate, inflated
    # by the tube's curvature, sets a denoising radius that smooths the two views into
    # different shapes. Refined on those, the answer turns 4.8° / 2.7 mm (2.7 % of the size)
    # from the truth, and the denoised clouds explain less than the raw ones did at that pose
    # (0.49 vs 0.61 within half a voxel). Accepted without the check; refused with it.
    shape = sim.trefoil_knot(size=0.1)
    src, tgt, truth = _object_pair(shape, 40_000, 0.0017, 60.0, seed=2)
    res = register_global(src, tgt)
    assert not res.accepted
    assert res.reasons[0] == NO_ALIGNMENT
    assert "fit looser than the raw ones" in res.reasons[1], res.reasons
    monkeypatch.setattr(global_registration, "MIN_DENOISED_FIT", 0.0)
    loose = register_global(src, tgt)
    assert loose.accepted and loose.pose is not None
    assert _errors(loose.pose, truth)[0] > 3.0
