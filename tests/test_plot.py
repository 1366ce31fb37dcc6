"""Plots: every figure is written in the format its extension names, with the expected pixel
size; bad input is refused with errors naming the argument."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import scanreg
from scanreg import SE2, SE3
from scanreg.io import Trajectory

pytest.importorskip(
    "matplotlib", reason="matplotlib is not installed (pip install 'scanreg[plot]')"
)

from scanreg import plot
from scanreg.plot import _break_at_gaps, _plane_axes
from scanreg.quality import conditioning


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def _is_svg(path: Path) -> bool:
    text = path.read_text()
    return text.startswith("<?xml") and "<svg" in text and text.rstrip().endswith("</svg>")


@pytest.fixture(scope="module")
def scan_pair() -> tuple:
    rng = np.random.default_rng(0)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    ranges = np.where(np.abs(np.cos(angles)) > np.abs(np.sin(angles)) * 0.6, 4.0, 2.5)
    target = np.ascontiguousarray(np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], 1))
    pose = SE2.from_vector([0.3, -0.1, 0.1])
    source = np.ascontiguousarray(pose.inverse().apply(target) + rng.normal(0, 0.01, target.shape))
    return source, target, scanreg.align_paired(source, target)


def _trajectory(n: int = 50, noise: float = 0.0, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n)
    xyyaw = np.stack([10 * np.cos(t), 5 * np.sin(t), t], axis=1) + rng.normal(0, noise, (n, 3))
    return Trajectory.from_xyyaw(xyyaw, timestamps=np.arange(n) * 0.1)


def test_scan_alignment_png_and_svg(tmp_path: Path, scan_pair: tuple) -> None:
    source, target, result = scan_pair
    png = plot.plot_scan_alignment(
        tmp_path / "a.png", source, target, result.pose, result.covariance
    )
    assert png == tmp_path / "a.png"
    assert _png_size(png) == (round(4.6 * 3 * 110), round(4.6 * 110))  # three panels
    two = plot.plot_scan_alignment(tmp_path / "b.png", source, target, result.pose)
    assert _png_size(two) == (round(4.6 * 2 * 110), round(4.6 * 110))  # no covariance: two
    svg = plot.plot_scan_alignment(
        tmp_path / "a.svg", source, target, result.pose, result.covariance
    )
    assert _is_svg(svg) and svg.stat().st_size > 10_000


def test_trajectory_figures(tmp_path: Path) -> None:
    ref = _trajectory()
    est = _trajectory(noise=0.05, seed=1)
    out = plot.plot_trajectories(tmp_path / "t.png", est, ref, alignment="se3")
    assert _png_size(out) == (round(6.4 * 110), round(6.0 * 110))
    assert _is_svg(plot.plot_trajectories(tmp_path / "t.svg", est))
    err = plot.plot_error_over_distance(tmp_path / "e.png", est, ref)
    assert _png_size(err) == (round(7.5 * 110), round(5.0 * 110))
    # the estimate differs from the reference: the figure differs from a perfect estimate's
    same = plot.plot_error_over_distance(tmp_path / "same.png", ref, ref)
    assert err.read_bytes() != same.read_bytes()


def test_weak_directions_and_histogram(tmp_path: Path, scan_pair: tuple) -> None:
    source, _, result = scan_pair
    every = plot.plot_weak_directions(
        tmp_path / "w_all.png", source, result.conditioning, all_directions=True
    )
    assert _png_size(every)[0] == round(5.2 * 3 * 110)  # one panel per direction
    # a corridor's point-to-line information: translation along x is free
    rng = np.random.default_rng(0)
    pts = np.ascontiguousarray(
        np.stack([rng.uniform(-10, 10, 200), np.where(rng.uniform(size=200) < 0.5, -1.0, 1.0)], 1)
    )
    jac = np.stack([np.zeros(200), np.ones(200), pts[:, 0]], axis=1)
    cond = conditioning(jac.T @ jac, 2, 5.0)
    assert cond.weakest.ratio < 1e-12
    assert cond.weakest.description == "translation along (1.00, 0.00)"
    assert _is_svg(plot.plot_weak_directions(tmp_path / "w.svg", pts, cond))
    # 3D conditioning with 3D points
    pts3 = np.ascontiguousarray(rng.normal(size=(100, 3)))
    weak_z = conditioning(np.diag([1.0, 1.0, 1e-9, 1.0, 1.0, 1.0]), 3, 1.0)  # free along z
    assert weak_z.weakest.description == "translation along (0.00, 0.00, 1.00)"
    assert _png_size(plot.plot_weak_directions(tmp_path / "w3.png", pts3, weak_z))[0] > 0
    residuals = np.concatenate([rng.normal(0, 0.02, 500), rng.uniform(-1, 1, 20)])
    hist = plot.plot_residual_histogram(tmp_path / "h.png", residuals, threshold=0.1, log=True)
    assert _png_size(hist) == (round(6.4 * 110), round(4.2 * 110))


def test_helpers() -> None:
    pos = np.arange(12.0).reshape(4, 3)
    broken = _break_at_gaps(pos, np.array([0.0, 0.1, 0.2, 5.0]))
    assert broken.shape == (5, 3) and np.isnan(broken[3]).all()
    assert _break_at_gaps(pos, None) is pos
    kitti_like = np.stack([np.linspace(0, 100, 10), np.zeros(10), np.linspace(0, 300, 10)], 1)
    assert _plane_axes("auto", kitti_like) == (0, 2)
    assert _plane_axes("yz", kitti_like) == (1, 2)


def test_refuses_bad_input(tmp_path: Path, scan_pair: tuple) -> None:
    source, target, result = scan_pair
    pose, cov = result.pose, result.covariance
    with pytest.raises(ValueError, match=r"path: .*\.jpg must end in one of"):
        plot.plot_scan_alignment(tmp_path / "a.jpg", source, target, pose)
    with pytest.raises(FileNotFoundError, match="path: folder"):
        plot.plot_scan_alignment(tmp_path / "missing" / "a.png", source, target, pose)
    with pytest.raises(TypeError, match=r"pose: expected a scanreg\.SE2"):
        plot.plot_scan_alignment(tmp_path / "a.png", source, target, SE3.identity())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="covariance"):
        plot.plot_scan_alignment(tmp_path / "a.png", source, target, pose, np.eye(6))
    with pytest.raises(ValueError, match="covariance: is not symmetric"):
        plot.plot_scan_alignment(tmp_path / "a.png", source, target, pose, cov + np.triu(cov, 1))
    with pytest.raises(ValueError, match="source"):
        plot.plot_scan_alignment(tmp_path / "a.png", np.zeros((5, 3)), target, pose)
    with pytest.raises(TypeError, match="target"):
        plot.plot_scan_alignment(tmp_path / "a.png", source, "target", pose)  # type: ignore[arg-type]
    ref = _trajectory()
    with pytest.raises(TypeError, match=r"estimate: expected a scanreg\.io\.Trajectory"):
        plot.plot_trajectories(tmp_path / "t.png", ref.poses)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="estimate: needs at least 2 poses"):
        plot.plot_trajectories(tmp_path / "t.png", Trajectory(ref.poses[:1]))
    with pytest.raises(ValueError, match="alignment"):
        plot.plot_trajectories(tmp_path / "t.png", ref, ref, alignment="umeyama")
    with pytest.raises(ValueError, match="alignment: needs a reference"):
        plot.plot_trajectories(tmp_path / "t.png", ref, alignment="se3")
    with pytest.raises(ValueError, match="plane"):
        plot.plot_trajectories(tmp_path / "t.png", ref, plane="xx")
    with pytest.raises(ValueError, match="points: the conditioning is over 3 dof"):
        plot.plot_weak_directions(tmp_path / "w.png", np.zeros((4, 3)), result.conditioning)
    with pytest.raises(TypeError, match="conditioning"):
        plot.plot_weak_directions(tmp_path / "w.png", source, result)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="residuals: contains NaN"):
        plot.plot_residual_histogram(tmp_path / "h.png", np.array([0.1, np.nan]))
    with pytest.raises(ValueError, match="residuals: is empty"):
        plot.plot_residual_histogram(tmp_path / "h.png", np.zeros(0))
    with pytest.raises(TypeError, match="residuals"):
        plot.plot_residual_histogram(tmp_path / "h.png", [0.1, 0.2])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="bins"):
        plot.plot_residual_histogram(tmp_path / "h.png", np.ones(3), bins=0)
    with pytest.raises(ValueError, match="threshold"):
        plot.plot_residual_histogram(tmp_path / "h.png", np.ones(3), threshold=-1.0)
    assert not list(tmp_path.iterdir())  # nothing was written by a refused call


def test_cli_plot(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    import json

    from scanreg import cli
    from scanreg.io import write_tum

    ref, est = _trajectory(), _trajectory(noise=0.05, seed=1)
    write_tum(tmp_path / "ref.txt", ref)
    write_tum(tmp_path / "est.txt", est)
    argv = ["plot", "trajectory", str(tmp_path / "est.txt"), "--format", "tum"]
    out_png = tmp_path / "t.png"
    assert (
        cli.main([*argv, "--reference", str(tmp_path / "ref.txt"), "-o", str(out_png), "--json"])
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result == {"plot": "trajectory", "output": str(out_png), "bytes": out_png.stat().st_size}
    assert _png_size(out_png) == (round(6.4 * 110), round(6.0 * 110))
    errs = [
        "plot",
        "errors",
        str(tmp_path / "est.txt"),
        str(tmp_path / "ref.txt"),
        "--format",
        "tum",
    ]
    assert cli.main([*errs, "--alignment", "se3", "-o", str(tmp_path / "e.svg")]) == 0
    assert _is_svg(tmp_path / "e.svg")
    capsys.readouterr()
    assert cli.main([*argv, "-o", str(tmp_path / "t.jpg")]) == cli.EXIT_BAD_INPUT
    assert "t.jpg" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli.main(["plot", "trajectory", str(tmp_path / "est.txt"), "--format", "tum"])  # no -o
    assert exc.value.code == cli.EXIT_USAGE
