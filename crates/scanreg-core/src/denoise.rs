//! Denoising by local planes: each point projected onto the plane (a line in 2D) fitted to its
//! neighbourhood.
//!
//! Point `i`'s neighbourhood is its `k` nearest points within `radius` (itself included); `q̄`
//! is their mean and `n` the eigenvector of their scatter with the smallest eigenvalue. The
//! point moves to `p − n (n · (p − q̄))`: along the normal only, so the noise across the surface
//! falls about as `1/√m` over `m` neighbours while the sampling along it is kept. A point with
//! fewer than `dim + 1` neighbours, or whose neighbourhood spans no plane (line in 2D), is kept
//! as it is.
//!
//! On a curved surface the fitted plane lies inside the curve by a fraction of its sagitta, the
//! same on every scan of the surface (so two views stay aligned) as long as the neighbourhood is
//! small beside the curvature's radius; the caller picks `radius` from the measured noise.

#![allow(clippy::needless_range_loop)] // fixed-size coordinate loops read better indexed

use crate::error::{Error, Result};
use crate::knn::{check_k, KdTree};
use crate::normals::{eigen, scatter, spans};
use crate::reduce::MIN_PAR_ITEMS;
use rayon::prelude::*;

/// Every point of `tree` (input order, row-major `N x dim`) projected onto the plane of its at
/// most `k` nearest points within `radius` (module docs). `dim + 1 <= k <= N`, `radius > 0`.
pub fn project_to_local_planes(tree: &KdTree, k: usize, radius: f64) -> Result<Vec<f64>> {
    let dim = tree.dim();
    let n = tree.len();
    check_k("k", k, n)?;
    if k <= dim {
        return Err(Error::invalid(
            "k",
            format!("must be >= {} to fit a plane in {dim}D, got {k}", dim + 1),
        ));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(Error::invalid(
            "radius",
            format!("must be positive and finite, got {radius}"),
        ));
    }
    let sq_radius = radius * radius;
    let rows: Vec<[f64; 3]> = (0..n)
        .into_par_iter()
        .with_min_len(MIN_PAR_ITEMS)
        .map_init(Vec::new, |buf, i| {
            let p = tree.point(i);
            let mut out = [0.0; 3];
            out[..dim].copy_from_slice(p);
            buf.clear();
            tree.knn_into(p, k, sq_radius, buf);
            if buf.len() <= dim {
                return out;
            }
            let (vals, vecs) = eigen(&scatter(tree, buf), dim);
            if !spans(&vals, dim) {
                return out;
            }
            let mut mean = [0.0; 3];
            for &(j, _) in buf.iter() {
                let q = tree.point(j as usize);
                for c in 0..dim {
                    mean[c] += q[c];
                }
            }
            let m = buf.len() as f64;
            let normal = &vecs[0];
            let along: f64 = (0..dim).map(|c| normal[c] * (p[c] - mean[c] / m)).sum();
            for c in 0..dim {
                out[c] -= along * normal[c];
            }
            out
        })
        .collect();
    Ok(rows.iter().flat_map(|r| r[..dim].to_vec()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane `z = 0.3 x − 0.2 y` sampled on a grid, each point lifted by a known offset.
    fn noisy_plane(lift: impl Fn(usize) -> f64) -> Vec<f64> {
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f64 * 0.01, j as f64 * 0.01);
                pts.extend_from_slice(&[x, y, 0.3 * x - 0.2 * y + lift(i * 40 + j)]);
            }
        }
        pts
    }

    fn off_plane(pts: &[f64]) -> f64 {
        let norm = (1.0f64 + 0.09 + 0.04).sqrt();
        pts.chunks(3)
            .map(|p| ((0.3 * p[0] - 0.2 * p[1] - p[2]) / norm).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_plane_stays_and_alternating_offsets_are_removed() {
        let flat = noisy_plane(|_| 0.0);
        let tree = KdTree::build(&flat, 3).unwrap();
        let out = project_to_local_planes(&tree, 30, 0.05).unwrap();
        assert!(off_plane(&out) < 1e-12);
        for (a, b) in out.iter().zip(&flat) {
            assert!((a - b).abs() < 1e-12, "moved along the plane");
        }
        // ±1 mm in a checkerboard: every neighbourhood's plane is within a fraction of it.
        let noisy = noisy_plane(|i| if (i + i / 40) % 2 == 0 { 0.001 } else { -0.001 });
        assert!(off_plane(&noisy) > 0.0009);
        let tree = KdTree::build(&noisy, 3).unwrap();
        let out = project_to_local_planes(&tree, 30, 0.05).unwrap();
        assert!(off_plane(&out) < 0.0003, "{}", off_plane(&out));
    }

    #[test]
    fn lonely_points_are_kept_and_bad_arguments_named() {
        let pts = [
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.3, 0.3, 0.3,
        ];
        let tree = KdTree::build(&pts, 3).unwrap();
        // Within 0.1 every point is alone: nothing moves.
        assert_eq!(
            project_to_local_planes(&tree, 5, 0.1).unwrap(),
            pts.to_vec()
        );
        let err = project_to_local_planes(&tree, 3, 1.0).unwrap_err();
        assert!(err.to_string().contains("k"), "{err}");
        let err = project_to_local_planes(&tree, 4, f64::NAN).unwrap_err();
        assert!(err.to_string().contains("radius"), "{err}");
    }
}
