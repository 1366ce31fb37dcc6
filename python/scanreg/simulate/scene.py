"""Scenes: a table of primitives (planes, boxes, vertical cylinders, spheres, walls), some
of them moving, plus generators for floor plans, corridors, streets and tunnels.

Every primitive is a closed surface; a sensor inside a box sees its inner faces (a room or a
tunnel). A 2D scene is a 3D scene of vertical walls, boxes and cylinders spanning
``z ∈ [-1, 1]``, scanned by a laser in the plane ``z = 0``.

Moving primitives (people, cars) walk back and forth along a straight path in the xy plane at
constant speed; within one scan they move at their velocity at the scan start (the turnaround
instant inside a scan is not modelled).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _core
from .._validate import FloatArray
from .._validate import frozen as _frozen
from ._checks import finite, non_negative, positive
from ._checks import seed as check_seed

COLUMNS: int = _core.SIMULATE_PRIMITIVE_COLUMNS
PLANE, BOX, CYLINDER, SPHERE, WALL = 0.0, 1.0, 2.0, 3.0, 4.0
#: Vertical extent of 2D primitives.
FLAT_Z = 1.0


@dataclass(frozen=True, eq=False)
class Scene:
    """A scene of primitives; build with :class:`SceneBuilder` or a generator."""

    #: 2 (floor plan for a planar laser) or 3.
    dim: int
    #: ``(N, COLUMNS)`` rows ``[kind, p0..p6, 0, 0, 0]``, moving ones at their path start.
    primitives: FloatArray
    #: A label per primitive ("wall", "person", "ground", "facade", "pole", "car", ...).
    labels: tuple[str, ...]
    #: ``(N, 2)`` xy displacement from the path start to its other end (0 for static).
    paths: FloatArray
    #: ``(N,)`` walking speed along the path (m/s); 0 for static primitives.
    speeds: FloatArray
    #: ``(N,)`` distance already walked at t = 0 (m).
    phases: FloatArray

    @property
    def num_primitives(self) -> int:
        return int(self.primitives.shape[0])

    @property
    def dynamic(self) -> Any:
        """``(N,)`` bool: which primitives move."""
        return self.speeds > 0

    def primitives_at(self, time: float) -> FloatArray:
        """The primitive table at ``time``: moving centres placed, velocities filled in."""
        t = finite(time, "time")
        table = np.array(self.primitives)
        moving = np.flatnonzero(self.speeds > 0)
        if moving.size:
            length = np.hypot(self.paths[moving, 0], self.paths[moving, 1])
            unit = self.paths[moving] / length[:, None]
            s = np.mod(self.phases[moving] + self.speeds[moving] * t, 2 * length)
            forward = s < length
            along = np.where(forward, s, 2 * length - s)
            table[moving, 1:3] += unit * along[:, None]
            sign = np.where(forward, 1.0, -1.0)
            table[moving, 8:10] = unit * (sign * self.speeds[moving])[:, None]
        return table

    def merged(self, other: Scene) -> Scene:
        """Both scenes' primitives in one scene (same ``dim``)."""
        if other.dim != self.dim:
            raise ValueError(f"other: dim {other.dim} does not match {self.dim}")
        return Scene(
            self.dim,
            _frozen(np.vstack([self.primitives, other.primitives])),
            self.labels + other.labels,
            _frozen(np.vstack([self.paths, other.paths])),
            _frozen(np.concatenate([self.speeds, other.speeds])),
            _frozen(np.concatenate([self.phases, other.phases])),
        )


class SceneBuilder:
    """Collects primitives; ``build()`` freezes them into a :class:`Scene`.

    Coordinates in metres, world frame, z up; ``yaw`` in radians.
    """

    def __init__(self, dim: int) -> None:
        if dim not in (2, 3):
            raise ValueError(f"dim: must be 2 or 3, got {dim}")
        self.dim = dim
        self._rows: list[FloatArray] = []
        self._labels: list[str] = []
        self._paths: list[tuple[float, float]] = []
        self._speeds: list[float] = []
        self._phases: list[float] = []

    def _add(self, kind: float, params: list[float], label: str) -> SceneBuilder:
        row = np.zeros(COLUMNS)
        row[0] = kind
        row[1 : 1 + len(params)] = params
        self._rows.append(row)
        self._labels.append(label)
        self._paths.append((0.0, 0.0))
        self._speeds.append(0.0)
        self._phases.append(0.0)
        return self

    def _z(self, z0: float, z1: float) -> tuple[float, float]:
        return (-FLAT_Z, FLAT_Z) if self.dim == 2 else (z0, z1)

    def plane(self, normal: Any, offset: float, label: str = "plane") -> SceneBuilder:
        """Infinite plane ``normal · x = offset``."""
        n = np.asarray(normal, dtype=float)
        if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) == 0:
            raise ValueError(f"normal: expected a finite non-zero 3-vector, got {normal}")
        return self._add(PLANE, [*n.tolist(), finite(offset, "offset")], label)

    def ground(self, height: float = 0.0) -> SceneBuilder:
        return self.plane([0.0, 0.0, 1.0], height, "ground")

    def box(
        self,
        centre: Any,
        size: Any,
        yaw: float = 0.0,
        label: str = "box",
    ) -> SceneBuilder:
        """Box with ``centre`` (2 or 3 values) and full ``size`` (2 or 3 values)."""
        c = np.zeros(3)
        s = np.full(3, 2 * FLAT_Z)
        cc, ss = np.asarray(centre, dtype=float), np.asarray(size, dtype=float)
        c[: cc.size], s[: ss.size] = cc, ss
        if self.dim == 2:
            c[2], s[2] = 0.0, 2 * FLAT_Z
        if not (np.isfinite(c).all() and np.isfinite(s).all() and (s > 0).all()):
            raise ValueError(f"size: expected finite positive extents, got {size} at {centre}")
        return self._add(BOX, [*c.tolist(), *(s / 2).tolist(), finite(yaw, "yaw")], label)

    def cylinder(
        self,
        x: float,
        y: float,
        radius: float,
        z0: float = 0.0,
        z1: float = 1.0,
        label: str = "pole",
    ) -> SceneBuilder:
        """Vertical capped cylinder (a circle in 2D)."""
        lo, hi = self._z(finite(z0, "z0"), finite(z1, "z1"))
        if hi <= lo:
            raise ValueError(f"z1: must exceed z0 ({z0}), got {z1}")
        return self._add(
            CYLINDER, [finite(x, "x"), finite(y, "y"), lo, hi, positive(radius, "radius")], label
        )

    def circle(self, x: float, y: float, radius: float, label: str = "clutter") -> SceneBuilder:
        return self.cylinder(x, y, radius, label=label)

    def sphere(self, centre: Any, radius: float, label: str = "sphere") -> SceneBuilder:
        c = np.asarray(centre, dtype=float)
        if c.shape != (3,) or not np.isfinite(c).all():
            raise ValueError(f"centre: expected a finite 3-vector, got {centre}")
        return self._add(SPHERE, [*c.tolist(), positive(radius, "radius")], label)

    def wall(
        self, start: Any, end: Any, z0: float = 0.0, z1: float = 3.0, label: str = "wall"
    ) -> SceneBuilder:
        """Zero-thickness vertical wall over the segment ``start → end`` (xy)."""
        a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
        if (
            a.shape != (2,)
            or b.shape != (2,)
            or not (np.isfinite(a).all() and np.isfinite(b).all())
        ):
            raise ValueError("start, end: expected finite 2-vectors")
        if np.hypot(*(b - a)) == 0:
            raise ValueError("end: wall has zero length")
        lo, hi = self._z(finite(z0, "z0"), finite(z1, "z1"))
        if hi <= lo:
            raise ValueError(f"z1: must exceed z0 ({z0}), got {z1}")
        return self._add(WALL, [*a.tolist(), *b.tolist(), lo, hi], label)

    def polyline(self, points: Any, *, closed: bool = False, **kwargs: Any) -> SceneBuilder:
        p = np.asarray(points, dtype=float)
        pairs = list(itertools.pairwise(p)) + ([(p[-1], p[0])] if closed else [])
        for a, b in pairs:
            self.wall(a, b, **kwargs)
        return self

    def moving(self, path: Any, speed: float, phase: float = 0.0) -> SceneBuilder:
        """Make the last added primitive walk back and forth along ``path`` (xy offset to
        the far end, m) at ``speed`` (m/s), ``phase`` metres into the walk at t = 0."""
        if not self._rows:
            raise ValueError("moving: add a primitive first")
        if self._rows[-1][0] in (PLANE, WALL):
            raise ValueError("moving: only boxes, cylinders and spheres can move")
        d = np.asarray(path, dtype=float)
        if d.shape != (2,) or not np.isfinite(d).all() or np.hypot(*d) == 0:
            raise ValueError(f"path: expected a finite non-zero xy offset, got {path}")
        self._paths[-1] = (float(d[0]), float(d[1]))
        self._speeds[-1] = positive(speed, "speed")
        self._phases[-1] = non_negative(phase, "phase")
        return self

    def person(
        self, x: float, y: float, path: Any, speed: float = 1.2, phase: float = 0.0
    ) -> SceneBuilder:
        """A walking person: a cylinder of radius 0.25 m, 1.8 m tall."""
        self.cylinder(x, y, 0.25, 0.0, 1.8, label="person")
        return self.moving(path, speed, phase)

    def build(self) -> Scene:
        rows = np.array(self._rows, dtype=np.float64).reshape(-1, COLUMNS)
        return Scene(
            self.dim,
            _frozen(rows),
            tuple(self._labels),
            _frozen(np.array(self._paths, dtype=np.float64).reshape(-1, 2)),
            _frozen(self._speeds),
            _frozen(self._phases),
        )


# --- 2D generators --------------------------------------------------------------------------
def square_room(half_width: float = 5.0) -> Scene:
    """A closed square room ``[-h, h]²`` (2D), for analytic checks."""
    h = positive(half_width, "half_width")
    return SceneBuilder(2).polyline([(-h, -h), (h, -h), (h, h), (-h, h)], closed=True).build()


def corridor(
    length: float = 60.0, width: float = 2.0, *, closed_ends: bool = True, dim: int = 2
) -> Scene:
    """A long featureless corridor along +x from ``x = 0`` to ``length``, centred on ``y = 0``:
    the classic degenerate case (no constraint along x once the ends are out of range)."""
    ln, w = positive(length, "length"), positive(width, "width") / 2
    b = SceneBuilder(dim)
    if dim == 3:
        b.ground(0.0)
        b.plane([0.0, 0.0, 1.0], 3.0, label="ceiling")
    b.wall((0.0, -w), (ln, -w)).wall((0.0, w), (ln, w))
    if closed_ends:
        b.wall((0.0, -w), (0.0, w)).wall((ln, -w), (ln, w))
    return b.build()


def floor_plan(
    seed: int = 0,
    *,
    rooms_per_side: int = 4,
    room_width: float = 6.0,
    room_depth: float = 5.0,
    corridor_width: float = 2.4,
    clutter_per_room: int = 4,
    num_people: int = 3,
) -> Scene:
    """An office floor (2D): a corridor along +x from ``x = 0`` with ``rooms_per_side`` rooms
    on each side, each opening onto it through a 1 m door at a random position; random
    furniture (boxes, round tables) in the rooms; people walking in the corridor.

    The corridor centreline is ``y = 0``; the floor spans ``x ∈ [0, rooms_per_side·room_width]``.
    """
    rng = np.random.default_rng(check_seed(seed))
    n = int(rooms_per_side)
    if n < 1:
        raise ValueError(f"rooms_per_side: must be >= 1, got {rooms_per_side}")
    rw, rd = positive(room_width, "room_width"), positive(room_depth, "room_depth")
    cw = positive(corridor_width, "corridor_width") / 2
    door = 1.0
    if rw < door + 1.0:
        raise ValueError(f"room_width: must be >= {door + 1.0} to fit a door, got {room_width}")
    length = n * rw
    b = SceneBuilder(2)
    for side in (1.0, -1.0):
        inner, outer = side * cw, side * (cw + rd)
        b.wall((0.0, outer), (length, outer))
        for i in range(n + 1):
            b.wall((i * rw, inner), (i * rw, outer))
        for i in range(n):
            x0 = i * rw
            d0 = x0 + 0.5 + rng.uniform(0.0, rw - door - 1.0)
            b.wall((x0, inner), (d0, inner), label="wall")
            b.wall((d0 + door, inner), ((i + 1) * rw, inner), label="wall")
            for _ in range(int(clutter_per_room)):
                cx = rng.uniform(x0 + 0.8, x0 + rw - 0.8)
                cy = side * rng.uniform(cw + 1.2, cw + rd - 0.6)
                if rng.uniform() < 0.5:
                    size = rng.uniform(0.4, 1.2, 2)
                    b.box((cx, cy), size, yaw=rng.uniform(0, math.pi), label="furniture")
                else:
                    b.circle(cx, cy, rng.uniform(0.15, 0.4), label="furniture")
    b.wall((0.0, -cw - rd), (0.0, cw + rd))
    b.wall((length, -cw - rd), (length, cw + rd))
    for _ in range(int(num_people)):
        y = rng.uniform(-cw + 0.4, cw - 0.4)
        b.person(
            0.5, y, (length - 1.0, 0.0), speed=rng.uniform(0.8, 1.5), phase=rng.uniform(0, length)
        )
    return b.build()


# --- 3D generators --------------------------------------------------------------------------
def street(
    seed: int = 0,
    *,
    length: float = 200.0,
    road_half_width: float = 7.0,
    num_pedestrians: int = 4,
    num_moving_cars: int = 1,
) -> Scene:
    """An urban street along +x, centred on ``y = 0``, ``x ∈ [-length/2, length/2]``: ground
    plane ``z = 0``, building façades (boxes) with gaps on both sides, poles, parked cars,
    vegetation (clusters of small spheres), walking pedestrians and moving cars."""
    rng = np.random.default_rng(check_seed(seed))
    half = positive(length, "length") / 2
    road = positive(road_half_width, "road_half_width")
    b = SceneBuilder(3).ground(0.0)
    for side in (1.0, -1.0):
        x = -half
        while x < half:
            w = rng.uniform(8.0, 25.0)
            depth = rng.uniform(8.0, 15.0)
            h = rng.uniform(6.0, 20.0)
            setback = road + rng.uniform(3.0, 6.0)
            b.box((x + w / 2, side * (setback + depth / 2), h / 2), (w, depth, h), label="facade")
            x += w + rng.uniform(0.0, 6.0)
        x = -half + rng.uniform(0, 10)
        while x < half:
            b.cylinder(x, side * (road + 1.0), rng.uniform(0.08, 0.18), 0.0, rng.uniform(4.0, 8.0))
            x += rng.uniform(12.0, 25.0)
        x = -half + rng.uniform(0, 8)
        while x < half:
            if rng.uniform() < 0.6:
                b.box(
                    (x, side * (road - 1.2), 0.75),
                    (rng.uniform(3.8, 4.8), 1.8, rng.uniform(1.4, 1.6)),
                    yaw=rng.normal(0.0, 0.03),
                    label="car",
                )
            x += rng.uniform(5.5, 7.0)
        for _ in range(int(length / 15)):
            cx, cy = rng.uniform(-half, half), side * (road + rng.uniform(1.8, 3.0))
            for _ in range(rng.integers(4, 10)):
                r = rng.uniform(0.2, 0.6)
                c = (cx + rng.normal(0, 0.7), cy + rng.normal(0, 0.4), rng.uniform(0.3, 2.5))
                b.sphere(c, r, label="vegetation")
    for _ in range(int(num_pedestrians)):
        side = rng.choice([-1.0, 1.0])
        b.person(
            rng.uniform(-half, half - 20),
            side * (road + 2.4),
            (20.0, 0.0),
            speed=rng.uniform(0.8, 1.5),
            phase=rng.uniform(0, 20),
        )
    for _ in range(int(num_moving_cars)):
        b.box((-half + 10, -1.75, 0.75), (4.5, 1.8, 1.5), label="car")
        b.moving((2 * half - 20, 0.0), speed=rng.uniform(6.0, 12.0), phase=rng.uniform(0, half))
    return b.build()


def tunnel(length: float = 400.0, width: float = 10.0, height: float = 6.0) -> Scene:
    """A straight tunnel along +x centred on the origin: ground ``z = 0`` and the inside of a
    box (walls at ``y = ±width/2``, ceiling at ``height``). Featureless along x: only the
    far ends (at ``±length/2``, keep them beyond max range) constrain it."""
    ln, w, h = positive(length, "length"), positive(width, "width"), positive(height, "height")
    b = SceneBuilder(3).ground(0.0)
    # The box floor is 1 m below the ground, hidden by it.
    b.box((0.0, 0.0, (h - 1.0) / 2), (ln, w, h + 1.0), label="tunnel")
    return b.build()
