"""One notion of degeneracy: ``result.degeneracy`` is the only verdict on weakness. A 2D frame,
a 3D frame and the registration behind it agree on the corridor, tunnel, room and street, and
``Conditioning`` carries numbers only."""

from __future__ import annotations

import numpy as np
import pytest
import scanreg
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.pipeline import Odometry2D
from scanreg.pipeline.odometry import Odometry, OdometryConfig
from test_odometry import _odometry, _run, _tunnel

LASER = sim.LaserModel.preset("laser_360")


def _scans(scene: sim.Scene, pose: SE2) -> list[np.ndarray]:
    poses = [pose, pose @ SE2.from_vector([0.3, 0.1, np.deg2rad(2.0)])]
    return [
        np.ascontiguousarray(sim.simulate_scan(scene, LASER, p, seed=k).points)
        for k, p in enumerate(poses)
    ]


def _2d_flags(scene: sim.Scene, pose: SE2) -> tuple[bool, bool]:
    src_tgt = _scans(scene, pose)
    res = scanreg.register(src_tgt[1], src_tgt[0], max_correspondence_distance=1.0)
    odo = Odometry2D()
    odo.step(src_tgt[0])
    frame = odo.step(src_tgt[1], prior=SE2.from_vector([0.3, 0.1, np.deg2rad(2.0)]))
    assert frame.registration is not None and frame.registration.degeneracy is not None
    assert frame.degenerate == frame.registration.degeneracy.degenerate
    assert res.degeneracy is not None
    return res.degeneracy.degenerate, frame.degenerate


def test_corridor_and_room_in_2d() -> None:
    assert _2d_flags(sim.corridor(length=200.0, width=3.0), SE2.from_vector([100.0, 0, 0])) == (
        True,
        True,
    )
    assert _2d_flags(sim.square_room(5.0), SE2.from_vector([0.5, 0.3, 0.3])) == (False, False)


def test_tunnel_and_street_in_3d() -> None:
    seq, gt = _tunnel()
    odo = Odometry(OdometryConfig())
    for k in range(6):
        f = seq[k]
        prior = None if k == 0 else scanreg.SE3.from_matrix(np.linalg.inv(gt[k - 1]) @ gt[k])
        frame = odo.step(f.points, f.timestamps, prior, stamp=f.stamp)
    # The tunnel's axis is held to the prior: the frame is degenerate, and says along what.
    assert frame.held_directions and frame.degenerate
    # One way to hold: the registration's solve held the axis, so the pose returned is the one
    # its verdict judged; only the covariance along the axis becomes the prior's.
    reg = frame.registration
    assert reg is not None and frame.pose == reg.pose and frame.verdict is reg.verdict
    sigma = OdometryConfig().prior_sigma
    assert frame.covariance[0, 0] == pytest.approx(sigma**2, rel=1e-3)
    assert frame.covariance[0, 0] > 10 * reg.covariance[0, 0]
    run = _run("street", 10.0, 4)
    frames = _odometry(run, OdometryConfig())
    for frame in frames[1:]:
        reg = frame.registration
        assert reg is not None and reg.degeneracy is not None
        assert not frame.degenerate and not reg.degeneracy.degenerate and not frame.held_directions


def test_conditioning_is_numbers_only() -> None:
    src, tgt = _scans(sim.square_room(5.0), SE2.from_vector([0.5, 0.3, 0.3]))
    cond = scanreg.register(tgt, src).conditioning
    assert not hasattr(cond, "weak_directions") and not hasattr(cond, "degenerate")
    assert 0.0 < cond.weakest.ratio <= 1.0 and cond.scaled_condition_number >= 1.0
