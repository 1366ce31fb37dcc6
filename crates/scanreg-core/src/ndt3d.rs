//! 3D Normal Distributions Transform, point to distribution (Magnusson 2009, ch. 6): the target
//! as one Gaussian per voxel, and the score, gradient and Hessian of a source cloud under a pose.
//!
//! * A voxel of `cell_size` with at least `min_points` target points holds their mean `μ` and
//!   sample covariance `Σ` (`/(n−1)`, accumulated about the voxel's first point so the second
//!   moments stay well conditioned far from the origin); eigenvalues below
//!   `min_eigen_ratio · λ_max` are raised to it, so a planar patch keeps an invertible `Σ`
//!   (Magnusson §6.2.1 uses 0.001; PCL 0.01).
//! * Each transformed source point scores against the Gaussians of its own voxel and its six
//!   face neighbours (Magnusson's "7 neighbouring cells", Autoware's DIRECT7): the cost stays
//!   smooth where a point crosses a voxel border.
//! * The cost is `f = −Σ_points Σ_cells exp(−½ qᵀΣ⁻¹q)`, `q = T x − μ`, over the right
//!   perturbation `T·exp(δ)`, `δ = [ρ, φ]` (the crate's tangent convention, so the information
//!   is already in the covariance's coordinates and the lever arm is the source's own origin,
//!   not the world's). To second order `exp(δ)x = x + φ×x + ½ φ×(φ×x) + ρ + ½ φ×ρ`, so with
//!   `J = ∂q/∂δ = R [I, −[x]×]` and `e = exp(−½ qᵀΣ⁻¹q)`:
//!   `∇f = Σ e · JᵀΣ⁻¹q` and
//!   `∇²f = Σ e · (JᵀΣ⁻¹J + qᵀΣ⁻¹ ∂²q/∂δ² − (JᵀΣ⁻¹q)(JᵀΣ⁻¹q)ᵀ)` (Magnusson eqs. 6.12–6.13).
//! * Sums run over fixed chunks in order, so the result does not depend on the thread count.

use crate::error::{Error, Result};
use crate::points::check_points;
use crate::reduce::chunked_sum;
use crate::symeig::sym3;
use nalgebra::{Matrix3, Vector3};
use rustc_hash::FxHashMap;

/// One voxel's Gaussian.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NdtCell3 {
    pub mean: [f64; 3],
    /// Regularised covariance, row-major 3×3.
    pub covariance: [f64; 9],
    /// Its inverse, row-major 3×3.
    pub inverse: [f64; 9],
    pub count: usize,
}

/// The voxel Gaussians of a target cloud.
#[derive(Debug, Clone)]
pub struct NdtGrid3 {
    cell_size: f64,
    cells: FxHashMap<[i64; 3], NdtCell3>,
}

/// Cost, gradient and Hessian at one pose, over the tangent `[ρ, φ]` (right perturbation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NdtEvaluation3 {
    /// `f = −Σ e` (lower is better; `−7N` at most).
    pub cost: f64,
    pub gradient: [f64; 6],
    /// Row-major 6×6 (may be indefinite where points cross voxel borders).
    pub hessian: [f64; 36],
    /// `Σ e · JᵀΣ⁻¹J`: the Gauss–Newton part (positive semi-definite; the Fisher information
    /// of the voxel Gaussians), row-major 6×6.
    pub information: [f64; 36],
    /// Source points with at least one Gaussian among their seven voxels.
    pub num_matched: usize,
}

const NEIGHBOURS: [[i64; 3]; 7] = [
    [0, 0, 0],
    [-1, 0, 0],
    [1, 0, 0],
    [0, -1, 0],
    [0, 1, 0],
    [0, 0, -1],
    [0, 0, 1],
];

/// Voxel keys beyond this magnitude would overflow neighbour arithmetic: refused.
const MAX_KEY: f64 = 4.0e15;

fn key(p: &[f64], inv: f64) -> Option<[i64; 3]> {
    let mut k = [0i64; 3];
    for (out, v) in k.iter_mut().zip(p) {
        let c = (v * inv).floor();
        if !c.is_finite() || c.abs() >= MAX_KEY {
            return None;
        }
        *out = c as i64;
    }
    Some(k)
}

impl NdtGrid3 {
    /// Build the voxel Gaussians of `target` (flat `(N, 3)`).
    pub fn build(
        target: &[f64],
        cell_size: f64,
        min_points: usize,
        min_eigen_ratio: f64,
    ) -> Result<Self> {
        check_points("target", target, 3)?;
        if target.is_empty() {
            return Err(Error::invalid("target", "is empty (0 points)"));
        }
        if !(cell_size.is_finite() && cell_size > 0.0) {
            return Err(Error::invalid(
                "cell_size",
                format!("must be finite and > 0, got {cell_size}"),
            ));
        }
        if min_points < 4 {
            return Err(Error::invalid(
                "min_points",
                format!("must be >= 4 (a 3D covariance), got {min_points}"),
            ));
        }
        if !(min_eigen_ratio.is_finite() && min_eigen_ratio > 0.0 && min_eigen_ratio <= 1.0) {
            return Err(Error::invalid(
                "min_eigen_ratio",
                format!("must be in (0, 1], got {min_eigen_ratio}"),
            ));
        }
        let inv = 1.0 / cell_size;
        // (anchor, n, Σd, Σd dᵀ upper) with d = p − anchor.
        type Moments = ([f64; 3], f64, [f64; 3], [f64; 6]);
        let mut acc: FxHashMap<[i64; 3], Moments> = FxHashMap::default();
        for p in target.chunks_exact(3) {
            let Some(k) = key(p, inv) else {
                return Err(Error::invalid(
                    "cell_size",
                    format!("{cell_size} m voxels are too small for coordinates of {p:?}"),
                ));
            };
            let e = acc
                .entry(k)
                .or_insert(([p[0], p[1], p[2]], 0.0, [0.0; 3], [0.0; 6]));
            let d = [p[0] - e.0[0], p[1] - e.0[1], p[2] - e.0[2]];
            e.1 += 1.0;
            for (sum, di) in e.2.iter_mut().zip(d) {
                *sum += di;
            }
            let s = &mut e.3;
            s[0] += d[0] * d[0];
            s[1] += d[0] * d[1];
            s[2] += d[0] * d[2];
            s[3] += d[1] * d[1];
            s[4] += d[1] * d[2];
            s[5] += d[2] * d[2];
        }
        let cells = acc
            .into_iter()
            .filter_map(|(k, (anchor, n, sum, s))| {
                if (n as usize) < min_points {
                    return None;
                }
                let m = [sum[0] / n, sum[1] / n, sum[2] / n];
                let c = |a: usize, b: usize, v: f64| (v - n * m[a] * m[b]) / (n - 1.0);
                let cov = [
                    c(0, 0, s[0]),
                    c(0, 1, s[1]),
                    c(0, 2, s[2]),
                    c(0, 1, s[1]),
                    c(1, 1, s[3]),
                    c(1, 2, s[4]),
                    c(0, 2, s[2]),
                    c(1, 2, s[4]),
                    c(2, 2, s[5]),
                ];
                let (covariance, inverse) = regularise(&cov, min_eigen_ratio)?;
                Some((
                    k,
                    NdtCell3 {
                        mean: [anchor[0] + m[0], anchor[1] + m[1], anchor[2] + m[2]],
                        covariance,
                        inverse,
                        count: n as usize,
                    },
                ))
            })
            .collect();
        Ok(NdtGrid3 { cell_size, cells })
    }

    pub fn cell_size(&self) -> f64 {
        self.cell_size
    }

    pub fn num_cells(&self) -> usize {
        self.cells.len()
    }

    /// Every cell, in voxel-key order (deterministic).
    pub fn cells(&self) -> Vec<NdtCell3> {
        let mut keys: Vec<&[i64; 3]> = self.cells.keys().collect();
        keys.sort();
        keys.into_iter().map(|k| self.cells[k]).collect()
    }

    /// Cost, gradient and Hessian of `source` (flat `(N, 3)`) at `pose` (row-major 4×4).
    pub fn evaluate(&self, source: &[f64], pose: &[f64]) -> Result<NdtEvaluation3> {
        let n = check_points("source", source, 3)?;
        if pose.len() != 16 || !pose.iter().all(|v| v.is_finite()) {
            return Err(Error::invalid(
                "pose",
                "expected a finite row-major 4x4 matrix",
            ));
        }
        let r = Matrix3::new(
            pose[0], pose[1], pose[2], pose[4], pose[5], pose[6], pose[8], pose[9], pose[10],
        );
        let t = Vector3::new(pose[3], pose[7], pose[11]);
        let inv_size = 1.0 / self.cell_size;
        let identity = NdtEvaluation3 {
            cost: 0.0,
            gradient: [0.0; 6],
            hessian: [0.0; 36],
            information: [0.0; 36],
            num_matched: 0,
        };
        let out = chunked_sum(
            n,
            identity,
            |range| {
                let mut acc = identity;
                for idx in range {
                    let x = Vector3::new(source[3 * idx], source[3 * idx + 1], source[3 * idx + 2]);
                    let y = r * x + t;
                    let Some(k) = key(y.as_slice(), inv_size) else {
                        continue;
                    };
                    let xh = hat(&x);
                    let mut matched = false;
                    for off in NEIGHBOURS {
                        let nk = [k[0] + off[0], k[1] + off[1], k[2] + off[2]];
                        let Some(cell) = self.cells.get(&nk) else {
                            continue;
                        };
                        matched = true;
                        accumulate(&mut acc, cell, &y, &x, &r, &xh);
                    }
                    acc.num_matched += matched as usize;
                }
                acc
            },
            |mut a, b| {
                a.cost += b.cost;
                for i in 0..6 {
                    a.gradient[i] += b.gradient[i];
                }
                for i in 0..36 {
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

/// `[v]×`, the cross-product matrix.
#[inline]
fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v[2], v[1], v[2], 0.0, -v[0], -v[1], v[0], 0.0)
}

/// One point against one Gaussian: adds its cost, gradient, Hessian and information.
///
/// In the body frame, with `M = RᵀΣ⁻¹R`, `w = RᵀΣ⁻¹q` and `X = [x]×` (so `J = R [I, −X]`):
/// `JᵀΣ⁻¹q = [w, x × w]`, `JᵀΣ⁻¹J = [[M, −MX], [XM, −XMX]]`, and the second-order term
/// `qᵀΣ⁻¹ ∂²q/∂δ²` is 0 for two translations, `−½[w]×` for (rotation, translation) (from
/// `½ wᵀ(e_a × e_b)`) and `½(x wᵀ + w xᵀ) − (w·x) I` for two rotations (from
/// `½ wᵀ(e_a×(e_b×x) + e_b×(e_a×x))`). Block products instead of 21 pairs of column
/// products: the evaluation took 2-3× longer that way.
fn accumulate(
    acc: &mut NdtEvaluation3,
    cell: &NdtCell3,
    y: &Vector3<f64>,
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
    xh: &Matrix3<f64>,
) {
    let inv = Matrix3::from_row_slice(&cell.inverse);
    let q = y - Vector3::from(cell.mean);
    let iq = inv * q;
    let e = (-0.5 * q.dot(&iq)).exp();
    if e == 0.0 {
        return;
    }
    acc.cost -= e;
    let rt = r.transpose();
    let w = rt * iq;
    let m = rt * inv * r;
    let mx = m * xh;
    let tr = -mx; // translation rows, rotation columns
    let rr = -(xh * mx);
    let g = {
        let gr = x.cross(&w);
        [w[0], w[1], w[2], gr[0], gr[1], gr[2]]
    };
    let wx = w.dot(x);
    let wh = hat(&w);
    for a in 0..6 {
        acc.gradient[a] += e * g[a];
        for b in a..6 {
            let (jsj, second) = match (a >= 3, b >= 3) {
                (false, false) => (m[(a, b)], 0.0),
                (false, true) => (tr[(a, b - 3)], -0.5 * wh[(b - 3, a)]),
                (true, true) => {
                    let (i, j) = (a - 3, b - 3);
                    let s = 0.5 * (x[i] * w[j] + w[i] * x[j]) - if i == j { wx } else { 0.0 };
                    (rr[(i, j)], s)
                }
                (true, false) => unreachable!("b >= a"),
            };
            let h = e * (jsj + second - g[a] * g[b]);
            let info = e * jsj;
            acc.hessian[a * 6 + b] += h;
            acc.information[a * 6 + b] += info;
            if a != b {
                acc.hessian[b * 6 + a] += h;
                acc.information[b * 6 + a] += info;
            }
        }
    }
}

/// Raise eigenvalues below `ratio · λ_max`; `None` for a degenerate voxel (identical points).
fn regularise(cov: &[f64; 9], ratio: f64) -> Option<([f64; 9], [f64; 9])> {
    let (vals, vecs) = sym3(cov);
    let top = vals[2];
    if !(top.is_finite() && top > 0.0) {
        return None;
    }
    let floor = ratio * top;
    let lam = vals.map(|v| v.max(floor));
    let mut c = [0.0; 9];
    let mut ci = [0.0; 9];
    for (k, v) in vecs.iter().enumerate() {
        for i in 0..3 {
            for j in 0..3 {
                c[i * 3 + j] += lam[k] * v[i] * v[j];
                ci[i * 3 + j] += v[i] * v[j] / lam[k];
            }
        }
    }
    Some((c, ci))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lie::se3_exp;

    /// A box-shaped room with a pillar: planes in every direction.
    fn room() -> Vec<f64> {
        let mut pts = Vec::new();
        let mut s = 17u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        for _ in 0..4000 {
            let (u, v, n) = (8.0 * rnd(), 4.0 * rnd() + 2.0, 0.01 * rnd());
            pts.extend([u, -3.0 + n, v]); // wall y = −3
            pts.extend([5.0 + n, u * 0.7, v]); // wall x = 5
            pts.extend([u, 0.7 * rnd() * 8.0, n]); // floor
            pts.extend([
                1.0 + 0.3 * (6.3 * rnd()).cos(),
                1.0 + 0.3 * (6.3 * rnd()).sin(),
                v,
            ]);
        }
        pts
    }

    fn pose_of(rho: [f64; 3], phi: [f64; 3]) -> [f64; 16] {
        let t = se3_exp(Vector3::from(rho), Vector3::from(phi));
        [
            t.r[(0, 0)],
            t.r[(0, 1)],
            t.r[(0, 2)],
            t.t[0],
            t.r[(1, 0)],
            t.r[(1, 1)],
            t.r[(1, 2)],
            t.t[1],
            t.r[(2, 0)],
            t.r[(2, 1)],
            t.r[(2, 2)],
            t.t[2],
            0.0,
            0.0,
            0.0,
            1.0,
        ]
    }

    fn compose(a: &[f64; 16], b: &[f64; 16]) -> [f64; 16] {
        let mut out = [0.0; 16];
        for i in 0..4 {
            for j in 0..4 {
                out[i * 4 + j] = (0..4).map(|k| a[i * 4 + k] * b[k * 4 + j]).sum();
            }
        }
        out
    }

    #[test]
    fn gradient_and_hessian_match_finite_differences_of_the_right_perturbation() {
        let target = room();
        let grid = NdtGrid3::build(&target, 1.0, 5, 0.01).unwrap();
        let base = pose_of([0.05, -0.04, 0.02], [0.01, -0.02, 0.03]);
        // The seven-voxel neighbourhood changes where a point crosses a voxel border (the cost
        // steps there): keep points well inside their voxel, so differences see only the smooth
        // part.
        let source: Vec<f64> = target
            .chunks_exact(3)
            .filter(|x| {
                (0..3).all(|i| {
                    let y = (0..3).map(|k| base[i * 4 + k] * x[k]).sum::<f64>() + base[i * 4 + 3];
                    let f = y - y.floor();
                    (0.05..0.95).contains(&f)
                })
            })
            .take(3000)
            .flatten()
            .copied()
            .collect();
        let ev = grid.evaluate(&source, &base).unwrap();
        assert!(ev.num_matched > 900);
        let h = 1e-6;
        for a in 0..6 {
            let mut d = [0.0; 6];
            d[a] = h;
            let plus = compose(&base, &pose_of([d[0], d[1], d[2]], [d[3], d[4], d[5]]));
            d[a] = -h;
            let minus = compose(&base, &pose_of([d[0], d[1], d[2]], [d[3], d[4], d[5]]));
            let (ep, em) = (
                grid.evaluate(&source, &plus).unwrap(),
                grid.evaluate(&source, &minus).unwrap(),
            );
            let g = (ep.cost - em.cost) / (2.0 * h);
            assert!(
                (g - ev.gradient[a]).abs() < 1e-4 * (1.0 + g.abs()),
                "gradient {a}: {g} vs {}",
                ev.gradient[a]
            );
        }
        // The Hessian of g(δ) = f(T·exp(δ)) at δ = 0, by central differences of the cost.
        let g = |d: [f64; 6]| {
            let m = compose(&base, &pose_of([d[0], d[1], d[2]], [d[3], d[4], d[5]]));
            grid.evaluate(&source, &m).unwrap().cost
        };
        let h2 = 1e-4;
        for a in 0..6 {
            for b in 0..6 {
                let at = |sa: f64, sb: f64| {
                    let mut d = [0.0; 6];
                    d[a] += sa * h2;
                    d[b] += sb * h2;
                    g(d)
                };
                let fd = (at(1.0, 1.0) - at(1.0, -1.0) - at(-1.0, 1.0) + at(-1.0, -1.0))
                    / (4.0 * h2 * h2);
                let an = ev.hessian[a * 6 + b];
                assert!(
                    (fd - an).abs() < 1e-3 * (1.0 + fd.abs().max(an.abs())) + 0.5,
                    "hessian {a}{b}: {fd} vs {an}"
                );
            }
        }
        // The information is the Hessian's Gauss–Newton part: symmetric, positive semi-definite.
        for a in 0..6 {
            assert!(ev.information[a * 6 + a] > 0.0);
            for b in 0..6 {
                assert_eq!(ev.information[a * 6 + b], ev.information[b * 6 + a]);
            }
        }
    }

    #[test]
    fn the_cost_is_lowest_at_the_true_pose() {
        let target = room();
        let grid = NdtGrid3::build(&target, 1.0, 5, 0.01).unwrap();
        let at = grid
            .evaluate(&target, &pose_of([0.0; 3], [0.0; 3]))
            .unwrap();
        for off in [[0.2, 0.0, 0.0], [0.0, -0.2, 0.0], [0.0, 0.0, 0.2]] {
            let moved = grid.evaluate(&target, &pose_of(off, [0.0; 3])).unwrap();
            assert!(moved.cost > at.cost, "{off:?}");
        }
        for rot in [[0.05, 0.0, 0.0], [0.0, -0.05, 0.0], [0.0, 0.0, 0.05]] {
            let turned = grid.evaluate(&target, &pose_of([0.0; 3], rot)).unwrap();
            assert!(turned.cost > at.cost, "{rot:?}");
        }
    }

    #[test]
    fn cells_are_far_from_the_origin_as_accurate_as_near_it() {
        let near = room();
        let far: Vec<f64> = near
            .iter()
            .enumerate()
            .map(|(i, v)| v + [5.0e5, 4.2e6, 120.0][i % 3])
            .collect();
        let a = NdtGrid3::build(&near, 1.0, 5, 0.01).unwrap().cells();
        let b = NdtGrid3::build(&far, 1.0, 5, 0.01).unwrap().cells();
        assert!(!a.is_empty());
        let sum = |c: &[NdtCell3]| {
            c.iter()
                .map(|c| c.covariance[0] + c.covariance[4])
                .sum::<f64>()
        };
        assert!((sum(&a) - sum(&b)).abs() < 1e-6 * sum(&a));
    }

    #[test]
    fn hostile_input_is_an_error() {
        assert!(NdtGrid3::build(&[], 1.0, 5, 0.01).is_err());
        assert!(NdtGrid3::build(&[0.0, f64::NAN, 0.0], 1.0, 5, 0.01).is_err());
        assert!(NdtGrid3::build(&[0.0, 0.0, 0.0], 0.0, 5, 0.01).is_err());
        assert!(NdtGrid3::build(&[0.0, 0.0, 0.0], 1.0, 3, 0.01).is_err());
        assert!(NdtGrid3::build(&[0.0, 0.0, 0.0], 1.0, 5, 0.0).is_err());
        assert!(NdtGrid3::build(&[1e300, 0.0, 0.0], 1e-300, 5, 0.01).is_err());
        let g = NdtGrid3::build(&room(), 1.0, 5, 0.01).unwrap();
        assert!(g.evaluate(&[0.0, 0.0], &[0.0; 16]).is_err());
        let mut bad = pose_of([0.0; 3], [0.0; 3]);
        bad[3] = f64::NAN;
        assert!(g.evaluate(&[0.0, 0.0, 0.0], &bad).is_err());
        assert!(g.evaluate(&[0.0, 0.0, 0.0], &bad[..12]).is_err());
        // A point whose voxel key would overflow is simply unmatched.
        let ev = g
            .evaluate(&[1e300, 0.0, 0.0], &pose_of([0.0; 3], [0.0; 3]))
            .unwrap();
        assert_eq!(ev.num_matched, 0);
    }
}
