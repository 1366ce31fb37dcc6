"""Extend a saved 2D map with a new run: one graph over both sessions.

:func:`extend_map` takes a :class:`scanreg.SavedMap` (format 2: it keeps its nodes' scans)
and a new run mapped on its own (:func:`~scanreg.pipeline.run_mapping`, in its own frame):

1. **locate** — the new run's first node is searched for over the whole saved map at any
   heading (:meth:`Localizer2D.relocalize`, the global search ``scanreg localize`` uses); if
   the verdict rejects it, the next nodes are tried (a run may start outside the old map);
2. **close** — every new node is matched against the submap of its nearest old node, from
   the pose the latest fix predicts (:func:`~scanreg.pipeline.loops.match_loop`: correlative
   search, point-to-line refinement, verdict, χ² against a generous prior); accepted matches
   become inter-session loop edges and refresh the fix, so the new run's own drift stays
   small against the search window;
3. **optimize** — one graph: the old nodes (ids kept, node 0 fixed) with their edges, the
   new nodes after them with theirs (their own loops included), the inter-session loops;
   loop edges carry the mapping's robust kernel (old edges between non-consecutive nodes are
   loops).

Every scan's pose follows its node's correction (the scan's pose relative to the node it was
mapped after is kept). A new run that neither the global search nor any node's match places
in the old map is refused: nothing is written that would pretend to be one map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..io.g2o import PoseGraph, PoseGraphEdge
from ..io.occupancy import occupancy_grid
from ..saved_map import SavedMap
from ..transform import SE2
from .loops import match_loop
from .mapping import MappingConfig, MappingResult


@dataclass(frozen=True)
class ExtendReport:
    """How a new run was joined to a saved map (:func:`extend_map`)."""

    #: New node located by the global search, and its correlative score.
    located_node: int
    located_score: float
    #: Inter-session loops matched and accepted.
    candidates: int
    accepted: int
    #: Every inter-session candidate as a ``loops.jsonl`` record (node ids of the joint map).
    records: tuple[dict[str, Any], ...]

    def as_dict(self) -> dict[str, Any]:
        return {
            "located_node": self.located_node,
            "located_score": self.located_score,
            "inter_session_candidates": self.candidates,
            "inter_session_loops": self.accepted,
        }


def _locate(saved: SavedMap, new: SavedMap, tries: int) -> tuple[int, SE2, float]:
    """The first of the new run's nodes the global search places in the saved map:
    ``(node, T_old_newworld, score)``."""
    from .localizer2d import Localizer2D

    loc = Localizer2D.from_saved_map(saved)
    reasons: list[str] = []
    assert new.node_points is not None
    new_poses = new.node_poses
    for node in range(min(tries, len(new.node_points))):
        pts = new.node_points[node]
        if len(pts) < 3:
            continue
        fix = loc.relocalize(pts)
        if fix.frame.verdict.accepted:
            here = fix.frame.pose
            assert isinstance(here, SE2)
            node_pose = new_poses[node]
            assert isinstance(node_pose, SE2)
            return node, here @ node_pose.inverse(), fix.score
        reasons.append(f"node {node}: {'; '.join(fix.frame.verdict.reasons)}")
    raise ValueError(
        "extend: the new run could not be located in the saved map from no initial pose "
        f"(its first {min(tries, len(new.node_points))} nodes tried): " + " | ".join(reasons)
    )


def _scan_nodes(node_scans: tuple[int, ...], num_scans: int) -> FloatArray:
    """For every scan, the node it was mapped after (the last node at or before it; the
    first node for scans before it)."""
    idx = np.searchsorted(np.asarray(node_scans), np.arange(num_scans), side="right") - 1
    return np.clip(idx, 0, len(node_scans) - 1)


def extend_map(
    saved: SavedMap,
    result: MappingResult[Any] | SavedMap,
    *,
    session: str | None = None,
    config: MappingConfig | None = None,
    locate_tries: int = 10,
    max_distance: float = 2.0,
    prior_sigma: tuple[float, float] = (0.3, math.radians(5.0)),
    window: tuple[float, float] = (1.0, math.radians(15.0)),
    min_loops: int = 2,
) -> tuple[SavedMap, ExtendReport]:
    """``saved`` and the new run ``result`` as one map (module docstring): returns the joint
    :class:`~scanreg.SavedMap` (one more session) and how they were joined. ``result``: a
    :class:`~scanreg.pipeline.MappingResult` (named ``session``) or a saved map of format 2
    (its sessions kept).

    ``max_distance``: a new node is matched against its nearest old node when that lies
    within this (m) of where the fix puts it; ``prior_sigma`` (m, rad): the fix's assumed
    uncertainty per axis (the χ² test's prior); ``window`` (m, rad): the search half-widths;
    ``min_loops``: the inter-session loops needed to join (one alone could be a look-alike:
    the global search placed an ACES excerpt in an Intel map, and one loop would have
    followed it)."""
    from ..graph import Graph

    if not isinstance(saved, SavedMap):
        raise TypeError(f"saved: expected a SavedMap, got {type(saved).__name__}")
    if isinstance(result, MappingResult):
        if session is None:
            raise ValueError("session: a new run's name is needed (e.g. its log's path)")
        new = SavedMap.from_result(result, session=session, resolution=_resolution(saved))
    elif isinstance(result, SavedMap):
        new = result
    else:
        raise TypeError(
            f"result: expected a MappingResult or SavedMap, got {type(result).__name__}"
        )
    if saved.dim != 2 or new.dim != 2:
        raise ValueError("extend: only 2D maps can be extended yet")
    for name, m in (("saved", saved), ("result", new)):
        if m.node_points is None or m.node_scans is None or m.graph is None:
            raise ValueError(
                f"{name}: a format-{m.format_version} map keeps no node scans; it cannot be "
                "joined (map its run again to write format 2)"
            )
    clash = set(new.sessions) & set(saved.sessions)
    if clash or not new.sessions:
        raise ValueError(f"session: expected a new, non-empty name, got {sorted(clash)}")
    assert new.node_points is not None and new.node_scans is not None and new.graph is not None
    assert saved.node_points is not None and saved.node_scans is not None
    assert saved.graph is not None
    if isinstance(min_loops, bool) or not isinstance(min_loops, int) or min_loops < 1:
        raise ValueError(f"min_loops: expected an int >= 1, got {min_loops!r}")
    cfg = MappingConfig() if config is None else config
    assert saved.grid is not None
    located, transform, score = _locate(saved, new, locate_tries)

    old_ids = sorted(saved.graph.vertices)
    k_old = len(old_ids)
    if old_ids != list(range(k_old)):
        raise ValueError("saved: its graph's node ids are not 0..K-1")
    old_poses: list[SE2] = [saved.graph.vertices[k] for k in old_ids]  # type: ignore[misc]
    old_xy = np.array([p.translation for p in old_poses])
    new_poses: list[SE2] = list(new.node_poses)  # type: ignore[arg-type]

    settings = cfg.loops
    prior = np.diag([prior_sigma[0] ** 2, prior_sigma[0] ** 2, prior_sigma[1] ** 2])
    records: list[dict[str, Any]] = []
    edges: list[tuple[int, int, SE2, FloatArray]] = []
    submaps: dict[int, Any] = {}
    start: SE2 | None = None
    for n, pose in enumerate(new_poses):
        pts = new.node_points[n]
        if len(pts) < 3:
            continue
        guess = transform @ pose
        d = np.linalg.norm(old_xy - guess.translation, axis=1)
        anchor = int(np.argmin(d))
        if d[anchor] > max_distance:
            continue
        if anchor not in submaps:
            submaps[anchor] = saved.submap(
                anchor,
                half_size=cfg.submap_half_size,
                resolution=settings.resolution,
                voxel_size=cfg.node_voxel_size,
            )
        predicted = old_poses[anchor].inverse() @ guess
        match = match_loop(
            pts, k_old + n, submaps[anchor], predicted, prior, settings, window=window
        )
        record = {
            "submap_node": anchor,
            "node": k_old + n,
            "submap_scan": saved.node_scans[anchor],
            "scan": saved.num_scans + new.node_scans[n],
            "accepted": match.accepted,
            "reasons": list(match.reasons),
            "measured": [float(v) for v in match.measured.as_vector()],
            "score": float(match.score),
            "inter_session": True,
        }
        records.append(record)
        if match.accepted:
            edges.append((anchor, k_old + n, match.measured, match.information))
            # The fix follows the new run: its drift since the last match stays small.
            transform = old_poses[anchor] @ match.measured @ pose.inverse()
            # The graph starts from the first match: where the new run's drift is least.
            start = transform if start is None else start
    if len(edges) < min_loops:
        raise ValueError(
            f"extend: located at new node {located} (score {score:.2f}) but {len(edges)} of "
            f"{len(records)} new nodes' scans matched the saved map (within {max_distance} m; "
            f"{min_loops} needed): no reliable overlap, nothing joined"
        )

    g = Graph(2)
    for k, p in enumerate(old_poses):
        g.add_node(k, p)
    g.add_prior(0, old_poses[0], 1e6 * np.eye(3))
    assert start is not None
    for n, p in enumerate(new_poses):
        g.add_node(k_old + n, start @ p)
    kernel = cfg.loop_kernel
    for e in saved.graph.edges:
        loop = abs(e.to_id - e.from_id) != 1
        g.add_edge(
            e.from_id,
            e.to_id,
            e.measurement,
            e.information,
            kind="loop" if loop else "odometry",
            kernel=kernel if loop else None,
        )
    for e in new.graph.edges:
        loop = abs(e.to_id - e.from_id) != 1
        g.add_edge(
            k_old + e.from_id,
            k_old + e.to_id,
            e.measurement,
            e.information,
            kind="loop" if loop else "odometry",
            kernel=kernel if loop else None,
        )
    for i, j, measured, information in edges:
        g.add_edge(i, j, measured, information, kind="loop", kernel=kernel)
    g.optimize()
    joint = g.poses()
    node_poses: list[SE2] = [joint[k] for k in range(k_old + len(new_poses))]  # type: ignore[misc]

    def moved(
        poses: tuple[Any, ...], node_scans: tuple[int, ...], before: list[SE2], offset: int
    ) -> list[SE2]:
        owner = _scan_nodes(node_scans, len(poses))
        return [
            node_poses[offset + int(o)] @ before[int(o)].inverse() @ p
            for p, o in zip(poses, owner, strict=True)
        ]

    scan_poses = moved(saved.poses, saved.node_scans, old_poses, 0)
    new_scan_poses = moved(new.poses, new.node_scans, new_poses, k_old)
    node_points = (*saved.node_points, *new.node_points)
    grid = occupancy_grid(node_poses, list(node_points), resolution=saved.grid.resolution)
    graph_edges = tuple(
        PoseGraphEdge(e.i, e.j, e.measurement, e.information) for e in g.edges if e.kind != "prior"
    )
    new_loops = []
    for r in new.loops:
        rec = dict(r)
        for key in ("submap_node", "node"):
            rec[key] += k_old
        for key in ("submap_scan", "scan"):
            rec[key] += saved.num_scans
        new_loops.append(rec)
    sessions = saved.scan_sessions
    assert sessions is not None
    joined = SavedMap(
        dim=2,
        poses=(*scan_poses, *new_scan_poses),
        stamps=np.concatenate([saved.stamps, new.stamps]),
        graph=PoseGraph(dict(enumerate(node_poses)), graph_edges, frozenset({0})),
        odometry_poses=(*(saved.odometry_poses or saved.poses), *(new.odometry_poses or new.poses)),
        node_scans=(*saved.node_scans, *(saved.num_scans + s for s in new.node_scans)),
        node_points=node_points,
        sessions=(*saved.sessions, *new.sessions),
        scan_sessions=np.concatenate([sessions, len(saved.sessions) + _sessions_of(new)]),
        grid=grid,
        loops=(*saved.loops, *new_loops, *records),
    )
    report = ExtendReport(located, score, len(records), len(edges), tuple(records))
    return joined, report


def _resolution(saved: SavedMap) -> float:
    return 0.05 if saved.grid is None else saved.grid.resolution


def _sessions_of(m: SavedMap) -> np.ndarray[Any, np.dtype[np.int64]]:
    if m.scan_sessions is None:
        return np.zeros(m.num_scans, dtype=np.int64)
    return m.scan_sessions


__all__ = ["ExtendReport", "extend_map"]
