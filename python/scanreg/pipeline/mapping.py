"""Mapping with loop closure on a pose graph (2D).

One :meth:`Mapper.step` per scan, in five stages:

1. **odometry** — :class:`~scanreg.pipeline.Odometry2D` (scan-to-map, correlative front end)
   gives ``T_odom_scan``;
2. **node** — the scan becomes a graph node (a keyframe) when it has moved more than
   ``node_distance`` or turned more than ``node_angle`` since the last one; the edge from the
   previous node is the odometry's relative pose with covariance ``Σ_match + Σ_drift(d)``
   (the scan's calibrated covariance against the local map, plus a drift term growing with
   the distance ``d`` between the nodes); iSAM2 adds it;
3. **candidates** — earlier nodes, excluding the last ``loop_min_travel`` metres of path,
   whose predicted distance to the new node, ``|t|`` of ``T_n_c = inv(T_world_n) T_world_c``
   from the graph, is within ``loop_max_range`` once ``loop_gate_sigmas`` σ of that
   prediction's uncertainty (the joint marginal of the two nodes) are allowed for;
   the nearest ``max_candidates`` are matched;
4. **match and verify** — :func:`~scanreg.pipeline.loops.match_loop` against the candidate's
   submap; every candidate, accepted or not, is kept as a :class:`LoopRecord` with its
   reasons;
5. **close** — an accepted loop becomes an edge with information = inverse calibrated
   covariance (nothing along its degenerate directions) and a robust kernel, and iSAM2
   re-solves.

:meth:`Mapper.finish` runs a final batch Levenberg–Marquardt pass and lays every scan on its
node: ``T_world_scan = T_world_node @ inv(T_odom_node) @ T_odom_scan``.

The shape is dimension-independent (nodes, edges, candidates, records, results); the 2D parts
are the odometry front end and the loop matcher (:mod:`scanreg.pipeline.loops`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np

from .._validate import FloatArray, as_points
from ..graph import Graph, Kernel
from ..io.carmen import CarmenLog
from ..preprocess import voxel_downsample
from ..transform import SE2, SE3, as_pose
from .loops import LoopMatch, LoopSettings, Submap2D, build_submap, match_loop
from .loops3d import LoopMatch3D
from .odometry2d import Odometry2D, OdometryConfig2D, _count, _positive

#: The pose type of a run (2D or 3D) and of its loop matches: one result shape for both.
PoseT = TypeVar("PoseT", SE2, SE3)
MatchT = TypeVar("MatchT", LoopMatch, LoopMatch3D)


def _default_odometry() -> OdometryConfig2D:
    return OdometryConfig2D(front_end="correlative", kernel="cauchy", max_keyframes=50)


@dataclass(frozen=True)
class MappingConfig:
    """How :class:`Mapper` runs. Frozen; validated on construction. Metres, radians."""

    odometry: OdometryConfig2D = field(default_factory=_default_odometry)
    #: A scan becomes a graph node after moving this far ...
    node_distance: float = 0.5
    #: ... or turning this much since the last node.
    node_angle: float = math.radians(20.0)
    #: Node scans are kept voxel-downsampled to this for submaps and the map.
    node_voxel_size: float = 0.05
    #: A submap holds this many nodes on each side of its anchor.
    submap_half_size: int = 2
    #: Odometry-edge drift: σ = ``drift_translation`` · d (m) and ``drift_rotation`` · d (rad)
    #: over a distance d between nodes, plus the floors.
    drift_translation: float = 0.02
    drift_rotation: float = math.radians(0.5)
    drift_floor_translation: float = 0.005
    drift_floor_rotation: float = math.radians(0.2)
    #: Loop candidates: not within the last ``loop_min_travel`` m of path ...
    loop_min_travel: float = 8.0
    #: ... predicted within ``loop_max_range`` m, allowing ``loop_gate_sigmas`` σ ...
    loop_max_range: float = 4.0
    loop_gate_sigmas: float = 3.0
    #: ... the nearest ``max_candidates`` of them matched per new node.
    max_candidates: int = 2
    #: Look for loops at every ``loop_every``-th node.
    loop_every: int = 1
    #: Robust kernel of loop edges (Mahalanobis units).
    loop_kernel: Kernel = field(default_factory=lambda: Kernel("cauchy", 1.0))
    loops: LoopSettings = field(default_factory=LoopSettings)
    #: Run the final batch Levenberg–Marquardt pass in :meth:`Mapper.finish`.
    batch: bool = True
    #: Returns kept from a range scan (:func:`run_mapping` on a CARMEN log), metres.
    min_range: float = 0.1
    max_range: float = 40.0

    def __post_init__(self) -> None:
        if not isinstance(self.odometry, OdometryConfig2D):
            raise TypeError(
                f"odometry: expected OdometryConfig2D, got {type(self.odometry).__name__}"
            )
        for name in (
            "node_distance",
            "node_angle",
            "node_voxel_size",
            "drift_translation",
            "drift_rotation",
            "loop_min_travel",
            "loop_max_range",
        ):
            _positive(getattr(self, name), name, allow_zero=True)
        for name in ("drift_floor_translation", "drift_floor_rotation", "loop_gate_sigmas"):
            _positive(getattr(self, name), name)
        _positive(self.min_range, "min_range", allow_zero=True)
        _positive(self.max_range, "max_range")
        if self.max_range <= self.min_range:
            raise ValueError(
                f"max_range: must exceed min_range ({self.min_range}), got {self.max_range}"
            )
        _count(self.submap_half_size, "submap_half_size", 0)
        _count(self.max_candidates, "max_candidates", 0)
        _count(self.loop_every, "loop_every", 1)
        if not isinstance(self.loop_kernel, Kernel):
            raise TypeError(f"loop_kernel: expected Kernel, got {type(self.loop_kernel).__name__}")
        if not isinstance(self.loops, LoopSettings):
            raise TypeError(f"loops: expected LoopSettings, got {type(self.loops).__name__}")


@dataclass(frozen=True)
class LoopRecord(Generic[MatchT]):
    """One loop candidate as matched and judged (:class:`~scanreg.pipeline.loops.LoopMatch`
    in 2D, :class:`~scanreg.pipeline.loops3d.LoopMatch3D` in 3D), with the scans behind its
    two nodes."""

    match: MatchT
    #: Scan index of the submap's anchor node and of the current node.
    submap_scan: int
    scan: int

    @property
    def accepted(self) -> bool:
        return self.match.accepted

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready record."""
        m = self.match
        out = {
            "submap_node": m.submap_node,
            "node": m.node,
            "submap_scan": self.submap_scan,
            "scan": self.scan,
            "accepted": m.accepted,
            "reasons": list(m.reasons),
            "predicted": [float(v) for v in m.predicted.as_vector()],
            "measured": [float(v) for v in m.measured.as_vector()],
            "window": [_number(v) for v in m.window],
            "score": _number(m.score),
            "overlap": _number(m.overlap),
            "chi2": _number(m.chi2),
            "covariance": [[_number(v) for v in row] for row in np.asarray(m.covariance)],
            "information": np.asarray(m.information).tolist(),
            "degenerate_directions": list(m.degenerate_directions),
        }
        if isinstance(m, LoopMatch3D):
            out["origin"] = m.origin  # "graph" or "place"
        return out


def _number(value: float) -> float | None:
    """A float for JSON: ``None`` where it is not a number (JSON has no NaN)."""
    v = float(value)
    return v if math.isfinite(v) else None


def _clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


@dataclass
class MappingTiming:
    """Seconds spent per stage, summed over the run: wall clock, and the process's CPU time
    (all its threads; on a shared machine the wall time says more about the load)."""

    odometry: float = 0.0
    candidates: float = 0.0
    matching: float = 0.0
    optimization: float = 0.0
    total: float = 0.0
    odometry_cpu: float = 0.0
    candidates_cpu: float = 0.0
    matching_cpu: float = 0.0
    optimization_cpu: float = 0.0
    total_cpu: float = 0.0

    def add(self, stage: str, since: tuple[float, float]) -> None:
        """Add the wall and CPU time elapsed since ``since`` (:func:`_clock`) to ``stage``."""
        wall, cpu = _clock()
        setattr(self, stage, getattr(self, stage) + wall - since[0])
        setattr(self, f"{stage}_cpu", getattr(self, f"{stage}_cpu") + cpu - since[1])


@dataclass(frozen=True)
class MappingStep:
    """The outcome of one :meth:`Mapper.step`."""

    index: int
    #: ``T_odom_scan`` (``None``: the scan had too few points and was skipped).
    odometry_pose: SE2 | SE3 | None
    #: The graph node this scan created, if any.
    node: int | None
    #: Loop candidates matched at this scan.
    loops: tuple[LoopRecord[Any], ...]


@dataclass(frozen=True)
class MappingResult(Generic[PoseT]):
    """Everything :meth:`Mapper.finish` (``MappingResult[SE2]``) and
    :meth:`~scanreg.pipeline.Mapper3D.finish` (``MappingResult[SE3]``) return (scan indices
    are step order)."""

    #: ``T_world_scan`` of every scan after optimization.
    poses: tuple[PoseT, ...]
    #: ``T_odom_scan``: the odometry alone (the trajectory before loop closure).
    odometry_poses: tuple[PoseT, ...]
    stamps: tuple[float | None, ...]
    #: Scan index of every node, by node id.
    node_scans: tuple[int, ...]
    #: Every loop candidate matched, accepted or rejected, in order.
    loops: tuple[LoopRecord[Any], ...]
    #: Scans skipped (too few points: 2D fewer than 3, 3D fewer than 10 in range); their
    #: pose is carried from their neighbours.
    skipped: tuple[int, ...]
    #: Every node's scan (voxel-downsampled, own frame), by node id: the map's material.
    node_points: tuple[FloatArray, ...]
    graph: Graph
    timing: MappingTiming
    num_scans: int

    @property
    def accepted_loops(self) -> tuple[LoopRecord[Any], ...]:
        return tuple(r for r in self.loops if r.accepted)

    @property
    def rejected_loops(self) -> tuple[LoopRecord[Any], ...]:
        return tuple(r for r in self.loops if not r.accepted)


class Mapper:
    """2D mapping with loop closure (see the module docstring).

    >>> mapper = Mapper(MappingConfig())
    >>> for points, prior, stamp in scans:
    ...     mapper.step(points, prior=prior, stamp=stamp)
    >>> result = mapper.finish()
    >>> result.poses, result.loops, result.graph
    """

    def __init__(self, config: MappingConfig | None = None) -> None:
        cfg = MappingConfig() if config is None else config
        if not isinstance(cfg, MappingConfig):
            raise TypeError(f"config: expected MappingConfig, got {type(cfg).__name__}")
        self.config = cfg
        self._odometry = Odometry2D(cfg.odometry)
        self._graph = Graph(2)
        self._odom_poses: list[SE2 | None] = []
        self._stamps: list[float | None] = []
        self._scan_node: list[int] = []  # node each scan hangs from (-1 before the first)
        self._node_scans: list[int] = []
        self._node_points: dict[int, FloatArray] = {}
        self._node_odom: dict[int, SE2] = {}
        self._node_cov: dict[int, FloatArray] = {}  # odometry covariance of each node's scan
        self._node_blind: dict[int, tuple[float, float]] = {}  # bearing gap: start, width
        self._node_travel: list[float] = []  # path length at each node
        self._submaps: dict[int, Submap2D] = {}
        self._loops: list[LoopRecord[LoopMatch]] = []
        self._skipped: list[int] = []
        self._pending = SE2.identity()  # motion prior accumulated over skipped scans
        self._last_pose: SE2 | None = None
        self._timing = MappingTiming()
        self._finished = False

    @property
    def graph(self) -> Graph:
        return self._graph

    @property
    def num_nodes(self) -> int:
        return len(self._node_scans)

    @property
    def loops(self) -> tuple[LoopRecord[LoopMatch], ...]:
        return tuple(self._loops)

    # -- per scan ------------------------------------------------------------------------
    def step(self, points: Any, prior: Any = None, *, stamp: float | None = None) -> MappingStep:
        """Add one scan: ``(N, 2)`` points in its own frame, ``prior`` = ``T_prev_curr`` from
        wheel odometry (or ``None``), ``stamp`` its time (may step backwards: it is only
        recorded)."""
        if self._finished:
            raise RuntimeError("Mapper: finish() was called; start a new Mapper")
        t_start = _clock()
        pts = as_points(points, "points", dim=2, min_points=0)
        motion = None if prior is None else as_pose(prior, "prior", 2)
        if stamp is not None and not math.isfinite(float(stamp)):
            raise ValueError(f"stamp: must be finite, got {stamp!r}")
        index = len(self._odom_poses)
        self._stamps.append(None if stamp is None else float(stamp))
        if motion is not None:
            self._pending = self._pending @ motion  # type: ignore[operator]

        if pts.shape[0] < 3:
            # No alignment possible: carry the pose on the accumulated prior (or hold it).
            self._skipped.append(index)
            pose = None if self._last_pose is None else self._last_pose @ self._pending
            self._odom_poses.append(pose)
            self._scan_node.append(self.num_nodes - 1)
            self._timing.add("total", t_start)
            return MappingStep(index, pose, None, ())

        first = self._last_pose is None
        frame = self._odometry.step(pts, prior=None if first or prior is None else self._pending)
        self._pending = SE2.identity()
        pose = frame.pose
        self._last_pose = pose
        self._odom_poses.append(pose)
        self._timing.add("odometry", t_start)

        node = self._maybe_add_node(index, pts, pose, frame.covariance)
        self._scan_node.append(self.num_nodes - 1)
        records: tuple[LoopRecord[LoopMatch], ...] = ()
        if node is not None:
            records = self._close_loops(node)
        self._timing.add("total", t_start)
        return MappingStep(index, pose, node, records)

    def _maybe_add_node(
        self, index: int, pts: FloatArray, pose: SE2, covariance: FloatArray
    ) -> int | None:
        cfg = self.config
        g = self._graph
        if self._node_scans:
            rel = self._node_odom[self.num_nodes - 1].inverse() @ pose
            dist = float(np.linalg.norm(rel.translation))
            if dist <= cfg.node_distance and abs(rel.angle) <= cfg.node_angle:
                return None
        node = self.num_nodes
        kept = pts
        if cfg.node_voxel_size > 0:
            kept = np.ascontiguousarray(voxel_downsample(pts, cfg.node_voxel_size).points)
        self._node_scans.append(index)
        self._node_points[node] = kept
        self._node_blind[node] = _blind_sector(kept)
        self._node_odom[node] = pose
        self._node_cov[node] = np.asarray(covariance, dtype=np.float64)
        t0 = _clock()
        if node == 0:
            g.add_node(0, pose)
            g.add_prior(0, pose, np.diag([1e8, 1e8, 1e8]))
            self._node_travel.append(0.0)
        else:
            prev = node - 1
            rel = self._node_odom[prev].inverse() @ pose
            dist = float(np.linalg.norm(rel.translation))
            self._node_travel.append(self._node_travel[-1] + dist)
            g.add_node(node, g.pose(prev) @ rel)  # type: ignore[operator]
            st = cfg.drift_floor_translation + cfg.drift_translation * dist
            sr = cfg.drift_floor_rotation + cfg.drift_rotation * dist
            cov = np.diag([st**2, st**2, sr**2])
            measured = np.asarray(covariance, dtype=np.float64)
            if measured.shape == (3, 3) and np.isfinite(measured).all():
                cov = cov + 0.5 * (measured + measured.T)
            g.add_edge(prev, node, rel, np.linalg.inv(cov))
        g.update()
        self._timing.add("optimization", t0)
        return node

    def _submap(self, anchor: int) -> Submap2D:
        sub = self._submaps.get(anchor)
        if sub is None:
            h = self.config.submap_half_size
            nodes = [n for n in range(anchor - h, anchor + h + 1) if 0 <= n < self.num_nodes]
            sub = build_submap(
                anchor,
                nodes,
                self._node_points,
                self._node_odom,
                resolution=self.config.loops.resolution,
                voxel_size=self.config.node_voxel_size,
                covariances=self._node_cov,
            )
            # Only cache a submap whose later nodes all exist (it will not change).
            if anchor + h < self.num_nodes:
                self._submaps[anchor] = sub
        return sub

    def _candidates(self, node: int) -> list[tuple[float, int]]:
        cfg = self.config
        g = self._graph
        travel = np.asarray(self._node_travel)
        # Nodes before the recent past (the last loop_min_travel metres of path).
        num_old = int(np.searchsorted(travel, travel[node] - cfg.loop_min_travel, side="left"))
        if num_old == 0:
            return []
        _, rows = g.pose_vectors()
        old, here = rows[:num_old], rows[node]
        # T_n_c translation = R_nᵀ (t_c − t_n): only its length is needed here.
        d = np.linalg.norm(here[:2] - old[:, :2], axis=1)
        # A cheap, generous first gate: the new node's own marginal spread (the first node
        # is anchored) bounds the relative one up to their correlation.
        cov_here = g.marginal_covariance(node)
        spread = math.sqrt(max(float(np.linalg.eigvalsh(cov_here[:2, :2])[-1]), 0.0))
        reach = cfg.loop_max_range + cfg.loop_gate_sigmas * spread
        near = np.flatnonzero(d <= reach)
        order = near[np.argsort(d[near], kind="stable")]
        # Nearest first, but a node that could not have seen most of this scan from where the
        # graph puts it (a 180° laser passing the same spot the other way) only after the
        # others: its match is doomed and would take a candidate's place.
        seen = np.array([self._visible(node, here, old[n], int(n)) for n in order])
        order = np.concatenate([order[seen >= 0.5], order[seen < 0.5]])
        gated: list[tuple[float, int]] = []
        for n in order:
            if len(gated) >= cfg.max_candidates:
                break
            dist = float(d[n])
            if dist <= cfg.loop_max_range:
                gated.append((dist, int(n)))
                continue
            # Beyond the range: a Mahalanobis test on the relative pose's joint marginal.
            cov = g.relative_covariance(int(n), node)
            c, s = math.cos(old[n, 2]), math.sin(old[n, 2])
            t_rel = np.array([[c, s], [-s, c]]) @ (here[:2] - old[n, :2])
            u = t_rel / max(dist, 1e-12)
            sigma = math.sqrt(max(float(u @ cov[:2, :2] @ u), 1e-12))
            if (dist - cfg.loop_max_range) / sigma <= cfg.loop_gate_sigmas:
                gated.append((dist, int(n)))
        return gated

    def _visible(self, node: int, here: FloatArray, there: FloatArray, other: int) -> float:
        """The fraction of ``node``'s points that lie outside ``other``'s blind sector (the
        widest gap in its scan's bearings), with both nodes at their graph poses ``here`` and
        ``there`` (``[x, y, θ]``)."""
        pts = self._node_points[node]
        c, s = math.cos(here[2]), math.sin(here[2])
        world = pts @ np.array([[c, s], [-s, c]]) + here[:2]
        c, s = math.cos(there[2]), math.sin(there[2])
        local = (world - there[:2]) @ np.array([[c, -s], [s, c]])
        start, width = self._node_blind[other]
        bearing = np.mod(np.arctan2(local[:, 1], local[:, 0]) - start, 2.0 * math.pi)
        return float(np.mean(bearing >= width)) if len(pts) else 0.0

    def _close_loops(self, node: int) -> tuple[LoopRecord[LoopMatch], ...]:
        cfg = self.config
        if cfg.max_candidates == 0 or node % cfg.loop_every:
            return ()
        g = self._graph
        t0 = _clock()
        candidates = self._candidates(node)
        self._timing.add("candidates", t0)
        records = []
        for _, n in candidates:
            t_m = _clock()
            predicted = g.pose(n).inverse() @ g.pose(node)  # type: ignore[operator]
            assert isinstance(predicted, SE2)
            rel_cov = g.relative_covariance(n, node)
            match = match_loop(
                self._node_points[node], node, self._submap(n), predicted, rel_cov, cfg.loops
            )
            self._timing.add("matching", t_m)
            record = LoopRecord(match, self._node_scans[n], self._node_scans[node])
            records.append(record)
            if match.accepted:
                t_o = _clock()
                g.add_edge(
                    n, node, match.measured, match.information, kind="loop", kernel=cfg.loop_kernel
                )
                # A loop moves many nodes at once: relinearise a little more than usual.
                g.update(extra_iterations=2)
                self._timing.add("optimization", t_o)
        self._loops.extend(records)
        return tuple(records)

    # -- end of run ----------------------------------------------------------------------
    def finish(self) -> MappingResult[SE2]:
        """Batch-optimize (unless ``config.batch`` is off) and return every scan's pose."""
        if self._finished:
            raise RuntimeError("Mapper: finish() was already called")
        if not self._node_scans:
            raise ValueError("scans: no scan had at least 3 points; nothing was mapped")
        self._finished = True
        g = self._graph
        if self.config.batch:
            t0 = _clock()
            g.optimize()
            self._timing.add("optimization", t0)
            self._timing.add("total", t0)
        node_poses = g.poses()
        poses: list[SE2] = []
        odometry: list[SE2] = []
        first_pose = self._node_odom[0]
        for k, odo in enumerate(self._odom_poses):
            n = max(self._scan_node[k], 0)
            base = node_poses[n]
            if odo is None:  # skipped before any aligned scan: at the first node
                odo = first_pose
            odometry.append(odo)
            rel = self._node_odom[n].inverse() @ odo
            pose = base @ rel  # type: ignore[operator]
            assert isinstance(pose, SE2)
            poses.append(pose)
        return MappingResult(
            poses=tuple(poses),
            odometry_poses=tuple(odometry),
            stamps=tuple(self._stamps),
            node_scans=tuple(self._node_scans),
            loops=tuple(self._loops),
            skipped=tuple(self._skipped),
            node_points=tuple(self._node_points[n] for n in range(self.num_nodes)),
            graph=g,
            timing=self._timing,
            num_scans=len(self._odom_poses),
        )

    def node_points(self, node: int) -> FloatArray:
        """The kept (downsampled) scan of ``node``, in its own frame."""
        return self._node_points[node]


def _blind_sector(points: FloatArray) -> tuple[float, float]:
    """``(start, width)`` of the widest gap between the bearings of ``points`` (scan frame):
    the part of the plane the sensor did not see (about π for a 180° laser, one beam step
    for a 360° one)."""
    if len(points) < 2:
        return 0.0, 2.0 * math.pi
    b = np.sort(np.arctan2(points[:, 1], points[:, 0]))
    gaps = np.diff(np.append(b, b[0] + 2.0 * math.pi))
    k = int(np.argmax(gaps))
    return float(b[k]), float(gaps[k])


def run_mapping(
    log: CarmenLog,
    config: MappingConfig | None = None,
    *,
    kind: str | None = None,
    max_scans: int | None = None,
    progress: bool = False,
) -> MappingResult[SE2]:
    """Map a CARMEN log in file order (its timestamps may step backwards; they are kept as
    written), with each scan's wheel-odometry motion as the prior.

    ``kind``: the laser message kind to use (default: ``FLASER`` if present, else the first
    kind in the log). ``progress``: a progress line on stderr (scans/s, loops accepted and
    rejected).
    """
    from .._progress import Progress

    cfg = MappingConfig() if config is None else config
    kinds = [s.kind for s in log.scans]
    if not kinds:
        raise ValueError(f"log: {log.path} holds no laser scan")
    chosen = kind if kind is not None else ("FLASER" if "FLASER" in kinds else kinds[0])
    indices = [i for i, k in enumerate(kinds) if k == chosen]
    if not indices:
        raise ValueError(f"kind: the log has no {chosen!r} scans (it has {sorted(set(kinds))})")
    if max_scans is not None:
        if max_scans < 1:
            raise ValueError(f"max_scans: must be >= 1, got {max_scans}")
        indices = indices[:max_scans]
    mapper = Mapper(cfg)
    bar = Progress(len(indices), description="map", unit="scans", enabled=progress)
    previous: int | None = None
    with bar:
        for i in indices:
            scan = log.scans[i]
            prior = None
            has_odometry = scan.odometry_pose is not None
            if (
                previous is not None
                and has_odometry
                and log.scans[previous].odometry_pose is not None
            ):
                prior = log.motion_prior(previous, i)
            step = mapper.step(
                scan.to_points(cfg.min_range, cfg.max_range), prior, stamp=scan.timestamp
            )
            previous = i
            if step.loops or step.index % 25 == 0:
                bar.set_counters(
                    nodes=mapper.num_nodes,
                    loops=sum(r.accepted for r in mapper.loops),
                    rejected=sum(not r.accepted for r in mapper.loops),
                )
            bar.update()
    return mapper.finish()
