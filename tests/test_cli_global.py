"""`scanreg register SOURCE TARGET --global`: JSON with the verdict and the hypotheses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scanreg import io
from scanreg import simulate as sim
from scanreg.cli import main
from scanreg.transform import SE3


def test_register_global_json_and_exit_status(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = sim.street(seed=4, length=80.0, num_pedestrians=0, num_moving_cars=0)
    pts = sim.simulate_sweep(
        scene, sim.LidarModel.preset("hdl64"), SE3.from_vector([0, 0, 1.8, 0, 0, 0])
    ).points
    move = SE3.from_vector([2.0, -1.0, 0.3, 0.1, -0.2, 2.0])
    io.write_points(tmp_path / "s.ply", io.PointCloud(pts @ move.rotation.T + move.translation))
    io.write_points(tmp_path / "t.ply", io.PointCloud(pts))
    code = main(
        ["register", str(tmp_path / "s.ply"), str(tmp_path / "t.ply"), "--global", "--json"]
    )
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert out["accepted"] is True and out["reasons"] == []
    np.testing.assert_allclose(np.array(out["pose"]), move.inverse().as_matrix(), atol=0.01)
    assert np.array(out["covariance"]).shape == (6, 6)
    assert out["hypotheses"][0]["num_inliers"] > 12
    # No overlap at all: exit status 1 and the reason.
    io.write_points(tmp_path / "far.ply", io.PointCloud(pts[pts[:, 0] > 15]))
    io.write_points(tmp_path / "near.ply", io.PointCloud(pts[pts[:, 0] < -15]))
    code = main(
        ["register", str(tmp_path / "far.ply"), str(tmp_path / "near.ply"), "--global", "--json"]
    )
    out = json.loads(capsys.readouterr().out)
    assert code == 1
    assert out["accepted"] is False and out["pose"] is None
    assert out["reasons"][0] == "no reliable alignment"
