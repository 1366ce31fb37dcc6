"""Interop: ROS pose-with-covariance layouts (round trips, Monte-Carlo check of the frame
conversion, against the adjoint that would be wrong) and Open3D conversions."""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np
import pytest
from conftest import data_dir
from scanreg import SE2, SE3
from scanreg.interop import (
    covariance_from_ros,
    covariance_to_ros,
    from_open3d,
    from_ros_pose2d_covariance,
    from_ros_pose_with_covariance,
    to_open3d,
    to_ros_pose2d_covariance,
    to_ros_pose_with_covariance,
)
from scanreg.io import PointCloud, read_kitti_bin
from scanreg.transform import so3_exp, so3_log

# A pose far from the origin: the adjoint's [t]x term would show up at once.
POSE = SE3.from_vector([25.0, -12.0, 3.0, 0.3, -0.5, 2.1])
POSE2 = SE2.from_vector([18.0, -7.0, 2.4])


def _spd(rng: np.random.Generator, sigmas: list[float]) -> np.ndarray:
    """A covariance with the given standard deviations and random correlations."""
    a = rng.normal(size=(len(sigmas), len(sigmas)))
    corr = a @ a.T + len(sigmas) * np.eye(len(sigmas))
    d = 1 / np.sqrt(np.diag(corr))
    return np.asarray(np.outer(d * sigmas, d * sigmas) * corr)


def test_layout_and_round_trip() -> None:
    cov = _spd(np.random.default_rng(1), [0.05, 0.08, 0.02, 0.01, 0.012, 0.03])
    msg = to_ros_pose_with_covariance(POSE, cov)
    assert set(msg) == {"pose", "covariance"}
    assert list(msg["pose"]["position"].values()) == [25.0, -12.0, 3.0]
    q = msg["pose"]["orientation"]
    assert list(q) == ["x", "y", "z", "w"]
    # rotation vector r = angle * axis  ->  q = (sin(angle/2) axis, cos(angle/2))
    r = np.array([0.3, -0.5, 2.1])
    angle = np.linalg.norm(r)
    expected_q = [*(np.sin(angle / 2) * r / angle), np.cos(angle / 2)]
    np.testing.assert_allclose([q["x"], q["y"], q["z"], q["w"]], expected_q, atol=1e-12)
    flat = np.array(msg["covariance"])
    assert flat.shape == (36,)
    ros = flat.reshape(6, 6)
    rot = POSE.rotation
    # row-major, x y z first: the position block is R Σ_ρρ Rᵀ, the rotation block R Σ_φφ Rᵀ
    np.testing.assert_allclose(ros[:3, :3], rot @ cov[:3, :3] @ rot.T, atol=1e-15)
    np.testing.assert_allclose(ros[3:, 3:], rot @ cov[3:, 3:] @ rot.T, atol=1e-15)
    np.testing.assert_allclose(ros[:3, 3:], rot @ cov[:3, 3:] @ rot.T, atol=1e-15)
    pose, back = from_ros_pose_with_covariance(msg)
    assert pose.is_close(POSE, atol=1e-12)
    np.testing.assert_allclose(back, cov, atol=1e-15)


def test_accepts_message_objects() -> None:
    """Message objects with attributes (rosbags, rclpy) read like the dict layout."""
    pytest.importorskip("rosbags", reason="rosbags is not installed")
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.LATEST)
    cov = _spd(np.random.default_rng(2), [0.1, 0.1, 0.1, 0.02, 0.02, 0.02])
    d = to_ros_pose_with_covariance(POSE, cov)
    t = ts.types
    msg = t["geometry_msgs/msg/PoseWithCovariance"](
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](**d["pose"]["position"]),
            orientation=t["geometry_msgs/msg/Quaternion"](**d["pose"]["orientation"]),
        ),
        covariance=np.array(d["covariance"]),
    )
    raw = ts.serialize_cdr(msg, "geometry_msgs/msg/PoseWithCovariance")
    decoded = ts.deserialize_cdr(raw, "geometry_msgs/msg/PoseWithCovariance")
    pose, back = from_ros_pose_with_covariance(decoded)
    assert pose.is_close(POSE, atol=1e-12)
    np.testing.assert_allclose(back, cov, atol=1e-15)


def test_monte_carlo_frame_conversion() -> None:
    """Sample δ in scanreg's convention, measure ROS's ε; and the reverse."""
    rng = np.random.default_rng(7)
    cov = _spd(rng, [0.05, 0.03, 0.04, 0.01, 0.015, 0.02])
    n = 6000
    deltas = rng.multivariate_normal(np.zeros(6), cov, size=n)
    eps = np.empty((n, 6))
    for i, d in enumerate(deltas):
        true = POSE @ SE3.exp(d)
        eps[i, :3] = true.translation - POSE.translation
        eps[i, 3:] = so3_log(true.rotation @ POSE.rotation.T)
    empirical = np.cov(eps.T)
    predicted = covariance_to_ros(POSE, cov)
    # correlations to 0.05 and variances to 8 % (6000 samples: sampling errors ≤ 0.013 and
    # 1.8 %, so about 4σ)
    sd, sd_emp = np.sqrt(np.diag(predicted)), np.sqrt(np.diag(empirical))
    np.testing.assert_allclose(
        empirical / np.outer(sd_emp, sd_emp), predicted / np.outer(sd, sd), atol=0.05
    )
    np.testing.assert_allclose(np.diag(empirical), np.diag(predicted), rtol=0.08)
    # The SE(3) adjoint (left perturbation exp(ε) T) would be badly wrong for ROS here.
    adj = POSE.adjoint()
    wrong = adj @ cov @ adj.T
    assert np.diag(wrong)[:3].min() > 3 * np.diag(empirical)[:3].max()

    # reverse: ε in ROS's convention, measured δ = log(T⁻¹ T_true)
    ros_cov = predicted
    eps = rng.multivariate_normal(np.zeros(6), ros_cov, size=n)
    deltas = np.empty((n, 6))
    for i, e in enumerate(eps):
        true = SE3.from_rt(so3_exp(e[3:]) @ POSE.rotation, POSE.translation + e[:3])
        deltas[i] = (POSE.inverse() @ true).log()
    back = covariance_from_ros(POSE, ros_cov)
    np.testing.assert_allclose(np.diag(np.cov(deltas.T)), np.diag(back), rtol=0.08)
    np.testing.assert_allclose(back, cov, atol=1e-15)


def test_planar_round_trip_and_monte_carlo() -> None:
    rng = np.random.default_rng(3)
    cov = _spd(rng, [0.04, 0.02, 0.01])
    msg = to_ros_pose2d_covariance(POSE2, cov)
    full = np.array(msg["covariance"]).reshape(6, 6)
    idx = np.ix_([0, 1, 5], [0, 1, 5])
    assert np.count_nonzero(full) == np.count_nonzero(full[idx]) == 9
    assert msg["pose"]["position"]["z"] == 0.0
    assert msg["pose"]["orientation"]["x"] == msg["pose"]["orientation"]["y"] == 0.0
    pose, back = from_ros_pose2d_covariance(msg)
    assert pose.is_close(POSE2, atol=1e-12)
    np.testing.assert_allclose(back, cov, atol=1e-15)
    # Monte Carlo: δ in scanreg's convention → [x, y, yaw] errors in the parent frame
    deltas = rng.multivariate_normal(np.zeros(3), cov, size=6000)
    errs = np.array([(POSE2 @ SE2.exp(d)).as_vector() - POSE2.as_vector() for d in deltas])
    np.testing.assert_allclose(np.cov(errs.T), full[idx], rtol=0.08, atol=2e-5)
    loose = to_ros_pose2d_covariance(POSE2, cov, unobserved_variance=1e6)
    assert np.array(loose["covariance"]).reshape(6, 6)[2, 2] == 1e6


def test_refuses_bad_input() -> None:
    cov = np.eye(6) * 0.01
    with pytest.raises(TypeError, match="pose"):
        to_ros_pose_with_covariance(POSE2, cov)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="covariance"):
        to_ros_pose_with_covariance(POSE, np.eye(3))
    asym = cov.copy()
    asym[0, 1] = 0.5
    with pytest.raises(ValueError, match="covariance: is not symmetric"):
        to_ros_pose_with_covariance(POSE, asym)
    with pytest.raises(ValueError, match="positive semi-definite"):
        to_ros_pose_with_covariance(POSE, -cov)
    with pytest.raises(ValueError, match="covariance"):
        to_ros_pose_with_covariance(POSE, np.full((6, 6), np.nan))
    msg = to_ros_pose_with_covariance(POSE, cov)
    msg["pose"]["orientation"]["w"] *= 3
    with pytest.raises(ValueError, match="quaternion norm"):
        from_ros_pose_with_covariance(msg)
    with pytest.raises(ValueError, match="has no 'covariance'"):
        from_ros_pose_with_covariance({"pose": to_ros_pose_with_covariance(POSE, cov)["pose"]})
    tilted = to_ros_pose_with_covariance(POSE, cov)
    with pytest.raises(ValueError, match="not a rotation about Z"):
        from_ros_pose2d_covariance(tilted)
    with pytest.raises(ValueError, match="unobserved_variance"):
        to_ros_pose2d_covariance(POSE2, np.eye(3), unobserved_variance=-1.0)


HAS_OPEN3D = importlib.util.find_spec("open3d") is not None


@pytest.mark.skipif(not HAS_OPEN3D, reason="open3d is not installed (optional dependency)")
def test_open3d_round_trip() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 3))
    normals = rng.normal(size=(500, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cloud = PointCloud(points=pts, fields={"normal": normals, "color": rng.uniform(size=(500, 3))})
    pcd = to_open3d(cloud)
    np.testing.assert_array_equal(np.asarray(pcd.points), pts)
    back = from_open3d(pcd)
    np.testing.assert_array_equal(back.points, pts)
    np.testing.assert_array_equal(back.fields["normal"], normals)
    np.testing.assert_array_equal(back.fields["color"], cloud.fields["color"])
    flat = to_open3d(np.ascontiguousarray(pts[:, :2]))
    np.testing.assert_array_equal(np.asarray(flat.points)[:, 2], 0.0)
    np.testing.assert_array_equal(np.asarray(flat.points)[:, :2], pts[:, :2])
    bare = from_open3d(to_open3d(pts))
    assert dict(bare.fields) == {}
    # a real KITTI frame through Open3D and back, bit for bit
    kitti = read_kitti_bin(data_dir("kitti-odometry-00-frames-000-015", "velodyne", "000000.bin"))
    np.testing.assert_array_equal(from_open3d(to_open3d(kitti)).points, kitti.points)
    nan = np.array(pts)
    nan[3, 1] = np.nan
    with pytest.raises(ValueError, match="cloud"):
        to_open3d(PointCloud(points=nan))
    with pytest.raises(TypeError, match="pcd"):
        from_open3d(pts)


def test_open3d_missing_is_a_clear_error(monkeypatch: Any) -> None:
    """Without open3d the call says what to install (simulated by hiding the module)."""
    import builtins

    real_import = builtins.__import__

    def fake_import(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "open3d":
            raise ImportError("No module named 'open3d'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(ImportError, match="pip install open3d"):
        to_open3d(np.zeros((3, 3)))
