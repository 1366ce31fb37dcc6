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

/// How the 2D sampling term finds a point's neighbouring samples
/// ([`sampling_system`], chosen by [`sampling_model`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SamplingModel {
    /// One scan from its origin: the points in order of their bearing are the beams.
    Sweep,
    /// Anything else (a map, merged submaps, points sampled along surfaces): a point's
    /// neighbouring samples are its nearest neighbours on either side along its surface.
    Cloud,
}

/// A source is not one scan when both: its input order is no single sweep (the bearing's
/// total travel from point to point, in input order, more than [`SWEEP_MAX_TRAVEL`] times the
/// angular span it covers), and points lie behind points along a bearing (pairs next to each
/// other in bearing order less than half the median bearing step apart, their ranges more
/// than [`BEHIND_RANGE_STEPS`] median steps apart: at least [`BEHIND_MIN_PAIRS`] and
/// [`BEHIND_MIN_FRACTION`] of the points).
///
/// A scan from one viewpoint, in beam order, travels its field of view once (Intel, ACES,
/// hospital and MbICP scans: 1.00–1.47 even with the points moved 0.2 m off their sensor,
/// the split-beam pairs, whose near clutter then swings back and forth in bearing) and has no
/// point behind another (a beam stops at the first surface), though moved off its sensor it
/// may (MbICP split-beam halves: up to 19 of 167). Six scans merged travel 6×, points
/// sampled along walls ~50×; a room sampled along its walls with an obstacle has a pair
/// behind at nearly every point of the obstacle's sector (5–44 at 0.1–0.02 m spacing).
pub const SWEEP_MAX_TRAVEL: f64 = 2.0;
/// See [`SWEEP_MAX_TRAVEL`].
pub const BEHIND_MIN_PAIRS: usize = 3;
/// See [`SWEEP_MAX_TRAVEL`].
pub const BEHIND_MIN_FRACTION: f64 = 0.01;
/// See [`SWEEP_MAX_TRAVEL`].
pub const BEHIND_RANGE_STEPS: f64 = 5.0;

/// Whether the input order is one sweep (see [`SWEEP_MAX_TRAVEL`]): the bearing's travel
/// from point to point (each step wrapped to `(−π, π]`) against the span of the sorted
/// bearings (2π less the widest gap between neighbours).
fn one_sweep_in_order(bearing: &[f64], order: &[usize]) -> bool {
    use std::f64::consts::{PI, TAU};
    let n = bearing.len();
    if n < 3 {
        return true;
    }
    let travel: f64 = bearing
        .windows(2)
        .map(|w| {
            let d = (w[1] - w[0] + PI).rem_euclid(TAU) - PI;
            d.abs()
        })
        .sum();
    let (first, last) = (bearing[order[0]], bearing[order[n - 1]]);
    let widest = order
        .windows(2)
        .map(|w| bearing[w[1]] - bearing[w[0]])
        .fold(first + TAU - last, f64::max);
    travel <= SWEEP_MAX_TRAVEL * (TAU - widest)
}

/// The source's points in order of their bearing from its origin (stable: points at the same
/// bearing keep their input order, the reference's argsort) and each point's bearing.
fn bearing_order(source: &[f64], n: usize) -> (Vec<usize>, Vec<f64>) {
    // Each bearing once (the comparator computed two per comparison).
    let bearing: Vec<f64> = (0..n)
        .map(|i| source[2 * i + 1].atan2(source[2 * i]))
        .collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| bearing[i].total_cmp(&bearing[j]));
    (order, bearing)
}

fn median(mut v: Vec<f64>) -> f64 {
    let m = v.len();
    if m == 0 {
        return f64::NAN;
    }
    let (_, &mut hi, _) = v.select_nth_unstable_by(m / 2, f64::total_cmp);
    if m % 2 == 1 {
        hi
    } else {
        let lo = v[..m / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (lo + hi) / 2.0
    }
}

/// How many pairs of bearing neighbours lie one behind the other (see [`BEHIND_MIN_PAIRS`]),
/// given the bearing order.
fn count_behind(source: &[f64], order: &[usize], bearing: &[f64]) -> usize {
    let range = |i: usize| source[2 * i].hypot(source[2 * i + 1]);
    let angular: Vec<f64> = order
        .windows(2)
        .map(|w| bearing[w[1]] - bearing[w[0]])
        .collect();
    let step = median(angular.iter().copied().filter(|&a| a > 1e-9).collect());
    let spacing = median(
        order
            .windows(2)
            .map(|w| {
                let (a, b) = (w[0], w[1]);
                (source[2 * b] - source[2 * a]).hypot(source[2 * b + 1] - source[2 * a + 1])
            })
            .collect(),
    );
    if !(step.is_finite() && spacing.is_finite()) {
        return 0;
    }
    order
        .windows(2)
        .zip(&angular)
        .filter(|(w, &a)| {
            a < 0.5 * step && (range(w[1]) - range(w[0])).abs() > BEHIND_RANGE_STEPS * spacing
        })
        .count()
}

/// Whether a 2D source is one scan from its origin ([`SamplingModel::Sweep`]) or not
/// ([`SamplingModel::Cloud`]: no single sweep in input order, and points behind points
/// along a bearing, [`SWEEP_MAX_TRAVEL`]).
/// One sort of the bearings and one pass; `Sweep` with fewer than 3 points or in 3D.
pub fn sampling_model(source: &[f64], dim: usize) -> SamplingModel {
    let n = source.len() / dim.max(1);
    if dim != 2 || n < 3 {
        return SamplingModel::Sweep;
    }
    let (order, bearing) = bearing_order(source, n);
    model_of(source, &order, &bearing)
}

fn model_of(source: &[f64], order: &[usize], bearing: &[f64]) -> SamplingModel {
    if one_sweep_in_order(bearing, order) {
        return SamplingModel::Sweep;
    }
    let behind = count_behind(source, order, bearing);
    let least = BEHIND_MIN_PAIRS.max((BEHIND_MIN_FRACTION * order.len() as f64).ceil() as usize);
    if behind >= least {
        SamplingModel::Cloud
    } else {
        SamplingModel::Sweep
    }
}

/// [`sampling_system`]'s result: `H` and `M`, row-major `3 × 3`, the model used and the mean
/// step along the surfaces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplingSystem {
    pub hessian: [f64; 9],
    pub meat: [f64; 9],
    pub model: SamplingModel,
    pub mean_step: f64,
    /// The per-coordinate noise of the points about their surfaces, from the bends along it
    /// ([`surface_noise`]); NaN with fewer than 3 points stepped on both sides.
    pub surface_noise: f64,
}

/// Per-coordinate noise variance of points about their surface from each point's bend
/// `b_i = m_i · ((p_prev + p_next)/2 − p_i)` (variance `1.5 σ²` for independent noise on a
/// straight surface): `median(b²) / median(χ²₁) / 1.5`, so that corners and clutter, a
/// minority, do not enter. Neighbours chosen as the nearest on either side read a little less
/// than the noise where it is not small against the step: a bound the association's hidden
/// noise is kept under ([`super::association`]).
fn surface_noise(mut bends: Vec<f64>) -> f64 {
    if bends.len() < 3 {
        return f64::NAN;
    }
    let mid = bends.len() / 2;
    let (_, &mut median, _) = bends.select_nth_unstable_by(mid, f64::total_cmp);
    median / super::association::MEDIAN_CHI2_1 / 1.5
}

/// A point's sampling step `(s, back, ahead, bend)` from its rank in bearing order, its index
/// and its target normal in the source frame (None: no neighbours to step to); `bend`, with a
/// neighbour on either side, is their midpoint less the point.
type StepOf<'a> = dyn Fn(usize, usize, [f64; 2]) -> Option<Step> + 'a;
type Step = ([f64; 2], f64, f64, Option<[f64; 2]>);

/// Neighbours searched per point for [`SamplingModel::Cloud`]'s samples on either side.
const CLOUD_NEIGHBOURS: usize = 8;

/// [`SamplingModel::Cloud`]'s `M` relative to a scan's: independent samplings of a surface
/// fall anywhere within a step of each other (a uniform phase, variance 1/12 step²), where
/// the two halves of one scan's beams interleave half a step apart (the ¼ step² of
/// [`super::covariance::SAMPLING_PHASE_VARIANCE`]).
const CLOUD_PHASE_RATIO: f64 = 1.0 / 3.0;

/// 2D: the sampling system `(H, M)`, each `3 × 3` row-major over `[ρx, ρy, θ]`, of the
/// source's sampling (`TrustInputs.sampling_system` in `scanreg.trust`), and the model used.
///
/// The points are samples of the surfaces one sampling step apart; the other scan sampled
/// them elsewhere. Moving point `i`'s sample one step along its surface,
/// `s_i = (p_next − p_prev) / 2`, changes its point-to-line residual by `e_i = m_i · s_i`
/// (`m_i = Rᵀ n_i`, its target normal in the source frame): zero along a straight wall, up
/// to the step on clutter, corners and edges. `H = Σ J_i J_iᵀ` over the matched points
/// (`correspondences[i] ≥ 0`) and `M = Σ J_i J_iᵀ e_i²` over those with a step, with the
/// point-to-line Jacobian `J_i = [m_i, m_i · p_i^⊥]`. `normals` are the target's (`normal_of(j)` for target row `j`).
///
/// Which samples are a point's neighbours depends on what the source is ([`sampling_model`]).
/// One scan from its origin (the sensor): its neighbours in bearing order, the beams next to
/// it (the beam phase); an edge (one long step across a depth jump, one short along its
/// surface) stays: where it falls is what the beam phase decides. A cloud that is not one
/// scan (points behind points along a bearing: a map, merged submaps): taking bearing order
/// there made every point of an obstacle and the wall behind it a depth jump (a room sampled
/// along its walls: mean NEES 0.2–0.5 against 3); its neighbours are instead the nearest
/// samples on either side of it along its surface (the direction normal to `m_i`, among its
/// [`CLOUD_NEIGHBOURS`] nearest), one-sided (`s_i = p_next − p_i`) at a free end, with the
/// phase of independent samplings ([`CLOUD_PHASE_RATIO`]). A point
/// whose steps to both neighbours are longer than `max_step` (half the gate) is left out: a
/// wall seen at grazing incidence, along which moving a sample changes nothing but where the
/// target's normal, fitted over a stretch longer than the wall is wide, is not the wall's.
/// Also the stepped points' mean step along their surface, `|m_i^⊥ · s_i|`: the sampling step
/// [`super::association`] reads the hidden noise against.
/// None with fewer than 3 matched points or in 3D.
pub fn sampling_system(
    source: &[f64],
    dim: usize,
    correspondences: &[i64],
    rotation: &[f64],
    max_step: f64,
    normal_of: impl Fn(usize) -> Option<[f64; 2]>,
) -> Option<SamplingSystem> {
    let n = source.len() / dim.max(1);
    if dim != 2 || n < 3 || correspondences.len() != n || rotation.len() < 4 {
        return None;
    }
    let (order, bearing) = bearing_order(source, n);
    let model = model_of(source, &order, &bearing);
    let pt = |i: usize| [source[2 * i], source[2 * i + 1]];
    let dist = |a: [f64; 2], b: [f64; 2]| (b[0] - a[0]).hypot(b[1] - a[1]);
    let bend = |a: [f64; 2], p: [f64; 2], b: [f64; 2]| {
        [0.5 * (a[0] + b[0]) - p[0], 0.5 * (a[1] + b[1]) - p[1]]
    };
    // Per point: `(s, back, ahead)`, its sampling step and the distances to its neighbours.
    let steps: Box<StepOf<'_>> = match model {
        SamplingModel::Sweep => {
            // `step[k]`: from the k-th point in bearing order to the next; a point's step
            // back is its predecessor's step ahead, each taken once.
            let step: Vec<f64> = order.windows(2).map(|w| dist(pt(w[0]), pt(w[1]))).collect();
            let order = &order;
            Box::new(move |k: usize, _i: usize, _m: [f64; 2]| {
                if k == 0 || k == n - 1 {
                    return None;
                }
                let (prev, next) = (pt(order[k - 1]), pt(order[k + 1]));
                let s = [0.5 * (next[0] - prev[0]), 0.5 * (next[1] - prev[1])];
                Some((
                    s,
                    step[k - 1],
                    step[k],
                    Some(bend(prev, pt(order[k]), next)),
                ))
            })
        }
        SamplingModel::Cloud => {
            let tree = KdTree::build(source, dim).ok()?;
            let buf = std::cell::RefCell::new(Vec::with_capacity(CLOUD_NEIGHBOURS + 2));
            Box::new(move |_k: usize, i: usize, m: [f64; 2]| {
                let p = pt(i);
                let tangent = [-m[1], m[0]];
                let mut buf = buf.borrow_mut();
                buf.clear();
                tree.knn_into(&p, CLOUD_NEIGHBOURS + 1, f64::INFINITY, &mut buf);
                let (mut prev, mut next) = (None, None);
                for &(j, _) in buf.iter() {
                    let q = pt(j as usize);
                    if j as usize == i || (q[0] == p[0] && q[1] == p[1]) {
                        continue;
                    }
                    let along = (q[0] - p[0]) * tangent[0] + (q[1] - p[1]) * tangent[1];
                    if along < 0.0 {
                        prev = prev.or(Some(q));
                    } else {
                        next = next.or(Some(q));
                    }
                }
                match (prev, next) {
                    (Some(a), Some(b)) => Some((
                        [0.5 * (b[0] - a[0]), 0.5 * (b[1] - a[1])],
                        dist(a, p),
                        dist(p, b),
                        Some(bend(a, p, b)),
                    )),
                    (Some(a), None) => {
                        Some(([p[0] - a[0], p[1] - a[1]], dist(a, p), f64::INFINITY, None))
                    }
                    (None, Some(b)) => {
                        Some(([b[0] - p[0], b[1] - p[1]], f64::INFINITY, dist(p, b), None))
                    }
                    (None, None) => None,
                }
            })
        }
    };
    let mut h = [0.0; 9];
    let mut h_all = [0.0; 9];
    let mut m = [0.0; 9];
    let mut count = 0usize;
    let mut along = 0.0;
    let mut bends = Vec::new();
    for (k, &i) in order.iter().enumerate() {
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
        let (px, py) = (source[2 * i], source[2 * i + 1]);
        let jac = [mx, my, -mx * py + my * px];
        for r in 0..3 {
            for c in 0..3 {
                h_all[3 * r + c] += jac[r] * jac[c];
            }
        }
        let Some(([sx, sy], back, ahead, bent)) = steps(k, i, [mx, my]) else {
            continue;
        };
        if back.min(ahead) > max_step {
            continue;
        }
        let e = mx * sx + my * sy;
        let e2 = e * e;
        along += (my * sx - mx * sy).abs();
        if let Some([bx, by]) = bent {
            bends.push((mx * bx + my * by).powi(2));
        }
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
    if model == SamplingModel::Cloud {
        m = m.map(|v| v * CLOUD_PHASE_RATIO);
    }
    if misses_a_direction(&h, &h_all) {
        h = h_all;
    }
    Some(SamplingSystem {
        hessian: h,
        meat: m,
        model,
        mean_step: along / count as f64,
        surface_noise: surface_noise(bends),
    })
}

/// Whether the stepped points' `H` leaves out a direction every matched point's `H_all`
/// constrains (the least generalised eigenvalue of the pair below [`MIN_STEPPED_SHARE`]).
/// The sampling term's `A⁻¹` is then taken from `H_all`: the stepped points alone were
/// singular where only one wall's points had neighbours close enough (a hospital split-beam
/// pair: σ 4·10⁷ m along the corridor). Otherwise the stepped points' own `H`, on which the
/// term was calibrated (taking `H_all` everywhere made it 2–5× over-confident on the
/// split-beam pairs: grazing walls carry much of `H_all` and none of `M`).
fn misses_a_direction(h: &[f64; 9], h_all: &[f64; 9]) -> bool {
    use super::dense::{eigh, from_rows, scale_columns};
    let (vals, vecs) = eigh(&from_rows(3, h_all));
    if vals[0] <= 0.0 {
        return false; // nothing better to fall back on
    }
    let inv_root = scale_columns(&vecs, &vals.map(|v| 1.0 / v.sqrt()));
    let (w, _) = eigh(&(inv_root.transpose() * from_rows(3, h) * &inv_root));
    w[0] < MIN_STEPPED_SHARE
}

/// See [`misses_a_direction`].
const MIN_STEPPED_SHARE: f64 = 1e-3;

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
    fn a_scan_is_a_sweep_and_a_room_sampled_around_an_obstacle_is_not() {
        // A scan from the origin of a 4 m ring with a post in front: beam order, one sweep.
        let mut scan = Vec::new();
        for k in 0..360 {
            let a = (k as f64).to_radians();
            let r = if (10..20).contains(&k) { 1.0 } else { 4.0 };
            scan.extend([r * a.cos(), r * a.sin()]);
        }
        assert_eq!(sampling_model(&scan, 2), SamplingModel::Sweep);
        // The same points with the ring's far side (behind the post) sampled too and the
        // order interleaved: not one scan.
        let mut cloud = Vec::new();
        for k in 0..360 {
            let j = (k * 97) % 360; // a scrambled order
            let a = (j as f64).to_radians();
            cloud.extend([4.0 * a.cos(), 4.0 * a.sin()]);
            if (10..20).contains(&j) {
                let b = a + 0.3f64.to_radians();
                cloud.extend([1.0 * b.cos(), 1.0 * b.sin()]);
            }
        }
        assert_eq!(sampling_model(&cloud, 2), SamplingModel::Cloud);
        // Scrambled alone (nothing behind anything): still taken as one scan.
        let scrambled: Vec<f64> = (0..360)
            .flat_map(|k| {
                let a = (((k * 97) % 360) as f64).to_radians();
                [4.0 * a.cos(), 4.0 * a.sin()]
            })
            .collect();
        assert_eq!(sampling_model(&scrambled, 2), SamplingModel::Sweep);
    }

    #[test]
    fn stepped_points_missing_a_direction_fall_back_on_every_point() {
        let all = [2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 3.0];
        // Only x and θ among the stepped points: y is every matched point's alone.
        let stepped = [1.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0];
        assert!(misses_a_direction(&stepped, &all));
        let most = [1.5, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 2.0];
        assert!(!misses_a_direction(&most, &all));
    }

    #[test]
    fn a_straight_wall_has_no_sampling_error_and_a_zigzag_has() {
        let eye = [1.0, 0.0, 0.0, 1.0];
        let corr: Vec<i64> = vec![0; 40];
        // A wall at y = 2, normal (0, 1): moving a sample along it changes no residual.
        let wall: Vec<f64> = (0..40).flat_map(|i| [i as f64 * 0.1 - 2.0, 2.0]).collect();
        let sys = sampling_system(&wall, 2, &corr, &eye, 1.0, |_| Some([0.0, 1.0])).unwrap();
        assert_eq!(sys.model, SamplingModel::Sweep);
        assert!(sys.hessian[4] > 37.0 && sys.meat.iter().all(|v| v.abs() < 1e-24));
        assert!((sys.mean_step - 0.1).abs() < 1e-12);
        assert!(sys.surface_noise.abs() < 1e-24);
        // Every third point 5 cm off the wall (clutter): a step crosses the surface.
        let zig: Vec<f64> = (0..40)
            .flat_map(|i| [i as f64 * 0.1 - 2.0, 2.0 + 0.05 * f64::from(i % 3 == 0)])
            .collect();
        let sys = sampling_system(&zig, 2, &corr, &eye, 1.0, |_| Some([0.0, 1.0])).unwrap();
        assert!(sys.meat[4] > 0.0);
        assert!(sampling_system(&wall, 3, &corr, &eye, 1.0, |_| None).is_none());
        let axis = smallest_axis_2d(&[4.0, 0.0, 0.0, 0.01]);
        assert!((axis[0].abs() - 0.0).abs() < 1e-12 && (axis[1].abs() - 1.0).abs() < 1e-12);
    }
}
