//! Closed-form covariance of an ICP estimate (Censi 2007), and the per-point sums behind the
//! other covariance kinds, at a fixed pose and fixed correspondences.
//!
//! At the optimum the gradient `g(x, z) = Σ_i k_i J_iᵀ W_i r_i` is zero. Perturbing the data `z`
//! (source points `p_i`, target points `q_j`) moves the optimum by `δx = −H⁻¹ (∂g/∂z) δz`, so
//! (Censi 2007, "An accurate closed-form estimate of ICP's covariance", eq. 4)
//!
//! ```text
//! Σ_x = H⁻¹ (∂g/∂z) Σ_z (∂g/∂z)ᵀ H⁻¹,   H = ∂g/∂x (Gauss–Newton).
//! ```
//!
//! This module returns the middle term (the "meat") for isotropic per-point noise `σ_s²` on every
//! source point and `σ_t²` on every target point. Target points are shared: when several source
//! points correspond to the same target point, its noise moves all of their residuals together,
//! so their derivatives are summed per target point before the outer product (the dependence of
//! the correspondences that a per-residual formula ignores). Normals, GICP weights `W` and kernel
//! weights `k` are held fixed, as the solver holds them.
//!
//! Per correspondence, with `e = R p + t − q`, `A(p) = ∂(exp(δ) p)/∂δ` and `C(w) = ∂(A(p)ᵀ w)/∂p`
//! at fixed `w` (`[0; −[w]×]` in 3D, `[0, 0; w_y, −w_x]` in 2D):
//! * point-to-point (`r = Rᵀe`): `∂g/∂p = k (Aᵀ + C(r))`, `∂g/∂q = −k Aᵀ Rᵀ`;
//! * point-to-plane/line (`m = Rᵀn`, `r = nᵀe`): `∂g/∂p = k (Aᵀ m mᵀ + r C(m))`, `∂g/∂q = −k Aᵀ m nᵀ`,
//!   and for the target normal (its direction noise `σ_n² (I − nnᵀ)`, Censi's "line" term)
//!   `∂g/∂n = k Aᵀ (Rᵀ r + m eᵀ)`;
//! * GICP (`W_l = Rᵀ W R`, `r = Rᵀe`): `∂g/∂p = k (Aᵀ W_l + C(W_l r))`, `∂g/∂q = −k Aᵀ W_l Rᵀ`.
//!
//! The same pass also sums the per-point scores `ψ_i = k J_iᵀ W r_i` by spatial block (cells of
//! `block_size` in the source frame): `Σ_b ψ_b ψ_bᵀ` is the meat of a cluster-robust sandwich,
//! which stays honest when residual errors are correlated in space (sampling, model error),
//! and the point-to-plane information `Σ Jᵀ J` over correspondences with a plane normal, the
//! geometry-only matrix the degeneracy analysis uses for every method. The plane normal is the
//! target's; without target normals, GICP's target covariance's (its least axis), else the
//! source's (its normal, or GICP's source covariance's) rotated into the target.
//!
//! Noisy normals fake information: a normal error `δn` (variance `ε²` per tangent axis) adds
//! `Aᵀ(I − m mᵀ)A ε²` in expectation to a correspondence's `JᵀJ`, along directions no surface
//! faces (a tunnel's axis gains `ε²` per correspondence). The pass sums that unit-noise term
//! (`plane_noise_information`) and, where a correspondence has a target and a source normal,
//! their squared sine (the two scans' normals disagree by `2ε²` per tangent axis), so that
//! the degeneracy analysis can judge a direction by the information noise does not explain.

use crate::error::{Error, Result};
use crate::factor;
use crate::group::{Group, Planar, Spatial};
use crate::icp::Method;
use crate::kernel::Kernel;
use crate::points::{all_finite, check_points, mat_at, split_pose, vec_at};
use crate::reduce::{chunk_len, SEQUENTIAL_MAX};
use crate::symeig;
use nalgebra::{SMatrix, SVector, Vector2, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// Marker for "no correspondence".
pub const NONE: u32 = u32::MAX;

/// The data at the final pose.
pub struct Input<'a> {
    /// `N * D` source points (source frame).
    pub source: &'a [f64],
    /// `N * D * D` source covariances (GICP only).
    pub source_covariances: Option<&'a [f64]>,
    /// `M * D` target points (target frame).
    pub target: &'a [f64],
    /// `M * D` unit target normals (point-to-plane; optional otherwise: the plane information).
    pub target_normals: Option<&'a [f64]>,
    /// `M * D * D` target covariances (GICP only).
    pub target_covariances: Option<&'a [f64]>,
    /// One target index per source point, [`NONE`] for none.
    pub correspondences: &'a [u32],
    /// `N * D` unit source normals, a row of shorter than 1/2 for none (the plane information's
    /// fallback without target normals, and the normal disagreement between the two scans).
    pub source_normals: Option<&'a [f64]>,
    /// `M` flags: the target point's neighbourhood is linear, so its normal is not determined
    /// (3D; [`crate::normals::LocalGeometry::linear`]). Such correspondences are left out of
    /// the plane information. `None`: not known, every target normal counts.
    pub target_linear: Option<&'a [bool]>,
}

/// Options of [`analyse`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    pub method: Method,
    pub kernel: Kernel,
    /// Variance of each coordinate of a source point (units²).
    pub source_variance: f64,
    /// Variance of each coordinate of a target point (units²).
    pub target_variance: f64,
    /// Variance of a target normal's direction, per tangent axis (rad²): the normal is
    /// perturbed within its tangent plane, `Σ_n = normal_variance (I − n nᵀ)`. Point-to-plane
    /// only (the residual `nᵀe` depends on it).
    pub normal_variance: f64,
    /// Edge of the cubic (square) blocks the scores are summed over; `inf`: one block per point.
    pub block_size: f64,
}

/// Row-major `dof x dof` matrices.
#[derive(Debug, Clone, PartialEq)]
pub struct Analysis {
    /// `Σ k JᵀWJ` over the correspondences.
    pub hessian: Vec<f64>,
    /// `(∂g/∂z) Σ_z (∂g/∂z)ᵀ`: Censi's middle term with the [`Options`] variances; the sum
    /// of the three unit-variance terms below, each times its variance.
    pub censi_meat: Vec<f64>,
    /// The source-point term at unit variance (`σ_s² = 1`).
    pub source_meat: Vec<f64>,
    /// The target-point term at unit variance, shared target points summed.
    pub target_meat: Vec<f64>,
    /// The target-normal term at unit variance (point-to-plane/line; zeros otherwise).
    pub normal_meat: Vec<f64>,
    /// `Σ (nᵀe)²` over correspondences whose target has a normal: the residual along the
    /// surface normal, for every method (the noise that matters, free of the along-surface
    /// sampling offsets in `|e|²`).
    pub plane_sum_squares: f64,
    /// The same sum over the `num_determined_correspondences` whose normal is determined (all
    /// of them unless `target_linear` left some out): a linear neighbourhood's normal is a
    /// guess, and the residual along it carries along-surface offsets (the rings' misfit of a
    /// held pose), not the points' noise.
    pub determined_plane_sum_squares: f64,
    /// `Σ_b ψ_b ψ_bᵀ` over spatial blocks.
    pub block_meat: Vec<f64>,
    /// Blocks holding at least one correspondence.
    pub num_blocks: usize,
    /// `block_meat` over the pairs whose target neighbourhood is not flagged linear (all of
    /// them without `target_linear`), and the blocks holding at least one such pair.
    pub determined_block_meat: Vec<f64>,
    pub num_determined_blocks: usize,
    /// `Σ Jᵀ J` of the point-to-plane factor over correspondences whose target has a normal,
    /// a determined one when `target_linear` is given (zeros without normals).
    pub plane_information: Vec<f64>,
    /// Correspondences with a plane normal.
    pub num_plane_correspondences: usize,
    /// Of those, the ones `plane_information` (and its noise terms) sums: all of them unless
    /// `target_linear` left some out.
    pub num_determined_correspondences: usize,
    /// Whether `target_linear` was given (the degeneracy's floor depends on it).
    pub linear_known: bool,
    pub num_correspondences: usize,
    /// `Σ Aᵀ(I − m mᵀ)A` over the same correspondences: the information unit normal noise
    /// adds to `plane_information` in expectation (zeros without `source_normals`).
    pub plane_noise_information: Vec<f64>,
    /// The solve's own gradient `Σ k JᵀWr` at `pose` (zero at a converged optimum).
    pub score: Vec<f64>,
    /// The solve's own `Σ k JᵀWJ` and `Σ k JᵀWr` over the correspondences whose target
    /// neighbourhood is not flagged linear (all of them when `target_linear` is not given):
    /// with `hessian` and `score`, the two systems of GICP's model-error shift
    /// (`trust::shift`).
    pub determined_hessian: Vec<f64>,
    pub determined_score: Vec<f64>,
    pub num_determined_pairs: usize,
    /// `Σ sin²` of the angle between the source normal (rotated) and the target normal, over
    /// `num_normal_pairs` plane correspondences that have both.
    pub normal_disagreement: f64,
    pub num_normal_pairs: usize,
}

/// What the sensitivities need beyond [`Group`] (whose point Jacobian `A(p)` and inverse they
/// share with the ICP loop).
trait Geometry<const D: usize, const N: usize>: Group<D, N> {
    /// `∂(A(p)ᵀ w)/∂p` at fixed `w`.
    fn c(w: &SVector<f64, D>) -> SMatrix<f64, N, D>;
    /// The normal of a plane-like (line-like in 2D) covariance: the unit eigenvector of its
    /// least eigenvalue when that is under half the next (a voxel of too few points keeps the
    /// identity, which has none).
    fn plane_normal(cov: &SMatrix<f64, D, D>) -> Option<SVector<f64, D>>;
}

impl Geometry<2, 3> for Planar {
    fn c(w: &Vector2<f64>) -> SMatrix<f64, 3, 2> {
        SMatrix::<f64, 3, 2>::new(0.0, 0.0, 0.0, 0.0, w.y, -w.x)
    }
    fn plane_normal(cov: &SMatrix<f64, 2, 2>) -> Option<Vector2<f64>> {
        let (l, v) = symeig::sym2(cov[(0, 0)], cov[(0, 1)], cov[(1, 1)]);
        (l[0] < 0.5 * l[1]).then(|| Vector2::new(v[0][0], v[0][1]))
    }
}

impl Geometry<3, 6> for Spatial {
    fn c(w: &Vector3<f64>) -> SMatrix<f64, 6, 3> {
        // −[w]× in the rotation rows.
        #[rustfmt::skip]
        let c = SMatrix::<f64, 6, 3>::new(
            0.0, 0.0, 0.0,
            0.0, 0.0, 0.0,
            0.0, 0.0, 0.0,
            0.0, w.z, -w.y,
            -w.z, 0.0, w.x,
            w.y, -w.x, 0.0,
        );
        c
    }
    fn plane_normal(cov: &SMatrix<f64, 3, 3>) -> Option<Vector3<f64>> {
        let m: [f64; 9] = std::array::from_fn(|k| cov[(k / 3, k % 3)]);
        let (l, v) = symeig::sym3(&m);
        (l[0] < 0.5 * l[1]).then(|| Vector3::new(v[0][0], v[0][1], v[0][2]))
    }
}

/// What one correspondence contributes.
struct Term<const D: usize, const N: usize> {
    h: SMatrix<f64, N, N>,
    score: SVector<f64, N>,
    dp: SMatrix<f64, N, D>,
    dq: SMatrix<f64, N, D>,
    /// `∂g/∂n` and the target normal `n` (point-to-plane only; `Σ_n ∝ I − n nᵀ`).
    dn: Option<(SMatrix<f64, N, D>, SVector<f64, D>)>,
    /// Plane information `JᵀJ`, `(nᵀe)²`, the unit-noise term `Aᵀ(I − m mᵀ)A`, and the
    /// source/target normal `sin²` when both exist.
    plane: Option<Plane<N>>,
}

struct Plane<const N: usize> {
    info: SMatrix<f64, N, N>,
    d2: f64,
    noise: Option<SMatrix<f64, N, N>>,
    sin2: Option<f64>,
    /// The normal is not a linear neighbourhood's guess (see [`Input::target_linear`]).
    determined: bool,
}

fn unit<const D: usize>(v: SVector<f64, D>) -> Option<SVector<f64, D>> {
    (v.iter().all(|x| x.is_finite()) && v.norm_squared() >= 0.25).then_some(v)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn term<G: Geometry<D, N>, const D: usize, const N: usize>(
    input: &Input<'_>,
    opts: &Options,
    r: &SMatrix<f64, D, D>,
    t: &SVector<f64, D>,
    i: usize,
    j: usize,
) -> Option<Term<D, N>> {
    let p: SVector<f64, D> = vec_at(input.source, i);
    let q: SVector<f64, D> = vec_at(input.target, j);
    let e = r * p + t - q;
    let a = G::point_jacobian(&p);
    let rt = r.transpose();
    let normal: Option<SVector<f64, D>> =
        input.target_normals.and_then(|n| unit(vec_at::<D>(n, j)));
    // The source normal in the target frame: given, or (GICP) its covariance's.
    let source_normal = || -> Option<SVector<f64, D>> {
        let n = match (input.source_normals, input.source_covariances) {
            (Some(sn), _) => unit(vec_at::<D>(sn, i)),
            (None, Some(sc)) if opts.method == Method::Gicp => G::plane_normal(&mat_at::<D>(sc, i)),
            _ => None,
        };
        n.map(|n| r * n)
    };
    // A target that keeps covariances only (odometry's voxel map): GICP's own whitened `JᵀWJ`
    // cannot show a tunnel (plane-regularised covariances weigh each correspondence ~1/2 along
    // its tangent plane) and point-to-point's is isotropic; the covariance's normal can, and
    // its disagreement with the source normal measures the normals' noise.
    let plane_normal = normal.or_else(|| match input.target_covariances {
        Some(c) if matches!(opts.method, Method::Gicp | Method::PointToPoint) => {
            G::plane_normal(&mat_at::<D>(c, j))
        }
        _ => None,
    });
    let (plane_normal, from_source) = match plane_normal {
        Some(n) => (Some(n), false),
        None => (source_normal(), true),
    };
    // Only the target's own normals carry the flags (a covariance's or the source's do not).
    let determined = !(normal.is_some() && input.target_linear.is_some_and(|l| l[j]));
    let plane = plane_normal.map(|n| {
        let m = rt * n;
        let jrow = G::jacobian_t_mul(&p, &m).transpose(); // mᵀA, the same sums
        let info = jrow.transpose() * jrow;
        let sin2 = if from_source || input.source_normals.is_none() {
            None
        } else {
            source_normal().map(|s| (1.0 - n.dot(&s).powi(2)).max(0.0))
        };
        Plane {
            info,
            d2: n.dot(&e).powi(2),
            // Only the noise removal reads it, and that needs the source normals.
            noise: input.source_normals.map(|_| a.transpose() * a - info),
            sin2,
            determined,
        }
    });
    let mut dn = None;
    let (h, score, dp, dq, norm) = match opts.method {
        Method::PointToPoint => {
            let rl = rt * e;
            (
                a.transpose() * a,
                a.transpose() * rl,
                a.transpose() + G::c(&rl),
                -(a.transpose() * rt),
                e.norm(),
            )
        }
        Method::PointToPlane => {
            let n = normal?;
            let m = rt * n;
            let d = n.dot(&e);
            let jt = a.transpose() * m; // N x 1
                                        // g = Aᵀ m d with m = Rᵀn, d = nᵀe: ∂g/∂n = Aᵀ (Rᵀ d + m eᵀ).
            let dgn = a.transpose() * (rt * d + m * e.transpose());
            // The projector I − n nᵀ is applied in `run` as dn dnᵀ − (dn n)(dn n)ᵀ, never formed:
            // rustc 1.95 at opt-level 3 with one codegen unit (the release profile) miscompiled
            // `identity() - n * n.transpose()` here (the SLP vectoriser reused [n_x², n_y²] from
            // the `norm_squared` filter above for the column [n_x², n_y n_x], so the off-diagonal
            // came out −n_y² instead of −n_x n_y); tests::all_meats_match_finite_differences_*.
            dn = Some((dgn, n));
            (
                jt * jt.transpose(),
                jt * d,
                jt * m.transpose() + G::c(&m) * d,
                -(jt * n.transpose()),
                d.abs(),
            )
        }
        Method::Gicp => {
            let cq: SMatrix<f64, D, D> = mat_at(input.target_covariances?, j);
            let cp: SMatrix<f64, D, D> = mat_at(input.source_covariances?, i);
            let wl = factor::gicp_weight::<G, D, N>(r, &cq, &cp)?;
            let el = rt * e;
            let we = wl * el;
            // `Aᵀ W_l` once for the three products that start with it, and every product with
            // `A` structured (`Group::jacobian_t_mul`: nalgebra's sums without `A`'s zeros and
            // ones, the same bits), as the ICP loop's GICP factor computes them.
            let awl = G::jacobian_t_mul(&p, &wl);
            (
                G::mul_jacobian(&awl, &p),
                G::jacobian_t_mul(&p, &we),
                awl + G::c(&we),
                -factor::mul(&awl, &rt),
                el.dot(&we).max(0.0).sqrt(),
            )
        }
    };
    let k = opts.kernel.weight(norm);
    if k == 1.0 {
        // Without a kernel (or inside Huber's threshold) the scaling is the identity: x · 1 = x
        // exactly, so skipping it changes no bit.
        return Some(Term {
            h,
            score,
            dp,
            dq,
            dn,
            plane,
        });
    }
    Some(Term {
        h: h * k,
        score: score * k,
        dp: dp * k,
        dq: dq * k,
        dn: dn.map(|(d, c)| (d * k, c)),
        plane,
    })
}

/// `acc += x xᵀ` on the lower triangle only. Entry `(r, c)` of `x xᵀ` is `Σ_k x_rk x_ck`
/// summed over `k` in order, as nalgebra's product sums it, and the products are the same
/// numbers for `(c, r)` (multiplication commutes exactly): mirroring the lower triangle once
/// at the end ([`mirrored`]) gives the full product's sum to the bit, for half the work.
#[inline(always)]
fn add_outer_lower<const N: usize, const D: usize>(
    acc: &mut SMatrix<f64, N, N>,
    x: &SMatrix<f64, N, D>,
) {
    for c in 0..N {
        for r in c..N {
            let mut s = x[(r, 0)] * x[(c, 0)];
            for k in 1..D {
                s += x[(r, k)] * x[(c, k)];
            }
            acc[(r, c)] += s;
        }
    }
}

/// `acc += m` on the lower triangle only (`m` symmetric to the bit, as `jᵀj` is).
#[inline(always)]
fn add_lower<const N: usize>(acc: &mut SMatrix<f64, N, N>, m: &SMatrix<f64, N, N>) {
    for c in 0..N {
        for r in c..N {
            acc[(r, c)] += m[(r, c)];
        }
    }
}

/// The full symmetric matrix from the lower triangle [`add_outer_lower`] summed.
fn mirrored<const N: usize>(mut m: SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    m.fill_upper_triangle_with_lower_triangle();
    m
}

fn block_key<const D: usize>(p: &SVector<f64, D>, size: f64, i: usize) -> [i64; 4] {
    if !size.is_finite() {
        return [i as i64, 0, 0, 0];
    }
    let mut key = [0i64; 4];
    for (k, v) in p.iter().enumerate() {
        // saturating float-to-int cast: far points share the extreme block, never overflow
        key[k] = (v / size).floor() as i64;
    }
    key
}

/// One spatial block's scores (see [`Analysis::block_meat`]).
struct Block<const N: usize> {
    all: SVector<f64, N>,
    determined: SVector<f64, N>,
    num_determined: usize,
}

impl<const N: usize> Block<N> {
    fn zero() -> Self {
        Block {
            all: SVector::zeros(),
            determined: SVector::zeros(),
            num_determined: 0,
        }
    }
}

/// The sums of one run of consecutive target groups (see [`run`]).
struct Partial<const N: usize> {
    h: SMatrix<f64, N, N>,
    score: SVector<f64, N>,
    h_det: SMatrix<f64, N, N>,
    score_det: SVector<f64, N>,
    det_pairs: usize,
    m_src: SMatrix<f64, N, N>,
    m_tgt: SMatrix<f64, N, N>,
    m_nrm: SMatrix<f64, N, N>,
    plane: SMatrix<f64, N, N>,
    plane_noise: SMatrix<f64, N, N>,
    plane_ss: f64,
    plane_ss_det: f64,
    plane_count: usize,
    determined_count: usize,
    sin2: f64,
    sin2_count: usize,
    count: usize,
    /// Per block: the score over every pair, over the determined ones, and their count.
    blocks: FxHashMap<[i64; 4], Block<N>>,
}

impl<const N: usize> Partial<N> {
    fn new() -> Self {
        Partial {
            h: SMatrix::zeros(),
            score: SVector::zeros(),
            h_det: SMatrix::zeros(),
            score_det: SVector::zeros(),
            det_pairs: 0,
            m_src: SMatrix::zeros(),
            m_tgt: SMatrix::zeros(),
            m_nrm: SMatrix::zeros(),
            plane: SMatrix::zeros(),
            plane_noise: SMatrix::zeros(),
            plane_ss: 0.0,
            plane_ss_det: 0.0,
            plane_count: 0,
            determined_count: 0,
            sin2: 0.0,
            sin2_count: 0,
            count: 0,
            blocks: FxHashMap::default(),
        }
    }

    fn add(mut self, other: Self) -> Self {
        self.h += other.h;
        self.score += other.score;
        self.h_det += other.h_det;
        self.score_det += other.score_det;
        self.det_pairs += other.det_pairs;
        self.m_src += other.m_src;
        self.m_tgt += other.m_tgt;
        self.m_nrm += other.m_nrm;
        self.plane += other.plane;
        self.plane_noise += other.plane_noise;
        self.plane_ss += other.plane_ss;
        self.plane_ss_det += other.plane_ss_det;
        self.plane_count += other.plane_count;
        self.determined_count += other.determined_count;
        self.sin2 += other.sin2;
        self.sin2_count += other.sin2_count;
        self.count += other.count;
        for (key, b) in other.blocks {
            let e = self.blocks.entry(key).or_insert_with(Block::zero);
            e.all += b.all;
            e.determined += b.determined;
            e.num_determined += b.num_determined;
        }
        self
    }
}

/// The `(target, source)` index pairs of the correspondences sorted by target, then source:
/// a counting sort over the target indices (source indices arrive ascending, so each group
/// keeps them in order), the same sequence as sorting the pairs.
fn pairs_by_target(correspondences: &[u32], num_targets: usize) -> Vec<(u32, u32)> {
    let mut start = vec![0u32; num_targets + 1];
    for &j in correspondences.iter().filter(|&&j| j != NONE) {
        start[j as usize + 1] += 1;
    }
    for j in 0..num_targets {
        start[j + 1] += start[j];
    }
    let mut pairs = vec![(0u32, 0u32); start[num_targets] as usize];
    for (i, &j) in correspondences.iter().enumerate() {
        if j != NONE {
            let slot = &mut start[j as usize];
            pairs[*slot as usize] = (j, i as u32);
            *slot += 1;
        }
    }
    pairs
}

fn run<G: Geometry<D, N>, const D: usize, const N: usize>(
    input: &Input<'_>,
    pose: &[f64],
    opts: &Options,
) -> Analysis {
    let m = D + 1;
    let r: SMatrix<f64, D, D> = SMatrix::from_fn(|i, j| pose[i * m + j]);
    let t: SVector<f64, D> = SVector::from_fn(|i, _| pose[i * m + D]);
    // Correspondences grouped by target point: the target noise moves every residual of its
    // group together, so each group's derivatives are summed before the outer product. Each
    // term is computed once, inside its group, and folded into the sums at once (no per-point
    // storage: a 25k-point cloud's terms were 26 MB).
    let pairs = pairs_by_target(input.correspondences, input.target.len() / D);
    // Fixed chunks of the sorted pairs, each boundary moved forward to a group start: the
    // partition depends on the data only, so the sums do not depend on the thread count.
    let len = chunk_len(pairs.len());
    let mut starts = vec![0usize];
    let mut next = len;
    while next < pairs.len() {
        while next < pairs.len() && pairs[next].0 == pairs[next - 1].0 {
            next += 1;
        }
        if next < pairs.len() {
            starts.push(next);
        }
        next += len;
    }
    starts.push(pairs.len());
    let chunk = |c: usize| {
        let mut acc = Partial::<N>::new();
        let items = &pairs[starts[c]..starts[c + 1]];
        let mut k = 0;
        while k < items.len() {
            let j = items[k].0;
            let mut d = SMatrix::<f64, N, D>::zeros();
            let mut dn = SMatrix::<f64, N, D>::zeros();
            let mut normal = SVector::<f64, D>::zeros();
            while k < items.len() && items[k].0 == j {
                let i = items[k].1 as usize;
                k += 1;
                let Some(tm) = term::<G, D, N>(input, opts, &r, &t, i, j as usize) else {
                    continue;
                };
                acc.count += 1;
                acc.h += tm.h;
                acc.score += tm.score;
                if !input.target_linear.is_some_and(|l| l[j as usize]) {
                    acc.h_det += tm.h;
                    acc.score_det += tm.score;
                    acc.det_pairs += 1;
                }
                add_outer_lower(&mut acc.m_src, &tm.dp);
                if let Some(pl) = tm.plane {
                    // The residual along the normal counts for the point noise either way.
                    acc.plane_ss += pl.d2;
                    acc.plane_count += 1;
                    if pl.determined {
                        acc.plane_ss_det += pl.d2;
                        add_lower(&mut acc.plane, &pl.info);
                        if let Some(noise) = pl.noise {
                            acc.plane_noise += noise;
                        }
                        acc.determined_count += 1;
                        if let Some(s2) = pl.sin2 {
                            acc.sin2 += s2;
                            acc.sin2_count += 1;
                        }
                    }
                }
                let p: SVector<f64, D> = vec_at(input.source, i);
                let linear = input.target_linear.is_some_and(|l| l[j as usize]);
                let b = acc
                    .blocks
                    .entry(block_key(&p, opts.block_size, i))
                    .or_insert_with(Block::zero);
                b.all += tm.score;
                if !linear {
                    b.determined += tm.score;
                    b.num_determined += 1;
                }
                d += tm.dq;
                if let Some((dgn, nv)) = tm.dn {
                    dn += dgn;
                    normal = nv;
                }
            }
            add_outer_lower(&mut acc.m_tgt, &d);
            // dn (I − n nᵀ) dnᵀ, the normal's direction noise within its tangent plane
            let along = dn * normal;
            acc.m_nrm += dn * dn.transpose() - along * along.transpose();
        }
        acc
    };
    let chunks = starts.len() - 1;
    let parts: Vec<Partial<N>> = if pairs.len() <= SEQUENTIAL_MAX {
        (0..chunks).map(chunk).collect()
    } else {
        (0..chunks).into_par_iter().map(chunk).collect()
    };
    let acc = parts.into_iter().fold(Partial::<N>::new(), Partial::add);
    // The blocks in key order: the sum of their outer products does not depend on how the
    // hash map happened to lay them out.
    let mut blocks: Vec<(&[i64; 4], &Block<N>)> = acc.blocks.iter().collect();
    blocks.sort_unstable_by_key(|(key, _)| **key);
    let mut block_meat = SMatrix::<f64, N, N>::zeros();
    let mut determined_block_meat = SMatrix::<f64, N, N>::zeros();
    let mut num_determined_blocks = 0;
    for (_, b) in &blocks {
        block_meat += b.all * b.all.transpose();
        if b.num_determined > 0 {
            determined_block_meat += b.determined * b.determined.transpose();
            num_determined_blocks += 1;
        }
    }
    let (m_src, m_tgt) = (mirrored(acc.m_src), mirrored(acc.m_tgt));
    let meat = m_src * opts.source_variance
        + m_tgt * opts.target_variance
        + acc.m_nrm * opts.normal_variance;
    let flat = |mat: SMatrix<f64, N, N>| mat.transpose().iter().copied().collect::<Vec<f64>>();
    Analysis {
        hessian: flat(acc.h),
        censi_meat: flat(meat),
        source_meat: flat(m_src),
        target_meat: flat(m_tgt),
        normal_meat: flat(acc.m_nrm),
        plane_sum_squares: acc.plane_ss,
        determined_plane_sum_squares: acc.plane_ss_det,
        block_meat: flat(block_meat),
        num_blocks: blocks.len(),
        determined_block_meat: flat(determined_block_meat),
        num_determined_blocks,
        plane_information: flat(mirrored(acc.plane)),
        num_plane_correspondences: acc.plane_count,
        num_determined_correspondences: acc.determined_count,
        linear_known: input.target_linear.is_some(),
        num_correspondences: acc.count,
        plane_noise_information: flat(acc.plane_noise),
        score: acc.score.iter().copied().collect(),
        determined_hessian: flat(acc.h_det),
        determined_score: acc.score_det.iter().copied().collect(),
        num_determined_pairs: acc.det_pairs,
        normal_disagreement: acc.sin2,
        num_normal_pairs: acc.sin2_count,
    }
}

fn check_len(arg: &'static str, data: &[f64], n: usize, per: usize) -> Result<()> {
    if data.len() != n * per {
        return Err(Error::invalid(
            arg,
            format!(
                "expected {} values ({n} points x {per}), got {}",
                n * per,
                data.len()
            ),
        ));
    }
    if !all_finite(data) {
        return Err(Error::invalid(arg, "contains NaN or inf"));
    }
    Ok(())
}

/// Censi's middle term, the block-score meat and the plane information at `pose` (row-major
/// homogeneous `T_target_source`) over the given correspondences.
pub fn analyse(input: &Input<'_>, pose: &[f64], dim: usize, opts: &Options) -> Result<Analysis> {
    let n = check_points("source", input.source, dim)?;
    let m = check_points("target", input.target, dim)?;
    split_pose("pose", pose, dim)?;
    if input.correspondences.len() != n {
        return Err(Error::invalid(
            "correspondences",
            format!(
                "expected one per source point ({n}), got {}",
                input.correspondences.len()
            ),
        ));
    }
    if let Some(&bad) = input
        .correspondences
        .iter()
        .find(|&&j| j != NONE && j as usize >= m)
    {
        return Err(Error::invalid(
            "correspondences",
            format!("index {bad} out of range for {m} target points"),
        ));
    }
    for (arg, v) in [
        ("source_variance", opts.source_variance),
        ("target_variance", opts.target_variance),
        ("normal_variance", opts.normal_variance),
    ] {
        if !v.is_finite() || v < 0.0 {
            return Err(Error::invalid(
                arg,
                format!("must be finite and >= 0, got {v}"),
            ));
        }
    }
    if opts.block_size.is_nan() || opts.block_size <= 0.0 {
        return Err(Error::invalid(
            "block_size",
            format!("must be > 0, got {}", opts.block_size),
        ));
    }
    if let Some(nrm) = input.target_normals {
        check_len("target_normals", nrm, m, dim)?;
    }
    if let Some(tc) = input.target_covariances {
        check_len("target_covariances", tc, m, dim * dim)?;
    }
    if let Some(lin) = input.target_linear {
        if lin.len() != m {
            return Err(Error::invalid(
                "target_linear",
                format!(
                    "expected one flag per target point ({m}), got {}",
                    lin.len()
                ),
            ));
        }
    }
    if let Some(nrm) = input.source_normals {
        // NaN rows are allowed: a point without a normal.
        if nrm.len() != n * dim {
            return Err(Error::invalid(
                "source_normals",
                format!(
                    "expected {} values ({n} points x {dim}), got {}",
                    n * dim,
                    nrm.len()
                ),
            ));
        }
    }
    match opts.method {
        Method::PointToPoint => {}
        Method::PointToPlane => {
            if input.target_normals.is_none() {
                return Err(Error::invalid(
                    "target_normals",
                    "are required for point-to-plane/line",
                ));
            }
        }
        Method::Gicp => {
            // (Checked above when given.)
            input
                .target_covariances
                .ok_or_else(|| Error::invalid("target_covariances", "are required for GICP"))?;
            let sc = input
                .source_covariances
                .ok_or_else(|| Error::invalid("source_covariances", "are required for GICP"))?;
            check_len("source_covariances", sc, n, dim * dim)?;
        }
    }
    Ok(if dim == 2 {
        run::<Planar, 2, 3>(input, pose, opts)
    } else {
        run::<Spatial, 3, 6>(input, pose, opts)
    })
}

#[cfg(test)]
mod tests;
