"""Per-frame tables (JSON lines, CSV) and pose writers, read back; the CLI's sequence summaries
and progress output."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import data_dir
from scanreg import SE3, cli
from scanreg.io import (
    read_jsonl,
    read_kitti_poses,
    read_tum,
    write_csv_rows,
    write_jsonl,
    write_poses,
    write_rows,
)

ROWS = [
    {"frame": 0, "accepted": True, "fitness": 0.93, "reasons": "", "sigma_x": np.float64(0.01)},
    {"frame": 1, "accepted": False, "fitness": float("nan"), "reasons": "degenerate: x"},
    {"frame": 2, "accepted": True, "fitness": 1 / 3, "extra": None, "iterations": np.int64(7)},
]


def test_jsonl_round_trip(tmp_path: Path) -> None:
    path = write_rows(tmp_path / "q.jsonl", ROWS)
    back = read_jsonl(path)
    assert len(back) == 3
    assert back[0] == {
        "frame": 0,
        "accepted": True,
        "fitness": 0.93,
        "reasons": "",
        "sigma_x": 0.01,
    }
    assert back[1]["fitness"] is None  # JSON has no NaN
    assert back[2]["fitness"] == 1 / 3 and back[2]["iterations"] == 7
    for line in path.read_text().splitlines():
        json.loads(line)  # strict JSON per line


def test_csv_round_trip(tmp_path: Path) -> None:
    path = write_rows(tmp_path / "q.csv", ROWS)
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == [
        "frame",
        "accepted",
        "fitness",
        "reasons",
        "sigma_x",
        "extra",
        "iterations",
    ]
    assert rows[0]["accepted"] == "true" and rows[1]["accepted"] == "false"
    assert rows[1]["fitness"] == "nan" and rows[1]["sigma_x"] == ""
    assert float(rows[2]["fitness"]) == 1 / 3  # repr precision
    assert rows[1]["reasons"] == "degenerate: x"
    assert write_csv_rows(tmp_path / "empty.csv", []).read_text().strip() == ""


def test_rows_rejected(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match=r"rows\[0\]\['pose'\]: expected a scalar"):
        write_jsonl(tmp_path / "a.jsonl", [{"pose": [1, 2, 3]}])
    with pytest.raises(TypeError, match=r"rows\[1\]: expected a mapping"):
        write_csv_rows(tmp_path / "a.csv", [{"a": 1}, [1]])  # type: ignore[list-item]
    with pytest.raises(ValueError, match=r"no table writer for '\.txt'"):
        write_rows(tmp_path / "a.txt", ROWS)
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"a": 1}\n[1]\n')
    with pytest.raises(ValueError, match="line 2: expected an object"):
        read_jsonl(bad)


def test_write_poses_kitti_and_tum(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    poses = [SE3.exp(rng.normal(0, 1, 6)) for _ in range(5)]
    stamps = 1_700_000_000.0 + 0.1 * np.arange(5)
    k = write_poses(tmp_path / "est_kitti.txt", poses, "kitti")
    np.testing.assert_allclose(
        read_kitti_poses(k).poses, [p.as_matrix() for p in poses], atol=1e-11
    )
    mats = np.array([p.as_matrix() for p in poses])
    t = write_poses(tmp_path / "est_tum.txt", mats, "tum", timestamps=stamps)
    tum = read_tum(t)
    np.testing.assert_allclose(tum.poses, mats, atol=1e-10)
    assert tum.timestamps is not None
    np.testing.assert_allclose(tum.timestamps, stamps, atol=1e-6)
    with pytest.raises(ValueError, match="TUM files need timestamps"):
        write_poses(tmp_path / "x.txt", mats, "tum")
    with pytest.raises(ValueError, match="format"):
        write_poses(tmp_path / "x.txt", mats, "g2o")


def test_write_run_outputs(tmp_path: Path) -> None:
    from scanreg import RegistrationSettings
    from scanreg.config import load_config
    from scanreg.io import write_run_outputs

    rng = np.random.default_rng(3)
    poses = np.array([SE3.exp(rng.normal(0, 1, 6)).as_matrix() for _ in range(4)])
    tr = SE3.exp(rng.normal(0, 1, 6))
    cfg = RegistrationSettings(kernel="cauchy")
    paths = write_run_outputs(
        tmp_path / "run",
        poses=poses,
        stamps=[0.0, 0.1, 0.2, 0.3],
        rows=ROWS,
        config=cfg,
        T_cam0_velo=tr,
    )
    assert sorted(paths) == [
        "config",
        "poses_kitti",
        "poses_kitti_cam0",
        "poses_tum",
        "quality_csv",
        "quality_jsonl",
    ]
    np.testing.assert_allclose(read_kitti_poses(paths["poses_kitti"]).poses, poses, atol=1e-11)
    cam = read_kitti_poses(paths["poses_kitti_cam0"]).poses
    np.testing.assert_allclose(
        np.linalg.inv(tr.as_matrix()) @ cam @ tr.as_matrix(), poses, atol=1e-9
    )
    assert len(read_jsonl(paths["quality_jsonl"])) == 3
    assert load_config(RegistrationSettings, paths["config"]) == cfg
    minimal = write_run_outputs(tmp_path / "min", poses=poses, stamps=[0, 1, 2, 3])
    assert sorted(minimal) == ["poses_kitti", "poses_tum"]


# --------------------------------------------------------------------------- CLI


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, object]:
    assert cli.main([*argv, "--json"]) == cli.EXIT_OK
    out: dict[str, object] = json.loads(capsys.readouterr().out)
    return out


def test_info_on_kitti_sequence(capsys: pytest.CaptureFixture[str]) -> None:
    out = _json(capsys, "info", str(data_dir("kitti-odometry-00-frames-000-015")))
    assert out["kind"] == "sequence" and out["loader"] == "KittiSequence"
    assert out["frames"] == 16 and out["ground_truth"] is True
    assert out["per_point_time"] is False
    assert out["points_per_frame"] == {"0": 124668, "8": 122123, "15": 121023}


def test_info_on_simulated_and_simulated_folder(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = _json(capsys, "info", "sim:street,frames=120")
    assert out["frames"] == 120 and out["per_point_time"] is True
    assert out["ground_truth_length_m"] == pytest.approx(119.0, rel=1e-3)
    run = tmp_path / "run"
    _json(
        capsys, "simulate", "--scene", "tunnel", "--sensor", "vlp16", "--scans", "3", "-o", str(run)
    )
    out = _json(capsys, "info", str(run))
    assert out["loader"] == "FolderSequence" and out["frames"] == 3
    assert out["ground_truth"] is True and out["per_point_time"] is True
    assert 0.09 < out["sweep_time_span_s"] < 0.1  # type: ignore[operator]
    assert cli.main(["info", "sim:mars"]) == cli.EXIT_BAD_INPUT
    assert "unknown scene 'mars'" in capsys.readouterr().err


def test_simulate_progress_goes_to_stderr_unless_quiet_or_json(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    args = ["simulate", "--scans", "3", "-o", str(tmp_path / "a")]
    assert cli.main(args) == cli.EXIT_OK
    captured = capsys.readouterr()
    assert captured.err.startswith("simulate 3/3 [####################] 100% ")
    assert "scans/s" in captured.err and "simulate 3/3" not in captured.out
    assert cli.main([*args, "--quiet"]) == cli.EXIT_OK
    assert capsys.readouterr().err == ""
    assert cli.main([*args, "--json"]) == cli.EXIT_OK
    captured = capsys.readouterr()
    assert captured.err == "" and json.loads(captured.out)["scans"] == 3
