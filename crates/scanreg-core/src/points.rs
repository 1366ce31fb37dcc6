//! Validated views of flat point arrays.

use crate::error::{Error, Result};
use nalgebra::{SMatrix, SVector};

/// `x.floor()`, inlined: on the baseline x86-64 target (no SSE4.1 `roundsd`) `f64::floor` is
/// a libm call, which showed at 3 % of an odometry profile (voxel keys of every point). Exact
/// for |x| < 4e18 (the truncating cast is exact there); NaN, inf and larger take `floor`.
#[inline]
pub fn floor(x: f64) -> f64 {
    if x.is_nan() || x.abs() >= 4.0e18 {
        return x.floor();
    }
    let t = x as i64 as f64;
    // Branch-free: the sign of x (so whether truncation rounded up) varies point to point.
    t - f64::from(u8::from(t > x))
}

/// `floor(x)` as an integer, branch-free, for `x` known finite and well inside ±2^62 (voxel
/// coordinates after a range check).
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    t - i64::from((t as f64) > x)
}

/// Whether every value is finite: a branch-free scan per block of 512 (vectorised; `any` or
/// `position` exit early and are not), so a caller looks for the culprit only when one exists.
#[inline]
pub fn all_finite(data: &[f64]) -> bool {
    data.chunks(512)
        .all(|c| c.iter().fold(true, |ok, v| ok & v.is_finite()))
}

/// Check that `data` holds whole `dim`-vectors, all finite, and return their count.
pub fn check_points(arg: &'static str, data: &[f64], dim: usize) -> Result<usize> {
    if dim != 2 && dim != 3 {
        return Err(Error::invalid(
            arg,
            format!("dimension must be 2 or 3, got {dim}"),
        ));
    }
    if !data.len().is_multiple_of(dim) {
        return Err(Error::invalid(
            arg,
            format!(
                "length {} is not a multiple of the dimension {dim}",
                data.len()
            ),
        ));
    }
    if let Some(i) = (!all_finite(data))
        .then(|| data.iter().position(|v| !v.is_finite()))
        .flatten()
    {
        return Err(Error::invalid(
            arg,
            format!("point {} has a non-finite coordinate (NaN or inf)", i / dim),
        ));
    }
    Ok(data.len() / dim)
}

/// Check per-point weights: one per point, finite, non-negative, not all zero.
pub fn check_weights(arg: &'static str, weights: &[f64], n: usize) -> Result<()> {
    if weights.len() != n {
        return Err(Error::invalid(
            arg,
            format!(
                "expected {n} weights (one per point), got {}",
                weights.len()
            ),
        ));
    }
    if let Some(i) = weights.iter().position(|w| !w.is_finite() || *w < 0.0) {
        return Err(Error::invalid(
            arg,
            format!(
                "weight {i} is {} (weights must be finite and >= 0)",
                weights[i]
            ),
        ));
    }
    if !weights.iter().any(|w| *w > 0.0) {
        return Err(Error::invalid(arg, "all weights are zero"));
    }
    Ok(())
}

/// Check a row-major homogeneous `(dim+1) x (dim+1)` pose and return its rotation
/// (row-major, `dim*dim`) and translation.
pub fn split_pose(arg: &'static str, pose: &[f64], dim: usize) -> Result<(Vec<f64>, Vec<f64>)> {
    let m = dim + 1;
    if pose.len() != m * m {
        return Err(Error::invalid(
            arg,
            format!(
                "expected a {m}x{m} homogeneous matrix, got {} values",
                pose.len()
            ),
        ));
    }
    if pose.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(arg, "pose has a non-finite entry"));
    }
    let mut rot = Vec::with_capacity(dim * dim);
    let mut trans = Vec::with_capacity(dim);
    for r in 0..dim {
        rot.extend_from_slice(&pose[r * m..r * m + dim]);
        trans.push(pose[r * m + dim]);
    }
    Ok((rot, trans))
}

/// Integer voxel coordinates of a point (`floor(p / voxel_size)`), or an error if they would
/// not fit comfortably in an `i64` (voxel far too small for the extent).
#[inline]
pub(crate) fn voxel_of(p: &[f64], inv: f64) -> Option<[i64; 3]> {
    let mut key = [0i64; 3];
    for (k, v) in key.iter_mut().zip(p) {
        let c = floor(v * inv);
        if c.is_nan() || c.abs() >= 9.0e15 {
            return None;
        }
        *k = c as i64;
    }
    Some(key)
}

/// Row `i` of a flat `N * D` array as a vector.
#[inline]
pub(crate) fn vec_at<const D: usize>(data: &[f64], i: usize) -> SVector<f64, D> {
    SVector::from_column_slice(&data[i * D..(i + 1) * D])
}

/// Matrix `i` of a flat `N * D * D` array of symmetric matrices.
#[inline]
pub(crate) fn mat_at<const D: usize>(data: &[f64], i: usize) -> SMatrix<f64, D, D> {
    // Covariances are symmetric, so row- vs column-major does not matter.
    SMatrix::from_column_slice(&data[i * D * D..(i + 1) * D * D])
}

#[cfg(test)]
mod tests {
    #[test]
    fn floor_matches_std() {
        let mut s = 7u64;
        for _ in 0..100_000 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let x = ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2e6;
            assert_eq!(super::floor(x), x.floor(), "{x}");
        }
        for x in [
            0.0,
            -0.5,
            0.5,
            -1.0,
            1.0,
            -1e-300,
            4.5e18,
            -4.5e18,
            1e300,
            f64::INFINITY,
        ] {
            assert_eq!(super::floor(x), x.floor(), "{x}");
        }
        assert!(super::floor(f64::NAN).is_nan());
        for x in [0.0, -0.5, 0.5, -1.0, 1.0, -1e-300, 2.5e6, -2.5e6 - 0.25] {
            assert_eq!(super::floor_i64(x), x.floor() as i64, "{x}");
        }
    }
}
