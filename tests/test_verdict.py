"""Verdict: accepted on good registrations, rejected with the right reasons otherwise."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.slide import SlideCheck
from scanreg.verdict import QualityReport, VerdictThresholds, assess, judge


def _street() -> np.ndarray:
    sweep = sim.simulate_sweep(
        sim.street(seed=4),
        sim.LidarModel.preset("vlp16"),
        sim.Trajectory.stationary(SE3.from_vector([0, 1.75, 1.73, 0, 0, 0])),
        seed=0,
    )
    return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(sweep.points), 0.3).points


TRUTH = SE3.from_vector([0.5, -0.3, 0.02, 0.0, 0.0, 0.04])


def test_good_registration_is_accepted() -> None:
    source = _street()
    target = scanreg.prepare(TRUTH.apply(source))
    res = scanreg.register(source, target, max_correspondence_distance=1.5)
    out = assess(res, source, target)
    assert out.verdict.accepted, out.verdict.reasons
    assert out.verdict.reasons == ()
    assert out.report.overlap > 0.99
    assert out.report.residual_rmse < 1e-3
    assert out.report.translation_from_init == pytest.approx(
        np.linalg.norm([0.5, -0.3, 0.02]), abs=1e-3
    )


def test_low_overlap_is_rejected_with_the_measured_fraction() -> None:
    source = _street()
    target_pts = TRUTH.apply(source)
    keep = target_pts[:, 0] > np.quantile(target_pts[:, 0], 0.8)  # the target sees 20 % of it
    target = scanreg.prepare(np.ascontiguousarray(target_pts[keep]))
    res = scanreg.register(source, target, init=TRUTH, max_correspondence_distance=0.5)
    out = assess(res, source, target, init=TRUTH)
    assert not out.verdict.accepted
    assert 0.1 < out.report.overlap < 0.35
    assert f"overlap {out.report.overlap:.2f} < 0.50" in out.verdict.reasons


def test_weak_direction_becomes_a_degenerate_reason() -> None:
    # Information along x a million times weaker than elsewhere (scaled analysis, L = 1 m).
    cond = scanreg.quality.conditioning(np.diag([1e-6, 1.0, 1.0, 1.0, 1.0, 1.0]), 3, 1.0)
    report = QualityReport(
        overlap=0.9,
        gate=1.0,
        num_source_points=100,
        residual_mean=0.01,
        residual_median=0.01,
        residual_rmse=0.01,
        residual_trimmed_rmse=0.01,
        translation_from_init=0.0,
        rotation_from_init=0.0,
        converged=True,
        stop_reason="converged",
        conditioning=cond,
    )
    verdict = judge(report, VerdictThresholds())
    assert verdict.reasons == ("degenerate: translation along (1.00, 0.00, 0.00) (ratio 1.0e-06)",)


def test_motion_bound_and_convergence_reasons() -> None:
    source = _street()
    target = scanreg.prepare(TRUTH.apply(source))
    res = scanreg.register(source, target, max_correspondence_distance=1.5)
    th = VerdictThresholds(max_translation=0.2, max_rotation=math.radians(1.0))
    reasons = assess(res, source, target, thresholds=th).verdict.reasons
    assert any(r == "moved 0.583 from the initial guess > bound 0.2" for r in reasons)
    assert any(r == "rotated 2.29° from the initial guess > bound 1°" for r in reasons)
    stuck = scanreg.register(source, target, max_correspondence_distance=1.5, max_iterations=1)
    assert "not converged: max_iterations" in assess(stuck, source, target).verdict.reasons


def test_no_overlap_at_all_rejects_on_rmse_too() -> None:
    report = QualityReport(
        overlap=0.0,
        gate=1.0,
        num_source_points=10,
        residual_mean=math.nan,
        residual_median=math.nan,
        residual_rmse=math.nan,
        residual_trimmed_rmse=math.nan,
        translation_from_init=0.0,
        rotation_from_init=0.0,
        converged=True,
        stop_reason="converged",
        conditioning=scanreg.quality.conditioning(np.eye(3), 2, 1.0),
    )
    verdict = judge(report, VerdictThresholds())
    assert verdict.reasons == ("overlap 0.00 < 0.50", "inlier RMSE nan > 0.5")


def test_loose_fit_is_rejected_with_the_measured_fraction() -> None:
    # Overlap and RMSE inside the generous gate, but only 12 % of the source within the tight
    # gate at the pose returned (as the never-worse-than-the-start check counted it).
    def report(fit: float, outcome: str = "kept") -> QualityReport:
        slide = SlideCheck(gate=0.1, start_fit=0.6, end_fit=fit, outcome=outcome)  # type: ignore[arg-type]
        return QualityReport(
            overlap=0.9,
            gate=1.0,
            num_source_points=100,
            residual_mean=0.2,
            residual_median=0.2,
            residual_rmse=0.25,
            residual_trimmed_rmse=0.2,
            translation_from_init=0.0,
            rotation_from_init=0.0,
            converged=True,
            stop_reason="converged",
            conditioning=scanreg.quality.conditioning(np.eye(3), 2, 1.0),
            slide=slide,
        )

    th = VerdictThresholds()
    assert judge(report(0.12), th).reasons == ("loose fit: 12% of the source within 0.1 < 20%",)
    assert judge(report(0.2), th).accepted
    assert judge(report(0.12), VerdictThresholds(min_tight_fit=0.0)).accepted
    # A start returned after a slide is rejected for that alone (its fit is the start's).
    slid = judge(report(0.12, "start"), th).reasons
    assert len(slid) == 1 and slid[0].startswith("slid from a start that fitted better")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"min_overlap": 1.5}, "min_overlap: must be in"),
        ({"overlap_gate": 0.0}, "overlap_gate: must be > 0"),
        ({"overlap_gate": math.inf}, "overlap_gate: must be >= 0 and finite"),
        ({"max_inlier_rmse": -1.0}, "max_inlier_rmse: must be >= 0"),
        ({"weak_ratio": 0.0}, "weak_ratio: must be in"),
        ({"max_translation": math.nan}, "max_translation: must be >= 0"),
        ({"min_tight_fit": 1.5}, "min_tight_fit: must be in"),
        ({"min_tight_fit": math.nan}, "min_tight_fit: must be in"),
    ],
)
def test_thresholds_are_validated(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        VerdictThresholds(**kwargs)  # type: ignore[arg-type]


def test_assess_refuses_mismatched_inputs() -> None:
    source = _street()
    res = scanreg.register(source, TRUTH.apply(source), max_correspondence_distance=1.5)
    with pytest.raises(ValueError, match=r"source: expected shape \(N, 3\)"):
        assess(res, source[:, :2].copy(), source)
    with pytest.raises(TypeError, match="thresholds: expected VerdictThresholds"):
        assess(res, source, source, thresholds={"min_overlap": 0.5})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="init: expected SE3 for 3D points, got SE2"):
        assess(res, source, source, init=SE2())
