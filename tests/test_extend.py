"""``scanreg map NEW --extend OLD/`` (scanreg.pipeline.extend): a second session joined to a
saved 2D map in one graph. Real Intel excerpts: the scans both sessions hold get the same pose
from each; the old nodes keep their ids; a map of another building is refused."""

from __future__ import annotations

import bz2
import json
import re
import shutil
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import data_dir, interrupt_mapping_at
from scanreg import SE2
from scanreg.cli import EXIT_BAD_INPUT, EXIT_OK, main

pytest.importorskip("gtsam")

from scanreg.pipeline import MappingConfig, extend_map, run_mapping
from scanreg.saved_map import MANIFEST, SavedMap


@cache
def _lines(name: str, count: int) -> tuple[str, ...]:
    with bz2.open(data_dir("freiburg-slam-benchmark", name), "rt", encoding="utf-8") as fh:
        return tuple(next(fh) for _ in range(count))


def _log(folder: Path, name: str, lines: tuple[str, ...]) -> Path:
    path = folder / name
    path.write_text("".join(lines), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Intel lines 0-1800 (session a, 604 scans) and 900-2700 (session b, 604 scans): b
    drives a's second half again, then on."""
    lines = _lines("intel.clf.bz2", 2700)
    folder = tmp_path_factory.mktemp("intel")
    return {"a": _log(folder, "a.clf", lines[:1800]), "b": _log(folder, "b.clf", lines[900:])}


def _by_stamp(saved: SavedMap, session: int) -> dict[float, SE2]:
    assert saved.scan_sessions is not None
    stamps = saved.stamps[saved.scan_sessions == session]
    poses = saved.session_poses(session)
    return {round(float(s), 6): p for s, p in zip(stamps, poses, strict=True)}  # type: ignore[misc]


@pytest.fixture(scope="module")
def mapped(sessions: dict[str, Path]) -> dict[str, Any]:
    from scanreg.io import read_scans

    return {
        "a": run_mapping(read_scans(sessions["a"]), MappingConfig()),
        "b": run_mapping(read_scans(sessions["b"]), MappingConfig()),
        "b_log": sessions["b"],
    }


def test_extend_joins_a_second_session(mapped: dict[str, Any]) -> None:
    a, b = mapped["a"], mapped["b"]
    old = SavedMap.from_result(a, session="a")
    joint, report = extend_map(old, b, session="b")
    assert joint.sessions == ("a", "b") and joint.num_scans == a.num_scans + b.num_scans
    assert joint.num_nodes == len(a.node_scans) + len(b.node_scans)
    # Measured: located at b's first node; 33 of 33 candidates accepted.
    assert report.accepted >= 20 and report.accepted >= 0.8 * report.candidates
    # The old nodes keep their ids and (node 0 fixed, their edges kept) their place.
    assert joint.graph is not None and old.graph is not None
    assert joint.node_scans is not None and old.node_scans is not None
    assert joint.node_scans[: old.num_nodes] == old.node_scans
    moved = [
        np.linalg.norm((old.graph.vertices[k].inverse() @ joint.graph.vertices[k]).translation)
        for k in range(old.num_nodes)
    ]
    assert max(moved) < 0.1  # measured 0.062 m at a's far end
    # The scans both sessions mapped (~300): the same pose from each, in one frame. Without
    # the join they are in unrelated frames (b starts at its own origin).
    mine, theirs = _by_stamp(joint, 0), _by_stamp(joint, 1)
    shared = sorted(set(mine) & set(theirs))
    assert len(shared) > 250
    err = np.array([np.linalg.norm((mine[t].inverse() @ theirs[t]).translation) for t in shared])
    # Measured: median 0.007 m, max 0.057 m (the agreeing loops without a kernel; 0.055 m with).
    assert np.median(err) < 0.02 and err.max() < 0.1, (np.median(err), err.max())
    alone = {round(float(s), 6): p for s, p in zip(b.stamps, b.poses, strict=True)}
    apart = [np.linalg.norm((mine[t].inverse() @ alone[t]).translation) for t in shared]
    assert min(apart) > 1.0  # b's own frame is not a's: the join did the work
    # Inter-session loops are recorded as such.
    records = [r for r in joint.loops if r.get("inter_session")]
    assert len(records) == report.candidates and all(r["node"] >= old.num_nodes for r in records)


def test_cli_extend_writes_both_sessions(
    sessions: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, out2 = tmp_path / "out", tmp_path / "out2"
    assert main(["map", str(sessions["a"]), "-o", str(out), "--json", "--no-plots"]) == EXIT_OK
    first = json.loads(capsys.readouterr().out)
    argv = ["map", str(sessions["b"]), "--extend", str(out), "-o", str(out2), "--json"]
    assert main(argv) == EXIT_OK
    result = json.loads(capsys.readouterr().out)
    assert result["sessions"] == [str(sessions["a"]), str(sessions["b"])]
    assert result["num_scans"] == first["num_scans"] + result["new_run"]["num_scans"]
    assert result["scans_per_session"] == [first["num_scans"], result["new_run"]["num_scans"]]
    joint = SavedMap.load(out2)
    files = json.loads((out2 / MANIFEST).read_text())["files"]
    for k in (0, 1):
        tum = np.loadtxt(out2 / f"session_{k}_poses_tum.txt")
        assert len(tum) == result["scans_per_session"][k] and f"session_{k}_poses_tum.txt" in files
    assert np.loadtxt(out2 / "poses_tum.txt").shape == (joint.num_scans, 8)
    assert set(files) == {p.name for p in out2.iterdir()}
    # The joint map's self-check (each session's scans judge the other's) in its summary.
    check = json.loads((out2 / "summary.json").read_text())["self_check"]
    assert check == result["self_check"] and check["consistent"], check
    assert check["returns"] > 1000 and (out2 / "contradictions.csv").is_file(), check
    # In place (no -o): the folder becomes the joint map; the first run's plot (it describes
    # one run) is gone, its self-check replaced by the joint map's, and the manifest says so.
    inplace = tmp_path / "inplace"
    shutil.copytree(out, inplace)
    (inplace / "trajectory.png").write_bytes(b"")
    argv = ["map", str(sessions["b"]), "--extend", str(inplace), "--json"]
    assert main(argv) == EXIT_OK
    capsys.readouterr()
    files = json.loads((inplace / MANIFEST).read_text())["files"]
    assert set(files) == {p.name for p in inplace.iterdir()}
    assert "trajectory.png" not in files and "contradictions.csv" in files
    assert json.loads((inplace / "summary.json").read_text())["self_check"]["consistent"]
    assert SavedMap.load(inplace).sessions == (str(sessions["a"]), str(sessions["b"]))
    # The saved map it extended is untouched; the joint map localizes like any other.
    assert SavedMap.load(out).sessions == (str(sessions["a"]),)
    loc = tmp_path / "loc"
    argv = ["localize", str(sessions["b"]), "--map", str(out2), "-o", str(loc), "--json"]
    assert main([*argv, "--max-scans", "30"]) == EXIT_OK
    located = json.loads(capsys.readouterr().out)
    assert located["accepted"] >= 28, located


def _floor_plan_run() -> Any:
    """30 scans of a simulated floor plan: another building."""
    import dataclasses

    from scanreg import simulate as sim
    from scanreg.pipeline import Mapper

    laser = dataclasses.replace(sim.LaserModel.preset("laser_360"), max_range=10.0)
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        1.0, 0.2, duration=7.0, dim=2, start=SE2.from_vector([1.0, 0.0, 0.0])
    )
    run = sim.simulate_run(sim.floor_plan(seed=0), laser, traj, num_scans=30, scan_rate=5.0)
    mapper = Mapper(MappingConfig())
    for k, scan in enumerate(run.scans):
        mapper.step(scan.points, stamp=k / 5.0)
    return mapper.finish()


def test_extend_refuses_another_building_and_old_formats(
    mapped: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from scanreg.pipeline import write_outputs

    old = SavedMap.from_result(mapped["a"], session="a")
    other = _floor_plan_run()
    with pytest.raises(ValueError, match=r"no reliable overlap, nothing joined|not be located"):
        extend_map(old, other, session="floor")
    with pytest.raises(ValueError, match="session: expected a new, non-empty name"):
        extend_map(old, other, session="a")
    # A folder from before the manifest (format 1) keeps no node scans: refused, naming it.
    out = tmp_path / "old"
    write_outputs(out, mapped["a"], plot=False)
    (out / MANIFEST).unlink()
    (out / "map_data.npz").unlink()
    with pytest.raises(ValueError, match="format-1 map keeps no node scans"):
        extend_map(SavedMap.load(out), mapped["b"], session="b")
    argv = ["map", str(mapped["b_log"]), "--extend", str(out), "-o", str(tmp_path / "x")]
    assert main([*argv, "--json"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "is a format-1 2D map; a 2D run extends only a 2D map of format 2" in err, err
    assert not (tmp_path / "x").exists()


@pytest.fixture(scope="module")
def old_map(sessions: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Session a's map, as ``scanreg map`` writes it."""
    out = tmp_path_factory.mktemp("old") / "a"
    assert main(["map", str(sessions["a"]), "-o", str(out), "--quiet", "--no-plots"]) == EXIT_OK
    return out


def test_cli_extend_from_a_bag_with_report_and_bag(
    sessions: dict[str, Path], old_map: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The new run from a LaserScan bag (session b written as ROS 2 by rosbags' writer):
    placed like the log; ``--report`` draws both sessions and the loops between them;
    ``--bag`` holds every node of both."""
    pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'scanreg[ros]')")
    pytest.importorskip("plotly", reason="plotly is not installed (pip install 'scanreg[report]')")
    from _carmen_bag import write_carmen_bag
    from scanreg.io import read_scans
    from scanreg.io.rosbag import list_topics

    capsys.readouterr()
    bag = write_carmen_bag(read_scans(sessions["b"]), tmp_path / "b.mcap")
    out = tmp_path / "both"
    argv = ["map", str(bag), "--extend", str(old_map), "-o", str(out), "--json"]
    assert main([*argv, "--report", "--bag", str(out / "map.mcap")]) == EXIT_OK
    result = json.loads(capsys.readouterr().out)
    assert result["sessions"] == [str(sessions["a"]), str(bag)]
    assert result["inter_session_loops"] >= 20, result
    joint = SavedMap.load(out)
    mine, theirs = _by_stamp(joint, 0), _by_stamp(joint, 1)
    shared = sorted(set(mine) & set(theirs))
    assert len(shared) > 250  # the bag's stamps are the log's
    err = np.array([np.linalg.norm((mine[t].inverse() @ theirs[t]).translation) for t in shared])
    assert np.median(err) < 0.02 and err.max() < 0.1, (np.median(err), err.max())
    # The report is the joint map's: one trajectory per session, the loops between them.
    text = (out / "report.html").read_text(encoding="utf-8")
    # (plotly's JSON escapes "/" as \u002f: decoded to read the trace names)
    text = re.sub(r"\\u([0-9a-f]{4})", lambda m: chr(int(m.group(1), 16)), text)
    assert f"session 0: {sessions['a']}" in text and f"session 1: {bag}" in text
    assert "loop closures (between sessions)" in text and "loops between sessions" in text
    assert "Occupancy grid" in text and "both, a map of 2 sessions" in text
    assert "Self-check" in text and result["self_check"]["consistent"], result["self_check"]
    assert result["outputs"]["report"] == str(out / "report.html")
    files = json.loads((out / MANIFEST).read_text())["files"]
    assert "report.html" in files and "new_run_checkpoint" not in {p.name for p in out.iterdir()}
    # The bag: every node of both sessions, the joint grid once.
    topics = {t.name: t.message_count for t in list_topics(out / "map.mcap")}
    assert topics["/scanreg/pose"] == topics["/scanreg/scan"] == joint.num_nodes
    assert topics["/scanreg/grid"] == 1 and result["outputs"]["bag"] == str(out / "map.mcap")


def test_cli_extend_checkpoint_keeps_the_new_run(
    sessions: dict[str, Path],
    old_map: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``--checkpoint N`` with ``--extend``: the new run's map alone every N scans in
    OUT/new_run_checkpoint/, removed once joined; a stop leaves it there, the saved map
    untouched, and ``scanreg merge`` joins what was mapped."""
    from scanreg.cli import EXIT_INTERRUPTED
    from scanreg.pipeline import mapping_output

    written: list[tuple[Path, int]] = []
    write_outputs = mapping_output.write_outputs

    def spy(folder: Path, result: Any, **options: Any) -> Any:
        written.append((Path(folder), result.num_scans))
        return write_outputs(folder, result, **options)

    monkeypatch.setattr(mapping_output, "write_outputs", spy)
    capsys.readouterr()
    out = tmp_path / "both"
    argv = ["map", str(sessions["b"]), "--extend", str(old_map), "-o", str(out), "--quiet"]
    assert main([*argv, "--checkpoint", "200", "--no-plots"]) == EXIT_OK
    held = out / "new_run_checkpoint"
    assert written == [(held, 200), (held, 400), (held, 600)]
    assert not held.exists() and len(SavedMap.load(out).sessions) == 2
    # Ctrl-C at the new run's 250th scan: the saved map is unchanged, the new run's 250
    # scans are a map of their own, which merge joins to the saved one.
    interrupt_mapping_at(monkeypatch, 250)
    stopped = tmp_path / "stopped"
    argv = ["map", str(sessions["b"]), "--extend", str(old_map), "-o", str(stopped)]
    assert main([*argv, "--quiet", "--checkpoint", "100"]) == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    held = stopped / "new_run_checkpoint"
    assert f"the saved map {old_map}/ is unchanged" in err, err
    assert f"written to {held}/ (250 scans" in err, err
    assert SavedMap.load(old_map).sessions == (str(sessions["a"]),)
    partial = SavedMap.load(held)
    assert partial.num_scans == 250 and partial.sessions == (str(sessions["b"]),)
    argv = ["merge", str(old_map), str(held), "-o", str(tmp_path / "merged"), "--json"]
    assert main(argv) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["inter_session_loops"] >= 10
    argv = ["map", str(sessions["b"]), "--extend", str(old_map), "--checkpoint", "0"]
    assert main(argv) == EXIT_BAD_INPUT
    assert "--checkpoint must be >= 1 scans" in capsys.readouterr().err
