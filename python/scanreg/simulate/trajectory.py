"""Ground-truth trajectories: piecewise constant body twist, exact at every instant.

Segment ``k`` starts at ``knot_times[k]`` with pose ``T_k = knot_poses[k]``
(``T_world_sensor``) and body twist ``ξ_k`` (translation first, sensor frame:
``[vx, vy, ω]`` in 2D, ``[vx, vy, vz, ωx, ωy, ωz]`` in 3D); inside it
``T(t) = T_k @ exp((t − knot_times[k]) ξ_k)``. Before the first knot and after the last the
first/last segment is extrapolated. The ray caster evaluates the same formula for every
beam, so :meth:`Trajectory.pose_at` is the exact truth for each point's timestamp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray, as_matrix
from .._validate import frozen as _frozen
from ..transform import SE2, SE3
from ._checks import finite, non_negative, positive


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A piecewise constant-twist trajectory of ``SE2`` or ``SE3`` poses (see module docs)."""

    #: ``(K + 1,)`` strictly increasing segment boundaries (s).
    knot_times: FloatArray
    #: ``K`` poses ``T_world_sensor`` at the start of each segment.
    knot_poses: tuple[SE2, ...] | tuple[SE3, ...]
    #: ``(K, 3)`` (2D) or ``(K, 6)`` (3D) body twists.
    twists: FloatArray

    def __post_init__(self) -> None:
        if not self.knot_poses:
            raise ValueError("knot_poses: need at least one segment")
        kind = type(self.knot_poses[0])
        if kind not in (SE2, SE3) or any(type(p) is not kind for p in self.knot_poses):
            raise TypeError("knot_poses: expected all SE2 or all SE3")
        k = len(self.knot_poses)
        times = as_matrix(self.knot_times, "knot_times", (k + 1,))
        if (np.diff(times) <= 0).any():
            raise ValueError("knot_times: must be strictly increasing")
        dof = 3 if kind is SE2 else 6
        twists = as_matrix(self.twists, "twists", (k, dof))
        object.__setattr__(self, "knot_times", _frozen(times))
        object.__setattr__(self, "twists", _frozen(twists))

    @property
    def dim(self) -> int:
        return 2 if isinstance(self.knot_poses[0], SE2) else 3

    @property
    def start_time(self) -> float:
        return float(self.knot_times[0])

    @property
    def end_time(self) -> float:
        return float(self.knot_times[-1])

    def _segment(self, t: float) -> int:
        k = int(np.searchsorted(self.knot_times[1:-1], t, side="right"))
        return k

    def pose_at(self, time: float) -> SE2 | SE3:
        """``T_world_sensor`` at ``time`` (s)."""
        t = finite(time, "time")
        k = self._segment(t)
        step = (t - float(self.knot_times[k])) * self.twists[k]
        start = self.knot_poses[k]
        if isinstance(start, SE2):
            return start @ SE2.exp(step)
        return start @ SE3.exp(step)

    def poses_at(self, times: Any) -> tuple[SE2, ...] | tuple[SE3, ...]:
        """``pose_at`` for each of ``times``."""
        ts = np.asarray(times, dtype=np.float64).ravel()
        return tuple(self.pose_at(float(t)) for t in ts)  # type: ignore[return-value]

    def twist_at(self, time: float) -> FloatArray:
        """Body twist in effect at ``time``."""
        out: FloatArray = self.twists[self._segment(finite(time, "time"))].copy()
        return out

    def as_3d_segments(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(knot_times, poses (K, 16), twists (K, 6))`` for the ray caster (2D lifted to 3D)."""
        k = len(self.knot_poses)
        poses = np.zeros((k, 16))
        twists = np.zeros((k, 6))
        for i, p in enumerate(self.knot_poses):
            if isinstance(p, SE2):
                m = np.eye(4)
                m[:2, :2] = p.rotation
                m[:2, 3] = p.translation
                poses[i] = m.ravel()
            else:
                poses[i] = p.as_matrix().ravel()
        if self.dim == 2:
            twists[:, 0:2] = self.twists[:, 0:2]
            twists[:, 5] = self.twists[:, 2]
        else:
            twists[:] = self.twists
        return np.ascontiguousarray(self.knot_times), poses, twists

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def stationary(
        cls, pose: SE2 | SE3, *, start_time: float = 0.0, duration: float = 1.0
    ) -> Trajectory:
        """A sensor that does not move."""
        dof = 3 if isinstance(pose, SE2) else 6
        t0 = finite(start_time, "start_time")
        return cls(np.array([t0, t0 + positive(duration, "duration")]), (pose,), np.zeros((1, dof)))  # type: ignore[arg-type]

    @classmethod
    def constant_velocity(
        cls,
        start: SE2 | SE3,
        velocity: Any,
        angular_velocity: Any,
        *,
        duration: float,
        start_time: float = 0.0,
    ) -> Trajectory:
        """Constant body twist: ``velocity`` (m/s, sensor frame, 2 or 3 values) and
        ``angular_velocity`` (rad/s: a number in 2D, 3 values in 3D)."""
        if not isinstance(start, (SE2, SE3)):
            raise TypeError(f"start: expected SE2 or SE3, got {type(start).__name__}")
        t0 = finite(start_time, "start_time")
        t1 = t0 + positive(duration, "duration")
        if isinstance(start, SE2):
            v = as_matrix(velocity, "velocity", (2,))
            w = as_matrix(
                np.atleast_1d(np.asarray(angular_velocity, dtype=float)), "angular_velocity", (1,)
            )
            twist = np.concatenate([v, w])[None, :]
            return cls(np.array([t0, t1]), (start,), twist)
        v = as_matrix(velocity, "velocity", (3,))
        w = as_matrix(angular_velocity, "angular_velocity", (3,))
        return cls(np.array([t0, t1]), (start,), np.concatenate([v, w])[None, :])

    @classmethod
    def from_speed_and_yaw_rate(
        cls,
        speed: float,
        yaw_rate: float,
        *,
        duration: float,
        dim: int = 2,
        start: SE2 | SE3 | None = None,
        yaw_rate_amplitude: float = 0.0,
        yaw_rate_period: float = 10.0,
        step: float = 0.05,
        start_time: float = 0.0,
    ) -> Trajectory:
        """A vehicle driving forward (+x) at ``speed`` (m/s) while turning at
        ``yaw_rate + yaw_rate_amplitude · sin(2π t / yaw_rate_period)`` (rad/s).

        The yaw rate is held constant over ``step`` seconds (evaluated at each step's
        midpoint), so the path is a chain of circular arcs — smooth in position and heading.
        With ``yaw_rate_amplitude = 0`` it is a single exact arc (or line).
        """
        v = finite(speed, "speed")
        w0 = finite(yaw_rate, "yaw_rate")
        amp = non_negative(yaw_rate_amplitude, "yaw_rate_amplitude")
        period = positive(yaw_rate_period, "yaw_rate_period")
        total = positive(duration, "duration")
        t0 = finite(start_time, "start_time")
        if dim not in (2, 3):
            raise ValueError(f"dim: must be 2 or 3, got {dim}")
        if start is None:
            start = SE2.identity() if dim == 2 else SE3.identity()
        if not isinstance(start, SE2 if dim == 2 else SE3):
            raise TypeError(f"start: expected {'SE2' if dim == 2 else 'SE3'} for dim={dim}")
        # A constant yaw rate is one exact arc; a varying one is held over `step` seconds.
        n = 1 if amp == 0.0 else max(1, math.ceil(total / positive(step, "step")))
        knots = t0 + np.linspace(0.0, total, n + 1)
        mid = 0.5 * (knots[:-1] + knots[1:]) - t0
        rates = w0 + amp * np.sin(2 * math.pi * mid / period)
        dof = 3 if dim == 2 else 6
        twists = np.zeros((n, dof))
        twists[:, 0] = v
        twists[:, dof - 1] = rates
        poses: list[Any] = [start]
        for k in range(n - 1):
            dt = knots[k + 1] - knots[k]
            poses.append(poses[-1] @ type(start).exp(dt * twists[k]))
        return cls(knots, tuple(poses), twists)
