"""Trajectory, calibration and g2o readers/writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scanreg.io as sio
from conftest import data_dir
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scanreg import SE2, SE3
from scanreg.io import PoseGraph, PoseGraphEdge, Trajectory
from scanreg.io.trajectory import quaternion_to_rotation, rotation_to_quaternion

EVO = "trajectories-evo-testdata"
KITTI = "kitti-odometry-00-frames-000-015"


def _random_trajectory(n: int, seed: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    poses = [SE3.from_vector(np.r_[rng.normal(0, 50, 3), rng.normal(0, 1.5, 3)]) for _ in range(n)]
    return Trajectory.from_poses(poses, 1.3e9 + np.cumsum(rng.uniform(0.01, 0.1, n)))


@pytest.mark.parametrize("fmt", ["kitti", "tum"])
def test_trajectory_round_trip(tmp_path: Path, fmt: str) -> None:
    traj = _random_trajectory(30, 1)
    sio.write_trajectory(tmp_path / "t.txt", traj, fmt)
    back = sio.read_trajectory(tmp_path / "t.txt", fmt)
    assert len(back) == 30
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-9)
    if fmt == "tum":
        np.testing.assert_allclose(back.timestamps, traj.timestamps, atol=1e-9)  # type: ignore[arg-type]
    else:
        assert back.timestamps is None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-4, 4), min_size=3, max_size=3))
def test_quaternion_round_trip(rotvec: list[float]) -> None:
    r = SE3.from_vector([0, 0, 0, *rotvec]).rotation
    q = rotation_to_quaternion(r)
    assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    np.testing.assert_allclose(quaternion_to_rotation(q), r, atol=1e-12)


def test_trajectory_helpers() -> None:
    traj = _random_trajectory(3, 2)
    assert traj.se3(1).is_close(SE3.from_matrix(traj.poses[1]), atol=1e-12)
    assert len(traj.as_se3()) == 3
    planar = Trajectory.from_xyyaw([[1.0, 2.0, 0.5]])
    assert planar.se3(0).is_close(SE3.from_vector([1, 2, 0, 0, 0, 0.5]), atol=1e-12)
    same = Trajectory.from_poses([SE2.from_vector([1.0, 2.0, 0.5])])
    np.testing.assert_allclose(same.poses, planar.poses, atol=1e-15)
    with pytest.raises(ValueError, match="timestamps"):
        Trajectory(traj.poses, np.zeros(2))
    with pytest.raises(ValueError, match="need timestamps"):
        sio.write_tum("/nonexistent/x.txt", Trajectory(traj.poses))


def test_real_trajectories() -> None:
    for name in ("KITTI_00_ORB.txt", "KITTI_00_SPTAM.txt"):
        assert len(sio.read_kitti_poses(data_dir(EVO, name))) == 4541
    counts = {
        "fr2_desk_ORB.txt": 2893,
        "fr2_desk_groundtruth.txt": 20957,
        "freiburg1_xyz-groundtruth.txt": 3000,
        "freiburg1_xyz-rgbdslam.txt": 788,
    }
    for name, count in counts.items():
        traj = sio.read_tum(data_dir(EVO, name))
        assert len(traj) == count and traj.timestamps is not None
        assert np.all(np.diff(traj.timestamps) >= 0)  # fr2 desk GT repeats one stamp
    gt = sio.read_kitti_poses(data_dir(KITTI, "poses.txt"))
    assert len(gt) == 16
    assert len(sio.read_kitti_poses(data_dir(KITTI, "poses_00_full.txt"))) == 4541
    times = sio.read_times(data_dir(KITTI, "times.txt"))
    assert times.shape == (16,) and times[0] == 0.0
    # GT moves ≈ 0.86 m forward per frame (camera z axis)
    assert 0.8 < np.linalg.norm(gt.positions[1] - gt.positions[0]) < 0.9


def test_kitti_calib() -> None:
    calib = sio.read_kitti_calib(data_dir(KITTI, "calib.txt"))
    assert set(calib.matrices) == {"P0", "P1", "P2", "P3", "Tr"}
    tr = calib.T_cam0_velo
    # velodyne x (forward) becomes camera z (forward); velodyne z (up) becomes camera -y
    np.testing.assert_allclose(tr.rotation @ [1, 0, 0], [0, 0, 1], atol=0.02)
    np.testing.assert_allclose(tr.rotation @ [0, 0, 1], [0, -1, 0], atol=0.02)


def test_g2o_round_trip_3d(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    vertices = {i: SE3.from_vector(rng.normal(0, 1, 6)) for i in range(4)}
    a = rng.normal(size=(6, 6))
    info = a @ a.T + 6 * np.eye(6)
    edges = tuple(
        PoseGraphEdge(i, i + 1, vertices[i].inverse() @ vertices[i + 1], info) for i in range(3)
    )
    graph = PoseGraph(vertices, edges, frozenset({0}))
    sio.write_g2o(tmp_path / "g.g2o", graph)
    text = (tmp_path / "g.g2o").read_text().splitlines()
    assert text[0].startswith("VERTEX_SE3:QUAT 0 ") and "FIX 0" in text
    edge_line = next(ln for ln in text if ln.startswith("EDGE_SE3:QUAT")).split()
    assert len(edge_line) == 3 + 7 + 21
    # g2o's upper triangle by rows: I11 I12 ... I16 I22 ...
    assert float(edge_line[10]) == info[0, 0] and float(edge_line[11]) == info[0, 1]
    assert float(edge_line[16]) == info[1, 1]
    back = sio.read_g2o(tmp_path / "g.g2o")
    assert back.fixed == {0}
    for i, pose in vertices.items():
        assert back.vertices[i].is_close(pose, atol=1e-12)
    for e, f in zip(edges, back.edges, strict=True):
        assert (e.from_id, e.to_id) == (f.from_id, f.to_id)
        assert e.measurement.is_close(f.measurement, atol=1e-12)
        np.testing.assert_array_equal(e.information, f.information)


def test_g2o_round_trip_2d(tmp_path: Path) -> None:
    vertices = {0: SE2.identity(), 1: SE2.from_vector([1.0, 0.5, 0.3])}
    info = np.array([[10.0, 1.0, 0.5], [1.0, 20.0, 0.0], [0.5, 0.0, 100.0]])
    graph = PoseGraph(vertices, (PoseGraphEdge(0, 1, vertices[1], info),))
    sio.write_g2o(tmp_path / "g.g2o", graph)
    line = (tmp_path / "g.g2o").read_text().splitlines()[-1].split()
    assert line[0] == "EDGE_SE2" and [float(v) for v in line[6:]] == [10, 1, 0.5, 20, 0, 100]
    back = sio.read_g2o(tmp_path / "g.g2o")
    assert back.vertices[1].is_close(vertices[1], atol=1e-15)
    np.testing.assert_array_equal(back.edges[0].information, info)


def test_g2o_information() -> None:
    cov = np.diag([0.01, 0.04, 0.09, 1e-4, 4e-4, 9e-4])
    info = sio.g2o_information(cov)
    # the rotation block is over the quaternion's imaginary part (≈ φ/2): 4× the information
    np.testing.assert_allclose(np.diag(info), [100, 25, 1 / 0.09, 4e4, 1e4, 4 / 9e-4])
    np.testing.assert_allclose(sio.g2o_information(np.diag([1.0, 2, 4])), np.diag([1, 0.5, 0.25]))


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 20))
def test_tum_round_trip_hypothesis(tmp_path: Path, seed: int, n: int) -> None:
    traj = _random_trajectory(n, seed)
    sio.write_tum(tmp_path / "t.txt", traj)
    np.testing.assert_allclose(sio.read_tum(tmp_path / "t.txt").poses, traj.poses, atol=1e-8)
