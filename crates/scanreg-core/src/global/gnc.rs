//! Robust rotation + translation from correspondences: graduated non-convexity with a
//! truncated least-squares cost (GNC-TLS; Yang, Antonante, Tzoumas & Carlone 2020,
//! "Graduated Non-Convexity for Robust Spatial Perception", §IV and Prop. 5).
//!
//! The cost is `Σ min(r_i², β²)`, `r_i = |R s_i + t − t_i|`. GNC replaces it by a surrogate
//! with parameter `μ` (convex for `μ → 0`, the TLS cost for `μ → ∞`) and alternates a weighted
//! least-squares solve (Horn / Umeyama, closed form) with the closed-form weights
//!
//! * `w_i = 1` where `r_i² <= μ/(μ+1) β²`,
//! * `w_i = 0` where `r_i² >= (μ+1)/μ β²`,
//! * `w_i = β/r_i √(μ(μ+1)) − μ` in between,
//!
//! starting from `μ = β² / (2 r_max² − β²)` and multiplying `μ` by 1.4 per step, until the
//! weights are binary (every `w_i` within 1e-6 of 0 or 1) or the TLS cost stops changing.

use nalgebra::{Matrix3, Vector3};

/// Result of [`gnc_tls`].
#[derive(Debug, Clone, PartialEq)]
pub struct GncResult {
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
    /// Final weight of each correspondence (binary at convergence).
    pub weights: Vec<f64>,
    pub iterations: usize,
}

/// Weighted least-squares rigid transform `(R, t)` minimising `Σ w_i |R s_i + t − t_i|²`
/// (Horn 1987; Umeyama 1991's reflection guard). `None` when the weights sum to zero or the
/// weighted points are collinear (the rotation about their line is undetermined).
pub fn weighted_rigid(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    weights: &[f64],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let wsum: f64 = weights.iter().sum();
    if wsum <= 0.0 || !wsum.is_finite() {
        return None;
    }
    let mut ms = Vector3::zeros();
    let mut mt = Vector3::zeros();
    for ((s, t), &w) in source.iter().zip(target).zip(weights) {
        ms += w * s;
        mt += w * t;
    }
    ms /= wsum;
    mt /= wsum;
    let mut h = Matrix3::zeros();
    for ((s, t), &w) in source.iter().zip(target).zip(weights) {
        h += w * (t - mt) * (s - ms).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let sv = svd.singular_values;
    // nalgebra leaves singular values unordered; collinear data has two (near) zero ones.
    let mut sorted = [sv[0], sv[1], sv[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if sorted[0] <= 0.0 || sorted[1] <= 1e-12 * sorted[0] {
        return None;
    }
    let d = (u * vt).determinant().signum();
    let mut fix = Matrix3::identity();
    // Flip the axis of the smallest singular value when the best orthogonal matrix is a
    // reflection.
    let smallest = (0..3).min_by(|&a, &b| sv[a].total_cmp(&sv[b])).unwrap_or(2);
    fix[(smallest, smallest)] = d;
    let r = u * fix * vt;
    let t = mt - r * ms;
    Some((r, t))
}

/// GNC-TLS over paired points with noise bound `beta` (> 0): see the module docs. `None`
/// when no rotation is determined (fewer than 3 non-collinear points).
pub fn gnc_tls(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    beta: f64,
    max_iterations: usize,
) -> Option<GncResult> {
    let n = source.len();
    let mut weights = vec![1.0; n];
    let (mut r, mut t) = weighted_rigid(source, target, &weights)?;
    let beta2 = beta * beta;
    let residuals = |r: &Matrix3<f64>, t: &Vector3<f64>| -> Vec<f64> {
        source
            .iter()
            .zip(target)
            .map(|(s, q)| (r * s + t - q).norm_squared())
            .collect()
    };
    let mut res = residuals(&r, &t);
    let rmax = res.iter().copied().fold(0.0, f64::max);
    if rmax <= beta2 {
        return Some(GncResult {
            rotation: r,
            translation: t,
            weights,
            iterations: 0,
        });
    }
    let mut mu = beta2 / (2.0 * rmax - beta2).max(1e-12);
    let mut prev_cost = f64::INFINITY;
    let mut iterations = 0;
    for it in 0..max_iterations {
        iterations = it + 1;
        let lo = mu / (mu + 1.0) * beta2;
        let hi = (mu + 1.0) / mu * beta2;
        for (w, &r2) in weights.iter_mut().zip(&res) {
            *w = if r2 <= lo {
                1.0
            } else if r2 >= hi {
                0.0
            } else {
                (beta / r2.sqrt() * (mu * (mu + 1.0)).sqrt() - mu).clamp(0.0, 1.0)
            };
        }
        let Some((rn, tn)) = weighted_rigid(source, target, &weights) else {
            break;
        };
        r = rn;
        t = tn;
        res = residuals(&r, &t);
        let cost: f64 = res.iter().map(|&r2| r2.min(beta2)).sum();
        let binary = weights.iter().all(|&w| !(1e-6..=1.0 - 1e-6).contains(&w));
        if binary && (prev_cost - cost).abs() <= 1e-12 * cost.max(1e-300) {
            break;
        }
        prev_cost = cost;
        mu *= 1.4;
    }
    // Final weights: the TLS inliers of the last estimate.
    for (w, &r2) in weights.iter_mut().zip(&res) {
        *w = if r2 <= beta2 { 1.0 } else { 0.0 };
    }
    Some(GncResult {
        rotation: r,
        translation: t,
        weights,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lie::se3_exp;

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn recovers_the_pose_with_half_outliers() {
        let truth = se3_exp(Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.4, -1.1, 2.0));
        let mut st = 7u64;
        let (mut s, mut q) = (Vec::new(), Vec::new());
        for i in 0..200 {
            let p = Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)) * 10.0;
            s.push(p);
            if i % 2 == 0 {
                q.push(
                    truth.apply(p)
                        + Vector3::new(lcg(&mut st) - 0.5, lcg(&mut st) - 0.5, 0.0) * 0.02,
                );
            } else {
                q.push(Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)) * 10.0);
            }
        }
        let out = gnc_tls(&s, &q, 0.05, 100).unwrap();
        assert!((out.rotation - truth.r).abs().max() < 5e-3, "{out:?}");
        assert!((out.translation - truth.t).norm() < 0.05);
        let inliers = out.weights.iter().filter(|&&w| w > 0.5).count();
        assert!((100..=103).contains(&inliers), "{inliers}");
    }

    #[test]
    fn collinear_points_have_no_rotation() {
        let s: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(weighted_rigid(&s, &s, &[1.0; 5]).is_none());
    }
}
