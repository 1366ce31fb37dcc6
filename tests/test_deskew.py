"""deskew: exact against the simulator's ground truth and an independent per-point reference."""

from __future__ import annotations

import numpy as np
import pytest
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.deskew import deskew, velocity_from_motion


def _street_sweep(reference: str) -> sim.LidarSweep:
    drive = sim.Trajectory.from_speed_and_yaw_rate(
        12.0, 0.4, duration=1.0, dim=3, start=SE3.from_vector([0, 1.75, 1.73, 0, 0, 0])
    )
    return sim.simulate_sweep(
        sim.street(seed=2), sim.LidarModel.preset("vlp16"), drive, reference=reference, seed=1
    )


@pytest.mark.parametrize("reference", ["start", "middle", "end"])
def test_matches_simulator_ground_truth(reference: str) -> None:
    sweep = _street_sweep(reference)
    velocity = np.array([12.0, 0.0, 0.0, 0.0, 0.0, 0.4])  # body twist of the drive
    # The simulator's "end" is the nominal end of the sweep, not the last return's time:
    # pass its reference time in seconds.
    out = deskew(sweep.points, sweep.timestamps, velocity, reference_time=sweep.reference_time)
    np.testing.assert_allclose(out, sweep.points_deskewed, atol=1e-9)
    # The sweep was visibly distorted: ~12 m/s over 0.1 s.
    assert np.abs(sweep.points - sweep.points_deskewed).max() > 0.5


def test_explicit_reference_time_equals_named_one() -> None:
    sweep = _street_sweep("start")
    v = np.array([12.0, 0.0, 0.0, 0.0, 0.0, 0.4])
    named = deskew(sweep.points, sweep.timestamps, v, reference_time="end")
    explicit = deskew(
        sweep.points, sweep.timestamps, v, reference_time=float(sweep.timestamps.max())
    )
    np.testing.assert_array_equal(named, explicit)


def test_matches_per_point_se3_exp_reference() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(-20, 20, (500, 3))
    times = rng.uniform(0.0, 0.1, 500)
    xi = np.array([8.0, -0.5, 0.2, 0.05, -0.1, 0.7])
    out = deskew(pts, times, xi, reference_time=0.03)
    ref = np.array(
        [SE3.exp((t - 0.03) * xi).apply(p[None])[0] for p, t in zip(pts, times, strict=True)]
    )
    np.testing.assert_allclose(out, ref, atol=1e-10)


def test_2d_matches_per_point_se2_exp_reference() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform(-20, 20, (300, 2))
    times = rng.uniform(0.0, 0.2, 300)
    xi = np.array([1.5, 0.1, -0.8])
    out = deskew(pts, times, xi)  # reference: the earliest timestamp
    t0 = times.min()
    ref = np.array(
        [SE2.exp((t - t0) * xi).apply(p[None])[0] for p, t in zip(pts, times, strict=True)]
    )
    np.testing.assert_allclose(out, ref, atol=1e-10)


def test_velocity_from_motion_round_trip() -> None:
    motion = SE3.from_vector([1.2, 0.1, 0.0, 0.0, 0.0, 0.05])  # T_start_end over 0.1 s
    xi = velocity_from_motion(motion, 0.1)
    assert SE3.exp(0.1 * xi).is_close(motion, atol=1e-12)
    pts = np.array([[5.0, 1.0, 0.0]])
    # A point measured at the end of the interval, expressed at the start.
    np.testing.assert_allclose(
        deskew(pts, np.array([0.1]), xi, reference_time=0.0), motion.apply(pts), atol=1e-12
    )


def test_public_name() -> None:
    assert scanreg.deskew is deskew


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        (
            (np.zeros((3, 3)), np.zeros(2), np.zeros(6)),
            {},
            ValueError,
            r"timestamps: expected shape \(3,\)",
        ),
        (
            (np.zeros((3, 3)), np.zeros(3), np.zeros(3)),
            {},
            ValueError,
            r"velocity: expected shape \(6,\)",
        ),
        (
            (np.zeros((3, 2)), np.zeros(3), np.zeros(6)),
            {},
            ValueError,
            r"velocity: expected shape \(3,\)",
        ),
        (
            (np.zeros((3, 3)), np.array([0.0, np.nan, 1.0]), np.zeros(6)),
            {},
            ValueError,
            "timestamps: contains NaN",
        ),
        (
            (np.full((3, 3), np.inf), np.zeros(3), np.zeros(6)),
            {},
            ValueError,
            "points: point 0 has a non-finite",
        ),
        ((np.zeros((0, 3)), np.zeros(0), np.zeros(6)), {}, ValueError, "points: is empty"),
        ((np.zeros((3, 4)), np.zeros(3), np.zeros(6)), {}, ValueError, r"points: expected shape"),
        (
            (np.zeros((3, 3)), np.zeros(3), np.zeros(6)),
            {"reference_time": "mid"},
            ValueError,
            "reference_time: expected seconds or one of",
        ),
        (
            (np.zeros((3, 3)), np.zeros(3), np.zeros(6)),
            {"reference_time": float("nan")},
            ValueError,
            "reference_time: must be finite",
        ),
        (
            (np.zeros((3, 3), dtype=np.complex128), np.zeros(3), np.zeros(6)),
            {},
            TypeError,
            "points: expected real numbers",
        ),
    ],
)
def test_bad_input(
    args: tuple[object, ...], kwargs: dict[str, object], error: type[Exception], match: str
) -> None:
    with pytest.raises(error, match=match):
        deskew(*args, **kwargs)  # type: ignore[arg-type]


def test_velocity_from_motion_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="duration: must be finite and > 0"):
        velocity_from_motion(SE3(), 0.0)
    with pytest.raises(TypeError, match="motion: expected SE2 or SE3"):
        velocity_from_motion(np.eye(4), 0.1)  # type: ignore[arg-type]
