"""`scanreg odometry` end to end, checked through its JSON output and the files it writes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import data_dir
from scanreg import cli
from scanreg.config import load_config
from scanreg.io import read_kitti_poses
from scanreg.pipeline.odometry import OdometryConfig


def odometry_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    assert cli.main(["odometry", *argv, "--json"]) == cli.EXIT_OK
    out: dict[str, Any] = json.loads(capsys.readouterr().out)
    return out


def test_simulated_street_is_scored_and_written(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = odometry_json(capsys, "sim:street,frames=15", "-o", str(tmp_path))
    assert out["frames"] == 15 and out["method"] == "gicp"
    assert out["accepted"] + out["rejected"] == 15
    assert out["accepted"] >= 13
    # 15 frames at the preset's speed: mid-sweep truth, exact. Measured ATE 0.01 m.
    assert out["accuracy"]["ate_rmse_m"] < 0.1
    poses = read_kitti_poses(tmp_path / "poses_kitti.txt").poses
    assert poses.shape == (15, 4, 4)
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    rows = [json.loads(line) for line in (tmp_path / "quality.jsonl").read_text().splitlines()]
    assert [r["frame"] for r in rows] == list(range(15))
    assert {"accepted", "reasons", "sigma_x", "overlap", "time_ms"} <= set(rows[1])
    # The effective config reads back to the same object.
    assert load_config(OdometryConfig, tmp_path / "config.toml") == OdometryConfig()
    for name in ("trajectory.png", "uncertainty.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_config_preset_and_method_flags(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    cfg = tmp_path / "run.toml"
    cfg.write_text("max_points_per_voxel = 10\n[thresholds]\nmin_overlap = 0.2\n")
    out = odometry_json(
        capsys,
        "sim:street,frames=4",
        "--config",
        str(cfg),
        "--preset",
        "ouster-os1-64",
        "--method",
        "point_to_plane",
        "--no-plots",
        "--save-map",
        "-o",
        str(tmp_path / "out"),
    )
    assert out["map_points"] > 1000 and (tmp_path / "out" / "map.ply").stat().st_size > 10_000
    assert out["method"] == "point_to_plane"
    eff = load_config(OdometryConfig, tmp_path / "out" / "config.toml")
    assert (eff.max_points_per_voxel, eff.voxel_size, eff.thresholds.min_overlap) == (10, 0.5, 0.2)
    assert not (tmp_path / "out" / "trajectory.png").exists()


def test_unknown_config_key_exits_3_naming_it(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text("voxel_szie = 0.5\n")
    code = cli.main(["odometry", "sim:street,frames=2", "--config", str(cfg), "-o", str(tmp_path)])
    assert code == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "voxel_szie" in err and "voxel_size" in err  # the key and the suggestion


def test_real_kitti_frames(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    # The 16 real frames: their ground truth is doubtful (README), and KISS-ICP, GenZ-ICP and
    # small_gicp all end 1.17-1.23 m from it with ATE 0.36-0.37 m (../shared/bench results).
    # We must agree with them, not with the truth: ATE within 0.5 m, every frame accepted.
    folder = data_dir("kitti-odometry-00-frames-000-015")
    out = odometry_json(
        capsys, str(folder), "--preset", "velodyne-hdl64", "--no-plots", "-o", str(tmp_path)
    )
    assert out["frames"] == 16 and out["accepted"] == 16
    assert out["accuracy"]["ate_rmse_m"] < 0.5
    assert 0.6 < out["accuracy"]["end_error_m"] < 1.8
    assert (tmp_path / "poses_kitti_cam0.txt").exists()
