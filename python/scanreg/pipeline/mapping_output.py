"""Write a mapping run to a folder: poses, graph, loops, occupancy map and a plot.

=====================  ==================================================================
``poses_kitti.txt``    every scan's optimized ``T_world_scan`` (KITTI, 12 numbers a line)
``poses_tum.txt``      the same with each scan's own timestamp (TUM)
``odometry_tum.txt``   the odometry alone, before loop closure (TUM)
``graph.g2o``          the pose graph (nodes at their optimized poses; ``FIX 0``)
``loops.jsonl``        every loop candidate: nodes, scans, verdict, reasons, information
``map.pgm/.yaml``      2D: the occupancy grid, ROS ``map_server`` convention; ``map.png``
``map.ply/.pcd``       3D: the node clouds at their optimized poses, voxelized (world frame)
``places.npz``         3D: the nodes' optimized poses and Scan Context descriptors (the
                       place database :class:`~scanreg.pipeline.MapLocalizer` relocalizes with)
``trajectory.png``     odometry against the optimized trajectory, loop edges drawn
``summary.json``       :func:`summary`, with the run's self-check (:mod:`.map_check`)
``contradictions.csv`` ``x,y`` (3D: ``x,y,z``) of every return the self-check found contradicted
``map_data.npz``       the exact state :class:`scanreg.SavedMap` reads (node scans included)
``manifest.json``      format version, sensor, frames, sessions, what each file is
=====================  ==================================================================
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import FloatArray, check_flag, positive
from ..io.g2o import PoseGraph, PoseGraphEdge
from ..preprocess import voxel_downsample
from ..saved_map import SavedMap, refresh_manifest
from ..transform import SE2, SE3
from .map_check import MapCheck, check_map
from .mapping import MappingResult


def scan_stamps(result: MappingResult[Any]) -> np.ndarray[Any, np.dtype[np.float64]]:
    """Every scan's stamp; the scan index stands in where the input had no times."""
    if all(s is not None for s in result.stamps):
        return np.array(result.stamps, dtype=np.float64)
    return np.arange(result.num_scans, dtype=np.float64)


def pose_graph(result: MappingResult[Any]) -> PoseGraph:
    """The run's graph as :class:`scanreg.io.g2o.PoseGraph` (the information in scanreg's
    ordering: 2D ``[x, y, θ]`` as g2o's; 3D translation first, as g2o's ``EDGE_SE3:QUAT``;
    the prior on node 0 becomes ``FIX 0``)."""
    g = result.graph
    vertices = dict(g.poses())
    # 3D: g2o's rotation error is half the rotation vector (see scanreg.io.g2o.g2o_information);
    # done here on the information itself, which may be rank-deficient (degenerate loops).
    d = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0]) if g.dim == 3 else np.ones(3)
    edges = [
        PoseGraphEdge(e.i, e.j, e.measurement, d[:, None] * e.information * d[None, :])
        for e in g.edges
        if e.kind != "prior"
    ]
    return PoseGraph(vertices, tuple(edges), frozenset({0}))


def map_points_3d(result: MappingResult[Any], voxel_size: float = 0.2) -> FloatArray:
    """A 3D run's map: every node's cloud at its optimized pose (world frame), voxelized to
    ``voxel_size`` (m; 0 keeps every point)."""
    if result.graph.dim != 3:
        raise ValueError("result: map_points_3d needs a 3D run (an SE3 graph)")
    node_poses = result.graph.poses()
    return map_cloud(
        [node_poses[n] for n in range(len(result.node_points))], result.node_points, voxel_size
    )


def map_cloud(node_poses: Any, node_points: Any, voxel_size: float = 0.2) -> FloatArray:
    """Node clouds (each in its node's frame) laid at ``node_poses`` (``T_world_node``, one
    per cloud) and voxelized to ``voxel_size`` (m; 0 keeps every point): a 3D map."""
    if not (math.isfinite(voxel_size) and voxel_size >= 0):
        raise ValueError(f"voxel_size: must be finite and >= 0, got {voxel_size}")
    parts = [pose.apply(pts) for pose, pts in zip(node_poses, node_points, strict=True)]
    pts = np.ascontiguousarray(np.vstack(parts))
    if voxel_size > 0:
        pts = np.ascontiguousarray(voxel_downsample(pts, voxel_size).points)
    return pts


def places_of(result: MappingResult[Any]) -> tuple[FloatArray, FloatArray, float, float]:
    """A 3D run's place database: ``poses`` ``(K, 4, 4)`` the nodes' optimized
    ``T_world_node``, ``descriptors`` ``(K, rings, sectors)`` their Scan Context (computed from
    the node clouds, out to ``max_radius``: as far as the keyframes reach, at most 80 m),
    ``max_radius`` and ``height_offset``."""
    if result.graph.dim != 3:
        raise ValueError("result: places_of needs a 3D run (an SE3 graph)")
    node_poses = result.graph.poses()
    return places_of_nodes(
        [node_poses[n] for n in range(len(result.node_points))], result.node_points
    )


def place_layout(node_points: Any) -> Any:
    """The :class:`~scanreg.place.PlaceDatabase` (empty) whose layout a map's nodes are
    described with: out to as far as the keyframes reach, at most 80 m."""
    from ..place import PlaceDatabase

    reach = max(float(np.hypot(p[:, 0], p[:, 1]).max()) for p in node_points if len(p))
    return PlaceDatabase(max_radius=min(80.0, max(reach, 1.0)))


def places_of_nodes(
    node_poses: Any, node_points: Any
) -> tuple[FloatArray, FloatArray, float, float]:
    """:func:`places_of` for nodes given as poses (``T_world_node``) and clouds (own frame)."""
    db = place_layout(node_points)
    descriptors = np.array([db.describe(p).descriptor for p in node_points])
    poses = np.array([p.as_matrix() for p in node_poses])
    return poses, descriptors, float(db.max_radius), float(db.height_offset)


def write_places(path: Path, result: MappingResult[Any]) -> Path:
    """Write :func:`places_of` as ``places.npz`` (keys ``poses``, ``descriptors``,
    ``max_radius``, ``height_offset``)."""
    poses, descriptors, max_radius, height_offset = places_of(result)
    p = Path(path)
    with p.open("wb") as fh:
        np.savez(
            fh,
            poses=poses,
            descriptors=descriptors,
            max_radius=np.float64(max_radius),
            height_offset=np.float64(height_offset),
        )
    return p


def write_outputs(
    folder: str | os.PathLike[str],
    result: MappingResult[Any],
    *,
    resolution: float = 0.05,
    voxel_size: float = 0.2,
    plot: bool = True,
    check: MapCheck | None = None,
    session: str = "session-0",
) -> dict[str, Path]:
    """Write every file of the table above into ``folder`` (created); returns their paths.
    ``resolution``: the 2D occupancy grid's cell (m); ``voxel_size``: the 3D map's voxel (m).
    ``plot=False`` skips ``trajectory.png`` (the only file that needs matplotlib).
    ``check``: the run's self-check if already made (else it is made here). ``session``:
    the run's name in the manifest (e.g. the input's path). The map itself goes through
    :class:`scanreg.SavedMap` (``manifest.json``, ``map_data.npz``)."""
    if not isinstance(folder, (str, os.PathLike)):
        raise TypeError(f"folder: expected a str or os.PathLike, got {type(folder).__name__}")
    if not isinstance(result, MappingResult):
        raise TypeError(
            f"result: expected a MappingResult (run_mapping, run_mapping_3d), "
            f"got {type(result).__name__}"
        )
    positive(resolution, "resolution")
    positive(voxel_size, "voxel_size")
    check_flag(plot, "plot")
    if check is not None and not isinstance(check, MapCheck):
        raise TypeError(f"check: expected a MapCheck or None, got {type(check).__name__}")
    if not isinstance(session, str) or not session:
        raise ValueError(f"session: expected a non-empty str, got {session!r}")
    out = Path(folder)
    saved = SavedMap.from_result(
        result, session=session, resolution=resolution, voxel_size=voxel_size
    )
    paths = saved.save(out)
    check = check_map(result) if check is None else check
    paths["contradictions"] = out / "contradictions.csv"
    header = "x,y" if result.graph.dim == 2 else "x,y,z"
    points = check.contradiction_points
    np.savetxt(paths["contradictions"], points, "%.3f", ",", header=header, comments="")
    if plot:
        paths["plot"] = plot_mapping(out / "trajectory.png", result)
    paths["summary"] = out / "summary.json"
    headline = summary(result, check)
    paths["summary"].write_text(json.dumps(headline, indent=2) + "\n", encoding="utf-8")
    refresh_manifest(out)
    return paths


def plot_mapping(path: Path, result: MappingResult[Any]) -> Path:
    """Odometry (grey) against the optimized trajectory (blue), accepted loop edges (green)
    and rejected candidates (red, thin), top view."""
    from ..plot import _check_path, _figure, _save

    p = _check_path(path)
    fig = _figure(7.0, 7.0)
    ax = fig.add_subplot(1, 1, 1)
    before = np.array([q.translation for q in result.odometry_poses])
    after = np.array([q.translation for q in result.poses])
    ax.plot(before[:, 0], before[:, 1], color="#999999", lw=0.8, label="odometry")
    ax.plot(after[:, 0], after[:, 1], color="#1f77b4", lw=0.8, label="after loop closure")
    for accepted, color, lw in ((False, "#d62728", 0.4), (True, "#2ca02c", 0.6)):
        first = True
        for r in result.loops:
            if r.accepted != accepted:
                continue
            a, b = after[r.submap_scan], after[r.scan]
            label = None
            if first:
                n = sum(x.accepted == accepted for x in result.loops)
                label = f"{'accepted' if accepted else 'rejected'} loops ({n})"
                first = False
            ax.plot([a[0], b[0]], [a[1], b[1]], color=color, lw=lw, label=label)
    # A revisit on the same lane joins two points metres apart or less: its edge is
    # invisible at the scale of the map, so the loop's later end is marked too.
    ends = np.array([after[r.scan] for r in result.loops if r.accepted]).reshape(-1, after.shape[1])
    if len(ends):
        ax.scatter(ends[:, 0], ends[:, 1], s=6, color="#2ca02c", zorder=3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{result.num_scans} scans, {len(result.node_scans)} nodes")
    return _save(fig, p)


def summary(result: MappingResult[Any], check: MapCheck | None = None) -> dict[str, Any]:
    """A JSON-ready summary of a run (with its self-check under ``self_check`` if given)."""
    t = result.timing
    last: SE2 | SE3 = result.poses[-1]
    out = {
        "num_scans": result.num_scans,
        "num_nodes": len(result.node_scans),
        "skipped_scans": len(result.skipped),
        "odometry_rejected_scans": len(result.rejected),
        "odometry_held_scans": len(result.held),
        "odometry_reseeded_scans": list(result.reseeded),
        "loops_accepted": len(result.accepted_loops),
        "loops_rejected": len(result.rejected_loops),
        "loops_by_evidence": {
            kind: sum(getattr(r.match, "evidence", "graph") == kind for r in result.accepted_loops)
            for kind in ("graph", "loops")
        },
        "back_end_recoveries": list(result.graph.recoveries),
        "anchored_nodes": list(result.graph.anchored),
        "partial": result.partial,
        "final_pose": [float(v) for v in last.as_vector()],
        "timing": {
            "odometry": t.odometry,
            "candidates": t.candidates,
            "matching": t.matching,
            "optimization": t.optimization,
            "total": t.total,
            "loop_search_max": t.loop_search_max,
        },
        "timing_cpu": {
            "odometry": t.odometry_cpu,
            "candidates": t.candidates_cpu,
            "matching": t.matching_cpu,
            "optimization": t.optimization_cpu,
            "total": t.total_cpu,
        },
        "scans_per_second": result.num_scans / t.total if t.total > 0 else None,
    }
    if check is not None:
        out["self_check"] = check.as_dict()
    return out
