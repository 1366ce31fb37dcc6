"""scanreg.SavedMap: the folder ``scanreg map`` writes, versioned; round trips field by field
(2D and 3D), an older folder read as format 1, unknown versions and corrupt manifests refused
naming the file and field."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scanreg
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.io import FileFormatError

pytest.importorskip("gtsam")

from scanreg.pipeline import write_outputs
from scanreg.pipeline.mapping import Mapper, MappingConfig
from scanreg.saved_map import MANIFEST, SavedMap


@cache
def _run_2d() -> Any:
    """30 scans along a floor plan, 1 m/s and turning: a small 2D mapping run."""
    laser = dataclasses.replace(sim.LaserModel.preset("laser_360"), max_range=10.0)
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        1.0, 0.2, duration=7.0, dim=2, start=SE2.from_vector([1.0, 0.0, 0.0])
    )
    run = sim.simulate_run(sim.floor_plan(seed=0), laser, traj, num_scans=30, scan_rate=5.0)
    mapper = Mapper(MappingConfig())
    for k, scan in enumerate(run.scans):
        mapper.step(scan.points, stamp=100.0 + k / 5.0)
    return mapper.finish()


@cache
def _run_3d() -> Any:
    from scanreg.io import open_sequence
    from scanreg.pipeline.mapping3d import MappingConfig3D, run_mapping_3d

    config = dataclasses.replace(MappingConfig3D(), node_distance=3.0)
    return run_mapping_3d(open_sequence("sim:loop,lap_length=200,frames=12"), config)


def _same_poses(a: Any, b: Any) -> bool:
    return a is not None and len(a) == len(b) and all(p == q for p, q in zip(a, b, strict=True))


def _assert_equal(a: SavedMap, b: SavedMap) -> None:
    """Every field equal (the folder aside)."""
    assert (a.dim, a.format_version, a.sessions) == (b.dim, b.format_version, b.sessions)
    assert _same_poses(a.poses, b.poses)
    assert _same_poses(a.odometry_poses, b.odometry_poses)
    assert np.array_equal(a.stamps, b.stamps)
    assert np.array_equal(a.scan_sessions, b.scan_sessions)  # type: ignore[arg-type]
    assert a.node_scans == b.node_scans
    assert a.node_points is not None and b.node_points is not None
    assert len(a.node_points) == len(b.node_points)
    assert all(np.array_equal(p, q) for p, q in zip(a.node_points, b.node_points, strict=True))
    assert a.graph is not None and b.graph is not None
    assert a.graph.vertices == b.graph.vertices and a.graph.fixed == b.graph.fixed
    assert len(a.graph.edges) == len(b.graph.edges)
    for e, f in zip(a.graph.edges, b.graph.edges, strict=True):
        assert (e.from_id, e.to_id, e.measurement) == (f.from_id, f.to_id, f.measurement)
        assert np.array_equal(e.information, f.information)
    if a.grid is None:
        assert b.grid is None
    else:
        assert b.grid is not None
        assert np.array_equal(a.grid.probability, b.grid.probability, equal_nan=True)
        assert (a.grid.resolution, a.grid.origin) == (b.grid.resolution, b.grid.origin)
    for name in ("map_points",):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or np.array_equal(x, y), name
    if a.places is None:
        assert b.places is None
    else:
        assert b.places is not None
        assert np.array_equal(a.places.poses, b.places.poses)
        assert np.array_equal(a.places.descriptors, b.places.descriptors)
        assert a.places[2:] == b.places[2:]
    assert a.loops == b.loops


@pytest.mark.parametrize("dim", [2, 3])
def test_round_trip_field_by_field(dim: int, tmp_path: Path) -> None:
    result = _run_2d() if dim == 2 else _run_3d()
    saved = SavedMap.from_result(result, session="run-a")
    saved.save(tmp_path)
    loaded = scanreg.SavedMap.load(tmp_path)
    assert loaded.folder == tmp_path
    _assert_equal(saved, loaded)
    assert len(loaded.node_points or ()) == len(result.node_scans) > 2
    assert loaded.session_poses("run-a") == loaded.poses
    # Saving what was loaded writes the same state again.
    loaded.save(tmp_path / "again")
    _assert_equal(loaded, SavedMap.load(tmp_path / "again"))
    head = json.loads((tmp_path / MANIFEST).read_text())
    assert head["format"] == "scanreg-map" and head["format_version"] == 2
    assert head["sensor"] == f"{dim}d" and head["sessions"] == ["run-a"]
    assert "world" in head["frames"] and "map_data.npz" in head["files"]
    described = loaded.describe()
    assert described["num_nodes"] == len(result.node_scans)
    assert described["scans_per_session"] == [result.num_scans]
    if dim == 2:  # a node's submap is rebuilt from the saved node scans
        sub = loaded.submap(3, half_size=1)
        assert sub.nodes == (2, 3, 4) and len(sub.points) > 100
        with pytest.raises(ValueError, match=r"anchor: expected a node id 0\.\."):
            loaded.submap(loaded.num_nodes)
    # `scanreg info FOLDER` describes it.
    from scanreg.pipeline.commands import describe_input

    assert describe_input(tmp_path) == {"kind": "map", **described}


def test_write_outputs_folder_is_a_saved_map(tmp_path: Path) -> None:
    """What ``scanreg map`` writes loads as a SavedMap; the manifest lists every file; the
    2D localizer's map is the occupied cells ``map.yaml`` reads as (to the YAML's 1e-6)."""
    from scanreg.io.occupancy import read_map_server

    result = _run_2d()
    paths = write_outputs(tmp_path, result, plot=False, session="floor")
    saved = SavedMap.load(tmp_path)
    assert saved.sessions == ("floor",) and saved.num_scans == result.num_scans == 30
    files = json.loads(paths["manifest"].read_text())["files"]
    assert {"summary.json", "contradictions.csv", "map.yaml", "poses_tum.txt"} <= set(files)
    assert set(files) == {p.name for p in tmp_path.iterdir()}
    ours = saved.occupied_points()
    theirs, _ = read_map_server(tmp_path / "map.yaml")
    assert ours.shape == theirs.shape and len(ours) > 100
    assert np.abs(np.sort(ours, axis=0) - np.sort(theirs, axis=0)).max() < 1e-5


def test_older_folder_read_as_version_1(tmp_path: Path) -> None:
    """A folder from before the manifest: read with its map, poses and graph; no node scans;
    it cannot be saved as format 2 (the message names the version)."""
    result = _run_2d()
    write_outputs(tmp_path, result, plot=False)
    (tmp_path / MANIFEST).unlink()
    (tmp_path / "map_data.npz").unlink()
    old = SavedMap.load(tmp_path)
    assert old.format_version == 1 and old.node_points is None and old.dim == 2
    assert old.num_scans == 30 and old.graph is not None
    assert old.num_nodes == len(result.node_scans)
    truth = np.array([p.as_vector() for p in result.poses])
    got = np.array([p.as_vector() for p in old.poses])
    assert np.abs(got - truth).max() < 1e-6
    assert old.grid is not None and len(old.occupied_points()) > 100
    with pytest.raises(ValueError, match="format-1 map lacks its node scans"):
        old.save(tmp_path / "new")


@pytest.mark.parametrize("version", [3, 1, "2", None])
def test_unknown_version_refused_naming_it(version: Any, tmp_path: Path) -> None:
    SavedMap.from_result(_run_2d()).save(tmp_path)
    head = json.loads((tmp_path / MANIFEST).read_text())
    head["format_version"] = version
    (tmp_path / MANIFEST).write_text(json.dumps(head))
    with pytest.raises(FileFormatError, match=f"format_version: {version!r} is not one") as e:
        SavedMap.load(tmp_path)
    assert e.value.path == tmp_path / MANIFEST


def test_corrupt_or_missing_parts_named(tmp_path: Path) -> None:
    SavedMap.from_result(_run_2d()).save(tmp_path)
    manifest = tmp_path / MANIFEST
    good = manifest.read_text()
    head = json.loads(good)
    cases: list[tuple[str, str]] = [
        ("{not json", "not JSON"),
        (json.dumps([1, 2]), "expected a JSON object"),
        (json.dumps({k: v for k, v in head.items() if k != "sensor"}), "sensor: missing"),
        (json.dumps({**head, "format": "other"}), "format: expected 'scanreg-map'"),
        (json.dumps({**head, "sensor": "4d"}), "sensor: expected"),
    ]
    for text, message in cases:
        manifest.write_text(text)
        with pytest.raises(FileFormatError, match=message) as e:
            SavedMap.load(tmp_path)
        assert str(e.value).startswith(str(manifest))
    manifest.write_text(good)
    (tmp_path / "graph.g2o").unlink()
    with pytest.raises(FileFormatError, match=r"graph.g2o: missing \(listed in manifest.json\)"):
        SavedMap.load(tmp_path)
    # A data file missing a field.
    shutil.copy(tmp_path / "map_data.npz", tmp_path / "keep.npz")
    with np.load(tmp_path / "keep.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "node_offsets"}
    np.savez(tmp_path / "map_data.npz", **arrays)
    (tmp_path / "graph.g2o").write_text("")
    with pytest.raises(FileFormatError, match=r"map_data\.npz: node_offsets: missing"):
        SavedMap.load(tmp_path)
    # A data file that is not an npz at all, or cut short.
    whole = (tmp_path / "keep.npz").read_bytes()
    for damaged in (b"not a zip file", whole[: len(whole) // 2]):
        (tmp_path / "map_data.npz").write_bytes(damaged)
        with pytest.raises(FileFormatError, match=r"map_data\.npz: not a readable npz"):
            SavedMap.load(tmp_path)
    # No manifest and no map at all.
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FileFormatError, match=r"manifest.json: missing: not a map folder"):
        SavedMap.load(empty)


def test_bad_arguments_named(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="result: expected a MappingResult"):
        SavedMap.from_result(object())
    with pytest.raises(ValueError, match="session: expected a non-empty str"):
        SavedMap.from_result(_run_2d(), session="")
    with pytest.raises(TypeError, match="folder: expected a str"):
        SavedMap.load(3)  # type: ignore[arg-type]
    saved = SavedMap.from_result(_run_2d())
    with pytest.raises(ValueError, match=r"session: expected 0\.\.0"):
        saved.session_poses(2)
    assert math.isfinite(saved.stamps.sum())


@pytest.mark.parametrize("dim", [2, 3])
def test_transformed_moves_the_map_frame_and_back(dim: int) -> None:
    """A map moved into another frame: every pose is ``T @ pose``, the map cloud and places
    moved with it, the 2D grid rebuilt where the moved scans fall; moved back it is the
    original to round-off."""
    from scanreg import SE3

    saved = SavedMap.from_result(_run_2d() if dim == 2 else _run_3d(), session="run-a")
    t: SE2 | SE3 = (
        SE2.from_vector([40.0, -25.0, math.radians(73.0)])
        if dim == 2
        else SE3.from_vector([40.0, -25.0, 3.0, 0.1, -0.05, math.radians(73.0)])
    )
    moved = saved.transformed(t)
    assert moved is not saved and moved.folder is None
    for p, q in zip(saved.poses, moved.poses, strict=True):
        assert np.allclose(q.as_matrix(), t.as_matrix() @ p.as_matrix(), atol=1e-12)
    assert saved.odometry_poses is not None and moved.odometry_poses is not None
    q = moved.odometry_poses[-1].as_matrix()
    assert np.allclose(q, t.as_matrix() @ saved.odometry_poses[-1].as_matrix(), atol=1e-12)
    assert moved.graph is not None and saved.graph is not None
    # Relative quantities and the nodes' own frames are kept as they are.
    assert moved.graph.edges == saved.graph.edges and moved.node_points is saved.node_points
    assert moved.loops == saved.loops and np.array_equal(moved.stamps, saved.stamps)
    # The first scan no longer sits at the origin: it sits at t.
    assert np.linalg.norm(moved.poses[0].translation - t.translation) < 1e-9
    if dim == 2:
        assert saved.grid is not None and moved.grid is not None
        assert moved.grid.origin != saved.grid.origin
        # The rebuilt grid holds about as many occupied cells (cells are cut anew).
        before, after = len(saved.occupied_points()), len(moved.occupied_points())
        assert abs(after - before) < 0.1 * before, (before, after)
    else:
        assert saved.map_points is not None and moved.map_points is not None
        assert np.allclose(moved.map_points, t.apply(saved.map_points), atol=1e-9)
        assert saved.places is not None and moved.places is not None
        assert np.allclose(moved.places.poses[1], t.as_matrix() @ saved.places.poses[1])
        assert np.array_equal(moved.places.descriptors, saved.places.descriptors)
    back = moved.transformed(t.inverse())
    for p, q in zip(saved.poses, back.poses, strict=True):
        assert np.allclose(p.as_matrix(), q.as_matrix(), atol=1e-9)
    assert back.graph is not None
    for k, p in saved.graph.vertices.items():
        assert np.allclose(p.as_matrix(), back.graph.vertices[k].as_matrix(), atol=1e-9)
    if dim == 2:
        assert saved.grid is not None and back.grid is not None
        assert back.grid.probability.shape == saved.grid.probability.shape
        assert np.allclose(back.grid.origin, saved.grid.origin, atol=1e-9)
        assert np.allclose(back.grid.probability, saved.grid.probability, atol=1e-9, equal_nan=True)
    else:
        assert back.map_points is not None and back.places is not None
        assert np.allclose(back.map_points, saved.map_points, atol=1e-9)
        assert np.allclose(back.places.poses, saved.places.poses, atol=1e-9)
    # A 2D map takes an SE2, a 3D map an SE3.
    with pytest.raises(TypeError, match="transform: expected an SE"):
        saved.transformed(SE3.identity() if dim == 2 else SE2.identity())
    if dim == 2:  # a grid without the node scans it was made of (format 1) cannot be moved
        with pytest.raises(ValueError, match="map: transformed needs the node scans"):
            dataclasses.replace(saved, node_points=None).transformed(t)
