//! Covariance formulas on the small matrices (`scanreg.quality`): least squares, the
//! M-estimator sandwich, Censi's and the block sandwich from `H⁻¹`, their joint upper bound,
//! and the information of a covariance.

use super::dense::{all_finite, eigh, inverse, scale_columns, sym, Mat, Vector};

/// `σ̂² H⁻¹` (no kernel) or the sandwich `H⁻¹ (Σ ψψᵀ) H⁻¹ · m/(m − dof)`; all `inf` when
/// `H` is singular or the result is not finite.
pub fn of_hessian(
    hessian: &Mat,
    sigma2: f64,
    score_outer: Option<&Mat>,
    effective_residuals: f64,
) -> Mat {
    let dof = hessian.nrows();
    let cov = inverse(hessian).map(|h_inv| match score_outer {
        None => sym(&(h_inv * sigma2)),
        Some(s) => {
            let m = effective_residuals;
            let correction = m / (m - dof as f64).max(1.0);
            sym(&(h_inv.clone() * correction * s * h_inv))
        }
    });
    match cov {
        Some(c) if all_finite(&c) => c,
        _ => Mat::from_element(dof, dof, f64::INFINITY),
    }
}

/// `H⁻¹ meat H⁻¹`, symmetrised.
pub fn censi_from_inverse(h_inv: &Mat, meat: &Mat) -> Mat {
    sym(&(h_inv * meat * h_inv))
}

/// `H⁻¹ (Σ_b ψ_b ψ_bᵀ) H⁻¹ · G/(G − 1)` over `G = max(num_blocks, 2)` blocks, symmetrised.
pub fn block_from_inverse(h_inv: &Mat, block_meat: &Mat, num_blocks: usize) -> Mat {
    let g = num_blocks.max(2) as f64;
    sym(&(h_inv * (g / (g - 1.0)) * block_meat * h_inv))
}

/// The smallest `C ⪰ a, b` along their joint eigenbasis (`scanreg.quality.covariance_upper_bound`).
pub fn upper_bound(a: &Mat, b: &Mat) -> Mat {
    let (mut a, mut b) = (a, b);
    let (mut vals, mut vecs) = eigh(&sym(a));
    if vals[0] <= 0.0 {
        let (vals2, vecs2) = eigh(&sym(b));
        if vals2[0] <= 0.0 {
            return a.zip_map(b, f64::max);
        }
        std::mem::swap(&mut a, &mut b);
        vals = vals2;
        vecs = vecs2;
    }
    let _ = a;
    let root = scale_columns(&vecs, &vals.map(f64::sqrt));
    let inv_root = scale_columns(&vecs, &vals.map(|v| 1.0 / v.sqrt()));
    let (w_vals, w_vecs) = eigh(&(inv_root.transpose() * b * &inv_root));
    let m = scale_columns(&w_vecs, &w_vals.map(|v| v.max(1.0))) * w_vecs.transpose();
    sym(&(&root * m * root.transpose()))
}

/// Eigenvalues of a covariance below this fraction of its largest are floored there when it is
/// inverted: round-off, not information.
const MIN_RELATIVE_VARIANCE: f64 = 1e-14;

/// `cov⁻¹` of a finite covariance (`scanreg.quality.information_from_covariance`): all `inf`
/// for a zero one, variances floored at `1e-14` of the largest when near-singular.
pub fn information(cov: &Mat) -> Mat {
    let n = cov.nrows();
    let (vals, vecs) = eigh(&sym(cov));
    let top = vals[n - 1];
    // Also a NaN top: nothing to invert.
    if top.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Mat::from_element(n, n, f64::INFINITY);
    }
    if vals[0] > MIN_RELATIVE_VARIANCE * top {
        if let Some(inv) = inverse(cov) {
            return inv;
        }
    }
    let floored: Vector = vals.map(|v| 1.0 / v.max(MIN_RELATIVE_VARIANCE * top));
    scale_columns(&vecs, &floored) * vecs.transpose()
}

/// The variance of the beam phase, in steps²: the other scan's samples may fall half-way
/// between this one's (split-beam pairs: exactly), a phase of ±½ step.
pub const SAMPLING_PHASE_VARIANCE: f64 = 0.25;

/// The sampling term of `calibrated` (2D): `v · T A⁻¹ (Tᵀ M T) A⁻¹ Tᵀ`, `A = Tᵀ H T`, from
/// the sampling system `(H, M)` ([`super::scene::sampling_system`]) on the well-constrained
/// subspace (`T` its tangent directions; along weak directions the covariance is the
/// prior's), `v` = [`SAMPLING_PHASE_VARIANCE`]. None when `A` is singular or the result is
/// not finite.
pub fn sampling(h: &Mat, m: &Mat, deg: &super::degeneracy::Degeneracy) -> Option<Mat> {
    let dof = h.nrows();
    let s_inv = deg.scaling();
    let u = deg.strong_basis();
    let t = Mat::from_fn(dof, u.ncols(), |i, j| s_inv[i] * u[(i, j)]);
    let a_inv = inverse(&(t.transpose() * h * &t))?;
    let core = &a_inv * (t.transpose() * m * &t) * &a_inv;
    let out = sym(&(&t * core * t.transpose() * SAMPLING_PHASE_VARIANCE));
    all_finite(&out).then_some(out)
}

/// The sweep-distortion term of `calibrated` (2D): `E[b bᵀ] = K M Kᵀ` for the estimate's
/// first-order shift `b = K g`, `K = T A⁻¹ Tᵀ`, `A = Tᵀ H T`, from the distortion system
/// `(H, M)`, `M = E[g gᵀ]` ([`super::distortion::distortion_system`]: `g gᵀ` for one known
/// sweep, the mean over the sweeps that may have laid a map's points) on the
/// well-constrained subspace (along weak directions the covariance is the prior's). None
/// when `A` is singular or the term not finite.
pub fn distortion(h: &Mat, m: &Mat, deg: &super::degeneracy::Degeneracy) -> Option<Mat> {
    let dof = h.nrows();
    let s_inv = deg.scaling();
    let u = deg.strong_basis();
    let t = Mat::from_fn(dof, u.ncols(), |i, j| s_inv[i] * u[(i, j)]);
    let a_inv = inverse(&(t.transpose() * h * &t))?;
    let k = &t * a_inv * t.transpose();
    let out = sym(&(&k * m * k.transpose()));
    all_finite(&out).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::super::dense::from_rows;
    use super::*;

    #[test]
    fn upper_bound_covers_both() {
        let a = from_rows(2, &[4.0, 0.0, 0.0, 1.0]);
        let b = from_rows(2, &[1.0, 0.0, 0.0, 9.0]);
        let c = upper_bound(&a, &b);
        assert!((c[(0, 0)] - 4.0).abs() < 1e-12 && (c[(1, 1)] - 9.0).abs() < 1e-12);
    }

    #[test]
    fn singular_hessian_gives_inf() {
        let z = Mat::zeros(3, 3);
        assert!(of_hessian(&z, 1.0, None, 0.0)[(0, 0)].is_infinite());
        let i = information(&Mat::zeros(3, 3));
        assert!(i[(1, 1)].is_infinite());
    }
}
