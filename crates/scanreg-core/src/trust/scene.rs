//! Per-point quantities of the source the trust analysis reads: the rotation levers, the
//! length scale, the 2D beam phase and its sampling system, and the gate-wide prior built from them. Sums are numpy's
//! pairwise sums (the Python reference's `np.mean`), so the two agree to the last bits.

use crate::knn::KdTree;
use crate::reduce::SEQUENTIAL_MAX;
use rayon::prelude::*;

/// numpy's pairwise summation of a contiguous run (`pairwise_sum` in its umath loops): blocks of
/// at most 128 summed with eight accumulators, larger runs split in halves at a multiple of 8.
pub fn pairwise_sum(a: &[f64]) -> f64 {
    let n = a.len();
    if n < 8 {
        let mut res = 0.0;
        for &x in a {
            res += x;
        }
        res
    } else if n <= 128 {
        let mut r = [a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]];
        let mut i = 8;
        while i < n - (n % 8) {
            for k in 0..8 {
                r[k] += a[i + k];
            }
            i += 8;
        }
        let mut res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        while i < n {
            res += a[i];
            i += 1;
        }
        res
    } else {
        let mut n2 = n / 2;
        n2 -= n2 % 8;
        pairwise_sum(&a[..n2]) + pairwise_sum(&a[n2..])
    }
}

fn mean(a: &[f64]) -> f64 {
    pairwise_sum(a) / a.len() as f64
}

/// RMS distance of the points from each rotation axis through the origin (≥ 1e-9): one lever
/// in 2D, three in 3D.
pub fn rotation_levers(points: &[f64], dim: usize) -> Vec<f64> {
    let n = points.len() / dim;
    let sq: Vec<f64> = points.iter().map(|x| x * x).collect();
    let total: Vec<f64> = (0..n)
        .map(|i| {
            let r = &sq[i * dim..(i + 1) * dim];
            if dim == 2 {
                r[0] + r[1]
            } else {
                r[0] + r[1] + r[2]
            }
        })
        .collect();
    let levers: Vec<f64> = if dim == 2 {
        vec![mean(&total).sqrt()]
    } else {
        (0..3)
            .map(|a| {
                let v: Vec<f64> = (0..n).map(|i| total[i] - sq[i * 3 + a]).collect();
                mean(&v).sqrt()
            })
            .collect()
    };
    levers.into_iter().map(|l| l.max(1e-9)).collect()
}

/// RMS distance of the points from their centroid (the conditioning's rotation lever).
pub fn length_scale(points: &[f64], dim: usize) -> f64 {
    let n = points.len() / dim;
    let mut centre = [0.0; 3];
    for i in 0..n {
        for d in 0..dim {
            centre[d] += points[i * dim + d];
        }
    }
    for c in centre.iter_mut().take(dim) {
        *c /= n as f64;
    }
    let r2: Vec<f64> = (0..n)
        .map(|i| {
            let mut s = 0.0;
            for d in 0..dim {
                let e = points[i * dim + d] - centre[d];
                s += e * e;
            }
            s
        })
        .collect();
    mean(&r2).sqrt()
}

/// 2D: `Δα²/12` for the median angular step `Δα` between neighbouring points seen from the
/// origin (the sensor); 0 in 3D, or with fewer than 3 points or no step above 1e-9 rad.
pub fn beam_phase_variance(points: &[f64], dim: usize) -> f64 {
    let n = points.len() / dim;
    if dim != 2 || n < 3 {
        return 0.0;
    }
    let mut angles: Vec<f64> = (0..n)
        .map(|i| points[2 * i + 1].atan2(points[2 * i]))
        .collect();
    angles.sort_by(f64::total_cmp);
    let mut steps: Vec<f64> = angles
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|&s| s > 1e-9)
        .collect();
    if steps.is_empty() {
        return 0.0;
    }
    steps.sort_by(f64::total_cmp);
    let m = steps.len();
    let step = if m % 2 == 1 {
        steps[m / 2]
    } else {
        (steps[m / 2 - 1] + steps[m / 2]) / 2.0
    };
    step * step / 12.0
}

/// Median distance from each point of `tree` to its nearest other point (one 2-NN pass); NaN
/// with fewer than 2 points. How densely a cloud samples its surfaces: the 2D sampling term
/// scales with the target's spacing relative to the source's.
pub fn median_spacing(tree: &KdTree) -> f64 {
    let n = tree.len();
    let nearest = |buf: &mut Vec<(u32, f64)>, i: usize| {
        buf.clear();
        tree.knn_into(tree.point(i), 2, f64::INFINITY, buf);
        buf.get(1).map_or(f64::NAN, |&(_, d)| d)
    };
    let d2: Vec<f64> = if n <= SEQUENTIAL_MAX {
        let mut buf = Vec::with_capacity(3);
        (0..n).map(|i| nearest(&mut buf, i)).collect()
    } else {
        (0..n)
            .into_par_iter()
            .map_init(|| Vec::with_capacity(3), nearest)
            .collect()
    };
    median_of_squared(d2)
}

/// `√median(d2)` as numpy takes a median (the mean of the middle two of an even count); NaN
/// with fewer than 2 values or a NaN among them.
pub fn median_of_squared(mut d2: Vec<f64>) -> f64 {
    let m = d2.len();
    if m < 2 || d2.iter().any(|v| v.is_nan()) {
        return f64::NAN;
    }
    let (_, &mut hi, _) = d2.select_nth_unstable_by(m / 2, f64::total_cmp);
    let mid = if m % 2 == 1 {
        hi
    } else {
        // The largest of the lower half.
        let lo = d2[..m / 2]
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        (lo + hi) / 2.0
    };
    mid.sqrt()
}

/// The direction of least spread of a 2×2 covariance `[a, b; b, c]` (row-major), unit length:
/// the normal a GICP target carries in its covariance.
pub fn smallest_axis_2d(cov: &[f64]) -> [f64; 2] {
    let (a, b, c) = (cov[0], 0.5 * (cov[1] + cov[2]), cov[3]);
    let half = 0.5 * (a - c);
    let lam = 0.5 * (a + c) - (half * half + b * b).sqrt();
    // Two forms of the same eigenvector; the longer one is the well-conditioned one.
    let (u, v) = ([b, lam - a], [lam - c, b]);
    let nu = u[0].hypot(u[1]);
    let nv = v[0].hypot(v[1]);
    let (w, n) = if nu >= nv { (u, nu) } else { (v, nv) };
    if n > 0.0 && n.is_finite() {
        [w[0] / n, w[1] / n]
    } else {
        [0.0, 1.0]
    }
}

/// 2D: the sampling system `(H, M)`, each `3 × 3` row-major over `[ρx, ρy, θ]`, of the
/// source's beam phase (`TrustInputs.sampling_system` in `scanreg.trust`).
///
/// The points, taken in the order of their bearing from the source origin (the sensor), are
/// samples of the surfaces one beam step apart; the other scan sampled them elsewhere. Moving
/// point `i`'s sample one step along the scan, `s_i = (p_{i+1} − p_{i−1}) / 2`, changes its
/// point-to-line residual by `e_i = m_i · s_i` (`m_i = Rᵀ n_i`, its target normal in the
/// source frame): zero along a straight wall, up to the step on clutter, corners and edges.
/// `H = Σ J_i J_iᵀ` and `M = Σ J_i J_iᵀ e_i²` with the point-to-line Jacobian
/// `J_i = [m_i, m_i · p_i^⊥]` over the matched points (`correspondences[i] ≥ 0`) with both
/// neighbours. `normals` are the target's (`normal_of(j)` for target row `j`). A point whose
/// steps to both neighbours are longer than `max_step` (half the gate) is left out: a wall
/// seen at grazing incidence, along which moving a sample changes nothing but where the
/// target's normal, fitted over a stretch longer than the wall is wide, is not the wall's.
/// An edge (one long step across a depth jump, one short along its surface) stays: where it
/// falls is what the beam phase decides. None with fewer than 3 matched points or in 3D.
pub fn sampling_system(
    source: &[f64],
    dim: usize,
    correspondences: &[i64],
    rotation: &[f64],
    max_step: f64,
    normal_of: impl Fn(usize) -> Option<[f64; 2]>,
) -> Option<([f64; 9], [f64; 9])> {
    let n = source.len() / dim.max(1);
    if dim != 2 || n < 3 || correspondences.len() != n || rotation.len() < 4 {
        return None;
    }
    // Each bearing once (the comparator computed two per comparison).
    let bearing: Vec<f64> = (0..n)
        .map(|i| source[2 * i + 1].atan2(source[2 * i]))
        .collect();
    let mut order: Vec<usize> = (0..n).collect();
    // Stable: points at the same bearing keep their input order (the reference's argsort).
    order.sort_by(|&i, &j| bearing[i].total_cmp(&bearing[j]));
    // `step[k]`: from the k-th point in bearing order to the next; a point's step back is its
    // predecessor's step ahead (the same differences, so the same `hypot`), each taken once.
    let step: Vec<f64> = order
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            (source[2 * b] - source[2 * a]).hypot(source[2 * b + 1] - source[2 * a + 1])
        })
        .collect();
    let mut h = [0.0; 9];
    let mut m = [0.0; 9];
    let mut count = 0usize;
    for k in 1..n - 1 {
        let i = order[k];
        let Ok(j) = usize::try_from(correspondences[i]) else {
            continue;
        };
        let Some(nt) = normal_of(j) else {
            continue;
        };
        if !(nt[0].is_finite() && nt[1].is_finite()) {
            continue; // a target point without a normal (`drop_linear`)
        }
        // m = Rᵀ n (R row-major).
        let mx = rotation[0] * nt[0] + rotation[2] * nt[1];
        let my = rotation[1] * nt[0] + rotation[3] * nt[1];
        let (prev, next) = (order[k - 1], order[k + 1]);
        let sx = 0.5 * (source[2 * next] - source[2 * prev]);
        let sy = 0.5 * (source[2 * next + 1] - source[2 * prev + 1]);
        let (back, ahead) = (step[k - 1], step[k]);
        if back.min(ahead) > max_step {
            continue;
        }
        let e = mx * sx + my * sy;
        let (px, py) = (source[2 * i], source[2 * i + 1]);
        let jac = [mx, my, -mx * py + my * px];
        let e2 = e * e;
        for r in 0..3 {
            for c in 0..3 {
                let v = jac[r] * jac[c];
                h[3 * r + c] += v;
                m[3 * r + c] += v * e2;
            }
        }
        count += 1;
    }
    if count < 3 {
        return None;
    }
    Some((h, m))
}

/// The gate-wide prior of the initial guess: `diag(δ², …, (δ/L_a)², …) / 3` with `δ` the gate
/// (the RMS lever when the gate is infinite), row-major.
pub fn default_prior(dim: usize, levers: &[f64], gate: f64) -> Vec<f64> {
    let g = if gate.is_finite() {
        gate
    } else {
        let sq: Vec<f64> = levers.iter().map(|l| l * l).collect();
        mean(&sq).sqrt()
    };
    let dof = dim + levers.len();
    let mut out = vec![0.0; dof * dof];
    for i in 0..dof {
        let v = if i < dim {
            g * g
        } else {
            let r = g / levers[i - dim];
            r * r
        };
        out[i * dof + i] = v / 3.0;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levers_and_phase_of_a_ring() {
        let n = 360;
        let pts: Vec<f64> = (0..n)
            .flat_map(|i| {
                let a = (i as f64).to_radians();
                [2.0 * a.cos(), 2.0 * a.sin()]
            })
            .collect();
        assert!((rotation_levers(&pts, 2)[0] - 2.0).abs() < 1e-12);
        assert!((length_scale(&pts, 2) - 2.0).abs() < 1e-12);
        let step = 1f64.to_radians();
        assert!((beam_phase_variance(&pts, 2) - step * step / 12.0).abs() < 1e-15);
        let sum: f64 = pairwise_sum(&vec![0.1; 1000]);
        assert!((sum - 100.0).abs() < 1e-12);
    }

    #[test]
    fn a_straight_wall_has_no_sampling_error_and_a_zigzag_has() {
        let eye = [1.0, 0.0, 0.0, 1.0];
        let corr: Vec<i64> = vec![0; 40];
        // A wall at y = 2, normal (0, 1): moving a sample along it changes no residual.
        let wall: Vec<f64> = (0..40).flat_map(|i| [i as f64 * 0.1 - 2.0, 2.0]).collect();
        let (h, m) = sampling_system(&wall, 2, &corr, &eye, 1.0, |_| Some([0.0, 1.0])).unwrap();
        assert!(h[4] > 37.0 && m.iter().all(|v| v.abs() < 1e-24));
        // Every third point 5 cm off the wall (clutter): a step crosses the surface.
        let zig: Vec<f64> = (0..40)
            .flat_map(|i| [i as f64 * 0.1 - 2.0, 2.0 + 0.05 * f64::from(i % 3 == 0)])
            .collect();
        let (_, m) = sampling_system(&zig, 2, &corr, &eye, 1.0, |_| Some([0.0, 1.0])).unwrap();
        assert!(m[4] > 0.0);
        assert!(sampling_system(&wall, 3, &corr, &eye, 1.0, |_| None).is_none());
        let axis = smallest_axis_2d(&[4.0, 0.0, 0.0, 0.01]);
        assert!((axis[0].abs() - 0.0).abs() < 1e-12 && (axis[1].abs() - 1.0).abs() < 1e-12);
    }
}
