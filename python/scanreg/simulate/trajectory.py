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

    @classmethod
    def from_twists(
        cls,
        start: SE2 | SE3,
        durations: Any,
        twists: Any,
        *,
        start_time: float = 0.0,
    ) -> Trajectory:
        """Pieces of constant body twist driven one after another from ``start``.

        ``durations`` ``(K,)`` seconds (> 0) and ``twists`` ``(K, 3)`` / ``(K, 6)`` (see the
        module docs); each knot pose is the previous one composed with
        ``exp(duration · twist)``, so the path is continuous in pose by construction.
        """
        if not isinstance(start, (SE2, SE3)):
            raise TypeError(f"start: expected SE2 or SE3, got {type(start).__name__}")
        dt = np.asarray(durations, dtype=np.float64).ravel()
        if dt.size == 0:
            raise ValueError("durations: need at least one piece")
        if not np.isfinite(dt).all() or (dt <= 0).any():
            raise ValueError("durations: must be finite and > 0")
        dof = 3 if isinstance(start, SE2) else 6
        xi = as_matrix(twists, "twists", (dt.size, dof))
        knots = finite(start_time, "start_time") + np.concatenate([[0.0], np.cumsum(dt)])
        poses: list[Any] = [start]
        for k in range(dt.size - 1):
            poses.append(poses[-1] @ type(start).exp(dt[k] * xi[k]))
        return cls(knots, tuple(poses), xi)

    def end_pose(self) -> SE2 | SE3:
        """The pose at :attr:`end_time` (the last piece driven to its end)."""
        return self.pose_at(self.end_time)

    def lifted(self, height: float = 0.0) -> Trajectory:
        """This 2D trajectory as a 3D one in the plane ``z = height`` (yaw only)."""
        if self.dim != 2:
            raise ValueError("lifted: the trajectory is already 3D")
        z = finite(height, "height")
        poses = tuple(
            SE3.from_vector([*p.translation, z, 0.0, 0.0, p.angle]) for p in self.knot_poses
        )
        twists = np.zeros((len(poses), 6))
        twists[:, 0:2] = self.twists[:, 0:2]
        twists[:, 5] = self.twists[:, 2]
        return Trajectory(self.knot_times, poses, twists)

    @classmethod
    def through_waypoints(
        cls,
        waypoints: Any,
        *,
        speed: float = 1.0,
        turn_radius: float = 0.5,
        turn_rate: float = 0.8,
        max_fillet_angle: float = 2.0 * math.pi / 3.0,
        final_heading: float | None = None,
        start_time: float = 0.0,
    ) -> Trajectory:
        """A 2D robot driving straight between ``waypoints`` ``(K, 2)`` at ``speed`` (m/s).

        At each interior waypoint the corner is cut by a circular arc of ``turn_radius``
        (m) tangent to both legs (shrunk to fit half of the shorter leg); a turn sharper
        than ``max_fillet_angle`` (rad; a U-turn back the way it came) is made on the spot at
        ``turn_rate`` (rad/s). The path is continuous in position and heading, every piece
        has a constant twist, and :meth:`pose_at` is exact. The robot starts at
        ``waypoints[0]`` facing the first leg and ends at ``waypoints[-1]``, turned on the
        spot to ``final_heading`` (rad) when given.
        """
        w = np.asarray(waypoints, dtype=np.float64)
        if w.ndim != 2 or w.shape[1] != 2 or w.shape[0] < 2:
            raise ValueError(f"waypoints: expected shape (K, 2) with K >= 2, got {w.shape}")
        if not np.isfinite(w).all():
            raise ValueError("waypoints: contains NaN or inf")
        v = positive(speed, "speed")
        radius = positive(turn_radius, "turn_radius")
        rate = positive(turn_rate, "turn_rate")
        fillet_max = positive(max_fillet_angle, "max_fillet_angle")
        legs = np.diff(w, axis=0)
        lengths = np.hypot(legs[:, 0], legs[:, 1])
        if (lengths <= 1e-9).any():
            bad = int(np.flatnonzero(lengths <= 1e-9)[0])
            raise ValueError(f"waypoints: points {bad} and {bad + 1} coincide")
        headings = np.arctan2(legs[:, 1], legs[:, 0])
        turns = np.angle(np.exp(1j * np.diff(headings)))  # wrapped to (-π, π]
        # Per interior waypoint: the arc radius (0 = turn on the spot) and its tangent length.
        radii = np.zeros(turns.size)
        cut = np.zeros(lengths.size + 1)  # tangent length at each waypoint
        for j, phi in enumerate(turns):
            if abs(phi) < 1e-12 or abs(phi) > fillet_max:
                continue
            room = 0.5 * min(lengths[j], lengths[j + 1])
            r = min(radius, room / math.tan(abs(phi) / 2))
            radii[j] = r
            cut[j + 1] = r * math.tan(abs(phi) / 2)
        durations: list[float] = []
        twists: list[list[float]] = []

        def spin(phi: float) -> None:
            if abs(phi) > 1e-12:
                durations.append(abs(phi) / rate)
                twists.append([0.0, 0.0, math.copysign(rate, phi)])

        for i, length in enumerate(lengths):
            straight = length - cut[i] - cut[i + 1]
            if straight > 1e-12:
                durations.append(straight / v)
                twists.append([v, 0.0, 0.0])
            if i < turns.size:
                phi = float(turns[i])
                if radii[i] > 0:
                    durations.append(radii[i] * abs(phi) / v)
                    twists.append([v, 0.0, math.copysign(v / radii[i], phi)])
                else:
                    spin(phi)
        if final_heading is not None:
            spin(
                float(
                    np.angle(np.exp(1j * (finite(final_heading, "final_heading") - headings[-1])))
                )
            )
        start = SE2.from_vector([w[0, 0], w[0, 1], headings[0]])
        return cls.from_twists(start, durations, twists, start_time=start_time)
