//! 2D Normal Distributions Transform (Biber & Straßer 2003): the reference as Gaussians per
//! cell, and the score, gradient and Hessian of a source scan under a pose.
//!
//! * Four overlapping grids of `cell_size`, shifted by half a cell in x, y and both (§III of
//!   the paper), so every point falls into four cells and the score is smooth across borders.
//! * A cell with at least `min_points` reference points holds their mean `μ` and covariance
//!   `Σ` (sample, `/(n−1)`); the smaller eigenvalue is raised to `min_eigen_ratio · λ_max` so a
//!   straight wall does not give a singular `Σ` (the paper uses 0.001).
//! * The pose is the vector `p = [tx, ty, φ]` of `T_reference_source` (`x' = R(φ) x + t`). The
//!   cost is `f(p) = −Σ_points Σ_cells exp(−½ qᵀ Σ⁻¹ q)` with `q = x' − μ`; with
//!   `e = exp(−½ qᵀΣ⁻¹q)` and `J = ∂q/∂p`:
//!   `∇f_i = e · qᵀΣ⁻¹ J_i` and
//!   `∇²f_ij = e · (J_jᵀΣ⁻¹J_i + qᵀΣ⁻¹ ∂²q/∂p_i∂p_j − (qᵀΣ⁻¹J_i)(qᵀΣ⁻¹J_j))`
//!   (Biber & Straßer eqs. 5–9; Magnusson 2009 §6.2), where only `∂²q/∂φ²` is non-zero.
//!   Sums run over fixed chunks in order, so the result does not depend on the thread count.

use crate::error::{Error, Result};
use crate::reduce::chunked_sum;
use rustc_hash::FxHashMap;

/// One cell's Gaussian: mean and inverse covariance (row-major 2×2, symmetric).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NdtCell {
    pub mean: [f64; 2],
    pub covariance: [f64; 4],
    pub inverse: [f64; 4],
    pub count: usize,
}

/// The four shifted grids of a reference scan or map.
#[derive(Debug, Clone)]
pub struct NdtGrid {
    cell_size: f64,
    grids: [FxHashMap<(i64, i64), NdtCell>; 4],
}

/// Cost, gradient and Hessian at one pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NdtEvaluation {
    /// `f(p) = −Σ e` (lower is better; `−4N` at most).
    pub cost: f64,
    pub gradient: [f64; 3],
    /// Row-major 3×3.
    pub hessian: [f64; 9],
    /// `Σ e · JᵀΣ⁻¹J`: the Gauss–Newton part of the Hessian (positive semi-definite; the
    /// Fisher information of the cell Gaussians), row-major 3×3.
    pub information: [f64; 9],
    /// Source points that fell into at least one cell.
    pub num_matched: usize,
}

const SHIFTS: [[f64; 2]; 4] = [[0.0, 0.0], [0.5, 0.0], [0.0, 0.5], [0.5, 0.5]];

fn key(x: f64, y: f64, cell: f64, shift: [f64; 2]) -> (i64, i64) {
    (
        (x / cell - shift[0]).floor() as i64,
        (y / cell - shift[1]).floor() as i64,
    )
}

fn finite_points(points: &[f64], arg: &'static str) -> Result<usize> {
    if !points.len().is_multiple_of(2) {
        return Err(Error::invalid(arg, "length is not a multiple of 2"));
    }
    if points.is_empty() {
        return Err(Error::invalid(arg, "is empty (0 points)"));
    }
    if let Some(bad) = points.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(
            arg,
            format!("point {} has a non-finite coordinate (NaN or inf)", bad / 2),
        ));
    }
    Ok(points.len() / 2)
}

impl NdtGrid {
    /// Build the four grids from `reference` (flat `(N, 2)`).
    pub fn build(
        reference: &[f64],
        cell_size: f64,
        min_points: usize,
        min_eigen_ratio: f64,
    ) -> Result<Self> {
        finite_points(reference, "reference")?;
        if !(cell_size.is_finite() && cell_size > 0.0) {
            return Err(Error::invalid(
                "cell_size",
                format!("must be finite and > 0, got {cell_size}"),
            ));
        }
        if min_points < 3 {
            return Err(Error::invalid(
                "min_points",
                format!("must be >= 3 (a 2D covariance), got {min_points}"),
            ));
        }
        if !(min_eigen_ratio.is_finite() && min_eigen_ratio > 0.0 && min_eigen_ratio <= 1.0) {
            return Err(Error::invalid(
                "min_eigen_ratio",
                format!("must be in (0, 1], got {min_eigen_ratio}"),
            ));
        }
        let grids = SHIFTS.map(|shift| {
            // (n, Σx, Σy, Σxx, Σxy, Σyy) relative to the first point of the cell, which keeps
            // the second moments well conditioned far from the origin.
            let mut acc: FxHashMap<(i64, i64), ([f64; 2], [f64; 6])> = FxHashMap::default();
            for p in reference.chunks_exact(2) {
                let e = acc
                    .entry(key(p[0], p[1], cell_size, shift))
                    .or_insert(([p[0], p[1]], [0.0; 6]));
                let (dx, dy) = (p[0] - e.0[0], p[1] - e.0[1]);
                let s = &mut e.1;
                s[0] += 1.0;
                s[1] += dx;
                s[2] += dy;
                s[3] += dx * dx;
                s[4] += dx * dy;
                s[5] += dy * dy;
            }
            acc.into_iter()
                .filter_map(|(k, (anchor, s))| {
                    let n = s[0];
                    if (n as usize) < min_points {
                        return None;
                    }
                    let (mx, my) = (s[1] / n, s[2] / n);
                    let sxx = (s[3] - n * mx * mx) / (n - 1.0);
                    let sxy = (s[4] - n * mx * my) / (n - 1.0);
                    let syy = (s[5] - n * my * my) / (n - 1.0);
                    let covariance = regularise([sxx, sxy, syy], min_eigen_ratio)?;
                    let [a, b, _, d] = covariance;
                    let det = a * d - b * b;
                    let inverse = [d / det, -b / det, -b / det, a / det];
                    Some((
                        k,
                        NdtCell {
                            mean: [anchor[0] + mx, anchor[1] + my],
                            covariance,
                            inverse,
                            count: n as usize,
                        },
                    ))
                })
                .collect()
        });
        Ok(NdtGrid { cell_size, grids })
    }

    pub fn cell_size(&self) -> f64 {
        self.cell_size
    }

    /// Cells per grid (the four shifted grids).
    pub fn num_cells(&self) -> [usize; 4] {
        [0, 1, 2, 3].map(|g| self.grids[g].len())
    }

    /// Every cell of grid `g` (0..4) as `(mean, covariance)`, in a deterministic order.
    pub fn cells(&self, g: usize) -> Vec<NdtCell> {
        let mut keys: Vec<&(i64, i64)> = self.grids[g].keys().collect();
        keys.sort();
        keys.into_iter().map(|k| self.grids[g][k]).collect()
    }

    /// Cost, gradient and Hessian of `source` (flat `(N, 2)`) at `pose = [tx, ty, φ]`.
    pub fn evaluate(&self, source: &[f64], pose: [f64; 3]) -> Result<NdtEvaluation> {
        let n = finite_points(source, "source")?;
        if !pose.iter().all(|v| v.is_finite()) {
            return Err(Error::invalid("pose", "contains NaN or inf"));
        }
        let (s, c) = pose[2].sin_cos();
        let identity = NdtEvaluation {
            cost: 0.0,
            gradient: [0.0; 3],
            hessian: [0.0; 9],
            information: [0.0; 9],
            num_matched: 0,
        };
        let out = chunked_sum(
            n,
            identity,
            |range| {
                let mut acc = identity;
                for idx in range {
                    let (x, y) = (source[2 * idx], source[2 * idx + 1]);
                    let xp = [c * x - s * y + pose[0], s * x + c * y + pose[1]];
                    // J columns: ∂q/∂tx = (1, 0), ∂q/∂ty = (0, 1), ∂q/∂φ = (−x s − y c, x c − y s).
                    let jphi = [-x * s - y * c, x * c - y * s];
                    let hphi = [-x * c + y * s, -x * s - y * c];
                    let jac = [[1.0, 0.0], [0.0, 1.0], jphi];
                    let mut matched = false;
                    for (g, shift) in SHIFTS.iter().enumerate() {
                        let Some(cell) =
                            self.grids[g].get(&key(xp[0], xp[1], self.cell_size, *shift))
                        else {
                            continue;
                        };
                        matched = true;
                        let q = [xp[0] - cell.mean[0], xp[1] - cell.mean[1]];
                        let inv = cell.inverse;
                        let iq = [inv[0] * q[0] + inv[1] * q[1], inv[2] * q[0] + inv[3] * q[1]];
                        let e = (-0.5 * (q[0] * iq[0] + q[1] * iq[1])).exp();
                        acc.cost -= e;
                        let qj: [f64; 3] = jac.map(|j| iq[0] * j[0] + iq[1] * j[1]);
                        for i in 0..3 {
                            acc.gradient[i] += e * qj[i];
                            for k in 0..3 {
                                let (ji, jk) = (jac[i], jac[k]);
                                let jsj = ji[0] * (inv[0] * jk[0] + inv[1] * jk[1])
                                    + ji[1] * (inv[2] * jk[0] + inv[3] * jk[1]);
                                let second = if i == 2 && k == 2 {
                                    iq[0] * hphi[0] + iq[1] * hphi[1]
                                } else {
                                    0.0
                                };
                                acc.hessian[i * 3 + k] += e * (jsj + second - qj[i] * qj[k]);
                                acc.information[i * 3 + k] += e * jsj;
                            }
                        }
                    }
                    acc.num_matched += matched as usize;
                }
                acc
            },
            |mut a, b| {
                a.cost += b.cost;
                for i in 0..3 {
                    a.gradient[i] += b.gradient[i];
                }
                for i in 0..9 {
                    a.hessian[i] += b.hessian[i];
                    a.information[i] += b.information[i];
                }
                a.num_matched += b.num_matched;
                a
            },
        );
        Ok(out)
    }
}

/// Raise the smaller eigenvalue of `[sxx, sxy, syy]` to `ratio · λ_max`; `None` if degenerate.
fn regularise(c: [f64; 3], ratio: f64) -> Option<[f64; 4]> {
    let [a, b, d] = c;
    let tr = a + d;
    let disc = (((a - d) * 0.5).powi(2) + b * b).sqrt();
    let l1 = tr * 0.5 + disc;
    let l2 = tr * 0.5 - disc;
    if !(l1.is_finite() && l1 > 0.0) {
        return None; // all points identical
    }
    let l2n = l2.max(ratio * l1);
    if l2n == l2 {
        return Some([a, b, b, d]);
    }
    // Eigenvector of l1: (b, l1 − a) or (l1 − d, b), whichever is longer.
    let (mut vx, mut vy) = if (l1 - a).abs() + b.abs() > (l1 - d).abs() + b.abs() {
        (b, l1 - a)
    } else {
        (l1 - d, b)
    };
    let norm = (vx * vx + vy * vy).sqrt();
    if norm == 0.0 {
        (vx, vy) = (1.0, 0.0);
    } else {
        vx /= norm;
        vy /= norm;
    }
    // Σ = l1 v vᵀ + l2n w wᵀ with w ⊥ v.
    let (wx, wy) = (-vy, vx);
    Some([
        l1 * vx * vx + l2n * wx * wx,
        l1 * vx * vy + l2n * wx * wy,
        l1 * vx * vy + l2n * wx * wy,
        l1 * vy * vy + l2n * wy * wy,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> Vec<f64> {
        let mut pts = Vec::new();
        for k in 0..200 {
            let t = k as f64 / 200.0;
            pts.extend([-3.0 + 7.0 * t, -2.0 + 0.01 * (k % 3) as f64]);
            pts.extend([4.0, -2.0 + 5.0 * t]);
            pts.extend([-3.0 + 7.0 * t, 3.0]);
            pts.extend([-3.0 + 0.01 * (k % 2) as f64, -2.0 + 5.0 * t]);
            pts.extend([0.5 + 0.3 * (6.3 * t).cos(), 0.5 + 0.3 * (6.3 * t).sin()]);
        }
        pts
    }

    #[test]
    fn gradient_and_hessian_match_finite_differences() {
        let reference = room();
        let grid = NdtGrid::build(&reference, 1.0, 3, 0.001).unwrap();
        let source: Vec<f64> = reference.iter().map(|v| v * 0.99 + 0.02).collect();
        let p = [0.05, -0.03, 0.02];
        let ev = grid.evaluate(&source, p).unwrap();
        let h = 1e-6;
        for i in 0..3 {
            let mut pp = p;
            let mut pm = p;
            pp[i] += h;
            pm[i] -= h;
            let (ep, em) = (
                grid.evaluate(&source, pp).unwrap(),
                grid.evaluate(&source, pm).unwrap(),
            );
            let g = (ep.cost - em.cost) / (2.0 * h);
            assert!(
                (g - ev.gradient[i]).abs() < 1e-4 * (1.0 + g.abs()),
                "{i}: {g} {}",
                ev.gradient[i]
            );
            for k in 0..3 {
                let hk = (ep.gradient[k] - em.gradient[k]) / (2.0 * h);
                let an = ev.hessian[i * 3 + k];
                assert!(
                    (hk - an).abs() < 1e-3 * (1.0 + hk.abs()),
                    "{i}{k}: {hk} {an}"
                );
            }
        }
    }

    #[test]
    fn regularised_covariance_keeps_the_long_axis() {
        let c = regularise([1.0, 0.0, 0.0], 0.001).unwrap();
        assert_eq!(c, [1.0, 0.0, 0.0, 0.001]);
        let c = regularise([0.5, 0.5, 0.5], 0.01).unwrap();
        assert!((c[0] - 0.505).abs() < 1e-12 && (c[1] - 0.495).abs() < 1e-12);
        assert!(regularise([0.0, 0.0, 0.0], 0.001).is_none());
    }

    #[test]
    fn hostile_input_is_an_error() {
        assert!(NdtGrid::build(&[], 1.0, 3, 0.001).is_err());
        assert!(NdtGrid::build(&[0.0, f64::NAN], 1.0, 3, 0.001).is_err());
        assert!(NdtGrid::build(&[0.0, 0.0], 0.0, 3, 0.001).is_err());
        assert!(NdtGrid::build(&[0.0, 0.0], 1.0, 2, 0.001).is_err());
        assert!(NdtGrid::build(&[0.0, 0.0], 1.0, 3, 0.0).is_err());
        let g = NdtGrid::build(&room(), 1.0, 3, 0.001).unwrap();
        assert!(g.evaluate(&[0.0], [0.0; 3]).is_err());
        assert!(g.evaluate(&[0.0, 0.0], [f64::NAN, 0.0, 0.0]).is_err());
    }
}
