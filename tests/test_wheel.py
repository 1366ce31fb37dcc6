"""The wheels' noise model calibrated on the run (scanreg.pipeline.wheel.WheelOdometry): per
axis, the prediction's variance against the scans, identified from synthetic runs whose errors
are drawn (so known)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scanreg import SE2
from scanreg.pipeline.wheel import WheelNoise, WheelOdometry


def _drive(
    scan_sigma: np.ndarray, wheel_sigma: np.ndarray, n: int, seed: int = 0
) -> tuple[list[SE2], list[SE2]]:
    """Truth (5 cm and about 1° a step); the scans' poses, each off the truth by its own
    ``exp(ε_k)``; the wheels' steps, each off by ``exp(w_k)``."""
    rng = np.random.default_rng(seed)
    truth = [SE2.identity()]
    for _ in range(n - 1):
        truth.append(truth[-1] @ SE2.exp([0.05, 0.0, rng.normal(0.0, 0.02)]))
    scans = [p @ SE2.exp(rng.normal(0.0, 1.0, 3) * scan_sigma) for p in truth]
    wheels = [
        (a.inverse() @ b) @ SE2.exp(rng.normal(0.0, 1.0, 3) * wheel_sigma)
        for a, b in itertools.pairwise(truth)
    ]
    steps = [a.inverse() @ b for a, b in itertools.pairwise(scans)]
    return wheels, steps


@pytest.mark.parametrize(
    ("scan", "wheel"),
    [
        # Wheels far worse in heading than the model says (Intel's: 0.56° a step).
        ([0.003, 0.001, 5e-4], [0.006, 0.005, 0.0097]),
        # Wheels better than the model (the Freiburg hospital's heading: 0.10° a step).
        ([0.005, 0.004, 9e-4], [0.004, 0.003, 0.0005]),
    ],
)
def test_the_prediction_variance_is_calibrated_per_axis(
    scan: list[float], wheel: list[float]
) -> None:
    scan_sigma, wheel_sigma = np.array(scan), np.array(wheel)
    wheels, steps = _drive(scan_sigma, wheel_sigma, n=3000)
    odo = WheelOdometry(WheelNoise(calibrate_scale=False))
    for w, s in zip(wheels, steps, strict=True):
        odo.observe(w, s)
    # The prediction is off the scan's pose by the wheels' step error and the last scan's
    # own error: per axis var(w) + var(ε).
    expected = wheel_sigma**2 + scan_sigma**2
    got = np.mean([np.diag(odo.prior(w)[1]) for w in wheels[-2000:]], axis=0)
    # Measured (seed 0): 0.98 / 0.89 / 0.89 and 0.99 / 0.96 / 0.91 of the expected variance
    # (the 99.5th-percentile trim takes a little off a Gaussian's spread).
    np.testing.assert_allclose(got, expected, rtol=0.15)
    model = np.mean([np.diag(WheelNoise().covariance(w)) for w in wheels[-2000:]], axis=0)
    np.testing.assert_allclose(odo.noise_factor, expected / model, rtol=0.15)


def test_calibration_waits_for_consecutive_steps_and_can_be_off() -> None:
    wheels, steps = _drive(np.full(3, 1e-3), np.full(3, 5e-3), n=400)
    # Every other step unconstrained: no two observed steps follow each other.
    odo = WheelOdometry()
    for k, (w, s) in enumerate(zip(wheels, steps, strict=True)):
        odo.observe(w, s, constrained=k % 2 == 0)
    np.testing.assert_array_equal(odo.noise_factor, np.ones(3))
    fixed = WheelOdometry(WheelNoise(calibrate_noise=False))
    for w, s in zip(wheels, steps, strict=True):
        fixed.observe(w, s)
    np.testing.assert_array_equal(fixed.noise_factor, np.ones(3))
    motion, cov = fixed.prior(wheels[0])
    np.testing.assert_array_equal(cov, WheelNoise().covariance(motion))
    with pytest.raises(TypeError, match="constrained: expected a bool, got str"):
        fixed.observe(wheels[0], steps[0], constrained="yes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="increment: matrix: contains NaN"):
        fixed.observe(np.full((3, 3), np.nan), steps[0])
    with pytest.raises(TypeError, match="calibrate_noise: expected a bool"):
        WheelNoise(calibrate_noise=1)  # type: ignore[arg-type]
