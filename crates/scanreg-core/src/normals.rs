//! Local geometry by k-NN PCA: normals and (regularised) covariances, 2D and 3D.
//!
//! For point `i`, the neighbourhood is its `k` nearest points (itself included), sorted by
//! (distance, index); `C_i = (1/k) Σ (q - q̄)(q - q̄)ᵀ`, eigenvalues `λ_0 <= λ_1 [<= λ_2]` with
//! eigenvectors `v_j`. The normal is `v_0`, flipped so that `n · (viewpoint - p_i) >= 0`.
//!
//! A neighbourhood is *degenerate* when it does not span a line (2D) or a plane (3D):
//! `λ_max == 0` (all points coincide), or in 3D `λ_1 <= 1e-9 λ_2` (all collinear). Then the
//! normal is undefined: `valid[i] = false`, the normal is the zero vector and the covariance is
//! the identity (an isotropic, uninformative 1 m² blob), whatever the regularisation.
//!
//! A 3D neighbourhood can also be *linear*: a ring of a spinning LiDAR, a pole, an edge. Its
//! normal is then any direction across the line, picked by the noise, and a point-to-plane
//! correspondence with it pulls the pose along that arbitrary direction (in a simulated street
//! the x error of point-to-plane went from 2.6 cm to 0.65 cm once these were left out; on a
//! real outdoor pair rotation got worse, so callers opt in). With `drop_linear` such points get
//! no normal (zero; `valid` and the covariance are unchanged). The
//! rule is Demantké et al. 2011 (dimensionality features from `σ_j = √λ_j`,
//! `σ_1 >= σ_2 >= σ_3`): linear when `a1D = (σ_1 - σ_2)/σ_1` is at least both
//! `a2D = (σ_2 - σ_3)/σ_1` and `a3D = σ_3/σ_1` — about `λ_2 < λ_1 / 4` for a thin neighbourhood.

#![allow(clippy::needless_range_loop)] // fixed-size coordinate loops read better indexed

use crate::error::{Error, Result};
use crate::knn::{check_k, KdTree};
use crate::reduce::SEQUENTIAL_MAX;
use crate::symeig;
use rayon::prelude::*;

/// Relative eigenvalue below which a 3D neighbourhood counts as collinear.
pub const DEGENERATE_RATIO: f64 = 1e-9;

/// How covariances are regularised for GICP.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Regularization {
    /// The raw sample covariance.
    None,
    /// Segal et al. 2009 (Generalized-ICP, §III-B): eigenvalues replaced by `(ε, 1, 1)` in 3D,
    /// `(ε, 1)` in 2D: every point is a unit disc (segment) with thickness `ε`.
    Plane(f64),
    /// Eigenvalues divided by the largest and clamped below at `ε`: keeps the shape of the
    /// neighbourhood (a line stays a line) at unit scale.
    NormalizedMinEig(f64),
}

impl Regularization {
    pub fn from_name(name: &str, epsilon: f64) -> Result<Self> {
        if !epsilon.is_finite() || epsilon <= 0.0 {
            return Err(Error::invalid(
                "epsilon",
                format!("must be finite and > 0, got {epsilon}"),
            ));
        }
        match name {
            "none" => Ok(Regularization::None),
            "plane" => Ok(Regularization::Plane(epsilon)),
            "normalized_min_eig" => Ok(Regularization::NormalizedMinEig(epsilon)),
            other => Err(Error::invalid(
                "regularization",
                format!("unknown {other:?}; expected 'plane', 'normalized_min_eig' or 'none'"),
            )),
        }
    }
}

/// Per-point local geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalGeometry {
    /// `N * dim` unit normals (zero where invalid), when requested.
    pub normals: Option<Vec<f64>>,
    /// `N * dim * dim` row-major covariances (identity where invalid), when requested.
    pub covariances: Option<Vec<f64>>,
    /// Whether the neighbourhood of each point was non-degenerate.
    pub valid: Vec<bool>,
    pub num_invalid: usize,
    /// Valid points whose 3D neighbourhood is linear (a ring of a sparse LiDAR, a pole, an
    /// edge: its fitted normal can point anywhere about the line); left without a normal only
    /// with `drop_linear`. All false in 2D.
    pub linear: Vec<bool>,
    /// How many of `linear` are true.
    pub num_linear: usize,
    /// Each point's nearest other point (the second of its `k` neighbours, sorted by (squared
    /// distance, index), as a 2-NN query finds it), `u32::MAX` for none.
    pub nearest: Vec<u32>,
}

impl LocalGeometry {
    /// `(ε̂², ε̃²)` of the normals, as [`crate::normal_noise::target_normal_noise`] of the same
    /// tree gives them, from the neighbours the normals were computed from (no second search);
    /// None without normals.
    pub fn normal_noise(&self, dim: usize) -> Option<(f64, f64)> {
        let normals = self.normals.as_ref()?;
        Some(crate::normal_noise::noise_with_neighbour(
            normals,
            dim,
            |i| {
                self.nearest
                    .get(i)
                    .filter(|&&j| j != u32::MAX)
                    .map(|&j| j as usize)
            },
        ))
    }

    /// The median spacing of `tree`'s points ([`crate::trust::scene::median_spacing`]) from the
    /// nearest neighbours these normals were computed from (no second search): the same
    /// squared distances, in the same arithmetic, as the 2-NN pass.
    pub fn spacing(&self, tree: &KdTree) -> f64 {
        let d2 = self
            .nearest
            .iter()
            .enumerate()
            .map(|(i, &j)| {
                if j == u32::MAX {
                    return f64::NAN;
                }
                let (p, q) = (tree.point(i), tree.point(j as usize));
                let mut d = 0.0;
                for c in 0..p.len() {
                    let e = p[c] - q[c];
                    d += e * e;
                }
                d
            })
            .collect();
        crate::trust::scene::median_of_squared(d2)
    }
}

/// Demantké et al. 2011: the neighbourhood with ascending eigenvalues `vals` is linear (its
/// one-dimensional feature `a1D` is the largest of the three).
pub fn is_linear(vals: &[f64; 3]) -> bool {
    let s = vals.map(|l| l.max(0.0).sqrt());
    let (s1, s2, s3) = (s[2], s[1], s[0]);
    let a1 = s1 - s2;
    a1 >= s2 - s3 && a1 >= s3
}

/// GICP's plane-regularised covariance from the centred second moment `m` (row-major
/// `dim x dim` in a 3x3 array) of `count` points: unit eigenvalues along the surface and `1e-3`
/// along its normal (the smallest-eigenvalue direction; Segal et al. 2009). With fewer than
/// `dim + 2` points the surface is not known: the identity (a point-to-point-like factor).
pub(crate) fn plane_covariance(m: &[f64; 9], count: usize, dim: usize) -> [f64; 9] {
    const EPSILON: f64 = 1e-3;
    let mut cov = [0.0; 9];
    if count < dim + 2 {
        for c in 0..dim {
            cov[c * dim + c] = 1.0;
        }
        return cov;
    }
    // A line-like voxel (one scan ring) still gets its best-fit plane: measured, replacing it
    // by the identity doubled the rotation drift of a VLP-16 street drive.
    let (_, vecs) = eigen(m, dim);
    for (k, v) in vecs.iter().enumerate().take(dim) {
        let w = if k == 0 { EPSILON } else { 1.0 };
        for a in 0..dim {
            for b in 0..dim {
                cov[a * dim + b] += w * v[a] * v[b];
            }
        }
    }
    cov
}

/// Eigen-decomposition of a symmetric matrix: eigenvalues ascending and the matching unit
/// eigenvectors, as `dim x dim` column-major `[v_0 | v_1 | v_2]` (closed form, [`crate::symeig`]).
#[inline]
pub(crate) fn eigen(c: &[f64; 9], dim: usize) -> ([f64; 3], [[f64; 3]; 3]) {
    if dim == 2 {
        let (l, v) = symeig::sym2(c[0], c[1], c[3]);
        (
            [l[0], l[1], 0.0],
            [[v[0][0], v[0][1], 0.0], [v[1][0], v[1][1], 0.0], [0.0; 3]],
        )
    } else {
        symeig::sym3(c)
    }
}

/// Centred second moment `(1/m) Σ (q − q̄)(q − q̄)ᵀ` of the neighbours `buf` (row-major
/// `dim x dim` in a 3x3 array). Two passes: mean, then centred sum (no cancellation far from 0).
pub(crate) fn scatter(tree: &KdTree, buf: &[(u32, f64)]) -> [f64; 9] {
    if tree.dim() == 3 {
        scatter_of::<3>(tree.points(), buf)
    } else {
        scatter_of::<2>(tree.points(), buf)
    }
}

/// [`scatter`] for a fixed dimension: the loops unrolled, the same sums in the same order.
#[inline(always)]
fn scatter_of<const D: usize>(points: &[f64], buf: &[(u32, f64)]) -> [f64; 9] {
    let point = |j: u32| -> &[f64] { &points[j as usize * D..j as usize * D + D] };
    let mut mean = [0.0; 3];
    for &(j, _) in buf.iter() {
        let q = point(j);
        for c in 0..D {
            mean[c] += q[c];
        }
    }
    let m = buf.len() as f64;
    for v in mean.iter_mut() {
        *v /= m;
    }
    let mut cov = [0.0; 9];
    for &(j, _) in buf.iter() {
        let q = point(j);
        let mut d = [0.0; 3];
        for c in 0..D {
            d[c] = q[c] - mean[c];
        }
        for r in 0..D {
            for c in r..D {
                cov[r * D + c] += d[r] * d[c];
            }
        }
    }
    for r in 0..D {
        for c in r..D {
            cov[r * D + c] /= m;
            cov[c * D + r] = cov[r * D + c];
        }
    }
    cov
}

/// `Σ_j λ_j v_j v_jᵀ` (row-major `D x D` in a 3x3 array), summed over `j` in order.
#[inline(always)]
fn from_eigen<const D: usize>(lam: &[f64; 3], vecs: &[[f64; 3]; 3]) -> [f64; 9] {
    let mut out = [0.0; 9];
    for (j, v) in vecs.iter().enumerate().take(D) {
        for r in 0..D {
            for c in 0..D {
                out[r * D + c] += lam[j] * v[r] * v[c];
            }
        }
    }
    out
}

/// Whether a neighbourhood with ascending eigenvalues `vals` spans a line (2D) or a plane
/// (3D): the module's non-degeneracy rule.
pub(crate) fn spans(vals: &[f64; 3], dim: usize) -> bool {
    let lmax = vals[dim - 1];
    lmax > 0.0 && (dim == 2 || vals[1] > DEGENERATE_RATIO * lmax)
}

/// The unit vector `v` (a normal of the point `p`), flipped to face `viewpoint`.
pub(crate) fn facing(v: &[f64; 3], p: &[f64], viewpoint: &[f64], dim: usize) -> [f64; 3] {
    let mut normal = [0.0; 3];
    normal[..dim].copy_from_slice(&v[..dim]);
    let toward: f64 = (0..dim).map(|c| normal[c] * (viewpoint[c] - p[c])).sum();
    if toward < 0.0 {
        normal.iter_mut().for_each(|x| *x = -*x);
    }
    normal
}

/// Normals and/or covariances of every indexed point from its `k` nearest neighbours.
/// `viewpoint` has `dim` coordinates; `k` must be in `dim..=N`. Linear 3D neighbourhoods keep
/// their normal (see [`local_geometry_with`]).
pub fn local_geometry(
    tree: &KdTree,
    k: usize,
    viewpoint: &[f64],
    want_normals: bool,
    covariances: Option<Regularization>,
) -> Result<LocalGeometry> {
    local_geometry_with(tree, k, viewpoint, want_normals, covariances, false)
}

/// One worker's k-NN buffer and its previous query (point, k-th squared distance). Queries run
/// in leaf order, so consecutive points are close: the k neighbours of the previous point `p'`
/// lie within `√d'_k + |p − p'|` of `p`, a bound that prunes the search from its first node on
/// (the unbounded search accepts every point of the first leaves until it holds k). Exact: when
/// the bounded search finds k points they are the k nearest, and if rounding ever left it
/// short the query is repeated unbounded.
pub(crate) struct Scratch {
    buf: Vec<(u32, f64)>,
    prev: Option<(usize, f64)>,
}

impl Scratch {
    pub(crate) fn new(k: usize) -> Self {
        Scratch {
            buf: Vec::with_capacity(k + 1),
            prev: None,
        }
    }

    pub(crate) fn neighbours(&mut self, tree: &KdTree, i: usize, k: usize) -> &[(u32, f64)] {
        self.buf.clear();
        let p = tree.point(i);
        let bound = self.prev.map_or(f64::INFINITY, |(j, dk)| {
            let q = tree.point(j);
            let step: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            let r = dk.sqrt() + step.sqrt();
            r * r * (1.0 + 1e-9) + f64::MIN_POSITIVE
        });
        tree.knn_into(p, k, bound, &mut self.buf);
        if self.buf.len() < k && bound < f64::INFINITY {
            self.buf.clear();
            tree.knn_into(p, k, f64::INFINITY, &mut self.buf);
        }
        self.prev = self.buf.last().map(|&(_, dk)| (i, dk));
        &self.buf
    }
}

/// The unit normal [`local_geometry`] gives point `p` of a 3D `tree` from its `neighbours`
/// (its k nearest, itself included, sorted by (squared distance, index)) oriented towards
/// `viewpoint`, or zero where the neighbourhood has no plane: for a caller that found the
/// neighbours in a larger search already.
pub(crate) fn normal_from(
    tree: &KdTree,
    p: &[f64],
    neighbours: &[(u32, f64)],
    viewpoint: &[f64; 3],
) -> [f64; 3] {
    let (vals, vecs) = eigen(&scatter(tree, neighbours), 3);
    if spans(&vals, 3) {
        facing(&vecs[0], p, viewpoint, 3)
    } else {
        [0.0; 3]
    }
}

/// `f` over the points in the tree's leaf order (`order`), in parallel unless the cloud is
/// small (a 2D scan: waking the pool costs more), each worker with its own [`Scratch`].
fn in_leaf_order<T: Send>(
    n: usize,
    order: &[u32],
    k: usize,
    f: &(impl Fn(&mut Scratch, &u32) -> T + Sync),
) -> Vec<T> {
    if n <= SEQUENTIAL_MAX {
        let mut state = Scratch::new(k);
        order.iter().map(|i| f(&mut state, i)).collect()
    } else {
        order.par_iter().map_init(|| Scratch::new(k), f).collect()
    }
}

/// [`local_geometry`], and with `drop_linear` no normal (zero) where a 3D neighbourhood is
/// linear (module docs).
pub fn local_geometry_with(
    tree: &KdTree,
    k: usize,
    viewpoint: &[f64],
    want_normals: bool,
    covariances: Option<Regularization>,
    drop_linear: bool,
) -> Result<LocalGeometry> {
    let dim = tree.dim();
    let n = tree.len();
    check_k("k", k, n)?;
    if k < dim {
        return Err(Error::invalid(
            "k",
            format!(
                "must be >= {dim} to fit a {} in {dim}D, got {k}",
                if dim == 2 { "line" } else { "plane" }
            ),
        ));
    }
    if viewpoint.len() != dim || viewpoint.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "viewpoint",
            format!("expected {dim} finite coordinates, got {viewpoint:?}"),
        ));
    }
    // Points in the tree's leaf order: consecutive queries share most of their traversal, which
    // keeps it in cache. Each result is computed independently, then put back in input order.
    let order = tree.leaf_order();
    let geometry = |state: &mut Scratch, &i: &u32| {
        let i = i as usize;
        let p = tree.point(i);
        let buf = state.neighbours(tree, i, k);
        let nearest = buf.get(1).map_or(u32::MAX, |&(j, _)| j);
        let cov = scatter(tree, buf);
        let (vals, vecs) = eigen(&cov, dim);
        let lmax = vals[dim - 1];
        let valid = spans(&vals, dim);
        let mut normal = [0.0; 3];
        let linear = dim == 3 && valid && is_linear(&vals);
        if valid && !(drop_linear && linear) {
            normal = facing(&vecs[0], p, viewpoint, dim);
        }
        let mut out = [0.0; 9];
        match (valid, covariances) {
            (_, None) => {}
            (false, Some(_)) => {
                for r in 0..dim {
                    out[r * dim + r] = 1.0;
                }
            }
            (true, Some(reg)) => {
                let lam: [f64; 3] = match reg {
                    Regularization::None => vals,
                    Regularization::Plane(eps) => [eps, 1.0, 1.0],
                    Regularization::NormalizedMinEig(eps) => {
                        [vals[0] / lmax, vals[1] / lmax, vals[2] / lmax].map(|l| l.max(eps))
                    }
                };
                if matches!(reg, Regularization::None) {
                    out = cov;
                } else {
                    // C = Σ_j λ_j v_j v_jᵀ
                    out = if dim == 3 {
                        from_eigen::<3>(&lam, &vecs)
                    } else {
                        from_eigen::<2>(&lam, &vecs)
                    };
                }
            }
        }
        (normal, out, valid, linear, nearest)
    };
    // Results in leaf order, then each put in its input slot. Only what was asked for is
    // kept per point (a covariance is 72 bytes): this buffer is the call's peak memory.
    let mut normals = want_normals.then(|| vec![0.0; n * dim]);
    let mut covs = covariances.map(|_| vec![0.0; n * dim * dim]);
    let mut valid = vec![false; n];
    let mut linear = vec![false; n];
    let mut nearest = vec![u32::MAX; n];
    let mut place =
        |i: usize, normal: &[f64; 3], cov: Option<&[f64; 9]>, ok: bool, lin: bool, near: u32| {
            if let Some(out) = normals.as_mut() {
                out[i * dim..(i + 1) * dim].copy_from_slice(&normal[..dim]);
            }
            if let (Some(out), Some(c)) = (covs.as_mut(), cov) {
                out[i * dim * dim..(i + 1) * dim * dim].copy_from_slice(&c[..dim * dim]);
            }
            valid[i] = ok;
            linear[i] = lin;
            nearest[i] = near;
        };
    if covariances.is_some() {
        for (&i, (nrm, cov, ok, lin, near)) in
            order.iter().zip(in_leaf_order(n, order, k, &geometry))
        {
            place(i as usize, &nrm, Some(&cov), ok, lin, near);
        }
    } else {
        let without_cov = |st: &mut Scratch, i: &u32| {
            let (nrm, _, ok, lin, near) = geometry(st, i);
            (nrm, ok, lin, near)
        };
        for (&i, (nrm, ok, lin, near)) in order.iter().zip(in_leaf_order(n, order, k, &without_cov))
        {
            place(i as usize, &nrm, None, ok, lin, near);
        }
    }
    let num_invalid = valid.iter().filter(|v| !**v).count();
    let num_linear = linear.iter().filter(|v| **v).count();
    Ok(LocalGeometry {
        normals,
        covariances: covs,
        valid,
        num_invalid,
        linear,
        num_linear,
        nearest,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_normals_and_covariances() {
        // Grid on the plane z = 2 (normal ±z), viewpoint at the origin: normals point down.
        let mut pts = Vec::new();
        for i in 0..15 {
            for j in 0..15 {
                pts.extend_from_slice(&[i as f64 * 0.1, j as f64 * 0.13, 2.0]);
            }
        }
        let tree = KdTree::build(&pts, 3).unwrap();
        let g = local_geometry(
            &tree,
            10,
            &[0.0, 0.0, 0.0],
            true,
            Some(Regularization::Plane(1e-3)),
        )
        .unwrap();
        assert_eq!(g.num_invalid, 0);
        let nrm = g.normals.unwrap();
        let cov = g.covariances.unwrap();
        for i in 0..tree.len() {
            assert!((nrm[3 * i + 2] + 1.0).abs() < 1e-12);
            // (ε, 1, 1) with the ε axis along z.
            assert!((cov[9 * i + 8] - 1e-3).abs() < 1e-12);
            assert!((cov[9 * i] - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn bounded_neighbour_search_equals_the_unbounded_one() {
        // Scratch bounds each query by the previous one's k-th distance: the neighbour lists
        // must be exactly the unbounded k-NN, on random clouds and on grids (ties, duplicates).
        let mut seed = 99u64;
        let mut unit = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for (dim, grid) in [(2, false), (2, true), (3, false), (3, true)] {
            let pts: Vec<f64> = (0..600 * dim)
                .map(|_| {
                    if grid {
                        (unit() * 6.0).floor()
                    } else {
                        unit() * 20.0
                    }
                })
                .collect();
            let tree = KdTree::build(&pts, dim).unwrap();
            for k in [3, 10, 20] {
                let mut state = Scratch::new(k);
                for &i in tree.leaf_order() {
                    let got = state.neighbours(&tree, i as usize, k).to_vec();
                    let mut want = Vec::new();
                    tree.knn_into(tree.point(i as usize), k, f64::INFINITY, &mut want);
                    assert_eq!(got, want, "dim {dim} grid {grid} k {k} point {i}");
                }
            }
        }
    }

    #[test]
    fn collinear_is_invalid() {
        let pts: Vec<f64> = (0..10)
            .flat_map(|i| [i as f64, 2.0 * i as f64, 0.5])
            .collect();
        let tree = KdTree::build(&pts, 3).unwrap();
        let g = local_geometry(&tree, 5, &[0.0; 3], true, Some(Regularization::None)).unwrap();
        assert_eq!(g.num_invalid, 10);
        assert!(g.normals.unwrap().iter().all(|v| *v == 0.0));
        assert!(local_geometry(&tree, 2, &[0.0; 3], true, None).is_err());
        assert!(local_geometry(&tree, 11, &[0.0; 3], true, None).is_err());
        assert!(local_geometry(&tree, 5, &[0.0; 2], true, None).is_err());
    }

    #[test]
    fn linear_neighbourhoods_lose_their_normal_only_when_asked() {
        // A 3 cm-wide strip along x (a LiDAR ring on a wall: its neighbourhoods are lines) and
        // a 1 m square patch, both on the plane z = 1.
        let mut pts = Vec::new();
        for i in 0..40 {
            let w = if i % 2 == 0 { 0.0 } else { 0.03 };
            pts.extend_from_slice(&[i as f64 * 0.1, 5.0 + w, 1.0]);
        }
        for i in 0..10 {
            for j in 0..10 {
                pts.extend_from_slice(&[i as f64 * 0.1, j as f64 * 0.1, 1.0]);
            }
        }
        let tree = KdTree::build(&pts, 3).unwrap();
        let keep = local_geometry(&tree, 8, &[0.0; 3], true, None).unwrap();
        let drop = local_geometry_with(&tree, 8, &[0.0; 3], true, None, true).unwrap();
        // Flagged either way; only `drop_linear` drops their normals.
        assert_eq!(keep.linear, drop.linear);
        assert_eq!(drop.valid, keep.valid);
        let (kn, dn) = (keep.normals.unwrap(), drop.normals.unwrap());
        for i in 0..40 {
            assert_eq!(
                &dn[3 * i..3 * i + 3],
                &[0.0; 3],
                "strip point {i} is linear"
            );
            assert!((kn[3 * i..3 * i + 3].iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-9);
        }
        // The patch keeps its normals (a corner, with 8 neighbours along its two edges, may not).
        for i in 40..140 {
            let (a, b) = ((i - 40) / 10, (i - 40) % 10);
            if (1..9).contains(&a) && (1..9).contains(&b) {
                assert_eq!(
                    &dn[3 * i..3 * i + 3],
                    &kn[3 * i..3 * i + 3],
                    "patch point {i}"
                );
            }
        }
        assert_eq!(drop.linear.iter().filter(|v| **v).count(), drop.num_linear);
        assert!(drop.linear[..40].iter().all(|v| *v));
        assert!(
            drop.num_linear >= 40 && drop.num_linear <= 44,
            "{}",
            drop.num_linear
        );
        assert!(is_linear(&[0.0, 1e-4, 1.0]) && !is_linear(&[1e-4, 0.5, 1.0]));
        // 2D: a line is what a normal needs; nothing is dropped.
        let flat: Vec<f64> = (0..20)
            .flat_map(|i| [i as f64 * 0.1, 0.01 * (i % 2) as f64])
            .collect();
        let t2 = KdTree::build(&flat, 2).unwrap();
        assert_eq!(
            local_geometry_with(&t2, 5, &[0.0; 2], true, None, true)
                .unwrap()
                .num_linear,
            0
        );
    }
}
