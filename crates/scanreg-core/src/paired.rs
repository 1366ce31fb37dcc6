//! Paired (known-correspondence) alignment: the sums behind closed-form Kabsch/Umeyama and
//! the Gauss–Newton normal equations for point-to-point and point-to-plane/line residuals,
//! with the ICP loop's factors and accumulator ([`crate::factor`]).
//!
//! The small dense algebra on the returned matrices (SVD, solve, inverse) is the caller's.

use crate::error::{Error, Result};
use crate::factor::{self, row_major, NormalSums};
use crate::group::{Group, Planar, Spatial};
use crate::kernel::Kernel;
use crate::points::{check_points, check_weights, split_pose, vec_at};
use crate::reduce::chunked_sum;
use nalgebra::{SMatrix, SVector};

/// Weighted first and second moments of a paired point set, centred in two passes so that
/// far-from-origin coordinates (UTM, map frames) do not cancel catastrophically.
#[derive(Debug, Clone, PartialEq)]
pub struct Moments {
    pub weight_sum: f64,
    pub source_mean: Vec<f64>,
    pub target_mean: Vec<f64>,
    /// `Σ w (p - p̄)(q - q̄)ᵀ`, row-major `dim x dim` (rows index source coordinates).
    pub cross_covariance: Vec<f64>,
    /// `Σ w |p - p̄|²`, needed for the Umeyama scale.
    pub source_spread: f64,
    /// `Σ w |q - q̄|²`.
    pub target_spread: f64,
}

fn check_pair(source: &[f64], target: &[f64], dim: usize) -> Result<usize> {
    let n = check_points("source", source, dim)?;
    let m = check_points("target", target, dim)?;
    if n != m {
        return Err(Error::invalid(
            "target",
            format!("has {m} points but source has {n}; paired alignment needs one target point per source point"),
        ));
    }
    Ok(n)
}

fn weight_at(weights: Option<&[f64]>, i: usize) -> f64 {
    weights.map_or(1.0, |w| w[i])
}

/// Weighted centroids and centred cross-covariance of `source[i] ↔ target[i]`.
pub fn paired_moments(
    source: &[f64],
    target: &[f64],
    dim: usize,
    weights: Option<&[f64]>,
) -> Result<Moments> {
    let n = check_pair(source, target, dim)?;
    if n == 0 {
        return Err(Error::invalid("source", "is empty"));
    }
    if let Some(w) = weights {
        check_weights("weights", w, n)?;
    }
    // Pass 1: weighted sums for the centroids.
    let sums = chunked_sum(
        n,
        vec![0.0; 2 * dim + 1],
        |range| {
            let mut acc = vec![0.0; 2 * dim + 1];
            for i in range {
                let w = weight_at(weights, i);
                for k in 0..dim {
                    acc[k] += w * source[i * dim + k];
                    acc[dim + k] += w * target[i * dim + k];
                }
                acc[2 * dim] += w;
            }
            acc
        },
        add_vecs,
    );
    let weight_sum = sums[2 * dim];
    let source_mean: Vec<f64> = sums[..dim].iter().map(|s| s / weight_sum).collect();
    let target_mean: Vec<f64> = sums[dim..2 * dim].iter().map(|s| s / weight_sum).collect();
    // Pass 2: centred second moments.
    let len = dim * dim + 2;
    let second = chunked_sum(
        n,
        vec![0.0; len],
        |range| {
            let mut acc = vec![0.0; len];
            let mut p = [0.0; 3];
            let mut q = [0.0; 3];
            for i in range {
                let w = weight_at(weights, i);
                for k in 0..dim {
                    p[k] = source[i * dim + k] - source_mean[k];
                    q[k] = target[i * dim + k] - target_mean[k];
                }
                for r in 0..dim {
                    for c in 0..dim {
                        acc[r * dim + c] += w * p[r] * q[c];
                    }
                    acc[dim * dim] += w * p[r] * p[r];
                    acc[dim * dim + 1] += w * q[r] * q[r];
                }
            }
            acc
        },
        add_vecs,
    );
    Ok(Moments {
        weight_sum,
        source_mean,
        target_mean,
        cross_covariance: second[..dim * dim].to_vec(),
        source_spread: second[dim * dim],
        target_spread: second[dim * dim + 1],
    })
}

fn add_vecs(mut a: Vec<f64>, b: Vec<f64>) -> Vec<f64> {
    for (x, y) in a.iter_mut().zip(b) {
        *x += y;
    }
    a
}

/// Which residual each pair contributes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Objective {
    /// `r = R p + t - q` (a `dim`-vector).
    PointToPoint,
    /// `r = nᵀ (R p + t - q)` with `n` the target normal: point-to-plane in 3D,
    /// point-to-line in 2D.
    PointToPlane,
}

/// The Gauss–Newton normal equations at one pose, IRLS-weighted by a robust kernel.
#[derive(Debug, Clone, PartialEq)]
pub struct Linearization {
    /// `Σ w k JᵀJ`, row-major `dof x dof` (w: user weight, k: kernel weight).
    pub hessian: Vec<f64>,
    /// `Σ w k Jᵀ r`; the Gauss–Newton step is `δ = -H⁻¹ g`, applied as `T · exp(δ)`.
    pub gradient: Vec<f64>,
    /// `Σ (w k Jᵀ r)(w k Jᵀ r)ᵀ`, row-major `dof x dof`: the "meat" of the sandwich
    /// covariance `H⁻¹ M H⁻¹` of an M-estimator (Huber 1981, §7.6).
    pub score_outer: Vec<f64>,
    /// `Σ w rho(|r|)`.
    pub robust_cost: f64,
    /// `Σ w |r|²`.
    pub weighted_sum_squares: f64,
    /// `Σ w k |r|²`: the IRLS-weighted sum of squares.
    pub irls_sum_squares: f64,
    /// `Σ w k`: the effective number of pairs after kernel down-weighting.
    pub irls_weight_sum: f64,
    /// Per pair: `|r|` for point-to-point, signed `nᵀ r` for point-to-plane/line.
    pub residuals: Vec<f64>,
    /// Per pair: the kernel weight `k` (1 without a kernel).
    pub kernel_weights: Vec<f64>,
}

/// A chunk's normal-equation sums ([`NormalSums`], the ICP loop's accumulator) and the
/// per-pair residuals and kernel weights.
struct Acc<const D: usize, const N: usize> {
    sums: NormalSums<D, N>,
    residuals: Vec<f64>,
    kernel_weights: Vec<f64>,
}

impl<const D: usize, const N: usize> Acc<D, N> {
    fn new(capacity: usize) -> Self {
        Acc {
            sums: NormalSums::zeros(),
            residuals: Vec::with_capacity(capacity),
            kernel_weights: Vec::with_capacity(capacity),
        }
    }

    fn merge(mut self, other: Self) -> Self {
        self.sums.merge(&other.sums);
        self.residuals.extend(other.residuals);
        self.kernel_weights.extend(other.kernel_weights);
        self
    }

    fn finish<G: Group<D, N>>(self) -> Linearization {
        let s = &self.sums;
        Linearization {
            hessian: row_major(&s.hessian::<G>()),
            gradient: s.g.iter().copied().collect(),
            score_outer: row_major(&s.m),
            robust_cost: s.cost,
            weighted_sum_squares: s.ss,
            irls_sum_squares: s.irls_ss,
            irls_weight_sum: s.irls_w,
            residuals: self.residuals,
            kernel_weights: self.kernel_weights,
        }
    }
}

/// Unit normal `i`, or an error naming it when it has zero length.
fn unit_normal<const D: usize>(normals: &[f64], i: usize) -> Result<SVector<f64, D>> {
    let n = SVector::<f64, D>::from_fn(|k, _| normals[i * D + k]);
    let len = n.norm();
    if len < 1e-12 {
        return Err(Error::invalid(
            "target_normals",
            format!("normal {i} has zero length"),
        ));
    }
    Ok(n / len)
}

/// Linearise the paired residuals at `pose` (row-major homogeneous `T_target_source`).
///
/// `normals` (target frame, one per pair) is required for [`Objective::PointToPlane`].
#[allow(clippy::too_many_arguments)]
pub fn linearize_paired(
    source: &[f64],
    target: &[f64],
    normals: Option<&[f64]>,
    dim: usize,
    pose: &[f64],
    weights: Option<&[f64]>,
    objective: Objective,
    kernel: Kernel,
) -> Result<Linearization> {
    let n = check_pair(source, target, dim)?;
    if let Some(w) = weights {
        check_weights("weights", w, n)?;
    }
    let (rot, trans) = split_pose("pose", pose, dim)?;
    let normals = match (objective, normals) {
        (Objective::PointToPlane, None) => {
            return Err(Error::invalid(
                "target_normals",
                "are required for point-to-plane/line residuals",
            ))
        }
        (_, Some(nrm)) => {
            let m = check_points("target_normals", nrm, dim)?;
            if m != n {
                return Err(Error::invalid(
                    "target_normals",
                    format!("expected {n} normals (one per target point), got {m}"),
                ));
            }
            Some(nrm)
        }
        (_, None) => None,
    };
    if let Some(nrm) = normals {
        // Validate up front so the parallel loop below cannot fail.
        for i in 0..n {
            if dim == 2 {
                unit_normal::<2>(nrm, i)?;
            } else {
                unit_normal::<3>(nrm, i)?;
            }
        }
    }
    let (rot, trans) = (rot.as_slice(), trans.as_slice());
    Ok(if dim == 2 {
        linearize::<Planar, 2, 3>(
            source, target, normals, rot, trans, weights, objective, kernel,
        )
    } else {
        linearize::<Spatial, 3, 6>(
            source, target, normals, rot, trans, weights, objective, kernel,
        )
    })
}

/// [`linearize_paired`] once checked: each pair's factor ([`crate::factor`], the ICP loop's
/// own) added with weight `w k` (`w` the pair's weight, `k` its kernel weight).
#[allow(clippy::too_many_arguments)]
fn linearize<G: Group<D, N>, const D: usize, const N: usize>(
    source: &[f64],
    target: &[f64],
    normals: Option<&[f64]>,
    rot: &[f64],
    trans: &[f64],
    weights: Option<&[f64]>,
    objective: Objective,
    kernel: Kernel,
) -> Linearization {
    let n = source.len() / D;
    let r = SMatrix::<f64, D, D>::from_row_slice(rot);
    let t = SVector::<f64, D>::from_column_slice(trans);
    let rt = r.transpose();
    chunked_sum(
        n,
        Acc::<D, N>::new(n),
        |range| {
            let mut acc = Acc::<D, N>::new(range.len());
            for i in range {
                let p: SVector<f64, D> = vec_at(source, i);
                let e = r * p + t - vec_at::<D>(target, i);
                let w = weight_at(weights, i);
                let f = match objective {
                    Objective::PointToPoint => factor::point_to_point::<G, D, N>(&p, &rt, &e),
                    Objective::PointToPlane => {
                        // Validated (non-zero) by the caller.
                        let nrm = unit_normal::<D>(normals.unwrap_or(&[]), i)
                            .unwrap_or_else(|_| SVector::zeros());
                        factor::point_to_plane::<G, D, N>(&p, &rt, &nrm, &e)
                    }
                };
                let norm = f.residual.abs();
                let k = kernel.weight(norm);
                acc.sums
                    .add::<G>(&p, &f, w, w * k, w * kernel.rho(norm), true);
                acc.residuals.push(f.residual);
                acc.kernel_weights.push(k);
            }
            acc
        },
        Acc::merge,
    )
    .finish::<G>()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose_2d(theta: f64, tx: f64, ty: f64) -> Vec<f64> {
        let (s, c) = theta.sin_cos();
        vec![c, -s, tx, s, c, ty, 0.0, 0.0, 1.0]
    }

    fn apply_2d(pose: &[f64], pts: &[f64]) -> Vec<f64> {
        pts.chunks(2)
            .flat_map(|p| {
                [
                    pose[0] * p[0] + pose[1] * p[1] + pose[2],
                    pose[3] * p[0] + pose[4] * p[1] + pose[5],
                ]
            })
            .collect()
    }

    #[test]
    fn moments_of_translated_points() {
        let src = vec![0.0, 0.0, 2.0, 0.0, 0.0, 2.0];
        let tgt: Vec<f64> = src
            .chunks(2)
            .flat_map(|p| [p[0] + 1.0, p[1] - 1.0])
            .collect();
        let m = paired_moments(&src, &tgt, 2, None).unwrap();
        assert_eq!(m.weight_sum, 3.0);
        assert!((m.target_mean[0] - m.source_mean[0] - 1.0).abs() < 1e-15);
        // Pure translation: cross-covariance equals the source scatter matrix.
        assert!((m.cross_covariance[0] - m.source_spread / 2.0).abs() < 1e-12);
    }

    #[test]
    fn zero_residual_at_truth_and_gradient_matches_finite_difference() {
        let src: Vec<f64> = (0..50)
            .flat_map(|i| {
                let a = i as f64 * 0.37;
                [3.0 * a.cos() + 0.1 * i as f64, 2.0 * a.sin()]
            })
            .collect();
        let truth = pose_2d(0.2, 1.0, -0.5);
        let tgt = apply_2d(&truth, &src);
        let lin = linearize_paired(
            &src,
            &tgt,
            None,
            2,
            &truth,
            None,
            Objective::PointToPoint,
            Kernel::None,
        )
        .unwrap();
        assert!(lin.weighted_sum_squares < 1e-20);
        // At a perturbed pose, g = ∂cost/∂δ: compare with a finite difference along θ.
        let pose = pose_2d(0.25, 1.1, -0.4);
        let cost_at = |d: f64| {
            // T · exp([0, 0, d]) = rotation composed on the right.
            let rd = pose_2d(d, 0.0, 0.0);
            let mut m = vec![0.0; 9];
            for a in 0..3 {
                for b in 0..3 {
                    m[a * 3 + b] = (0..3).map(|k| pose[a * 3 + k] * rd[k * 3 + b]).sum();
                }
            }
            linearize_paired(
                &src,
                &tgt,
                None,
                2,
                &m,
                None,
                Objective::PointToPoint,
                Kernel::None,
            )
            .unwrap()
            .robust_cost
        };
        let lin = linearize_paired(
            &src,
            &tgt,
            None,
            2,
            &pose,
            None,
            Objective::PointToPoint,
            Kernel::None,
        )
        .unwrap();
        let h = 1e-6;
        let fd = (cost_at(h) - cost_at(-h)) / (2.0 * h);
        assert!((fd - lin.gradient[2]).abs() < 1e-5 * fd.abs().max(1.0));
    }

    #[test]
    fn rejects_bad_input() {
        let pose = pose_2d(0.0, 0.0, 0.0);
        let ok = vec![0.0; 6];
        let err = paired_moments(&ok, &ok[..4], 2, None).unwrap_err();
        assert!(err.to_string().starts_with("target:"), "{err}");
        let err = paired_moments(&[0.0, f64::NAN], &[0.0, 0.0], 2, None).unwrap_err();
        assert!(err.to_string().contains("non-finite"), "{err}");
        let err = paired_moments(&ok, &ok, 2, Some(&[0.0, 0.0, 0.0])).unwrap_err();
        assert!(err.to_string().contains("all weights are zero"), "{err}");
        let err = linearize_paired(
            &ok,
            &ok,
            None,
            2,
            &pose,
            None,
            Objective::PointToPlane,
            Kernel::None,
        )
        .unwrap_err();
        assert!(err.to_string().starts_with("target_normals:"), "{err}");
        let err = linearize_paired(
            &ok,
            &ok,
            Some(&[1.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
            2,
            &pose,
            None,
            Objective::PointToPlane,
            Kernel::None,
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("normal 1 has zero length"),
            "{err}"
        );
        let err = linearize_paired(
            &ok,
            &ok,
            None,
            2,
            &pose[..4],
            None,
            Objective::PointToPoint,
            Kernel::None,
        )
        .unwrap_err();
        assert!(err.to_string().starts_with("pose:"), "{err}");
    }
}
