"""Join a second session to a saved map, 2D or 3D: one graph over both (what ``extend`` and
``merge`` share).

:func:`join_sessions` takes two :class:`scanreg.SavedMap` of format 2 (they keep their nodes'
scans or clouds), each in its own frame — the frames need have nothing to do with each other.
Steps 1-2 find inter-session loop candidates, each dimension its own way; 3-4 are shared:

1. **locate** — 2D: nodes of the second map are searched for over the whole first map at any
   heading (:meth:`Localizer2D.relocalize`, the global search ``scanreg localize`` uses),
   until the verdict accepts one. 3D (:mod:`~scanreg.pipeline.join3d`): every node of the
   second map is looked up among the first's by Scan Context, and each place retrieved is
   matched from :func:`scanreg.register_global`'s pose (then GICP, the verdict);
2. **close** — 2D: from the located node forward, then back from it to the second map's
   start, every node is matched against the submap of its nearest node of the first map, from
   the pose the latest fix predicts (:func:`~scanreg.pipeline.loops.match_loop`: correlative
   search, point-to-line refinement, verdict, χ² against a generous prior); accepted matches
   refresh the fix, so the second session's own drift stays small against the search window;
   where none has for a stretch, the window and the prior grow with the path since the fix
   (the most that path could have drifted, as the mapping's wide search allows).
   3D: the nodes place recognition missed are matched the same way, by GICP from the fix of
   the nearest node it placed;
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

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..io.g2o import PoseGraph, PoseGraphEdge
from ..io.occupancy import occupancy_grid
from ..saved_map import SavedMap
from ..transform import SE2, SE3
from .loops import (
    MAX_DRIFT_PER_METRE,
    AgreementTolerances,
    LoopMatch,
    LoopSettings,
    loops_agree,
    match_loop,
)
from .mapping import MappingConfig
from .mapping3d import MappingConfig3D

#: Why an accepted inter-session match was left out of the graph.
DISAGREES = "disagrees with the other inter-session loops"
#: The voxel (m) of a joint 3D map's cloud (``scanreg map``'s ``--voxel-size`` default: a
#: saved map does not record the one it was made with).
MAP_VOXEL_SIZE = 0.2


@dataclass(frozen=True)
class JoinReport:
    """How a second session was joined to a saved map (:func:`join_sessions`): what
    :func:`~scanreg.pipeline.extend_map` and :func:`~scanreg.pipeline.merge_maps` return
    beside the joint map."""

    #: Second-map node first placed in the first map, and the score that placed it (2D: the
    #: global search's correlative score; 3D: the Scan Context distance of its place).
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
    """Raise ValueError naming ``name`` unless ``m`` is a map that keeps its node scans (2D)
    or clouds (3D)."""
    if not isinstance(m, SavedMap):
        raise TypeError(f"{name}: expected a SavedMap, got {type(m).__name__}")
    if m.node_points is None or m.node_scans is None or m.graph is None:
        raise ValueError(
            f"{name}: a format-{m.format_version} map keeps no node scans; it cannot be "
            "joined (map its run again to write format 2)"
        )


@dataclass
class Closure:
    """What one way of closing a second session against a saved map found (2D:
    :func:`_close_2d`; 3D: :func:`~scanreg.pipeline.join3d.close_3d`), before the agreement
    test: the matches the verdict accepted, in the order their records hold them."""

    #: Second-map node first placed in the saved map, and the score that placed it.
    located_node: int
    located_score: float
    #: Every candidate as a ``loops.jsonl`` record (node ids of the joint map).
    records: list[dict[str, Any]]
    #: The accepted matches (``submap_node``: a saved node; ``node``: ``K_saved + n``) ...
    matches: list[Any]
    #: ... and the ``T_saved_new`` each implies.
    fixes: list[SE2 | SE3]
    #: How the location was found, for the refusal's message.
    located: str


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
    matches: Sequence[Any], poses: Mapping[int, SE2 | SE3], settings: AgreementTolerances
) -> list[int]:
    """Indices of the largest set of ``matches`` that all agree with one of them (the one
    most others agree with; ties: the earliest), in order. ``poses``: every node's pose in its
    own session's graph (the legs between two matches' nodes stay within one session). 2D or
    3D matches alike (:func:`~scanreg.pipeline.loops.loops_agree`)."""
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


def _match_from_fix(
    points: FloatArray,
    node: int,
    submap: Any,
    predicted: SE2,
    settings: LoopSettings,
    *,
    prior_sigma: tuple[float, float],
    window: tuple[float, float],
    since_fix: float,
) -> LoopMatch:
    """Match one node of the second session from the pose the fix ``predicted``, searched
    over ``window`` with the χ² prior ``prior_sigma``; the fix was taken ``since_fix`` metres
    of the session's path ago.

    The fix is only as good as the session's own map over that path: once the most it could
    have drifted there (``MAX_DRIFT_PER_METRE``, as the mapping's wide search allows) exceeds
    the window, a node the window does not find is searched again over that bound, with the
    prior grown alike (on ACES' halves the fix turned 2.5° over 45 m without a match and the
    next place lay 1.4 m off, at the fixed window's edge). What is found so has only the drift
    bound to vouch for it, not the fix: it needs the strong score of a loop the graph
    disagrees with (``LoopSettings.hypothesis_min_score``; on Intel's halves a look-alike at
    0.54 would have carried the fix away from six true matches after it). Searching wider
    from the start let a look-alike 1.3 m off outscore the true place 4 m after a fix."""
    prior = np.diag([prior_sigma[0] ** 2, prior_sigma[0] ** 2, prior_sigma[1] ** 2])
    match = match_loop(points, node, submap, predicted, prior, settings, window=window)
    drift = MAX_DRIFT_PER_METRE * since_fix
    if match.accepted or drift <= window[0]:
        return match
    sigma = prior_sigma[0] + drift / settings.window_sigmas
    prior = np.diag([sigma**2, sigma**2, prior_sigma[1] ** 2])
    half = min(settings.wide_window[0], window[0] + drift)
    wide = match_loop(points, node, submap, predicted, prior, settings, window=(half, window[1]))
    if wide.accepted and wide.score >= settings.hypothesis_min_score:
        return wide
    again = wide.reasons or (
        f"score {wide.score:.2f} < {settings.hypothesis_min_score:.2f}, the least beyond the "
        "fix's window",
    )
    return dataclasses.replace(
        match, reasons=(*match.reasons, f"searched again over ±{half:.1f} m: " + "; ".join(again))
    )


def _close_2d(
    saved: SavedMap,
    new: SavedMap,
    cfg: MappingConfig,
    nodes: Sequence[int],
    *,
    max_distance: float,
    prior_sigma: tuple[float, float],
    window: tuple[float, float],
    verb: str,
) -> Closure:
    """2D: locate by the global search, then match every node from the fix (module
    docstring, steps 1-2)."""
    assert new.node_points is not None and new.node_scans is not None
    assert saved.node_scans is not None
    located, found, score = _locate(saved, new, nodes, verb)
    old_poses: list[SE2] = list(saved.node_poses)  # type: ignore[arg-type]
    k_old = len(old_poses)
    old_xy = np.array([p.translation for p in old_poses])
    new_poses: list[SE2] = list(new.node_poses)  # type: ignore[arg-type]
    settings = cfg.loops
    # Path (m) along the second session's nodes: its own drift since the fix grows with it.
    steps = np.linalg.norm(np.diff([p.translation for p in new_poses], axis=0), axis=1)
    path = np.concatenate([[0.0], np.cumsum(steps)])
    records: list[dict[str, Any]] = []
    matches: list[LoopMatch] = []
    fixes: list[SE2 | SE3] = []  # T_saved_new each accepted match implies
    fix_nodes: list[int] = []  # ... and the new node each was taken at
    submaps: dict[int, Any] = {}
    # Forward from the located node, then back from it: the fix is freshest where it starts.
    order = [*range(located, len(new_poses)), *range(located - 1, -1, -1)]
    transform, fixed_at = found, located  # the fix, and the new node it was taken at
    for n in order:
        if n == located - 1:
            transform = fixes[0] if fixes else found  # type: ignore[assignment]
            fixed_at = fix_nodes[0] if fix_nodes else located
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
        match = _match_from_fix(
            pts,
            k_old + n,
            submaps[anchor],
            predicted,
            settings,
            prior_sigma=prior_sigma,
            window=window,
            since_fix=abs(float(path[n] - path[fixed_at])),
        )
        records.append(
            {
                "submap_node": anchor,
                "node": k_old + n,
                "submap_scan": saved.node_scans[anchor],
                "scan": saved.num_scans + new.node_scans[n],
                "accepted": match.accepted,
                "reasons": list(match.reasons),
                "predicted": [float(v) for v in match.predicted.as_vector()],
                "measured": [float(v) for v in match.measured.as_vector()],
                # The window it was searched in: wider than ``window`` where the fix's drift
                # bound searched it again (_match_from_fix), as the mapping's records say.
                "window": [float(v) for v in match.window],
                "score": float(match.score),
                "inter_session": True,
            }
        )
        if match.accepted:
            matches.append(match)
            # The fix follows the second session: its drift since the last match stays small.
            transform = old_poses[anchor] @ match.measured @ pose.inverse()
            fixes.append(transform)
            fixed_at = n
            fix_nodes.append(n)
    return Closure(
        located,
        score,
        records,
        matches,
        fixes,
        f"located at node {located} of the second map (score {score:.2f})",
    )


def join_sessions(
    saved: SavedMap,
    new: SavedMap,
    *,
    config: MappingConfig | MappingConfig3D | None = None,
    locate_nodes: Sequence[int] = range(10),
    max_distance: float = 2.0,
    prior_sigma: tuple[float, float] = (0.3, math.radians(5.0)),
    window: tuple[float, float] = (1.0, math.radians(15.0)),
    min_loops: int = 2,
    min_fraction: float = 0.25,
    verb: str = "join",
) -> tuple[SavedMap, JoinReport]:
    """``saved`` and ``new`` (two 2D or two 3D maps of format 2, in any frames) as one map in
    ``saved``'s frame (module docstring): returns the joint :class:`~scanreg.SavedMap` (the
    sessions of both) and how they were joined. Raises ValueError starting with ``verb`` and
    saying why when there is no reliable overlap.

    2D: ``locate_nodes``: the new map's nodes the global search tries, in order;
    ``max_distance``: a new node is matched against its nearest old node when that lies
    within this (m) of where the fix puts it; ``prior_sigma`` (m, rad): the fix's assumed
    uncertainty per axis (the χ² test's prior); ``window`` (m, rad): the search half-widths;
    both as they are at the node the fix was taken at: their translation grows with the second
    session's path from there (its drift, up to 10 % of it; the window to at most
    ``LoopSettings.wide_window``).
    3D (:func:`~scanreg.pipeline.join3d.close_3d`): every new node is looked up by place
    recognition; ``max_distance`` and ``prior_sigma`` then serve the nodes it missed, matched
    from the fix (``locate_nodes`` and ``window`` are 2D's). ``min_loops``: the agreeing
    inter-session loops needed to join (one alone could be a look-alike: the global search
    placed an ACES excerpt in an Intel map, and one loop would have followed it), and at
    least ``min_fraction`` of the new nodes tried: a true overlap is followed node after node
    (Intel's halves: 25 of 29; ACES' 42 of 108), a look-alike here and there (an ACES excerpt
    located in an Intel map: 2 agreeing of 19 tried).
    ``config``: the mapping settings of the maps' dimension (defaults if ``None``)."""
    check_joinable(saved, "saved")
    check_joinable(new, "new")
    if saved.dim != new.dim:
        raise ValueError(f"{verb}: a {saved.dim}D map and a {new.dim}D map cannot be joined")
    clash = set(new.sessions) & set(saved.sessions)
    if clash or not new.sessions:
        raise ValueError(f"session: expected a new, non-empty name, got {sorted(clash)}")
    if isinstance(min_loops, bool) or not isinstance(min_loops, int) or min_loops < 1:
        raise ValueError(f"min_loops: expected an int >= 1, got {min_loops!r}")
    if isinstance(min_fraction, bool) or not (
        isinstance(min_fraction, (int, float)) and 0.0 <= min_fraction <= 1.0
    ):
        raise ValueError(f"min_fraction: expected a number in [0, 1], got {min_fraction!r}")
    assert saved.graph is not None
    k_old = saved.num_nodes
    if sorted(saved.graph.vertices) != list(range(k_old)):
        raise ValueError("saved: its graph's node ids are not 0..K-1")
    if saved.dim == 2:
        cfg2 = MappingConfig() if config is None else config
        if not isinstance(cfg2, MappingConfig):
            raise TypeError(f"config: expected MappingConfig, got {type(cfg2).__name__}")
        nodes = [int(n) for n in locate_nodes if 0 <= int(n) < new.num_nodes]
        if not nodes:
            raise ValueError(f"locate_nodes: expected node ids 0..{new.num_nodes - 1}")
        closure = _close_2d(
            saved,
            new,
            cfg2,
            nodes,
            max_distance=max_distance,
            prior_sigma=prior_sigma,
            window=window,
            verb=verb,
        )
        settings: AgreementTolerances = cfg2.loops
        kernel = cfg2.loop_kernel
    else:
        from .join3d import close_3d

        cfg3 = MappingConfig3D() if config is None else config
        if not isinstance(cfg3, MappingConfig3D):
            raise TypeError(f"config: expected MappingConfig3D, got {type(cfg3).__name__}")
        closure = close_3d(
            saved,
            new,
            cfg3,
            max_distance=max_distance,
            prior_sigma=prior_sigma,
            min_loops=min_loops,
            verb=verb,
        )
        settings = cfg3.loops
        kernel = cfg3.loop_kernel

    # 3. agree: the accepted inter-session loops must tell one story.
    matches, records = closure.matches, closure.records
    poses: dict[int, SE2 | SE3] = dict(enumerate(saved.node_poses))
    poses.update({k_old + n: p for n, p in enumerate(new.node_poses)})
    kept = agreeing_loops(matches, poses, settings)
    accepted_records = [r for r in records if r["accepted"]]
    for i, record in enumerate(accepted_records):
        if i not in kept:
            record["accepted"] = False
            record["reasons"] = [*record["reasons"], DISAGREES]
    needed = max(min_loops, math.ceil(min_fraction * len(records)))
    if len(kept) < needed:
        raise ValueError(
            f"{verb}: {closure.located} but {len(matches)} of {len(records)} of its nodes' "
            f"scans matched the first map (within {max_distance} m), {len(kept)} of them "
            f"agreeing ({needed} needed: at least {min_loops} and {min_fraction:.0%} of those "
            "tried): no reliable overlap, nothing joined"
        )
    joined = _joint_map(saved, new, [matches[i] for i in kept], closure.fixes[kept[0]], kernel)
    joined = dataclasses.replace(joined, loops=(*joined.loops, *records))
    report = JoinReport(
        closure.located_node,
        closure.located_score,
        len(records),
        len(kept),
        len(matches) - len(kept),
        tuple(records),
    )
    return joined, report


#: g2o's 3D rotation error is half the rotation vector: a saved graph's information is
#: ``D Λ D`` of the graph's own (:func:`scanreg.io.g2o.g2o_information`).
_G2O_SCALE = {2: np.ones(3), 3: np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])}


def _joint_map(
    saved: SavedMap, new: SavedMap, loops: Sequence[Any], start: SE2 | SE3, kernel: Any
) -> SavedMap:
    """Step 4 (module docstring): one graph over both maps' nodes and edges and the agreeing
    ``loops``, the new nodes starting at ``start @ pose``; every scan laid on its node; the
    map (2D grid, 3D cloud and places) made again from the nodes at their joint poses."""
    from ..graph import Graph

    assert saved.graph is not None and new.graph is not None
    assert saved.node_points is not None and saved.node_scans is not None
    assert new.node_points is not None and new.node_scans is not None
    dim = saved.dim
    scale = _G2O_SCALE[dim]
    old_poses = list(saved.node_poses)
    new_poses = list(new.node_poses)
    k_old = len(old_poses)
    g = Graph(dim)
    for k, p in enumerate(old_poses):
        g.add_node(k, p)
    g.add_prior(0, old_poses[0], 1e6 * np.eye(len(scale)))
    fix: Any = start  # (of the maps' dimension, as their poses)
    for n, p in enumerate(new_poses):
        g.add_node(k_old + n, fix @ p)
    for offset, graph in ((0, saved.graph), (k_old, new.graph)):
        for e in graph.edges:
            loop = abs(e.to_id - e.from_id) != 1
            g.add_edge(
                offset + e.from_id,
                offset + e.to_id,
                e.measurement,
                e.information / np.outer(scale, scale),
                kind="loop" if loop else "odometry",
                kernel=kernel if loop else None,
            )
    for m in loops:  # (no kernel: verified by agreement; see the module docstring)
        g.add_edge(m.submap_node, m.node, m.measured, m.information, kind="loop")
    g.optimize()
    g.move_gauge(0, old_poses[0])  # the old map's frame kept exactly (Graph.move_gauge)
    joint = g.poses()
    node_poses = [joint[k] for k in range(k_old + len(new_poses))]

    def moved(
        poses: tuple[Any, ...], node_scans: tuple[int, ...], before: list[Any], offset: int
    ) -> list[Any]:
        owner = _scan_nodes(node_scans, len(poses))
        return [
            node_poses[offset + int(o)] @ before[int(o)].inverse() @ p
            for p, o in zip(poses, owner, strict=True)
        ]

    scan_poses = moved(saved.poses, saved.node_scans, old_poses, 0)
    new_scan_poses = moved(new.poses, new.node_scans, new_poses, k_old)
    node_points = (*saved.node_points, *new.node_points)
    graph_edges = tuple(
        PoseGraphEdge(e.i, e.j, e.measurement, e.information * np.outer(scale, scale))
        for e in g.edges
        if e.kind != "prior"
    )
    new_loops = []
    for r in new.loops:
        rec = dict(r)
        for key in ("submap_node", "node"):
            rec[key] += k_old
        for key in ("submap_scan", "scan"):
            rec[key] += saved.num_scans
        new_loops.append(rec)
    grid = map_points = places = None
    if dim == 2:
        assert saved.grid is not None
        grid = occupancy_grid(
            node_poses,  # type: ignore[arg-type]
            list(node_points),
            resolution=saved.grid.resolution,
        )
    else:
        from ..saved_map import Places
        from .mapping_output import map_cloud, places_of_nodes

        cloud = map_cloud(node_poses, node_points, MAP_VOXEL_SIZE)
        map_points = np.ascontiguousarray(cloud.astype(np.float32).astype(np.float64))
        places = Places(*places_of_nodes(node_poses, node_points))
    return SavedMap(
        dim=dim,
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
        map_points=map_points,
        places=places,
        loops=(*saved.loops, *new_loops),
    )


def _sessions_of(m: SavedMap) -> np.ndarray[Any, np.dtype[np.int64]]:
    if m.scan_sessions is None:
        return np.zeros(m.num_scans, dtype=np.int64)
    return m.scan_sessions


__all__ = [
    "DISAGREES",
    "Closure",
    "JoinReport",
    "agreeing_loops",
    "check_joinable",
    "join_sessions",
]
