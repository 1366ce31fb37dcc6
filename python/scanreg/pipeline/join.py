"""Join a second 2D session to a saved map: one graph over both (what ``extend`` and
``merge`` share).

:func:`join_sessions` takes two :class:`scanreg.SavedMap` of format 2 (they keep their nodes'
scans), each in its own frame — the frames need have nothing to do with each other:

1. **locate** — nodes of the second map are searched for over the whole first map at any
   heading (:meth:`Localizer2D.relocalize`, the global search ``scanreg localize`` uses),
   until the verdict accepts one;
2. **close** — from the located node forward, then back from it to the second map's start,
   every node is matched against the submap of its nearest node of the first map, from the
   pose the latest fix predicts (:func:`~scanreg.pipeline.loops.match_loop`: correlative
   search, point-to-line refinement, verdict, χ² against a generous prior); accepted matches
   refresh the fix, so the second session's own drift stays small against the search window;
3. **agree** — the accepted inter-session loops must tell one story: the largest set that
   agrees with one of them (:func:`~scanreg.pipeline.loops.loops_agree`: each pair's cycle
   through both sessions' own graphs closes) is kept, the others are recorded as rejected;
   fewer than ``min_loops`` agreeing loops and nothing is joined;
4. **optimize** — one graph: the first map's nodes (ids kept, node 0 fixed) with their edges,
   the second's after them with theirs (their own loops included, with the mapping's robust
   kernel), the agreeing loops without one: the agreement test has already put the outliers
   out, and a kernel would let a session's own odometry, where it slipped yet claims
   centimetres, overrule every loop that says so (the Intel log's second half: seven agreeing
   loops at its tail, 0.98 m away, were left as outliers, and the map kept the slip).

Every scan's pose follows its node's correction (its pose relative to the node it was mapped
after is kept).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..io.g2o import PoseGraph, PoseGraphEdge
from ..io.occupancy import occupancy_grid
from ..saved_map import SavedMap
from ..transform import SE2
from .loops import LoopMatch, LoopSettings, loops_agree, match_loop
from .mapping import MappingConfig

#: Why an accepted inter-session match was left out of the graph.
DISAGREES = "disagrees with the other inter-session loops"


@dataclass(frozen=True)
class JoinReport:
    """How a second session was joined to a saved map (:func:`join_sessions`)."""

    #: Second-map node located by the global search, and its correlative score.
    located_node: int
    located_score: float
    #: Inter-session matches tried, and the loops joined (accepted and agreeing).
    candidates: int
    accepted: int
    #: Matches the verdict accepted but the other loops contradicted (left out).
    disagreeing: int
    #: Every inter-session candidate as a ``loops.jsonl`` record (node ids of the joint map).
    records: tuple[dict[str, Any], ...]

    def as_dict(self) -> dict[str, Any]:
        return {
            "located_node": self.located_node,
            "located_score": self.located_score,
            "inter_session_candidates": self.candidates,
            "inter_session_loops": self.accepted,
            "inter_session_disagreeing": self.disagreeing,
        }


def check_joinable(m: SavedMap, name: str) -> None:
    """Raise ValueError naming ``name`` unless ``m`` is a 2D map that keeps its node scans."""
    if not isinstance(m, SavedMap):
        raise TypeError(f"{name}: expected a SavedMap, got {type(m).__name__}")
    if m.dim != 2:
        raise ValueError(f"{name}: only 2D maps can be joined yet (got a {m.dim}D map)")
    if m.node_points is None or m.node_scans is None or m.graph is None:
        raise ValueError(
            f"{name}: a format-{m.format_version} map keeps no node scans; it cannot be "
            "joined (map its run again to write format 2)"
        )


def _locate(
    saved: SavedMap, new: SavedMap, nodes: Sequence[int], verb: str
) -> tuple[int, SE2, float]:
    """The first of ``nodes`` (the new map's) the global search places in the saved map:
    ``(node, T_saved_new, score)``."""
    from .localizer2d import Localizer2D

    loc = Localizer2D.from_saved_map(saved)
    reasons: list[str] = []
    assert new.node_points is not None
    new_poses = new.node_poses
    for node in nodes:
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
        f"{verb}: the second map could not be located in the first from no initial pose "
        f"(its nodes {list(nodes)} tried): no reliable overlap, nothing joined: "
        + " | ".join(reasons)
    )


def _scan_nodes(node_scans: tuple[int, ...], num_scans: int) -> FloatArray:
    """For every scan, the node it was mapped after (the last node at or before it; the
    first node for scans before it)."""
    idx = np.searchsorted(np.asarray(node_scans), np.arange(num_scans), side="right") - 1
    return np.clip(idx, 0, len(node_scans) - 1)


def agreeing_loops(
    matches: Sequence[LoopMatch], poses: dict[int, SE2], settings: LoopSettings
) -> list[int]:
    """Indices of the largest set of ``matches`` that all agree with one of them (the one
    most others agree with; ties: the earliest), in order. ``poses``: every node's pose in its
    own session's graph (the legs between two matches' nodes stay within one session)."""
    best: list[int] = []
    for i, first in enumerate(matches):
        group = [
            j
            for j, second in enumerate(matches)
            if j == i or loops_agree(first, second, poses, settings)
        ]
        if len(group) > len(best):
            best = group
    return best


def join_sessions(
    saved: SavedMap,
    new: SavedMap,
    *,
    config: MappingConfig | None = None,
    locate_nodes: Sequence[int] = range(10),
    max_distance: float = 2.0,
    prior_sigma: tuple[float, float] = (0.3, math.radians(5.0)),
    window: tuple[float, float] = (1.0, math.radians(15.0)),
    min_loops: int = 2,
    verb: str = "join",
) -> tuple[SavedMap, JoinReport]:
    """``saved`` and ``new`` (each a 2D map of format 2, in any frames) as one map in
    ``saved``'s frame (module docstring): returns the joint :class:`~scanreg.SavedMap` (the
    sessions of both) and how they were joined. Raises ValueError starting with ``verb`` and
    saying why when there is no reliable overlap.

    ``locate_nodes``: the new map's nodes the global search tries, in order;
    ``max_distance``: a new node is matched against its nearest old node when that lies
    within this (m) of where the fix puts it; ``prior_sigma`` (m, rad): the fix's assumed
    uncertainty per axis (the χ² test's prior); ``window`` (m, rad): the search half-widths;
    ``min_loops``: the agreeing inter-session loops needed to join (one alone could be a
    look-alike: the global search placed an ACES excerpt in an Intel map, and one loop would
    have followed it)."""
    from ..graph import Graph

    check_joinable(saved, "saved")
    check_joinable(new, "new")
    clash = set(new.sessions) & set(saved.sessions)
    if clash or not new.sessions:
        raise ValueError(f"session: expected a new, non-empty name, got {sorted(clash)}")
    assert new.node_points is not None and new.node_scans is not None and new.graph is not None
    assert saved.node_points is not None and saved.node_scans is not None
    assert saved.graph is not None and saved.grid is not None
    if isinstance(min_loops, bool) or not isinstance(min_loops, int) or min_loops < 1:
        raise ValueError(f"min_loops: expected an int >= 1, got {min_loops!r}")
    nodes = [int(n) for n in locate_nodes if 0 <= int(n) < new.num_nodes]
    if not nodes:
        raise ValueError(f"locate_nodes: expected node ids 0..{new.num_nodes - 1}")
    cfg = MappingConfig() if config is None else config
    located, found, score = _locate(saved, new, nodes, verb)

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
    matches: list[LoopMatch] = []
    fixes: list[SE2] = []  # T_saved_new each accepted match implies
    submaps: dict[int, Any] = {}
    # Forward from the located node, then back from it: the fix is freshest where it starts.
    order = [*range(located, len(new_poses)), *range(located - 1, -1, -1)]
    transform = found
    for n in order:
        if n == located - 1:
            transform = fixes[0] if fixes else found
        pose = new_poses[n]
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
        records.append(
            {
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
        )
        if match.accepted:
            matches.append(match)
            # The fix follows the second session: its drift since the last match stays small.
            transform = old_poses[anchor] @ match.measured @ pose.inverse()
            fixes.append(transform)
    accepted_records = [r for r in records if r["accepted"]]
    poses = {k: p for k, p in enumerate(old_poses)}
    poses.update({k_old + n: p for n, p in enumerate(new_poses)})
    kept = agreeing_loops(matches, poses, settings)
    for i, record in enumerate(accepted_records):
        if i not in kept:
            record["accepted"] = False
            record["reasons"] = [*record["reasons"], DISAGREES]
    if len(kept) < min_loops:
        raise ValueError(
            f"{verb}: located at node {located} of the second map (score {score:.2f}) but "
            f"{len(matches)} of {len(records)} of its nodes' scans matched the first map "
            f"(within {max_distance} m), {len(kept)} of them agreeing ({min_loops} needed): "
            "no reliable overlap, nothing joined"
        )

    g = Graph(2)
    for k, p in enumerate(old_poses):
        g.add_node(k, p)
    g.add_prior(0, old_poses[0], 1e6 * np.eye(3))
    start = fixes[kept[0]]  # the graph starts from the first agreeing loop's fix
    for n, p in enumerate(new_poses):
        g.add_node(k_old + n, start @ p)
    kernel = cfg.loop_kernel
    for offset, graph in ((0, saved.graph), (k_old, new.graph)):
        for e in graph.edges:
            loop = abs(e.to_id - e.from_id) != 1
            g.add_edge(
                offset + e.from_id,
                offset + e.to_id,
                e.measurement,
                e.information,
                kind="loop" if loop else "odometry",
                kernel=kernel if loop else None,
            )
    for i in kept:  # (no kernel: verified by agreement; see the module docstring)
        m = matches[i]
        g.add_edge(m.submap_node, m.node, m.measured, m.information, kind="loop")
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
    joined = SavedMap(
        dim=2,
        poses=(*scan_poses, *new_scan_poses),
        stamps=np.concatenate([saved.stamps, new.stamps]),
        graph=PoseGraph(dict(enumerate(node_poses)), graph_edges, frozenset({0})),
        odometry_poses=(*(saved.odometry_poses or saved.poses), *(new.odometry_poses or new.poses)),
        node_scans=(*saved.node_scans, *(saved.num_scans + s for s in new.node_scans)),
        node_points=node_points,
        sessions=(*saved.sessions, *new.sessions),
        scan_sessions=np.concatenate(
            [_sessions_of(saved), len(saved.sessions) + _sessions_of(new)]
        ),
        grid=grid,
        loops=(*saved.loops, *new_loops, *records),
    )
    report = JoinReport(
        located,
        score,
        len(records),
        len(kept),
        len(matches) - len(kept),
        tuple(records),
    )
    return joined, report


def _sessions_of(m: SavedMap) -> np.ndarray[Any, np.dtype[np.int64]]:
    if m.scan_sessions is None:
        return np.zeros(m.num_scans, dtype=np.int64)
    return m.scan_sessions


__all__ = ["DISAGREES", "JoinReport", "agreeing_loops", "check_joinable", "join_sessions"]
