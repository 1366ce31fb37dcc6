"""``scanreg merge A/ B/ -o M/`` on 3D maps (scanreg.pipeline.join3d): two drives around the
simulated city block, mapped separately, the second moved into a frame that has nothing to do
with the first, merged through place recognition and global registration; scored against the
exact truth. A drive around another block (another seed) is refused."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scanreg import SE3
from scanreg.cli import EXIT_BAD_INPUT, EXIT_OK, main

pytest.importorskip("gtsam")

from scanreg.eval import absolute_trajectory_error
from scanreg.io import Trajectory, read_tum
from scanreg.io.sequences import SimulatedSequence
from scanreg.pipeline import MapLocalizer, Mapper3D, MappingConfig3D
from scanreg.pipeline.join import DISAGREES
from scanreg.saved_map import MANIFEST, SavedMap

#: A 200 m lap; drive a covers its first 120 m, drive b (a lap later) 50-150 m: 70 m shared.
LAP = 200.0
A_FRAMES = range(0, 120)
B_FRAMES = range(250, 350)
#: The unrelated frame the second map is moved into.
ELSEWHERE = SE3.from_vector([40.0, -25.0, 3.0, 0.0, 0.0, math.radians(73.0)])
CONFIG = MappingConfig3D()


def _drive(seq: SimulatedSequence, frames: range, session: str) -> SavedMap:
    mapper = Mapper3D(CONFIG)
    for k in frames:
        f = seq[k]
        mapper.step(f.points, f.timestamps, stamp=f.stamp)
    return SavedMap.from_result(mapper.finish(), session=session)


@pytest.fixture(scope="module")
def drives(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Drives a and b mapped alone and saved (b moved 47 m / 73° away and 3 m up), merged
    by the command; the exact truth of every scan in a's frame."""
    seq = SimulatedSequence("loop", laps=2, lap_length=LAP)
    root = tmp_path_factory.mktemp("merge3d")
    a = _drive(seq, A_FRAMES, "a")
    b = _drive(seq, B_FRAMES, "b").transformed(ELSEWHERE)
    a.save(root / "a")
    b.save(root / "b")
    argv = ["merge", str(root / "a"), str(root / "b"), "-o", str(root / "m"), "--json"]
    code = main(argv)
    truth = seq.ground_truth_at(CONFIG.odometry.reference_time)
    return {
        "a": a,
        "b": b,
        "root": root,
        "code": code,
        "truth": np.concatenate([truth[list(A_FRAMES)], truth[list(B_FRAMES)]]),
        "stamps": np.concatenate([seq.stamps[list(A_FRAMES)], seq.stamps[list(B_FRAMES)]]),
        "frames": [*A_FRAMES, *B_FRAMES],
        "seq_truth": truth,
        "seq": seq,
    }


def test_two_drives_merge_against_exact_truth(drives: dict[str, Any]) -> None:
    assert drives["code"] == EXIT_OK
    a, b = drives["a"], drives["b"]
    merged = SavedMap.load(drives["root"] / "m")
    assert merged.dim == 3 and merged.sessions == ("a", "b")
    assert merged.num_scans == a.num_scans + b.num_scans
    # a's nodes keep their ids (and scans, clouds); b's follow.
    assert merged.num_nodes == a.num_nodes + b.num_nodes
    assert merged.node_scans is not None and merged.node_points is not None
    assert merged.node_scans[: a.num_nodes] == a.node_scans
    assert all(
        np.array_equal(p, q) for p, q in zip(merged.node_points, a.node_points or (), strict=False)
    )
    # Both maps' own edges, as they were (g2o's information convention in and out), then the
    # inter-session loops.
    assert merged.graph is not None and a.graph is not None and b.graph is not None
    own = [*a.graph.edges, *b.graph.edges]
    offsets = [0] * len(a.graph.edges) + [a.num_nodes] * len(b.graph.edges)
    for e, f, k in zip(merged.graph.edges, own, offsets, strict=False):
        assert (e.from_id, e.to_id) == (f.from_id + k, f.to_id + k)
        np.testing.assert_allclose(e.information, f.information, rtol=1e-9, atol=1e-9)
    # Every scan keeps its own stamp.
    assert np.array_equal(merged.stamps, drives["stamps"])
    # ATE over all 220 scans against the exact truth (≤ 0.10 m asked). Measured: 0.0513 m
    # (a alone: 120 m without a loop of its own, up to 0.26 m off at its end).
    est = np.array([p.as_matrix() for p in merged.poses])
    stamps = merged.stamps
    ate = absolute_trajectory_error(
        Trajectory(est, stamps), Trajectory(drives["truth"], stamps), alignment="se3"
    )
    assert ate.translation.rmse < 0.065, ate.translation.rmse
    # b was moved 47 m / 73° away: the merge did the work (b's own poses are far off).
    b_truth = drives["truth"][a.num_scans :]
    b_raw = np.array([p.translation for p in b.poses])
    assert np.min(np.linalg.norm(b_raw - b_truth[:, :3, 3], axis=1)) > 20.0
    # Every inter-session loop joined is true to a few centimetres (measured: 29 of 39
    # candidates, at most 0.027 m / 0.05°).
    truth, frames, k_a = drives["seq_truth"], drives["frames"], a.num_scans
    joined = [r for r in merged.loops if r.get("inter_session") and r["accepted"]]
    assert len(joined) >= 10
    for r in joined:
        t_true = SE3.from_matrix(
            np.linalg.inv(truth[frames[r["submap_scan"]]]) @ truth[frames[r["scan"]]]
        )
        e = (t_true.inverse() @ SE3.from_vector(r["measured"])).log()
        assert np.linalg.norm(e[:3]) < 0.1 and np.linalg.norm(e[3:]) < math.radians(0.5), r
    assert all(r["scan"] >= k_a > r["submap_scan"] for r in joined)
    left_out = [r for r in merged.loops if DISAGREES in r.get("reasons", ())]
    assert all(r.get("inter_session") for r in left_out)


def test_cli_merge_writes_a_3d_map(
    drives: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    root = drives["root"]
    out = root / "m"
    head = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
    assert head["sensor"] == "3d" and head["sessions"] == ["a", "b"]
    for name in ("map.ply", "places.npz", "graph.g2o", "session_0_poses_tum.txt", "summary.json"):
        assert name in head["files"], name
    tum = read_tum(out / "poses_tum.txt")
    assert np.allclose(tum.timestamps, drives["stamps"])
    b_only = read_tum(out / "session_1_poses_tum.txt")
    assert len(b_only) == drives["b"].num_scans
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["merged"] == [str(root / "a"), str(root / "b")]
    assert summary["inter_session_loops"] >= 10
    # The places of both drives, in a's frame: b's first node lies where b began.
    places = np.load(out / "places.npz")
    assert len(places["poses"]) == drives["a"].num_nodes + drives["b"].num_nodes
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == EXIT_OK
    info = json.loads(capsys.readouterr().out)
    assert info["sensor"] == "3d" and info["scans_per_session"] == [120, 100]
    assert info["inter_session_loops"] == summary["inter_session_loops"]
    # One map: sweeps where only b drove (130-135 m into the lap, past its last loop into a)
    # are located in it from no pose, in a's frame, where the merged map put them. Measured:
    # the map itself 0.12-0.13 m off the truth there (b's own drift), the first (global) fixes
    # 0.27-0.30 m from it, then 0.02-0.09 m.
    loc = MapLocalizer.from_folder(out)
    mapped = SavedMap.load(out).poses
    for k in range(330, 336):
        f = drives["seq"][k]
        frame = loc.step(f.points, f.timestamps, stamp=f.stamp)
        assert frame.verdict.accepted, (k, frame.verdict.reasons)
        here = frame.pose.translation
        assert np.linalg.norm(here - drives["seq_truth"][k][:3, 3]) < 0.35
        if k >= 332:
            gap = np.linalg.norm(here - mapped[len(A_FRAMES) + k - B_FRAMES.start].translation)
            assert gap < 0.12, (k, gap)


def test_merge_refuses_another_block(
    drives: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Another seed: another block of the same shape, other façades, poles and cars."""
    other = _drive(SimulatedSequence("loop", laps=2, lap_length=LAP, seed=3), B_FRAMES, "c")
    other.save(tmp_path / "c")
    # Measured: before the inter-session overlap bound, 17 loops 1.1-1.5 m / 1.7-3.4° off
    # agreed (the same road, façades as far from it) and the two blocks were merged.
    argv = ["merge", str(drives["root"] / "a"), str(tmp_path / "c"), "-o", str(tmp_path / "m")]
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "scanreg merge: error: merge: " in err and "no reliable overlap, nothing joined" in err
    # Not one inter-session loop was accepted (measured), let alone enough that agree.
    assert "none matched" in err, err
    assert not (tmp_path / "m").exists()


def test_cli_extend_a_3d_map(tmp_path: Path) -> None:
    """``scanreg map NEW --extend OLD/`` on 3D: a second run over the first one's start (the
    simulator's same sweeps: the wiring, not the search, is what this tests) joins it."""
    old, out = tmp_path / "old", tmp_path / "both"
    assert main(["map", "sim:loop,lap_length=200,frames=40", "-o", str(old), "--json"]) == 0
    spec = "sim:loop,lap_length=200,frames=25"
    assert main(["map", spec, "--extend", str(old), "-o", str(out), "--json"]) == EXIT_OK
    joint = SavedMap.load(out)
    assert joint.dim == 3 and joint.sessions == ("sim:loop,lap_length=200,frames=40", spec)
    assert joint.num_scans == 65 and joint.scan_sessions is not None
    first, second = joint.session_poses(0), joint.session_poses(1)
    gap = [
        np.linalg.norm((p.inverse() @ q).translation) for p, q in zip(first, second, strict=False)
    ]
    assert max(gap) < 0.05, max(gap)
    assert sum(bool(r.get("inter_session")) and r["accepted"] for r in joint.loops) >= 2


def test_cli_extend_a_3d_map_from_a_bag_with_report_and_bag(tmp_path: Path) -> None:
    """The new 3D run from a ROS 2 PointCloud2 bag (the simulator's sweeps with their
    per-point time, written by rosbags' writer); ``--report`` and ``--bag`` of the joint map,
    as plain 3D runs write them."""
    pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'scanreg[ros]')")
    pytest.importorskip("plotly", reason="plotly is not installed (pip install 'scanreg[report]')")
    import re

    from scanreg.io.rosbag import list_topics
    from test_rosbag import CLOUD, _cloud_msg, _store, write_bag

    old, out = tmp_path / "old", tmp_path / "both"
    spec = "sim:loop,lap_length=200,frames=40"
    argv = ["map", spec, "-o", str(old), "--json", "--report", "--bag", str(old / "map.mcap")]
    assert main(argv) == EXIT_OK
    assert (old / "report.html").is_file() and (old / "map.mcap").is_file()
    seq = SimulatedSequence("loop", lap_length=200, num_frames=25)
    ts, t0 = _store("mcap"), 1_700_000_000_000_000_000
    layout = np.dtype([("x", "f4"), ("y", "f4"), ("z", "f4"), ("time", "f4")])
    msgs = []
    for k in range(len(seq)):
        f = seq[k]
        records = np.zeros(len(f.points), layout)
        for i, axis in enumerate("xyz"):
            records[axis] = f.points[:, i]
        records["time"] = f.timestamps
        stamp = t0 + round(f.stamp * 1e9)
        msgs.append((stamp, _cloud_msg(ts, "mcap", records, stamp)))
    bag = write_bag(tmp_path / "drive", "mcap", {"/points": (CLOUD, msgs)})
    argv = ["map", str(bag), "--extend", str(old), "-o", str(out), "--json", "--report"]
    assert main([*argv, "--bag", str(out / "map.mcap")]) == EXIT_OK
    joint = SavedMap.load(out)
    assert joint.sessions == (spec, str(bag)) and joint.num_scans == 65
    first, second = joint.session_poses(0), joint.session_poses(1)
    gap = [
        np.linalg.norm((p.inverse() @ q).translation) for p, q in zip(first, second, strict=False)
    ]
    assert max(gap) < 0.05, max(gap)  # the same sweeps, from the bag
    text = (out / "report.html").read_text(encoding="utf-8")
    text = re.sub(r"\\u([0-9a-f]{4})", lambda m: chr(int(m.group(1), 16)), text)
    assert f"session 0: {spec}" in text and f"session 1: {bag}" in text
    assert 'id="scanreg-map"' in text and "loop closures (between sessions)" in text
    assert "both, a map of 2 sessions" in text
    # The path length is each session's own (not the jump back to the start between them).
    length = sum(
        np.linalg.norm(
            np.diff([p.translation for p in joint.session_poses(k)], axis=0), axis=1
        ).sum()
        for k in (0, 1)
    )
    assert f"<b>{length:.1f} m</b>" in text, length
    topics = {t.name: t.message_count for t in list_topics(out / "map.mcap")}
    assert topics["/scanreg/pose"] == topics["/scanreg/scan"] == joint.num_nodes
    assert topics["/scanreg/map"] == 1
    assert "report.html" in json.loads((out / MANIFEST).read_text())["files"]
    # 3D mapping has no checkpoints: refused, not ignored.
    assert main([*argv, "--checkpoint", "10"]) == EXIT_BAD_INPUT
