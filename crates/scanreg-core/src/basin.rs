//! The wrong-basin probe's outcome comparison (`scanreg.basin.probe_basin`): which of the
//! restarts' poses came back to the result, which an alternative the result's covariance
//! already covers, and for the rest — the distinct outcomes — the offset from the result and
//! the fraction of the source they explain within the tight gate. One pass over the outcomes
//! instead of a relative pose, a logarithm, a χ² and a nearest-neighbour call per outcome in
//! Python (those were about a fifth of a restarted probe's cost on 2D Intel pairs).

use crate::error::{Error, Result};
use crate::icp::NeighborSearch;
use crate::lie::{se2_log, se3_log};
use crate::points::{check_points, split_pose};
use nalgebra::{DMatrix, Matrix3, Vector3};

/// What an outcome is, relative to the result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The restart failed (its stop reason was neither converged nor max_iterations).
    Failed = 0,
    /// Within half the tight gate and 1° of the result: the result itself.
    Back = 1,
    /// Further away, but inside the result's covariance (χ² ≤ `chi2`): the same answer.
    Covered = 2,
    /// A distinct outcome: its offset and fraction are reported.
    Distinct = 3,
}

/// Per outcome, in the order given.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcomes {
    pub kinds: Vec<Kind>,
    /// `log(result⁻¹ · pose)` per outcome (`dof` values each, translation first); zeros for
    /// a failed outcome.
    pub offsets: Vec<f64>,
    /// Fraction of the source within the tight gate of a target point at the outcome (NaN
    /// unless distinct).
    pub fractions: Vec<f64>,
}

/// `vᵀ A⁺ v` for the pseudo-inverse of the symmetric `a` (`dof × dof`, row-major), the
/// eigenvalues below `1e-15 · max |λ|` dropped (numpy's `pinv(hermitian=True)` cut-off).
fn pinv_quadratic(info: &DMatrix<f64>, e: &[f64]) -> f64 {
    let n = e.len();
    let mut s = 0.0;
    for i in 0..n {
        let mut row = 0.0;
        for j in 0..n {
            row += info[(i, j)] * e[j];
        }
        s += e[i] * row;
    }
    s
}

fn pseudo_inverse(cov: &[f64], dof: usize) -> DMatrix<f64> {
    let a = DMatrix::from_row_slice(dof, dof, cov);
    let a = (&a + a.transpose()) * 0.5;
    let eig = a.symmetric_eigen();
    let largest = eig.eigenvalues.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let cutoff = 1e-15 * largest;
    let mut out = DMatrix::<f64>::zeros(dof, dof);
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l.abs() > cutoff {
            let v = eig.eigenvectors.column(k);
            out += (v * v.transpose()) / l;
        }
    }
    out
}

/// Source points (flat, `dim` per point) moved by `(r, t)` (row-major) with a target point
/// within `max_sq` (squared, inclusive): `overlap`'s `num_found`, without its statistics.
fn within(search: &dyn NeighborSearch, source: &[f64], r: &[f64], t: &[f64], max_sq: f64) -> usize {
    let dim = t.len();
    let mut q = [0.0; 3];
    source
        .chunks_exact(dim)
        .filter(|p| {
            for (row, out) in q.iter_mut().enumerate().take(dim) {
                *out = (0..dim).map(|c| p[c] * r[row * dim + c]).sum::<f64>() + t[row];
            }
            search.nearest_within(&q[..dim], max_sq).is_some()
        })
        .count()
}

/// Compare the restarts' `poses` (`K` row-major homogeneous matrices, flat) with `result`:
/// see [`Kind`]. `usable[k]`: whether restart `k` ended converged or at its iteration cap.
/// `tight`: the probe's tight gate (finite, > 0); `covariance`: the result's (`dof × dof`,
/// row-major), `None` when it is not finite (then only the fixed distances decide);
/// `chi2`: the χ² bound of "inside the covariance". Identical distinct poses share one
/// overlap pass.
#[allow(clippy::too_many_arguments)]
pub fn compare_outcomes(
    search: &dyn NeighborSearch,
    source: &[f64],
    result: &[f64],
    poses: &[f64],
    usable: &[bool],
    tight: f64,
    covariance: Option<&[f64]>,
    chi2: f64,
) -> Result<Outcomes> {
    let dim = search.dim();
    let dof = if dim == 2 { 3 } else { 6 };
    let n = check_points("source", source, dim)?;
    if n == 0 {
        return Err(Error::invalid("source", "no points"));
    }
    let (rr, rt) = split_pose("result", result, dim)?;
    let m = (dim + 1) * (dim + 1);
    if !poses.len().is_multiple_of(m) {
        return Err(Error::invalid(
            "poses",
            format!("expected a multiple of {m} values, got {}", poses.len()),
        ));
    }
    let count = poses.len() / m;
    if usable.len() != count {
        return Err(Error::invalid(
            "usable",
            format!("expected one per pose ({count}), got {}", usable.len()),
        ));
    }
    if !(tight.is_finite() && tight > 0.0) {
        return Err(Error::invalid(
            "tight",
            format!("must be finite and > 0, got {tight}"),
        ));
    }
    if let Some(c) = covariance {
        if c.len() != dof * dof || c.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "covariance",
                format!("expected {dof}x{dof} finite values, got {}", c.len()),
            ));
        }
    }
    let cos_1deg = 1.0f64.to_radians().cos();
    let one_deg = 1.0f64.to_radians();
    let half = 0.5 * tight;
    // The pseudo-inverse only when an outcome did not come back (most do).
    let mut info: Option<DMatrix<f64>> = None;
    let mut kinds = Vec::with_capacity(count);
    let mut offsets = vec![0.0; count * dof];
    let mut fractions = vec![f64::NAN; count];
    for k in 0..count {
        let pose = &poses[k * m..(k + 1) * m];
        if !usable[k] {
            kinds.push(Kind::Failed);
            continue;
        }
        let (pr, pt) = split_pose("poses", pose, dim)?;
        // rel = result⁻¹ · pose: (Rᵀ R_k, Rᵀ (t_k − t)).
        let e: Vec<f64> = if dim == 2 {
            let rot = |i: usize, j: usize| rr[i] * pr[j] + rr[2 + i] * pr[2 + j];
            let r = [rot(0, 0), rot(0, 1), rot(1, 0), rot(1, 1)];
            let d = [pt[0] - rt[0], pt[1] - rt[1]];
            let t = [rr[0] * d[0] + rr[2] * d[1], rr[1] * d[0] + rr[3] * d[1]];
            let cos = (r[0] + r[3]) / 2.0;
            if (t[0] * t[0] + t[1] * t[1]).sqrt() <= half && cos >= cos_1deg {
                kinds.push(Kind::Back);
                offsets[k * dof..(k + 1) * dof].copy_from_slice(&se2_log(r, t));
                continue;
            }
            se2_log(r, t).to_vec()
        } else {
            let ra = Matrix3::from_row_slice(&rr);
            let rb = Matrix3::from_row_slice(&pr);
            let r = ra.transpose() * rb;
            let t = ra.transpose() * (Vector3::from_row_slice(&pt) - Vector3::from_row_slice(&rt));
            let cos = (r.trace() - 1.0) / 2.0;
            if t.norm() <= half && cos >= cos_1deg {
                kinds.push(Kind::Back);
                offsets[k * dof..(k + 1) * dof].copy_from_slice(&se3_log(r, t));
                continue;
            }
            se3_log(r, t).to_vec()
        };
        offsets[k * dof..(k + 1) * dof].copy_from_slice(&e);
        let moved = e[..dim].iter().map(|v| v * v).sum::<f64>().sqrt();
        let turned = e[dim..].iter().map(|v| v * v).sum::<f64>().sqrt();
        if moved <= half && turned <= one_deg {
            kinds.push(Kind::Back);
            continue;
        }
        if let Some(c) = covariance {
            let inf = info.get_or_insert_with(|| pseudo_inverse(c, dof));
            if pinv_quadratic(inf, &e) <= chi2 {
                kinds.push(Kind::Covered);
                continue;
            }
        }
        kinds.push(Kind::Distinct);
        // Several restarts often land on the same pose: one overlap pass for them.
        let same =
            (0..k).find(|&j| kinds[j] == Kind::Distinct && poses[j * m..(j + 1) * m] == *pose);
        fractions[k] = match same {
            Some(j) => fractions[j],
            None => within(search, source, &pr, &pt, tight * tight) as f64 / n as f64,
        };
    }
    Ok(Outcomes {
        kinds,
        offsets,
        fractions,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::knn::KdTree;

    fn se2(x: f64, y: f64, th: f64) -> [f64; 9] {
        let (s, c) = th.sin_cos();
        [c, -s, x, s, c, y, 0.0, 0.0, 1.0]
    }

    #[test]
    fn outcomes_are_classified_and_measured() {
        // An L of points; the source is the target itself, the result the identity.
        let target: Vec<f64> = (0..40)
            .flat_map(|i| {
                if i < 20 {
                    [i as f64 * 0.1, 0.0]
                } else {
                    [0.0, (i - 19) as f64 * 0.1]
                }
            })
            .collect();
        let tree = KdTree::build(&target, 2).unwrap();
        let result = se2(0.0, 0.0, 0.0);
        let mut poses = Vec::new();
        poses.extend(se2(0.001, 0.0, 0.001)); // back
        poses.extend(se2(0.05, 0.0, 0.0)); // inside the covariance
        poses.extend(se2(0.0, 0.0, std::f64::consts::FRAC_PI_2)); // distinct
        poses.extend(se2(0.0, 0.0, std::f64::consts::FRAC_PI_2)); // the same pose again
        poses.extend(se2(9.0, 9.0, 0.0)); // failed
        let cov = [0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01];
        let o = compare_outcomes(
            &tree,
            &target,
            &result,
            &poses,
            &[true, true, true, true, false],
            0.02,
            Some(&cov),
            16.266,
        )
        .unwrap();
        use Kind::*;
        assert_eq!(o.kinds, vec![Back, Covered, Distinct, Distinct, Failed]);
        // The quarter turn maps the y leg onto −x (nothing there) and the x leg onto the y
        // leg: the 20 x-leg points (the corner among them) plus none of the rest.
        let expected = o.fractions[2];
        assert!(expected > 0.0 && expected < 1.0, "{expected}");
        assert_eq!(o.fractions[3], expected);
        assert!((o.offsets[2 * 3 + 2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!(o.fractions[0].is_nan() && o.fractions[4].is_nan());
        // Without a covariance the 5 cm move is distinct too.
        let o = compare_outcomes(
            &tree, &target, &result, &poses, &[true; 5], 0.02, None, 16.266,
        )
        .unwrap();
        assert_eq!(o.kinds[1], Distinct);
        assert!(
            compare_outcomes(&tree, &target, &result, &poses, &[true; 4], 0.02, None, 1.0).is_err()
        );
        assert!(
            compare_outcomes(&tree, &target, &result, &poses, &[true; 5], 0.0, None, 1.0).is_err()
        );
    }

    #[test]
    fn se3_log_matches_a_known_transform() {
        // A turn of 0.3 rad about z with ρ = (1, 0, 0): t = V(φ) ρ.
        let th: f64 = 0.3;
        let r = Matrix3::new(
            th.cos(),
            -th.sin(),
            0.0,
            th.sin(),
            th.cos(),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        let (a, b) = (th.sin() / th, (1.0 - th.cos()) / th);
        let t = Vector3::new(a, b, 0.0);
        let e = se3_log(r, t);
        for (v, w) in e.iter().zip([1.0, 0.0, 0.0, 0.0, 0.0, th]) {
            assert!((v - w).abs() < 1e-12, "{e:?}");
        }
    }
}
