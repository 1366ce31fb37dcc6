//! The prior's say along the weak directions (`calibrated` of a degenerate scene): the data's
//! conditional covariance on the strong subspace, the prior (plus the solve's own drift) along
//! the weak one, the tilt of a mis-estimated weak axis, and the degeneracy-aware solve's valley.

use super::degeneracy::Degeneracy;
use super::dense::{inverse, scale_both, sym, unscale_both, Mat, Vector};

/// Replace the data's say along the weak directions of `deg` by the prior's.
///
/// In scaled coordinates with `W` the weak eigenvectors and `U` the strong ones: the
/// well-determined part is the data's covariance of `U`-coordinates *given* the weak ones
/// (`(Uᵀ Λ U)⁻¹`, `Λ = cov⁻¹`): the solve fixes (aware) or drifts (not aware) along `W` and
/// solves the rest for that value. Along `W` the variance is the prior's plus the square of the
/// solve's own move along `W` (`drift`, tangent `log(start⁻¹ · pose)`: the data do not
/// determine it; zero when held). `W` is itself estimated from noisy normals: an error of `σ_w`
/// along the true axis shows as `σ_w · tilt_j` along each `u_j`
/// ([`Degeneracy::tilt_variances`]) or, for a translation, as its rotation rows
/// ([`axis_cover`]), added there. With the degeneracy-aware solve, `valley` (how the strong
/// coordinates follow the held weak ones, from held re-solves, `scanreg.trust.valley_moment`)
/// is added as well.
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
/// axis `w` (scaled coordinates): the second moment, `dof × dof`.
///
/// `w` is estimated from noisy normals; an error `a` along the true axis `w*` shows across `w`
/// as `a · Uᵀ (w* − w)`. In general `w*` is `w` tilted at random towards each `u_j` by `tilt_j`.
/// A weak direction that is mostly translation (`|t|² ≥ 1/2`) is taken to be a surface
/// symmetry — a corridor, a tunnel, a plane: exactly a translation, `w* = (t*, 0)`. Its rotation
/// rows are then a known deviation, not noise: biased normals put them there (the ring pattern
/// in a tunnel: −0.6 to −1.0 mrad of pitch per metre along the axis in every realisation,
/// `docs/calibration.md`), and only the translation rows keep the random tilt.
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
