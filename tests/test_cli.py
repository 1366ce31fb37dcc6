"""The scanreg command line, checked through its JSON output and exit codes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import data_dir
from scanreg import cli, io
from scanreg import eval as ev


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, object]:
    assert cli.main([*argv, "--json"]) == cli.EXIT_OK
    result: dict[str, object] = json.loads(capsys.readouterr().out)
    return result


def test_info_on_a_real_kitti_scan(capsys: pytest.CaptureFixture[str]) -> None:
    path = data_dir("kitti-odometry-00-frames-000-015", "velodyne", "000000.bin")
    out = run_json(capsys, "info", str(path))
    raw = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    assert out["points"] == raw.shape[0] == 124668
    assert out["dim"] == 3
    np.testing.assert_allclose(out["min"], raw[:, :3].min(axis=0), rtol=1e-6)  # type: ignore[arg-type]
    assert out["fields"] == ["intensity"]


def test_info_on_a_trajectory(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 3.0, 7.0]
    path = tmp_path / "poses.txt"
    io.write_kitti_poses(path, io.Trajectory(poses))
    out = run_json(capsys, "info", str(path), "--trajectory-format", "kitti")
    assert out["poses"] == 3
    assert out["path_length_m"] == pytest.approx(7.0)


def test_evaluate_matches_the_library(capsys: pytest.CaptureFixture[str]) -> None:
    est = data_dir("trajectories-evo-testdata", "KITTI_00_ORB.txt")
    ref = data_dir("kitti-odometry-00-frames-000-015", "poses_00_full.txt")
    out = run_json(capsys, "evaluate", str(est), str(ref), "--format", "kitti", "--metric", "ate")
    direct = ev.absolute_trajectory_error(io.read_kitti_poses(est), io.read_kitti_poses(ref))
    assert out["translation_m"]["rmse"] == pytest.approx(direct.translation.rmse, rel=1e-12)  # type: ignore[index]
    # evo's stored APE for this pair (res_files/orb_ape.zip) is 1.3034 m.
    assert out["translation_m"]["rmse"] == pytest.approx(1.3034, abs=1e-4)  # type: ignore[index]
    out = run_json(capsys, "evaluate", str(est), str(ref), "--format", "kitti", "--metric", "kitti")
    assert out["translation_percent"] == pytest.approx(0.6997, abs=1e-3)


def test_bad_input_exits_3_with_the_file_named(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    bad = tmp_path / "broken.pcd"
    bad.write_text("not a pcd\n")
    assert cli.main(["info", str(bad)]) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "scanreg info: error:" in err and "broken.pcd" in err
    assert cli.main(["info", str(tmp_path / "missing.ply")]) == cli.EXIT_BAD_INPUT
    assert "missing.ply" in capsys.readouterr().err


def test_usage_errors_exit_2() -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["evaluate", "a.txt"])
    assert exc.value.code == cli.EXIT_USAGE
    with pytest.raises(SystemExit) as exc:
        cli.main(["frobnicate"])
    assert exc.value.code == cli.EXIT_USAGE


def test_demo_runs_end_to_end_as_a_command() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "scanreg", "demo"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert "estimate inside 3σ of the predicted covariance: yes" in done.stdout


def _write_pair(tmp_path: Path) -> tuple[Path, Path, np.ndarray]:
    """A simulated street sweep and the same points moved by a known T_target_source."""
    from scanreg import SE3
    from scanreg import simulate as sim

    sweep = sim.simulate_sweep(
        sim.street(seed=3),
        sim.LidarModel.preset("vlp16"),
        sim.Trajectory.stationary(SE3.from_vector([0, 1.75, 1.73, 0, 0, 0])),
        seed=0,
    )
    truth = SE3.from_vector([0.4, -0.2, 0.05, 0.0, 0.01, 0.05])
    src, tgt = tmp_path / "source.ply", tmp_path / "target.ply"
    io.write_points(src, io.PointCloud(np.ascontiguousarray(sweep.points)))
    io.write_points(tgt, io.PointCloud(truth.apply(sweep.points)))
    return src, tgt, truth.as_matrix()


def test_register_recovers_a_known_transform(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    src, tgt, truth = _write_pair(tmp_path)
    out = run_json(capsys, "register", str(src), str(tgt), "--max-correspondence-distance", "2")
    assert out["converged"] is True and out["stop_reason"] == "converged"
    np.testing.assert_allclose(out["pose"], truth, atol=1e-3)  # type: ignore[arg-type]
    assert 0.9 < out["fitness"] <= 1.0  # type: ignore[operator]
    assert np.array(out["covariance"]).shape == (6, 6)


def test_register_exit_code_1_when_not_converged(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    src, tgt, _ = _write_pair(tmp_path)
    code = cli.main(["register", str(src), str(tgt), "--max-iterations", "1", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == cli.EXIT_CHECK_FAILED
    assert out["converged"] is False and out["stop_reason"] == "max_iterations"
