//! Fast Point Feature Histograms (Rusu, Blodow & Beetz 2009, "Fast Point Feature Histograms
//! (FPFH) for 3D registration", §IV).
//!
//! For a pair of oriented points `(p_s, n_s)`, `(p_t, n_t)` with `d = (p_t − p_s)/|p_t − p_s|`,
//! the *source* of the pair is the point whose normal makes the smaller angle with the line
//! joining them (`|n_s·d| >= |n_t·d|`, else the two swap and `d` flips), so the features do not
//! depend on the order of the pair. In the Darboux frame `u = n_s`, `v = d × u / |d × u|`,
//! `w = u × v`:
//!
//! * `θ = atan2(w·n_t, u·n_t)` in `[−π, π]`,
//! * `α = v·n_t` in `[−1, 1]`,
//! * `φ = u·d` in `[−1, 1]`.
//!
//! The simplified histogram `SPFH(p)` bins the three features of `p` with each of its
//! neighbours into 11 equal bins per feature (33 values), each pair adding `100 / m` (`m` the
//! number of pairs with a defined frame), so each 11-bin block sums to 100. Then
//! `FPFH(p) = SPFH(p) + Σ_k SPFH(p_k) / ω_k / Σ_k 1/ω_k` with `ω_k = |p − p_k|`: Rusu's
//! Eq. 4 with the neighbours' weights normalised to sum to one instead of `1/k` times their
//! sum (Eq. 4 is not unit-free; Open3D normalises the same way), and each block is rescaled
//! to sum to 100 again. The neighbourhood of `p` is its
//! `max_neighbors` nearest points within `radius`, `p` itself and points without a normal
//! excluded. A point with no usable neighbour has an all-zero descriptor.

use crate::error::{Error, Result};
use crate::knn::KdTree;
use rayon::prelude::*;

/// Bins per feature.
pub const BINS: usize = 11;
/// Length of one descriptor.
pub const FPFH_DIM: usize = 3 * BINS;

#[inline]
fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn row(data: &[f64], i: usize) -> [f64; 3] {
    [data[3 * i], data[3 * i + 1], data[3 * i + 2]]
}

/// `(θ, α, φ)` of a pair of oriented points, or `None` when the frame is undefined (coincident
/// points, or the source normal parallel to the joining line).
pub fn pair_features(
    p1: &[f64; 3],
    n1: &[f64; 3],
    p2: &[f64; 3],
    n2: &[f64; 3],
) -> Option<(f64, f64, f64)> {
    pair_frame(p1, n1, p2, n2).map(|(y, x, alpha, phi)| (y.atan2(x), alpha, phi))
}

/// `(w·n_t, u·n_t, α, φ)`: [`pair_features`] with `θ` left as the two arguments of its
/// arctangent.
#[inline]
fn pair_frame(
    p1: &[f64; 3],
    n1: &[f64; 3],
    p2: &[f64; 3],
    n2: &[f64; 3],
) -> Option<(f64, f64, f64, f64)> {
    let mut d = [p2[0] - p1[0], p2[1] - p1[1], p2[2] - p1[2]];
    let len = dot(&d, &d).sqrt();
    if len == 0.0 {
        return None;
    }
    d.iter_mut().for_each(|x| *x /= len);
    let a1 = dot(n1, &d);
    let a2 = dot(n2, &d);
    let (u, nt, phi) = if a1.abs() >= a2.abs() {
        (n1, n2, a1)
    } else {
        d.iter_mut().for_each(|x| *x = -*x);
        (n2, n1, -a2)
    };
    let v = cross(&d, u);
    let vn = dot(&v, &v).sqrt();
    if vn == 0.0 {
        return None;
    }
    let v = [v[0] / vn, v[1] / vn, v[2] / vn];
    let w = cross(u, &v);
    Some((dot(&w, nt), dot(u, nt), dot(&v, nt), phi))
}

/// `cos` of the θ bin edges in `(0, π)`, `π/11, 3π/11, …, 9π/11` (the edges are
/// `−π + k·2π/11`; the middle bin straddles 0).
const THETA_EDGE_COS: [f64; 5] = [
    0.959_492_973_614_497_4,
    0.654_860_733_945_285_1,
    0.142_314_838_273_285_12,
    -0.415_415_013_001_886_3,
    -0.841_253_532_831_181_1,
];

/// The bin of `θ = atan2(y, x)` in `[−π, π]`, as [`bin`] gives it, without the arctangent (a
/// third of the descriptor stage's time): `|θ|` passes an edge `β` where `x ≤ r cos β`
/// (`r = |(x, y)|`), and the sign of `y` (a signed zero as `atan2` reads it) says on which
/// side of the middle bin. Equal to [`bin`] of `atan2` except within a rounding of an edge.
#[inline]
fn theta_bin(y: f64, x: f64) -> usize {
    let r = (x * x + y * y).sqrt();
    if !(r > 0.0 && r.is_finite()) {
        return bin(y.atan2(x), -std::f64::consts::PI, std::f64::consts::PI);
    }
    let passed = THETA_EDGE_COS.iter().filter(|&&c| x <= r * c).count();
    if y.is_sign_negative() {
        // θ in [−π, 0]: 5 bins below the middle one, left as |θ| passes each edge.
        BINS / 2 - passed
    } else {
        BINS / 2 + passed
    }
}

#[inline]
fn bin(value: f64, lo: f64, hi: f64) -> usize {
    let b = ((value - lo) / (hi - lo) * BINS as f64).floor();
    if b.is_nan() || b < 0.0 {
        0
    } else {
        (b as usize).min(BINS - 1)
    }
}

/// The neighbours of every point: up to `max_neighbors` nearest within `radius`, itself and
/// points without a normal (`valid` false) left out, with their distances; none for an
/// invalid point. Input order. (A radius search then a cut: a bounded `max_neighbors + 1`-NN
/// search kept a sorted buffer of 101 and took longer.)
pub fn neighbourhoods(
    tree: &KdTree,
    valid: &[bool],
    radius: f64,
    max_neighbors: usize,
) -> Vec<Vec<(u32, f64)>> {
    let n = tree.len();
    let sq = radius * radius;
    (0..n)
        .into_par_iter()
        .map_init(Vec::new, |buf, i| {
            buf.clear();
            if !valid[i] {
                return Vec::new();
            }
            tree.radius_into(tree.point(i), sq, buf);
            buf.iter()
                .filter(|&&(j, _)| j as usize != i && valid[j as usize])
                .take(max_neighbors)
                .map(|&(j, d2)| (j, d2.sqrt()))
                .collect()
        })
        .collect()
}

/// Whether each row of `normals` (`N * 3`) is a unit normal (zero marks none).
pub fn has_normal(normals: &[f64]) -> Vec<bool> {
    normals
        .chunks_exact(3)
        .map(|m| m[0] * m[0] + m[1] * m[1] + m[2] * m[2] > 0.5)
        .collect()
}

/// FPFH descriptors of the points indexed by `tree`, `N * 33` row-major (`f32`: the
/// correspondence search reads them in that precision), and whether each is defined.
///
/// `normals` is `N * 3` unit vectors, zero where a point has none (it then gets no descriptor
/// and is nobody's neighbour).
pub fn fpfh(
    tree: &KdTree,
    normals: &[f64],
    radius: f64,
    max_neighbors: usize,
) -> Result<(Vec<f32>, Vec<bool>)> {
    let n = tree.len();
    if tree.dim() != 3 {
        return Err(Error::invalid(
            "points",
            "FPFH is defined for 3D points only",
        ));
    }
    if normals.len() != 3 * n {
        return Err(Error::invalid(
            "normals",
            format!("expected {} values (N x 3), got {}", 3 * n, normals.len()),
        ));
    }
    if normals.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid("normals", "has a non-finite value"));
    }
    if !radius.is_finite() || radius <= 0.0 {
        return Err(Error::invalid(
            "feature_radius",
            format!("must be finite and > 0, got {radius}"),
        ));
    }
    if max_neighbors == 0 {
        return Err(Error::invalid("max_neighbors", "must be >= 1"));
    }
    let valid = has_normal(normals);
    let nbrs = neighbourhoods(tree, &valid, radius, max_neighbors);
    Ok(fpfh_from(tree, normals, &nbrs))
}

/// [`fpfh`] over neighbourhoods already found by [`neighbourhoods`] (inputs checked there).
pub fn fpfh_from(
    tree: &KdTree,
    normals: &[f64],
    nbrs: &[Vec<(u32, f64)>],
) -> (Vec<f32>, Vec<bool>) {
    let n = tree.len();
    let pts = tree.points();
    let spfh: Vec<[f64; FPFH_DIM]> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut h = [0.0; FPFH_DIM];
            let (p, np) = (row(pts, i), row(normals, i));
            // Counts first, scaled once the number of defined pairs is known.
            let mut m = 0usize;
            for &(j, _) in &nbrs[i] {
                let q = (row(pts, j as usize), row(normals, j as usize));
                if let Some((y, x, alpha, phi)) = pair_frame(&p, &np, &q.0, &q.1) {
                    h[theta_bin(y, x)] += 1.0;
                    h[BINS + bin(alpha, -1.0, 1.0)] += 1.0;
                    h[2 * BINS + bin(phi, -1.0, 1.0)] += 1.0;
                    m += 1;
                }
            }
            if m > 0 {
                let inc = 100.0 / m as f64;
                h.iter_mut().for_each(|v| *v *= inc);
            }
            h
        })
        .collect();
    let rows: Vec<([f32; FPFH_DIM], bool)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut f = spfh[i];
            let k = nbrs[i].len();
            if k == 0 || f.iter().all(|&v| v == 0.0) {
                return ([0.0; FPFH_DIM], false);
            }
            // Σ_k SPFH(p_k) / ω_k, rescaled to the mass of SPFH(p) (Rusu's 1/k leaves the
            // balance between p and its neighbours to the unit of length: in metres at a
            // 5 cm voxel the neighbours outweighed p tenfold, and matching got worse).
            let mut nb = [0.0; FPFH_DIM];
            let mut wsum = 0.0;
            for &(j, dist) in &nbrs[i] {
                if dist == 0.0 {
                    continue; // a duplicate point: the weight is undefined
                }
                let w = 1.0 / dist;
                wsum += w;
                for (a, b) in nb.iter_mut().zip(spfh[j as usize].iter()) {
                    *a += w * b;
                }
            }
            if wsum > 0.0 {
                for (a, b) in f.iter_mut().zip(nb.iter()) {
                    *a += b / wsum;
                }
            }
            let mut out = [0.0f32; FPFH_DIM];
            for block in 0..3 {
                let s: f64 = f[block * BINS..(block + 1) * BINS].iter().sum();
                if s > 0.0 {
                    for c in block * BINS..(block + 1) * BINS {
                        out[c] = (f[c] * 100.0 / s) as f32;
                    }
                }
            }
            (out, true)
        })
        .collect();
    let mut desc = Vec::with_capacity(n * FPFH_DIM);
    let mut ok = Vec::with_capacity(n);
    for (r, v) in rows {
        desc.extend_from_slice(&r);
        ok.push(v);
    }
    (desc, ok)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_features_do_not_depend_on_the_order_of_the_pair() {
        let p1 = [0.0, 0.0, 0.0];
        let n1 = [0.0, 0.0, 1.0];
        let p2 = [1.0, 0.5, 0.2];
        let s = (0.3f64, 0.1f64, 1.0f64);
        let l = (s.0 * s.0 + s.1 * s.1 + s.2 * s.2).sqrt();
        let n2 = [s.0 / l, s.1 / l, s.2 / l];
        let a = pair_features(&p1, &n1, &p2, &n2).unwrap();
        let b = pair_features(&p2, &n2, &p1, &n1).unwrap();
        assert!((a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12);
        assert!((a.2 - b.2).abs() < 1e-12);
    }

    #[test]
    fn theta_bins_equal_the_arctangent_s() {
        // Every direction on a fine circle, the signed zeros and the axes included.
        let pi = std::f64::consts::PI;
        let mut cases: Vec<(f64, f64)> = (0..100_000)
            .map(|k| {
                let a = -pi + 2.0 * pi * (k as f64 + 0.37) / 100_000.0;
                (a.sin() * 0.7, a.cos() * 0.7)
            })
            .collect();
        cases.extend([
            (0.0, 1.0),
            (-0.0, 1.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 0.0),
        ]);
        cases.extend([(-1.0, 0.0), (0.0, 0.0), (-0.0, -0.0), (1e-300, -1.0)]);
        for (y, x) in cases {
            assert_eq!(theta_bin(y, x), bin(y.atan2(x), -pi, pi), "y {y} x {x}");
        }
        for (k, c) in THETA_EDGE_COS.iter().enumerate() {
            assert!((c - ((2 * k + 1) as f64 * pi / 11.0).cos()).abs() < 1e-15);
        }
    }

    #[test]
    fn a_plane_puts_every_pair_in_one_bin_per_feature() {
        let mut pts = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                pts.extend_from_slice(&[i as f64 * 0.1, j as f64 * 0.1, 0.0]);
            }
        }
        let normals: Vec<f64> = (0..100).flat_map(|_| [0.0, 0.0, 1.0]).collect();
        let tree = KdTree::build(&pts, 3).unwrap();
        let (d, ok) = fpfh(&tree, &normals, 0.25, 50).unwrap();
        assert!(ok.iter().all(|&v| v));
        // Coplanar, parallel normals: θ = 0, α = 0, φ = 0 -> the middle bin of each block.
        for i in 0..100 {
            let r = &d[i * FPFH_DIM..(i + 1) * FPFH_DIM];
            for b in 0..3 {
                assert!((r[b * BINS + 5] - 100.0).abs() < 1e-3, "{r:?}");
            }
        }
    }
}
