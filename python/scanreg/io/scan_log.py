"""A run of 2D laser scans as the 2D pipelines read it, whatever file it came from.

:class:`ScanLog` is what a CARMEN log (:func:`scanreg.pipeline.scan_source.scan_log`) and a
ROS bag with ``sensor_msgs/LaserScan`` (:func:`scanreg.io.laserscan_bag.read_laserscan_bag`)
both become: per scan its ranges (laser frame), its own stamp, and the wheel odometry
``T_odom_base`` at that stamp; once per run the laser's mounting ``T_base_laser``. The
pipelines (:func:`~scanreg.pipeline.mapping.run_mapping`, ``scanreg odometry`` / ``localize``)
work in the base frame: :meth:`ScanLog.points` puts each scan's returns there, and
:meth:`ScanLog.prior` is the wheels' motion of the base, so both describe the same body and
the poses they return are ``T_world_base``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import FloatArray
from ..transform import SE2
from ._common import _readonly
from .carmen import LaserScan


@dataclass(frozen=True)
class OdometryStream:
    """Wheel-odometry messages as a bag recorded them, in the order it received them.

    Attributes
    ----------
    stamps : (K,) float64
        Each message's own stamp (s).
    poses : (K, 3) float64
        ``[x, y, θ]``: ``T_odom_base`` per message.
    received : (K,) float64
        When the bag received each message (s; the scans': their ``logger_timestamp``).
    """

    stamps: FloatArray
    poses: FloatArray
    received: FloatArray

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("stamps", "received"):
            set_(self, name, _readonly(np.array(getattr(self, name), dtype=np.float64).ravel()))
        poses = np.array(self.poses, dtype=np.float64)
        if poses.size == 0:
            poses = poses.reshape(0, 3)
        if poses.ndim != 2 or poses.shape[1] != 3:
            raise ValueError(f"poses: expected (K, 3) rows [x, y, θ], got shape {poses.shape}")
        set_(self, "poses", _readonly(poses))
        for name in ("stamps", "poses", "received"):
            if not np.isfinite(getattr(self, name)).all():
                raise ValueError(f"{name}: expected finite values, got NaN or inf")
        if not len(self.stamps) == len(self.poses) == len(self.received):
            raise ValueError(
                f"stamps, poses, received: expected the same length, got {len(self.stamps)}, "
                f"{len(self.poses)}, {len(self.received)}"
            )

    def __len__(self) -> int:
        return len(self.stamps)


@dataclass(frozen=True)
class ScanLog:
    """2D laser scans in the order they were taken, with their odometry and mounting.

    Attributes
    ----------
    path : Path
        The file (or bag folder) read.
    scans : tuple of LaserScan
        One laser stream, in recording order (CARMEN: file order; bag: receive order).
    stamps : (N,) float64
        Each scan's own time, seconds, as recorded (may step backwards in corrupted logs).
    odometry : tuple of SE2 or None
        ``T_odom_base``: the wheel odometry at each scan's stamp (None where there is none;
        a bag's as read: interpolated at the stamps, until the pipelines pair it with the
        scans as a log's: :func:`scanreg.pipeline.odometry_timing.settle_odometry`).
    T_base_laser : SE2
        The laser's mounting on the base (identity: the base is the laser).
    mirrored : bool
        The laser is mounted upside down: its beams sweep clockwise seen from above, so
        :meth:`points` mirrors them (y → −y) before the mounting.
    base_frame, laser_frame : str
        Frame names (bags: the tf frame ids; CARMEN: ``"robot"`` / ``"laser"``).
    odometry_source : str
        Where :attr:`odometry` came from (``"nav_msgs/Odometry /odom"``, ``"tf odom →
        base_link"``, ``"CARMEN FLASER odometry fields / ODOM"``, ``"none"``, …).
    odometry_stream : OdometryStream or None
        A bag's odometry messages as recorded, until the pipelines have paired them with the
        scans (then None; always None for a CARMEN log, whose lines pair them).
    laser_latency : float or None
        How long before its stamp each scan was taken, as applied to :attr:`odometry` (s;
        None: the odometry is each scan's own, or none was measured).
    """

    path: Path
    scans: tuple[LaserScan, ...]
    stamps: FloatArray
    odometry: tuple[SE2 | None, ...]
    T_base_laser: SE2
    mirrored: bool = False
    base_frame: str = "base"
    laser_frame: str = "laser"
    odometry_source: str = "none"
    odometry_stream: OdometryStream | None = None
    laser_latency: float | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "path", Path(self.path))
        set_(self, "scans", tuple(self.scans))
        set_(self, "odometry", tuple(self.odometry))
        stamps = np.array(self.stamps, dtype=np.float64).reshape(-1)
        if not (len(self.scans) == len(stamps) == len(self.odometry)):
            raise ValueError(
                f"scans, stamps, odometry: expected the same length, got {len(self.scans)}, "
                f"{len(stamps)}, {len(self.odometry)}"
            )
        if not np.isfinite(stamps).all():
            raise ValueError("stamps: contains NaN or inf")
        set_(self, "stamps", _readonly(stamps))
        if not isinstance(self.T_base_laser, SE2):
            raise TypeError(f"T_base_laser: expected SE2, got {type(self.T_base_laser).__name__}")
        for k, pose in enumerate(self.odometry):
            if pose is not None and not isinstance(pose, SE2):
                raise TypeError(f"odometry[{k}]: expected SE2 or None, got {type(pose).__name__}")
        stream = self.odometry_stream
        if stream is not None and not isinstance(stream, OdometryStream):
            raise TypeError(
                f"odometry_stream: expected OdometryStream or None, got {type(stream).__name__}"
            )

    def __len__(self) -> int:
        return len(self.scans)

    @property
    def has_odometry(self) -> bool:
        """Whether any scan has a wheel-odometry pose."""
        return any(p is not None for p in self.odometry)

    def points(self, k: int, min_range: float = 0.0, max_range: float | None = None) -> FloatArray:
        """Scan ``k``'s valid returns in ``(min_range, max_range)`` as ``(M, 2)`` points in the
        base frame (the scan's own ``range_min`` / ``range_max``, NaN and inf honoured:
        :meth:`LaserScan.valid`)."""
        pts = self.scans[self._index(k)].to_points(min_range, max_range)
        if self.mirrored:
            pts[:, 1] = -pts[:, 1]
        if self.T_base_laser.is_close(SE2.identity(), atol=0.0):
            return pts  # the base is the laser: the points as read, bit for bit
        return np.ascontiguousarray(self.T_base_laser.apply(pts))

    def _index(self, k: int) -> int:
        """``k`` checked as a scan index (negative from the end, as a sequence's)."""
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise TypeError(f"k: expected an int scan index, got {type(k).__name__}")
        if not -len(self) <= k < len(self):
            raise IndexError(f"k: scan {k} out of range for {len(self)} scans")
        return int(k) % len(self)

    def point_times(
        self, k: int, min_range: float = 0.0, max_range: float | None = None
    ) -> FloatArray | None:
        """When each of :meth:`points`' returns was measured, seconds after ``stamps[k]``: a
        ``sensor_msgs/LaserScan``'s ``k · time_increment`` (its stamp is its first beam's
        time); ``None`` for a scan that does not say (a CARMEN log's, ``time_increment`` 0)."""
        scan = self.scans[self._index(k)]
        increment = float(getattr(scan, "time_increment", 0.0))  # (a RosLaserScan field)
        if increment == 0.0 or not math.isfinite(increment):
            return None
        times = np.arange(len(scan), dtype=np.float64) * increment
        return np.ascontiguousarray(times[scan.valid(min_range, max_range)])

    def swept_points(
        self, k: int, min_range: float = 0.0, max_range: float | None = None
    ) -> tuple[FloatArray, FloatArray | None]:
        """Scan ``k``'s returns as :meth:`points` gives them, its sweep undone when the scan
        says when each beam was measured (:meth:`point_times`): ``(points, None)`` with every
        return moved into the base frame at ``stamps[k]`` by the wheels' motion from this
        scan to the next (the motion during its sweep, which starts at its stamp), spread
        evenly over the time between them (:func:`scanreg.deskew`); without that motion (no
        odometry at either scan, the last scan, stamps not increasing) ``(points, times)``,
        each return's time on the clock of ``stamps`` for the pipeline to deskew with its own
        prediction; ``(points, None)`` for a scan without beam times."""
        from ..deskew import deskew, velocity_from_motion

        k = self._index(k)
        pts = self.points(k, min_range, max_range)
        times = self.point_times(k, min_range, max_range)
        if times is None:
            return pts, None
        stamp = float(self.stamps[k])
        during = self.prior(k + 1) if k + 1 < len(self) else None
        if during is None or not float(self.stamps[k + 1]) > stamp:
            return pts, stamp + times
        velocity = velocity_from_motion(during, float(self.stamps[k + 1]) - stamp)
        return deskew(pts, times, velocity, reference_time=0.0), None

    def deskew_motion(
        self, k: int, min_range: float = 0.0, max_range: float | None = None
    ) -> tuple[FloatArray, SE2, SE2 | None] | None:
        """How :meth:`swept_points` undid scan ``k``'s sweep with the wheels: each return's
        time as a fraction of the interval to the next scan, the wheels' increment over that
        interval (the motion it was undone with, at a constant rate), and the previous
        interval's increment at its rate over this interval (None for the first scan or
        without it): what the robot did before, which the rate during the sweep may still
        be closer to (a corner's turn ending within the interval). What the deskew leaves in
        the scan follows from both (:mod:`scanreg.pipeline.sweep_residual`). None where the
        sweep was not undone so."""
        k = self._index(k)
        times = self.point_times(k, min_range, max_range)
        if times is None or k + 1 >= len(self):
            return None
        during = self.prior(k + 1)
        interval = float(self.stamps[k + 1]) - float(self.stamps[k])
        if during is None or not interval > 0:
            return None
        before = self.prior(k)
        if before is not None:
            gap = float(self.stamps[k]) - float(self.stamps[k - 1])
            before = SE2.exp(before.log() * (interval / gap)) if gap > 0 else None
        return times / interval, during, before

    def prior(self, k: int) -> SE2 | None:
        """The wheels' motion of the base from scan ``k − 1`` to scan ``k``,
        ``inv(O_{k-1}) O_k`` (None for the first scan or where either pose is missing)."""
        if k <= 0:
            return None
        before, here = self.odometry[k - 1], self.odometry[k]
        if before is None or here is None:
            return None
        rel = before.inverse() @ here
        assert isinstance(rel, SE2)
        return rel

    def head(self, count: int | None) -> ScanLog:
        """The first ``count`` scans (all when None)."""
        if count is None:
            return self
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise ValueError(f"max_scans: must be an integer >= 1, got {count!r}")
        return self.select(range(min(int(count), len(self))))

    def select(self, indices: Sequence[int]) -> ScanLog:
        """The scans at ``indices``, in that order (their odometry and stamps with them)."""
        idx = [int(i) for i in indices]
        return dataclasses.replace(
            self,
            scans=tuple(self.scans[i] for i in idx),
            stamps=self.stamps[idx],
            odometry=tuple(self.odometry[i] for i in idx),
        )

    def describe(self) -> dict[str, object]:
        """A JSON-ready summary: scans, frames, mounting, odometry source."""
        return {
            "scans": len(self),
            "base_frame": self.base_frame,
            "laser_frame": self.laser_frame,
            "laser_pose": [float(v) for v in self.T_base_laser.as_vector()],
            "laser_mirrored": self.mirrored,
            "odometry": self.odometry_source,
            "laser_latency": self.laser_latency,
            "scans_with_odometry": sum(p is not None for p in self.odometry),
        }


def laser_pose_argument(value: object) -> SE2 | None:
    """``--laser-pose x y θ`` / ``laser_pose=`` as ``T_base_laser`` (None stays None)."""
    if value is None or isinstance(value, SE2):
        return value
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ValueError(f"laser_pose: expected finite [x, y, θ], got {value!r}")
    return SE2.from_vector(arr)


__all__ = ["OdometryStream", "ScanLog", "laser_pose_argument"]
