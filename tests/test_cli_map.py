"""``scanreg map``: a real CARMEN excerpt end to end through the JSON and the files; bad input."""

from __future__ import annotations

import bz2
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import data_dir, interrupt_mapping_at
from scanreg.cli import EXIT_BAD_INPUT, EXIT_OK, main

pytest.importorskip("gtsam")


@pytest.fixture(scope="module")
def excerpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 1200 lines of the Intel log (about 400 scans) as a .clf.bz2."""
    source = data_dir("freiburg-slam-benchmark", "intel.clf.bz2")
    with bz2.open(source, "rt", encoding="utf-8") as fh:
        lines = [next(fh) for _ in range(1200)]
    path = tmp_path_factory.mktemp("log") / "intel_head.clf.bz2"
    with bz2.open(path, "wt", encoding="utf-8") as fh:
        fh.writelines(lines)
    return path


def test_map_end_to_end(
    excerpt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: Any
) -> None:
    from scanreg import SE2
    from scanreg.pipeline import map_check

    # The self-check of the run's poses with the second half turned 0.5 rad about its first
    # pose, neighbours judging each other too: the run must say it is inconsistent, and go on.
    strict = map_check.MapCheckSettings(min_gap=0)
    check_map = map_check.check_map

    def twisted(res: Any) -> Any:
        half = res.poses[len(res.poses) // 2]
        turn = half @ SE2.from_vector([0.0, 0.0, 0.5]) @ half.inverse()
        poses = [p if k < len(res.poses) // 2 else turn @ p for k, p in enumerate(res.poses)]
        return check_map(res, poses, settings=strict)

    monkeypatch.setattr(map_check, "check_map", twisted)
    out = tmp_path / "out"
    config = tmp_path / "map.toml"
    config.write_text("node_distance = 0.4\n[loops]\nmin_score = 0.55\n", encoding="utf-8")
    bag = out / "map.mcap"
    args = ["map", str(excerpt), "-o", str(out), "--config", str(config), "--json"]
    code = main([*args, "--bag", str(bag), "--report"])
    assert code == EXIT_OK
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    n = result["num_scans"]
    assert 300 < n < 500 and result["skipped_scans"] == 0
    check = result["self_check"]
    assert not check["consistent"] and check["contradictions"] > 0, check
    assert "scanreg map: WARNING: the map is inconsistent: contradictions:" in captured.err
    # ... and where to look: the worst square and the scans whose returns it contradicts (the
    # half turned by 0.5 rad is the second one, from scan n // 2 on).
    worst = check["regions"][0]
    assert f"scanreg map: contradicted: {worst['contradictions']} of" in captured.err
    assert any(b >= n // 2 for _, b, _ in worst["passes"]), worst
    assert json.loads((out / "summary.json").read_text())["self_check"] == check
    report = (out / "report.html").read_text(encoding="utf-8")
    assert "Self-check" in report and "whose they are" in report
    assert result["num_nodes"] > 20
    assert result["timing"]["total"] > 0 and result["scans_per_second"] > 0
    for key in ("poses_kitti", "poses_tum", "graph", "loops", "map_pgm", "map_yaml", "map_png"):
        assert Path(result["outputs"][key]).is_file(), key
    tum = np.loadtxt(out / "poses_tum.txt")
    assert tum.shape == (n, 8)
    # Stamped with each scan's own ipc_timestamp, in file order.
    assert 9.76e8 < tum[0, 0] < 9.77e8
    assert np.allclose(tum[-1, 1:3], result["final_pose"][:2])
    assert np.loadtxt(out / "poses_kitti.txt").shape == (n, 12)
    effective = (out / "config.toml").read_text()
    assert "node_distance = 0.4" in effective and "min_score = 0.55" in effective
    assert "resolution: 0.05" in (out / "map.yaml").read_text()
    # The bag: one message set per graph node, the grid and the loop markers, read back.
    from scanreg.io import list_topics

    topics = {t.name: t for t in list_topics(bag)}
    assert topics["/scanreg/grid"].msgtype == "nav_msgs/msg/OccupancyGrid"
    assert topics["/scanreg/odometry"].message_count == result["num_nodes"]
    # Latched once when the run matched any loop (accepted or rejected: both are drawn).
    assert ("/scanreg/loop_closures" in topics) == bool(
        result["loops_accepted"] + result["loops_rejected"]
    )
    assert result["outputs"]["bag"] == str(bag)
    report = Path(result["outputs"]["report"]).read_text(encoding="utf-8")
    assert report.startswith("<!DOCTYPE html>") and "plotly" in report
    # The same log located in its own saved map, from no initial pose (a global fix first).
    loc = tmp_path / "loc"
    code = main(["localize", str(excerpt), "--map", str(out), "-o", str(loc), "--json"])
    assert code == EXIT_OK
    found = json.loads(capsys.readouterr().out)
    assert found["num_scans"] == n and found["global_fixes"] >= 1
    rows = [json.loads(line) for line in (loc / "quality.jsonl").read_text().splitlines()]
    assert rows[0]["prediction_source"] == "global" and rows[0]["accepted"]
    assert found["accepted"] >= 0.9 * n, found
    located = np.loadtxt(loc / "poses_tum.txt")
    ok = np.array([r["accepted"] for r in rows])
    gap = np.linalg.norm(located[ok, 1:3] - tum[ok, 1:3], axis=1)
    assert np.median(gap) < 0.05, np.median(gap)


def test_map_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 3 1.0 nope\n", encoding="utf-8")
    assert main(["map", str(bad), "-o", str(tmp_path / "o"), "--quiet"]) == EXIT_BAD_INPUT
    assert "bad.clf" in capsys.readouterr().err
    typo = tmp_path / "typo.toml"
    typo.write_text("node_distanse = 0.4\n", encoding="utf-8")
    code = main(["map", str(bad), "--config", str(typo), "-o", str(tmp_path / "o")])
    assert code == EXIT_BAD_INPUT
    assert "node_distanse" in capsys.readouterr().err
    assert main(["map", str(bad), "--max-scans", "0", "-o", str(tmp_path / "o")]) == EXIT_BAD_INPUT


def test_odometry_reads_carmen_logs(
    excerpt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # `scanreg odometry` on a 2D CARMEN log: Odometry2D with the wheel prior, the mapping
    # pipeline's odometry settings under the user's strict config file.
    out = tmp_path / "odo"
    config = tmp_path / "odo.toml"
    config.write_text("max_keyframes = 30\n", encoding="utf-8")
    code = main(["odometry", str(excerpt), "-o", str(out), "--config", str(config), "--json"])
    assert code == EXIT_OK
    result = json.loads(capsys.readouterr().out)
    n = result["frames"]
    assert 300 < n < 500 and result["front_end"] == "correlative"
    tum = np.loadtxt(out / "poses_tum.txt")
    assert tum.shape == (n, 8) and 9.76e8 < tum[0, 0] < 9.77e8
    assert np.allclose(tum[-1, 1:3], result["final_pose"][:2])
    rows = [json.loads(line) for line in (out / "quality.jsonl").read_text().splitlines()]
    assert len(rows) == n and rows[0]["prediction_source"] == "first"
    assert all(r["prediction_source"] == "prior" for r in rows[1:])  # the wheel odometry
    effective = (out / "config.toml").read_text()
    assert "max_keyframes = 30" in effective and 'front_end = "correlative"' in effective
    typo = tmp_path / "typo.toml"
    typo.write_text("max_keyframe = 30\n", encoding="utf-8")
    assert main(["odometry", str(excerpt), "--config", str(typo), "-o", str(out)]) == EXIT_BAD_INPUT
    assert "max_keyframe" in capsys.readouterr().err
    code = main(["odometry", str(excerpt), "--preset", "velodyne-hdl64", "-o", str(out)])
    assert code == EXIT_BAD_INPUT
    assert "--preset: not available for a 2D laser log" in capsys.readouterr().err


def test_interrupted_map_writes_what_was_mapped(
    excerpt: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Ctrl-C at the 150th scan: the run stops, says so, and leaves a readable folder of what
    # it had mapped (poses, graph, map), never nothing.
    from scanreg.cli import EXIT_INTERRUPTED

    interrupt_mapping_at(monkeypatch, 150)
    out = tmp_path / "out"
    code = main(["map", str(excerpt), "-o", str(out), "--quiet", "--no-plots"])
    assert code == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    assert "stopped at scan 150 of" in err and "interrupted" in err
    assert f"what was mapped so far is written to {out}/ (150 scans" in err
    tum = np.loadtxt(out / "poses_tum.txt")
    assert tum.shape == (150, 8)
    assert (out / "graph.g2o").read_text().startswith("VERTEX_SE2")
    assert (out / "map.pgm").is_file() and (out / "map.yaml").is_file()


def test_checkpoint_writes_partial_outputs(
    excerpt: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from scanreg.pipeline import mapping

    seen: list[int] = []
    original = mapping.Mapper.snapshot

    def spy(self: mapping.Mapper, reason: str) -> mapping.MappingResult[mapping.SE2]:
        partial = original(self, reason)
        seen.append(partial.num_scans)
        return partial

    monkeypatch.setattr(mapping.Mapper, "snapshot", spy)
    out = tmp_path / "out"
    args = ["map", str(excerpt), "-o", str(out), "--quiet", "--no-plots", "--max-scans", "250"]
    code = main([*args, "--checkpoint", "100", "--json"])
    assert code == EXIT_OK
    assert seen == [100, 200]
    assert json.loads(capsys.readouterr().out)["partial"] is None
    assert np.loadtxt(out / "poses_tum.txt").shape == (250, 8)  # the final run overwrote it
    assert main(["map", str(excerpt), "-o", str(out), "--checkpoint", "0"]) == EXIT_BAD_INPUT
    assert "--checkpoint must be >= 1" in capsys.readouterr().err
