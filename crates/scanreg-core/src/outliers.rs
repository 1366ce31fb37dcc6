//! Outlier removal by neighbourhood statistics (on a prebuilt [`KdTree`]).

use crate::error::{Error, Result};
use crate::knn::{check_k, KdTree};
use crate::reduce::{chunked_sum, MIN_PAR_ITEMS};
use rayon::prelude::*;

/// Result of [`statistical_outliers`].
#[derive(Debug, Clone, PartialEq)]
pub struct StatisticalOutliers {
    /// Indices of the kept points, increasing.
    pub kept: Vec<usize>,
    /// Per input point: mean distance to its `k` nearest other points.
    pub mean_distance: Vec<f64>,
    /// Keep threshold `mean + std_ratio * std` over all points (sample std, `N - 1`).
    pub threshold: f64,
}

/// Statistical outlier removal (Rusu et al. 2008): for each point, the mean distance `d_i` to
/// its `k` nearest *other* points; keep the points with `d_i <= mean(d) + std_ratio * std(d)`.
/// Needs `1 <= k < N`.
pub fn statistical_outliers(
    tree: &KdTree,
    k: usize,
    std_ratio: f64,
) -> Result<StatisticalOutliers> {
    let n = tree.len();
    check_k("k", k, n.saturating_sub(1))?;
    if !std_ratio.is_finite() {
        return Err(Error::invalid(
            "std_ratio",
            format!("must be finite, got {std_ratio}"),
        ));
    }
    let mean_distance: Vec<f64> = (0..n)
        .into_par_iter()
        .with_min_len(MIN_PAR_ITEMS)
        .map_init(Vec::new, |buf, i| {
            buf.clear();
            tree.knn_into(tree.point(i), k + 1, f64::INFINITY, buf);
            // Drop the point itself (or, if a duplicate displaced it, the farthest).
            let skip = buf.iter().position(|x| x.0 as usize == i).unwrap_or(k);
            let s: f64 = buf
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != skip)
                .map(|(_, x)| x.1.sqrt())
                .sum();
            s / k as f64
        })
        .collect();
    let add = |a: (f64, f64), b: (f64, f64)| (a.0 + b.0, a.1 + b.1);
    let (sum, _) = chunked_sum(n, (0.0, 0.0), |r| (mean_distance[r].iter().sum(), 0.0), add);
    let mean = sum / n as f64;
    let (sq, _) = chunked_sum(
        n,
        (0.0, 0.0),
        |r| {
            (
                mean_distance[r]
                    .iter()
                    .map(|d| (d - mean) * (d - mean))
                    .sum(),
                0.0,
            )
        },
        add,
    );
    let std = if n > 1 {
        (sq / (n - 1) as f64).sqrt()
    } else {
        0.0
    };
    let threshold = mean + std_ratio * std;
    let kept = (0..n).filter(|&i| mean_distance[i] <= threshold).collect();
    Ok(StatisticalOutliers {
        kept,
        mean_distance,
        threshold,
    })
}

/// Radius outlier removal: keep the points with at least `min_neighbors` other points within
/// `radius` (inclusive). Returns the kept indices, increasing.
pub fn radius_outliers(tree: &KdTree, radius: f64, min_neighbors: usize) -> Result<Vec<usize>> {
    if !radius.is_finite() || radius <= 0.0 {
        return Err(Error::invalid(
            "radius",
            format!("must be finite and > 0, got {radius}"),
        ));
    }
    if min_neighbors < 1 {
        return Err(Error::invalid("min_neighbors", "must be >= 1, got 0"));
    }
    let sq = radius * radius;
    Ok((0..tree.len())
        .into_par_iter()
        .with_min_len(MIN_PAR_ITEMS)
        .map_init(Vec::new, |buf, i| {
            buf.clear();
            // The point itself is always within the radius, so `min_neighbors + 1` hits
            // (whichever ones) mean at least `min_neighbors` others.
            tree.knn_into(tree.point(i), min_neighbors + 1, sq, buf);
            (i, buf.len() > min_neighbors)
        })
        .filter(|(_, keep)| *keep)
        .map(|(i, _)| i)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planted_outliers_are_removed() {
        // A 20x20 grid of spacing 0.1 plus two far points.
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                pts.extend_from_slice(&[i as f64 * 0.1, j as f64 * 0.1]);
            }
        }
        pts.extend_from_slice(&[10.0, 10.0, -7.0, 3.0]);
        let tree = KdTree::build(&pts, 2).unwrap();
        let s = statistical_outliers(&tree, 8, 2.0).unwrap();
        assert_eq!(s.kept, (0..400).collect::<Vec<_>>());
        let r = radius_outliers(&tree, 0.15, 2).unwrap();
        assert_eq!(r, (0..400).collect::<Vec<_>>());
        assert!(statistical_outliers(&tree, 402, 2.0).is_err());
        assert!(radius_outliers(&tree, 0.0, 2).is_err());
    }
}
