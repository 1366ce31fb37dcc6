//! The odometry front end in one pass: range crop, then centroid voxel grids at two sizes.
//!
//! A sweep of ~120k points goes through crop and a fine grid (the points that join the map)
//! and a coarse grid of the fine points (the points registered). Done with generic tools that
//! is a filter, a gather, a sort-based grid and a second grid; here it is one hash-accumulation
//! pass over the input in order (so sums, and the output order — voxels in order of their
//! first point — do not depend on anything but the input), then a second over the fine grid.

use crate::error::{Error, Result};
use crate::normals::plane_covariance;
use crate::points::{check_points, floor_i64};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// The two grids of a sweep (row-major `N * dim`).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepGrids {
    pub fine: Vec<f64>,
    pub coarse: Vec<f64>,
    /// When asked for: per coarse point (`dim * dim` each), the plane-regularised covariance
    /// of the fine points it averages (see [`plane_covariance`]) — GICP's source covariances
    /// without a neighbour search.
    pub coarse_covariances: Option<Vec<f64>>,
    /// Points left after the range crop.
    pub num_in_range: usize,
}

fn check_voxel(arg: &'static str, v: f64) -> Result<f64> {
    if !v.is_finite() || v <= 0.0 {
        return Err(Error::invalid(
            arg,
            format!("must be finite and > 0, got {v}"),
        ));
    }
    Ok(1.0 / v)
}

/// Voxel indices (each within ±2^20, which `sweep_grids` checks through the crop) packed 21
/// bits per axis: hashing one u64 is a third of the work of three i64.
#[inline]
fn packed_key(p: &[f64], inv: f64) -> u64 {
    const OFF: i64 = 1 << 20;
    let mut key = 0u64;
    for &v in p {
        key = key << 21 | (floor_i64(v * inv) + OFF) as u64;
    }
    key
}

/// A voxel grid of `points` (those passing `keep`): centroids in order of first point, how
/// many points were kept, and (when `want_slots`) each kept point's voxel (its output row).
struct Grid {
    centroids: Vec<f64>,
    kept: usize,
    slots: Vec<u32>,
}

fn grid(
    points: &[f64],
    dim: usize,
    inv: f64,
    want_slots: bool,
    keep: impl Fn(&[f64]) -> bool + Sync,
) -> Grid {
    const DROPPED: u64 = u64::MAX; // packed keys use 63 bits at most
                                   // The per-point arithmetic (crop test, voxel key) in parallel chunks; the accumulation
                                   // below stays in input order, so sums and output order do not depend on the threads.
                                   // An indexed iterator: the keys are written in place, with no per-chunk vectors to join.
    let keys: Vec<u64> = points
        .par_chunks_exact(dim)
        .with_min_len(4096)
        .map(|p| if keep(p) { packed_key(p, inv) } else { DROPPED })
        .collect();
    // Sized for a typical sweep (a few points per voxel) so the table rarely grows mid-pass.
    let guess = points.len() / dim / 16 + 16;
    let mut index: FxHashMap<u64, u32> =
        FxHashMap::with_capacity_and_hasher(guess, Default::default());
    let mut sums: Vec<[f64; 4]> = Vec::with_capacity(guess);
    let mut slots = Vec::with_capacity(if want_slots { points.len() / dim } else { 0 });
    let mut kept = 0;
    // A sweep comes ring by ring: consecutive points mostly share a voxel, so the last
    // voxel's slot is remembered and the table (a cache miss each) consulted only on a change.
    let mut last: Option<(u64, u32)> = None;
    for (p, &key) in points.chunks_exact(dim).zip(&keys) {
        if key == DROPPED {
            continue;
        }
        kept += 1;
        let slot = match last {
            Some((k, s)) if k == key => s,
            _ => {
                let next = sums.len() as u32;
                let slot = *index.entry(key).or_insert(next);
                if slot == next {
                    sums.push([0.0; 4]);
                }
                last = Some((key, slot));
                slot
            }
        };
        if want_slots {
            slots.push(slot);
        }
        let s = &mut sums[slot as usize];
        for c in 0..dim {
            s[c] += p[c];
        }
        s[3] += 1.0;
    }
    let mut centroids = Vec::with_capacity(sums.len() * dim);
    for s in &sums {
        for c in 0..dim {
            centroids.push(s[c] / s[3]);
        }
    }
    Grid {
        centroids,
        kept,
        slots,
    }
}

/// Per voxel of `grid` (built over `points` with slots), the plane-regularised covariance of
/// its points about their centroid.
fn voxel_covariances(points: &[f64], dim: usize, grid: &Grid) -> Vec<f64> {
    let d2 = dim * dim;
    let voxels = grid.centroids.len() / dim;
    let mut moments = vec![0.0; voxels * d2];
    let mut counts = vec![0usize; voxels];
    for (p, &slot) in points.chunks_exact(dim).zip(&grid.slots) {
        let v = slot as usize;
        let mean = &grid.centroids[v * dim..(v + 1) * dim];
        let m = &mut moments[v * d2..(v + 1) * d2];
        for a in 0..dim {
            for b in 0..dim {
                m[a * dim + b] += (p[a] - mean[a]) * (p[b] - mean[b]);
            }
        }
        counts[v] += 1;
    }
    // The eigen-decompositions, one per voxel, in parallel (in place: same values on any
    // number of threads).
    moments
        .par_chunks_exact_mut(d2)
        .zip(counts.par_iter())
        .with_min_len(256)
        .for_each(|(m, &count)| {
            let mut full = [0.0; 9];
            full[..d2].copy_from_slice(m);
            m.copy_from_slice(&plane_covariance(&full, count, dim)[..d2]);
        });
    moments
}

/// Keep points with `min_range <= |p| <= max_range`, then centroid grids of `fine_voxel` over
/// them and of `coarse_voxel` over the fine centroids.
pub fn sweep_grids(
    points: &[f64],
    dim: usize,
    min_range: f64,
    max_range: f64,
    fine_voxel: f64,
    coarse_voxel: f64,
    coarse_covariances: bool,
) -> Result<SweepGrids> {
    check_points("points", points, dim)?;
    if !(min_range.is_finite() && min_range >= 0.0) {
        return Err(Error::invalid(
            "min_range",
            format!("must be finite and >= 0, got {min_range}"),
        ));
    }
    if !(max_range.is_finite() && max_range > min_range) {
        return Err(Error::invalid(
            "max_range",
            format!("must be finite and > min_range ({min_range}), got {max_range}"),
        ));
    }
    let fine_inv = check_voxel("fine_voxel", fine_voxel)?;
    let coarse_inv = check_voxel("coarse_voxel", coarse_voxel)?;
    // Voxel indices within the crop must fit `packed_key`'s 21 bits per axis.
    if (max_range * fine_inv.max(coarse_inv)).ceil() >= (1u64 << 20) as f64 - 1.0 {
        return Err(Error::invalid(
            "fine_voxel",
            "too small for max_range (voxel indices would overflow)",
        ));
    }
    let (lo, hi) = (min_range * min_range, max_range * max_range);
    let fine = grid(points, dim, fine_inv, false, |p| {
        let r2: f64 = p.iter().map(|v| v * v).sum();
        r2 >= lo && r2 <= hi
    });
    let coarse = grid(&fine.centroids, dim, coarse_inv, coarse_covariances, |_| {
        true
    });
    let covs = coarse_covariances.then(|| voxel_covariances(&fine.centroids, dim, &coarse));
    Ok(SweepGrids {
        fine: fine.centroids,
        coarse: coarse.centroids,
        coarse_covariances: covs,
        num_in_range: fine.kept,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::downsample::{crop_range, gather, voxel_downsample, VoxelMethod};

    fn cloud(n: usize) -> Vec<f64> {
        let mut s = 12345u64;
        (0..n * 3)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64) * 60.0 - 30.0
            })
            .collect()
    }

    /// Same points (as sets, to rounding) as crop + the generic grids.
    #[test]
    fn equals_crop_then_two_grids() {
        let pts = cloud(20000);
        let got = sweep_grids(&pts, 3, 2.0, 25.0, 0.5, 1.5, false).unwrap();
        let kept = crop_range(&pts, 3, 2.0, 25.0).unwrap();
        assert_eq!(got.num_in_range, kept.len());
        let cropped = gather(&pts, 3, &kept);
        let fine = voxel_downsample(&cropped, 3, 0.5, VoxelMethod::Centroid)
            .unwrap()
            .points;
        let coarse = voxel_downsample(&fine, 3, 1.5, VoxelMethod::Centroid)
            .unwrap()
            .points;
        for (a, b) in [(&got.fine, &fine), (&got.coarse, &coarse)] {
            assert_eq!(a.len(), b.len());
            let sort = |v: &Vec<f64>| {
                let mut rows: Vec<[f64; 3]> =
                    v.chunks_exact(3).map(|r| [r[0], r[1], r[2]]).collect();
                rows.sort_by(|x, y| x.partial_cmp(y).unwrap());
                rows
            };
            for (x, y) in sort(a).iter().zip(sort(b).iter()) {
                for c in 0..3 {
                    assert!((x[c] - y[c]).abs() < 1e-9, "{x:?} vs {y:?}");
                }
            }
        }
    }

    /// Each coarse point's covariance is the plane fit of the fine points it averages.
    #[test]
    fn coarse_covariances_fit_the_fine_points_of_each_voxel() {
        // A tilted plane z = 0.3 x + 5 sampled densely over [1.5, 3) x [1.5, 3) (one coarse
        // voxel of 1.5 m holding 3 x 3 columns of fine voxels of 0.5 m), and one lone point.
        let mut pts = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                let (x, y) = (1.525 + 0.05 * i as f64, 1.525 + 0.05 * j as f64);
                pts.extend_from_slice(&[x, y, 0.3 * x + 5.0]);
            }
        }
        pts.extend_from_slice(&[-8.2, 1.1, 0.4]);
        let g = sweep_grids(&pts, 3, 0.0, 50.0, 0.5, 1.5, true).unwrap();
        let covs = g.coarse_covariances.unwrap();
        assert_eq!(covs.len(), g.coarse.len() / 3 * 9);
        let n = nalgebra::Vector3::new(-0.3, 0.0, 1.0).normalize();
        assert_eq!(g.coarse.len(), 2 * 3);
        for (c, row) in g.coarse.chunks_exact(3).zip(covs.chunks_exact(9)) {
            let m = nalgebra::Matrix3::from_row_slice(row);
            if c[0] < 0.0 {
                assert_eq!(m, nalgebra::Matrix3::identity(), "a lone point: no plane");
                continue;
            }
            // Eigenvalues (1e-3, 1, 1) with the plane normal as the thin direction.
            let e = m.symmetric_eigen();
            let k = e.eigenvalues.imin();
            assert!((e.eigenvalues[k] - 1e-3).abs() < 1e-12);
            assert!((e.eigenvalues.sum() - 2.001).abs() < 1e-12);
            assert!(e.eigenvectors.column(k).dot(&n).abs() > 1.0 - 1e-9);
        }
        assert!(sweep_grids(&pts, 3, 0.0, 50.0, 0.5, 1.5, false)
            .unwrap()
            .coarse_covariances
            .is_none());
    }

    #[test]
    fn rejects_bad_arguments() {
        let pts = cloud(10);
        for (args, name) in [
            ((-1.0, 10.0, 0.5, 1.0), "min_range"),
            ((5.0, 1.0, 0.5, 1.0), "max_range"),
            ((0.0, 10.0, 0.0, 1.0), "fine_voxel"),
            ((0.0, 10.0, 0.5, f64::NAN), "coarse_voxel"),
            ((0.0, 1e300, 0.5, 1.0), "fine_voxel"),
        ] {
            let e = sweep_grids(&pts, 3, args.0, args.1, args.2, args.3, false).unwrap_err();
            assert!(e.to_string().starts_with(name), "{e}");
        }
        assert!(sweep_grids(&[f64::NAN, 0.0, 0.0], 3, 0.0, 1.0, 0.5, 1.0, false).is_err());
    }
}
