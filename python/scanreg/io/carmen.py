"""CARMEN laser logs (``.log``, ``.clf``, gzip or bzip2): 2D laser scans and wheel odometry.

One line per message, whitespace separated (tabs occur), ``#`` comments. Messages read:

* ``FLASER n r_0 … r_{n-1} x y θ odom_x odom_y odom_θ ipc_ts host logger_ts`` (front laser;
  ``RLASER`` is the rear laser, same layout). ``x y θ`` is the laser pose in the world,
  ``odom_*`` the robot's odometry pose. The field of view is 180° starting at −90°; the beam
  spacing is ``π/(n−1)`` for an odd ``n`` (181, 361: both ends included) and ``π/n`` for an
  even ``n`` (180, 360: 1° / 0.5°, last beam at 89° / 89.5°), as in the Radish/Freiburg logs.
* ``ROBOTLASER1/2 type start fov resolution max_range accuracy remission_mode n r… m e…
  lx ly lθ rx ry rθ tv rv forward_safety side_safety turn_axis ipc_ts host logger_ts``.
* ``RAWLASER1..4 type start fov resolution max_range accuracy remission_mode n r… m e…
  ipc_ts host logger_ts`` (no pose).
* ``ODOM x y θ tv rv accel ipc_ts host logger_ts``.

Other messages (``PARAM``, ``NEFF``, ``SYNC``, ``TRUEPOS``, …) are skipped and counted in
:attr:`CarmenLog.skipped`.

Quirks handled (all occur in the shared test logs): ``NaN`` / ``nan`` / ``inf`` range tokens
(invalid readings), the sensor maximum (81.83, 81.91) as "no return", relative timestamps,
all-zero timestamps, timestamps truncated to 6 significant digits (``1.01893e+09``) and
corrupted, non-monotonic ones. Timestamps are returned as stored; :attr:`CarmenLog.time_status`
says whether they can be used as times.
"""

from __future__ import annotations

import bz2
import gzip
import math
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray
from ..transform import SE2
from ._common import FileFormatError, PathLike, _readonly

#: FLASER/RLASER lines carry no maximum range; readings at or above this are "no return"
#: (SICK LMS logs in CARMEN mark them with the sensor maximum, 81.83 or 81.91 m).
FLASER_MAX_RANGE = 81.0

_LASER_KINDS = ("FLASER", "RLASER")
_RAW_KINDS = ("RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4")
_ROBOT_KINDS = ("ROBOTLASER1", "ROBOTLASER2")
_MESSAGE_NAME = re.compile(r"[A-Z][A-Z0-9_]*")


def _pose_vector(value: Any, name: str) -> FloatArray:
    arr = np.array(value, dtype=np.float64)
    if arr.shape != (3,):
        raise ValueError(f"{name}: expected [x, y, θ], got shape {arr.shape}")
    return _readonly(arr)


@dataclass(frozen=True)
class LaserScan:
    """One 2D laser scan from a CARMEN log.

    Attributes
    ----------
    kind : str
        The message: ``"FLASER"``, ``"RLASER"``, ``"ROBOTLASER1"``, ``"RAWLASER1"``, …
    ranges : (n,) float64
        As logged, metres; invalid readings (``NaN`` tokens) are NaN. Read-only.
    angles : (n,) float64
        Beam angles in the laser frame, radians (x forward, y left). Read-only.
    max_range : float
        Readings at or above this are "no return" (from the message when it has one, else
        :data:`FLASER_MAX_RANGE`).
    laser_pose : (3,) float64 or None
        ``[x, y, θ]`` of the laser in the log's world frame (the corrected pose in the
        "corrected" logs); None for RAWLASER.
    odometry_pose : (3,) float64 or None
        ``[x, y, θ]`` of the robot by wheel odometry; None for RAWLASER.
    timestamp, logger_timestamp : float
        ``ipc_timestamp`` and ``logger_timestamp`` as stored, seconds (see
        :attr:`CarmenLog.time_status` before trusting them).
    line : int
        1-based line number in the file.
    """

    kind: str
    ranges: FloatArray
    angles: FloatArray
    max_range: float
    laser_pose: FloatArray | None
    odometry_pose: FloatArray | None
    timestamp: float
    logger_timestamp: float
    line: int = 0

    def __post_init__(self) -> None:
        ranges = np.array(self.ranges, dtype=np.float64)
        angles = np.array(self.angles, dtype=np.float64)
        if ranges.ndim != 1 or angles.shape != ranges.shape:
            raise ValueError(
                f"ranges, angles: expected equal shapes (n,), got {ranges.shape} {angles.shape}"
            )
        if not np.isfinite(angles).all():
            raise ValueError("angles: contains NaN or inf")
        if not (self.max_range > 0):
            raise ValueError(f"max_range: must be > 0, got {self.max_range}")
        set_ = object.__setattr__
        set_(self, "ranges", _readonly(ranges))
        set_(self, "angles", _readonly(angles))
        if self.laser_pose is not None:
            set_(self, "laser_pose", _pose_vector(self.laser_pose, "laser_pose"))
        if self.odometry_pose is not None:
            set_(self, "odometry_pose", _pose_vector(self.odometry_pose, "odometry_pose"))

    def __len__(self) -> int:
        return int(self.ranges.shape[0])

    def valid(self, min_range: float = 0.0, max_range: float | None = None) -> NDArray[np.bool_]:
        """Mask of beams with a finite return in ``(min_range, max_range)``.

        ``max_range`` defaults to, and is never above, the scan's own :attr:`max_range`.
        """
        upper = self.max_range if max_range is None else min(float(max_range), self.max_range)
        lower = max(float(min_range), 0.0)
        if not (upper > lower):
            raise ValueError(f"max_range: must be > min_range, got {upper} <= {lower}")
        r = self.ranges
        with np.errstate(invalid="ignore"):
            mask: NDArray[np.bool_] = np.isfinite(r) & (r > lower) & (r < upper)
        return mask

    def to_points(self, min_range: float = 0.0, max_range: float | None = None) -> FloatArray:
        """The valid returns as points ``(M, 2)`` in the laser frame, metres, in beam order.

        Beam ``k`` at angle ``angles[k]`` becomes ``r_k [cos a_k, sin a_k]``; the angles of the
        kept beams are ``scan.angles[scan.valid(min_range, max_range)]``.
        """
        mask = self.valid(min_range, max_range)
        r = self.ranges[mask]
        a = self.angles[mask]
        return np.ascontiguousarray(np.stack([r * np.cos(a), r * np.sin(a)], axis=1))

    @property
    def laser_se2(self) -> SE2 | None:
        """:attr:`laser_pose` as ``T_world_laser``."""
        return None if self.laser_pose is None else SE2.from_vector(self.laser_pose)

    @property
    def odometry_se2(self) -> SE2 | None:
        """:attr:`odometry_pose` as ``T_odom_robot``."""
        return None if self.odometry_pose is None else SE2.from_vector(self.odometry_pose)


@dataclass(frozen=True)
class Odometry:
    """The ``ODOM`` messages of a log.

    Attributes
    ----------
    poses : (K, 3) float64
        ``[x, y, θ]`` per message (``T_odom_robot``).
    velocities : (K, 3) float64
        ``[tv, rv, accel]`` as logged (m/s, rad/s, m/s²).
    timestamps : (K,) float64
        ``ipc_timestamp`` as stored.
    lines : (K,) int64
        1-based line number of each message in the file (how the messages interleave with
        the laser lines, :attr:`LaserScan.line`); empty when not known.
    """

    poses: FloatArray
    velocities: FloatArray
    timestamps: FloatArray
    lines: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "poses", _readonly(np.array(self.poses, dtype=np.float64).reshape(-1, 3)))
        set_(
            self,
            "velocities",
            _readonly(np.array(self.velocities, dtype=np.float64).reshape(-1, 3)),
        )
        set_(self, "timestamps", _readonly(np.array(self.timestamps, dtype=np.float64).reshape(-1)))
        set_(self, "lines", _readonly(np.array(self.lines, dtype=np.int64).reshape(-1)))
        if not (len(self.poses) == len(self.velocities) == len(self.timestamps)):
            raise ValueError("poses, velocities, timestamps: expected the same length")
        if len(self.lines) not in (0, len(self.timestamps)):
            raise ValueError(
                f"lines: expected one per message ({len(self.timestamps)}) or none, "
                f"got {len(self.lines)}"
            )

    def __len__(self) -> int:
        return int(self.poses.shape[0])


@dataclass(frozen=True)
class CarmenLog:
    """Everything read from a CARMEN log.

    Attributes
    ----------
    path : Path
    scans : tuple of LaserScan
        Every laser message, in file order (all kinds; filter with :meth:`laser`).
    odometry : Odometry
        The ``ODOM`` messages.
    skipped : mapping of str to int
        Messages not read (``PARAM``, ``NEFF``, …) and how many of each.
    time_status : str
        ``"ok"`` (scan timestamps strictly increasing), ``"all_zero"``, ``"coarse"``
        (non-decreasing with repeats: truncated to a few digits) or ``"non_monotonic"``
        (corrupted: going back in time). ``"empty"`` without scans.
    """

    path: Path
    scans: tuple[LaserScan, ...]
    odometry: Odometry
    skipped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.scans)

    def laser(self, kind: str = "FLASER") -> tuple[LaserScan, ...]:
        """The scans of one message kind."""
        return tuple(s for s in self.scans if s.kind == kind)

    @property
    def timestamps(self) -> FloatArray:
        """``(N,)`` scan ``ipc_timestamp``s as stored."""
        return np.array([s.timestamp for s in self.scans], dtype=np.float64)

    @property
    def time_status(self) -> str:
        t = self.timestamps
        if t.size == 0:
            return "empty"
        if not np.isfinite(t).all():
            return "non_monotonic"
        if (t == 0).all():
            return "all_zero"
        d = np.diff(t)
        if (d > 0).all():
            return "ok"
        if (d >= 0).all():
            return "coarse"
        return "non_monotonic"

    def laser_poses(self) -> FloatArray:
        """``(N, 3)`` laser poses ``[x, y, θ]`` (NaN rows for scans without one)."""
        nan = np.full(3, np.nan)
        return np.array(
            [nan if s.laser_pose is None else s.laser_pose for s in self.scans]
        ).reshape(-1, 3)

    def odometry_poses(self) -> FloatArray:
        """``(N, 3)`` odometry poses ``[x, y, θ]`` of the scans (NaN rows without one)."""
        nan = np.full(3, np.nan)
        return np.array(
            [nan if s.odometry_pose is None else s.odometry_pose for s in self.scans]
        ).reshape(-1, 3)

    def motion_prior(self, i: int, j: int, T_robot_laser: SE2 | None = None) -> SE2:
        """Wheel-odometry motion from scan ``i`` to scan ``j``: ``T_i_j`` (SE2).

        The pose of scan ``j`` in the frame of scan ``i`` as the odometry has it,
        ``inv(O_i) @ O_j`` — the ``init`` for matching scan ``j`` (source) against scan ``i``
        (reference). With ``T_robot_laser`` (the laser mounting) it is expressed between the
        laser frames: ``inv(L) @ inv(O_i) @ O_j @ L``.
        """
        n = len(self.scans)
        for name, k in (("i", i), ("j", j)):
            if not isinstance(k, (int, np.integer)) or not -n <= k < n:
                raise IndexError(f"{name}: scan index {k!r} out of range for {n} scans")
        oi, oj = self.scans[i].odometry_se2, self.scans[j].odometry_se2
        for k, o in ((i, oi), (j, oj)):
            if o is None:
                raise ValueError(f"scan {k}: a {self.scans[k].kind} has no odometry pose")
        assert oi is not None and oj is not None
        rel = oi.inverse() @ oj
        if T_robot_laser is not None:
            rel = T_robot_laser.inverse() @ rel @ T_robot_laser
        return rel


def flaser_angles(n: int) -> FloatArray:
    """Beam angles of an ``n``-beam FLASER/RLASER scan (180° from −90°; see the module doc)."""
    if n < 1:
        raise ValueError(f"n: expected at least one beam, got {n}")
    step = math.pi / (n - 1) if n % 2 == 1 and n > 1 else math.pi / n
    angles: FloatArray = -math.pi / 2 + step * np.arange(n, dtype=np.float64)
    return angles


class _LineError(Exception):
    pass


def _floats(tokens: list[str], what: str) -> FloatArray:
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for tok in tokens:
            try:
                float(tok)
            except ValueError:
                raise _LineError(f"{what}: {tok!r} is not a number") from None
        raise _LineError(f"{what}: not numbers") from None


def _count(tok: str, what: str, limit: int) -> int:
    try:
        value = float(tok)
    except ValueError:
        raise _LineError(f"{what}: {tok!r} is not a count") from None
    if not math.isfinite(value) or value != int(value) or value < 0:
        raise _LineError(f"{what}: {tok!r} is not a non-negative integer")
    if value > limit:
        raise _LineError(f"{what}: {int(value)} but only {limit} values follow")
    return int(value)


def _need(parts: list[str], count: int, kind: str) -> None:
    if len(parts) < count:
        raise _LineError(f"{kind}: expected at least {count} fields, got {len(parts)} (truncated?)")


def _parse_ranges(parts: list[str], at: int, kind: str) -> tuple[FloatArray, int]:
    n = _count(parts[at], f"{kind} beam count", len(parts) - at - 1)
    ranges = _floats(parts[at + 1 : at + 1 + n], f"{kind} ranges")
    if (ranges < 0).any():
        raise _LineError(f"{kind} ranges: negative range {ranges.min()}")
    return ranges, at + 1 + n


def _timestamps(parts: list[str], at: int, kind: str) -> tuple[float, float]:
    # ipc_timestamp host logger_timestamp; some converters (laserazosSM3) write
    # ipc_timestamp logger_timestamp host instead, so the host is whichever is not a number.
    _need(parts, at + 3, kind)
    ipc = _floats([parts[at]], f"{kind} ipc_timestamp")[0]
    for tok in (parts[at + 2], parts[at + 1]):
        try:
            return float(ipc), float(tok)
        except ValueError:
            continue
    raise _LineError(f"{kind} logger_timestamp: {parts[at + 2]!r} is not a number")


def _parse_flaser(parts: list[str], line: int) -> LaserScan:
    kind = parts[0]
    _need(parts, 2, kind)
    ranges, at = _parse_ranges(parts, 1, kind)
    _need(parts, at + 9, kind)
    poses = _floats(parts[at : at + 6], f"{kind} poses")
    if not np.isfinite(poses).all():
        raise _LineError(f"{kind} poses: non-finite value")
    ts, lts = _timestamps(parts, at + 6, kind)
    return LaserScan(
        kind=kind,
        ranges=ranges,
        angles=flaser_angles(len(ranges)),
        max_range=FLASER_MAX_RANGE,
        laser_pose=poses[:3],
        odometry_pose=poses[3:],
        timestamp=ts,
        logger_timestamp=lts,
        line=line,
    )


def _parse_new_laser(parts: list[str], line: int, with_pose: bool) -> LaserScan:
    kind = parts[0]
    _need(parts, 9, kind)
    head = _floats(parts[1:7], f"{kind} header")
    if not np.isfinite(head).all():
        raise _LineError(f"{kind} header: non-finite value")
    start, fov, resolution, max_range = head[1], head[2], head[3], head[4]
    if not max_range > 0:
        raise _LineError(f"{kind} maximum_range: must be > 0, got {max_range}")
    ranges, at = _parse_ranges(parts, 8, kind)
    _need(parts, at + 1, kind)
    _, at = _parse_ranges(parts, at, f"{kind} remission")
    n = len(ranges)
    if n > 1 and resolution == 0:
        resolution = fov / (n - 1)
    angles = start + resolution * np.arange(n, dtype=np.float64)
    laser_pose: FloatArray | None = None
    robot_pose: FloatArray | None = None
    if with_pose:
        _need(parts, at + 11 + 3, kind)
        poses = _floats(parts[at : at + 6], f"{kind} poses")
        if not np.isfinite(poses).all():
            raise _LineError(f"{kind} poses: non-finite value")
        laser_pose, robot_pose = poses[:3], poses[3:]
        at += 11  # laser pose, robot pose, tv rv forward_safety side_safety turn_axis
    ts, lts = _timestamps(parts, at, kind)
    return LaserScan(
        kind=kind,
        ranges=ranges,
        angles=angles,
        max_range=float(max_range),
        laser_pose=laser_pose,
        odometry_pose=robot_pose,
        timestamp=ts,
        logger_timestamp=lts,
        line=line,
    )


def _parse_odom(parts: list[str]) -> tuple[FloatArray, float]:
    _need(parts, 10, "ODOM")
    values = _floats(parts[1:7], "ODOM values")
    if not np.isfinite(values[:3]).all():
        raise _LineError("ODOM pose: non-finite value")
    ts, _ = _timestamps(parts, 7, "ODOM")
    return values, ts


def _open_lines(path: Path) -> list[str]:
    try:
        if path.name.lower().endswith(".gz"):
            with gzip.open(path, "rt", encoding="utf-8", errors="strict") as fh:
                return fh.read().splitlines()
        if path.name.lower().endswith(".bz2"):
            with bz2.open(path, "rt", encoding="utf-8", errors="strict") as fh:
                return fh.read().splitlines()
        return path.read_text(encoding="utf-8", errors="strict").splitlines()
    # zlib.error: a corrupt deflate stream inside a valid gzip header (found by fuzz/).
    except (OSError, EOFError, UnicodeDecodeError, zlib.error) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise FileFormatError(path, f"cannot read as a CARMEN text log: {exc}") from None


def read_carmen(path: PathLike) -> CarmenLog:
    """Read a CARMEN log (plain, gzip or bzip2), see the module docstring for the messages.

    Raises
    ------
    FileFormatError
        (a ``ValueError``) naming the file and the 1-based line of a corrupt or truncated
        message, or when the file holds no laser scan and no odometry at all.
    """
    p = Path(path)
    lines = _open_lines(p)
    scans: list[LaserScan] = []
    odom_values: list[FloatArray] = []
    odom_times: list[float] = []
    odom_lines: list[int] = []
    skipped: dict[str, int] = {}
    for number, text in enumerate(lines, start=1):
        parts = text.split()
        if not parts or parts[0].startswith("#"):
            continue
        kind = parts[0]
        try:
            if kind in _LASER_KINDS:
                scans.append(_parse_flaser(parts, number))
            elif kind in _ROBOT_KINDS:
                scans.append(_parse_new_laser(parts, number, with_pose=True))
            elif kind in _RAW_KINDS:
                scans.append(_parse_new_laser(parts, number, with_pose=False))
            elif kind == "ODOM":
                values, ts = _parse_odom(parts)
                odom_values.append(values)
                odom_times.append(ts)
                odom_lines.append(number)
            elif _MESSAGE_NAME.fullmatch(kind):
                skipped[kind] = skipped.get(kind, 0) + 1
            else:
                raise _LineError(f"unknown message {kind[:40]!r}")
        except _LineError as exc:
            raise FileFormatError(p, f"line {number}: {exc}") from None
        except ValueError as exc:  # a field that failed LaserScan validation
            raise FileFormatError(p, f"line {number}: {exc}") from None
    if not scans and not odom_values:
        raise FileFormatError(p, "no laser scan and no ODOM message (not a CARMEN log?)")
    values = np.array(odom_values, dtype=np.float64).reshape(-1, 6)
    odometry = Odometry(
        poses=values[:, :3],
        velocities=values[:, 3:],
        timestamps=np.array(odom_times, dtype=np.float64),
        lines=np.array(odom_lines, dtype=np.int64),
    )
    return CarmenLog(path=p, scans=tuple(scans), odometry=odometry, skipped=skipped)


__all__ = [
    "FLASER_MAX_RANGE",
    "CarmenLog",
    "LaserScan",
    "Odometry",
    "flaser_angles",
    "read_carmen",
]
