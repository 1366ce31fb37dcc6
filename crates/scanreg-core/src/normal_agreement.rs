//! Point-to-plane/line normal equations over a sample of correspondences, split by whether the
//! source and target normals of each pair agree.
//!
//! Why: on sparse spinning-LiDAR scans the pairs whose two normals disagree (a ring on a wall,
//! a pole: PCA of a line picks a "normal" at random) bias the point-to-plane minimum by more
//! than its noise (`docs/calibration.md`, the street). The Python side solves both systems at
//! the final pose; the difference of the two steps is the shift those pairs cause, and goes
//! into the covariance as a model-error term.

use crate::error::{Error, Result};
use crate::kernel::Kernel;

/// A normal shorter than this (squared) marks a point without one.
const VALID_SQ: f64 = 0.25;

/// `JᵀWJ` (row-major `dof × dof`) and `JᵀWr` (`dof`) of the point-to-plane/line residual
/// `r = n_t · (R p + t − q)`, right perturbation, translation first.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalSystem {
    pub hessian: Vec<f64>,
    pub gradient: Vec<f64>,
    pub count: usize,
}

impl NormalSystem {
    fn new(dof: usize) -> Self {
        NormalSystem {
            hessian: vec![0.0; dof * dof],
            gradient: vec![0.0; dof],
            count: 0,
        }
    }

    fn add(&mut self, jac: &[f64], r: f64, w: f64) {
        let dof = jac.len();
        for a in 0..dof {
            self.gradient[a] += w * jac[a] * r;
            for b in 0..dof {
                self.hessian[a * dof + b] += w * jac[a] * jac[b];
            }
        }
        self.count += 1;
    }
}

/// Both systems: over every sampled pair with two normals, and over those whose normals agree.
#[derive(Debug, Clone, PartialEq)]
pub struct AgreementSystems {
    pub all: NormalSystem,
    pub agreeing: NormalSystem,
}

/// The inputs of [`normal_agreement_systems`]; arrays are row-major, `dim` columns.
pub struct AgreementInput<'a> {
    /// Source rows of the sampled points.
    pub sample: &'a [usize],
    /// One normal per sampled point (a zero row: none), in the source frame.
    pub sample_normals: &'a [f64],
    pub source: &'a [f64],
    pub target: &'a [f64],
    /// One per target point (a zero row: none).
    pub target_normals: &'a [f64],
    /// Target row of each source point, `< 0` for none.
    pub correspondences: &'a [i64],
    /// `(dim + 1) × (dim + 1)` homogeneous, row-major.
    pub pose: &'a [f64],
    pub dim: usize,
}

fn invalid(arg: &'static str, msg: impl Into<String>) -> Error {
    Error::invalid(arg, msg)
}

fn check(input: &AgreementInput<'_>, min_agreement: f64) -> Result<()> {
    let dim = input.dim;
    if dim != 2 && dim != 3 {
        return Err(invalid("dim", format!("expected 2 or 3, got {dim}")));
    }
    let rows = |data: &[f64], arg: &'static str| -> Result<usize> {
        if !data.len().is_multiple_of(dim) {
            return Err(invalid(
                arg,
                format!("length {} is not a multiple of {dim}", data.len()),
            ));
        }
        if data.iter().any(|v| !v.is_finite()) {
            return Err(invalid(arg, "contains NaN or inf"));
        }
        Ok(data.len() / dim)
    };
    let n_src = rows(input.source, "source")?;
    let n_tgt = rows(input.target, "target")?;
    if rows(input.sample_normals, "sample_normals")? != input.sample.len() {
        return Err(invalid(
            "sample_normals",
            "expected one row per sampled point",
        ));
    }
    if rows(input.target_normals, "target_normals")? != n_tgt {
        return Err(invalid(
            "target_normals",
            "expected one row per target point",
        ));
    }
    if input.correspondences.len() != n_src {
        return Err(invalid(
            "correspondences",
            "expected one entry per source point",
        ));
    }
    if input.pose.len() != (dim + 1) * (dim + 1) || input.pose.iter().any(|v| !v.is_finite()) {
        return Err(invalid(
            "pose",
            format!("expected a finite {0}x{0} matrix", dim + 1),
        ));
    }
    if !(0.0..=1.0).contains(&min_agreement) {
        return Err(invalid(
            "min_agreement",
            format!("must be in [0, 1], got {min_agreement}"),
        ));
    }
    if let Some(&i) = input.sample.iter().find(|&&i| i >= n_src) {
        return Err(invalid("sample", format!("index {i} out of range")));
    }
    if let Some(&j) = input.correspondences.iter().find(|&&j| j >= n_tgt as i64) {
        return Err(invalid(
            "correspondences",
            format!("index {j} out of range"),
        ));
    }
    Ok(())
}

/// The normal equations of the sampled pairs at `input.pose`, all and agreeing
/// (`|R n_s · n_t| >= min_agreement`), each pair weighted by `kernel` at its residual.
pub fn normal_agreement_systems(
    input: &AgreementInput<'_>,
    min_agreement: f64,
    kernel: Kernel,
) -> Result<AgreementSystems> {
    check(input, min_agreement)?;
    let dim = input.dim;
    let dof = if dim == 2 { 3 } else { 6 };
    let side = dim + 1;
    let rot = |r: usize, c: usize| input.pose[r * side + c];
    let trans = |r: usize| input.pose[r * side + dim];
    let mut out = AgreementSystems {
        all: NormalSystem::new(dof),
        agreeing: NormalSystem::new(dof),
    };
    let mut jac = [0.0; 6];
    for (s, &i) in input.sample.iter().enumerate() {
        let j = input.correspondences[i];
        if j < 0 {
            continue;
        }
        let j = j as usize;
        let p = &input.source[i * dim..(i + 1) * dim];
        let q = &input.target[j * dim..(j + 1) * dim];
        let nt = &input.target_normals[j * dim..(j + 1) * dim];
        let ns = &input.sample_normals[s * dim..(s + 1) * dim];
        let norm2 = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>();
        if norm2(nt) < VALID_SQ || norm2(ns) < VALID_SQ {
            continue;
        }
        // r = n_t · (R p + t − q); m = Rᵀ n_t; agreement = |(R n_s) · n_t| = |n_s · m|.
        let mut r = 0.0;
        let mut m = [0.0; 3];
        for a in 0..dim {
            let moved: f64 = (0..dim).map(|c| rot(a, c) * p[c]).sum::<f64>() + trans(a);
            r += nt[a] * (moved - q[a]);
            for (c, mc) in m.iter_mut().enumerate().take(dim) {
                *mc += rot(a, c) * nt[a];
            }
        }
        let cos: f64 = (0..dim).map(|c| ns[c] * m[c]).sum::<f64>().abs()
            / (norm2(ns).sqrt() * norm2(nt).sqrt());
        // d r / d δt = m, d r / d δω = p × m (2D: p_x m_y − p_y m_x).
        jac[..dim].copy_from_slice(&m[..dim]);
        if dim == 2 {
            jac[2] = p[0] * m[1] - p[1] * m[0];
        } else {
            jac[3] = p[1] * m[2] - p[2] * m[1];
            jac[4] = p[2] * m[0] - p[0] * m[2];
            jac[5] = p[0] * m[1] - p[1] * m[0];
        }
        let w = kernel.weight(r.abs());
        out.all.add(&jac[..dof], r, w);
        if cos >= min_agreement {
            out.agreeing.add(&jac[..dof], r, w);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane z = 0 (normals +z) seen by both scans, plus pairs whose source normal is
    /// tilted by 45°: only those are left out of `agreeing`.
    #[test]
    fn splits_pairs_by_normal_agreement() {
        let n = 40;
        let mut src = Vec::new();
        let mut tgt = Vec::new();
        let mut ns = Vec::new();
        let mut nt = Vec::new();
        for i in 0..n {
            let (x, y) = ((i % 7) as f64, (i / 7) as f64);
            src.extend([x, y, 0.01]);
            tgt.extend([x, y, 0.0]);
            nt.extend([0.0, 0.0, 1.0]);
            let h = std::f64::consts::FRAC_1_SQRT_2;
            ns.extend(if i % 4 == 0 {
                [h, 0.0, h]
            } else {
                [0.0, 0.0, 1.0]
            });
        }
        let sample: Vec<usize> = (0..n).collect();
        let corr: Vec<i64> = (0..n as i64).collect();
        let pose = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let input = AgreementInput {
            sample: &sample,
            sample_normals: &ns,
            source: &src,
            target: &tgt,
            target_normals: &nt,
            correspondences: &corr,
            pose: &pose,
            dim: 3,
        };
        let out = normal_agreement_systems(&input, 0.99, Kernel::None).unwrap();
        assert_eq!(out.all.count, n);
        assert_eq!(out.agreeing.count, n - n / 4);
        // Every residual is 0.01 along z: g_z = Σ r = 0.01 · count, H_zz = count.
        assert!((out.all.gradient[2] - 0.01 * n as f64).abs() < 1e-12);
        assert!((out.agreeing.hessian[2 * 6 + 2] - (n - n / 4) as f64).abs() < 1e-12);
        // The rotation rows: d r / d ω_x = y, so H_{z,ωx} = Σ y.
        let sum_y: f64 = (0..n).map(|i| (i / 7) as f64).sum();
        assert!((out.all.hessian[2 * 6 + 3] - sum_y).abs() < 1e-12);
    }

    #[test]
    fn two_d_jacobian_matches_finite_differences() {
        // One pair, rotated pose: compare J with a numeric derivative of r(pose · exp(δ)).
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let pose = [c, -s, 0.5, s, c, -0.2, 0.0, 0.0, 1.0];
        let src = [1.0, 2.0];
        let tgt = [0.1, 2.5];
        let nt = [0.6, 0.8];
        let ns = [-s * 0.6 + c * 0.8, -c * 0.6 - s * 0.8]; // any unit vector
        let input = AgreementInput {
            sample: &[0],
            sample_normals: &ns,
            source: &src,
            target: &tgt,
            target_normals: &nt,
            correspondences: &[0],
            pose: &pose,
            dim: 2,
        };
        let out = normal_agreement_systems(&input, 0.0, Kernel::None).unwrap();
        let residual = |d: [f64; 3]| {
            // T exp(δ) p ≈ R (R(θ) p + ρ) + t for small δ (the left Jacobian is 1 + O(δ)).
            let (cd, sd) = (d[2].cos(), d[2].sin());
            let pl = [
                cd * src[0] - sd * src[1] + d[0],
                sd * src[0] + cd * src[1] + d[1],
            ];
            let m = [c * pl[0] - s * pl[1] + 0.5, s * pl[0] + c * pl[1] - 0.2];
            nt[0] * (m[0] - tgt[0]) + nt[1] * (m[1] - tgt[1])
        };
        let r0 = residual([0.0; 3]);
        // g = J r with one pair: J = g / r.
        for a in 0..3 {
            let mut d = [0.0; 3];
            d[a] = 1e-7;
            let numeric = (residual(d) - r0) / 1e-7;
            assert!(
                (out.all.gradient[a] / r0 - numeric).abs() < 1e-5,
                "axis {a}"
            );
        }
    }

    #[test]
    fn rejects_bad_input() {
        let input = AgreementInput {
            sample: &[3],
            sample_normals: &[0.0, 1.0],
            source: &[0.0, 0.0],
            target: &[0.0, 0.0],
            target_normals: &[0.0, 1.0],
            correspondences: &[0],
            pose: &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            dim: 2,
        };
        let err = normal_agreement_systems(&input, 0.99, Kernel::None).unwrap_err();
        assert!(err.to_string().contains("sample"), "{err}");
        let ok = AgreementInput {
            sample: &[0],
            ..input
        };
        let err = normal_agreement_systems(&ok, 1.5, Kernel::None).unwrap_err();
        assert!(err.to_string().contains("min_agreement"), "{err}");
    }
}
