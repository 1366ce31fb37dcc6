"""Trajectory metrics: agreement with evo's stored results, KITTI metric, Kümmerle relations."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scanreg.eval as ev
import scanreg.io as sio
from conftest import data_dir
from scanreg import SE3
from scanreg.io import Trajectory

EVO = "trajectories-evo-testdata"
KITTI = "kitti-odometry-00-frames-000-015"
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _evo_archive(name: str) -> tuple[dict[str, str], dict[str, float], np.ndarray]:
    with zipfile.ZipFile(data_dir(EVO, "res_files", f"{name}.zip")) as z:
        info = json.loads(z.read("info.json"))
        stats = json.loads(z.read("stats.json"))
        errors = np.load(io.BytesIO(z.read("error_array.npz")))
    return info, stats, errors


def _kitti(name: str) -> Trajectory:
    if name == "gt":
        return sio.read_kitti_poses(data_dir(KITTI, "poses_00_full.txt"))
    return sio.read_kitti_poses(data_dir(EVO, f"KITTI_00_{name}.txt"))


def _assert_matches_evo(
    result: ev.ErrorStatistics, stats: dict[str, float], errors: np.ndarray
) -> None:
    assert len(result) == errors.size
    np.testing.assert_allclose(result.errors, errors, rtol=0, atol=1e-6)
    for key in STATS:
        # sse is a sum over thousands of values: compare it relatively
        tol = {"sse": 1e-6 * stats["sse"]}.get(key, 1e-6)
        assert abs(getattr(result, key) - stats[key]) <= tol, (
            key,
            getattr(result, key),
            stats[key],
        )


@pytest.mark.parametrize("name", ["orb", "sptam"])
def test_ape_matches_evo(name: str) -> None:
    info, stats, errors = _evo_archive(f"{name}_ape")
    assert "translation part" in info["title"] and "SE(3) Umeyama alignment" in info["title"]
    result = ev.absolute_trajectory_error(_kitti(name.upper()), _kitti("gt"), alignment="se3")
    _assert_matches_evo(result.translation, stats, errors)
    assert result.alignment.scale == 1.0


@pytest.mark.parametrize("name", ["orb", "sptam"])
def test_rpe_by_distance_matches_evo(name: str) -> None:
    info, stats, errors = _evo_archive(f"{name}_rpe")
    assert "delta = 10.0 (m) using consecutive pairs" in info["title"]
    assert "(not aligned)" in info["title"]
    est, gt = _kitti(name.upper()), _kitti("gt")
    # evo (2018) chose the pairs along the estimate's path; see relative_pose_error
    result = ev.relative_pose_error(est, gt, delta=10, unit="meters", path_from="estimate")
    _assert_matches_evo(result.translation, stats, errors)
    # every pair spans >= 10 m of estimated path, and they do not overlap
    dist = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(est.positions, axis=0), axis=1))])
    i, j = result.pairs.T
    assert np.all(dist[j] - dist[i] >= 10.0) and np.all(i[1:] == j[:-1])
    # along the reference path the pairs differ, and so do the numbers
    by_ref = ev.relative_pose_error(est, gt, delta=10, unit="meters")
    assert len(by_ref.translation) != errors.size


def test_ate_alignment_recovers_a_similarity() -> None:
    rng = np.random.default_rng(0)
    ref = Trajectory.from_poses([SE3.from_vector(rng.normal(0, 5, 6)) for _ in range(50)])
    motion = SE3.from_vector([3.0, -2.0, 1.0, 0.3, -0.2, 1.0])
    moved = np.array(ref.poses)
    moved[:, :3, 3] *= 0.5  # monocular scale
    moved = motion.as_matrix() @ moved
    est = Trajectory(moved)
    sim3 = ev.absolute_trajectory_error(est, ref, alignment="sim3")
    assert sim3.translation.max < 1e-9 and sim3.rotation_deg.max < 1e-6
    assert abs(sim3.alignment.scale - 2.0) < 1e-12
    se3 = ev.absolute_trajectory_error(est, ref, alignment="se3")
    assert se3.translation.rmse > 1.0  # the scale cannot be explained without Sim(3)
    none = ev.absolute_trajectory_error(ref, ref, alignment="none")
    assert none.translation.max < 1e-12


def test_rpe_by_frames() -> None:
    rng = np.random.default_rng(1)
    ref = Trajectory.from_poses([SE3.from_vector(rng.normal(0, 5, 6)) for _ in range(21)])
    # a constant world offset leaves every relative pose unchanged
    est = Trajectory(SE3.from_vector([5, 5, 5, 0.5, 0, 0]).as_matrix() @ ref.poses)
    res = ev.relative_pose_error(est, ref, delta=1)
    assert len(res.translation) == 20 and res.translation.max < 1e-9
    assert ev.pairs_by_frames(21, 5).tolist() == [[0, 5], [5, 10], [10, 15], [15, 20]]
    assert len(ev.pairs_by_frames(21, 5, all_pairs=True)) == 16
    # a single bad pose shows up in exactly the two pairs that contain it
    bad = np.array(ref.poses)
    bad[7, 0, 3] += 1.0
    res = ev.relative_pose_error(Trajectory(bad), ref, delta=1)
    np.testing.assert_allclose(np.sort(res.translation.errors)[-2:], [1.0, 1.0])
    assert np.sum(res.translation.errors > 1e-9) == 2


def test_tum_association() -> None:
    gt = sio.read_tum(data_dir(EVO, "freiburg1_xyz-groundtruth.txt"))
    est = sio.read_tum(data_dir(EVO, "freiburg1_xyz-rgbdslam.txt"))
    res = ev.absolute_trajectory_error(est, gt, alignment="se3")
    assert 700 <= len(res.translation) <= 788
    assert 0.005 < res.translation.rmse < 0.05  # RGBD-SLAM on fr1/xyz: about a centimetre


def test_kitti_metric() -> None:
    gt = _kitti("gt")
    orb = ev.kitti_odometry_error(_kitti("ORB"), gt)
    # ORB-SLAM2 stereo on KITTI 00 is published at ≈ 0.70 % and ≈ 0.25 deg/100 m
    assert 0.6 < orb.translation_percent < 0.8
    assert 0.2 < orb.rotation_deg_per_m * 100 < 0.3
    assert orb.lengths.tolist() == list(ev.KITTI_LENGTHS)
    assert np.isfinite(orb.translation_percent_by_length).all()
    assert ev.kitti_odometry_error(gt, gt).translation_percent < 1e-9
    # configurable short segments on the 16-frame excerpt (≈ 13 m)
    short = sio.read_kitti_poses(data_dir(KITTI, "poses.txt"))
    res = ev.kitti_odometry_error(short, short, lengths=(2.0, 5.0), step=1)
    assert len(res.segments) > 10 and res.translation_percent < 1e-9
    with pytest.raises(ValueError, match="no segment"):
        ev.kitti_odometry_error(short, short)


def test_kitti_metric_known_drift() -> None:
    # straight 1 m steps; the estimate is 1 % too long
    n = 1001
    ref = Trajectory.from_xyyaw(np.column_stack([np.arange(n), np.zeros(n), np.zeros(n)]))
    est = Trajectory.from_xyyaw(np.column_stack([1.01 * np.arange(n), np.zeros(n), np.zeros(n)]))
    res = ev.kitti_odometry_error(est, ref, lengths=(100.0,))
    # a segment ends at the first frame *beyond* 100 m (101 m away), divided by 100 m: 1.01 %
    assert abs(res.translation_percent - 1.01) < 1e-9
    assert res.rotation_deg_per_m == 0.0


def _intel_trajectory() -> Trajectory:
    rows = []
    for line in (
        data_dir("carmen-intel", "intel_gfs_subset_clf_timestamps.clf").read_text().splitlines()
    ):
        w = line.split()
        if w and w[0] == "FLASER":
            n = int(w[1])
            x, y, theta = (float(v) for v in w[2 + n : 5 + n])
            rows.append((x, y, theta, float(w[2 + n + 6])))
    table = np.array(rows)
    return Trajectory.from_xyyaw(table[:, :3], table[:, 3])


def test_relations_metric_on_intel() -> None:
    traj = _intel_trajectory()
    assert len(traj) == 902
    rel = ev.read_relations(data_dir("carmen-intel", "intel_gfs_subset.relations"))
    res = ev.relation_error(traj, rel)
    assert len(res.used) == 90 and res.missing == 0
    # the data README: GMapping poses give 0.036 ± 0.027 m and 0.42 ± 0.46°
    assert round(res.translation.mean, 3) == 0.036 and round(res.translation.std, 3) == 0.027
    assert round(res.rotation_deg.mean, 2) == 0.42 and round(res.rotation_deg.std, 2) == 0.46
    full = ev.relation_error(traj, ev.read_relations(data_dir("carmen-intel", "intel.relations")))
    assert len(full.used) == 90 and full.missing == 2984 - 90


def test_relations_3d_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    poses = [SE3.from_vector(rng.normal(0, 1, 6)) for _ in range(5)]
    traj = Trajectory.from_poses(poses, np.arange(5.0))
    lines = []
    for a, b in [(0, 1), (1, 3), (4, 2)]:
        rel = (poses[a].inverse() @ poses[b]).as_matrix()
        r = rel[:3, :3]
        roll, pitch, yaw = (
            np.arctan2(r[2, 1], r[2, 2]),
            -np.arcsin(r[2, 0]),
            np.arctan2(r[1, 0], r[0, 0]),
        )
        offset = 0.1 if (a, b) == (4, 2) else 0.0
        lines.append(f"{a} {b} {rel[0, 3] + offset} {rel[1, 3]} {rel[2, 3]} {roll} {pitch} {yaw}")
    (tmp_path / "r.relations").write_text("\n".join(lines) + "\n")
    res = ev.relation_error(traj, ev.read_relations(tmp_path / "r.relations"))
    np.testing.assert_allclose(res.translation.errors, [0, 0, 0.1], atol=1e-9)
    assert res.rotation_deg.max < 1e-6
