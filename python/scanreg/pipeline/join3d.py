"""3D inter-session loop candidates for :func:`~scanreg.pipeline.join.join_sessions`.

Two 3D maps in unrelated frames share no prediction of where one's nodes lie in the other,
so the first loops come from what a node sees, not from where it is (steps 1-2 of the join):

1. **places** — every ``place_every``-th node cloud of the second map (the mapping's own
   setting; every node when it is 0 or 1) is described by Scan Context (:mod:`scanreg.place`,
   one layout for both maps) and looked up among the first map's nodes;
   each place retrieved is matched from :func:`scanreg.register_global`'s pose, then GICP
   against the retrieved node's submap, and judged by the verdict
   (:func:`~scanreg.pipeline.loops3d.match_loop_3d` with ``origin="place"``; the prediction
   is the descriptor's yaw with an uncertainty too wide to constrain anything; the verdict
   asks for ``inter_session_min_overlap`` of the node within the gate, not the in-session
   0.5: a look-alike street passes that);
2. **fill** — once at least ``min_loops`` of those loops agree with each other (the
   agreement test of step 3, :func:`~scanreg.pipeline.join.agreeing_loops`), the second
   map's nodes that place recognition missed are matched by GICP from the pose the nearest
   agreeing loop's fix predicts, against the submap of the first map's node nearest to it
   (``origin="graph"``, χ² against ``prior_sigma``). The fill adds coverage, never the
   evidence: without agreeing place loops it does not run, so a scene that only looks alike
   in one place is not walked along from that place.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..saved_map import SavedMap
from ..transform import SE3
from .join import Closure, agreeing_loops
from .loops3d import LoopMatch3D, Submap3D, build_submap_3d, match_loop_3d
from .mapping import LoopRecord
from .mapping3d import MIN_POINTS, MappingConfig3D
from .mapping_output import place_layout

#: How wide (m, rad per axis) the "prediction" of a place candidate is: the descriptor's yaw
#: and no translation, which must not constrain the match (its window is then the settings'
#: ``max_window``, its χ² test void).
UNINFORMED_SIGMA = (10.0, math.pi)
#: Places retrieved per node of the second map (the best first; the first accepted ends the
#: lookup).
PLACE_TOP_K = 3


def close_3d(
    saved: SavedMap,
    new: SavedMap,
    cfg: MappingConfig3D,
    *,
    max_distance: float,
    prior_sigma: tuple[float, float],
    min_loops: int,
    verb: str,
) -> Closure:
    """The inter-session candidates of two 3D maps (module docstring): every one as a
    ``loops.jsonl`` record, the accepted matches with the ``T_saved_new`` each implies.
    Raises ValueError starting with ``verb`` when no node of ``new`` is recognised in
    ``saved``."""
    assert saved.node_points is not None and saved.node_scans is not None
    assert new.node_points is not None and new.node_scans is not None
    # A loop between sessions needs more overlap than one within a session (no prediction).
    own = cfg.loops.thresholds
    strict = dataclasses.replace(
        own, min_overlap=max(own.min_overlap, cfg.loops.inter_session_min_overlap)
    )
    settings = dataclasses.replace(cfg.loops, thresholds=strict)
    old_poses = [_se3(p) for p in saved.node_poses]
    new_poses = [_se3(p) for p in new.node_poses]
    k_old = len(old_poses)
    old_points = dict(enumerate(saved.node_points))
    old_by_id = dict(enumerate(old_poses))
    submaps: dict[int, Submap3D] = {}

    def submap(anchor: int) -> Submap3D:
        if anchor not in submaps:
            h = cfg.submap_half_size
            submaps[anchor] = build_submap_3d(
                anchor,
                [n for n in range(anchor - h, anchor + h + 1) if 0 <= n < k_old],
                old_points,
                old_by_id,
                voxel_size=cfg.node_voxel_size,
                num_neighbors=cfg.odometry.num_neighbors,
                refine=cfg.refine_submaps,
            )
        return submaps[anchor]

    records: list[dict[str, Any]] = []
    matches: list[LoopMatch3D] = []
    fixes: list[Any] = []
    owner: list[int] = []  # the new node of each accepted match

    old_scans, new_scans = saved.node_scans, new.node_scans

    def keep(match: LoopMatch3D, anchor: int, n: int) -> None:
        record = LoopRecord(match, old_scans[anchor], saved.num_scans + new_scans[n]).as_dict()
        record["inter_session"] = True
        records.append(record)
        if match.accepted:
            matches.append(match)
            fixes.append(old_poses[anchor] @ match.measured @ new_poses[n].inverse())
            owner.append(n)

    # 1. places: one descriptor layout for both maps (their own may reach differently far).
    db = place_layout([*saved.node_points, *new.node_points])
    for k, pts in enumerate(saved.node_points):
        db.add(db.describe(pts), key=k)
    st, sr = UNINFORMED_SIGMA
    uninformed = np.diag([st**2] * 3 + [sr**2] * 3)
    placed: set[int] = set()
    tried = 0
    every = max(cfg.place_every, 1)
    for n, pts in enumerate(new.node_points):
        if n % every or len(pts) < MIN_POINTS:
            continue
        hits = db.query(db.describe(pts), PLACE_TOP_K, max_distance=settings.place_max_distance)
        for hit in hits:
            tried += 1
            anchor = int(hit.index)
            match = match_loop_3d(
                pts,
                k_old + n,
                submap(anchor),
                _se3(hit.initial_guess),
                uninformed,
                settings,
                origin="place",
                score=hit.distance,
            )
            keep(match, anchor, n)
            if match.accepted:
                placed.add(n)
                break
    if not matches:
        raise ValueError(
            f"{verb}: no node of the second map was recognised in the first ({tried} places "
            f"of Scan Context distance <= {settings.place_max_distance} retrieved for "
            f"{len(range(0, new.num_nodes, every))} of its {new.num_nodes} nodes, none "
            "matched): no reliable overlap, nothing joined"
        )
    first = matches[0]
    located_node = first.node - k_old
    located = (
        f"{len(placed)} of the {len(range(0, new.num_nodes, every))} nodes of the second map "
        "looked up recognised in the first by place recognition"
    )

    # 2. fill: only from place loops that already agree (they are the evidence).
    poses: dict[int, Any] = dict(enumerate(old_poses))
    poses.update({k_old + n: p for n, p in enumerate(new_poses)})
    agree = agreeing_loops(matches, poses, settings)
    if len(agree) >= min_loops:
        located_node = matches[agree[0]].node - k_old
        anchors_at = np.array([p.translation for p in old_poses])
        sources = np.array([owner[i] for i in agree])
        ts, rs = prior_sigma
        prior = np.diag([ts**2] * 3 + [rs**2] * 3)
        for n, pts in enumerate(new.node_points):
            if n in placed or len(pts) < MIN_POINTS:
                continue
            # The fix of the agreeing loop nearest along the second session: its drift since.
            fix = fixes[agree[int(np.argmin(np.abs(sources - n)))]]
            guess = _se3(fix @ new_poses[n])
            d = np.linalg.norm(anchors_at - guess.translation, axis=1)
            anchor = int(np.argmin(d))
            if d[anchor] > max_distance:
                continue
            predicted = _se3(old_poses[anchor].inverse() @ guess)
            match = match_loop_3d(pts, k_old + n, submap(anchor), predicted, prior, settings)
            keep(match, anchor, n)
    score = next(
        (m.score for m in matches if m.node - k_old == located_node and m.origin == "place"),
        math.nan,
    )
    return Closure(located_node, float(score), records, list(matches), fixes, located)


def _se3(pose: Any) -> SE3:
    assert isinstance(pose, SE3)
    return pose


__all__ = ["PLACE_TOP_K", "UNINFORMED_SIGMA", "close_3d"]
