//! The prior's say along the weak directions (`calibrated` of a degenerate scene): the data's
//! conditional covariance on the strong subspace, the prior (plus the solve's own drift) along
//! the weak one, the tilt of a mis-estimated weak axis, and the degeneracy-aware solve's valley.

use super::degeneracy::Degeneracy;
use super::dense::{inverse, scale_both, sym, unscale_both, Mat, Vector};

/// Replace the data's say along the weak directions of `deg` by the prior's (scaled coordinates
/// inside; `scanreg.trust` documents the model). `drift`: tangent `log(start⁻¹ · pose)`.
pub fn with_prior_along_weak(
    cov: &Mat,
    deg: &Degeneracy,
    prior: &Mat,
    drift: &Vector,
    normal_noise: f64,
    valley: Option<&Mat>,
) -> Mat {
    let s_inv = deg.scaling();
    let w = deg.weak_basis();
    let dof = s_inv.len();
    let u = deg.strong_basis();
    let cov_s = unscale_both(cov, &s_inv);
    let prior_s = unscale_both(prior, &s_inv);
    let strong = if u.ncols() == 0 {
        Mat::zeros(dof, dof)
    } else {
        let conditional = inverse(&cov_s)
            .map(|lam| u.transpose() * lam * &u)
            .and_then(|m| inverse(&m));
        match conditional {
            Some(c) => &u * c * u.transpose(),
            // A singular data covariance (a noise-free fit): the marginal covers it.
            None => &u * (u.transpose() * &cov_s * &u) * u.transpose(),
        }
    };
    let d_w = w.transpose() * drift.component_div(&s_inv);
    let weak_prior = w.transpose() * &prior_s * &w + &d_w * d_w.transpose();
    let tilt = deg.tilt_variances(normal_noise);
    let mut weak = &w * &weak_prior * w.transpose();
    for i in 0..w.ncols() {
        let col: Vector = w.column(i).into_owned();
        let t: Vector = tilt.row(i).transpose();
        weak += axis_cover(&col, &u, &t) * weak_prior[(i, i)];
    }
    if let Some(v) = valley {
        weak += v;
    }
    sym(&scale_both(&(strong + weak), &s_inv))
}

/// Where a unit error along the true weak axis lands in the strong subspace, for the estimated
/// axis `w` (scaled coordinates): the second moment (`scanreg.trust._axis_cover`). A mostly
/// translational `w` (`|t|² ≥ 1/2`) is taken to be a surface symmetry: only its translation
/// rows keep the random tilt, and the offset to the pure translation is added as `d dᵀ`.
pub fn axis_cover(w: &Vector, u: &Mat, tilt: &Vector) -> Mat {
    let dof = w.len();
    let dim = if dof == 3 { 2 } else { 3 };
    let cover = u * Mat::from_diagonal(tilt) * u.transpose();
    let t = w.rows(0, dim).into_owned();
    if t.dot(&t) < 0.5 {
        return cover;
    }
    let mut rows = Mat::zeros(dof, dof);
    for i in 0..dim {
        rows[(i, i)] = 1.0;
    }
    let cover = u * (u.transpose() * &rows * cover * &rows * u) * u.transpose();
    let mut v = Vector::zeros(dof);
    let norm = t.norm();
    for i in 0..dim {
        v[i] = t[i] / norm;
    }
    let d = u * (u.transpose() * (v - w));
    cover + &d * d.transpose()
}
