//! Eigen-analysis of the solve's `JᵀWJ` (`scanreg.quality.Conditioning`): raw, and scaled with
//! rotation in metres at the length scale.

use super::degeneracy::unit_directions;
use super::dense::{eigh, scale_both, sym, Mat, Vector};

#[derive(Debug, Clone, PartialEq)]
pub struct Conditioning {
    pub eigenvalues: Vector,
    pub eigenvectors: Mat,
    pub condition_number: f64,
    pub length_scale: f64,
    pub scaled_eigenvalues: Vector,
    pub scaled_condition_number: f64,
    /// The least constrained direction, tangent units, and its ratio to the best.
    pub weakest: Vector,
    pub weakest_ratio: f64,
}

pub fn conditioning(hessian: &Mat, dim: usize, length_scale: f64) -> Conditioning {
    let dof = hessian.nrows();
    let h = sym(hessian);
    let (raw_vals, raw_vecs) = eigh(&h);
    let length = length_scale.max(1e-12);
    let mut s_inv = Vector::from_element(dof, 1.0);
    for i in dim..dof {
        s_inv[i] = 1.0 / length;
    }
    let (vals, vecs) = eigh(&scale_both(&h, &s_inv));
    let top = vals[dof - 1];
    let ratio0 = if top > 0.0 { vals[0] / top } else { 0.0 };
    let units = unit_directions(&vecs, &s_inv, None);
    Conditioning {
        condition_number: if raw_vals[0] > 0.0 {
            raw_vals[dof - 1] / raw_vals[0]
        } else {
            f64::INFINITY
        },
        eigenvalues: raw_vals,
        eigenvectors: raw_vecs,
        length_scale: length,
        scaled_eigenvalues: vals,
        scaled_condition_number: if ratio0 > 0.0 {
            1.0 / ratio0
        } else {
            f64::INFINITY
        },
        weakest: units.column(0).into_owned(),
        weakest_ratio: ratio0,
    }
}
