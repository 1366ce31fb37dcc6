//! The model-error shift of `calibrated` (`CovarianceEstimates.model_shift`): one Gauss–Newton
//! step on the strong subspace with the pairs whose normals agree, minus the step with all
//! sampled pairs (point-to-plane/line; point-to-point keeps the agreeing step). GICP: its own
//! step over the pairs whose target neighbourhood is not linear minus its step over all of
//! them (`trust::gicp_systems`).

use super::degeneracy::Degeneracy;
use super::dense::{solve, Mat, Vector};

/// A point-to-plane/line system `(H, g, count)` of the sampled pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct System {
    pub hessian: Mat,
    pub gradient: Vector,
    pub count: usize,
}

/// Each step is solved on the well-constrained subspace only (scaled coordinates, the weak
/// directions left out: along them the covariance is the prior's, and a step there is not
/// determined). Zeros with fewer than `10 dof` agreeing pairs, a singular system or a
/// non-finite step.
pub fn model_shift(
    all: &System,
    agreeing: &System,
    deg: &Degeneracy,
    point_to_point: bool,
) -> Vector {
    let dof = deg.eigenvalues.len();
    let zero = Vector::zeros(dof);
    if agreeing.count < 10 * dof {
        return zero;
    }
    let s_inv = deg.scaling();
    let u = deg.strong_basis();
    // Tangent directions of the strong subspace.
    let t = Mat::from_fn(dof, u.ncols(), |i, j| s_inv[i] * u[(i, j)]);
    let step = |s: &System| -> Option<Vector> {
        let c = solve(
            &(t.transpose() * &s.hessian * &t),
            &-(t.transpose() * &s.gradient),
        )?;
        Some(&t * c)
    };
    let shift = match step(agreeing) {
        Some(a) if point_to_point => a,
        Some(a) => match step(all) {
            Some(b) => a - b,
            None => return zero,
        },
        None => return zero,
    };
    if shift.iter().all(|x| x.is_finite()) {
        shift
    } else {
        zero
    }
}
