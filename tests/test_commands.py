"""scanreg.pipeline.commands: each command's library function, called from Python, returns
what ``scanreg COMMAND --json`` prints and writes the same files; bad options are named."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from scanreg import cli
from scanreg.pipeline import commands


def _cli(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, object]:
    assert cli.main([*argv, "--json"]) == cli.EXIT_OK
    out: dict[str, object] = json.loads(capsys.readouterr().out)
    return out


def test_simulate_info_evaluate_register_as_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    ours = commands.simulate_to_folder(a, scene="corridor", scans=4, speed=0.5, seed=2)
    theirs = _cli(
        capsys, "simulate", "--scene", "corridor", "--scans", "4", "--speed", "0.5",
        "--seed", "2", "-o", str(b), "--quiet",
    )  # fmt: skip
    assert {**ours, "output": ""} == {**theirs, "output": ""}
    for name in ("000003.csv", "poses_tum.txt"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert commands.describe_input(a / "000000.csv") == _cli(capsys, "info", str(b / "000000.csv"))
    tum = str(a / "poses_tum.txt")
    got = commands.evaluate_trajectories(tum, b / "poses_tum.txt", format="tum", metric="rpe")
    assert got == _cli(capsys, "evaluate", tum, tum, "--format", "tum", "--metric", "rpe")
    assert got["translation_m"]["max"] == 0.0  # type: ignore[index]
    src, tgt = str(a / "000001.csv"), str(a / "000000.csv")
    reg = commands.register_files(src, tgt, method="point_to_line")
    printed = _cli(capsys, "register", src, tgt, "--method", "point_to_line")
    assert reg["pose"] == printed["pose"] and reg["converged"] is True


def test_bad_options_are_named(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="scene: expected one of"):
        commands.simulate_to_folder(tmp_path, scene="moon")
    with pytest.raises(ValueError, match="--scene street is not available for the 2D sensor"):
        commands.simulate_to_folder(tmp_path, scene="street")
    with pytest.raises(ValueError, match="kind: expected 'trajectory' or 'errors'"):
        commands.plot_trajectory_files("map", "a.txt", "b.png", format="tum")
    with pytest.raises(TypeError, match=r"path: expected a str or os\.PathLike"):
        commands.run_mapping_to_folder(3, tmp_path)  # type: ignore[arg-type]
    # The counts, positive values and options not available, each named as the CLI spells it.
    for scans, rate, message in (
        (0, 10.0, "--scans must be >= 1, got 0"),
        (2, 0.0, "--scan-rate must be > 0, got 0.0"),
        (2, float("nan"), "--scan-rate must be > 0, got nan"),
    ):
        with pytest.raises(ValueError, match=message):
            commands.simulate_to_folder(tmp_path, scans=scans, scan_rate=rate)
    with pytest.raises(ValueError, match="--max-frames must be >= 1, got 0"):
        commands.run_odometry_to_folder("sim:loop", tmp_path, max_frames=0)
    log = tmp_path / "run.clf"
    for options, message in (
        ({"max_frames": -2}, "--max-frames must be >= 1, got -2"),
        ({"save_map": True}, "--save-map: not available for a 2D laser log"),
    ):
        with pytest.raises(ValueError, match=message):
            commands.run_odometry_to_folder(log, tmp_path, **options)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="--max-scans must be >= 1, got 0"):
        commands.run_localization_to_folder(log, tmp_path, tmp_path / "loc", max_scans=0)
    pytest.importorskip("gtsam")
    for options, message in (
        ({"max_scans": 0}, "--max-scans must be >= 1, got 0"),
        ({"resolution": 0.0}, "--resolution must be > 0, got 0.0"),
        ({"checkpoint": 0}, "--checkpoint must be >= 1 scans, got 0"),
        ({"extend": tmp_path, "checkpoint": 0}, "--checkpoint must be >= 1 scans, got 0"),
    ):
        with pytest.raises(ValueError, match=message):
            commands.run_mapping_to_folder(log, tmp_path / "map", **options)  # type: ignore[arg-type]
    # A 3D --extend run keeps no checkpoint of its new run: refused, not ignored.
    with pytest.raises(ValueError, match=r"--checkpoint: not available for 3D --extend runs"):
        commands.run_mapping_to_folder("sim:loop", tmp_path / "m", checkpoint=5, extend=tmp_path)
