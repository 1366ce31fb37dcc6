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
   reasons. Recall does not rest on the graph knowing its own drift: when these windows have
   found nothing for ``LoopSettings.wide_spacing`` metres, the nearest candidate is searched
   for in a larger submap (its pass, grown to what the scan can see:
   :func:`~scanreg.pipeline.loops.wide_submap_span`) over a wide window
   (``LoopSettings.wide_window``: up to ±20 m, as wide as the path between the two could have
   drifted); such a loop, and a match that is sound on its own evidence (and not degenerate)
   but fails only the χ² test, is held until another loop agrees with it (both are then
   closed: the graph, not the loops, was wrong; :func:`~scanreg.pipeline.loops.loops_agree`),
   unless it moves its node farther than the path between the two, through the loops already
   closed, could have drifted (:func:`~scanreg.pipeline.graph_path.path_between`).
   While a loop is held, each new node is also searched where that loop puts it (the
   old node nearest there, over the least window): a true loop's successors lie where it
   says, and their matches confirm it;
5. **close** — an accepted loop becomes an edge with information = inverse calibrated
   covariance (nothing along its degenerate directions) and a robust kernel, and iSAM2
   re-solves.

:func:`run_mapping` runs the odometry (:meth:`Mapper.track`) of the next scans on a second
thread while the graph takes this one (:meth:`Mapper.integrate`); Ctrl-C or an error leaves
what was mapped in :class:`MappingInterrupted`.

:meth:`Mapper.finish` runs a final batch Levenberg–Marquardt pass and lays every scan on its
node: ``T_world_scan = T_world_node @ inv(T_odom_node) @ T_odom_scan``; with wheel odometry the
scans between nodes are then re-solved from their scan and wheel steps, each weighted by step
noise identified on the run (``MappingConfig.smooth_scans``, :mod:`scanreg.pipeline.smoothing`).

The shape is dimension-independent (nodes, edges, candidates, records, results); the 2D parts
are the odometry front end and the loop matcher (:mod:`scanreg.pipeline.loops`).
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import time
import warnings
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np

from .._validate import FloatArray, as_matrix, as_points
from ..graph import Graph, GraphSolveError, Kernel
from ..io.carmen import CarmenLog
from ..io.scan_log import ScanLog
from ..preprocess import voxel_downsample
from ..transform import SE2, SE3, as_pose
from . import odometry_process as odometry_processes
from .graph_path import path_between
from .loops import (
    MAX_DRIFT_PER_METRE,
    LoopMatch,
    LoopSettings,
    Submap2D,
    agreeing_group,
    build_submap,
    match_loop,
    record_decided,
    wide_submap_span,
)
from .loops3d import LoopMatch3D
from .mapping_graph import is_new_node, odometry_edge_covariance, validate_graph_fields
from .odometry2d import Odometry2D, OdometryConfig2D, _positive
from .odometry_timing import measure_laser_latency, odometry_at_scans
from .smoothing import StepNoise, identify_step_noise, smooth_scan_poses
from .sweep_residual import DeskewedSweep, deskew_error
from .wheel import WheelNoise, WheelOdometry

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
    #: The wheel odometry's noise model: each ``prior`` (scaled by the wheels' distance scale,
    #: learned online from the well-constrained steps:
    #: :class:`~scanreg.pipeline.wheel.WheelOdometry`) enters the odometry's solve with its
    #: covariance, so that along a direction the scan does not constrain (a corridor's axis)
    #: the wheels hold the pose
    #: (:meth:`Odometry2D.step`'s ``prior_covariance``). ``None``: the prior only starts the
    #: odometry's search. Off by default: on the data at hand it did not help — Intel 0.0158
    #: against 0.0155 m, ACES 0.0415 against 0.0391 m (benchmarks/README.md,
    #: "freiburg_mapping.py"), the Intel excerpt of tests/test_mapping.py 0.023 against
    #: 0.017 m, the simulated room tours' mean ATE 0.0144 against 0.0135 m.
    wheel: WheelNoise | None = None
    #: The motion cost of the odometry's correlative search: the wheels' step (its distance
    #: scale and its noise model's variances calibrated on the run against the steps the
    #: scans pin, :class:`~scanreg.pipeline.wheel.WheelOdometry`) with that covariance ranks
    #: the candidates (``OdometryConfig2D.prior_covariance_use="search"``), so that where the
    #: scan barely prefers one pose over another (a corridor's axis, a repeated doorway) the
    #: one the wheels support is refined; the refinement, verdict and covariance stay the
    #: scan's. Unused without wheel odometry and while ``wheel`` is set (the wheels are then
    #: in the solve itself). On by default: without it the Freiburg hospital's odometry lost
    #: its heading in places (351 steps more than 3° off the wheels'; all relations 10.0 m,
    #: mapped 9.97 m), with it 1.01 m (mapped 1.02 m); Intel 0.0152 → 0.0154 m, ACES
    #: 0.0360 → 0.0352 m mapped (benchmarks/README.md, "freiburg_mapping.py"). ``None`` (from
    #: Python or a dict): the candidates are ranked by the scan alone.
    motion_cost: WheelNoise | None = field(default_factory=WheelNoise)
    #: The final pass (:meth:`Mapper.finish`, after the batch pass): every scan re-solved
    #: from its scan step and its wheel step, each weighted by step noise identified on the
    #: run itself, with each node's scan held at its loop-closed pose (σ: the drift floors)
    #: (:mod:`scanreg.pipeline.smoothing`); skipped without wheel odometry (fewer than 50
    #: consecutive steps with a ``prior``). Freiburg benchmark: ACES 0.0390 → 0.0348 m,
    #: Intel 0.0155 → 0.0150 m, the same runs (benchmarks/README.md, "freiburg_mapping.py").
    smooth_scans: bool = True
    #: How long before its timestamp a scan was taken (s), where :func:`run_mapping` reads
    #: the odometry from the log's ``ODOM`` stream (:func:`scan_odometry`); ``None``: measured
    #: on the log (:func:`estimate_laser_latency`).
    laser_latency: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.odometry, OdometryConfig2D):
            raise TypeError(
                f"odometry: expected OdometryConfig2D, got {type(self.odometry).__name__}"
            )
        validate_graph_fields(self)
        _positive(self.min_range, "min_range", allow_zero=True)
        _positive(self.max_range, "max_range")
        if self.laser_latency is not None:
            _positive(self.laser_latency, "laser_latency", allow_zero=True)
        if not isinstance(self.smooth_scans, bool):
            raise TypeError(
                f"smooth_scans: expected a bool, got {type(self.smooth_scans).__name__}"
            )
        if self.max_range <= self.min_range:
            raise ValueError(
                f"max_range: must exceed min_range ({self.min_range}), got {self.max_range}"
            )
        if not isinstance(self.loops, LoopSettings):
            raise TypeError(f"loops: expected LoopSettings, got {type(self.loops).__name__}")
        if self.wheel is not None and not isinstance(self.wheel, WheelNoise):
            raise TypeError(f"wheel: expected WheelNoise or None, got {type(self.wheel).__name__}")
        if self.motion_cost is not None and not isinstance(self.motion_cost, WheelNoise):
            raise TypeError(
                f"motion_cost: expected WheelNoise or None, got {type(self.motion_cost).__name__}"
            )


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
        else:
            out["search"] = m.search  # "graph", "wide" or "guided"
            out["rival"] = _number(m.rival)  # null: no rival search
        return out


def _number(value: float) -> float | None:
    """A float for JSON: ``None`` where it is not a number (JSON has no NaN)."""
    v = float(value)
    return v if math.isfinite(v) else None


def _clock() -> tuple[float, float]:
    # The calling thread's CPU clock, not the process's: reading the process's while the
    # other thread or the core's workers run on the other core costs the reader wall time
    # (the kernel samples every running thread): on the 2-core VM at load 7, 0.3 ms a read,
    # 2.8 s of the odometry's 17 s over 3000 Intel scans (at other times a few µs).
    return time.perf_counter(), time.thread_time()


@dataclass
class MappingTiming:
    """Seconds spent per stage, summed over the run: wall clock, and the CPU time of the
    thread that ran the stage (:func:`run_mapping` runs the odometry and the graph on two
    threads; the core's worker threads, which the loop search's matching uses, are not
    counted: the process's CPU time over a run is the figure for the whole)."""

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
    #: The most wall time one node's loop search (candidates and matching) took (s): what
    #: the loop search's per-node budget (``max_candidates`` windows sized by the graph, at
    #: most one wide window per ``LoopSettings.wide_spacing`` metres) comes to.
    loop_search_max: float = 0.0

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
class Tracked:
    """One scan after the odometry (:meth:`Mapper.track`), before the graph
    (:meth:`Mapper.integrate`)."""

    index: int
    points: FloatArray
    #: ``T_odom_scan`` (``None``: skipped before any scan was aligned).
    pose: SE2 | None
    #: The odometry's covariance of the scan (``None``: too few points, skipped).
    covariance: FloatArray | None
    #: How the scan was deskewed before it came in (``Mapper.track``'s ``deskewed_with``).
    sweep: DeskewedSweep | None = None


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
    #: ``None`` for a finished run; otherwise why this is a partial result (an interrupted
    #: run, a checkpoint): the poses are the graph's at that moment, with no final pass.
    partial: str | None = None
    #: Scans whose odometry registration its verdict rejected (2D): their poses are the
    #: odometry's best guess (a corridor's axis held to the wheels, a start kept where the
    #: refinement ran off), unconfirmed by the scan alone.
    rejected: tuple[int, ...] = ()
    #: Scans whose odometry pose the wheels alone placed along a direction the scan left open
    #: (2D, :attr:`~scanreg.pipeline.Frame2D.held_directions`: a bare corridor's axis); the
    #: scan confirms them across it only. Wheels that stall or slip there go unseen.
    held: tuple[int, ...] = ()
    #: Scans where the odometry had lost its map and went on from its best guess (2D,
    #: :attr:`~scanreg.pipeline.Frame2D.map_reseeded`): the map is unconfirmed there.
    reseeded: tuple[int, ...] = ()

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
    ...     mapper.step(points, prior=prior, stamp=stamp)   # as Mapper3D.step
    >>> result = mapper.finish()
    >>> result.poses, result.loops, result.graph
    """

    def __init__(self, config: MappingConfig | None = None) -> None:
        cfg = MappingConfig() if config is None else config
        if not isinstance(cfg, MappingConfig):
            raise TypeError(f"config: expected MappingConfig, got {type(cfg).__name__}")
        self.config = cfg
        odometry = cfg.odometry
        if cfg.motion_cost is not None and cfg.wheel is None:
            odometry = dataclasses.replace(odometry, prior_covariance_use="search")
        self._odometry = Odometry2D(odometry)
        self._wheels = None if cfg.wheel is None else WheelOdometry(cfg.wheel)
        # The motion cost's wheels, their distance scale learned as the wheel prior's is.
        self._cost_wheels = (
            None
            if cfg.motion_cost is None or cfg.wheel is not None
            else WheelOdometry(cfg.motion_cost)
        )
        self._graph = Graph(2)
        self._odom_poses: list[SE2 | None] = []
        # Each scan's wheel increment T_prev_curr (None where there was none) and whether its
        # pose is its own registration's (not carried over a skipped scan): the final pass's
        # material (scanreg.pipeline.smoothing).
        self._scan_wheel: list[SE2 | None] = []
        self._scanned: list[bool] = []
        self._stamps: list[float | None] = []
        self._scan_node: list[int] = []  # node each scan hangs from (-1 before the first)
        self._node_scans: list[int] = []
        self._node_points: dict[int, FloatArray] = {}
        self._node_odom: dict[int, SE2] = {}
        self._node_cov: dict[int, FloatArray] = {}  # odometry covariance of each node's scan
        self._node_blind: dict[int, tuple[float, float]] = {}  # bearing gap: start, width
        self._node_sweep: dict[int, DeskewedSweep] = {}  # how each node's scan was deskewed
        self._node_travel: list[float] = []  # path length at each node
        self._loop_links: dict[int, list[int]] = {}  # the nodes each has an accepted loop with
        self._submaps: OrderedDict[tuple[int, int, int], Submap2D] = OrderedDict()  # anchor, lo, hi
        self._submap_bytes = 0
        self._loops: list[LoopRecord[LoopMatch]] = []
        # Loops held as hypotheses (good on their own evidence, at odds with the graph).
        self._held: list[LoopRecord[LoopMatch]] = []
        # Path length (m) at the last node that closed a loop, and at the last wide search.
        self._last_closed = -math.inf
        self._last_wide = -math.inf
        self._skipped: list[int] = []
        self._rejected: list[int] = []  # scans whose odometry verdict rejected them
        self._held_scans: list[int] = []  # scans held to the wheels along a direction
        self._reseeded: list[int] = []  # scans where the odometry's map was left behind
        self._pending = SE2.identity()  # motion prior accumulated over skipped scans
        self._timed_stamp: float | None = None  # the last stamp a deskewed scan had
        self._last_pose: SE2 | None = None
        self._timing = MappingTiming()
        self._finished = False
        self._step_noise: StepNoise | None = None

    @property
    def graph(self) -> Graph:
        return self._graph

    @property
    def num_nodes(self) -> int:
        return len(self._node_scans)

    @property
    def loops(self) -> tuple[LoopRecord[LoopMatch], ...]:
        return tuple(self._loops)

    @property
    def wheel_scale(self) -> float:
        """The wheels' distance scale learned so far (1 without a wheel model)."""
        wheels = self._wheels if self._wheels is not None else self._cost_wheels
        return 1.0 if wheels is None else wheels.scale

    # -- per scan ------------------------------------------------------------------------
    def step(
        self,
        points: Any,
        timestamps: Any = None,
        prior: Any = None,
        *,
        stamp: float | None = None,
    ) -> MappingStep:
        """Add one scan; the signature of :meth:`scanreg.pipeline.Mapper3D.step`.

        ``points``: ``(N, 2)`` in the scan's own frame. ``timestamps``: ``(N,)`` each point's
        time on the clock of ``stamp`` (a ``sensor_msgs/LaserScan``'s stamp plus ``k ·
        time_increment``), or ``None`` (the scan taken as instantaneous): with them the scan
        is deskewed to ``stamp`` under the predicted motion (:meth:`Odometry2D.step`), and
        the node keeps the deskewed scan; ``stamp`` is then required (a stamp earlier than
        the last deskewed scan's, as in a corrupted log, gives no interval: that scan is
        taken as instantaneous).
        ``prior``: ``T_prev_curr`` from wheel odometry (or ``None``). ``stamp``: the scan's
        time (without ``timestamps`` it may step backwards: it is only recorded).

        The same as ``integrate(track(points, timestamps, prior, stamp=stamp))``."""
        return self.integrate(self.track(points, timestamps, prior, stamp=stamp))

    def track(
        self,
        points: Any,
        timestamps: Any = None,
        prior: Any = None,
        *,
        stamp: float | None = None,
        deskewed_with: tuple[Any, ...] | None = None,
    ) -> Tracked:
        """The front end of :meth:`step`: the scan's odometry (arguments as there).

        ``deskewed_with``: ``(fractions, increment[, previous])`` for a scan already deskewed
        with the wheels' ``increment`` (``T_prev_curr`` as reported) over an interval at a
        constant rate, each point measured at ``fractions`` (``(N,)``) of it, ``previous``
        the interval before's motion at its rate over this one (or None;
        :meth:`scanreg.io.ScanLog.deskew_motion`, as :func:`run_mapping` passes it): its
        loops' covariances then cover what the deskew left
        (:mod:`scanreg.pipeline.sweep_residual`); ignored without a wheel noise model.

        :meth:`track` touches only the odometry and :meth:`integrate` only the graph, so the
        two may run on two threads, the odometry of the next scans going on while the graph
        takes this one (:func:`run_mapping` does); each must be called in scan order."""
        if self._finished:
            raise RuntimeError("Mapper: finish() was called; start a new Mapper")
        t_start = _clock()
        pts = as_points(points, "points", dim=2, min_points=0)
        motion = None if prior is None else as_pose(prior, "prior", 2)
        if stamp is not None and not math.isfinite(float(stamp)):
            raise ValueError(f"stamp: must be finite, got {stamp!r}")
        # The odometry deskews (and checks the times and that stamps do not decrease).
        timed: dict[str, Any] = {}
        if timestamps is not None:
            if stamp is None:
                raise ValueError("stamp: required with timestamps (the time they deskew it to)")
            times = as_matrix(timestamps, "timestamps", (len(pts),))
            # A stamp out of order (a corrupted log) gives no interval: taken as instantaneous.
            if self._timed_stamp is None or float(stamp) >= self._timed_stamp:
                timed = {"timestamps": times, "stamp": float(stamp)}
        index = len(self._odom_poses)
        self._stamps.append(None if stamp is None else float(stamp))
        if motion is not None:
            self._pending = self._pending @ motion  # type: ignore[operator]

        if pts.shape[0] < 3:
            # No alignment possible: carry the pose on the accumulated prior (or hold it).
            self._skipped.append(index)
            pose = None if self._last_pose is None else self._last_pose @ self._pending
            self._odom_poses.append(pose)
            self._scan_wheel.append(motion)  # type: ignore[arg-type]
            self._scanned.append(False)
            self._timing.add("odometry", t_start)
            self._timing.add("total", t_start)
            return Tracked(index, pts, pose, None)

        first = self._last_pose is None
        wheel = None if first or prior is None else self._pending
        if wheel is not None and self._wheels is not None:
            scaled, cov = self._wheels.prior(wheel)
            frame = self._odometry.step(pts, prior=scaled, prior_covariance=cov, **timed)
            self._wheels.observe(wheel, frame.motion, constrained=_well_constrained(frame))
        elif wheel is not None and self._cost_wheels is not None:
            # The wheels' step (rescaled) both predicts and, with its covariance, ranks the
            # correlative candidates; the scan alone refines and is judged.
            scaled, cost = self._cost_wheels.prior(wheel)
            frame = self._odometry.step(pts, prior=scaled, prior_covariance=cost, **timed)
            self._cost_wheels.observe(wheel, frame.motion, constrained=_well_constrained(frame))
        else:
            frame = self._odometry.step(pts, prior=wheel, **timed)
        if timed:
            self._timed_stamp = timed["stamp"]
        if not frame.verdict.accepted:
            self._rejected.append(index)
        if frame.held_directions:
            self._held_scans.append(index)
        if frame.map_reseeded:
            self._reseeded.append(index)
        self._pending = SE2.identity()
        if self._last_pose is None:
            pose = frame.pose
        else:
            pose = (self._last_pose @ frame.motion).orthonormalized()
        assert isinstance(pose, SE2)
        self._last_pose = pose
        self._odom_poses.append(pose)
        self._scan_wheel.append(motion)  # type: ignore[arg-type]
        self._scanned.append(True)
        self._timing.add("odometry", t_start)
        self._timing.add("total", t_start)
        kept = pts if frame.deskewed is None else frame.deskewed  # (a node keeps it deskewed)
        return Tracked(
            index, kept, pose, frame.covariance, self._deskewed_sweep(deskewed_with, pts)
        )

    # -- the odometry's record, for a Mapper that integrates what another one tracked ---
    #: What :meth:`track` appends to, one entry (or none) per scan; :meth:`integrate`,
    #: :meth:`snapshot` and :meth:`finish` read them.
    _ODOMETRY_RECORD = (
        "_stamps",
        "_skipped",
        "_odom_poses",
        "_scan_wheel",
        "_scanned",
        "_rejected",
        "_held_scans",
        "_reseeded",
    )
    #: The time :meth:`track` adds to (:class:`MappingTiming` fields).
    _ODOMETRY_TIME = ("odometry", "odometry_cpu", "total", "total_cpu")

    def odometry_mark(self) -> tuple[tuple[int, ...], tuple[float, ...]]:
        """Where the odometry's record and time stand (for :meth:`odometry_since`)."""
        return (
            tuple(len(getattr(self, name)) for name in self._ODOMETRY_RECORD),
            tuple(getattr(self._timing, name) for name in self._ODOMETRY_TIME),
        )

    def odometry_since(
        self, mark: tuple[tuple[int, ...], tuple[float, ...]]
    ) -> tuple[tuple[list[Any], ...], tuple[float, ...]]:
        """What :meth:`track` recorded since ``mark``, and the time it took: for another
        Mapper to :meth:`adopt_odometry` before it integrates the same :class:`Tracked`
        (:mod:`scanreg.pipeline.odometry_process`)."""
        lengths, seconds = _checked_mark(mark, len(self._ODOMETRY_RECORD), self._ODOMETRY_TIME)
        lists = tuple(
            getattr(self, name)[start:]
            for name, start in zip(self._ODOMETRY_RECORD, lengths, strict=True)
        )
        spent = tuple(
            getattr(self._timing, name) - before
            for name, before in zip(self._ODOMETRY_TIME, seconds, strict=True)
        )
        return lists, spent

    def adopt_odometry(self, record: tuple[tuple[list[Any], ...], tuple[float, ...]]) -> None:
        """Record what another Mapper's :meth:`track` recorded, and its time
        (:meth:`odometry_since`)."""
        lists, spent = _checked_record(record, len(self._ODOMETRY_RECORD), self._ODOMETRY_TIME)
        for name, entries in zip(self._ODOMETRY_RECORD, lists, strict=True):
            getattr(self, name).extend(entries)
        for name, seconds in zip(self._ODOMETRY_TIME, spent, strict=True):
            setattr(self._timing, name, getattr(self._timing, name) + float(seconds))

    def odometry_end(self) -> dict[str, Any]:
        """After the last :meth:`track`: the wheels as calibrated."""
        return {"wheels": self._wheels, "cost_wheels": self._cost_wheels}

    def adopt_odometry_end(self, end: dict[str, Any]) -> None:
        """Take another Mapper's :meth:`odometry_end`."""
        if not (isinstance(end, dict) and set(end) == {"wheels", "cost_wheels"}):
            raise ValueError("end: expected what Mapper.odometry_end returns")
        for name in ("wheels", "cost_wheels"):
            if end[name] is not None and not isinstance(end[name], WheelOdometry):
                raise TypeError(f"end[{name!r}]: expected WheelOdometry or None")
        self._wheels, self._cost_wheels = end["wheels"], end["cost_wheels"]

    def _deskewed_sweep(self, deskewed_with: Any, pts: FloatArray) -> DeskewedSweep | None:
        """``deskewed_with`` (:meth:`step`) with its increment's error: the wheels' noise
        model as calibrated so far, and the rate's change from the previous interval
        (:func:`~scanreg.pipeline.sweep_residual.deskew_error`); None without a model."""
        wheels = self._wheels if self._wheels is not None else self._cost_wheels
        if deskewed_with is None or wheels is None:
            return None
        if not (isinstance(deskewed_with, tuple) and len(deskewed_with) in (2, 3)):
            raise TypeError(
                "deskewed_with: expected (fractions, increment[, previous]), got "
                f"{deskewed_with!r:.60}"
            )
        fractions = as_matrix(deskewed_with[0], "deskewed_with fractions", (len(pts),))
        increment = as_pose(deskewed_with[1], "deskewed_with increment", 2)
        before = deskewed_with[2] if len(deskewed_with) == 3 else None
        if before is not None:
            before = as_pose(before, "deskewed_with previous", 2)
        assert isinstance(increment, SE2) and (before is None or isinstance(before, SE2))
        cov = deskew_error(increment, before, wheels.covariance(increment))
        return DeskewedSweep(np.ascontiguousarray(fractions), cov)

    def integrate(self, tracked: Tracked) -> MappingStep:
        """The back end of :meth:`step`: ``tracked`` (from :meth:`track`) becomes a node when
        it has moved far enough, and a node looks for loops."""
        if not isinstance(tracked, Tracked):
            raise TypeError(f"tracked: expected Tracked (Mapper.track), got {type(tracked)}")
        if tracked.index != len(self._scan_node):
            raise ValueError(
                f"tracked: scan {tracked.index} out of order (expected {len(self._scan_node)})"
            )
        t_start = _clock()
        if tracked.covariance is None:
            self._scan_node.append(self.num_nodes - 1)
            self._timing.add("total", t_start)
            return MappingStep(tracked.index, tracked.pose, None, ())
        assert tracked.pose is not None
        node = self._maybe_add_node(
            tracked.index, tracked.points, tracked.pose, tracked.covariance, tracked.sweep
        )
        self._scan_node.append(self.num_nodes - 1)
        records: tuple[LoopRecord[LoopMatch], ...] = ()
        if node is not None:
            records = self._close_loops(node)
        self._timing.add("total", t_start)
        return MappingStep(tracked.index, tracked.pose, node, records)

    def _maybe_add_node(
        self,
        index: int,
        pts: FloatArray,
        pose: SE2,
        covariance: FloatArray,
        sweep: DeskewedSweep | None = None,
    ) -> int | None:
        cfg = self.config
        g = self._graph
        if self._node_scans:
            rel = self._node_odom[self.num_nodes - 1].inverse() @ pose
            dist = float(np.linalg.norm(rel.translation))
            if not is_new_node(dist, rel.angle, cfg):
                return None
        node = self.num_nodes
        kept = pts
        if cfg.node_voxel_size > 0:
            grid = voxel_downsample(pts, cfg.node_voxel_size)
            kept = np.ascontiguousarray(grid.points)
            if sweep is not None:  # (a voxel's time: its first point's)
                sweep = DeskewedSweep(sweep.fractions[grid.indices], sweep.covariance)
        if sweep is not None:
            self._node_sweep[node] = sweep
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
            cov = odometry_edge_covariance(dist, covariance, cfg, 2)
            g.add_edge(prev, node, rel, np.linalg.inv(cov))
        g.update()
        self._timing.add("optimization", t0)
        return node

    def _submap(self, anchor: int, before: int, half_size: int | None = None) -> Submap2D:
        """Nodes ``anchor ± half_size`` (default ``submap_half_size``), none from ``before``
        on: a submap must not hold the searching node's recent past (matched against its own
        last metres, a scan "closes" a loop that says nothing)."""
        h = self.config.submap_half_size if half_size is None else half_size
        return self._submap_of(anchor, anchor - h, anchor + h, before)

    def _submap_of(self, anchor: int, lo: int, hi: int, before: int) -> Submap2D:
        """Nodes ``lo … hi`` that exist before ``before``, in ``anchor``'s frame; cached."""
        key = (anchor, lo, hi)
        sub = self._submaps.get(key)
        if sub is not None:
            self._submaps.move_to_end(key)
        else:
            nodes = [n for n in range(lo, hi + 1) if 0 <= n < before]
            sub = build_submap(
                anchor,
                nodes,
                self._node_points,
                self._node_odom,
                resolution=self.config.loops.resolution,
                voxel_size=self.config.node_voxel_size,
                covariances=self._node_cov,
                sweeps=self._node_sweep,
            )
            # Only cache a submap whose later nodes all exist and were all taken (it will
            # not change).
            if hi < before:
                self._submaps[key] = sub
                self._submap_bytes += _submap_bytes(sub)
                # Least recently searched out first: a long-range laser's submap grids are
                # ~100 MB each (an 80 m disc at 5 cm cells), and the hospital log's run grew
                # to 20 GB with every searched submap kept.
                while self._submap_bytes > SUBMAP_CACHE_BYTES and len(self._submaps) > 1:
                    _, old = self._submaps.popitem(last=False)
                    self._submap_bytes -= _submap_bytes(old)
        return sub

    def _wide_submap(
        self,
        anchor: int,
        node: int,
        before: int,
        *,
        here: FloatArray | None = None,
        margin: float = 0.0,
    ) -> Submap2D:
        """The wide search's submap around ``anchor``: nodes ``anchor ± wide_submap_half_size``,
        grown along the anchor's own pass (consecutive nodes, whose odometry poses agree with
        each other) while the next node lies within ``wide_submap_radius`` of where the graph
        puts ``node``, up to ``wide_submap_max_half_size`` a side; none from ``before`` on. A
        scan that passes the place the other way sees what lay behind the earlier pass."""
        _, rows = self._graph.pose_vectors()
        at = rows[node, :2] if here is None else here
        lo, hi = wide_submap_span(anchor, rows[:before, :2], at, self.config.loops, margin=margin)
        return self._submap_of(anchor, lo, hi, before)

    def _candidates(
        self, node: int, *, reach: float | None = None, limit: int | None = None
    ) -> list[tuple[float, int]]:
        """Earlier nodes to match ``node`` against, nearest (by the graph) first.

        Default: within ``loop_max_range``, or beyond it within ``loop_gate_sigmas`` σ of
        the graph's uncertainty, at most ``max_candidates``. With ``reach``: every old node
        predicted within ``reach`` m, whatever the graph's uncertainty (the wide search),
        at most ``limit``."""
        cfg = self.config
        g = self._graph
        num_old = self._num_old(node)
        if num_old == 0:
            return []
        _, rows = g.pose_vectors()
        old, here = rows[:num_old], rows[node]
        # T_n_c translation = R_nᵀ (t_c − t_n): only its length is needed here.
        d = np.linalg.norm(here[:2] - old[:, :2], axis=1)
        fixed = reach is not None
        if reach is None:
            # A cheap, generous first gate: the new node's own marginal spread (the first
            # node is anchored) bounds the relative one up to their correlation.
            cov_here = g.marginal_covariance(node)
            spread = math.sqrt(max(float(np.linalg.eigvalsh(cov_here[:2, :2])[-1]), 0.0))
            reach = cfg.loop_max_range + cfg.loop_gate_sigmas * spread
        limit = cfg.max_candidates if limit is None else limit
        near = np.flatnonzero(d <= reach)
        order = near[np.argsort(d[near], kind="stable")]
        gated: list[tuple[float, int]] = []
        # Each test beyond the range costs a joint marginal (milliseconds on a large graph):
        # a few per node, nearest first (a drifting graph's marginals let hundreds in).
        tests = [_GATE_TESTS_PER_CANDIDATE * limit]  # shared with _seen_first, which reads it
        for n in self._seen_first(node, here, old, order, d, fixed, tests):
            if len(gated) >= limit:
                break
            dist = float(d[n])
            if fixed or dist <= cfg.loop_max_range:
                gated.append((dist, int(n)))
                continue
            if tests[0] == 0:
                continue
            tests[0] -= 1
            # Beyond the range: a Mahalanobis test on the relative pose's joint marginal.
            cov = g.relative_covariance(int(n), node)
            c, s = math.cos(old[n, 2]), math.sin(old[n, 2])
            t_rel = np.array([[c, s], [-s, c]]) @ (here[:2] - old[n, :2])
            u = t_rel / max(dist, 1e-12)
            sigma = math.sqrt(max(float(u @ cov[:2, :2] @ u), 1e-12))
            if (dist - cfg.loop_max_range) / sigma <= cfg.loop_gate_sigmas:
                gated.append((dist, int(n)))
        return gated

    def _num_old(self, node: int) -> int:
        """How many nodes come before ``node``'s recent past (its last ``loop_min_travel``
        metres of path): the ones a loop from it may close to."""
        travel = self._node_travel
        return bisect.bisect_left(travel, travel[node] - self.config.loop_min_travel)

    def _seen_first(
        self,
        node: int,
        here: FloatArray,
        old: FloatArray,
        order: np.ndarray,
        d: FloatArray,
        fixed: bool,
        tests_left: list[int],
    ) -> Iterator[int]:
        """``order`` (nearest first), but a node that could not have seen most of this scan
        from where the graph puts it (a 180° laser passing the same spot the other way) only
        after the others: its match is doomed and would take a candidate's place. Lazily: the
        visibility of the far nodes, which most searches never reach, is not computed; past
        ``loop_max_range`` with no gate test left (``tests_left[0]``, spent by the caller as
        it goes) no later node can be a candidate (unless ``fixed``), so the seen ones stop
        there and the deferred ones follow."""
        deferred = []
        for n in order:
            if not fixed and d[n] > self.config.loop_max_range and tests_left[0] == 0:
                break
            if self._visible(node, here, old[n], int(n)) >= 0.5:
                yield n
            else:
                deferred.append(n)
        yield from deferred

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
        t0 = _clock()
        try:
            candidates = self._candidates(node)
            self._timing.add("candidates", t0)
            return self._search_loops(node, candidates)
        except GraphSolveError as exc:
            # The graph's marginals could not be computed at this node: no loop search here
            # (the run goes on; the summary lists it among the back end's recoveries).
            self._graph.recoveries.append(f"node {node}: loop search skipped: {exc}")
            return ()
        finally:
            spent = _clock()[0] - t0[0]
            self._timing.loop_search_max = max(self._timing.loop_search_max, spent)

    def _search_loops(
        self, node: int, candidates: list[tuple[float, int]]
    ) -> tuple[LoopRecord[LoopMatch], ...]:
        records: list[LoopRecord[LoopMatch]] = []
        try:
            self._search_into(records, node, candidates)
        finally:
            # Whatever was matched is recorded, even if the back end stopped the search.
            self._loops.extend(records)
        return tuple(records)

    def _search_into(
        self, records: list[LoopRecord[LoopMatch]], node: int, candidates: list[tuple[float, int]]
    ) -> None:
        cfg = self.config
        searched = (0.0, 0.0)
        for _, n in candidates:
            record, window = self._match(n, node, None)
            searched = (max(searched[0], window[0]), max(searched[1], window[1]))
            records.append(record)
        travel = self._node_travel[node]
        if any(r.accepted for r in records):
            self._last_closed = travel
        # A held loop says where this node is, if it is true: look there (see _guided).
        if not any(r.accepted for r in records):
            records.extend(self._guided(node))
            if any(r.accepted for r in records):
                self._last_closed = travel
        # The drift-independent search: when the windows the graph's uncertainty sized have
        # found nothing for a while, the nearest candidate the scan could have seen is
        # searched over a fixed wide window (the graph may have drifted more than it knows).
        # Its cost is bounded: one search per ``wide_spacing`` metres of path at most.
        wide = cfg.loops.wide_window
        spacing = cfg.loops.wide_spacing
        if (
            travel - self._last_closed >= spacing
            and travel - self._last_wide >= spacing
            and (searched[0] < wide[0] or searched[1] < wide[1])
        ):
            far = self._candidates(node, reach=cfg.loop_max_range + wide[0], limit=1)
            for _, n in far:
                self._last_wide = travel
                # No wider than the drift the path between the two could hold: a candidate
                # just past loop_min_travel along the same corridor is not metres off, and a
                # window that lets it be finds the corridor's look-alikes (the hospital log,
                # windows grown with the path since the last loop: pairs of hypotheses 13
                # nodes apart, 1-4 m along the corridor, agreeing with each other and
                # accepted). Searched over a larger submap than the usual search's (a revisit
                # from another heading sees little of a few nodes' points), measured against
                # the usual one.
                between = travel - self._node_travel[n]
                half = min(wide[0], cfg.loops.min_window[0] + MAX_DRIFT_PER_METRE * between)
                record, _ = self._match(n, node, (half, wide[1]), wide_submap=True, margin=half)
                records.append(record)
                if record.accepted:
                    self._last_closed = travel

    def _guided(self, node: int) -> list[LoopRecord[LoopMatch]]:
        """Matches of ``node`` where the held loops put it.

        A held loop ``T_a_n`` (:meth:`_hypothesize`) and the graph's short leg ``n → node``
        predict ``node``'s pose in ``a``'s frame whatever the graph's drift; the old node
        nearest that prediction is searched around it over the least loop window (in the
        wide search's grown submap, as the held loop was found). A true loop's successors
        lie where it says, and their matches agree with it (:func:`loops_agree`): held the
        same way, they confirm it. Without this, a held loop waited for another wide search
        (one per ``wide_spacing`` m, around the graph's wrong prediction) to find a partner
        within ``hypothesis_horizon``: the Freiburg hospital's return to its start, 13-20 m
        off after 1 km, was found by the wide search twice, 330 scans apart, and never
        confirmed. At most ``_GUIDED_PER_NODE`` held loops (the latest) guide a node."""
        cfg = self.config
        travel = self._node_travel
        horizon = cfg.loops.hypothesis_horizon
        num_old = self._num_old(node)
        guides = [
            h
            for h in self._held
            if h.match.node != node
            and travel[node] - travel[h.match.node] <= horizon
            and not h.match.degenerate_directions
        ][-_GUIDED_PER_NODE:]
        if not guides or num_old == 0:
            return []
        g = self._graph
        _, rows = g.pose_vectors()
        records: list[LoopRecord[LoopMatch]] = []
        tried: set[int] = set()
        for h in reversed(guides):
            a, n = h.match.submap_node, h.match.node
            # T_a_node under the held loop, and where that puts node among the old ones.
            in_a = h.match.measured @ (g.pose(n).inverse() @ g.pose(node))  # type: ignore[operator]
            world = g.pose(a) @ in_a  # type: ignore[operator]
            assert isinstance(world, SE2)
            xy = np.asarray(world.translation)
            d = np.linalg.norm(rows[:num_old, :2] - xy, axis=1)
            c = int(np.argmin(d))
            if d[c] > cfg.loop_max_range or c in tried:
                continue
            tried.add(c)
            predicted = g.pose(c).inverse() @ world  # type: ignore[operator]
            assert isinstance(predicted, SE2)
            record = self._guided_match(c, node, predicted, world)
            records.append(record)
            if record.accepted:
                break
        return records

    def _guided_match(self, c: int, node: int, predicted: SE2, world: SE2) -> LoopRecord[LoopMatch]:
        """Match ``node`` against ``c`` around ``predicted`` (a held loop's) over the least
        loop window; the match, if its own evidence is good, is held with the others
        (:meth:`_hypothesize`) and closes with the loop that guided it when the two agree."""
        cfg = self.config
        t_m = _clock()
        before = self._num_old(node)
        window = cfg.loops.min_window
        # Its χ² is against the guiding loop's prediction: as far as loops_agree lets it be.
        tol = cfg.loops.agreement
        cov = np.diag([tol[0] ** 2, tol[0] ** 2, tol[1] ** 2])
        match = match_loop(
            self._node_points[node],
            node,
            self._submap(c, before),
            predicted,
            cov,
            cfg.loops,
            window=window,
            search_submap=self._wide_submap(c, node, before, here=world.translation),
            sweep=self._node_sweep.get(node),
        )
        self._timing.add("matching", t_m)
        match = dataclasses.replace(match, search="guided")
        good = match.accepted or match.hypothesis
        if not good or match.degenerate_directions or match.score < cfg.loops.hypothesis_min_score:
            # Never a loop of its own: its χ² was against the guiding loop's prediction.
            why = () if not good else (_GUIDED_UNSOUND,)
            match = dataclasses.replace(
                match, accepted=False, evidence="", reasons=(*match.reasons, *why)
            )
            return LoopRecord(match, self._node_scans[c], self._node_scans[node])
        held = dataclasses.replace(
            match, accepted=False, evidence="", hypothesis=True, reasons=(_GUIDED,)
        )
        return self._hypothesize(LoopRecord(held, self._node_scans[c], self._node_scans[node]))

    def _match(
        self,
        n: int,
        node: int,
        window: tuple[float, float] | None,
        *,
        wide_submap: bool = False,
        margin: float = 0.0,
    ) -> tuple[LoopRecord[LoopMatch], tuple[float, float]]:
        """Match ``node``'s scan against submap ``n``; close the loop, or hold it as a
        hypothesis (see :meth:`_hypothesize`). ``wide_submap``: the correlative search runs
        in the wide search's larger submap (:meth:`_wide_submap`); the match is measured
        against the usual submap, or the larger one when the usual one rejects it."""
        g = self._graph
        cfg = self.config
        t_m = _clock()
        predicted = g.pose(n).inverse() @ g.pose(node)  # type: ignore[operator]
        assert isinstance(predicted, SE2)
        rel_cov = g.relative_covariance(n, node)
        before = self._num_old(node)
        search = self._wide_submap(n, node, before, margin=margin) if wide_submap else None
        match = match_loop(
            self._node_points[node],
            node,
            self._submap(n, before),
            predicted,
            rel_cov,
            cfg.loops,
            window=window,
            search_submap=search,
            sweep=self._node_sweep.get(node),
            unchecked=wide_submap,
        )
        self._timing.add("matching", t_m)
        if wide_submap:
            match = dataclasses.replace(match, search="wide")
        record = LoopRecord(match, self._node_scans[n], self._node_scans[node])
        if match.accepted and wide_submap and not match.degenerate_directions:
            # The wide search's window is as wide as the drift could be, and the graph that
            # passed its χ² test may know too little to check it: the loop waits for another
            # loop to agree with it (Freiburg hospital: a lone one, 2 m and 27° off, bent the
            # map around it; every true one there had a partner within 20 m of path). A
            # degenerate one cannot wait (its look-alikes agree with each other); it carries
            # nothing along its weak directions.
            unchecked = dataclasses.replace(
                match, accepted=False, evidence="", hypothesis=True, reasons=(_UNCHECKED,)
            )
            record = self._hypothesize(dataclasses.replace(record, match=unchecked))
        elif match.accepted:
            (record,) = self._add_loops([record], kernel=cfg.loop_kernel)
        elif match.hypothesis:
            record = self._hypothesize(record)
        return record, match.window

    def _hypothesize(self, record: LoopRecord[LoopMatch]) -> LoopRecord[LoopMatch]:
        """Hold a loop the graph disagrees with (or one the wide search found, which the
        graph could not check); once ``loops.min_agreeing`` held loops from different nodes
        agree with each other (:func:`loops_agree`), close them all: the graph, not the loops,
        was wrong. A wide-search loop may also be confirmed by a loop accepted within the
        horizon. Returns ``record``, accepted if it completed a group."""
        cfg = self.config
        travel = self._node_travel
        here = record.match.node
        why = self._beyond_drift(record.match)
        if why is not None:
            return dataclasses.replace(record, match=_refused(record.match, why))
        # Only recent hypotheses: the leg between two nodes must be short to be trusted.
        horizon = cfg.loops.hypothesis_horizon
        self._held = [h for h in self._held if travel[here] - travel[h.match.node] <= horizon]
        support: list[LoopRecord[LoopMatch]] = []
        if record.match.reasons == (_UNCHECKED,):
            for r in reversed(self._loops):
                if travel[here] - travel[r.match.node] > horizon:
                    break
                if r.accepted:
                    support.append(r)
        group = agreeing_group(record, self._held, self._graph.pose, cfg.loops, support=support)
        if group is None:
            self._held.append(record)
            return record
        confirmed = [
            dataclasses.replace(
                h,
                match=dataclasses.replace(h.match, accepted=True, reasons=(), evidence="loops"),
            )
            for h in group
        ]
        held = {id(h) for h in group}
        self._held = [h for h in self._held if id(h) not in held]
        # No robust kernel: the graph disagrees with these loops by far more than their
        # covariance (that is why they were held), and a kernel would weigh them to nothing.
        # They have passed a stronger test than χ²: each other. Wide-search loops the graph
        # agreed with keep the usual kernel.
        graph_agreed = all(h.match.reasons == (_UNCHECKED,) for h in group)
        confirmed = self._add_loops(confirmed, kernel=cfg.loop_kernel if graph_agreed else None)
        if confirmed[0].accepted:
            # A correction of many σ: iSAM2's few relinearisations may not carry it through.
            self._graph.optimize()
        record_decided(self._loops, group[1:], confirmed[1:])
        return confirmed[0]

    def _beyond_drift(self, match: LoopMatch) -> str | None:
        """Why a held loop is refused, or None: it moves its node farther from where the graph
        puts it (relative to the submap's anchor) than the path between the two could have
        drifted — the least loop window plus ``MAX_DRIFT_PER_METRE`` of that path, taken
        through the loops already closed (:func:`~scanreg.pipeline.graph_path.path_between`):
        the bound the wide search's window has, where no loop shortens the path. MIT's
        infinite corridor: the wide search laid node 373's scan, looking down an unseen
        stretch, onto the known one 11.5 m back (score 0.86, no rival at 0.9 of it), 144 m
        of travel after its anchor 229 but 2.5 m of path and one loop (229 → 370) from it;
        the next node, searched where it put it, fitted the same look-alike, and the two
        agreed."""
        g = self._graph
        a, n = match.submap_node, match.node
        graph = g.pose(a).inverse() @ g.pose(n)  # type: ignore[operator]
        assert isinstance(graph, SE2)
        off = float(np.linalg.norm((graph.inverse() @ match.measured).translation))
        slack = self.config.loops.min_window[0]
        if off <= slack:
            return None
        limit = (off - slack) / MAX_DRIFT_PER_METRE
        # A loop on the route may be as far off as the widest window the graph's search
        # accepts one in (``max_window``): it counts as the path that drifts that much. A
        # false loop shortens the path too: counted as the least window (0.5 m), it held
        # a no-odometry room tour (seed 1) to a 1.4 m error a right wide loop would have
        # undone (0.103 -> 0.130 m ATE), and csail to 0.9 m (0.104 -> 0.160 m).
        hop = self.config.loops.max_window[0] / MAX_DRIFT_PER_METRE
        path = path_between(self._node_travel, self._loop_links, n, a, hop=hop, limit=limit)
        if path >= limit:
            return None
        return (
            f"moves the node {off:.1f} m from the graph's pose, more than {path:.1f} m of path "
            "through the closed loops could have drifted"
        )

    def _add_loops(
        self, records: list[LoopRecord[LoopMatch]], *, kernel: Kernel | None
    ) -> list[LoopRecord[LoopMatch]]:
        """Add the loops' edges and re-solve; returns the records, rejected with the back
        end's reason when the graph could not be solved with them (their edges dropped)."""
        g = self._graph
        t_o = _clock()
        for r in records:
            m = r.match
            g.add_edge(m.submap_node, m.node, m.measured, m.information, kind="loop", kernel=kernel)
        try:
            # A loop moves many nodes at once: relinearise a little more than usual.
            g.update(extra_iterations=2)
            for r in records:
                self._loop_links.setdefault(r.match.submap_node, []).append(r.match.node)
                self._loop_links.setdefault(r.match.node, []).append(r.match.submap_node)
        except GraphSolveError as exc:
            g.remove_last_edges(len(records))
            g.optimize()
            reason = f"back end could not solve with it (edge dropped): {exc}"
            records = [
                dataclasses.replace(
                    r,
                    match=dataclasses.replace(
                        r.match, accepted=False, evidence="", reasons=(*r.match.reasons, reason)
                    ),
                )
                for r in records
            ]
        self._timing.add("optimization", t_o)
        return records

    # -- end of run ----------------------------------------------------------------------
    def finish(self) -> MappingResult[SE2]:
        """Batch-optimize (unless ``config.batch`` is off), re-solve the scans between the nodes
        (``config.smooth_scans``) and return every scan's pose."""
        if self._finished:
            raise RuntimeError("Mapper: finish() was already called")
        if not self._node_scans:
            raise ValueError("scans: no scan had at least 3 points; nothing was mapped")
        if len(self._scan_node) != len(self._odom_poses):
            raise RuntimeError(
                f"Mapper: {len(self._odom_poses) - len(self._scan_node)} tracked scans were "
                "never integrated"
            )
        self._finished = True
        g = self._graph
        if self.config.batch:
            t0 = _clock()
            g.optimize()
            self._timing.add("optimization", t0)
            self._timing.add("total", t0)
        # The map's frame is its first node's odometry pose, exactly (Graph.move_gauge).
        g.move_gauge(0, self._node_odom[0])
        return self._result(smooth=self.config.smooth_scans)

    def snapshot(self, reason: str) -> MappingResult[SE2]:
        """What is mapped so far, as the graph has it now (no batch pass, no final pass over
        the scans): a checkpoint, or what an interrupted run leaves. The mapper goes on
        unchanged. ``reason`` becomes :attr:`MappingResult.partial`."""
        if not self._node_scans:
            raise ValueError("scans: no scan had at least 3 points; nothing was mapped")
        return dataclasses.replace(self._result(smooth=False), partial=str(reason))

    def _result(self, *, smooth: bool) -> MappingResult[SE2]:
        g = self._graph
        node_poses = g.poses()
        poses: list[SE2] = []
        odometry: list[SE2] = []
        first_pose = self._node_odom[0]
        # The scans the graph has taken (the odometry may have run ahead of it).
        num_scans = len(self._scan_node)
        for k, odo in enumerate(self._odom_poses[:num_scans]):
            n = max(self._scan_node[k], 0)
            base = node_poses[n]
            if odo is None:  # skipped before any aligned scan: at the first node
                odo = first_pose
            odometry.append(odo)
            rel = self._node_odom[n].inverse() @ odo
            pose = base @ rel  # type: ignore[operator]
            assert isinstance(pose, SE2)
            poses.append(pose)
        if smooth:
            t0 = _clock()
            poses = self._smoothed(poses, odometry)
            self._timing.add("optimization", t0)
            self._timing.add("total", t0)
        return MappingResult(
            poses=tuple(poses),
            odometry_poses=tuple(odometry),
            stamps=tuple(self._stamps[:num_scans]),
            node_scans=tuple(self._node_scans),
            loops=tuple(self._loops),
            skipped=tuple(k for k in self._skipped if k < num_scans),
            rejected=tuple(k for k in self._rejected if k < num_scans),
            held=tuple(k for k in self._held_scans if k < num_scans),
            reseeded=tuple(k for k in self._reseeded if k < num_scans),
            node_points=tuple(self._node_points[n] for n in range(self.num_nodes)),
            graph=g,
            timing=dataclasses.replace(self._timing),
            num_scans=num_scans,
        )

    def _smoothed(self, poses: list[SE2], odometry: list[SE2]) -> list[SE2]:
        """The final pass (:mod:`scanreg.pipeline.smoothing`): ``poses`` unchanged without
        enough wheel steps to identify the step noise."""
        scanned = self._scanned
        steps: list[SE2 | None] = [None]
        for k in range(1, len(odometry)):
            both = scanned[k] and scanned[k - 1]
            steps.append(odometry[k - 1].inverse() @ odometry[k] if both else None)
        wheels: list[SE2 | None] = [None, *self._scan_wheel[1:]]
        noise = identify_step_noise(steps, wheels)
        if noise is None:
            return poses
        self._step_noise = noise
        cfg = self.config
        # A node is held as firmly as the graph's odometry edges' floor: the graph knows it no
        # better against its neighbours (ACES 0.0352 m held at 1 mm, 0.0348 m at the floor).
        hold = (cfg.drift_floor_translation, cfg.drift_floor_rotation)
        return smooth_scan_poses(poses, odometry, scanned, wheels, self._node_scans, noise, hold)

    @property
    def step_noise(self) -> StepNoise | None:
        """The step noise the final pass identified (``None`` before :meth:`finish`, or when
        it was skipped)."""
        return self._step_noise

    def node_points(self, node: int) -> FloatArray:
        """The kept (downsampled) scan of ``node``, in its own frame."""
        return self._node_points[node]


def _well_constrained(frame: Any) -> bool:
    """Whether a frame's step can calibrate the wheels: registered, accepted, and held along
    no direction nor named degenerate in any (its motion is the scans' alone)."""
    return bool(
        frame.registration is not None
        and frame.verdict.accepted
        and not frame.held_directions
        and not frame.degenerate
    )


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


def scan_odometry(
    log: CarmenLog,
    indices: Sequence[int],
    *,
    latency: float | None = 0.0,
    min_range: float = 0.1,
    max_range: float = 40.0,
) -> list[SE2 | None]:
    """The wheel odometry ``T_odom_robot`` of each scan ``log.scans[i]``, ``i`` in ``indices``,
    at the scan's own time (:func:`~scanreg.pipeline.odometry_timing.odometry_at_scans`, as
    for a bag).

    A CARMEN laser message carries, as its odometry fields, the last ``ODOM`` message the
    logger had received. When those are stale — by a median of more than
    :data:`~scanreg.pipeline.odometry_timing.STALE_ODOMETRY` over the log (ACES: 0.02-0.25 s,
    median 0.08 s, or 3 cm at the robot's 0.4 m/s; Intel: 0.3 ms, synchronous) — the ``ODOM``
    stream is interpolated instead (linearly, the heading along the shorter arc) at the scan's
    time less ``latency`` (s: how long before its timestamp the scan was taken; ``None``:
    measured on the log by :func:`estimate_laser_latency` with the returns in ``[min_range,
    max_range]``, only when the odometry is stale; ACES: 0.07 s). A scan keeps its own
    fields when the log is synchronous, when no two ``ODOM`` messages at most 1 s apart
    bracket that time, or when its fields match no ``ODOM`` message (its lag is then
    unknown), and every scan keeps them when the log's stamps cannot place it in the stream
    (:attr:`~scanreg.io.CarmenLog.time_status` ``"coarse"`` or ``"all_zero"``). ``None`` for a
    scan without odometry.
    """
    return _scan_odometry(log, indices, latency, min_range, max_range)[0]


def _scan_odometry(
    log: CarmenLog,
    indices: Sequence[int],
    latency: float | None,
    min_range: float,
    max_range: float,
) -> tuple[list[SE2 | None], float | None]:
    """:func:`scan_odometry` and the latency it applied (None: the fields kept)."""
    scans = [log.scans[i] for i in indices]
    own = [s.odometry_se2 for s in scans]
    odom = log.odometry
    t_odom, p_odom = np.asarray(odom.timestamps), np.asarray(odom.poses)
    if log.time_status in ("coarse", "all_zero"):
        # Stamps that repeat or are all zero place no scan in the ODOM stream: each scan
        # keeps the fields the logger paired it with. (Radish's belgioioso and csail logs,
        # stamps truncated to 1e5 s: every scan interpolated at a handful of instants read
        # a standing robot over their 219 and 380 m.)
        return own, None
    message = {tuple(p): k for k, p in enumerate(p_odom.tolist())}
    lags = [
        s.timestamp - t_odom[message[tuple(s.odometry_pose.tolist())]]
        for s in scans
        if s.odometry_pose is not None and tuple(s.odometry_pose.tolist()) in message
    ]
    stamps = np.array([s.timestamp for s in scans], dtype=np.float64)
    return odometry_at_scans(
        own,
        lags,
        stamps,
        t_odom,
        p_odom,
        lambda k: scans[k].to_points(min_range, max_range),
        latency=latency,
    )


def estimate_laser_latency(
    log: CarmenLog,
    indices: Sequence[int],
    *,
    min_range: float = 0.1,
    max_range: float = 40.0,
    max_pairs: int = 400,
    max_latency: float = 0.3,
) -> float:
    """How long before its timestamp a laser scan ``log.scans[i]``, ``i`` in ``indices``, was
    taken, against the log's ``ODOM`` stream (s):
    :func:`~scanreg.pipeline.odometry_timing.measure_laser_latency` with the scans' returns
    in ``[min_range, max_range]`` (ACES: 0.07 s; ``0.0`` without an ``ODOM`` stream)."""
    scans = [log.scans[i] for i in indices]
    return measure_laser_latency(
        np.array([s.timestamp for s in scans], dtype=np.float64),
        lambda k: scans[k].to_points(min_range, max_range),
        np.asarray(log.odometry.timestamps),
        np.asarray(log.odometry.poses),
        max_pairs=max_pairs,
        max_latency=max_latency,
    )


#: The most memory the cache of prepared submaps may hold (bytes).
SUBMAP_CACHE_BYTES = 2 << 30


def _submap_bytes(sub: Submap2D) -> int:
    """About what a submap holds once searched: ~48 bytes a cell for its grid's layers and
    pooled levels (measured: 40-60 MB for a hospital submap of 1.0 M cells), and the points."""
    width, height = sub.grid.shape
    return 48 * width * height + 64 * len(sub.points)


#: Why a loop the wide search found waits (:meth:`Mapper._match`).
_UNCHECKED = "found by the wide search: waits for another loop to agree"

#: Why a match a held loop guided waits (:meth:`Mapper._guided`).
_GUIDED = "found where a held loop puts the node: waits for it to agree"

#: Why a match a held loop guided is dropped though it fits there.
_GUIDED_UNSOUND = "found where a held loop puts the node, but degenerate or weak: cannot agree"


def _refused(match: LoopMatch, why: str) -> LoopMatch:
    """``match`` neither accepted nor held, for ``why``."""
    return dataclasses.replace(
        match, accepted=False, hypothesis=False, evidence="", reasons=(*match.reasons, why)
    )


#: How many held loops guide one node's search (:meth:`Mapper._guided`), the latest first.
_GUIDED_PER_NODE = 2

#: Joint-marginal tests of candidates beyond ``loop_max_range``, per candidate wanted.
_GATE_TESTS_PER_CANDIDATE = 2


#: How many scans the odometry thread may run ahead of the graph (the results do not depend
#: on it: the two threads share nothing). Not more: 64 let the hospital's odometry go on
#: through its long loop searches (wall 79 against 89 s, load 3), but the two threads then
#: run side by side most of the time and each goes slower: process CPU +10 % on the hospital,
#: +19-24 % on Intel (its odometry's thread 38-42 against 31-34 s, no faster wall; load 7).
_TRACK_AHEAD = 4
#: :func:`run_mapping` runs the odometry in a child process for runs of at least this many
#: scans (starting it and handing it the log costs ~1-2 s).
PROCESS_MIN_SCANS = 1000


class MappingInterrupted(Exception):
    """A run stopped before its last scan, by Ctrl-C or an error, after mapping something:
    :attr:`partial` holds what was mapped so far (:meth:`Mapper.snapshot`), ``__cause__`` the
    ``KeyboardInterrupt`` or the error."""

    def __init__(self, message: str, partial: MappingResult[Any]) -> None:
        super().__init__(message)
        self.partial = partial


Checkpoint = Callable[[MappingResult[Any]], None]


def laser_mounting(log: CarmenLog, indices: Sequence[int]) -> SE2:
    """``T_robot_laser`` of a CARMEN log: the laser's pose in the robot's frame, from the
    laser and odometry poses each message carries (``ROBOTLASER1``: both; ``FLASER``: the same
    pose twice in the raw Freiburg logs, so the identity). The median over the scans that
    carry both; the identity when none does, or when the two poses do not differ by one fixed
    offset (a "corrected" log's laser pose is the corrected trajectory, not a mounting)."""
    rel = [
        SE2.from_vector(s.odometry_pose).inverse() @ SE2.from_vector(s.laser_pose)
        for s in (log.scans[i] for i in indices)
        if s.laser_pose is not None and s.odometry_pose is not None
    ]
    if not rel:
        return SE2.identity()
    vectors = np.array([r.as_vector() for r in rel])
    x, y = np.median(vectors[:, 0]), np.median(vectors[:, 1])
    angle = math.atan2(np.median(np.sin(vectors[:, 2])), np.median(np.cos(vectors[:, 2])))
    spread = np.abs(vectors - [x, y, angle])
    spread[:, 2] = np.abs(np.angle(np.exp(1j * spread[:, 2])))
    if np.percentile(spread, 95, axis=0).max() > 0.01:  # 1 cm or 0.6°: not one mounting
        return SE2.identity()
    if max(abs(x), abs(y), abs(angle)) < 1e-9:
        # Exactly the identity (a log's 1e-19 rad of rounding would move every point by as
        # much, and a correlative search's ties with it).
        return SE2.identity()
    return SE2.from_vector([float(x), float(y), angle])


def _checked_mark(
    mark: Any, num_lists: int, times: tuple[str, ...]
) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """``mark`` as :meth:`Mapper.odometry_mark` gives it, or ValueError / TypeError by name."""
    if not (isinstance(mark, tuple) and len(mark) == 2):
        raise TypeError("mark: expected what Mapper.odometry_mark returns (lengths, seconds)")
    lengths, seconds = mark
    if len(lengths) != num_lists or not all(isinstance(n, int) and n >= 0 for n in lengths):
        raise ValueError(f"mark: expected {num_lists} list lengths >= 0, got {lengths!r:.80}")
    if len(seconds) != len(times) or not all(math.isfinite(float(t)) for t in seconds):
        raise ValueError(f"mark: expected {len(times)} finite times, got {seconds!r:.80}")
    return tuple(lengths), tuple(float(t) for t in seconds)


def _checked_record(
    record: Any, num_lists: int, times: tuple[str, ...]
) -> tuple[tuple[list[Any], ...], tuple[float, ...]]:
    """``record`` as :meth:`Mapper.odometry_since` gives it, or ValueError / TypeError by
    name."""
    if not (isinstance(record, tuple) and len(record) == 2):
        raise TypeError("record: expected what Mapper.odometry_since returns (lists, seconds)")
    lists, spent = record
    if len(lists) != num_lists or not all(isinstance(x, list) for x in lists):
        raise ValueError(f"record: expected {num_lists} lists of entries")
    if len(spent) != len(times) or not all(
        math.isfinite(float(t)) and float(t) >= 0 for t in spent
    ):
        raise ValueError(f"record: expected {len(times)} finite times >= 0, got {spent!r:.80}")
    return tuple(lists), tuple(float(t) for t in spent)


def track_scan(mapper: Mapper, scans: ScanLog, config: MappingConfig, k: int) -> Tracked:
    """Scan ``k`` of ``scans`` through ``mapper``'s odometry (:meth:`Mapper.track`), as
    :func:`run_mapping` feeds it."""
    if not isinstance(scans, ScanLog):
        raise TypeError(f"scans: expected a ScanLog, got {type(scans).__name__}")
    cfg = config
    # In the base frame, as the wheel prior and the poses are (and the relations of a
    # benchmark: the hospital's laser sits 0.22 m ahead of the robot's centre).
    # A sweep with beam times (a LaserScan's time_increment) is undone by the wheels'
    # motion during it, else by the odometry's prediction (ScanLog.swept_points).
    points, times = scans.swept_points(k, cfg.min_range, cfg.max_range)
    undone = None if times is not None else scans.deskew_motion(k, cfg.min_range, cfg.max_range)
    return mapper.track(
        points,
        times,
        prior=scans.prior(k),
        stamp=float(scans.stamps[k]),
        deskewed_with=undone,
    )


def run_mapping(
    log: CarmenLog | ScanLog,
    config: MappingConfig | None = None,
    *,
    kind: str | None = None,
    max_scans: int | None = None,
    progress: bool = False,
    checkpoint: Checkpoint | None = None,
    checkpoint_every: int = 1000,
    odometry_process: bool | None = None,
) -> MappingResult[SE2]:
    """Map a run of 2D scans in recording order (its timestamps may step backwards; they are
    kept as written), with each scan's wheel-odometry motion as the prior.

    ``log``: a CARMEN log (the odometry at each scan's time, :func:`scan_odometry`; the
    laser's mounting, :func:`laser_mounting`) or a :class:`~scanreg.io.ScanLog` (a LaserScan
    bag: :func:`~scanreg.io.read_laserscan_bag`); both through
    :func:`~scanreg.pipeline.scan_source.scan_log`. The scans are mapped in the base frame,
    where the odometry is (the mounting applied to their points): the poses are
    ``T_world_base``. ``kind``: a CARMEN log's laser message kind (default ``FLASER`` if
    present, else the first kind in the log). ``progress``: a progress line on stderr
    (scans/s, loops accepted and rejected). ``checkpoint``: called with
    :meth:`Mapper.snapshot` every ``checkpoint_every`` scans (e.g. to write the outputs so far).
    ``odometry_process``: run the odometry in a child process beside the graph
    (:mod:`scanreg.pipeline.odometry_process`; the same result, to the bit, as on a second
    thread, without the two sharing one interpreter lock); ``None``: for runs of at least
    :data:`PROCESS_MIN_SCANS` scans where the platform allows it.

    Raises
    ------
    MappingInterrupted
        When Ctrl-C or an error stops the run before its last scan; it carries what was
        mapped so far (``None`` if nothing was) and chains the cause.
    """
    from .._progress import Progress
    from .scan_source import scan_log

    cfg = MappingConfig() if config is None else config
    _checked_checkpoint_every(checkpoint_every)
    if odometry_process is not None and not isinstance(odometry_process, bool):
        raise TypeError(
            f"odometry_process: expected True, False or None, got {type(odometry_process).__name__}"
        )
    scans = scan_log(
        log,
        kind=kind,
        max_scans=max_scans,
        latency=cfg.laser_latency,
        min_range=cfg.min_range,
        max_range=cfg.max_range,
    )
    mapper = Mapper(cfg)
    total = len(scans)
    bar = Progress(total, description="map", unit="scans", enabled=progress)

    if odometry_process is None:
        odometry_process = total >= PROCESS_MIN_SCANS and odometry_processes.available()
    front: _ThreadedOdometry | odometry_processes.OdometryProcess | None = None
    if odometry_process:
        try:
            front = odometry_processes.OdometryProcess(scans, cfg)
        except (OSError, odometry_processes.OdometryProcessError) as exc:
            warnings.warn(
                f"run_mapping: the odometry runs on a thread ({exc})", RuntimeWarning, stacklevel=2
            )
    if front is None:
        front = _ThreadedOdometry(mapper, scans, cfg)
    k = 0
    try:
        with bar:
            for k in range(total):
                step = mapper.integrate(front.next(mapper))
                _stepped(mapper, step, bar, 25, k, total, checkpoint, checkpoint_every)
        front.finish(mapper)
        return mapper.finish()
    except (KeyboardInterrupt, Exception) as exc:
        front.close()
        stopped = _stopped_run(mapper, exc, k, total)
        if stopped is None:
            raise
        raise stopped from exc


class _ThreadedOdometry:
    """The odometry of the next scans on a second thread while the caller's closes loops:
    the two share nothing (:meth:`Mapper.track` / :meth:`Mapper.integrate`), and both spend
    much of their time in the Rust core with the GIL released. The interface of
    :class:`~scanreg.pipeline.odometry_process.OdometryProcess`."""

    def __init__(self, mapper: Mapper, scans: ScanLog, config: MappingConfig) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="scanreg-odometry")
        self._ahead: deque[Future[Tracked]] = deque()
        self._mapper, self._scans, self._config = mapper, scans, config
        self._next = 0

    def next(self, mapper: Mapper) -> Tracked:
        total = len(self._scans)
        while len(self._ahead) < _TRACK_AHEAD and self._next < total:
            self._ahead.append(
                self._pool.submit(track_scan, self._mapper, self._scans, self._config, self._next)
            )
            self._next += 1
        return self._ahead.popleft().result()

    def finish(self, mapper: Mapper) -> None:
        self._pool.shutdown()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


def _stepped(
    mapper: Any,
    step: MappingStep,
    bar: Any,
    every: int,
    k: int,
    total: int,
    checkpoint: Checkpoint | None,
    checkpoint_every: int,
) -> None:
    """After scan ``k`` of ``total`` (2D or 3D mapper): the progress bar, its node and loop
    counts at each loop and every ``every`` scans, and the checkpoint when due."""
    # The counts walk every loop so far: only for a bar that shows them.
    if bar.enabled and (step.loops or step.index % every == 0):
        loops = mapper.loops
        bar.set_counters(
            nodes=mapper.num_nodes,
            loops=sum(r.accepted for r in loops),
            rejected=sum(not r.accepted for r in loops),
        )
    bar.update()
    if checkpoint is not None and (k + 1) % checkpoint_every == 0:
        checkpoint(mapper.snapshot(f"checkpoint after {k + 1} of {total} scans"))


def _checked_checkpoint_every(checkpoint_every: object) -> None:
    """Refuse a ``checkpoint_every`` that is not an int >= 1, by name."""
    if isinstance(checkpoint_every, bool) or not (
        isinstance(checkpoint_every, int) and checkpoint_every >= 1
    ):
        raise ValueError(f"checkpoint_every: must be an int >= 1, got {checkpoint_every!r}")


def _stopped_run(mapper: Any, exc: BaseException, k: int, total: int) -> MappingInterrupted | None:
    """The exception that carries what ``mapper`` (2D or 3D) mapped before ``exc`` stopped it
    at scan ``k`` of ``total``; ``None`` when nothing was mapped (the cause is then raised as
    is)."""
    if isinstance(exc, MappingInterrupted) or not mapper.num_nodes:
        return None
    why = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
    reason = f"stopped at scan {k} of {total} ({why})"
    try:
        partial = mapper.snapshot(reason)
    except Exception:  # the state itself is broken: nothing to save
        return None
    return MappingInterrupted(reason, partial)
