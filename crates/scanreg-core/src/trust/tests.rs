use super::*;
use crate::censi::Analysis;

/// A 2D corridor along x: every normal along y, so `x` is unconstrained.
fn corridor() -> Analysis {
    let n = 200usize;
    let mut plane = vec![0.0; 9];
    // J = [n, p × n] with n = (0, 1) at x in [-5, 5]: Σ J Jᵀ.
    for i in 0..n {
        let x = -5.0 + 10.0 * i as f64 / (n - 1) as f64;
        let j = [0.0, 1.0, x];
        for r in 0..3 {
            for c in 0..3 {
                plane[r * 3 + c] += j[r] * j[c];
            }
        }
    }
    let mut hessian = plane.clone();
    hessian[0] += 1e-6; // not exactly singular
    Analysis {
        hessian: hessian.clone(),
        censi_meat: vec![0.0; 9],
        source_meat: hessian.clone(),
        target_meat: hessian.clone(),
        normal_meat: vec![0.0; 9],
        plane_sum_squares: 0.01 * n as f64,
        determined_plane_sum_squares: 0.01 * n as f64,
        block_meat: hessian,
        num_blocks: 10,
        determined_block_meat: vec![0.0; 9],
        num_determined_blocks: 0,
        plane_information: plane,
        num_plane_correspondences: n,
        num_determined_correspondences: n,
        linear_known: false,
        num_correspondences: n,
        plane_noise_information: vec![0.0; 9],
        score: vec![0.0; 3],
        determined_hessian: vec![0.0; 9],
        determined_score: vec![0.0; 3],
        num_determined_pairs: 0,
        normal_disagreement: 0.0,
        num_normal_pairs: 0,
    }
}

#[test]
fn corridor_is_weak_along_x_and_takes_the_prior_there() {
    let a = corridor();
    let prior = [0.03, 0.0, 0.0, 0.0, 0.03, 0.0, 0.0, 0.0, 0.001];
    let input = Input {
        dim: 2,
        method: Method::PointToPlane,
        analysis: &a,
        hessian: &a.hessian,
        sigma2: 1e-4,
        score_outer: None,
        effective_residuals: 0.0,
        num_correspondences: 200,
        sum_squared_distances: 0.02,
        levers: &[3.0],
        normal_noise: f64::NAN,
        typical_normal_noise: f64::NAN,
        normal_variance: 0.0,
        held: None,
        prior: &prior,
        drift: &[0.0; 3],
        agreement: None,
        valley: None,
        sampling_system: None,
        sampling: 0.0,
        hidden_noise_variance: 0.0,
        distortion_system: None,
        length_scale: 3.0,
        chosen: Kind::Calibrated,
        motion: &[0.3, 0.0],
    };
    let out = analyse(&input).unwrap();
    assert_eq!(out.degeneracy.num_weak(), 1);
    let w = out.degeneracy.directions.column(0);
    assert!(w[0].abs() > 0.999, "weak direction {w}");
    // Along x the data say nothing: the prior's variance.
    assert!(
        (out.calibrated[(0, 0)] - 0.03).abs() < 1e-9,
        "{}",
        out.calibrated
    );
    assert!(out.calibrated[(1, 1)] < 0.01);
    assert!((out.motion_nees.unwrap() - 3.0).abs() < 1e-12);
    let bad = Input {
        prior: &[0.0; 4],
        ..input
    };
    assert!(analyse(&bad).is_err());
}

#[test]
fn the_floor_is_lower_without_linear_guesses_but_never_under_twenty_facing() {
    use super::degeneracy::{floor, MIN_CONSTRAINT, MIN_DETERMINED_CONSTRAINT};
    assert_eq!(floor(false, 5000), MIN_CONSTRAINT);
    assert_eq!(floor(true, 5000), MIN_DETERMINED_CONSTRAINT);
    // 500 correspondences: 20 of them facing a direction is 0.04 each.
    assert!((floor(true, 500) - 0.04).abs() < 1e-12);
    assert_eq!(floor(true, 0), 20.0);
}
