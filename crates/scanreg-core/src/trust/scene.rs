//! Per-point quantities of the source the trust analysis reads: the rotation levers, the
//! length scale, the 2D beam phase, and the gate-wide prior built from them. Sums are numpy's
//! pairwise sums (the Python reference's `np.mean`), so the two agree to the last bits.

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
}
