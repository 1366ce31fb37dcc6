"""A saved map: the folder ``scanreg map`` writes, as one versioned Python object.

:class:`SavedMap` is what a mapping run leaves behind and what ``scanreg localize`` (and
later runs that extend or merge maps) read: the pose graph with every node's scan or cloud,
every scan's pose with its session, and the map itself (2D: an occupancy grid; 3D: the
voxelized cloud and the Scan Context place database).

>>> saved = SavedMap.from_result(result, session="intel.clf")
>>> saved.save("out/")
>>> saved = SavedMap.load("out/")
>>> saved.describe()["num_nodes"]

The folder holds ``manifest.json`` — ``format`` (``"scanreg-map"``), ``format_version``,
``sensor`` (``"2d"``/``"3d"``), ``frames`` (what each pose and point frame is),
``sessions``, and ``files`` (every file and what it holds) — and:

=====================  ==================================================================
``map_data.npz``       the exact state: every scan's pose, odometry pose, stamp and
                       session; every node's scan index, pose and points (node frame); the
                       graph's edges; 2D the occupancy probabilities
``poses_kitti.txt``    every scan's ``T_world_scan`` (KITTI), for other tools
``poses_tum.txt``      the same with each scan's own stamp (TUM)
``odometry_tum.txt``   the odometry alone, before loop closure (TUM)
``graph.g2o``          the pose graph (g2o text)
``loops.jsonl``        every loop candidate, accepted or not
``map.pgm/.yaml/.png`` 2D: the occupancy grid (ROS ``map_server``)
``map.ply/.pcd``       3D: the node clouds at their poses, voxelized (float32 coordinates)
``places.npz``         3D: the nodes' poses and Scan Context descriptors
=====================  ==================================================================

A map of several sessions (:func:`scanreg.pipeline.extend_map`,
:func:`scanreg.pipeline.merge_maps`) also holds
``session_K_poses_tum.txt``: session K's scans' poses, each with its own stamp.

Format versions: **2** (this one) as above. **1**: what ``scanreg map`` wrote before the
manifest (a folder without ``manifest.json``): read, with what it lacks left ``None`` (the
node scans, the sessions), so it can be localized in but not extended. Any other version is
refused with a :class:`~scanreg.io.FileFormatError` naming it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ._validate import FloatArray
from ._version import __version__
from .io._common import FileFormatError
from .io.g2o import PoseGraph, PoseGraphEdge
from .io.occupancy import OccupancyGrid
from .transform import SE2, SE3

#: The manifest's ``format``.
FORMAT = "scanreg-map"
#: The version :meth:`SavedMap.save` writes.
FORMAT_VERSION = 2
#: Versions :meth:`SavedMap.load` reads.
READABLE_VERSIONS = (1, 2)
MANIFEST = "manifest.json"
DATA = "map_data.npz"

#: What a damaged ``.npz`` raises while read (a zip archive of ``.npy`` members).
_NPZ_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)

#: What each file of a map folder holds (the manifest's ``files``).
FILE_DESCRIPTIONS: dict[str, str] = {
    MANIFEST: "this manifest",
    DATA: "exact state: scans' poses, stamps, sessions; nodes' scans, poses, points; edges",
    "poses_kitti.txt": "every scan's optimized T_world_scan (KITTI)",
    "poses_tum.txt": "every scan's optimized T_world_scan with its own stamp (TUM)",
    "odometry_tum.txt": "the odometry alone, before loop closure (TUM)",
    "graph.g2o": "the pose graph: nodes at their optimized poses, FIX 0",
    "loops.jsonl": "every loop candidate: nodes, scans, verdict, reasons, information",
    "map.pgm": "2D occupancy grid image (ROS map_server)",
    "map.yaml": "2D occupancy grid metadata (ROS map_server)",
    "map.png": "2D occupancy grid as PNG",
    "map.ply": "3D map: node clouds at their optimized poses, voxelized",
    "map.pcd": "3D map: the same as map.ply",
    "places.npz": "3D place database: nodes' poses and Scan Context descriptors",
    "trajectory.png": "odometry against the optimized trajectory, loop edges",
    "summary.json": "the run's summary and self-check",
    "contradictions.csv": "self-check: returns the map contradicts (x,y; 3D x,y,z)",
    "config.toml": "the mapping configuration the run used",
    "report.html": "the run's HTML report",
}

#: What the poses and points of each sensor kind are.
FRAMES: dict[int, dict[str, str]] = {
    2: {
        "world": "the map frame: the first scan's base pose",
        "scan": "the robot base at the scan's time (the laser's mounting applied)",
        "points": "node scans in their scan frame, (x, y) m",
    },
    3: {
        "world": "the map frame: the first sweep's sensor pose",
        "scan": "the LiDAR at the sweep's reference time",
        "points": "node clouds in their scan frame, (x, y, z) m",
    },
}

Pose = SE2 | SE3


class Places(NamedTuple):
    """A 3D map's place database (``places.npz``), as
    :class:`~scanreg.pipeline.MapLocalizer`'s ``places`` takes it."""

    poses: FloatArray
    descriptors: FloatArray
    max_radius: float
    height_offset: float


@dataclass(frozen=True, eq=False)
class SavedMap:
    """A mapping run's map (see the module docstring). Poses are ``T_world_scan``."""

    #: 2 or 3.
    dim: int
    #: Every scan's optimized pose, in step order.
    poses: tuple[Pose, ...]
    #: Every scan's stamp (s; the scan index where the input had none).
    stamps: FloatArray
    #: The pose graph: nodes at their optimized poses (node id = vertex id), edges, fixed.
    graph: PoseGraph | None
    #: Every scan's odometry pose (before loop closure); ``None`` if absent (format 1).
    odometry_poses: tuple[Pose, ...] | None = None
    #: Scan index of every node, by node id (``None``: format 1).
    node_scans: tuple[int, ...] | None = None
    #: Every node's scan or cloud in its own frame, by node id (``None``: format 1).
    node_points: tuple[FloatArray, ...] | None = None
    #: Session names (the inputs mapped), and every scan's session index.
    sessions: tuple[str, ...] = ()
    scan_sessions: np.ndarray[Any, np.dtype[np.int64]] | None = None
    #: 2D: the occupancy grid.
    grid: OccupancyGrid | None = None
    #: 3D: the voxelized map cloud, world frame.
    map_points: FloatArray | None = None
    #: 3D: the place database.
    places: Places | None = None
    #: Every loop candidate's record (``loops.jsonl``).
    loops: tuple[dict[str, Any], ...] = ()
    format_version: int = FORMAT_VERSION
    #: The folder it was loaded from (``None``: built in memory).
    folder: Path | None = field(default=None, compare=False)

    # -- describing -------------------------------------------------------------------
    @property
    def num_scans(self) -> int:
        return len(self.poses)

    @property
    def num_nodes(self) -> int:
        return 0 if self.graph is None else len(self.graph.vertices)

    @property
    def node_poses(self) -> tuple[Pose, ...]:
        """Every node's optimized pose, by node id."""
        if self.graph is None:
            return ()
        return tuple(self.graph.vertices[k] for k in sorted(self.graph.vertices))

    @property
    def frames(self) -> dict[str, str]:
        return dict(FRAMES[self.dim])

    def session_poses(self, session: int | str) -> tuple[Pose, ...]:
        """The poses of one session's scans (by index or name), in step order."""
        if self.scan_sessions is None:
            raise ValueError("session: this map (format 1) records no sessions")
        k = self.sessions.index(session) if isinstance(session, str) else int(session)
        if not 0 <= k < len(self.sessions):
            raise ValueError(f"session: expected 0..{len(self.sessions) - 1}, got {session!r}")
        return tuple(p for p, s in zip(self.poses, self.scan_sessions, strict=True) if s == k)

    def submap(
        self, anchor: int, *, half_size: int = 2, resolution: float = 0.05, voxel_size: float = 0.05
    ) -> Any:
        """2D: the submap of node ``anchor`` — its scan and those of ``half_size`` nodes on
        each side, in its frame, prepared for loop matching
        (:class:`~scanreg.pipeline.loops.Submap2D`, as the mapping run built it: submaps are
        not stored, the node scans they are made of are)."""
        from .pipeline.loops import build_submap

        if self.dim != 2 or self.node_points is None:
            raise ValueError("map: submap needs a 2D map with its node scans (format 2)")
        k = self.num_nodes
        if isinstance(anchor, bool) or not isinstance(anchor, int) or not 0 <= anchor < k:
            raise ValueError(f"anchor: expected a node id 0..{k - 1}, got {anchor!r}")
        nodes = [n for n in range(anchor - half_size, anchor + half_size + 1) if 0 <= n < k]
        return build_submap(
            anchor,
            nodes,
            dict(enumerate(self.node_points)),
            dict(enumerate(self.node_poses)),  # type: ignore[arg-type]
            resolution=resolution,
            voxel_size=voxel_size,
        )

    def occupied_points(self) -> FloatArray:
        """2D: the occupied cells' centres, ``(M, 2)`` world frame (what a localizer reads)."""
        from .io.occupancy import occupied_points

        if self.grid is None:
            raise ValueError("map: occupied_points needs a 2D map with an occupancy grid")
        return occupied_points(self.grid)

    def describe(self) -> dict[str, Any]:
        """A JSON-ready description: version, sensor, frames, sessions, counts."""
        out: dict[str, Any] = {
            "format": FORMAT,
            "format_version": self.format_version,
            "sensor": f"{self.dim}d",
            "frames": self.frames,
            "sessions": list(self.sessions),
            "num_scans": self.num_scans,
            "num_nodes": self.num_nodes,
            "num_edges": 0 if self.graph is None else len(self.graph.edges),
            "loops_accepted": sum(bool(r.get("accepted")) for r in self.loops),
            # (those closing one session against another: extend, merge)
            "inter_session_loops": sum(
                bool(r.get("accepted")) and bool(r.get("inter_session")) for r in self.loops
            ),
            "has_node_points": self.node_points is not None,
        }
        if self.scan_sessions is not None:
            counts = np.bincount(self.scan_sessions, minlength=len(self.sessions))
            out["scans_per_session"] = [int(c) for c in counts]
        if self.grid is not None:
            out["grid"] = {
                "resolution": self.grid.resolution,
                "cells": list(self.grid.probability.shape),
                "origin": [float(v) for v in self.grid.origin],
            }
        if self.map_points is not None:
            out["map_points"] = len(self.map_points)
        if self.places is not None:
            out["places"] = len(self.places.poses)
        if self.folder is not None:
            out["folder"] = str(self.folder)
        return out

    # -- moving -----------------------------------------------------------------------
    def transformed(self, transform: SE2 | SE3) -> SavedMap:
        """This map in another frame: a new map with ``transform`` (``T_new_world``: an
        :class:`~scanreg.SE2` for a 2D map, :class:`~scanreg.SE3` for 3D) applied to all that
        is in the map frame — every scan's pose and odometry pose (``transform @ pose``), the
        graph's node poses; 2D the occupancy grid, rebuilt from the node scans at the moved
        node poses at the same resolution and thresholds (a grid cannot be turned cell for
        cell, so its origin and extent follow the scans); 3D the map cloud and the places'
        poses. What is in a node's own frame (node scans, graph edges, the loops' records,
        Scan Context descriptors), the stamps and sessions are kept. The new map is in memory
        only (``folder`` ``None``).

        ``m.transformed(T).transformed(T.inverse())`` is ``m`` to round-off.
        """
        kind = SE2 if self.dim == 2 else SE3
        if type(transform) is not kind:
            raise TypeError(
                f"transform: expected an {kind.__name__} for a {self.dim}D map, "
                f"got {type(transform).__name__}"
            )

        def move(pose: Pose) -> Pose:
            return transform @ pose  # type: ignore[operator]

        graph = self.graph
        if graph is not None:
            vertices = {k: move(p) for k, p in graph.vertices.items()}
            graph = dataclasses.replace(graph, vertices=vertices)
        grid = self.grid
        if grid is not None:
            from .io.occupancy import occupancy_grid

            if self.node_points is None or graph is None:
                raise ValueError(
                    "map: transformed needs the node scans to rebuild a 2D map's grid "
                    f"(a format-{self.format_version} map has none)"
                )
            nodes = [graph.vertices[k] for k in sorted(graph.vertices)]
            rebuilt = occupancy_grid(nodes, list(self.node_points), resolution=grid.resolution)  # type: ignore[arg-type]
            grid = dataclasses.replace(
                rebuilt, occupied_thresh=grid.occupied_thresh, free_thresh=grid.free_thresh
            )
        places = self.places
        if places is not None:
            matrix = transform.as_matrix()
            moved = np.array([matrix @ p for p in places.poses]).reshape(places.poses.shape)
            places = places._replace(poses=moved)
        return dataclasses.replace(
            self,
            poses=tuple(move(p) for p in self.poses),
            odometry_poses=(
                None if self.odometry_poses is None else tuple(move(p) for p in self.odometry_poses)
            ),
            graph=graph,
            grid=grid,
            map_points=None if self.map_points is None else transform.apply(self.map_points),
            places=places,
            folder=None,
        )

    # -- building ---------------------------------------------------------------------
    @classmethod
    def from_result(
        cls,
        result: Any,
        *,
        session: str = "session-0",
        resolution: float = 0.05,
        voxel_size: float = 0.2,
    ) -> SavedMap:
        """The map of a :class:`~scanreg.pipeline.MappingResult` (2D grid at ``resolution``;
        3D cloud at ``voxel_size``, its coordinates rounded to float32 as ``map.ply``
        stores them)."""
        from .io.occupancy import occupancy_grid
        from .pipeline.mapping import MappingResult
        from .pipeline.mapping_output import map_points_3d, pose_graph, scan_stamps

        if not isinstance(result, MappingResult):
            raise TypeError(f"result: expected a MappingResult, got {type(result).__name__}")
        if not isinstance(session, str) or not session:
            raise ValueError(f"session: expected a non-empty str, got {session!r}")
        dim = result.graph.dim
        graph = pose_graph(result)
        node_points = tuple(np.ascontiguousarray(p, dtype=np.float64) for p in result.node_points)
        grid = map_points = places = None
        if dim == 2:
            poses = [graph.vertices[n] for n in range(len(node_points))]
            grid = occupancy_grid(poses, list(node_points), resolution=resolution)  # type: ignore[arg-type]
        else:
            from .pipeline.mapping_output import places_of

            cloud = map_points_3d(result, voxel_size)
            map_points = np.ascontiguousarray(cloud.astype(np.float32).astype(np.float64))
            places = Places(*places_of(result))
        return cls(
            dim=dim,
            poses=tuple(result.poses),
            stamps=scan_stamps(result),
            graph=graph,
            odometry_poses=tuple(result.odometry_poses),
            node_scans=tuple(int(s) for s in result.node_scans),
            node_points=node_points,
            sessions=(session,),
            scan_sessions=np.zeros(result.num_scans, dtype=np.int64),
            grid=grid,
            map_points=map_points,
            places=places,
            loops=tuple(r.as_dict() for r in result.loops),
        )

    # -- writing ----------------------------------------------------------------------
    def save(self, folder: str | os.PathLike[str]) -> dict[str, Path]:
        """Write the map's files and ``manifest.json`` into ``folder`` (created); returns
        their paths by key. Always in format :data:`FORMAT_VERSION`."""
        from .io import PointCloud, write_points
        from .io.g2o import write_g2o
        from .io.occupancy import write_map
        from .io.trajectory import Trajectory, write_kitti_poses, write_tum

        if not isinstance(folder, (str, os.PathLike)):
            raise TypeError(f"folder: expected a str or os.PathLike, got {type(folder).__name__}")
        if self.node_points is None or self.node_scans is None or self.graph is None:
            raise ValueError(
                f"map: a format-{self.format_version} map lacks its node scans or graph; it "
                f"cannot be saved as format {FORMAT_VERSION} (map the run again)"
            )
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        paths: dict[str, Path] = {}
        paths["poses_kitti"] = out / "poses_kitti.txt"
        traj = Trajectory.from_poses(list(self.poses), self.stamps)  # type: ignore[arg-type]
        write_kitti_poses(paths["poses_kitti"], traj)
        paths["poses_tum"] = out / "poses_tum.txt"
        write_tum(paths["poses_tum"], traj)
        if self.odometry_poses is not None:
            paths["odometry_tum"] = out / "odometry_tum.txt"
            odo = Trajectory.from_poses(list(self.odometry_poses), self.stamps)  # type: ignore[arg-type]
            write_tum(paths["odometry_tum"], odo)
        for stale in out.glob("session_*_poses_tum.txt"):  # a former map's sessions
            stale.unlink()
        if len(self.sessions) > 1 and self.scan_sessions is not None:
            for k in range(len(self.sessions)):
                mine = self.scan_sessions == k
                poses = [p for p, m in zip(self.poses, mine, strict=True) if m]
                paths[f"session_{k}_poses_tum"] = out / session_file(k)
                own = Trajectory.from_poses(poses, self.stamps[mine])  # type: ignore[arg-type]
                write_tum(paths[f"session_{k}_poses_tum"], own)
        paths["graph"] = out / "graph.g2o"
        write_g2o(paths["graph"], self.graph)
        paths["loops"] = out / "loops.jsonl"
        with paths["loops"].open("w", encoding="utf-8") as fh:
            for record in self.loops:
                fh.write(json.dumps(record) + "\n")
        if self.grid is not None:
            for key, path in write_map(out, self.grid).items():
                paths[f"map_{key}"] = path
        if self.map_points is not None:
            cloud = PointCloud(points=self.map_points)
            for ext in ("ply", "pcd"):
                paths[f"map_{ext}"] = out / f"map.{ext}"
                write_points(paths[f"map_{ext}"], cloud)
        if self.places is not None:
            paths["places"] = out / "places.npz"
            with paths["places"].open("wb") as fh:
                np.savez(
                    fh,
                    poses=self.places.poses,
                    descriptors=self.places.descriptors,
                    max_radius=np.float64(self.places.max_radius),
                    height_offset=np.float64(self.places.height_offset),
                )
        paths["data"] = out / DATA
        with paths["data"].open("wb") as fh:
            np.savez(fh, **self._arrays())
        paths["manifest"] = write_manifest(out, self.dim, self.sessions, self.num_scans)
        return paths

    def _arrays(self) -> dict[str, Any]:
        assert self.node_points is not None and self.node_scans is not None
        assert self.graph is not None
        nodes = self.node_poses
        sessions = self.scan_sessions
        arrays: dict[str, Any] = {
            "poses": _matrices(self.poses, self.dim),
            "odometry_poses": _matrices(self.odometry_poses or (), self.dim),
            "has_odometry": np.bool_(self.odometry_poses is not None),
            "stamps": np.asarray(self.stamps, dtype=np.float64),
            "scan_sessions": np.zeros(0, np.int64) if sessions is None else sessions,
            "node_ids": np.array(sorted(self.graph.vertices), dtype=np.int64),
            "node_scans": np.array(self.node_scans, dtype=np.int64),
            "node_poses": _matrices(nodes, self.dim),
            "node_offsets": np.cumsum([0, *(len(p) for p in self.node_points)], dtype=np.int64),
            "node_points": (
                np.vstack(self.node_points) if self.node_points else np.zeros((0, self.dim))
            ),
            "edge_ids": np.array(
                [(e.from_id, e.to_id) for e in self.graph.edges], dtype=np.int64
            ).reshape(-1, 2),
            "edge_measurements": _matrices([e.measurement for e in self.graph.edges], self.dim),
            "edge_information": np.array(
                [e.information for e in self.graph.edges], dtype=np.float64
            ).reshape(-1, 3 * (self.dim - 1), 3 * (self.dim - 1)),
            "fixed": np.array(sorted(self.graph.fixed), dtype=np.int64),
        }
        if self.grid is not None:
            g = self.grid
            arrays["grid_probability"] = g.probability
            arrays["grid_resolution"] = np.float64(g.resolution)
            arrays["grid_origin"] = np.array(g.origin, dtype=np.float64)
            arrays["grid_thresholds"] = np.array([g.occupied_thresh, g.free_thresh])
        return arrays

    # -- reading ----------------------------------------------------------------------
    @classmethod
    def load(cls, folder: str | os.PathLike[str]) -> SavedMap:
        """The map in ``folder``. Format 2 (a ``manifest.json``) is read whole; a folder
        without a manifest that holds an older run's map (``map.yaml``, ``map.ply`` or
        ``map.pcd``) is read as format 1; anything else raises
        :class:`~scanreg.io.FileFormatError` naming the file and field."""
        if not isinstance(folder, (str, os.PathLike)):
            raise TypeError(f"folder: expected a str or os.PathLike, got {type(folder).__name__}")
        root = Path(folder)
        if not root.is_dir():
            raise FileNotFoundError(f"folder: {root} is not a folder")
        manifest = root / MANIFEST
        if not manifest.exists():
            if any((root / n).is_file() for n in ("map.yaml", "map.ply", "map.pcd")):
                return _load_version_1(root)
            raise FileFormatError(
                manifest, "missing: not a map folder (no manifest, no map.yaml/map.ply/map.pcd)"
            )
        head = read_manifest(manifest)
        return _load_version_2(root, head)


def session_file(k: int) -> str:
    """The file of session ``k``'s scans' poses (a map of several sessions)."""
    return f"session_{k}_poses_tum.txt"


def _known_files(folder: Path, sessions: int) -> dict[str, str]:
    """Every file of a map folder this module knows that is in ``folder``, described."""
    known = dict(FILE_DESCRIPTIONS)
    if sessions > 1:
        for k in range(sessions):
            known[session_file(k)] = f"session {k}'s scans' optimized poses with stamps (TUM)"
    return {
        name: known[name] for name in sorted(known) if name == MANIFEST or (folder / name).is_file()
    }


def write_manifest(folder: Path, dim: int, sessions: Sequence[str], num_scans: int) -> Path:
    """Write ``manifest.json`` listing every known file present in ``folder``."""
    files = _known_files(folder, len(sessions))
    head: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "written_by": f"scanreg {__version__}",
        "sensor": f"{dim}d",
        "frames": FRAMES[dim],
        "sessions": list(sessions),
        "num_scans": num_scans,
        "files": files,
    }
    path = folder / MANIFEST
    path.write_text(json.dumps(head, indent=2) + "\n", encoding="utf-8")
    return path


def refresh_manifest(folder: str | os.PathLike[str]) -> Path:
    """Rewrite ``folder``'s manifest so its ``files`` lists what is there now (after files
    such as ``config.toml`` or ``report.html`` were added beside the map, or removed)."""
    path = Path(folder) / MANIFEST
    head = read_manifest(path)
    # Files gone since are dropped; the ones added, listed.
    files = {n: d for n, d in head["files"].items() if (Path(folder) / str(n)).is_file()}
    for name, description in _known_files(Path(folder), len(head["sessions"])).items():
        files.setdefault(name, description)
    head["files"] = dict(sorted(files.items()))
    path.write_text(json.dumps(head, indent=2) + "\n", encoding="utf-8")
    return path


def read_manifest(path: Path) -> dict[str, Any]:
    """A checked ``manifest.json``: format, a version this scanreg reads, sensor, files."""
    try:
        head = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise FileFormatError(path, "not a text file (invalid UTF-8)") from None
    except json.JSONDecodeError as exc:
        raise FileFormatError(path, f"not JSON ({exc})") from None
    if not isinstance(head, dict):
        raise FileFormatError(path, f"expected a JSON object, got {type(head).__name__}")
    for key in ("format", "format_version", "sensor", "sessions", "files"):
        if key not in head:
            raise FileFormatError(path, f"{key}: missing")
    if head["format"] != FORMAT:
        raise FileFormatError(path, f"format: expected {FORMAT!r}, got {head['format']!r}")
    version = head["format_version"]
    if isinstance(version, bool) or not isinstance(version, int) or version != FORMAT_VERSION:
        readable = ", ".join(str(v) for v in READABLE_VERSIONS)
        raise FileFormatError(
            path,
            f"format_version: {version!r} is not one this scanreg ({__version__}) reads "
            f"(it reads {readable}; a manifest is written from version {FORMAT_VERSION} on)",
        )
    if head["sensor"] not in ("2d", "3d"):
        raise FileFormatError(path, f"sensor: expected '2d' or '3d', got {head['sensor']!r}")
    sessions = head["sessions"]
    if not isinstance(sessions, list) or not all(isinstance(s, str) for s in sessions):
        raise FileFormatError(path, f"sessions: expected a list of names, got {sessions!r}")
    if not isinstance(head["files"], dict):
        raise FileFormatError(path, f"files: expected an object, got {head['files']!r}")
    return head


def _matrices(poses: Sequence[Pose], dim: int) -> FloatArray:
    n = dim + 1
    return np.array([p.as_matrix() for p in poses], dtype=np.float64).reshape(-1, n, n)


def _poses(path: Path, key: str, mats: FloatArray, dim: int) -> tuple[Pose, ...]:
    n = dim + 1
    if mats.ndim != 3 or mats.shape[1:] != (n, n):
        raise FileFormatError(path, f"{key}: expected (N, {n}, {n}), got {mats.shape}")
    cls = SE2 if dim == 2 else SE3
    try:
        for m in mats:
            cls.from_matrix(m, atol=1e-6)  # checked as any pose matrix...
    except ValueError as exc:
        raise FileFormatError(path, f"{key}: {exc}") from None
    # ...but kept to the bit as stored (from_matrix re-projects the rotation), as pickle does.
    return tuple(cls._unchecked(m[:dim, :dim], m[:dim, dim]) for m in mats)


def _load_version_2(root: Path, head: Mapping[str, Any]) -> SavedMap:
    manifest = root / MANIFEST
    for name in head["files"]:
        if not isinstance(name, str) or "/" in name or name in ("", ".", ".."):
            raise FileFormatError(manifest, f"files: {name!r} is not a file name")
        if not (root / name).is_file():
            raise FileFormatError(root / name, f"missing (listed in {MANIFEST})")
    if DATA not in head["files"]:
        raise FileFormatError(manifest, f"files: {DATA} missing")
    dim = 2 if head["sensor"] == "2d" else 3
    path = root / DATA
    try:
        # The file opened here: np.load leaks its own handle when the archive is refused.
        with path.open("rb") as fh, np.load(fh, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except _NPZ_ERRORS as exc:
        raise FileFormatError(path, f"not a readable npz ({exc})") from None

    def need(key: str) -> Any:
        if key not in data:
            raise FileFormatError(path, f"{key}: missing")
        return data[key]

    poses = _poses(path, "poses", need("poses"), dim)
    n = len(poses)
    stamps = np.asarray(need("stamps"), dtype=np.float64)
    sessions = tuple(head["sessions"])
    scan_sessions = np.asarray(need("scan_sessions"), dtype=np.int64)
    if len(stamps) != n or len(scan_sessions) != n:
        raise FileFormatError(path, f"stamps, scan_sessions: expected {n} each (one per scan)")
    if n and not (scan_sessions.min() >= 0 and scan_sessions.max() < len(sessions)):
        raise FileFormatError(path, f"scan_sessions: expected 0..{len(sessions) - 1}")
    odometry = None
    if bool(need("has_odometry")):
        odometry = _poses(path, "odometry_poses", need("odometry_poses"), dim)
        if len(odometry) != n:
            raise FileFormatError(path, f"odometry_poses: expected {n}, got {len(odometry)}")
    ids = [int(v) for v in need("node_ids")]
    node_poses = _poses(path, "node_poses", need("node_poses"), dim)
    node_scans = tuple(int(v) for v in need("node_scans"))
    offsets = np.asarray(need("node_offsets"), dtype=np.int64)
    points = np.asarray(need("node_points"), dtype=np.float64)
    k = len(node_poses)
    if len(ids) != k or len(node_scans) != k or len(offsets) != k + 1:
        raise FileFormatError(path, f"node_ids, node_scans, node_offsets: expected {k} nodes")
    if points.ndim != 2 or points.shape[1] != dim or offsets[-1] != len(points):
        raise FileFormatError(path, f"node_points: expected ({offsets[-1]}, {dim})")
    if np.any(np.diff(offsets) < 0) or offsets[0] != 0:
        raise FileFormatError(path, "node_offsets: must start at 0 and not decrease")
    if any(not 0 <= s < n for s in node_scans):
        raise FileFormatError(path, f"node_scans: expected scan indices 0..{n - 1}")
    node_points = tuple(np.ascontiguousarray(points[offsets[i] : offsets[i + 1]]) for i in range(k))
    edge_ids = np.asarray(need("edge_ids"), dtype=np.int64)
    meas = _poses(path, "edge_measurements", need("edge_measurements"), dim)
    info = np.asarray(need("edge_information"), dtype=np.float64)
    if len(edge_ids) != len(meas) or len(info) != len(meas):
        raise FileFormatError(path, "edge_ids, edge_measurements, edge_information: lengths")
    try:
        graph = PoseGraph(
            dict(zip(ids, node_poses, strict=True)),
            tuple(
                PoseGraphEdge(int(a), int(b), m, np.array(i))
                for (a, b), m, i in zip(edge_ids, meas, info, strict=True)
            ),
            frozenset(int(v) for v in need("fixed")),
        )
    except ValueError as exc:
        raise FileFormatError(path, f"edge_ids: {exc}") from None
    grid = map_points = places = None
    if dim == 2:
        origin = np.asarray(need("grid_origin"), dtype=np.float64)
        thresholds = np.asarray(need("grid_thresholds"), dtype=np.float64)
        grid = OccupancyGrid(
            np.asarray(need("grid_probability"), dtype=np.float64),
            float(need("grid_resolution")),
            (float(origin[0]), float(origin[1])),
            float(thresholds[0]),
            float(thresholds[1]),
        )
    else:
        map_points = _read_cloud(root)
        places = _read_places(root / "places.npz") if (root / "places.npz").is_file() else None
    return SavedMap(
        dim=dim,
        poses=poses,
        stamps=stamps,
        graph=graph,
        odometry_poses=odometry,
        node_scans=node_scans,
        node_points=node_points,
        sessions=sessions,
        scan_sessions=scan_sessions,
        grid=grid,
        map_points=map_points,
        places=places,
        loops=_read_loops(root / "loops.jsonl"),
        format_version=2,
        folder=root,
    )


def _read_cloud(root: Path) -> FloatArray:
    from .io import read_points

    found = [root / n for n in ("map.ply", "map.pcd") if (root / n).is_file()]
    if not found:
        raise FileFormatError(root / "map.ply", "missing: a 3D map folder holds map.ply or .pcd")
    return np.ascontiguousarray(read_points(found[0]).points, dtype=np.float64)


def _read_places(path: Path) -> Places:
    try:
        with path.open("rb") as fh, np.load(fh, allow_pickle=False) as z:
            for key in ("poses", "descriptors", "max_radius", "height_offset"):
                if key not in z.files:
                    raise FileFormatError(path, f"{key}: missing")
            return Places(
                np.asarray(z["poses"], dtype=np.float64),
                np.asarray(z["descriptors"], dtype=np.float64),
                float(z["max_radius"]),
                float(z["height_offset"]),
            )
    except _NPZ_ERRORS as exc:
        if isinstance(exc, FileFormatError):
            raise
        raise FileFormatError(path, f"not a readable npz ({exc})") from None


def _read_loops(path: Path) -> tuple[dict[str, Any], ...]:
    if not path.is_file():
        return ()
    out = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            raise FileFormatError(path, f"line {number}: not JSON") from None
        if not isinstance(record, dict):
            raise FileFormatError(path, f"line {number}: expected a JSON object")
        out.append(record)
    return tuple(out)


def _load_version_1(root: Path) -> SavedMap:
    """A folder ``scanreg map`` wrote before the manifest: the map, poses and graph as the
    files hold them (poses to the text files' precision; no node scans, no sessions)."""
    from .io.g2o import read_g2o
    from .io.occupancy import read_occupancy_grid
    from .io.trajectory import read_kitti_poses, read_tum

    dim = 2 if (root / "map.yaml").is_file() else 3
    grid = read_occupancy_grid(root / "map.yaml") if dim == 2 else None
    map_points = _read_cloud(root) if dim == 3 else None
    places = _read_places(root / "places.npz") if (root / "places.npz").is_file() else None

    def planar(mats: FloatArray) -> tuple[Pose, ...]:
        if dim == 3:
            return tuple(SE3.from_matrix(m, atol=1e-6) for m in mats)
        return tuple(
            SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])]) for m in mats
        )

    poses: tuple[Pose, ...] = ()
    stamps = np.zeros(0)
    if (root / "poses_tum.txt").is_file():
        traj = read_tum(root / "poses_tum.txt")
        poses = planar(traj.poses)
        stamps = np.asarray(traj.timestamps, dtype=np.float64)
    elif (root / "poses_kitti.txt").is_file():
        poses = planar(read_kitti_poses(root / "poses_kitti.txt").poses)
        stamps = np.arange(len(poses), dtype=np.float64)
    odometry = None
    if (root / "odometry_tum.txt").is_file():
        odometry = planar(read_tum(root / "odometry_tum.txt").poses)
    graph = read_g2o(root / "graph.g2o") if (root / "graph.g2o").is_file() else None
    return SavedMap(
        dim=dim,
        poses=poses,
        stamps=stamps,
        graph=graph,
        odometry_poses=odometry,
        grid=grid,
        map_points=map_points,
        places=places,
        loops=_read_loops(root / "loops.jsonl"),
        format_version=1,
        folder=root,
    )


__all__ = [
    "FILE_DESCRIPTIONS",
    "FORMAT",
    "FORMAT_VERSION",
    "READABLE_VERSIONS",
    "Places",
    "SavedMap",
    "read_manifest",
    "refresh_manifest",
    "write_manifest",
]
