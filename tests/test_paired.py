"""align_paired: exact recovery, covariance calibration, degeneracy and hostile input."""

from __future__ import annotations

import numpy as np
import pytest
import scanreg
import scanreg.demo
from hypothesis import given, settings
from hypothesis import strategies as st
from scanreg import SE2, SE3, align_paired
from scanreg.quality import nees_band


def random_pose(rng: np.random.Generator, dim: int, max_angle: float = np.pi) -> SE2 | SE3:
    if dim == 2:
        return SE2.from_vector([*rng.uniform(-10, 10, 2), rng.uniform(-max_angle, max_angle)])
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return SE3.from_vector([*rng.uniform(-10, 10, 3), *(axis * rng.uniform(0, max_angle))])


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    dim=st.sampled_from([2, 3]),
    n=st.integers(4, 60),
    weighted=st.booleans(),
)
def test_noise_free_exact_recovery(seed: int, dim: int, n: int, weighted: bool) -> None:
    rng = np.random.default_rng(seed)
    truth = random_pose(rng, dim)
    source = rng.normal(size=(n, dim)) * rng.uniform(0.5, 20.0) + rng.uniform(-50, 50, dim)
    target = truth.apply(source)
    weights = rng.uniform(0.1, 5.0, n) if weighted else None
    result = align_paired(source, target, weights)
    assert result.pose.is_close(truth, atol=1e-9)
    assert np.linalg.det(result.pose.rotation) == pytest.approx(1.0, abs=1e-12)
    assert result.residuals.rmse < 1e-9


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dim=st.sampled_from([2, 3]))
def test_noise_free_point_to_plane_from_offset_init(seed: int, dim: int) -> None:
    rng = np.random.default_rng(seed)
    truth = random_pose(rng, dim)
    n = 40
    source = rng.uniform(-5, 5, (n, dim))
    target = truth.apply(source)
    normals = rng.normal(size=(n, dim))
    init = truth @ type(truth).exp(rng.normal(size=truth.DOF) * 0.05)
    method = "point_to_line" if dim == 2 else "point_to_plane"
    result = align_paired(source, target, method=method, target_normals=normals, init=init)
    assert result.converged
    assert result.pose.is_close(truth, atol=1e-9)


def test_umeyama_scale_exact() -> None:
    rng = np.random.default_rng(1)
    truth = random_pose(rng, 3)
    source = rng.normal(size=(30, 3))
    target = 2.5 * source @ truth.rotation.T + truth.translation
    result = align_paired(source, target, with_scale=True)
    assert result.scale == pytest.approx(2.5, rel=1e-12)
    np.testing.assert_allclose(result.pose.rotation, truth.rotation, atol=1e-12)
    np.testing.assert_allclose(result.pose.translation, truth.translation, atol=1e-9)


def test_integer_weights_equal_duplicated_points() -> None:
    rng = np.random.default_rng(2)
    source = rng.normal(size=(25, 3))
    target = random_pose(rng, 3).apply(source) + rng.normal(scale=0.05, size=(25, 3))
    reps = rng.integers(1, 4, 25)
    weighted = align_paired(source, target, reps.astype(np.float64))
    duplicated = align_paired(np.repeat(source, reps, axis=0), np.repeat(target, reps, axis=0))
    assert weighted.pose.is_close(duplicated.pose, atol=1e-12)


def _horn_rotation(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Horn (1987) quaternion method: an independent closed form, always a proper rotation."""
    s = (p - p.mean(0)).T @ (q - q.mean(0))
    sxx, sxy, sxz, syx, syy, syz, szx, szy, szz = s.ravel()
    n = np.array(
        [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ]
    )
    w, x, y, z = np.linalg.eigh(n)[1][:, -1]
    return np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )


def test_reflection_gets_the_best_proper_rotation() -> None:
    rng = np.random.default_rng(3)
    source = rng.normal(size=(50, 3)) * [3.0, 2.0, 1.0]
    target = source * [1.0, 1.0, -1.0]  # a mirror image: the unconstrained optimum has det -1
    result = align_paired(source, target)
    rot = result.pose.rotation
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(rot, _horn_rotation(source, target), atol=1e-9)
    # The naive SVD answer U Vᵀ without the fix is the reflection itself.
    u, _, vt = np.linalg.svd(source.T @ target)
    assert np.linalg.det(vt.T @ u.T) == pytest.approx(-1.0)


def test_noisy_3d_matches_horn() -> None:
    rng = np.random.default_rng(4)
    source = rng.normal(size=(100, 3))
    target = random_pose(rng, 3).apply(source) + rng.normal(scale=0.1, size=(100, 3))
    np.testing.assert_allclose(
        align_paired(source, target).pose.rotation, _horn_rotation(source, target), atol=1e-9
    )


def _lab(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    source = np.column_stack([rng.uniform(-5, 5, 200), rng.uniform(-3, 3, 200)])
    target = scanreg.demo.LAB_TRUTH.apply(source) + rng.normal(0.0, 0.02, source.shape)
    return source, target


def test_lab_monte_carlo_covariance_is_calibrated() -> None:
    """≥ 500 trials of the seed's lab: empirical vs predicted covariance, and mean NEES."""
    rng = np.random.default_rng(20261123)
    trials = 1000
    truth = scanreg.demo.LAB_TRUTH
    errors = np.empty((trials, 3))
    predicted = np.empty((trials, 3, 3))
    nees = np.empty(trials)
    for k in range(trials):
        res = align_paired(*_lab(rng))
        errors[k] = (res.pose.inverse() @ truth).log()  # δ with truth = pose @ exp(δ)
        predicted[k] = res.covariance
        nees[k] = errors[k] @ res.information @ errors[k]
    empirical = np.cov(errors.T)
    ratio = np.diag(empirical) / np.diag(predicted.mean(axis=0))
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
    lo, hi = nees_band(3, trials)
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)
    assert np.abs(errors.mean(axis=0) / np.sqrt(np.diag(empirical))).max() < 0.15  # unbiased


def test_3d_monte_carlo_nees_with_offset_pose() -> None:
    """Right-perturbation convention: with a large offset a left-frame covariance would fail."""
    rng = np.random.default_rng(5)
    truth = SE3.from_vector([20.0, -15.0, 3.0, 0.3, -0.2, 1.0])
    source = rng.uniform(-4, 4, (80, 3))
    trials = 400
    nees = np.empty(trials)
    for k in range(trials):
        target = truth.apply(source) + rng.normal(scale=0.05, size=source.shape)
        res = align_paired(source, target)
        d = (res.pose.inverse() @ truth).log()
        nees[k] = d @ res.information @ d
    lo, hi = nees_band(6, trials)
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)


@pytest.mark.parametrize("kernel", ["huber", "cauchy", "tukey", "geman_mcclure", "welsch"])
def test_robust_kernels_reject_gross_outliers(kernel: str) -> None:
    rng = np.random.default_rng(6)
    truth = random_pose(rng, 3, max_angle=0.5)
    source = rng.uniform(-5, 5, (300, 3))
    target = truth.apply(source) + rng.normal(scale=0.01, size=source.shape)
    bad = rng.choice(300, 60, replace=False)  # 20 % gross outliers
    target[bad] += rng.uniform(-5, 5, (60, 3))
    plain = align_paired(source, target)
    robust = align_paired(source, target, kernel=kernel)
    err_plain = np.linalg.norm((plain.pose.inverse() @ truth).log())
    err_robust = np.linalg.norm((robust.pose.inverse() @ truth).log())
    assert err_plain > 0.05
    assert err_robust < 0.005, (kernel, err_robust)
    assert robust.converged and robust.refined
    # The robust noise estimate sees the inliers, not the outliers.
    assert np.sqrt(robust.sigma2) < 0.03


def test_point_to_line_ignores_sliding_along_the_line() -> None:
    rng = np.random.default_rng(7)
    truth = SE2.from_vector([0.4, -0.3, 0.1])
    n = 120
    # Points on three walls; the target observations slide along their wall (unknown).
    normals = np.repeat(np.array([[1.0, 0.0], [0.0, 1.0], [0.7071, 0.7071]]), n // 3, axis=0)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    source = rng.uniform(-5, 5, (n, 2))
    target = truth.apply(source)
    tangents = normals @ np.array([[0.0, 1.0], [-1.0, 0.0]])
    target += tangents * rng.uniform(-0.5, 0.5, (n, 1))
    result = align_paired(source, target, method="point_to_line", target_normals=normals)
    assert result.pose.is_close(truth, atol=1e-9)
    assert not align_paired(source, target).pose.is_close(truth, atol=1e-3)


def test_nearly_collinear_3d_reports_the_weak_rotation() -> None:
    rng = np.random.default_rng(8)
    source = np.column_stack([np.linspace(-5, 5, 50), rng.normal(scale=1e-4, size=(50, 2))])
    target = SE3.from_vector([1.0, 2.0, 3.0, 0.0, 0.0, 0.3]).apply(source)
    result = align_paired(source, target)
    cond = result.conditioning
    assert cond.condition_number > 1e8 and cond.weakest.ratio < 1e-8
    assert cond.weakest.description == "rotation about (1.00, 0.00, 0.00)"
    # Conditioning is numbers only: no verdict on weakness of its own.
    assert not hasattr(cond, "weak_directions") and not hasattr(cond, "degenerate")
    # The covariance says so: the roll standard deviation dwarfs the others.
    sd = result.standard_deviations
    assert sd[3] > 1e3 * max(sd[4], sd[5])


def test_well_spread_points_are_not_degenerate() -> None:
    rng = np.random.default_rng(9)
    source = rng.uniform(-5, 5, (100, 3))
    res = align_paired(source, random_pose(rng, 3).apply(source) + 0.01 * rng.normal(size=(100, 3)))
    assert res.conditioning.weakest.ratio > 0.1
    assert res.conditioning.scaled_condition_number < 10


def test_exactly_collinear_3d_is_refused() -> None:
    source = np.column_stack([np.linspace(0, 9, 10), 2 * np.linspace(0, 9, 10), np.zeros(10)])
    with pytest.raises(
        ValueError, match=r"source: .*rotation about \(0.45, 0.89, 0.00\) is unobservable"
    ):
        align_paired(source, source + 1.0)


def test_coincident_2d_points_are_refused() -> None:
    source = np.ones((5, 2))
    with pytest.raises(ValueError, match="source: all points coincide"):
        align_paired(source, source)


def test_degenerate_point_to_line_flags_the_free_translation() -> None:
    # A single straight wall (a corridor seen from one side): sliding along it is free.
    rng = np.random.default_rng(10)
    source = np.column_stack([rng.uniform(-10, 10, 100), np.full(100, 2.0)])
    normals = np.tile([0.0, 1.0], (100, 1))
    target = source + np.array([0.0, 0.1])
    with pytest.raises(ValueError, match=r"translation along \(1.00, 0.00\) is unobservable"):
        align_paired(source, target, method="point_to_line", target_normals=normals)


# --- hostile input --------------------------------------------------------------------------

GOOD = np.random.default_rng(0).normal(size=(10, 3))


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (
            {"source": GOOD, "target": GOOD[:9]},
            ValueError,
            "target: has 9 points but source has 10",
        ),
        (
            {"source": np.zeros((10, 4)), "target": GOOD},
            ValueError,
            r"source: expected shape \(N, 2\) or \(N, 3\), got \(10, 4\)",
        ),
        (
            {"source": GOOD, "target": GOOD[:, :2].copy()},
            ValueError,
            r"target: expected shape \(N, 3\)",
        ),
        (
            {"source": np.where(np.arange(30).reshape(10, 3) == 7, np.nan, GOOD), "target": GOOD},
            ValueError,
            "source: point 2 has a non-finite",
        ),
        (
            {"source": GOOD, "target": np.where(np.arange(30).reshape(10, 3) == 0, np.inf, GOOD)},
            ValueError,
            "target: point 0 has a non-finite",
        ),
        (
            {"source": GOOD[:2], "target": GOOD[:2]},
            ValueError,
            "source: point_to_point in 3D needs at least 3 pairs",
        ),
        (
            {"source": GOOD[:, :2].copy()[:1], "target": GOOD[:, :2].copy()[:1]},
            ValueError,
            "source: point_to_point in 2D needs at least 2 pairs",
        ),
        (
            {"source": GOOD, "target": GOOD, "weights": np.zeros(10)},
            ValueError,
            "weights: all weights are zero",
        ),
        (
            {"source": GOOD, "target": GOOD, "weights": -np.ones(10)},
            ValueError,
            "weights: weights must be >= 0",
        ),
        (
            {"source": GOOD, "target": GOOD, "weights": np.ones(9)},
            ValueError,
            r"weights: expected shape \(10,\)",
        ),
        (
            {"source": GOOD, "target": GOOD, "weights": np.r_[np.ones(2), np.zeros(8)]},
            ValueError,
            "needs at least 3 pairs with positive weight, got 2",
        ),
        (
            {"source": GOOD.astype(object), "target": GOOD},
            TypeError,
            "source: expected real numbers",
        ),
        (
            {"source": GOOD.astype(complex), "target": GOOD},
            TypeError,
            "source: expected real numbers",
        ),
        ({"source": "points", "target": GOOD}, TypeError, "source: expected an array of numbers"),
        (
            {"source": GOOD, "target": GOOD, "kernel": "hubber"},
            ValueError,
            "kernel: unknown 'hubber'",
        ),
        (
            {"source": GOOD, "target": GOOD, "kernel": "huber", "kernel_scale": 0.0},
            ValueError,
            "kernel_scale: must be finite and > 0",
        ),
        (
            {"source": GOOD, "target": GOOD, "method": "point_to_plane"},
            ValueError,
            "target_normals: required",
        ),
        (
            {"source": GOOD, "target": GOOD, "method": "point_to_line", "target_normals": GOOD},
            ValueError,
            "method: 'point_to_line' is for 2D points",
        ),
        (
            {"source": GOOD, "target": GOOD, "method": "plane"},
            ValueError,
            "method: unknown 'plane'",
        ),
        (
            {
                "source": GOOD,
                "target": GOOD,
                "method": "point_to_plane",
                "target_normals": np.zeros((10, 3)),
            },
            ValueError,
            "target_normals: normal 0 has zero length",
        ),
        (
            {"source": GOOD, "target": GOOD, "init": np.eye(3)},
            ValueError,
            r"init: matrix: expected shape \(4, 4\)",
        ),
        (
            {"source": GOOD, "target": GOOD, "init": SE2()},
            TypeError,
            "init: expected SE3 for 3D points, got SE2",
        ),
        (
            {"source": GOOD, "target": GOOD, "init": np.diag([1.0, 1.0, -1.0, 1.0])},
            ValueError,
            "init: rotation: is a reflection",
        ),
        (
            {"source": GOOD, "target": GOOD, "with_scale": True, "kernel": "huber"},
            ValueError,
            "with_scale: only the closed form",
        ),
        (
            {"source": np.zeros((0, 3)), "target": np.zeros((0, 3))},
            ValueError,
            r"source: is empty \(0 points\)",
        ),
    ],
)
def test_bad_input_is_refused_with_a_named_argument(
    kwargs: dict[str, object], error: type[Exception], match: str
) -> None:
    with pytest.raises(error, match=match):
        align_paired(**kwargs)  # type: ignore[arg-type]


def test_native_module_refuses_bad_arrays_without_panicking() -> None:
    core = scanreg._core
    ok = np.zeros((5, 3))
    with pytest.raises(TypeError, match="source"):
        core.paired_moments(ok.astype(np.int32), ok)
    with pytest.raises(ValueError, match="source: array is not C-contiguous"):
        core.paired_moments(np.asfortranarray(np.ones((5, 3))), ok)
    with pytest.raises(ValueError, match=r"source: expected shape \(N, 2\) or \(N, 3\)"):
        core.paired_moments(np.zeros((5, 5)), np.zeros((5, 5)))
    with pytest.raises(ValueError, match="target: has 4 points but source has 5"):
        core.paired_moments(ok, ok[:4])
    with pytest.raises(ValueError, match="source: is empty"):
        core.paired_moments(ok[:0], ok[:0])
    with pytest.raises(ValueError, match="source: point 1 has a non-finite"):
        core.paired_moments(np.array([[0.0, 0.0], [np.nan, 1.0]]), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="weights: weight 0 is -1"):
        core.paired_moments(ok, ok, -np.ones(5))
    with pytest.raises(ValueError, match=r"pose_matrix: expected a \(4, 4\)"):
        core.linearize_paired(
            ok, ok, np.eye(3), objective="point_to_point", kernel="none", kernel_scale=1.0
        )
    with pytest.raises(ValueError, match="pose: pose has a non-finite entry"):
        core.linearize_paired(
            ok,
            ok,
            np.full((4, 4), np.nan),
            objective="point_to_point",
            kernel="none",
            kernel_scale=1.0,
        )
    with pytest.raises(ValueError, match="objective: unknown"):
        core.linearize_paired(ok, ok, np.eye(4), objective="x", kernel="none", kernel_scale=1.0)
    with pytest.raises(ValueError, match="kernel: unknown"):
        core.linearize_paired(
            ok, ok, np.eye(4), objective="point_to_point", kernel="x", kernel_scale=1.0
        )


def test_result_is_frozen() -> None:
    res = align_paired(GOOD, GOOD + 1.0)
    with pytest.raises(AttributeError):
        res.scale = 2.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        res.covariance[0, 0] = 1.0
