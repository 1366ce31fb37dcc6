"""Localization in a prior map (scanreg.Localizer) on a simulated street with exact truth."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scanreg import SE3, Localizer, OdometryConfig
from scanreg.io.sequences import SimulatedSequence


@cache
def _street() -> tuple[SimulatedSequence, np.ndarray, np.ndarray]:
    """40 sweeps at 5 m/s; the prior map is every third sweep, deskewed exactly, in the frame
    of the first sweep's start (the map frame)."""
    seq = SimulatedSequence("street", num_frames=40, speed=5.0)
    gt = seq.ground_truth_at("start")
    parts = [
        (gt[k][:3, :3] @ seq.sweep(k).points_deskewed.T).T + gt[k][:3, 3] for k in range(0, 40, 3)
    ]
    return seq, gt, np.ascontiguousarray(np.vstack(parts))


def _error(pose: SE3, truth: np.ndarray) -> tuple[float, float]:
    e = SE3.from_matrix(truth).inverse() @ pose
    return float(np.linalg.norm(e.translation)), float(np.degrees(e.angle))


def test_relocalizes_from_a_rough_guess_then_tracks() -> None:
    seq, gt, prior_map = _street()
    loc = Localizer(prior_map, OdometryConfig(deskew=False))
    k0 = 20
    guess = SE3.from_matrix(gt[k0]) @ SE3.from_vector([1.5, -1.0, 0.0, 0.0, 0.0, np.radians(25)])
    rel = loc.relocalize(seq.sweep(k0).points_deskewed, guess, radius=2.0, num_headings=12)
    assert rel.frame.verdict.accepted, rel.frame.verdict.reasons
    t, r = _error(rel.frame.pose, gt[k0])
    assert t < 0.02 and r < 0.1, (t, r)  # measured 0.8 mm, 0.008°
    for k in range(k0 + 1, k0 + 6):
        res = loc.step(seq.sweep(k).points_deskewed)
        t, r = _error(res.pose, gt[k])
        assert res.verdict.accepted and t < 0.02 and r < 0.1, (k, t, r)
        assert not res.map_updated
    assert len(loc.prior_map) == res.num_map_points  # the map never grows


def test_tracks_motion_distorted_sweeps_with_deskew() -> None:
    seq, _, prior_map = _street()
    k0 = 10
    # Mid-sweep truth (the odometry's reference time) in the map frame (first sweep's start).
    t0 = seq.trajectory.pose_at(float(seq.stamps[0])).inverse()
    half = 0.5 * seq.lidar.sweep_duration

    def truth(k: int) -> np.ndarray:
        pose = t0 @ seq.trajectory.pose_at(float(seq.stamps[k]) + half)
        out: np.ndarray = pose.as_matrix()
        return out

    loc = Localizer(prior_map, OdometryConfig(), initial_pose=truth(k0))
    for k in range(k0, k0 + 8):
        f = seq[k]
        res = loc.step(f.points, f.timestamps, stamp=f.stamp)
        t, _ = _error(res.pose, truth(k))
        assert t < 0.05, (k, t)


def test_a_guess_in_the_wrong_place_is_rejected() -> None:
    seq, gt, prior_map = _street()
    loc = Localizer(prior_map, OdometryConfig(deskew=False))
    wrong = SE3.from_matrix(gt[5]) @ SE3.from_vector([0.0, 60.0, 0.0, 0.0, 0.0, 0.0])
    rel = loc.relocalize(seq.sweep(20).points_deskewed, wrong, radius=2.0, num_headings=4)
    assert not rel.frame.verdict.accepted
    assert any(r.startswith("overlap") for r in rel.frame.verdict.reasons)
    assert loc.poses == ()  # a rejected relocalization leaves the track as it was


def test_bad_arguments_are_named() -> None:
    _, _, prior_map = _street()
    loc = Localizer(prior_map[:2000], OdometryConfig(deskew=False))
    pts = prior_map[:500]
    with pytest.raises(ValueError, match="radius"):
        loc.relocalize(pts, np.eye(4), radius=-1.0)
    with pytest.raises(ValueError, match="num_headings"):
        loc.relocalize(pts, np.eye(4), num_headings=0)
    with pytest.raises(ValueError, match="guess"):
        loc.relocalize(pts, np.eye(3))
    with pytest.raises(ValueError, match="map_points"):
        Localizer(np.zeros((3, 3)))


def test_ndt_localizer_tracks_in_the_prior_map() -> None:
    seq, gt, prior_map = _street()
    k0 = 12
    start = SE3.from_matrix(gt[k0]) @ SE3.from_vector([0.3, -0.2, 0.0, 0.0, 0.0, 0.02])
    loc = Localizer(prior_map, OdometryConfig(deskew=False), initial_pose=start, method="ndt")
    assert loc.ndt_map is not None
    for k in range(k0, k0 + 5):
        res = loc.step(seq.sweep(k).points_deskewed)
        t, r = _error(res.pose, gt[k])
        assert res.verdict.accepted, (k, res.verdict.reasons)
        assert res.registration is None and res.ndt is not None and res.ndt.converged
        assert t < 0.01 and r < 0.05, (k, t, r)  # measured 0.3-0.5 mm, < 0.003°
        assert np.all(np.isfinite(res.covariance)) and not res.map_updated
    with pytest.raises(ValueError, match="method: unknown 'icp'"):
        Localizer(prior_map, method="icp")
