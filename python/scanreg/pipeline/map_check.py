"""A map that checks itself without ground truth: does the trajectory agree with its own scans?

:func:`check_map` judges a 2D or 3D mapping run or a saved 2D map (or any trajectory of its
scans, e.g. the odometry alone) on two kinds of evidence a user can trust without ground truth:

* **Contradictions.** A return says "beams stop here". Each node's kept scan is looked up from
  the nodes that come back later (or came earlier: at least ``min_gap`` nodes apart in order,
  within ``max_range`` of the return) in their own range images
  (:func:`scanreg._core.see_through`): a node *sees* the return when its beams around that
  bearing reach it, and *sees through* it when they all go more than ``margin`` beyond. Where
  the trajectory is wrong, a revisit puts its walls where the first visit saw through. A
  return is contradicted when at least ``min_views`` revisits saw it and most of them saw
  through it; the fraction of contradicted returns among those seen, and the regions where
  they gather, say how and where the map disagrees with itself. A door that was open once and
  closed later, or people, contradict too: the limit leaves room for that. A failure can be
  local (one revisit never closed in an otherwise good map): a square of the map where many
  of the returns are contradicted, holding a sizeable share of all of them, is one too.
* **Loop edges after optimization.** Each accepted loop edge's residual χ² at the judged poses,
  against the 99.9 % bound of its rank, and the weight the back end's robust kernel gives it
  there: a loop the back end down-weighted is one the rest of the graph disagrees with.

A mapping run also says where its odometry lost its map and went on from its best guess
(:attr:`~scanreg.pipeline.MappingResult.reseeded`): a map bent there can be consistent with
itself, with no revisit left to contradict it, so any such place is a reason too.

A 3D run is judged alike, its node clouds' range images binned by azimuth and elevation
(:data:`SETTINGS_3D`; regions are squares of the ground plane). On the simulated two-lap drive
of ``tests/test_mapping3d.py`` the loop-closed map reads 0.04 % contradicted, the same run's
nodes moved along a drift growing to 0.6 / 1 / 2 m at the revisit 1.2 / 17.9 / 23.1 %, turned by
a heading drift growing to 2° / 4° 4.0 / 38.9 %. On ``benchmarks/mapping_3d.py``'s two-lap
drives (default settings) the loop-closed maps read 0.01–0.39 % contradicted (the true poses
0.00–0.37 %), the odometry alone of the drive with 25 m odometry (0.54 m RMS off) 1.79 %: a
3D map is flagged by its contradictions from about a metre or a few degrees off, and by its
loop edges below that.

The verdict ``consistent`` holds when the contradicted fraction (over the map and in its worst
square) and the fraction of loop edges over their bound are under :class:`MapCheckSettings`'
limits and the odometry never lost its map; ``reasons`` names each limit exceeded. The limits
were chosen on the Freiburg Intel and ACES logs and the simulated tours
(``benchmarks/freiburg_mapping.py --self-check``, ``benchmarks/simulated_buildings.py``; the
figures are in ``benchmarks/README.md``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import _core
from .._validate import FloatArray
from ..graph import Edge, Kernel
from ..saved_map import SavedMap
from ..transform import SE2, SE3
from .mapping import MappingResult

#: χ² 99.9 % quantiles by degrees of freedom (an edge's information may be rank-deficient).
CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266, 4: 18.467, 5: 20.515, 6: 22.458}


@dataclass(frozen=True)
class MapCheckSettings:
    """How :func:`check_map` looks and what it tolerates (the limits chosen on the Freiburg
    logs, see the module docstring)."""

    #: Bearing (3D: azimuth) bins of the nodes' range images (no narrower than the beam
    #: spacing).
    bins: int = 360
    #: 3D: elevation bins over [-90°, 90°] (no narrower than the rings' spacing).
    elevation_bins: int = 60
    #: Tolerance along the beam (m).
    margin: float = 0.3
    #: Only nodes within this distance of a return judge it (m).
    max_range: float = 10.0
    #: Only nodes at least this many nodes apart in order judge each other: a revisit, not the
    #: neighbours a person walking along would fool alike.
    min_gap: int = 100
    #: A return is judged when at least this many revisits saw it.
    min_views: int = 2
    #: About this many returns are judged (every k-th): the fraction needs no more.
    max_judged: int = 50_000
    #: The map is inconsistent above this fraction of contradicted returns among those judged
    #: (chosen on Intel 0.9 % loop-closed, 14.7 % without loops; ACES 7.7 %, 31.5 %; the
    #: mapping of later commits read 0.9 %, 16.4 %; 6.0 %, 52.2 %).
    max_contradiction_fraction: float = 0.10
    #: Side of the square regions the contradictions are gathered in (m).
    region_size: float = 4.0
    #: The map is inconsistent where one region has more than this fraction of its returns
    #: contradicted ...
    max_region_fraction: float = 0.2
    #: ... and they are at least this share of all returns judged. Chosen on the simulated
    #: tours (benchmarks/simulated_buildings.py) and the Freiburg maps at 4 m: the worst such
    #: region of a good map held 0.63 % (ACES loop-closed), a tour with one stretch unclosed
    #: 2.9 % (no odometry, seed 1: 0.105 m ATE, 4.6 % over the map), the 360° laser without
    #: beam times 3.2 %, Intel's odometry alone 1.4 %.
    min_region_share: float = 0.01
    #: Regions reported, worst first.
    num_regions: int = 5
    #: A loop edge is down-weighted when its robust kernel keeps less than this share of it.
    downweighted: float = 0.1
    #: The map is inconsistent above this fraction of accepted loop edges over their bound.
    max_loops_over_bound: float = 0.05

    def __post_init__(self) -> None:
        for name in ("margin", "max_range", "region_size"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be finite and > 0, got {v!r}")
        for name, least in (
            ("bins", 3), ("elevation_bins", 3), ("min_gap", 0), ("min_views", 1),
            ("max_judged", 1), ("num_regions", 1),
        ):  # fmt: skip
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise ValueError(f"{name}: must be an int >= {least}, got {v!r}")
        for name in (
            "max_contradiction_fraction", "max_region_fraction", "min_region_share",
            "downweighted", "max_loops_over_bound",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise ValueError(f"{name}: must be in [0, 1], got {v!r}")


#: The settings a 3D run is judged with unless others are given: nodes are 2 m apart (a
#: revisit is 25 nodes away, the loop search's 50 m), their clouds voxelized at 0.3 m and
#: seen to 100 m, rings 0.4–2° apart. Loop edges over their bound: at most 15 %, since at the
#: true poses 6–11 % of the 3D loop edges exceed it on ``benchmarks/mapping_3d.py``'s three
#: drives (their covariance's tail: loop NEES 5.5–7.4 against the ideal 6), the loop-closed
#: maps 1–7 %, the same runs' odometry alone 22–100 % (each drive held out in turn, the
#: other two leave the limit between 8–11 % and 22–35 %; 15 % judges the held-out one right).
SETTINGS_3D = MapCheckSettings(
    margin=0.5, max_range=30.0, min_gap=25, region_size=10.0, max_loops_over_bound=0.15
)


@dataclass(frozen=True)
class ContradictionRegion:
    """A square of the map (``size`` m, centred at ``x``, ``y``) and its contradicted returns;
    ``passes``: whose they are, where in the run to look — ``(first_scan, last_scan,
    contradicted)`` per pass of the robot through the square (scans of the log, in order;
    passes split where their nodes lie more than ``min_gap // 2`` apart)."""

    x: float
    y: float
    size: float
    contradictions: int
    returns: int
    passes: tuple[tuple[int, int, int], ...] = ()


@dataclass(frozen=True)
class LoopResidual:
    """An accepted loop edge (nodes ``i``, ``j``) at the judged poses: residual χ² over the
    ``dof`` directions its information holds, the 99.9 % bound for them, and the share of the
    edge the robust kernel keeps at that residual (1 without a kernel)."""

    i: int
    j: int
    chi2: float
    dof: int
    bound: float
    weight: float

    @property
    def over_bound(self) -> bool:
        return self.chi2 > self.bound


@dataclass(frozen=True)
class MapCheck:
    """What :func:`check_map` found (see the module docstring)."""

    consistent: bool
    #: One sentence per limit exceeded (empty when consistent).
    reasons: tuple[str, ...]
    #: Returns judged (at least ``min_views`` revisits saw them) and those most of them saw
    #: through.
    returns: int
    contradictions: int
    #: Where the contradictions gather, worst first.
    regions: tuple[ContradictionRegion, ...]
    #: World coordinates of every contradicted return ``(K, 2)`` (3D: ``(K, 3)``; for a plot
    #: of the map).
    contradiction_points: FloatArray = field(repr=False)
    loops: tuple[LoopResidual, ...]
    settings: MapCheckSettings
    #: Scans where the run's odometry had lost its map and went on from its best guess
    #: (:attr:`~scanreg.pipeline.MappingResult.reseeded`; none for a saved map).
    reseeded: tuple[int, ...] = ()

    @property
    def contradiction_fraction(self) -> float:
        return self.contradictions / self.returns if self.returns else 0.0

    @property
    def loops_over_bound(self) -> int:
        return sum(r.over_bound for r in self.loops)

    @property
    def loops_downweighted(self) -> int:
        return sum(r.weight < self.settings.downweighted for r in self.loops)

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (without the contradicted points)."""
        chi2 = np.array([r.chi2 for r in self.loops])
        return {
            "consistent": self.consistent,
            "reasons": list(self.reasons),
            "returns": self.returns,
            "contradictions": self.contradictions,
            "contradiction_fraction": self.contradiction_fraction,
            "regions": [
                {
                    "x": r.x,
                    "y": r.y,
                    "size": r.size,
                    "contradictions": r.contradictions,
                    "returns": r.returns,
                    "passes": [list(p) for p in r.passes],
                }
                for r in self.regions
            ],
            "reseeded": list(self.reseeded),
            "loops": len(self.loops),
            "loops_over_bound": self.loops_over_bound,
            "loops_downweighted": self.loops_downweighted,
            "loop_chi2_median": float(np.median(chi2)) if len(chi2) else None,
            "thresholds": {
                "min_gap": self.settings.min_gap,
                "min_views": self.settings.min_views,
                "margin": self.settings.margin,
                "max_contradiction_fraction": self.settings.max_contradiction_fraction,
                "max_region_fraction": self.settings.max_region_fraction,
                "min_region_share": self.settings.min_region_share,
                "max_loops_over_bound": self.settings.max_loops_over_bound,
                "downweighted": self.settings.downweighted,
            },
        }


def kernel_weight(kernel: Kernel | None, chi2: float) -> float:
    """The share of an edge a robust kernel keeps at whitened squared residual ``chi2``
    (gtsam's weights: Cauchy ``1 / (1 + r²/c²)``, Huber ``min(1, k / r)``, DCS ``s²`` with
    ``s = min(1, 2Φ / (Φ + r²))``)."""
    if kernel is None or kernel.name == "none":
        return 1.0
    c = kernel.scale
    if kernel.name == "cauchy":
        return 1.0 / (1.0 + chi2 / (c * c))
    if kernel.name == "huber":
        r = math.sqrt(chi2)
        return 1.0 if r <= c else c / r
    s = min(1.0, 2.0 * c / (c + chi2))
    return s * s


def loop_residual(edge: Edge, pose_i: SE2 | SE3, pose_j: SE2 | SE3) -> LoopResidual:
    """``edge``'s residual at ``pose_i``, ``pose_j`` (``T_world_i``, ``T_world_j``)."""
    predicted = pose_i.inverse() @ pose_j  # type: ignore[operator]
    e = (edge.measurement.inverse() @ predicted).log()  # type: ignore[operator]
    info = edge.information
    vals = np.linalg.eigvalsh(info)
    dof = int(np.sum(vals > 1e-9 * vals[-1]))
    chi2 = float(e @ info @ e)
    return LoopResidual(edge.i, edge.j, chi2, dof, CHI2_999[dof], kernel_weight(edge.kernel, chi2))


def describe_region(region: dict[str, Any]) -> str:
    """One line for a region of :meth:`MapCheck.as_dict`: where on the map, and the scans
    whose returns are contradicted there (where in the run)."""
    passes = ", ".join(f"{a}-{b} ({n})" for a, b, n in region.get("passes", []))
    return (
        f"{region['contradictions']} of {region['returns']} returns in the {region['size']:g} m "
        f"square at ({region['x']:.1f}, {region['y']:.1f})"
        + (f", from scans {passes}" if passes else "")
    )


def _passes(
    owners: np.ndarray[Any, Any], node_scans: Sequence[int], split: int
) -> tuple[tuple[int, int, int], ...]:
    """``(first_scan, last_scan, count)`` of the returns owned by nodes ``owners``, one per run
    of nodes no more than ``split`` apart."""
    nodes, counts = np.unique(owners, return_counts=True)
    breaks = np.flatnonzero(np.diff(nodes) > split) + 1
    return tuple(
        (int(node_scans[run[0]]), int(node_scans[run[-1]]), int(c.sum()))
        for run, c in zip(np.split(nodes, breaks), np.split(counts, breaks), strict=True)
    )


def _regions(
    world: FloatArray,
    contradicted: np.ndarray[Any, Any],
    owners: np.ndarray[Any, Any],
    node_scans: Sequence[int],
    s: MapCheckSettings,
) -> tuple[ContradictionRegion, ...]:
    if not contradicted.any():
        return ()
    lo = world.min(axis=0)
    ij = np.floor((world - lo) / s.region_size).astype(np.int64)
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    keys, first, total = np.unique(key, return_index=True, return_counts=True)
    slot = np.searchsorted(keys, key)
    bad = np.bincount(slot[contradicted], minlength=len(keys))
    order = np.lexsort((-total, -bad))
    # The contradicted returns' owners grouped by square (one sort, not a pass per square).
    by_slot = np.argsort(slot[contradicted], kind="stable")
    mine = np.split(owners[contradicted][by_slot], np.cumsum(bad)[:-1])
    split = max(1, s.min_gap // 2)
    return tuple(
        ContradictionRegion(
            x=float(lo[0] + (ij[first[k], 0] + 0.5) * s.region_size),
            y=float(lo[1] + (ij[first[k], 1] + 0.5) * s.region_size),
            size=s.region_size,
            contradictions=int(bad[k]),
            returns=int(total[k]),
            passes=_passes(mine[k], node_scans, split),
        )
        for k in order
        if bad[k] > 0
    )


def check_map(
    result: MappingResult[SE2] | MappingResult[SE3] | SavedMap,
    poses: Sequence[SE2] | Sequence[SE3] | None = None,
    settings: MapCheckSettings | None = None,
) -> MapCheck:
    """Judge ``result``'s map from its own scans (the nodes' kept scans, ``node_points``).

    ``result``: a 2D or 3D mapping run (a 3D run with :data:`SETTINGS_3D` unless ``settings``
    are given), or a saved 2D map of format 2 (:class:`scanreg.SavedMap`, e.g.
    the joint map ``merge`` or ``--extend`` wrote: the sessions' scans judge each other). A
    saved graph keeps no robust kernels: its loop edges (those between nodes that are not
    consecutive) count at full weight. ``poses``: every scan's ``T_world_scan`` to judge
    instead of the optimized graph's (``result.odometry_poses``, say; SE2 or SE3 as the run);
    each node is then at its scan's pose.
    """
    s = MapCheckSettings() if settings is None else settings
    if not isinstance(settings, MapCheckSettings | None):
        raise TypeError(f"settings: expected MapCheckSettings, got {type(settings).__name__}")
    sessions = None
    if isinstance(result, SavedMap):
        node_scans, node_points, graph_nodes, edges = _saved_parts(result)
        if result.scan_sessions is not None and len(result.sessions) > 1:
            sessions = np.asarray(result.scan_sessions, dtype=np.uint32)[list(node_scans)]
    elif isinstance(result, MappingResult):
        node_scans, node_points, edges = result.node_scans, result.node_points, result.graph.edges
        graph_poses = result.graph.poses()
        graph_nodes = [graph_poses[n] for n in range(len(node_scans))]
    else:
        raise TypeError(
            f"result: expected a MappingResult or a SavedMap, got {type(result).__name__}"
        )
    kind = SE3 if isinstance(result, MappingResult) and result.graph.dim == 3 else SE2
    if settings is None and kind is SE3:
        s = SETTINGS_3D
    if poses is None:
        nodes = list(graph_nodes)
    else:
        if len(poses) != result.num_scans:
            raise ValueError(f"poses: expected one per scan ({result.num_scans}), got {len(poses)}")
        if not all(isinstance(p, kind) for p in poses):
            raise TypeError(f"poses: expected {kind.__name__} poses")
        nodes = [poses[k] for k in node_scans]
    check = _check(nodes, node_points, node_scans, edges, s, sessions)
    if isinstance(result, MappingResult) and result.reseeded:
        check = _with_reseeds(check, result.reseeded)
    return check


def _with_reseeds(check: MapCheck, reseeded: Sequence[int]) -> MapCheck:
    """``check`` flagged where the odometry lost its map: it went on from its best guess, and
    a map bent there holds no revisit for the returns to judge (a corner the front end missed:
    the rest of the run drawn at the wrong heading, consistent with itself)."""
    shown = ", ".join(str(k) for k in reseeded[:5]) + (" ..." if len(reseeded) > 5 else "")
    reason = (
        f"odometry: lost its map {len(reseeded)} time(s) and went on from its best guess "
        f"(scans {shown}); the map is unconfirmed there"
    )
    return dataclasses.replace(
        check, reseeded=tuple(reseeded), reasons=(*check.reasons, reason), consistent=False
    )


def _saved_parts(
    m: SavedMap,
) -> tuple[Sequence[int], Sequence[FloatArray], Sequence[Any], Sequence[Edge]]:
    """A saved map's node scans, their points, node poses and edges (loop edges: between
    nodes that are not consecutive, as :mod:`.join` reads them)."""
    where = "" if m.folder is None else f" ({m.folder})"
    if m.dim != 2:
        raise ValueError(f"result: check_map needs a 2D map{where}, got a {m.dim}D one")
    if m.graph is None or m.node_scans is None or m.node_points is None:
        raise ValueError(
            f"result: the map{where} keeps no node scans (format {m.format_version}); "
            "only maps of format 2 can be checked"
        )
    edges = [
        Edge(
            "loop" if abs(e.to_id - e.from_id) != 1 else "odometry",
            e.from_id,
            e.to_id,
            e.measurement,
            e.information,  # (2D: g2o's ordering and scale are scanreg's)
        )
        for e in m.graph.edges
    ]
    return m.node_scans, m.node_points, m.node_poses, edges


def _check(
    nodes: Sequence[SE2 | SE3],
    points: Sequence[FloatArray],
    node_scans: Sequence[int],
    edges: Sequence[Edge],
    s: MapCheckSettings,
    sessions: np.ndarray[Any, np.dtype[np.uint32]] | None = None,
) -> MapCheck:
    dim = 3 if isinstance(nodes[0], SE3) else 2
    counts = np.array([len(p) for p in points], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    stacked = np.ascontiguousarray(np.vstack(points), dtype=np.float64).reshape(-1, dim)
    common: dict[str, Any] = {
        "bins": s.bins,
        "margin": s.margin,
        "max_range": s.max_range,
        "min_gap": s.min_gap,
        "stride": max(1, -(-len(stacked) // s.max_judged)),
        # Another session's scans are revisits however close in order (min_gap).
        "sessions": None if sessions is None else np.ascontiguousarray(sessions),
    }
    if dim == 2:
        rows = [p.as_vector() for p in nodes]
        judge = _core.see_through(
            np.ascontiguousarray(rows, dtype=np.float64), stacked, offsets, **common
        )
    else:
        # [R row-major, t] of each T_world_node.
        rows = [np.r_[m[:3, :3].ravel(), m[:3, 3]] for m in (p.as_matrix() for p in nodes)]
        judge = _core.see_through_3d(
            np.ascontiguousarray(rows, dtype=np.float64),
            stacked,
            offsets,
            elevation_bins=s.elevation_bins,
            **common,
        )
    world, judged, seen, through = judge
    seen_enough = seen >= s.min_views
    contradicted = seen_enough & (2 * through > seen)
    where = world  # the judged returns' own rows
    loops = tuple(loop_residual(e, nodes[e.i], nodes[e.j]) for e in edges if e.kind == "loop")
    returns, bad = int(seen_enough.sum()), int(contradicted.sum())
    # Each judged return's node: whose returns a region's are.
    owners = np.searchsorted(offsets, np.asarray(judged), side="right") - 1
    regions = _regions(
        where[seen_enough, :2], contradicted[seen_enough], owners[seen_enough], node_scans, s
    )
    reasons = []
    if returns and bad / returns > s.max_contradiction_fraction:
        reasons.append(
            f"contradictions: {bad / returns:.1%} of the returns revisits saw ({bad} of "
            f"{returns}) were seen through by most of them (limit "
            f"{s.max_contradiction_fraction:.0%})"
        )
    local = [
        r
        for r in regions
        if r.contradictions > s.max_region_fraction * r.returns
        and r.contradictions >= s.min_region_share * returns
    ]
    if local:
        r = local[0]
        share = r.contradictions / r.returns
        reasons.append(
            f"contradictions gather: {r.contradictions} of the {r.returns} returns revisits saw "
            f"in the {r.size:g} m square at ({r.x:.1f}, {r.y:.1f}) ({share:.0%}"
            f"; {r.contradictions / returns:.1%} of all judged) were seen through "
            f"(limits {s.max_region_fraction:.0%} of a square and {s.min_region_share:.0%} of "
            "all)" + (f"; {len(local) - 1} more such squares" if len(local) > 1 else "")
        )
    over = sum(r.over_bound for r in loops)
    if loops and over / len(loops) > s.max_loops_over_bound:
        reasons.append(
            f"loops: {over} of {len(loops)} loop edges exceed their 99.9 % χ² bound at the "
            f"final poses (limit {s.max_loops_over_bound:.0%})"
        )
    return MapCheck(
        consistent=not reasons,
        reasons=tuple(reasons),
        returns=returns,
        contradictions=bad,
        regions=regions[: s.num_regions],
        contradiction_points=np.ascontiguousarray(where[contradicted]),
        loops=loops,
        settings=s,
    )
