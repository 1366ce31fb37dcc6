//! Point-cloud reduction: voxel grid, seeded random subsampling, range and box crops.
//!
//! Every function returns the kept points together with their input indices, in a fixed
//! order that does not depend on the thread count (voxels in the order of their first point,
//! i.e. their lowest input index; filters in input order).

use crate::error::{Error, Result};
use crate::knn::voxel_of;
use crate::points::check_points;
use rayon::prelude::*;

/// How a voxel is represented.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VoxelMethod {
    /// The mean of the voxel's points.
    Centroid,
    /// The voxel's point with the lowest input index.
    First,
}

/// Result of [`voxel_downsample`].
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelGrid {
    /// One point per occupied voxel, `M * dim`, ordered by `index`.
    pub points: Vec<f64>,
    /// Lowest input index of each voxel's points (the point kept by `First`).
    pub index: Vec<i64>,
    /// Number of input points in each voxel.
    pub count: Vec<i64>,
}

/// Gather rows `idx` of `points`.
pub fn gather(points: &[f64], dim: usize, idx: &[usize]) -> Vec<f64> {
    let mut out = Vec::with_capacity(idx.len() * dim);
    for &i in idx {
        out.extend_from_slice(&points[i * dim..(i + 1) * dim]);
    }
    out
}

fn check_voxel_size(voxel_size: f64) -> Result<f64> {
    if !voxel_size.is_finite() || voxel_size <= 0.0 {
        return Err(Error::invalid(
            "voxel_size",
            format!("must be finite and > 0, got {voxel_size}"),
        ));
    }
    Ok(1.0 / voxel_size)
}

/// Voxel-grid downsampling: voxel `floor(p / voxel_size)`; one output point per occupied
/// voxel. Sort-based (voxel key, then index), so each centroid sums its points in input order.
/// An empty input gives an empty output.
pub fn voxel_downsample(
    points: &[f64],
    dim: usize,
    voxel_size: f64,
    method: VoxelMethod,
) -> Result<VoxelGrid> {
    let n = check_points("points", points, dim)?;
    let inv = check_voxel_size(voxel_size)?;
    let keyed: Option<Vec<([i64; 3], u32)>> = points
        .par_chunks_exact(dim)
        .enumerate()
        .map(|(i, p)| voxel_of(p, inv).map(|k| (k, i as u32)))
        .collect();
    let keyed = keyed.ok_or_else(|| {
        Error::invalid(
            "voxel_size",
            format!("{voxel_size} is too small for the extent of the points"),
        )
    })?;
    if n > u32::MAX as usize {
        return Err(Error::invalid("points", "more than 2^32 - 1 points"));
    }
    // Pack the key into one u64 (21 bits per axis) when every voxel coordinate fits: sorting
    // 16-byte (u64, u32) pairs instead of 32-byte ([i64; 3], u32) is ~2x faster. The packing
    // is injective, and voxels are reordered by first index at the end, so the output is the
    // same either way.
    const HALF: i64 = 1 << 20;
    if keyed
        .iter()
        .all(|(k, _)| k.iter().all(|&c| (-HALF..HALF).contains(&c)))
    {
        let packed: Vec<(u64, u32)> = keyed
            .iter()
            .map(|(k, i)| {
                let p = ((k[0] + HALF) as u64) << 42
                    | ((k[1] + HALF) as u64) << 21
                    | (k[2] + HALF) as u64;
                (p, *i)
            })
            .collect();
        drop(keyed);
        Ok(group_voxels(points, dim, method, packed))
    } else {
        Ok(group_voxels(points, dim, method, keyed))
    }
}

/// Sort `(key, index)` pairs, one voxel per run of equal keys, voxels by first index.
fn group_voxels<K: Ord + Copy + Send + Sync>(
    points: &[f64],
    dim: usize,
    method: VoxelMethod,
    mut keyed: Vec<(K, u32)>,
) -> VoxelGrid {
    // Keys are unique (the index breaks ties), so the unstable sort is deterministic.
    keyed.par_sort_unstable();
    let mut starts: Vec<usize> = Vec::new();
    for i in 0..keyed.len() {
        if i == 0 || keyed[i].0 != keyed[i - 1].0 {
            starts.push(i);
        }
    }
    starts.push(keyed.len());
    // Per voxel: (first index, count, representative point).
    let mut voxels: Vec<(u32, u32, [f64; 3])> = starts
        .par_windows(2)
        .map(|w| {
            let group = &keyed[w[0]..w[1]];
            let first = group[0].1;
            let mut rep = [0.0; 3];
            match method {
                VoxelMethod::First => {
                    let f = first as usize;
                    rep[..dim].copy_from_slice(&points[f * dim..(f + 1) * dim]);
                }
                VoxelMethod::Centroid => {
                    for &(_, i) in group {
                        let i = i as usize;
                        for c in 0..dim {
                            rep[c] += points[i * dim + c];
                        }
                    }
                    let m = group.len() as f64;
                    for r in rep.iter_mut().take(dim) {
                        *r /= m;
                    }
                }
            }
            (first, group.len() as u32, rep)
        })
        .collect();
    voxels.par_sort_unstable_by_key(|v| v.0);
    let mut out = VoxelGrid {
        points: Vec::with_capacity(voxels.len() * dim),
        index: Vec::with_capacity(voxels.len()),
        count: Vec::with_capacity(voxels.len()),
    };
    for (first, count, rep) in voxels {
        out.points.extend_from_slice(&rep[..dim]);
        out.index.push(first as i64);
        out.count.push(count as i64);
    }
    out
}

/// SplitMix64 (Steele, Lea & Flood 2014): a small, well-mixed, seedable generator.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..bound` (Lemire's multiply-shift; bias < bound / 2^64).
    fn below(&mut self, bound: usize) -> usize {
        ((self.next() as u128 * bound as u128) >> 64) as usize
    }
}

/// `count` distinct indices of `0..n` drawn uniformly without replacement (partial
/// Fisher–Yates), returned sorted. Same `seed`, same result, on every platform.
pub fn random_subsample_indices(n: usize, count: usize, seed: u64) -> Result<Vec<usize>> {
    if count > n {
        return Err(Error::invalid(
            "n",
            format!("is {count} but there are only {n} points"),
        ));
    }
    let mut rng = SplitMix64(seed);
    let mut idx: Vec<usize> = (0..n).collect();
    for i in 0..count {
        let j = i + rng.below(n - i);
        idx.swap(i, j);
    }
    idx.truncate(count);
    idx.sort_unstable();
    Ok(idx)
}

fn keep_where<F>(points: &[f64], dim: usize, pred: F) -> Vec<usize>
where
    F: Fn(&[f64]) -> bool + Sync,
{
    points
        .par_chunks_exact(dim)
        .enumerate()
        .filter(|(_, p)| pred(p))
        .map(|(i, _)| i)
        .collect()
}

/// Indices of the points whose distance from the origin is in `[min_distance, max_distance]`.
pub fn crop_range(
    points: &[f64],
    dim: usize,
    min_distance: f64,
    max_distance: f64,
) -> Result<Vec<usize>> {
    check_points("points", points, dim)?;
    if min_distance.is_nan() || min_distance < 0.0 || min_distance.is_infinite() {
        return Err(Error::invalid(
            "min_distance",
            format!("must be finite and >= 0, got {min_distance}"),
        ));
    }
    if max_distance.is_nan() || max_distance < min_distance {
        return Err(Error::invalid(
            "max_distance",
            format!("must be >= min_distance ({min_distance}), got {max_distance}"),
        ));
    }
    let (lo, hi) = (min_distance * min_distance, max_distance * max_distance);
    Ok(keep_where(points, dim, |p| {
        let r2: f64 = p.iter().map(|v| v * v).sum();
        r2 >= lo && r2 <= hi
    }))
}

/// Indices of the points inside the axis-aligned box `[min_corner, max_corner]` (inclusive).
pub fn crop_box(
    points: &[f64],
    dim: usize,
    min_corner: &[f64],
    max_corner: &[f64],
) -> Result<Vec<usize>> {
    check_points("points", points, dim)?;
    for (arg, c) in [("min_corner", min_corner), ("max_corner", max_corner)] {
        if c.len() != dim {
            return Err(Error::invalid(
                arg,
                format!("expected {dim} values, got {}", c.len()),
            ));
        }
        if c.iter().any(|v| v.is_nan()) {
            return Err(Error::invalid(arg, "contains NaN"));
        }
    }
    if let Some(k) = (0..dim).find(|&k| min_corner[k] > max_corner[k]) {
        return Err(Error::invalid(
            "max_corner",
            format!(
                "is below min_corner on axis {k} ({} < {})",
                max_corner[k], min_corner[k]
            ),
        ));
    }
    Ok(keep_where(points, dim, |p| {
        (0..dim).all(|k| p[k] >= min_corner[k] && p[k] <= max_corner[k])
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_centroid_and_first() {
        // Two voxels of size 1: {0, 2} in voxel (0,0), {1} in voxel (1,0).
        let pts = [0.2, 0.2, 1.5, 0.5, 0.6, 0.8];
        let c = voxel_downsample(&pts, 2, 1.0, VoxelMethod::Centroid).unwrap();
        assert_eq!(c.index, vec![0, 1]);
        assert_eq!(c.count, vec![2, 1]);
        assert!((c.points[0] - 0.4).abs() < 1e-15 && (c.points[1] - 0.5).abs() < 1e-15);
        assert_eq!(&c.points[2..], &[1.5, 0.5]);
        let f = voxel_downsample(&pts, 2, 1.0, VoxelMethod::First).unwrap();
        assert_eq!(f.points, vec![0.2, 0.2, 1.5, 0.5]);
        // Negative coordinates floor away from zero.
        let g = voxel_downsample(&[-0.1, 0.0, 0.1, 0.0], 2, 1.0, VoxelMethod::First).unwrap();
        assert_eq!(g.index.len(), 2);
        assert!(voxel_downsample(&pts, 2, 0.0, VoxelMethod::First).is_err());
        assert!(voxel_downsample(&pts, 2, f64::NAN, VoxelMethod::First).is_err());
    }

    #[test]
    fn subsample_is_seeded_and_distinct() {
        let a = random_subsample_indices(1000, 100, 42).unwrap();
        let b = random_subsample_indices(1000, 100, 42).unwrap();
        let c = random_subsample_indices(1000, 100, 43).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        assert!(random_subsample_indices(10, 11, 0).is_err());
    }

    #[test]
    fn crops() {
        let pts = [0.5, 0.0, 0.0, 2.0, 3.0, 4.0, -1.0, -1.0, -1.0];
        assert_eq!(crop_range(&pts, 3, 1.0, 6.0).unwrap(), vec![1, 2]);
        assert_eq!(
            crop_box(&pts, 3, &[-1.0, -1.0, -1.0], &[1.0, 1.0, 1.0]).unwrap(),
            vec![0, 2]
        );
        assert!(crop_range(&pts, 3, 2.0, 1.0).is_err());
        assert!(crop_box(&pts, 3, &[1.0, 0.0, 0.0], &[0.0, 1.0, 1.0]).is_err());
    }
}
