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


def test_demo_runs_end_to_end_as_a_command(tmp_path: Path) -> None:
    # The whole demo (its figures are tested one by one in test_demo.py): every check passes
    # and it leaves the 2D map and its report where it was told.
    pytest.importorskip("gtsam")
    pytest.importorskip("plotly")
    done = subprocess.run(
        [sys.executable, "-m", "scanreg", "demo", "-o", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "scanreg demo: PASS: all 13 checks" in done.stdout, done.stdout
    assert f"open {tmp_path / 'room_tour' / 'report.html'}" in done.stdout
    assert (tmp_path / "room_tour" / "report.html").stat().st_size > 10_000
    assert (tmp_path / "room_tour" / "map.yaml").is_file()
    assert "estimate inside 3σ of the predicted covariance: yes" in done.stdout
    assert "street drift below 2 % of the path: yes" in done.stdout
    assert "held to the prior: translation along (1.00" in done.stdout


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


def test_simulate_writes_scans_and_truth(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from scanreg import SE3
    from scanreg import simulate as sim

    out_dir = tmp_path / "run"
    args = ["simulate", "--scene", "street", "--sensor", "vlp16", "--scans", "3"]
    out = run_json(
        capsys, *args, "--speed", "8", "--yaw-rate", "0.1", "--seed", "2", "-o", str(out_dir)
    )
    assert out["scans"] == 3 and out["dim"] == 3
    assert sorted(p.name for p in out_dir.glob("*.pcd")) == [f"{k:06d}.pcd" for k in range(3)]
    # The same run through the library: the files must hold its truth and its points.
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        8.0,
        0.1,
        duration=0.1 * 3 + 0.5,
        dim=3,
        start=SE3.from_vector([0.0, 1.75, 1.73, 0.0, 0.0, 0.0]),
    )
    lidar = sim.LidarModel.preset("vlp16")
    run = sim.simulate_run(sim.street(seed=2), lidar, traj, num_scans=3, seed=2)
    truth = np.array([p.as_matrix() for p in run.poses])
    kitti = io.read_kitti_poses(out_dir / "poses_kitti.txt")
    tum = io.read_tum(out_dir / "poses_tum.txt")
    np.testing.assert_allclose(kitti.poses, truth, atol=1e-9)
    np.testing.assert_allclose(tum.poses, truth, atol=1e-9)
    assert tum.timestamps is not None
    np.testing.assert_allclose(tum.timestamps, run.start_times, atol=1e-9)
    cloud = io.read_points(out_dir / "000001.pcd")
    assert cloud.ring is not None and cloud.time is not None
    assert len(cloud) == len(run.scans[1].points) == out["points_per_scan"][1]  # type: ignore[index]
    np.testing.assert_allclose(cloud.points, run.scans[1].points, atol=1e-4)  # float32 file
    info = run_json(capsys, "info", str(out_dir / "000001.pcd"))
    assert info["points"] == len(run.scans[1].points)
    assert info["fields"] == ["ring", "time"]


def test_simulate_2d_csv_and_pcd(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out = run_json(capsys, "simulate", "--scans", "4", "-o", str(tmp_path / "a"))
    assert out["dim"] == 2 and len(list((tmp_path / "a").glob("*.csv"))) == 4
    info = run_json(capsys, "info", str(tmp_path / "a" / "000002.csv"))
    assert info["dim"] == 2 and info["points"] == out["points_per_scan"][2]  # type: ignore[index]
    assert len(io.read_kitti_poses(tmp_path / "a" / "poses_kitti.txt")) == 4
    out = run_json(
        capsys,
        "simulate",
        "--scene",
        "corridor",
        "--sensor",
        "laser_360",
        "--scans",
        "2",
        "--format",
        "pcd",
        "-o",
        str(tmp_path / "b"),
    )
    cloud = io.read_points(tmp_path / "b" / "000000.pcd")
    assert cloud.dim == 3 and np.all(cloud.points[:, 2] == 0.0)


@pytest.mark.parametrize(
    ("argv", "code"),
    [
        (["simulate", "--scene", "mars", "-o", "x"], cli.EXIT_USAGE),
        (["simulate", "--sensor", "hdl64"], cli.EXIT_USAGE),  # no -o
        (["simulate", "--scans", "many", "-o", "x"], cli.EXIT_USAGE),
        (
            ["simulate", "--scene", "street", "--sensor", "sick_lms200", "-o", "x"],
            cli.EXIT_BAD_INPUT,
        ),
        (["simulate", "--scene", "floor_plan", "--sensor", "vlp16", "-o", "x"], cli.EXIT_BAD_INPUT),
        (["simulate", "--scans", "0", "-o", "x"], cli.EXIT_BAD_INPUT),
        (["simulate", "--speed", "nan", "-o", "x"], cli.EXIT_BAD_INPUT),
    ],
)
def test_simulate_bad_arguments(
    argv: list[str], code: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    if code == cli.EXIT_USAGE:
        with pytest.raises(SystemExit) as exc:
            cli.main(argv)
        assert exc.value.code == code
    else:
        assert cli.main(argv) == code
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    "command", ["demo", "info", "evaluate", "register", "plot", "simulate", "odometry"]
)
def test_every_subcommand_help_shows_examples(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main([command, "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and f"scanreg {command}" in text
