//! What a deskew leaves in a 2D point-to-line match: the per-point sums behind the loop
//! covariance term of `scanreg.pipeline.sweep_residual` (the derivation is in its docstring).
//!
//! For the source points with a target neighbour (`nearest[i] >= 0`, the target's normal not
//! zero), with `J_i = [n_x, n_y, n · p_i^⊥]` (the target normal `n` turned into the source
//! frame), the sums are
//! * `A = Σ J_i J_iᵀ` (the match's information),
//! * `B = Σ s_i J_i J_iᵀ` (`s_i` the source point's sweep fraction),
//! * per submap node `k`: `C_k = Σ (s_j − s̄_k) J_i J'_jᵀ` over the points whose neighbour `j`
//!   node `k` laid in, `J'_j` the same row in node `k`'s frame.
//!
//! The 3×3 algebra on them stays in Python; these are the loops over the points.

use crate::error::{Error, Result};

/// A submap's deskewed sweeps, per target point and per node (see the module docs).
pub struct TargetSweeps<'a> {
    /// Per target point: the node slot that laid it in, `-1` when not deskewed.
    pub slots: &'a [i64],
    /// Per target point: its time as a fraction of its sweep's interval.
    pub fractions: &'a [f64],
    /// Per slot: the node's pose in the submap's frame, a row-major 3×3 homogeneous matrix.
    pub node_poses: &'a [f64],
    /// Per slot: the node's mean fraction `s̄_k`.
    pub mean_fractions: &'a [f64],
}

/// The sums of the module docs (row-major 3×3 each).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepSums {
    /// Source points that entered the sums.
    pub matched: usize,
    pub information: [f64; 9],
    /// `B`, when the source was deskewed.
    pub source: Option<[f64; 9]>,
    /// `C_k` per slot, when the target was.
    pub nodes: Vec<[f64; 9]>,
}

/// `[n_x, n_y, n · p^⊥]` with `n` turned by `rᵀ` (`r` = `[r00, r01, r10, r11]`, row-major).
fn jacobian_row(n: [f64; 2], r: [f64; 4], p: [f64; 2]) -> [f64; 3] {
    let nx = n[0] * r[0] + n[1] * r[2];
    let ny = n[0] * r[1] + n[1] * r[3];
    [nx, ny, ny * p[0] - nx * p[1]]
}

fn add_outer(acc: &mut [f64; 9], a: &[f64; 3], b: &[f64; 3], w: f64) {
    for r in 0..3 {
        for c in 0..3 {
            acc[r * 3 + c] += w * a[r] * b[c];
        }
    }
}

fn check_len(arg: &'static str, got: usize, want: usize) -> Result<()> {
    if got != want {
        return Err(Error::invalid(
            arg,
            format!("expected {want} values, got {got}"),
        ));
    }
    Ok(())
}

fn check_finite(arg: &'static str, v: &[f64]) -> Result<()> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err(Error::invalid(arg, "values must be finite"));
    }
    Ok(())
}

/// A 2D homogeneous matrix's rotation (row-major) and translation.
fn rigid(arg: &'static str, m: &[f64]) -> Result<([f64; 4], [f64; 2])> {
    check_len(arg, m.len(), 9)?;
    check_finite(arg, m)?;
    Ok(([m[0], m[1], m[3], m[4]], [m[2], m[5]]))
}

/// The sums of the module docs for `source` (`N * 2`) matched at `pose` (`T_target_source`,
/// 3×3 row-major) to the target points `target_points` / `target_normals` (`M * 2` each):
/// `nearest[i]` is source point `i`'s neighbour (`-1`: none). `None` when fewer than 3 source
/// points have a neighbour with a normal.
#[allow(clippy::too_many_arguments)]
pub fn sweep_sums(
    source: &[f64],
    nearest: &[i64],
    target_points: &[f64],
    target_normals: &[f64],
    pose: &[f64],
    source_fractions: Option<&[f64]>,
    target: Option<&TargetSweeps<'_>>,
) -> Result<Option<SweepSums>> {
    let n = nearest.len();
    check_len("source", source.len(), 2 * n)?;
    check_finite("source", source)?;
    let m = target_normals.len() / 2;
    check_len("target_normals", target_normals.len(), 2 * m)?;
    check_len("target_points", target_points.len(), 2 * m)?;
    let (rotation, _) = rigid("pose", pose)?;
    if let Some(f) = source_fractions {
        check_len("source_fractions", f.len(), n)?;
        check_finite("source_fractions", f)?;
    }
    let mut nodes: Vec<([f64; 4], [f64; 2])> = Vec::new();
    if let Some(t) = target {
        check_len("target_slots", t.slots.len(), m)?;
        check_len("target_fractions", t.fractions.len(), m)?;
        check_finite("target_fractions", t.fractions)?;
        let k = t.mean_fractions.len();
        check_len("node_poses", t.node_poses.len(), 9 * k)?;
        check_finite("mean_fractions", t.mean_fractions)?;
        for chunk in t.node_poses.chunks_exact(9) {
            nodes.push(rigid("node_poses", chunk)?);
        }
        if let Some(bad) = t.slots.iter().find(|&&s| s < -1 || s >= k as i64) {
            return Err(Error::invalid(
                "target_slots",
                format!("slot {bad} outside -1..{k}"),
            ));
        }
    }
    let mut out = SweepSums {
        matched: 0,
        information: [0.0; 9],
        source: source_fractions.map(|_| [0.0; 9]),
        nodes: vec![[0.0; 9]; nodes.len()],
    };
    for (i, &j) in nearest.iter().enumerate() {
        if j < 0 {
            continue;
        }
        let j = j as usize;
        if j >= m {
            return Err(Error::invalid(
                "nearest",
                format!("index {j} outside the target's {m} points"),
            ));
        }
        let normal = [target_normals[2 * j], target_normals[2 * j + 1]];
        if normal[0].abs() + normal[1].abs() == 0.0 {
            continue; // (a target point without a normal)
        }
        let row = jacobian_row(normal, rotation, [source[2 * i], source[2 * i + 1]]);
        out.matched += 1;
        add_outer(&mut out.information, &row, &row, 1.0);
        if let (Some(b), Some(f)) = (out.source.as_mut(), source_fractions) {
            add_outer(b, &row, &row, f[i]);
        }
        if let Some(t) = target {
            let slot = t.slots[j];
            if slot < 0 {
                continue;
            }
            let k = slot as usize;
            let (r, origin) = nodes[k];
            let q = [
                target_points[2 * j] - origin[0],
                target_points[2 * j + 1] - origin[1],
            ];
            let local = [q[0] * r[0] + q[1] * r[2], q[0] * r[1] + q[1] * r[3]]; // rᵀ (q − t)
            let node_row = jacobian_row(normal, r, local);
            let about_mean = t.fractions[j] - t.mean_fractions[k];
            add_outer(&mut out.nodes[k], &row, &node_row, about_mean);
        }
    }
    Ok((out.matched >= 3).then_some(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

    #[test]
    fn sums_over_matched_points_with_normals() {
        // Three source points on a wall y = 1 (normal +y), one unmatched, one whose neighbour
        // has no normal: A sums the three rows [0, 1, x].
        let source = [0.0, 1.0, 1.0, 1.0, 2.0, 1.0, 5.0, 5.0, 3.0, 1.0];
        let nearest = [0, 1, 2, -1, 3];
        let targets = [0.0, 1.0, 1.0, 1.0, 2.0, 1.0, 3.0, 1.0];
        let normals = [0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0];
        let fractions = [0.0, 0.5, 1.0, 0.0, 0.0];
        let sums = sweep_sums(
            &source,
            &nearest,
            &targets,
            &normals,
            &IDENTITY,
            Some(&fractions),
            None,
        )
        .unwrap()
        .unwrap();
        assert_eq!(sums.matched, 3);
        // rows [0, 1, x] for x = 0, 1, 2 (n · p^⊥ = n_y p_x − n_x p_y = x)
        assert_eq!(
            sums.information,
            [0.0, 0.0, 0.0, 0.0, 3.0, 3.0, 0.0, 3.0, 5.0]
        );
        let b = sums.source.unwrap();
        assert_eq!(b, [0.0, 0.0, 0.0, 0.0, 1.5, 2.5, 0.0, 2.5, 4.5]);
        assert!(sums.nodes.is_empty());
    }

    #[test]
    fn fewer_than_three_matches_give_none() {
        let r = sweep_sums(
            &[0.0, 1.0, 1.0, 1.0],
            &[0, 0],
            &[0.0, 1.0],
            &[0.0, 1.0],
            &IDENTITY,
            None,
            None,
        )
        .unwrap();
        assert!(r.is_none());
    }

    #[test]
    fn bad_input_names_the_argument() {
        let bad_slot = TargetSweeps {
            slots: &[2],
            fractions: &[0.0],
            node_poses: &IDENTITY,
            mean_fractions: &[0.0],
        };
        let e = sweep_sums(
            &[0.0, 1.0],
            &[0],
            &[0.0, 1.0],
            &[0.0, 1.0],
            &IDENTITY,
            None,
            Some(&bad_slot),
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("target_slots"), "{e}");
        let e = sweep_sums(
            &[0.0, 1.0],
            &[3],
            &[0.0, 1.0],
            &[0.0, 1.0],
            &IDENTITY,
            None,
            None,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("nearest"), "{e}");
        let e = sweep_sums(
            &[f64::NAN, 1.0],
            &[0],
            &[0.0, 1.0],
            &[0.0, 1.0],
            &IDENTITY,
            None,
            None,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("source"), "{e}");
    }
}
