"""Interoperability: Open3D point clouds and ROS pose-with-covariance message layouts.

Open3D
------
:func:`to_open3d` / :func:`from_open3d` convert to and from ``open3d.geometry.PointCloud``
(an optional dependency, imported only when called). Points, normals (``fields["normal"]``,
``(N, 3)``) and colours (``fields["color"]``, ``(N, 3)`` in [0, 1]) cross over; the legacy
Open3D cloud has no intensity, ring or time, so those stay behind.

ROS ``geometry_msgs/PoseWithCovariance``
----------------------------------------
The message holds a pose (position, orientation quaternion ``x, y, z, w``) and a row-major
6×6 covariance over ``(x, y, z, rotation about X, rotation about Y, rotation about Z)``. Its
definition says the orientation part uses a *fixed-axis* representation, and
``nav_msgs/Odometry`` says the pose (hence its covariance) is expressed in
``header.frame_id``, the parent frame: that is how ``robot_localization`` and AMCL read and
write it (position errors in the world/map frame, small rotations about the parent's fixed
axes). As perturbations of ``T = (R, t)``::

    ROS:      t_true = t + ε_t,          R_true = Exp(ε_φ) R        ε in the parent frame
    scanreg:  T_true = T @ Exp(δ),       δ = [ρ, φ] in the body (child) frame

To first order ``t_true = t + R ρ`` and ``R Exp(φ) = Exp(R φ) R``, so ``ε = J δ`` with
``J = diag(R, R)`` and ``Σ_ros = J Σ Jᵀ``. Note that this is **not** the SE(3) adjoint:
``Ad(T) = [[R, [t]× R], [0, R]]`` maps to the *left* SE(3) perturbation ``exp(ε) T``, whose
translation part also moves with the rotation about the parent's origin (the ``[t]×`` term).
Using it for ROS would inflate the position covariance by ``|t|²·σ_φ²`` far from the origin;
``tests/test_interop.py`` checks both claims by Monte Carlo.

2D: :func:`to_ros_pose2d_covariance` does the same for ``SE2`` (``J = diag(R₂, 1)``) and puts
the 3×3 block at rows/columns ``x, y, rotation about Z`` of the 6×6 message covariance, as
planar ROS nodes (AMCL, slam_toolbox, robot_localization in 2D mode) read it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ._validate import FloatArray, as_matrix, as_points
from .io import PointCloud
from .io.trajectory import quaternion_to_rotation, rotation_to_quaternion
from .transform import SE2, SE3

#: The order of the 6 coordinates of a ROS pose covariance (row-major 6×6 in the message).
ROS_POSE_COVARIANCE_ORDER = ("x", "y", "z", "rotation_x", "rotation_y", "rotation_z")
#: Indices of ``x, y, rotation about Z`` in the ROS 6×6 (the planar block).
ROS_PLANAR_INDICES = (0, 1, 5)

#: Relative tolerance on covariance symmetry and on negative eigenvalues.
_COVARIANCE_TOLERANCE = 1e-9
#: A ROS quaternion may deviate this much from unit norm (it is normalised).
QUATERNION_NORM_TOLERANCE = 1e-3


# --------------------------------------------------------------------------- Open3D


def _open3d() -> Any:
    try:
        import open3d
    except ImportError:
        raise ImportError("Open3D interop needs the 'open3d' package: pip install open3d") from None
    return open3d


def to_open3d(cloud: PointCloud | FloatArray) -> Any:
    """An ``open3d.geometry.PointCloud`` of a :class:`~scanreg.io.PointCloud` or an array.

    ``cloud`` may be a ``PointCloud`` (normals from ``fields["normal"]`` and colours from
    ``fields["color"]`` when present) or a float64 ``(N, 3)`` / ``(N, 2)`` array. 2D points
    get ``z = 0``. Non-finite points are refused (Open3D would silently keep them).
    """
    o3d = _open3d()
    normals = colors = None
    if isinstance(cloud, PointCloud):
        points = cloud.points
        normals = cloud.fields.get("normal")
        colors = cloud.fields.get("color")
        if not np.isfinite(points).all():
            raise ValueError("cloud: has non-finite points; use cloud.finite() first")
    else:
        points = as_points(cloud, "cloud", min_points=0)
    if points.shape[1] == 2:
        points = np.concatenate([points, np.zeros((points.shape[0], 1))], axis=1)
    out = o3d.geometry.PointCloud()
    # Open3D refuses read-only arrays (PointCloud's are): hand it copies
    out.points = o3d.utility.Vector3dVector(np.array(points, dtype=np.float64))
    for name, value in (("normal", normals), ("color", colors)):
        if value is None:
            continue
        if value.shape != (points.shape[0], 3):
            raise ValueError(f"cloud: fields[{name!r}] must have shape (N, 3), got {value.shape}")
        vec = o3d.utility.Vector3dVector(np.array(value, dtype=np.float64))
        if name == "normal":
            out.normals = vec
        else:
            out.colors = vec
    return out


def from_open3d(pcd: Any) -> PointCloud:
    """A :class:`~scanreg.io.PointCloud` of an ``open3d.geometry.PointCloud``.

    Normals become ``fields["normal"]`` and colours ``fields["color"]`` (each ``(N, 3)``).
    """
    o3d = _open3d()
    if not isinstance(pcd, o3d.geometry.PointCloud):
        raise TypeError(f"pcd: expected an open3d.geometry.PointCloud, got {type(pcd).__name__}")
    points = np.array(np.asarray(pcd.points), dtype=np.float64).reshape(-1, 3)
    fields: dict[str, FloatArray] = {}
    if pcd.has_normals():
        fields["normal"] = np.array(np.asarray(pcd.normals), dtype=np.float64)
    if pcd.has_colors():
        fields["color"] = np.array(np.asarray(pcd.colors), dtype=np.float64)
    return PointCloud(points=points, fields=fields)


# --------------------------------------------------------------------------- covariances


def _covariance(value: Any, name: str, dim: int) -> FloatArray:
    cov = as_matrix(value, name, (dim, dim))
    scale = max(float(np.abs(cov).max()), 1e-300)
    if np.abs(cov - cov.T).max() > _COVARIANCE_TOLERANCE * scale:
        raise ValueError(f"{name}: is not symmetric")
    if np.linalg.eigvalsh(cov).min() < -_COVARIANCE_TOLERANCE * scale:
        raise ValueError(f"{name}: is not positive semi-definite")
    out: FloatArray = 0.5 * (cov + cov.T)
    return out


def _pose(value: Any, name: str, cls: type[SE2] | type[SE3]) -> Any:
    if not isinstance(value, cls):
        raise TypeError(f"{name}: expected a scanreg.{cls.__name__}, got {type(value).__name__}")
    return value


def _ros_jacobian(pose: SE3) -> FloatArray:
    jac = np.zeros((6, 6))
    jac[:3, :3] = pose.rotation
    jac[3:, 3:] = pose.rotation
    return jac


def covariance_to_ros(pose: SE3, covariance: Any) -> FloatArray:
    """scanreg's 6×6 (right perturbation, body frame) → ROS's 6×6 (parent frame).

    ``Σ_ros = J Σ Jᵀ`` with ``J = diag(R, R)`` (see the module docstring).
    """
    pose = _pose(pose, "pose", SE3)
    jac = _ros_jacobian(pose)
    out: FloatArray = jac @ _covariance(covariance, "covariance", 6) @ jac.T
    return out


def covariance_from_ros(pose: SE3, covariance: Any) -> FloatArray:
    """ROS's 6×6 (parent frame) → scanreg's 6×6 (right perturbation): ``Jᵀ Σ_ros J``."""
    pose = _pose(pose, "pose", SE3)
    jac = _ros_jacobian(pose)
    out: FloatArray = jac.T @ _covariance(covariance, "covariance", 6) @ jac
    return out


def covariance2d_to_ros(pose: SE2, covariance: Any) -> FloatArray:
    """scanreg's 3×3 over ``[ρx, ρy, θ]`` (body frame) → ``[x, y, yaw]`` in the parent frame."""
    pose = _pose(pose, "pose", SE2)
    jac = np.eye(3)
    jac[:2, :2] = pose.rotation
    out: FloatArray = jac @ _covariance(covariance, "covariance", 3) @ jac.T
    return out


def covariance2d_from_ros(pose: SE2, covariance: Any) -> FloatArray:
    """``[x, y, yaw]`` covariance in the parent frame → scanreg's 3×3 (body frame)."""
    pose = _pose(pose, "pose", SE2)
    jac = np.eye(3)
    jac[:2, :2] = pose.rotation
    out: FloatArray = jac.T @ _covariance(covariance, "covariance", 3) @ jac
    return out


# --------------------------------------------------------------------------- messages


def _pose_dict(rotation: FloatArray, translation: FloatArray) -> dict[str, dict[str, float]]:
    q = rotation_to_quaternion(rotation)
    return {
        "position": dict(zip("xyz", map(float, translation), strict=True)),
        "orientation": dict(zip("xyzw", map(float, q), strict=True)),
    }


def to_ros_pose_with_covariance(pose: SE3, covariance: Any) -> dict[str, Any]:
    """The ``geometry_msgs/PoseWithCovariance`` layout of a pose and its scanreg covariance.

    Parameters
    ----------
    pose : SE3
        ``T_parent_child`` (e.g. ``T_map_base``; a registration result ``T_target_source``).
    covariance : (6, 6)
        Over scanreg's right-perturbation tangent ``[ρ, φ]`` (body frame).

    Returns
    -------
    dict
        ``{"pose": {"position": {x, y, z}, "orientation": {x, y, z, w}},
        "covariance": [36 floats]}`` — row-major, ordered ``x, y, z, rotation about X, Y, Z``,
        expressed in the parent frame (see the module docstring). Field names match the
        message, so it can be passed to a message constructor.
    """
    ros = covariance_to_ros(pose, covariance)
    return {
        "pose": _pose_dict(pose.rotation, pose.translation),
        "covariance": [float(v) for v in ros.reshape(36)],
    }


def _get(msg: Any, key: str, name: str) -> Any:
    try:
        return msg[key] if isinstance(msg, Mapping) else getattr(msg, key)
    except (KeyError, AttributeError):
        raise ValueError(f"{name}: has no {key!r}") from None


def _read_message(msg: Any, name: str) -> tuple[FloatArray, FloatArray, FloatArray]:
    pose = _get(msg, "pose", name)
    position = _get(pose, "position", f"{name}.pose")
    orientation = _get(pose, "orientation", f"{name}.pose")
    t = as_matrix(
        [_get(position, k, f"{name}.pose.position") for k in "xyz"], f"{name}.pose.position", (3,)
    )
    q = as_matrix(
        [_get(orientation, k, f"{name}.pose.orientation") for k in "xyzw"],
        f"{name}.pose.orientation",
        (4,),
    )
    if abs(float(np.linalg.norm(q)) - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(
            f"{name}.pose.orientation: quaternion norm {np.linalg.norm(q):.6g} is not 1"
        )
    cov = as_matrix(
        np.asarray(_get(msg, "covariance", name), dtype=np.float64).reshape(-1),
        f"{name}.covariance",
        (36,),
    ).reshape(6, 6)
    return quaternion_to_rotation(q), t, cov


def from_ros_pose_with_covariance(msg: Any) -> tuple[SE3, FloatArray]:
    """Inverse of :func:`to_ros_pose_with_covariance`: ``(pose, covariance)`` in scanreg's
    convention from a dict of that layout or a ``PoseWithCovariance`` message object."""
    rotation, t, cov = _read_message(msg, "msg")
    pose = SE3.from_rt(rotation, t)
    return pose, covariance_from_ros(pose, _covariance(cov, "msg.covariance", 6))


def to_ros_pose2d_covariance(
    pose: SE2, covariance: Any, *, unobserved_variance: float = 0.0
) -> dict[str, Any]:
    """The ``PoseWithCovariance`` layout of a planar pose and its 3×3 scanreg covariance.

    The pose is embedded at ``z = 0`` with its yaw about Z; the covariance over scanreg's
    ``[ρx, ρy, θ]`` (body frame) becomes ``[x, y, yaw]`` in the parent frame at rows/columns
    ``0, 1, 5``. ``z``, rotation about X and about Y get ``unobserved_variance`` on the
    diagonal (0: the planar constraint holds exactly, as AMCL publishes it; use a large value
    for filters that fuse every coordinate).
    """
    pose = _pose(pose, "pose", SE2)
    if not (np.isfinite(unobserved_variance) and unobserved_variance >= 0):
        raise ValueError(f"unobserved_variance: must be finite and >= 0, got {unobserved_variance}")
    planar = covariance2d_to_ros(pose, covariance)
    full = np.zeros((6, 6))
    idx = np.array(ROS_PLANAR_INDICES)
    full[np.ix_(idx, idx)] = planar
    for i in (2, 3, 4):
        full[i, i] = unobserved_variance
    rotation = np.eye(3)
    rotation[:2, :2] = pose.rotation
    translation = np.array([*pose.translation, 0.0])
    return {
        "pose": _pose_dict(rotation, translation),
        "covariance": [float(v) for v in full.reshape(36)],
    }


#: Largest tilt (radians) of a message's orientation accepted as planar.
PLANAR_TOLERANCE = 1e-6


def from_ros_pose2d_covariance(msg: Any) -> tuple[SE2, FloatArray]:
    """Inverse of :func:`to_ros_pose2d_covariance`: ``(SE2, 3×3)`` in scanreg's convention.

    The orientation must be a rotation about Z (within :data:`PLANAR_TOLERANCE`); ``z`` and
    the other covariance entries are ignored.
    """
    rotation, t, cov = _read_message(msg, "msg")
    tilt = float(np.arccos(np.clip(rotation[2, 2], -1.0, 1.0)))
    if tilt > PLANAR_TOLERANCE:
        raise ValueError(f"msg.pose.orientation: not a rotation about Z (tilted by {tilt:.3g} rad)")
    pose = SE2.from_vector([t[0], t[1], np.arctan2(rotation[1, 0], rotation[0, 0])])
    idx = np.array(ROS_PLANAR_INDICES)
    planar = _covariance(cov, "msg.covariance", 6)[np.ix_(idx, idx)]
    return pose, covariance2d_from_ros(pose, planar)


__all__ = [
    "PLANAR_TOLERANCE",
    "ROS_PLANAR_INDICES",
    "ROS_POSE_COVARIANCE_ORDER",
    "covariance2d_from_ros",
    "covariance2d_to_ros",
    "covariance_from_ros",
    "covariance_to_ros",
    "from_open3d",
    "from_ros_pose2d_covariance",
    "from_ros_pose_with_covariance",
    "to_open3d",
    "to_ros_pose2d_covariance",
    "to_ros_pose_with_covariance",
]
