"""Mapping with loop closure on a pose graph (3D).

The 3D counterpart of :class:`~scanreg.pipeline.Mapper`, with the same stages and the same
result (:class:`~scanreg.pipeline.MappingResult`, :class:`~scanreg.pipeline.LoopRecord`,
:func:`~scanreg.pipeline.mapping_output.write_outputs`). One :meth:`Mapper3D.step` per sweep:

1. **odometry** — :class:`~scanreg.pipeline.Odometry` (GICP against a voxel-hash local map)
   gives ``T_odom_sensor``;
2. **node** — the sweep becomes a graph node (a keyframe) when it has moved more than
   ``node_distance`` or turned more than ``node_angle`` since the last one. The edge from the
   previous node is the odometry's relative pose with covariance ``Σ_frame + Σ_drift(d)``;
   iSAM2 adds it. Its cloud waits for the next aligned sweep: then it is deskewed with the
   motion centred on it (the mean twist into and out of it), cropped and voxelized
   (``node_voxel_size``), and the node's loops (3.–5.) are searched;
3. **candidates** — earlier nodes, excluding the last ``loop_min_travel`` metres of path, whose
   predicted distance to the new node (from the graph) is within ``loop_max_range`` once
   ``loop_gate_sigmas`` σ of that prediction's uncertainty (the joint marginal of the two
   nodes) are allowed for; the nearest ``max_candidates`` are matched by GICP from the graph's
   prediction against the candidate's submap (:func:`~scanreg.pipeline.loops3d.match_loop_3d`);
4. **places** — when no graph candidate was accepted, Scan Context (:mod:`scanreg.place`)
   retrieves look-alike keyframes beyond the recent past; one within reach is matched from
   :func:`scanreg.register_global`'s pose, then GICP: the route for drift beyond GICP's
   basin. Within reach: the graph's Mahalanobis gate, *or* the drift-independent one (the
   drift the path between the two could hold, :func:`~scanreg.pipeline.loops3d.drift_window_3d`,
   however small the graph believes its σ to be). One beyond reach is logged as rejected,
   unmatched — a repeated structure's look-alike a quarter lap away is what this stops first,
   and every match's own tests second;
5. **close** — an accepted loop becomes an edge with information = inverse calibrated
   covariance (nothing along its degenerate directions) and a robust kernel; iSAM2 re-solves.
   Recall does not rest on the graph knowing its own drift: a match sound on its own evidence
   that fails only the graph's σ window or χ² test is *held* (a hypothesis) until a match of
   another node, within ``LoopSettings3D.hypothesis_horizon`` metres of path, agrees with it
   (:func:`~scanreg.pipeline.loops.loops_agree`); the group is then closed, without a robust
   kernel (the graph, not the loops, was wrong), and the graph re-solved in batch.
   A match held so must be the only fit: one from the graph's prediction is held only if
   :func:`scanreg.register_global` finds the same pose.

Cost per node, bounded whatever the drift: ``max_candidates`` GICP matches from the graph's
prediction (each held one also a global registration), and one place candidate (a global
registration and GICP) every ``place_every`` nodes without an accepted loop.

:meth:`Mapper3D.finish` runs a final batch Levenberg–Marquardt pass and lays every sweep on its
node: ``T_world_sensor = T_world_node @ inv(T_odom_node) @ T_odom_sensor``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validate import FloatArray, as_matrix, as_points
from ..deskew import deskew, velocity_from_motion
from ..graph import Graph, Kernel
from ..place import PlaceCandidate, PlaceDatabase
from ..preprocess import voxel_downsample
from ..transform import SE3, as_pose
from .loops import agreeing_group, record_decided
from .loops3d import (
    LoopMatch3D,
    LoopSettings3D,
    Submap3D,
    build_submap_3d,
    drift_window_3d,
    match_loop_3d,
)
from .mapping import (
    Checkpoint,
    LoopRecord,
    MappingResult,
    MappingStep,
    MappingTiming,
    _checked_checkpoint_every,
    _stepped,
    _stopped_run,
)
from .mapping_graph import is_new_node, odometry_edge_covariance, validate_graph_fields
from .odometry import Odometry, OdometryConfig
from .odometry2d import _count


def _se3(pose: Any) -> SE3:
    assert isinstance(pose, SE3)
    return pose


@dataclass(frozen=True)
class MappingConfig3D:
    """How :class:`Mapper3D` runs. Frozen; validated on construction. Metres, radians."""

    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    #: A sweep becomes a graph node after moving this far ...
    node_distance: float = 2.0
    #: ... or turning this much since the last node.
    node_angle: float = math.radians(20.0)
    #: Node clouds are kept voxelized to this (the submaps and the map's material).
    node_voxel_size: float = 0.3
    #: A submap holds this many nodes on each side of its anchor ...
    submap_half_size: int = 2
    #: ... each registered to the anchor's cloud from its odometry pose (see
    #: :func:`~scanreg.pipeline.loops3d.build_submap_3d`).
    refine_submaps: bool = True
    #: Odometry-edge drift: σ = ``drift_translation`` · d (m) and ``drift_rotation`` · d (rad)
    #: over a distance d between nodes, plus the floors.
    drift_translation: float = 0.01
    drift_rotation: float = math.radians(0.05)
    drift_floor_translation: float = 0.01
    drift_floor_rotation: float = math.radians(0.05)
    #: Loop candidates: not within the last ``loop_min_travel`` m of path ...
    loop_min_travel: float = 50.0
    #: ... predicted within ``loop_max_range`` m, allowing ``loop_gate_sigmas`` σ ...
    loop_max_range: float = 6.0
    loop_gate_sigmas: float = 3.0
    #: ... the nearest ``max_candidates`` of them matched per new node.
    max_candidates: int = 1
    #: Look for loops at every ``loop_every``-th node.
    loop_every: int = 1
    #: Query the place database at every ``place_every``-th node without an accepted graph
    #: loop (0: never; place recognition off).
    place_every: int = 2
    #: Robust kernel of loop edges (Mahalanobis units).
    loop_kernel: Kernel = field(default_factory=lambda: Kernel("cauchy", 1.0))
    loops: LoopSettings3D = field(default_factory=LoopSettings3D)
    #: Run the final batch Levenberg–Marquardt pass in :meth:`Mapper3D.finish`.
    batch: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.odometry, OdometryConfig):
            raise TypeError(
                f"odometry: expected OdometryConfig, got {type(self.odometry).__name__}"
            )
        validate_graph_fields(self)
        _count(self.place_every, "place_every", 0)
        if not isinstance(self.refine_submaps, bool):
            raise TypeError(
                f"refine_submaps: expected a bool, got {type(self.refine_submaps).__name__}"
            )
        if not isinstance(self.loops, LoopSettings3D):
            raise TypeError(f"loops: expected LoopSettings3D, got {type(self.loops).__name__}")


#: Sweeps with fewer returns in the odometry's range window are skipped (its own minimum).
MIN_POINTS = 10


class Mapper3D:
    """3D mapping with loop closure (see the module docstring).

    >>> mapper = Mapper3D(MappingConfig3D())
    >>> for frame in sequence:
    ...     mapper.step(frame.points, frame.timestamps, stamp=frame.stamp)
    >>> result = mapper.finish()        # MappingResult, as the 2D Mapper's
    >>> result.poses, result.loops, result.graph
    """

    def __init__(self, config: MappingConfig3D | None = None) -> None:
        cfg = MappingConfig3D() if config is None else config
        if not isinstance(cfg, MappingConfig3D):
            raise TypeError(f"config: expected MappingConfig3D, got {type(cfg).__name__}")
        self.config = cfg
        self._odometry = Odometry(cfg.odometry)
        self._graph = Graph(3)
        self._places = PlaceDatabase(max_radius=min(80.0, cfg.odometry.max_range))
        self._odom_poses: list[SE3 | None] = []
        self._stamps: list[float | None] = []
        self._scan_node: list[int] = []
        self._node_scans: list[int] = []
        self._node_points: dict[int, FloatArray] = {}
        self._node_odom: dict[int, SE3] = {}
        self._node_travel: list[float] = []
        self._submaps: dict[int, Submap3D] = {}
        self._loops: list[LoopRecord[LoopMatch3D]] = []
        # Loops held as hypotheses (sound on their own evidence, at odds with the graph).
        self._held: list[LoopRecord[LoopMatch3D]] = []
        self._skipped: list[int] = []
        self._pending = SE3.identity()
        self._last_pose: SE3 | None = None
        # A new node's sweep waits for the next aligned sweep (the motion out of it) before it
        # is deskewed, kept and searched for loops: (node, points, timestamps, twist into it).
        self._unfinished: tuple[int, FloatArray, FloatArray | None, FloatArray | None] | None = None
        self._last_stamp: float | None = None
        self._timing = MappingTiming()
        self._finished = False

    @property
    def graph(self) -> Graph:
        return self._graph

    @property
    def num_nodes(self) -> int:
        return len(self._node_scans)

    @property
    def loops(self) -> tuple[LoopRecord[LoopMatch3D], ...]:
        return tuple(self._loops)

    # -- per sweep -----------------------------------------------------------------------
    def step(
        self,
        points: Any,
        timestamps: Any = None,
        prior: Any = None,
        *,
        stamp: float | None = None,
    ) -> MappingStep:
        """Add one sweep: ``(N, 3)`` points in the sensor frame, optional per-point
        ``timestamps`` (s since the sweep start, for deskewing), ``prior`` = ``T_prev_curr``
        from wheel/IMU odometry (or ``None``), ``stamp`` its time (s). The returned
        :class:`~scanreg.pipeline.mapping.MappingStep` names the node this sweep made, and the
        loops of the node finished here (made at the previous aligned sweep)."""
        if self._finished:
            raise RuntimeError("Mapper3D: finish() was called; start a new Mapper3D")
        t_start = time.perf_counter()
        pts = as_points(points, "points", dim=3, min_points=0)
        times = None if timestamps is None else as_matrix(timestamps, "timestamps", (len(pts),))
        motion = None if prior is None else _se3(as_pose(prior, "prior", 3))
        if stamp is not None and not math.isfinite(float(stamp)):
            raise ValueError(f"stamp: must be finite, got {stamp!r}")
        index = len(self._odom_poses)
        self._stamps.append(None if stamp is None else float(stamp))
        if motion is not None:
            self._pending = _se3(self._pending @ motion)

        c = self.config.odometry
        rng = np.linalg.norm(pts, axis=1)
        if int(np.count_nonzero((rng >= c.min_range) & (rng <= c.max_range))) < MIN_POINTS:
            # Nothing to align: carry the pose on the accumulated prior (or hold it).
            self._skipped.append(index)
            pose = None if self._last_pose is None else _se3(self._last_pose @ self._pending)
            self._odom_poses.append(pose)
            self._scan_node.append(self.num_nodes - 1)
            self._timing.total += time.perf_counter() - t_start
            return MappingStep(index, pose, None, ())

        first = self._last_pose is None
        use_prior = not first and prior is not None
        frame = self._odometry.step(pts, times, self._pending if use_prior else None, stamp=stamp)
        self._pending = SE3.identity()
        pose = frame.pose
        self._last_pose = pose
        self._odom_poses.append(pose)
        t_odo = time.perf_counter()
        self._timing.odometry += t_odo - t_start

        # The node made at the previous sweep is finished now: the motion out of it is known.
        velocity = None if first else self._velocity(frame.motion, stamp, times)
        records = self._finish_node(velocity)
        node = self._maybe_add_node(index, pose, frame.covariance)
        if node is not None:
            self._unfinished = (node, pts, times, velocity)
        self._last_stamp = stamp
        self._scan_node.append(self.num_nodes - 1)
        self._timing.total += time.perf_counter() - t_start
        return MappingStep(index, pose, node, records)

    def _velocity(
        self, motion: SE3, stamp: float | None, times: FloatArray | None
    ) -> FloatArray | None:
        """The body twist of ``motion`` (from the previous aligned sweep to this one): over
        their stamps, else over this sweep's span."""
        period = math.nan
        if stamp is not None and self._last_stamp is not None:
            period = float(stamp) - self._last_stamp
        elif times is not None and len(times):
            period = float(times.max() - times.min())
        if not (math.isfinite(period) and period > 0):
            return None
        return velocity_from_motion(motion, period)

    def _finish_node(self, velocity_out: FloatArray | None) -> tuple[LoopRecord[LoopMatch3D], ...]:
        """Keep the unfinished node's sweep — deskewed with the motion centred on it, the mean
        of the twists into and out of it (with only one of them at the first node, or the
        last) — and search its loops."""
        if self._unfinished is None:
            return ()
        node, pts, times, velocity_in = self._unfinished
        self._unfinished = None
        known = [v for v in (velocity_in, velocity_out) if v is not None]
        velocity = None if not known else np.mean(known, axis=0)
        self._node_points[node] = self._node_cloud(pts, times, velocity)
        return self._close_loops(node)

    def _node_cloud(
        self, pts: FloatArray, times: FloatArray | None, velocity: FloatArray | None
    ) -> FloatArray:
        """The sweep as a keyframe keeps it: deskewed with ``velocity`` (body twist) to the
        odometry's reference time, cropped to its range window, voxelized."""
        c = self.config.odometry
        if c.deskew and times is not None and velocity is not None:
            pts = deskew(pts, times, velocity, reference_time=c.reference_time)
        rng = np.linalg.norm(pts, axis=1)
        kept = np.ascontiguousarray(pts[(rng >= c.min_range) & (rng <= c.max_range)])
        if self.config.node_voxel_size > 0:
            kept = np.ascontiguousarray(voxel_downsample(kept, self.config.node_voxel_size).points)
        return kept

    def _maybe_add_node(self, index: int, pose: SE3, covariance: FloatArray) -> int | None:
        """A graph node and its odometry edge when the sweep has moved enough (its cloud is
        kept by :meth:`_finish_node`, one aligned sweep later)."""
        cfg = self.config
        g = self._graph
        if self._node_scans:
            rel = _se3(self._node_odom[self.num_nodes - 1].inverse() @ pose)
            dist = float(np.linalg.norm(rel.translation))
            if not is_new_node(dist, rel.angle, cfg):
                return None
        node = self.num_nodes
        self._node_scans.append(index)
        self._node_odom[node] = pose
        t0 = time.perf_counter()
        if node == 0:
            g.add_node(0, pose)
            g.add_prior(0, pose, np.eye(6) * 1e8)
            self._node_travel.append(0.0)
        else:
            prev = node - 1
            rel = _se3(self._node_odom[prev].inverse() @ pose)
            dist = float(np.linalg.norm(rel.translation))
            self._node_travel.append(self._node_travel[-1] + dist)
            g.add_node(node, _se3(self._pose(prev) @ rel))
            cov = odometry_edge_covariance(dist, covariance, cfg, 3)
            g.add_edge(prev, node, rel, np.linalg.inv(cov))
        g.update()
        self._timing.optimization += time.perf_counter() - t0
        return node

    def _pose(self, node: int) -> SE3:
        return _se3(self._graph.pose(node))

    def _submap(self, anchor: int) -> Submap3D:
        sub = self._submaps.get(anchor)
        if sub is None:
            h = self.config.submap_half_size
            nodes = [
                n for n in range(anchor - h, anchor + h + 1) if 0 <= n < len(self._node_points)
            ]
            sub = build_submap_3d(
                anchor,
                nodes,
                self._node_points,
                self._node_odom,
                voxel_size=self.config.node_voxel_size,
                num_neighbors=self.config.odometry.num_neighbors,
                refine=self.config.refine_submaps,
            )
            if anchor + h < len(self._node_points):  # complete: it will not change
                self._submaps[anchor] = sub
        return sub

    def _num_old(self, node: int) -> int:
        """Nodes before the recent past (the last ``loop_min_travel`` metres of path)."""
        travel = np.asarray(self._node_travel)
        return int(
            np.searchsorted(travel, travel[node] - self.config.loop_min_travel, side="right")
        )

    def _within_reach(
        self, candidate: int, node: int, *, drift: bool = False
    ) -> tuple[bool, float, float]:
        """Whether ``candidate`` may be where ``node`` is, given the graph: the predicted
        distance less ``loop_gate_sigmas`` σ (σ along the predicted offset, from the joint
        marginal) is within ``loop_max_range``; with ``drift``, or less the drift the path
        between them could hold (:meth:`_drift_window`), whatever the graph's σ. Returns
        (verdict, distance, σ)."""
        cfg = self.config
        g = self._graph
        t_rel = _se3(self._pose(candidate).inverse() @ self._pose(node)).translation
        dist = float(np.linalg.norm(t_rel))
        if dist <= cfg.loop_max_range:
            return True, dist, 0.0
        if drift and dist <= cfg.loop_max_range + self._drift_window(candidate, node)[0]:
            return True, dist, 0.0
        cov = g.relative_covariance(candidate, node)
        u = t_rel / max(dist, 1e-12)
        sigma = math.sqrt(max(float(u @ cov[:3, :3] @ u), 1e-12))
        return (dist - cfg.loop_max_range) / sigma <= cfg.loop_gate_sigmas, dist, sigma

    def _drift_window(self, candidate: int, node: int) -> tuple[float, float]:
        """How far ``node`` may lie from the graph's prediction in ``candidate``'s frame,
        whatever the graph's σ: the drift the path between them could hold."""
        path = abs(self._node_travel[node] - self._node_travel[candidate])
        return drift_window_3d(path, self.config.loops)

    def _candidates(self, node: int) -> list[int]:
        cfg = self.config
        g = self._graph
        num_old = self._num_old(node)
        if num_old == 0:
            return []
        here = g.pose(node).translation
        old = np.array([g.pose(n).translation for n in range(num_old)])
        d = np.linalg.norm(old - here, axis=1)
        # A cheap, generous first gate: the new node's own marginal spread bounds the
        # relative one up to their correlation (the first node is anchored).
        cov_here = g.marginal_covariance(node)
        spread = math.sqrt(max(float(np.linalg.eigvalsh(cov_here[:3, :3])[-1]), 0.0))
        reach = cfg.loop_max_range + cfg.loop_gate_sigmas * spread
        near = np.flatnonzero(d <= reach)
        out: list[int] = []
        for n in near[np.argsort(d[near], kind="stable")]:
            if len(out) >= cfg.max_candidates:
                break
            if self._within_reach(int(n), node)[0]:
                out.append(int(n))
        return out

    def _close_loops(self, node: int) -> tuple[LoopRecord[LoopMatch3D], ...]:
        cfg = self.config
        records: list[LoopRecord[LoopMatch3D]] = []
        searching = cfg.max_candidates > 0 and node % cfg.loop_every == 0
        t0 = time.perf_counter()
        candidates = self._candidates(node) if searching else []
        self._timing.candidates += time.perf_counter() - t0
        for n in candidates:
            records.append(self._match(n, node, "graph"))
        # Places: the descriptor is built for every node (the database must hold them all),
        # queried only when the graph's own candidates gave nothing.
        t0 = time.perf_counter()
        desc = self._places.describe(self._node_points[node]) if cfg.place_every else None
        place_due = (
            desc is not None
            and searching
            and node % cfg.place_every == 0
            and not any(r.accepted for r in records)
        )
        hits: tuple[PlaceCandidate, ...] = ()
        num_old = self._num_old(node)
        if place_due and num_old > 0:
            assert desc is not None
            hits = self._places.query(
                desc,
                cfg.loops.place_top_k,
                exclude_recent=node - num_old,
                max_distance=cfg.loops.place_max_distance,
            )
        self._timing.candidates += time.perf_counter() - t0
        tried = set(candidates)
        for hit in hits:
            n = hit.index  # nodes join the database in order: index = node
            if n in tried:
                continue
            tried.add(n)
            ok, dist, sigma = self._within_reach(n, node, drift=True)
            if ok:
                records.append(self._match(n, node, "place", score=hit.distance))
            else:
                records.append(self._unreachable(n, node, hit.distance, dist, sigma))
        if desc is not None:
            self._places.add(desc, key=node)
        self._loops.extend(records)
        return tuple(records)

    def _match(
        self, n: int, node: int, origin: str, *, score: float = math.nan
    ) -> LoopRecord[LoopMatch3D]:
        cfg = self.config
        g = self._graph
        t_m = time.perf_counter()
        predicted = _se3(self._pose(n).inverse() @ self._pose(node))
        rel_cov = g.relative_covariance(n, node)
        match = match_loop_3d(
            self._node_points[node],
            node,
            self._submap(n),
            predicted,
            rel_cov,
            cfg.loops,
            origin="place" if origin == "place" else "graph",
            score=score,
            drift_window=self._drift_window(n, node),
        )
        self._timing.matching += time.perf_counter() - t_m
        record = LoopRecord(match, self._node_scans[n], self._node_scans[node])
        if match.accepted:
            self._add_loops([record], kernel=cfg.loop_kernel)
        elif match.hypothesis:
            record = self._hypothesize(record)
        return record

    def _hypothesize(self, record: LoopRecord[LoopMatch3D]) -> LoopRecord[LoopMatch3D]:
        """Hold a loop the graph disagrees with; once ``loops.min_agreeing`` loops from
        different nodes — held ones, or ones the graph accepted within the horizon — agree
        with each other (:func:`~scanreg.pipeline.loops.agreeing_group`), close the held ones.
        Returns ``record``, accepted if it completed a group."""
        s = self.config.loops
        travel = self._node_travel
        here = record.match.node
        self._held = [
            h for h in self._held if travel[here] - travel[h.match.node] <= s.hypothesis_horizon
        ]
        # Loops the graph accepted recently back it as well: a hypothesis that agrees with
        # one is the same story. (On the 25 m lap with the odometry's σ understated 30x, the
        # two revisits whose neighbours the graph had accepted otherwise waited in vain.)
        support = []
        for r in reversed(self._loops):
            if travel[here] - travel[r.match.node] > s.hypothesis_horizon:
                break
            if r.accepted:
                support.append(r)
        group = agreeing_group(record, self._held, self._pose, s, support=support)
        if group is None:
            self._held.append(record)
            return record
        held = {id(h) for h in group}
        self._held = [h for h in self._held if id(h) not in held]
        confirmed = [
            dataclasses.replace(
                h,
                match=dataclasses.replace(h.match, accepted=True, reasons=(), evidence="loops"),
            )
            for h in group
        ]
        # No robust kernel: the graph disagrees with these loops by far more than their
        # covariance (that is why they were held); they passed a stronger test: each other.
        self._add_loops(confirmed, kernel=None)
        # A correction of many σ: iSAM2's few relinearisations may not carry it through.
        t_o = time.perf_counter()
        self._graph.optimize()
        self._timing.optimization += time.perf_counter() - t_o
        record_decided(self._loops, group[1:], confirmed[1:])
        return confirmed[0]

    def _add_loops(self, records: list[LoopRecord[LoopMatch3D]], *, kernel: Any) -> None:
        g = self._graph
        t_o = time.perf_counter()
        for r in records:
            m = r.match
            g.add_edge(m.submap_node, m.node, m.measured, m.information, kind="loop", kernel=kernel)
        # A loop moves many nodes at once: relinearise a little more than usual.
        g.update(extra_iterations=2)
        self._timing.optimization += time.perf_counter() - t_o

    def _unreachable(
        self, n: int, node: int, score: float, dist: float, sigma: float
    ) -> LoopRecord[LoopMatch3D]:
        """A place candidate out of reach (:meth:`_within_reach`): logged with its reason,
        not matched."""
        cfg = self.config
        predicted = _se3(self._pose(n).inverse() @ self._pose(node))
        drift = self._drift_window(n, node)[0]
        reach = cfg.loop_max_range + max(cfg.loop_gate_sigmas * sigma, drift)
        match = LoopMatch3D(
            submap_node=n,
            node=node,
            predicted=predicted,
            measured=predicted,
            window=(reach, math.nan),
            score=float(score),
            overlap=math.nan,
            chi2=math.nan,
            covariance=np.full((6, 6), np.nan),
            information=np.zeros((6, 6)),
            degenerate_directions=(),
            weak_vectors=np.zeros((6, 0)),
            accepted=False,
            reasons=(
                f"place candidate beyond reach: predicted {dist:.1f} m away > {reach:.1f} m "
                f"({cfg.loop_gate_sigmas:g} σ = {cfg.loop_gate_sigmas * sigma:.2f} m; the "
                f"drift the path allows: {drift:.2f} m)",
            ),
            origin="place",
        )
        return LoopRecord(match, self._node_scans[n], self._node_scans[node])

    # -- end of run ----------------------------------------------------------------------
    def finish(self) -> MappingResult[SE3]:
        """Batch-optimize (unless ``config.batch`` is off) and return every sweep's pose."""
        if self._finished:
            raise RuntimeError("Mapper3D: finish() was already called")
        if not self._node_scans:
            raise ValueError(
                f"scans: no sweep had at least {MIN_POINTS} points within "
                f"[{self.config.odometry.min_range}, {self.config.odometry.max_range}] m; "
                "nothing was mapped"
            )
        self._finished = True
        t0 = time.perf_counter()
        self._finish_node(None)  # the last node: the motion into it only
        self._timing.total += time.perf_counter() - t0
        g = self._graph
        if self.config.batch:
            t0 = time.perf_counter()
            g.optimize()
            dt = time.perf_counter() - t0
            self._timing.optimization += dt
            self._timing.total += dt
        # The map's frame is its first node's odometry pose, exactly (Graph.move_gauge).
        g.move_gauge(0, self._node_odom[0])
        return self._result(self._node_points)

    def snapshot(self, reason: str) -> MappingResult[SE3]:
        """What is mapped so far, as the graph has it now (no batch pass): a checkpoint, or
        what an interrupted run leaves. The mapper goes on unchanged. The newest node's sweep,
        still waiting for the motion out of it, is deskewed with the motion into it only and
        not searched for loops. ``reason`` becomes :attr:`MappingResult.partial`."""
        if not self._node_scans:
            raise ValueError("scans: no sweep was aligned yet; nothing was mapped")
        points = dict(self._node_points)
        if self._unfinished is not None:
            node, pts, times, velocity_in = self._unfinished
            points[node] = self._node_cloud(pts, times, velocity_in)
        return dataclasses.replace(self._result(points), partial=str(reason))

    def _result(self, node_points: dict[int, FloatArray]) -> MappingResult[SE3]:
        g = self._graph
        node_poses = g.poses()
        poses: list[SE3] = []
        odometry: list[SE3] = []
        first_pose = self._node_odom[0]
        for k, odo in enumerate(self._odom_poses):
            n = max(self._scan_node[k], 0)
            if odo is None:  # skipped before any aligned sweep: at the first node
                odo = first_pose
            odometry.append(odo)
            rel = self._node_odom[n].inverse() @ odo
            poses.append(_se3(_se3(node_poses[n]) @ rel))
        return MappingResult(
            poses=tuple(poses),
            odometry_poses=tuple(odometry),
            stamps=tuple(self._stamps),
            node_scans=tuple(self._node_scans),
            loops=tuple(self._loops),
            skipped=tuple(self._skipped),
            node_points=tuple(node_points[n] for n in range(self.num_nodes)),
            graph=g,
            timing=self._timing,
            num_scans=len(self._odom_poses),
        )


def run_mapping_3d(
    sequence: Any,
    config: MappingConfig3D | None = None,
    *,
    max_scans: int | None = None,
    progress: bool = False,
    checkpoint: Checkpoint | None = None,
    checkpoint_every: int = 1000,
) -> MappingResult[SE3]:
    """Map a 3D :class:`~scanreg.io.ScanSequence` (KITTI folder, folder of point files, ROS
    bag, ``sim:`` drive) in order, each sweep deskewed with its per-point times when it has
    them. ``progress``: a progress line on stderr (scans/s, loops accepted and rejected).
    ``checkpoint``: called with :meth:`Mapper3D.snapshot` every ``checkpoint_every`` sweeps
    (e.g. to write the outputs so far).

    Raises
    ------
    MappingInterrupted
        When Ctrl-C or an error stops the run before its last sweep, after a node was made;
        it carries what was mapped so far and chains the cause.
    """
    from .._progress import Progress

    cfg = MappingConfig3D() if config is None else config
    _checked_checkpoint_every(checkpoint_every)
    total = len(sequence)
    if max_scans is not None:
        if max_scans < 1:
            raise ValueError(f"max_scans: must be >= 1, got {max_scans}")
        total = min(total, max_scans)
    if total == 0:
        raise ValueError("sequence: holds no sweep")
    mapper = Mapper3D(cfg)
    bar = Progress(total, description="map", unit="scans", enabled=progress)
    k = 0
    try:
        with bar:
            for k in range(total):
                frame = sequence[k]
                step = mapper.step(frame.points, frame.timestamps, stamp=frame.stamp)
                _stepped(mapper, step, bar, 10, k, total, checkpoint, checkpoint_every)
        return mapper.finish()
    except (KeyboardInterrupt, Exception) as exc:
        stopped = _stopped_run(mapper, exc, k, total)
        if stopped is None:
            raise
        raise stopped from exc


__all__ = ["Mapper3D", "MappingConfig3D", "run_mapping_3d"]
