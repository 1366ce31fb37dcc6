"""Inputs as users have them: float32 scans, strided views, Fortran order, lists and nearly
rigid poses read from files give the same result as the float64 C-contiguous array they convert
to, and the caller's array is left as it was."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.pipeline import Odometry2D


def _variants(points: np.ndarray) -> list[tuple[str, Any, np.ndarray]]:
    """(name, as the user has it, the float64 array it stands for)."""
    f32 = points.astype(np.float32)
    doubled = np.repeat(points, 2, axis=0)
    return [
        ("float32", f32, f32.astype(np.float64)),
        ("strided view", doubled[::2], np.ascontiguousarray(doubled[::2])),
        ("Fortran order", np.asfortranarray(points), points.copy()),
        ("list", points.tolist(), np.array(points.tolist())),
        ("int", np.rint(points * 100).astype(np.int32), np.rint(points * 100)),
    ]


def _scan_pair(dim: int) -> tuple[np.ndarray, np.ndarray, SE2 | SE3]:
    rng = np.random.default_rng(dim)
    if dim == 2:
        scene = sim.floor_plan(seed=2, num_people=0)
        laser = sim.LaserModel.preset("sick_lms200")
        a = SE2.from_vector([7.0, 0.3, 0.2])
        b = a @ SE2.from_vector([0.15, -0.05, 0.03])
        ref = sim.simulate_scan(scene, laser, a, seed=0).points
        src = sim.simulate_scan(scene, laser, b, seed=1).points
        return np.ascontiguousarray(src), np.ascontiguousarray(ref), a.inverse() @ b
    pts = rng.uniform(-5, 5, (600, 3))
    pts[:200, 2] = 0.0  # a floor, a wall and a box side: well constrained
    pts[200:400, 0] = 4.0
    pts[400:, 1] = -3.0
    truth = SE3.from_vector([0.1, -0.05, 0.02, 0.01, -0.02, 0.03])
    return truth.inverse().apply(pts), pts, truth


def _same(a: Any, b: Any) -> None:
    assert np.array_equal(a.pose.as_matrix(), b.pose.as_matrix())


CALLS: dict[str, Callable[[Any, Any], Any]] = {
    "register point_to_plane/line": lambda s, t: scanreg.register(
        s, t, method="point_to_line" if len(np.asarray(t)[0]) == 2 else "point_to_plane"
    ),
    "register gicp": lambda s, t: scanreg.register(s, t, method="gicp"),
    "align_paired": lambda s, t: scanreg.align_paired(s, t[: len(s)]),
}


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("call", sorted(CALLS))
def test_converted_inputs_give_the_same_pose(dim: int, call: str) -> None:
    source, target, _ = _scan_pair(dim)
    if call == "align_paired":
        n = min(len(source), len(target))
        source, target = source[:n], np.ascontiguousarray(target[:n])
    fn = CALLS[call]
    for name, user, exact in _variants(source):
        before = np.array(user, dtype=object) if isinstance(user, list) else user.copy()
        got, want = fn(user, target), fn(exact, target)
        _same(got, want)
        np.testing.assert_array_equal(np.asarray(user, dtype=object), before, err_msg=name)
    for name, user, exact in _variants(target):
        if call == "align_paired":
            continue  # the paired variants above already cover the second argument
        _same(fn(source, user), fn(source, exact))
        del name


def test_2d_matchers_and_odometry_take_converted_inputs() -> None:
    source, target, truth = _scan_pair(2)
    for _, user, exact in _variants(source):
        a = scanreg.match_correlative(user, target, window=(0.3, 0.3, 0.1))
        b = scanreg.match_correlative(exact, target, window=(0.3, 0.3, 0.1))
        _same(a, b)
        _same(scanreg.match_ndt(user, target), scanreg.match_ndt(exact, target))
    for _, user, exact in _variants(target)[:4]:  # (the int variant is in centimetres)
        grid_user = scanreg.prepare_correlative(user)
        grid_exact = scanreg.prepare_correlative(exact)
        assert np.array_equal(grid_user.likelihood, grid_exact.likelihood)
    frames = []
    for pts in (target.astype(np.float32), source[::1].tolist()):
        frames.append(Odometry2D().step(pts))
    assert all(f.pose == SE2.identity() for f in frames)
    # float32 rounding of the points (~1e-7 m here) moves the pose by far less than its σ.
    r32 = scanreg.register(source.astype(np.float32), target, method="point_to_line")
    r64 = scanreg.register(source, target, method="point_to_line")
    step = (r64.pose.inverse() @ r32.pose).as_vector()
    assert np.all(np.abs(step) < 1e-3 * np.sqrt(np.diag(r64.covariance)))
    del truth


def test_the_prepared_target_is_built_once_from_a_converted_cloud() -> None:
    _, target, _ = _scan_pair(3)
    prepared = scanreg.prepare(target.astype(np.float32), covariances=True)
    assert prepared.points.dtype == np.float64 and prepared.points.flags.c_contiguous
    assert np.array_equal(prepared.points, target.astype(np.float32).astype(np.float64))


def test_a_pose_read_with_file_precision_is_projected_a_non_rigid_one_refused() -> None:
    truth = SE3.from_vector([0.3, -1.2, 0.4, 0.2, -0.4, 1.1]).as_matrix()
    six_digits = np.array([[float(f"{v:.6g}") for v in row] for row in truth])
    as_float32 = truth.astype(np.float32)
    # Off by a few 1e-5 like the 3DMatch ground truth (7e-5).
    drifted = truth.copy()
    drifted[:3, :3] *= 1.0 + 3e-5
    for matrix in (six_digits, as_float32, drifted):
        pose = SE3.from_matrix(matrix)
        rot = pose.rotation
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(pose.as_matrix(), truth, atol=1e-4)
        res = scanreg.register(*_scan_pair(3)[:2], init=matrix)
        assert res.converged
    scaled = truth.copy()
    scaled[:3, :3] *= 1.01
    with pytest.raises(ValueError, match=r"init: rotation: not orthonormal \(max \|RᵀR - I\| = 2"):
        scanreg.register(*_scan_pair(3)[:2], init=scaled)


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ("points", "source: expected an array of numbers, got str"),
        (None, "source: expected an array of numbers, got NoneType"),
        ([[0.0, "x"], [1.0, 2.0]], "source: expected an array of real numbers"),
        (np.zeros((5, 2), dtype=complex), "source: expected real numbers"),
        (np.zeros((5, 2), dtype=object), "source: expected real numbers"),
    ],
)
def test_what_cannot_be_converted_is_refused_by_name(value: Any, match: str) -> None:
    _, target, _ = _scan_pair(2)
    with pytest.raises(TypeError, match=match):
        scanreg.register(value, target, method="point_to_line")


def test_submodules_are_reachable_after_a_plain_import() -> None:
    import subprocess
    import sys

    code = (
        "import scanreg; "
        "print(scanreg.io.read_scans.__name__, scanreg.eval.__name__, "
        "scanreg.pipeline.Odometry2D.__name__, 'io' in dir(scanreg))"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert out.stdout.split() == ["read_scans", "scanreg.eval", "Odometry2D", "True"]
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        _ = scanreg.nonexistent  # type: ignore[attr-defined]


def test_covariance_arguments_share_one_check() -> None:
    # register's init_covariance, match_correlative's motion cost and Odometry2D's
    # prior_covariance go through one validator: the same errors, each naming its argument.
    from scanreg import match_correlative, register

    pts = np.random.default_rng(3).uniform(-5, 5, size=(300, 2))
    with pytest.raises(TypeError, match=r"init_covariance: expected a \(3, 3\) array, got str"):
        register(pts, pts, method="point_to_line", init_covariance="wide")
    with pytest.raises(ValueError, match="init_covariance: must be finite and symmetric"):
        register(
            pts, pts, method="point_to_line", init_covariance=[[1, 2, 0], [0, 1, 0], [0, 0, 1]]
        )
    with pytest.raises(ValueError, match="init_covariance: must be positive semi-definite"):
        register(pts, pts, method="point_to_line", init_covariance=-np.eye(3))
    with pytest.raises(ValueError, match="init_covariance: must be positive definite"):
        match_correlative(
            pts,
            pts,
            init=SE2.identity(),
            window=(0.3, 0.3, 0.1),
            init_covariance=np.diag([1, 0, 1]),
        )
    odo = Odometry2D()
    odo.step(pts)
    with pytest.raises(
        ValueError, match=r"prior_covariance: expected shape \(3, 3\), got \(2, 2\)"
    ):
        odo.step(pts, prior=SE2.identity(), prior_covariance=np.eye(2))


def test_io_takes_points_poses_and_paths_as_users_have_them(tmp_path: Any) -> None:
    """Issue 40's audit: the points of a PointCloud as nested lists, a trajectory as a list of
    SE3, KITTI poses written from the matrices alone, an occupancy grid from 3x3 pose
    matrices, a config from any os.PathLike — each the same as the canonical form; what
    cannot be converted is refused by name."""
    import os
    from pathlib import Path

    from scanreg.config import load_config, write_config
    from scanreg.io import PointCloud, Trajectory, read_kitti_poses, write_kitti_poses
    from scanreg.io.occupancy import occupancy_grid
    from scanreg.pipeline import OdometryConfig

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 3))
    np.testing.assert_array_equal(PointCloud(points=pts.tolist()).points, pts)
    with pytest.raises(TypeError, match=r"points: expected an \(N, 3\) array, got list"):
        PointCloud(points=[[0.0, 1.0, 2.0], [1.0]])
    with pytest.raises(TypeError, match="points: expected an"):
        PointCloud(points=None)  # type: ignore[arg-type]

    poses = [SE3.exp(rng.normal(size=6) * 0.1) for _ in range(4)]
    matrices = np.stack([p.as_matrix() for p in poses])
    np.testing.assert_array_equal(Trajectory(poses).poses, matrices)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="poses: a trajectory holds 3D poses"):
        Trajectory([SE2.identity()])  # type: ignore[arg-type]
    write_kitti_poses(tmp_path / "a.txt", Trajectory(matrices))
    write_kitti_poses(tmp_path / "b.txt", matrices)
    write_kitti_poses(str(tmp_path / "c.txt"), poses)
    text = (tmp_path / "a.txt").read_text()
    assert (tmp_path / "b.txt").read_text() == (tmp_path / "c.txt").read_text() == text
    np.testing.assert_allclose(read_kitti_poses(tmp_path / "b.txt").poses, matrices, atol=1e-12)

    scan = rng.normal(size=(40, 2)) * 2
    pose = SE2.from_vector([0.5, -0.2, 0.3])
    a = occupancy_grid([pose], [scan], resolution=0.1)
    b = occupancy_grid([pose.as_matrix()], [scan.tolist()], resolution=0.1)
    np.testing.assert_array_equal(a.probability, b.probability)
    assert a.origin == b.origin

    class Where(os.PathLike[str]):
        def __init__(self, path: Path) -> None:
            self.path = path

        def __fspath__(self) -> str:
            return str(self.path)

    config = OdometryConfig(voxel_size=0.7)
    write_config(tmp_path / "c.toml", config)
    assert load_config(OdometryConfig, Where(tmp_path / "c.toml")) == config
