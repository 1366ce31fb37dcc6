"""Trajectories (KITTI and TUM formats) and KITTI calibration files.

A trajectory is a sequence of poses ``T_world_body`` (``p_world = R p_body + t``), optionally
with timestamps in seconds.

* KITTI odometry poses: one line per pose, 12 numbers — the 3×4 matrix ``[R | t]`` row-major.
* TUM RGB-D: ``timestamp tx ty tz qx qy qz qw`` per line (Hamilton quaternion, scalar last);
  lines starting with ``#`` are comments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..transform import SE2, SE3
from ._common import FileFormatError, PathLike

#: Largest accepted ``|RᵀR - I|`` in a file (text files round to ~9 digits; this catches
#: matrices that are not rotations at all while accepting rounding).
ROTATION_TOLERANCE = 1e-4
#: Largest accepted deviation of a TUM quaternion's norm from 1 (it is normalised).
QUATERNION_TOLERANCE = 1e-3


def _quaternion_rows(x: Any, y: Any, z: Any, w: Any) -> tuple[tuple[Any, Any, Any], ...]:
    """The rotation matrix of the unit quaternion ``[x, y, z, w]``, row by row (scalars or
    arrays)."""
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
        (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
        (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)),
    )


def quaternion_to_rotation(q: Any) -> FloatArray:
    """Rotation matrices of quaternions ``(..., 4)`` in ``[qx, qy, qz, qw]`` order (normalised)."""
    q = np.asarray(q, dtype=np.float64)
    norm = math.hypot(*q.tolist()) if q.shape == (4,) else 0.0
    if math.isfinite(norm) and norm > 0:
        # One quaternion (a g2o line): plain floats take a quarter of the array path's time.
        x, y, z, w = (v / norm for v in q.tolist())
        return np.array(_quaternion_rows(x, y, z, w))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    rows = _quaternion_rows(*np.moveaxis(q, -1, 0))
    r = np.empty((*q.shape[:-1], 3, 3))
    for i in range(3):
        for j in range(3):
            r[..., i, j] = rows[i][j]
    return r


def rotation_to_quaternion(rotation: Any) -> FloatArray:
    """Unit quaternion ``[qx, qy, qz, qw]`` (``qw >= 0``) of a 3×3 rotation matrix."""
    r = np.asarray(rotation, dtype=np.float64)
    trace = float(np.trace(r))
    # Shepperd: divide by the largest of 4w², 4x², 4y², 4z² for accuracy.
    cands = [trace, r[0, 0], r[1, 1], r[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    else:
        a = i - 1
        b, c = (a + 1) % 3, (a + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + r[a, a] - r[b, b] - r[c, c], 1e-300))
        v = np.zeros(3)
        v[a] = s / 4
        v[b] = (r[b, a] + r[a, b]) / s
        v[c] = (r[c, a] + r[a, c]) / s
        q = [*v, (r[c, b] - r[b, c]) / s]
    out: FloatArray = np.array(q) / np.linalg.norm(q)
    if out[3] < 0:
        out = -out
    return out


def _pose_matrices(value: Any) -> FloatArray:
    """``(N, 4, 4)`` float64 from an array-like of matrices or a sequence of ``SE3``."""
    if isinstance(value, (list, tuple)) and any(isinstance(p, SE2 | SE3) for p in value):
        if not all(isinstance(p, SE3) for p in value):
            raise TypeError("poses: a trajectory holds 3D poses: SE3 or (4, 4) matrices")
        value = [p.as_matrix() for p in value]
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(
            f"poses: expected an (N, 4, 4) array or a list of SE3, got {type(value).__name__}"
        ) from None


@dataclass(frozen=True)
class Trajectory:
    """Poses ``T_world_body`` over time.

    Attributes
    ----------
    poses : (N, 4, 4) float64
        Homogeneous matrices, read-only. Rotations are as stored in the file (not
        re-orthonormalised), so metrics reproduce other tools' numbers.
    timestamps : (N,) float64 or None
        Seconds (TUM); None for KITTI pose files.
    """

    poses: FloatArray
    timestamps: FloatArray | None = None

    def __post_init__(self) -> None:
        poses = _pose_matrices(self.poses)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise ValueError(f"poses: expected shape (N, 4, 4), got {poses.shape}")
        if not np.isfinite(poses).all():
            raise ValueError("poses: contains NaN or inf")
        if poses.size and np.abs(poses[:, 3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
            raise ValueError("poses: the last row of every matrix must be [0, 0, 0, 1]")
        poses.setflags(write=False)
        object.__setattr__(self, "poses", poses)
        if self.timestamps is not None:
            stamps = np.array(self.timestamps, dtype=np.float64)
            if stamps.shape != (poses.shape[0],):
                raise ValueError(
                    f"timestamps: expected shape ({poses.shape[0]},), got {stamps.shape}"
                )
            if not np.isfinite(stamps).all():
                raise ValueError("timestamps: contains NaN or inf")
            stamps.setflags(write=False)
            object.__setattr__(self, "timestamps", stamps)

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    @property
    def positions(self) -> FloatArray:
        """(N, 3) translations (the body origin in the world frame)."""
        return np.ascontiguousarray(self.poses[:, :3, 3])

    def se3(self, index: int) -> SE3:
        """Pose ``index`` as an :class:`~scanreg.SE3` (re-orthonormalised if needed)."""
        return SE3.from_matrix(self.poses[index], atol=ROTATION_TOLERANCE)

    def as_se3(self) -> list[SE3]:
        """Every pose as an :class:`~scanreg.SE3`."""
        return [self.se3(i) for i in range(len(self))]

    @classmethod
    def from_poses(cls, poses: list[SE3] | list[SE2], timestamps: Any = None) -> Trajectory:
        """From SE3 poses, or SE2 poses embedded in the plane z = 0 (yaw about z)."""
        mats = np.zeros((len(poses), 4, 4))
        for i, pose in enumerate(poses):
            if isinstance(pose, SE3):
                mats[i] = pose.as_matrix()
            elif isinstance(pose, SE2):
                mats[i] = np.eye(4)
                mats[i, :2, :2] = pose.rotation
                mats[i, :2, 3] = pose.translation
            else:
                raise TypeError(f"poses[{i}]: expected SE2 or SE3, got {type(pose).__name__}")
        return cls(mats, timestamps)

    @classmethod
    def from_xyyaw(cls, xyyaw: Any, timestamps: Any = None) -> Trajectory:
        """From planar poses ``(N, 3)`` rows ``[x, y, yaw]`` (radians), embedded at z = 0."""
        v = np.asarray(xyyaw, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"xyyaw: expected shape (N, 3), got {v.shape}")
        mats = np.tile(np.eye(4), (v.shape[0], 1, 1))
        c, s = np.cos(v[:, 2]), np.sin(v[:, 2])
        mats[:, 0, 0], mats[:, 0, 1], mats[:, 1, 0], mats[:, 1, 1] = c, -s, s, c
        mats[:, :2, 3] = v[:, :2]
        return cls(mats, timestamps)


def _numeric_rows(path: Path, width: int, what: str) -> tuple[FloatArray, list[int]]:
    """Non-comment lines of a text file as an (M, width) table, and their line numbers."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(path, "not a text file (invalid UTF-8)") from None
    rows, numbers = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.replace(",", " ").split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) != width:
            raise FileFormatError(
                path, f"line {number}: {len(words)} values, a {what} line has {width}"
            )
        rows.append(words)
        numbers.append(number)
    if not rows:
        raise FileFormatError(path, f"no {what} lines")
    try:
        table = np.array(rows, dtype=np.float64)
    except ValueError as exc:
        raise FileFormatError(path, f"bad number: {exc}") from None
    bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
    if bad.size:
        raise FileFormatError(path, f"line {numbers[bad[0]]}: NaN or inf")
    return table, numbers


def _check_rotations(path: Path, poses: FloatArray, numbers: list[int]) -> None:
    r = poses[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(r)
    bad = np.flatnonzero((err > ROTATION_TOLERANCE) | (det < 0))
    if bad.size:
        i = int(bad[0])
        raise FileFormatError(
            path, f"line {numbers[i]}: not a rotation matrix (|RᵀR - I| = {err[i]:.1e})"
        )


def read_kitti_poses(path: PathLike) -> Trajectory:
    """Read a KITTI odometry pose file (12 numbers per line: ``[R | t]`` row-major).

    Returns a :class:`Trajectory` without timestamps (KITTI keeps them in ``times.txt``;
    pass them with ``dataclasses.replace(traj, timestamps=...)``).
    """
    p = Path(path)
    table, numbers = _numeric_rows(p, 12, "KITTI pose")
    poses = np.tile(np.eye(4), (table.shape[0], 1, 1))
    poses[:, :3, :] = table.reshape(-1, 3, 4)
    _check_rotations(p, poses, numbers)
    return Trajectory(poses)


def read_tum(path: PathLike) -> Trajectory:
    """Read a TUM trajectory (``timestamp tx ty tz qx qy qz qw``; ``#`` comments)."""
    p = Path(path)
    table, numbers = _numeric_rows(p, 8, "TUM")
    # A component near 1e308 overflows the norm to inf: refused below (found by fuzz/).
    with np.errstate(over="ignore"):
        norms = np.linalg.norm(table[:, 4:], axis=1)
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= QUATERNION_TOLERANCE))
    if bad.size:
        i = int(bad[0])
        raise FileFormatError(p, f"line {numbers[i]}: quaternion norm {norms[i]:.6g}, not 1")
    poses = np.tile(np.eye(4), (table.shape[0], 1, 1))
    poses[:, :3, :3] = quaternion_to_rotation(table[:, 4:])
    poses[:, :3, 3] = table[:, 1:4]
    return Trajectory(poses, table[:, 0])


def read_times(path: PathLike) -> FloatArray:
    """Read a KITTI ``times.txt`` (one timestamp in seconds per line) as an (N,) array."""
    table, _ = _numeric_rows(Path(path), 1, "timestamp")
    return np.ascontiguousarray(table[:, 0])


def write_kitti_poses(path: PathLike, trajectory: Trajectory | Any) -> None:
    """Write the poses as KITTI lines (12 numbers, ``%.9e``; timestamps are not stored).

    ``trajectory`` is a :class:`Trajectory` or the poses alone (an ``(N, 4, 4)`` array-like
    or a list of ``SE3``): KITTI files hold no timestamps."""
    if not isinstance(trajectory, Trajectory):
        if trajectory is None or isinstance(trajectory, (str, bytes, dict)):
            got = type(trajectory).__name__
            raise TypeError(f"trajectory: expected Trajectory or (N, 4, 4) poses, got {got}")
        trajectory = Trajectory(poses=trajectory)
    rows = trajectory.poses[:, :3, :].reshape(-1, 12)
    np.savetxt(path, rows, fmt="%.12e")


def write_tum(path: PathLike, trajectory: Trajectory) -> None:
    """Write ``timestamp tx ty tz qx qy qz qw`` lines; needs timestamps."""
    if not isinstance(trajectory, Trajectory):
        raise TypeError(f"trajectory: expected Trajectory, got {type(trajectory).__name__}")
    if trajectory.timestamps is None:
        raise ValueError("trajectory: TUM files need timestamps; this trajectory has none")
    quats = np.array([rotation_to_quaternion(m[:3, :3]) for m in trajectory.poses]).reshape(-1, 4)
    table = np.column_stack([trajectory.timestamps, trajectory.positions, quats])
    with Path(path).open("w", encoding="utf-8") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        np.savetxt(fh, table, fmt="%.9f " + " ".join(["%.12g"] * 7))


@dataclass(frozen=True)
class KittiCalibration:
    """A KITTI odometry ``calib.txt``.

    Attributes
    ----------
    matrices : dict of name to (3, 4) float64
        Every entry (``P0`` … ``P3``, ``Tr``) as a 3×4 matrix.
    T_cam0_velo : SE3
        ``Tr``: maps Velodyne points into the camera-0 frame (``p_cam0 = R p_velo + t``).
    """

    matrices: dict[str, FloatArray]
    T_cam0_velo: SE3


def read_kitti_calib(path: PathLike) -> KittiCalibration:
    """Read a KITTI odometry ``calib.txt`` (lines ``NAME: 12 numbers``)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(p, "not a text file (invalid UTF-8)") from None
    matrices: dict[str, FloatArray] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        name, sep, rest = line.partition(":")
        if not sep:
            raise FileFormatError(p, f"line {number}: expected 'NAME: 12 numbers'")
        try:
            values = np.array(rest.split(), dtype=np.float64)
        except ValueError as exc:
            raise FileFormatError(p, f"line {number}: bad number: {exc}") from None
        if values.shape != (12,) or not np.isfinite(values).all():
            raise FileFormatError(p, f"line {number}: expected 12 finite numbers for {name}")
        matrices[name.strip()] = values.reshape(3, 4)
    if "Tr" not in matrices:
        raise FileFormatError(p, "no Tr (velodyne to camera-0) entry")
    tr = np.vstack([matrices["Tr"], [0.0, 0.0, 0.0, 1.0]])
    try:
        pose = SE3.from_matrix(tr, atol=ROTATION_TOLERANCE)
    except ValueError as exc:
        raise FileFormatError(p, f"Tr is not a rigid transform: {exc}") from None
    return KittiCalibration(matrices=matrices, T_cam0_velo=pose)
