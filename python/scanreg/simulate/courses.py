"""Courses: a scene and a trajectory through it that comes back to places already seen,
with exact truth — the test instrument for loop closure and place recognition.

* :func:`block_loop` (3D): a car drives laps around a city block on a ring road lined with
  buildings, poles, parked cars and trees; each lap ends exactly where it started.
  ``symmetry=2`` or ``4`` makes the block's sides identical copies (a scene with repeated
  structure: half a lap, or a quarter, away the view is the same, but the place is not).
* :func:`room_tour` (2D): a robot walks down an office corridor, enters rooms, turns round at
  the far end and walks back through the same rooms to its start.
  ``identical_rooms=True`` makes every room the same (door, furniture) up to a rigid motion.
* :func:`ring_corridor` (2D): a robot drives once round a ring of bare office corridors and on
  past its start: one large loop, closed only after the whole lap's drift.

Each returns a :class:`Course`; scan it with :func:`~scanreg.simulate.simulate_run`::

    from scanreg import simulate as sim
    course = sim.block_loop(seed=0, lap_length=300.0, laps=2)        # 600 m, 60 s at 10 m/s
    run = sim.simulate_run(course.scene, sim.LidarModel.preset("vlp16"), course.trajectory,
                           num_scans=course.num_scans(10.0))
    run.poses                                   # exact T_world_sensor of every sweep
    course.revisits(run.start_times, radius=3.0, min_time_gap=20.0)  # true loop pairs

Everything is reproducible from ``seed``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..transform import SE2, SE3
from ._checks import count, non_negative, positive
from ._checks import seed as check_seed
from .scene import Scene, SceneBuilder
from .trajectory import Trajectory


@dataclass(frozen=True, eq=False)
class Course:
    """A scene, a trajectory through it and where the trajectory comes back."""

    scene: Scene
    #: ``T_world_sensor`` at every instant (2D for a 2D scene, 3D at sensor height otherwise).
    trajectory: Trajectory
    #: Path length driven (m).
    length: float
    #: ``(P,)`` start time of each pass (s): each lap of a loop; the outbound and the return
    #: leg of a tour. A place seen in pass ``i`` is seen again in pass ``i + 1``.
    pass_start_times: FloatArray
    #: Frames of the identical parts of a scene with repeated structure (empty otherwise):
    #: what is seen from ``F_i @ X`` is also seen from ``F_j @ X`` (static objects; noise and
    #: what lies beyond the repeated parts aside). ``SE2`` for 2D, ``SE3`` for 3D.
    repeated_frames: tuple[SE2, ...] | tuple[SE3, ...]

    @property
    def duration(self) -> float:
        return self.trajectory.end_time - self.trajectory.start_time

    def num_scans(self, scan_rate: float = 10.0) -> int:
        """How many scans ``1 / scan_rate`` apart fit in the course (for ``simulate_run``)."""
        return math.floor(self.duration * positive(scan_rate, "scan_rate") + 1e-9)

    def revisits(
        self, times: Any, *, radius: float = 3.0, min_time_gap: float = 20.0
    ) -> list[tuple[int, int]]:
        """True loop pairs among scans taken at ``times`` (s): ``(i, j)`` with ``i < j``, the
        sensor positions within ``radius`` (m) and ``times[j] - times[i] >= min_time_gap`` (s,
        so that consecutive scans are not counted). Positions from the exact trajectory."""
        t = np.asarray(times, dtype=np.float64).ravel()
        r = positive(radius, "radius")
        gap = non_negative(min_time_gap, "min_time_gap")
        xy = np.array([p.translation[:2] for p in self.trajectory.poses_at(t)])
        out: list[tuple[int, int]] = []
        for j in range(t.size):
            earlier = np.flatnonzero(t[:j] <= t[j] - gap)
            if earlier.size:
                close = earlier[np.hypot(*(xy[earlier] - xy[j]).T) <= r]
                out.extend((int(i), j) for i in close)
        return out


# --------------------------------------------------------------------------- 3D block loop


def _corner(speed: float, radius: float, transition: float) -> tuple[list[float], list[float]]:
    """A 90° left turn as constant-twist pieces: the yaw rate ramps linearly (a clothoid in
    ``ramp_steps`` steps, midpoint values) up to ``speed / r`` over ``transition`` seconds,
    holds, and ramps down, so the yaw rate has no jump larger than one step. The arc radius
    ``r`` is set so that the corner's tangent length is about ``radius``."""
    ramp_steps = 8
    arc = radius - 0.5 * speed * transition  # a clothoid pair shifts the tangent by ~vτ/2
    if arc <= 0:
        raise ValueError(
            f"transition: {transition} s at {speed} m/s is too long for a {radius} m corner"
        )
    w = speed / arc
    hold = 0.5 * math.pi / w - transition
    if hold <= 0:
        raise ValueError(f"transition: {transition} s is longer than the corner itself")
    durations: list[float] = []
    rates: list[float] = []
    if transition > 0:
        ramp = (np.arange(ramp_steps) + 0.5) / ramp_steps * w
        durations += [transition / ramp_steps] * ramp_steps
        rates += ramp.tolist()
    durations.append(hold)
    rates.append(w)
    if transition > 0:
        durations += [transition / ramp_steps] * ramp_steps
        rates += ramp[::-1].tolist()
    return durations, rates


def _block_side(
    rng: np.random.Generator, length: float, reach: float, road: float, inner_depth: float
) -> list[tuple[str, tuple[Any, ...]]]:
    """Roadside objects of one straight of the ring road, in its local frame: ``u`` along the
    direction of travel from the straight's midpoint, ``v`` to the left (into the block), the
    road centreline at ``v = 0``, the ground at ``z = 0``. Items are ``(kind, params)``."""
    items: list[tuple[str, tuple[Any, ...]]] = []
    half = length / 2
    # Façades: inside the block only along the straight; outside also past the corners.
    for side, (u0, u1), depth_max in (
        (1.0, (-half, half), inner_depth),
        (-1.0, (-reach, reach), 15.0),
    ):
        u = u0 + rng.uniform(0.0, 3.0)
        while u1 - u > 4.0:
            w = min(rng.uniform(8.0, 25.0), u1 - u)
            depth = min(rng.uniform(8.0, 15.0), depth_max)
            h = rng.uniform(6.0, 20.0)
            setback = road + rng.uniform(3.0, 6.0)
            centre = (u + w / 2, side * (setback + depth / 2), h / 2)
            items.append(("box", (centre, (w, depth, h), 0.0, "facade")))
            u += w + rng.uniform(0.0, 6.0)
    for side in (1.0, -1.0):
        u = -half + rng.uniform(0.0, 10.0)
        while u < half:
            items.append(
                ("pole", (u, side * (road + 1.0), rng.uniform(0.08, 0.18), rng.uniform(4.0, 8.0)))
            )
            u += rng.uniform(12.0, 25.0)
        u = -half + 4.0 + rng.uniform(0.0, 8.0)
        while u < half - 4.0:
            if rng.uniform() < 0.6:
                size = (rng.uniform(3.8, 4.8), 1.8, rng.uniform(1.4, 1.6))
                centre = (u, side * (road - 1.2), 0.75)
                items.append(("box", (centre, size, rng.normal(0.0, 0.03), "car")))
            u += rng.uniform(5.5, 7.0)
        for _ in range(max(1, int(length / 15))):
            cu, cv = rng.uniform(-half, half), side * (road + rng.uniform(1.8, 3.0))
            for _ in range(int(rng.integers(4, 10))):
                r = rng.uniform(0.2, 0.6)
                c = (cu + rng.normal(0, 0.7), cv + rng.normal(0, 0.4), rng.uniform(0.3, 2.5))
                items.append(("sphere", (c, r)))
    return items


def _place(b: SceneBuilder, items: list[tuple[str, tuple[Any, ...]]], frame: SE2) -> None:
    """Add side ``items`` (local frame) to ``b`` at ``frame`` (``T_world_side``)."""
    yaw = frame.angle
    for kind, p in items:
        if kind == "box":
            (u, v, z), size, box_yaw, label = p
            x, y = frame.apply(np.array([[u, v]]))[0]
            b.box((x, y, z), size, yaw=yaw + box_yaw, label=label)
        elif kind == "pole":
            u, v, r, h = p
            x, y = frame.apply(np.array([[u, v]]))[0]
            b.cylinder(x, y, r, 0.0, h)
        else:
            (u, v, z), r = p
            x, y = frame.apply(np.array([[u, v]]))[0]
            b.sphere((x, y, z), r, label="vegetation")


def block_loop(
    seed: int = 0,
    *,
    lap_length: float = 300.0,
    laps: int = 2,
    aspect: float = 0.5,
    speed: float = 10.0,
    corner_radius: float = 12.0,
    transition: float = 0.5,
    road_half_width: float = 7.0,
    lane_offset: float = 1.75,
    sensor_height: float = 1.73,
    symmetry: int = 1,
    num_pedestrians: int = 4,
    num_moving_cars: int = 1,
) -> Course:
    """A car driving ``laps`` laps counter-clockwise around a city block (3D).

    The ring road is a rounded rectangle centred on the world origin, long side along x
    (short/long = ``aspect``), its centreline's corners of about ``corner_radius`` m; the car
    keeps to the right lane (``lane_offset`` m outside the centreline) at ``speed`` m/s with
    the sensor ``sensor_height`` m above the ground, starting in the middle of the south
    straight heading +x. Each lap is ``lap_length`` m: four straights and four 90° corners
    whose yaw rate ramps in and out over ``transition`` s (0: plain arcs). A lap is exactly
    a closed loop (the four identical corners make it the square of a half-turn), so every
    lap ends where the first began (to rounding, ~1e-12 m) and sweeps of lap 2 revisit the
    places of lap 1.

    The block is lined on both sides of the road with façades (inside the block and
    outside it), poles, parked cars and trees; ``num_pedestrians`` walk on the pavements
    and ``num_moving_cars`` drive back and forth in the other lane. ``symmetry`` 2 copies the
    south side onto the north side and the east onto the west (the scene is unchanged by a
    half-turn about the origin); 4 (needs ``aspect=1``) copies the south side onto all
    four: a place and its image a quarter-turn away look the same — the trap for a loop
    detector. Their frames are :attr:`Course.repeated_frames` (moving objects, if any, are
    not copied).
    """
    rng = np.random.default_rng(check_seed(seed))
    n_laps = count(laps, "laps")
    v = positive(speed, "speed")
    ratio = positive(aspect, "aspect")
    road = positive(road_half_width, "road_half_width")
    lane = non_negative(lane_offset, "lane_offset")
    if lane >= road:
        raise ValueError(f"lane_offset: must be < road_half_width ({road}), got {lane}")
    radius = positive(corner_radius, "corner_radius")
    if radius <= road:
        raise ValueError(f"corner_radius: must exceed road_half_width ({road}), got {radius}")
    tau = non_negative(transition, "transition")
    if symmetry not in (1, 2, 4):
        raise ValueError(f"symmetry: must be 1, 2 or 4, got {symmetry}")
    if symmetry == 4 and ratio != 1.0:
        raise ValueError(f"aspect: symmetry=4 needs a square block (aspect=1), got {aspect}")
    durations, rates = _corner(v, radius + lane, tau)
    corner_length = v * float(np.sum(durations))
    # The corner's tangent length (how far before the corner point it starts turning): the
    # scene is laid out around the path the car really drives.
    end = SE2.identity()
    for dt, w in zip(durations, rates, strict=True):
        end = end @ SE2.exp([v * dt, 0.0, w * dt])
    tangent = float(end.translation[0])  # == end.translation[1] by symmetry
    straights = positive(lap_length, "lap_length") - 4.0 * corner_length
    a = straights / (2.0 * (1.0 + ratio))
    if a <= 5.0:
        raise ValueError(
            f"lap_length: {lap_length} m leaves no straights for four corners of "
            f"{corner_length:.1f} m; make it longer or corner_radius smaller"
        )
    b_len = ratio * a
    sides = (a, b_len, a, b_len)
    centre_r = tangent - lane  # the road centreline's corner radius, as driven

    # Trajectory: half the south straight, then (corner, straight) × 4 with the last straight
    # halved, repeated for every lap.
    piece_t: list[float] = []
    piece_w: list[float] = []
    for _ in range(n_laps):
        for k in range(4):
            piece_t.append(sides[k] / 2 / v)
            piece_w.append(0.0)
            piece_t += durations
            piece_w += rates
            piece_t.append(sides[(k + 1) % 4] / 2 / v)
            piece_w.append(0.0)
    twists = np.zeros((len(piece_t), 3))
    twists[:, 0] = v
    twists[:, 2] = piece_w
    start = SE2.from_vector([0.0, -(b_len / 2 + tangent), 0.0])
    trajectory = Trajectory.from_twists(start, piece_t, twists).lifted(
        positive(sensor_height, "sensor_height")
    )
    lap_time = float(np.sum(piece_t)) / n_laps

    # Scene: each straight's side objects in its own frame (origin on the centreline at the
    # straight's middle, u along travel), copied to the sides that repeat it.
    builder = SceneBuilder(3).ground(0.0)
    frames = []
    for k in range(4):
        across = sides[(k + 1) % 4] / 2 + centre_r
        frames.append(
            SE2.from_vector([0.0, 0.0, k * math.pi / 2]) @ SE2.from_vector([0.0, -across, 0.0])
        )
    inner_depth = max(3.0, min(sides[1], sides[0]) / 2 + centre_r - road - 6.5)
    content: dict[int, list[tuple[str, tuple[Any, ...]]]] = {}
    for k in range(4):
        source = k % (4 // symmetry) if symmetry > 1 else k
        if source not in content:
            reach = sides[k] / 2 + centre_r + road + 6.0
            content[source] = _block_side(rng, sides[k], reach, road, inner_depth)
        _place(builder, content[source], frames[k])
    for _ in range(int(num_pedestrians)):
        k = int(rng.integers(0, 4))
        side = float(rng.choice([-1.0, 1.0]))
        # A 15 m walk, or the whole straight where the block is smaller than that.
        walk = min(15.0, sides[k])
        u0 = rng.uniform(-sides[k] / 2, sides[k] / 2 - walk)
        x, y = frames[k].apply(np.array([[u0, side * (road + 2.4)]]))[0]
        dx, dy = frames[k].rotation @ np.array([walk, 0.0])
        builder.person(x, y, (dx, dy), speed=rng.uniform(0.8, 1.5), phase=rng.uniform(0, 15))
    for _ in range(int(num_moving_cars)):
        k = int(rng.integers(0, 4))
        x, y = frames[k].apply(np.array([[-sides[k] / 2 + 3.0, lane]]))[0]
        dx, dy = frames[k].rotation @ np.array([sides[k] - 6.0, 0.0])
        builder.box((x, y, 0.75), (4.5, 1.8, 1.5), yaw=frames[k].angle + math.pi, label="car")
        builder.moving((dx, dy), speed=rng.uniform(6.0, 12.0), phase=rng.uniform(0, sides[k]))
    repeated: tuple[SE3, ...] = ()
    if symmetry > 1:
        repeated = tuple(
            SE3.from_vector([0, 0, 0, 0, 0, 2 * math.pi * k / symmetry]) for k in range(symmetry)
        )
    return Course(
        scene=builder.build(),
        trajectory=trajectory,
        length=v * trajectory.end_time,
        pass_start_times=_frozen(lap_time * np.arange(n_laps)),
        repeated_frames=repeated,
    )


def _frozen(a: Any) -> FloatArray:
    out: FloatArray = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


# --------------------------------------------------------------------------- 2D room tour


def room_tour(
    seed: int = 0,
    *,
    rooms_per_side: int = 4,
    visit: tuple[int, ...] | None = None,
    identical_rooms: bool = False,
    room_width: float = 6.0,
    room_depth: float = 5.0,
    corridor_width: float = 2.4,
    furniture_per_room: int = 4,
    speed: float = 0.8,
    turn_rate: float = 0.8,
    turn_radius: float = 0.5,
) -> Course:
    """A robot touring an office floor (2D) and coming back through the same rooms.

    The floor is a corridor along +x (centreline ``y = 0``, ``x ∈ [0, rooms_per_side ·
    room_width]``) with ``rooms_per_side`` rooms on each side, each with a 1 m door and
    ``furniture_per_room`` pieces of furniture in its back part (the front 2.3 m stay free
    for the robot). Rooms are numbered along +x, the ``+y`` side first (``0 … n-1``), then
    the ``-y`` side (``n … 2n-1``). The robot starts at ``(0.8, 0)`` facing +x, walks the
    corridor, enters each room of ``visit`` (default: all) through its door, crosses it
    1.5 m inside the door wall and comes back out; at the far end it turns round and visits
    the same rooms in reverse order, ending where it started, facing +x again. Corners are
    arcs of ``turn_radius``, U-turns are made on the spot at ``turn_rate``.

    ``identical_rooms=True``: every room is the same room (door, furniture) placed by a rigid
    motion — the rooms on the ``-y`` side are turned by a half-turn — so scans taken at
    the same spot of two rooms are nearly the same. :attr:`Course.repeated_frames` are the
    room frames (origin at the door wall's left end as seen from the corridor, x along that
    wall, y into the room).
    """
    rng = np.random.default_rng(check_seed(seed))
    n = count(rooms_per_side, "rooms_per_side")
    rw, rd = positive(room_width, "room_width"), positive(room_depth, "room_depth")
    cw = positive(corridor_width, "corridor_width") / 2
    door = 1.0
    if rw < 3.0:
        raise ValueError(f"room_width: must be >= 3.0 to fit a door and an aisle, got {room_width}")
    if rd < 4.0:
        raise ValueError(
            f"room_depth: must be >= 4.0 (a 2.3 m aisle and furniture), got {room_depth}"
        )
    rooms = tuple(range(2 * n)) if visit is None else tuple(int(r) for r in visit)
    for r in rooms:
        if not 0 <= r < 2 * n:
            raise ValueError(f"visit: room {r} does not exist (0 … {2 * n - 1})")
    length = n * rw
    # Room frames: origin at the door wall's end nearer x = 0 for +y rooms, the far end for
    # -y rooms (a half-turn), so that the same local layout gives congruent rooms.
    frames = [SE2.from_vector([i * rw, cw, 0.0]) for i in range(n)]
    frames += [SE2.from_vector([(i + 1) * rw, -cw, math.pi]) for i in range(n)]

    def layout() -> tuple[float, list[tuple[str, Any]]]:
        d0 = 0.5 + rng.uniform(0.0, rw - door - 1.0)
        items: list[tuple[str, Any]] = []
        for _ in range(int(furniture_per_room)):
            cu = rng.uniform(0.8, rw - 0.8)
            if rng.uniform() < 0.5:
                size = rng.uniform(0.4, 1.0, 2)
                cv = rng.uniform(2.3 + 0.72, rd - 0.72)
                items.append(("box", (cu, cv, size, rng.uniform(0, math.pi))))
            else:
                r = rng.uniform(0.15, 0.4)
                items.append(("circle", (cu, rng.uniform(2.3 + r, rd - 0.3 - r), r)))
        return d0, items

    shared = layout() if identical_rooms else None
    b = SceneBuilder(2)
    doors: list[float] = []
    for f in frames:
        d0, items = shared if shared is not None else layout()
        doors.append(d0)
        walls = [
            ((0, 0), (d0, 0)),
            ((d0 + door, 0), (rw, 0)),
            ((0, 0), (0, rd)),
            ((rw, 0), (rw, rd)),
            ((0, rd), (rw, rd)),
        ]
        for p, q in walls:
            pw, qw = f.apply(np.array([p, q], dtype=float))
            b.wall(pw, qw)
        for kind, p in items:
            if kind == "box":
                cu, cv, size, yaw = p
                b.box(f.apply(np.array([[cu, cv]]))[0], size, yaw=yaw + f.angle, label="furniture")
            else:
                cu, cv, r = p
                x, y = f.apply(np.array([[cu, cv]]))[0]
                b.circle(x, y, r, label="furniture")
    b.wall((0.0, -cw - rd), (0.0, cw + rd))
    b.wall((length, -cw - rd), (length, cw + rd))

    # Waypoints: per visited room, the corridor spot in front of its door, 1.5 m inside,
    # across the room to the far quarter, and back the same way.
    def excursion(k: int) -> list[FloatArray]:
        f, d0 = frames[k], doors[k]
        u = d0 + door / 2
        far = 0.25 * rw if u > rw / 2 else 0.75 * rw
        local = np.array([[u, -cw], [u, 1.5], [far, 1.5], [u, 1.5], [u, -cw]])
        return list(f.apply(local))

    order = sorted(rooms, key=lambda k: float(excursion(k)[0][0]))
    out = [np.array([0.8, 0.0])]
    for k in order:
        out += excursion(k)
    out.append(np.array([length - 0.8, 0.0]))
    turn_index = len(out) - 1
    for k in reversed(order):
        out += excursion(k)
    out.append(np.array([0.8, 0.0]))
    # Drop repeats (a room's exit spot is the next one's entry when they face each other).
    points = [out[0]]
    for i, spot in enumerate(out[1:], start=1):
        if np.hypot(*(spot - points[-1])) > 1e-9:
            points.append(spot)
        elif i <= turn_index:
            turn_index -= 1
    trajectory = Trajectory.through_waypoints(
        np.array(points),
        speed=speed,
        turn_radius=turn_radius,
        turn_rate=turn_rate,
        final_heading=0.0,
    )
    # The return pass starts when the robot reaches the far end of the corridor.
    # (the first piece that turns on the spot there).
    far_end = np.array(points[turn_index])
    at_end = [
        k
        for k, p in enumerate(trajectory.knot_poses)
        if trajectory.twists[k, 0] == 0 and np.hypot(*(p.translation - far_end)) < 1e-6
    ]
    t_turn = float(trajectory.knot_times[at_end[0]])
    moving = trajectory.twists[:, 0] > 0
    seg = np.diff(trajectory.knot_times)
    return Course(
        scene=b.build(),
        trajectory=trajectory,
        length=float(np.sum(seg[moving] * trajectory.twists[moving, 0])),
        pass_start_times=_frozen([trajectory.start_time, t_turn]),
        repeated_frames=tuple(frames) if identical_rooms else (),
    )


# --------------------------------------------------------------------------- 2D ring corridor


def ring_corridor(
    seed: int = 0,
    *,
    width: float = 40.0,
    depth: float = 24.0,
    corridor_width: float = 2.4,
    door_spacing: float = 8.0,
    overlap: float = 10.0,
    speed: float = 0.6,
    turn_radius: float = 0.8,
) -> Course:
    """A robot driving once round a ring of office corridors (2D) and on past its start: one
    large loop, closed only at the end — the revisit a loop closer must find after the whole
    lap's drift.

    The corridors ring a ``width`` × ``depth`` m building (outer walls ``[0, width] × [0,
    depth]``, the inner block ``corridor_width`` m in from them). Both walls of every corridor
    are bare but for door recesses (0.9–1.6 m wide, 0.3–1.2 m deep) about ``door_spacing`` m
    apart at random places: between them a corridor pins nothing along itself, as real ones
    do. The robot starts in the middle of the south corridor facing +x (on the corridor's
    centreline), drives counter-clockwise at ``speed`` m/s with corners cut by arcs of
    ``turn_radius``, passes its start and drives ``overlap`` m further.
    """
    rng = np.random.default_rng(check_seed(seed))
    w, d = positive(width, "width"), positive(depth, "depth")
    cw = positive(corridor_width, "corridor_width")
    spacing = positive(door_spacing, "door_spacing")
    extra = non_negative(overlap, "overlap")
    if min(w, d) < 2 * cw + 4.0:
        raise ValueError(
            f"width, depth: the inner block needs >= 4 m a side ({w} x {d} with corridors {cw})"
        )
    if extra > w / 2 - cw:
        raise ValueError(f"overlap: must be <= {w / 2 - cw:g} (the south corridor), got {overlap}")
    b = SceneBuilder(2)

    def wall_with_doors(a: FloatArray, z: FloatArray, away: FloatArray) -> None:
        """The wall ``a → z``, door recesses opening ``away`` from the corridor."""
        length = float(np.hypot(*(z - a)))
        u = (z - a) / length
        edges, s = [], 1.5 + rng.uniform(0.0, spacing)
        while s + 1.6 < length - 1.5:
            width_ = rng.uniform(0.9, 1.6)
            edges.append((s, s + width_, rng.uniform(0.3, 1.2)))
            s += width_ + rng.uniform(0.5, 1.5) * spacing
        start = 0.0
        for s0, s1, deep in edges:
            p0, p1 = a + s0 * u, a + s1 * u
            b.wall(a + start * u, p0)
            b.polyline([p0, p0 + deep * away, p1 + deep * away, p1])
            start = s1
        b.wall(a + start * u, z)

    corners = np.array([[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]])
    inner = np.array([[cw, cw], [w - cw, cw], [w - cw, d - cw], [cw, d - cw]])
    outward = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    for k in range(4):
        wall_with_doors(corners[k], corners[(k + 1) % 4], outward[k])
        wall_with_doors(inner[k], inner[(k + 1) % 4], -outward[k])

    h = cw / 2
    start = np.array([w / 2, h])
    waypoints = np.array(
        [
            start,
            [w - h, h],
            [w - h, d - h],
            [h, d - h],
            [h, h],
            start,
            start + np.array([extra, 0.0]),
        ]
    )
    trajectory = Trajectory.through_waypoints(
        waypoints if extra > 0 else waypoints[:-1],
        speed=positive(speed, "speed"),
        turn_radius=positive(turn_radius, "turn_radius"),
    )
    # The second pass starts when the robot is back at its start (a knot: the straight
    # pieces of the last two legs meet there).
    knots = trajectory.knot_poses
    back = [
        float(trajectory.knot_times[k])
        for k in range(1, len(knots))
        if np.hypot(*(knots[k].translation - start)) < 1e-6
    ]
    back.append(trajectory.end_time)  # overlap 0: the lap ends at the start
    moving = trajectory.twists[:, 0] > 0
    seg = np.diff(trajectory.knot_times)
    return Course(
        scene=b.build(),
        trajectory=trajectory,
        length=float(np.sum(seg[moving] * trajectory.twists[moving, 0])),
        pass_start_times=_frozen([trajectory.start_time, back[0]]),
        repeated_frames=(),
    )
