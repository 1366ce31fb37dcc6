"""The final pass of 2D mapping (scanreg.pipeline.smoothing): step noise identified from a
run's own scan and wheel steps, and the scans between nodes re-solved, against exact truth on
synthetic runs (no scan matching: the errors are drawn, so they are known)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scanreg import SE2

pytest.importorskip("gtsam")

import itertools

from scanreg.pipeline.mapping import Mapper, MappingConfig
from scanreg.pipeline.smoothing import StepNoise, identify_step_noise, smooth_scan_poses

NODE_EVERY = 10


def _run(scan_sigma: Any, wheel_sigma: Any, *, n: int = 2000, scale: float = 1.0, seed: int = 0):
    """Truth (a wandering drive, 5 cm and about 1° a step); the scans' odometry, each pose off
    the truth by its own error ``exp(ε_k)`` (scan-to-map: errors that do not accumulate);
    the wheels' steps, each off by ``exp(w_k)`` and with distances reading ``1 / scale``."""
    rng = np.random.default_rng(seed)
    truth = [SE2.identity()]
    for _ in range(n - 1):
        truth.append(truth[-1] @ SE2.exp([0.05, 0.0, rng.normal(0.0, 0.02)]))
    odometry = [p @ SE2.exp(rng.normal(0.0, 1.0, 3) * scan_sigma) for p in truth]
    wheels: list[SE2 | None] = [None]
    for a, b in itertools.pairwise(truth):
        w = (a.inverse() @ b) @ SE2.exp(rng.normal(0.0, 1.0, 3) * wheel_sigma)
        wheels.append(SE2.from_rt(w.rotation, w.translation / scale))
    return truth, odometry, wheels


def _steps(odometry: list[SE2]) -> list[SE2 | None]:
    return [None] + [a.inverse() @ b for a, b in itertools.pairwise(odometry)]


def test_step_noise_is_identified_from_the_run() -> None:
    scan = np.array([0.006, 0.003, 0.002])
    wheel = np.array([0.005, 0.004, 0.003])
    _, odometry, wheels = _run(scan, wheel, n=4000, scale=1.04)
    noise = identify_step_noise(_steps(odometry), wheels)
    assert noise is not None
    assert noise.pairs == 3998
    assert noise.scale == pytest.approx(1.04, abs=0.004)  # measured 1.038
    # Measured: scans 0.0061, 0.0027, 0.0020; wheels 0.0046, 0.0042, 0.0029 (seeds 1-2 alike;
    # trimmed at the 99.5th percentile, which takes a little off a Gaussian's spread).
    np.testing.assert_allclose(noise.scan, scan, rtol=0.15)
    np.testing.assert_allclose(noise.wheel, wheel, rtol=0.15)


def test_a_wheel_bias_counts_as_wheel_error() -> None:
    # The residuals' mean is the wheels' (the scans' step error has none): a heading bias of
    # 0.004 rad a step on 0.003 of noise is 0.005 of error; wheels that report no motion
    # while the robot drives 5 cm a step are 5 cm off on every step. Identified around the
    # mean alone, both read as their noise (0.003 rad; the floor, 1 mm), and the final pass
    # trusted stalled wheels over the scans.
    scan = np.array([0.002, 0.002, 0.001])
    truth, odometry, wheels = _run(scan, np.array([0.004, 0.004, 0.003]), n=3000)
    biased = [None if w is None else w @ SE2.exp([0.0, 0.0, 0.004]) for w in wheels]
    noise = identify_step_noise(_steps(odometry), biased)
    assert noise is not None
    assert noise.wheel[2] == pytest.approx(0.005, rel=0.1)
    stalled: list[SE2 | None] = [None] + [SE2.identity()] * (len(truth) - 1)
    noise = identify_step_noise(_steps(odometry), stalled)
    assert noise is not None
    assert noise.scale == 1.0  # (no wheel distance to compare)
    assert noise.wheel[0] == pytest.approx(0.05, rel=0.05)


def test_identification_needs_enough_steps_and_matching_lengths() -> None:
    _, odometry, wheels = _run(np.full(3, 1e-3), np.full(3, 1e-3), n=40)
    assert identify_step_noise(_steps(odometry), wheels) is None
    with pytest.raises(ValueError, match="wheel_steps: expected 40 steps"):
        identify_step_noise(_steps(odometry), wheels[:-1])
    with pytest.raises(TypeError, match=r"wheel_steps\[3\]: expected an SE2 or None, got str"):
        identify_step_noise(_steps(odometry), [*wheels[:3], "x", *wheels[4:]])
    noise = StepNoise(scale=1.0, scan=np.full(3, 1e-3), wheel=np.full(3, 1e-3), pairs=0)
    with pytest.raises(ValueError, match="node_sigma: expected two positive numbers"):
        smooth_scan_poses(odometry, odometry, [True] * 40, wheels, [0], noise, (0.0, 1e-3))
    with pytest.raises(ValueError, match=r"nodes: indices \[40\] outside the 40 poses"):
        smooth_scan_poses(odometry, odometry, [True] * 40, wheels, [0, 40], noise, (1e-3, 1e-3))
    with pytest.raises(ValueError, match="poses: no pose to smooth"):
        smooth_scan_poses([], [], [], [], [], noise, (1e-3, 1e-3))
    with pytest.raises(ValueError, match=r"scan: expected three finite σ > 0, got \[nan"):
        StepNoise(scale=1.0, scan=np.array([np.nan, 1e-3, 1e-3]), wheel=np.full(3, 1e-3), pairs=0)
    with pytest.raises(ValueError, match=r"wheel: expected shape \(3,\)"):
        StepNoise(scale=1.0, scan=np.full(3, 1e-3), wheel=np.full(2, 1e-3), pairs=0)
    with pytest.raises(ValueError, match="scale: must be > 0"):
        StepNoise(scale=0.0, scan=np.full(3, 1e-3), wheel=np.full(3, 1e-3), pairs=0)
    from scanreg.pipeline.smoothing import residual_moments

    good = np.zeros((60, 3))
    with pytest.raises(ValueError, match=r"here: residuals must be finite"):
        residual_moments(np.full((60, 3), np.nan), good)
    with pytest.raises(ValueError, match=r"before: expected shape \(n, 3\) with n >= 1"):
        residual_moments(good, np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"here: expected shape \(n, 3\)"):
        residual_moments(np.zeros((60, 2)), good)
    with pytest.raises(ValueError, match=r"before: expected the shape of here"):
        residual_moments(good, np.zeros((59, 3)))
    with pytest.raises(TypeError, match="smooth_scans: expected a bool"):
        MappingConfig(smooth_scans="yes")  # type: ignore[arg-type]


def _rms(poses: list[SE2], truth: list[SE2]) -> float:
    """RMS error of each scan's pose relative to the scan before (the short relations)."""
    err = [
        np.linalg.norm(((a.inverse() @ b).inverse() @ (s.inverse() @ t)).translation)
        for a, b, s, t in zip(poses[:-1], poses[1:], truth[:-1], truth[1:], strict=True)
    ]
    return float(np.sqrt(np.mean(np.square(err))))


@pytest.mark.parametrize(
    ("scan", "wheel", "bound"),
    [
        # Wheels more precise per step than the scans: the pass gains most.
        ([0.01, 0.004, 0.003], [0.003, 0.002, 0.001], 0.3),
        # Wheels worse than the scans (the noise identified on Intel): still a gain.
        ([0.003, 0.001, 5e-4], [0.006, 0.005, 0.009], 0.9),
    ],
)
def test_scans_between_nodes_are_resolved(scan: Any, wheel: Any, bound: float) -> None:
    truth, odometry, wheels = _run(np.array(scan), np.array(wheel), n=1500, seed=1)
    nodes = list(range(0, len(truth), NODE_EVERY))
    # What the mapper lays down before the pass: each node at its true pose (as a well
    # closed graph would put it), the scans after it on the odometry.
    closed = [
        truth[k - k % NODE_EVERY] @ odometry[k - k % NODE_EVERY].inverse() @ odometry[k]
        for k in range(len(truth))
    ]
    noise = identify_step_noise(_steps(odometry), wheels)
    assert noise is not None
    hold = (0.005, math.radians(0.2))  # MappingConfig's drift floors
    smoothed = smooth_scan_poses(closed, odometry, [True] * len(truth), wheels, nodes, noise, hold)
    for k in nodes:  # the nodes stay about where the graph put them
        assert np.linalg.norm((closed[k].inverse() @ smoothed[k]).translation) < 0.01
    # The first node is the map's frame: it does not move at all.
    assert np.abs((closed[0].inverse() @ smoothed[0]).log()).max() < 1e-12
    before, after = _rms(closed, truth), _rms(smoothed, truth)
    # Measured: 0.0155 -> 0.0035 m (0.22x); 0.0045 -> 0.0037 m (0.82x).
    assert after < bound * before


def test_mapper_runs_the_pass_only_with_wheels() -> None:
    # A square room seen from a short drive: with wheel priors the pass identifies the noise
    # (it needs 50 consecutive steps), without them it is skipped.
    rng = np.random.default_rng(3)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    truth = [SE2.from_vector([0.02 * k, 0.3 * math.sin(0.05 * k), 0.01 * k]) for k in range(80)]

    def scan(pose: SE2) -> Any:
        # A 10 m square room: the distance to its walls along each beam.
        d = np.array([np.cos(angles + pose.angle), np.sin(angles + pose.angle)]).T
        d = np.where(np.abs(d) < 1e-9, 1e-9, d)
        t = np.min((np.sign(d) * 5.0 - pose.translation) / d, axis=1)
        pts = t[:, None] * np.array([np.cos(angles), np.sin(angles)]).T
        return pts + rng.normal(0.0, 0.005, pts.shape)

    for with_wheels in (True, False):
        mapper = Mapper(MappingConfig())
        for k, p in enumerate(truth):
            prior = None if k == 0 or not with_wheels else truth[k - 1].inverse() @ p
            mapper.step(scan(p), prior=prior, stamp=0.2 * k)
        res = mapper.finish()
        assert (mapper.step_noise is not None) is with_wheels
        # The map's frame is the first scan's odometry pose exactly, whatever the loops and
        # the pass pulled (the pass moved it by ~1 mm while it held it as any other node).
        first = res.odometry_poses[0].inverse() @ res.poses[0]
        assert np.abs(first.log()).max() < 1e-12
        assert np.abs((res.odometry_poses[0].inverse() @ res.graph.pose(0)).log()).max() < 1e-12
        assert len(res.poses) == len(truth)
        end = (truth[0].inverse() @ truth[-1]).inverse() @ (res.poses[0].inverse() @ res.poses[-1])
        assert np.linalg.norm(end.translation) < 0.05
