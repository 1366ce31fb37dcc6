//! Local registration: the ICP family (point-to-point, point-to-plane / point-to-line, GICP)
//! against a k-d tree, with robust kernels, Gauss–Newton or Levenberg–Marquardt on the manifold.
//!
//! One iteration = for every source point, transform it by the current pose, find its nearest
//! target point within the gate (without a search when the last one's certificate settles it,
//! see `Cert`), linearise one *factor* (its residual and Jacobian in the
//! right-perturbation convention of [`crate::paired`]) and add it into the normal equations
//! `H = Σ k JᵀWJ`, `g = Σ k JᵀW r` with the deterministic chunked sum of [`crate::reduce`];
//! then solve for `δ` and update `T ← T · exp(δ)`. The whole loop runs here, so a registration is
//! one call from Python. It runs in a frame centred on the source's centroid (see `run`), so
//! results do not depend on where the clouds sit (map coordinates included).
//!
//! Factors, with `e = R p + t − q` and `A(p) = ∂(p ⊕ δ)/∂δ` (`[I, −[p]×]` in 3D, `[I, p⊥]` in 2D):
//! * point-to-point: `r = Rᵀe`, `J = A` (the residual is rotated into the source frame, which
//!   leaves `|r|` and `JᵀJ` unchanged);
//! * point-to-plane (3D) / point-to-line (2D): `r = nᵀe`, `J = (Rᵀn)ᵀ A`;
//! * GICP (Segal et al. 2009, eq. 2): `r = e` weighted by `W = (C_q + R C_p Rᵀ)⁻¹`, `J = R A`;
//!   `W` is held fixed while linearising (as in the paper and its implementations).
//!
//! A robust kernel re-weights each factor by `k(|r|)` (`|r|` is the Mahalanobis norm
//! `sqrt(rᵀWr)` for GICP): IRLS.

use crate::error::{Error, Result};
use crate::group::{Group, Planar, Spatial};
use crate::kernel::Kernel;
use crate::knn::{check_max_distance, KdTree};
use crate::points::{check_points, split_pose};
use crate::reduce::{chunk_len, chunked_sum};
use nalgebra::{SMatrix, SVector};
use rayon::ThreadPool;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Which factor each correspondence contributes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    PointToPoint,
    /// Point-to-plane in 3D, point-to-line in 2D (needs target normals).
    PointToPlane,
    /// Plane-to-plane (3D) / line-to-line (2D) GICP (needs source and target covariances).
    Gicp,
}

impl Method {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "point_to_point" => Ok(Method::PointToPoint),
            "point_to_plane" | "point_to_line" => Ok(Method::PointToPlane),
            "gicp" => Ok(Method::Gicp),
            other => Err(Error::invalid(
                "method",
                format!(
                    "unknown {other:?}; expected point_to_point, point_to_plane, point_to_line or gicp"
                ),
            )),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Optimizer {
    /// Take the Gauss–Newton step at every iteration (classic ICP).
    GaussNewton,
    /// Marquardt damping `H + λ diag(H)`; a step is accepted only if it lowers the cost over the
    /// iteration's correspondences, otherwise `λ ← 10 λ` and retry.
    LevenbergMarquardt,
}

impl Optimizer {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "gauss_newton" => Ok(Optimizer::GaussNewton),
            "levenberg_marquardt" => Ok(Optimizer::LevenbergMarquardt),
            other => Err(Error::invalid(
                "optimizer",
                format!("unknown {other:?}; expected gauss_newton or levenberg_marquardt"),
            )),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    pub method: Method,
    pub kernel: Kernel,
    /// The gate: a source point has a correspondence only if its nearest target point is at
    /// most this far (same units as the points).
    pub max_correspondence_distance: f64,
    pub max_iterations: usize,
    /// Converged when the last step moved the source's centroid less than this (units)...
    pub translation_tolerance: f64,
    /// ... and rotated less than this (radians).
    pub rotation_tolerance: f64,
    pub optimizer: Optimizer,
    /// Fewer correspondences than this stops the loop (`TooFewCorrespondences`).
    pub min_correspondences: usize,
    /// Degeneracy-aware solve (solution remapping, Zhang, Kaess & Singh 2016, §IV): every step
    /// `δ` is replaced by `P δ`, `P` (row-major `dof x dof`, first `dof²` values used) the
    /// projector onto the well-constrained directions along the weak ones, so the estimate
    /// keeps its initial value along weak directions. `None`: plain steps.
    pub step_projector: Option<[f64; 36]>,
    /// Point-to-point and point-to-plane/line under Gauss–Newton: stretch steps along a
    /// consistent direction (safeguarded Besl–McKay extrapolation, see `Extrapolation`).
    pub extrapolate: bool,
}

/// Why the iteration loop stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// The last step was below both tolerances (or, under LM, no step lowered the cost: a
    /// minimum).
    Converged,
    MaxIterations,
    TooFewCorrespondences,
    /// The step was non-finite, or the iterates ran away: three steps in a row implausibly
    /// large for the gate (moving the source's centroid over ten gates, or rotating over 90°:
    /// a near-singular `H`; a single one is shortened and the loop goes on); the pose before
    /// that step is returned.
    Diverged,
    /// `H` is singular: the correspondences do not determine the pose (e.g. all on one plane
    /// for point-to-plane).
    Degenerate,
}

impl StopReason {
    pub fn name(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::MaxIterations => "max_iterations",
            StopReason::TooFewCorrespondences => "too_few_correspondences",
            StopReason::Diverged => "diverged",
            StopReason::Degenerate => "degenerate",
        }
    }
}

/// Where the loop finds correspondences: a k-d tree over a fixed cloud, or a voxel map that
/// odometry updates in place. A point's id indexes `points()` (`id * dim`) and the target's
/// normals and covariances.
pub trait NeighborSearch: Sync {
    fn dim(&self) -> usize;
    /// Size of the id space (attribute arrays hold this many entries).
    fn id_count(&self) -> usize;
    fn points(&self) -> &[f64];
    /// Nearest point within the squared gate `max_sq`, as `(id, squared distance)`.
    fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)>;
    /// [`Self::nearest_within`] with a likely answer `hint` when there is one (the previous
    /// iteration's correspondence); the same result, found faster where the index can use it.
    fn nearest_within_hinted(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
    ) -> Option<(usize, f64)> {
        let _ = hint;
        self.nearest_within(q, max_sq)
    }
    /// [`Self::nearest_within_hinted`] and a certificate for the answer: a lower bound on the
    /// squared distance from `q` to every other point (to every point when there is no
    /// answer), searched out to `slack` beyond the answer (see [`Cert`]). `0`, no certificate,
    /// unless the index can give one.
    fn nearest_certified(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
        slack: f64,
    ) -> (Option<(usize, f64)>, f64) {
        let _ = slack;
        (self.nearest_within_hinted(q, max_sq, hint), 0.0)
    }
    /// True when [`Self::nearest_certified`] gives certificates (else none are kept).
    fn certifies(&self) -> bool {
        false
    }
    /// True when the attributes were validated on the way in (no per-call finiteness scan).
    fn attributes_validated(&self) -> bool {
        false
    }
    /// Ids sharing one row of the target's covariances (row `id / group`): a voxel map keeps
    /// one covariance per voxel instead of a copy per point.
    fn covariance_group(&self) -> usize {
        1
    }
}

impl NeighborSearch for KdTree {
    fn dim(&self) -> usize {
        KdTree::dim(self)
    }
    fn id_count(&self) -> usize {
        self.len()
    }
    fn points(&self) -> &[f64] {
        KdTree::points(self)
    }
    fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)> {
        KdTree::nearest_within(self, q, max_sq)
    }
    fn nearest_within_hinted(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
    ) -> Option<(usize, f64)> {
        match hint {
            Some(h) => KdTree::nearest_within_hinted(self, q, max_sq, h),
            None => KdTree::nearest_within(self, q, max_sq),
        }
    }
    fn nearest_certified(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
        slack: f64,
    ) -> (Option<(usize, f64)>, f64) {
        KdTree::nearest_certified(self, q, max_sq, hint, slack)
    }
    fn certifies(&self) -> bool {
        true
    }
}

/// The target: its neighbour search and, as the method needs, unit normals (`N * dim`; a zero
/// normal marks a point without one, which then never corresponds) or covariances
/// (`N * dim * dim`), indexed by point id.
pub struct Target<'a> {
    pub search: &'a dyn NeighborSearch,
    pub normals: Option<&'a [f64]>,
    pub covariances: Option<&'a [f64]>,
}

/// The source points (`N * dim`, source frame) and, for GICP, their covariances.
pub struct Source<'a> {
    pub points: &'a [f64],
    pub covariances: Option<&'a [f64]>,
}

/// The normal equations and residual statistics at one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// `Σ k JᵀWJ`, row-major `dof x dof`.
    pub hessian: Vec<f64>,
    /// `Σ k JᵀW r`; the Gauss–Newton step is `δ = −H⁻¹ g`.
    pub gradient: Vec<f64>,
    /// `Σ ψψᵀ` with `ψ = k JᵀW r` (the sandwich "meat"); zeros unless requested.
    pub score_outer: Vec<f64>,
    /// `Σ rho(|r|)` over correspondences.
    pub cost: f64,
    /// Source points that formed a factor.
    pub num_correspondences: usize,
    /// Source points whose nearest target point is inside the gate: the correspondences and
    /// those whose target point has no normal (point-to-plane) or no invertible covariance.
    pub num_in_gate: usize,
    /// `Σ |r|²` (whitened for GICP).
    pub sum_squares: f64,
    /// `Σ k |r|²`.
    pub irls_sum_squares: f64,
    /// `Σ k`.
    pub irls_weight_sum: f64,
    /// `Σ |R p + t − q|²` over correspondences: the Euclidean inlier error, for every method.
    pub sum_squared_distances: f64,
}

/// Result of [`register`].
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Row-major homogeneous `T_target_source`.
    pub pose: Vec<f64>,
    /// Number of steps computed (linearisations that had enough correspondences).
    pub iterations: usize,
    pub stop_reason: StopReason,
    /// At the returned pose, with the score outer products; re-using the last search's
    /// correspondences when converged (the last step was below the tolerances).
    pub evaluation: Evaluation,
    /// Wall time of each iteration, seconds.
    pub iteration_seconds: Vec<f64>,
    /// Wall time of the final evaluation, seconds.
    pub final_evaluation_seconds: f64,
    /// Target index of each source point at the returned pose (`u32::MAX`: none), as used by
    /// `evaluation`: its nearest target point inside the gate, whether or not that formed a
    /// factor (a target point without a normal forms none).
    pub correspondences: Vec<u32>,
}

/// Iterations remembered to recognise a periodic orbit (cycles of up to this length).
const ORBIT_MEMORY: usize = 8;

/// Relative match of two truncated costs taken as the same state of a periodic orbit (the
/// cycle's poses differ by the rounding of their compositions: ~1e-15).
const ORBIT_MATCH: f64 = 1e-12;

/// Over-long steps in a row after which the iterates are taken to run away (`Diverged`).
const MAX_OVERLONG_STEPS: usize = 3;

/// Marker for "no correspondence" in the per-point correspondence list.
const NONE: u32 = u32::MAX;

/// What a source point's last search proved ([`NeighborSearch::nearest_certified`]): from the
/// anchor `a` (where the point was), every target point but the answer `id` (every point, when
/// there was none) lies at least `clear` away. Queried again from `tp`, `δ = |tp − a|`: by the
/// triangle inequality every other point is at least `clear − δ` away, so when
/// `|tp − q_id| < clear − δ` the nearest is still `id` (when there is none and the gate is below
/// `clear − δ`, still none) and the search is skipped. Near convergence the points move by
/// millimetres between iterations, and most searches are. The answer is the search's exactly
/// (the same point, the distance computed the same way); `CERT_MARGIN` absorbs the rounding.
///
/// Compact (16 bytes in 3D): `id` is the correspondence list's entry, and the anchor is kept
/// in `f32` as an offset from the answer (`≤` the gate, so micrometre-exact at any map scale),
/// `clear` shrunk by that rounding and rounded down.
#[derive(Clone, Copy)]
struct Cert<const D: usize> {
    offset: [f32; D],
    clear: f32,
}

/// Relative margin on both sides of a certificate's test (rounding is ~1e-16 relative).
const CERT_MARGIN: f64 = 1e-9;
/// The furthest a certified search reaches past its answer, as a fraction of the gate: beyond
/// it the wider search costs more than the skipped ones save (measured on the Intel, KITTI and
/// outdoor pairs: 0.02-0.1 equally good, 0.2 worse).
const CERT_SLACK_MAX: f64 = 0.05;

impl<const D: usize> Cert<D> {
    /// The anchor: the answer's point (the origin when none) plus the stored offset.
    #[inline]
    fn anchor(offset: &[f32; D], id: u32, pts: &[f64]) -> SVector<f64, D> {
        let mut a = SVector::<f64, D>::from_fn(|c, _| f64::from(offset[c]));
        if id != NONE {
            a += vec_at::<D>(pts, id as usize);
        }
        a
    }

    /// The certificate of a search from `tp` that found `id` (`NONE`: none) with bound `clear`.
    fn new(tp: &SVector<f64, D>, id: u32, clear: f64, pts: &[f64]) -> Self {
        let base = if id == NONE {
            SVector::<f64, D>::zeros()
        } else {
            vec_at::<D>(pts, id as usize)
        };
        let offset: [f32; D] = std::array::from_fn(|c| (tp[c] - base[c]) as f32);
        // Stated from the rounded anchor: shrink the bound by the rounding, then round it down
        // (f32's relative rounding is 6e-8).
        let moved = (tp - Self::anchor(&offset, id, pts)).norm();
        let c = (clear - moved * (1.0 + CERT_MARGIN)) * (1.0 - 1e-6);
        Cert {
            offset,
            clear: if c > 0.0 {
                c.min(f64::from(f32::MAX)) as f32
            } else {
                0.0
            },
        }
    }

    /// From `tp`, the nearest point within the gate if this certificate (for answer `id`)
    /// settles it (`Ok(None)`: settled, none); `Err(δ)`, the move since the search, if not.
    #[inline]
    fn answer(
        &self,
        tp: &SVector<f64, D>,
        id: u32,
        pts: &[f64],
        max_sq: f64,
    ) -> std::result::Result<Option<(usize, f64)>, f64> {
        let delta = (tp - Self::anchor(&self.offset, id, pts)).norm();
        let room = f64::from(self.clear) * (1.0 - CERT_MARGIN) - delta * (1.0 + CERT_MARGIN);
        if room.is_nan() || room <= 0.0 {
            return Err(delta);
        }
        if id == NONE {
            return if max_sq.sqrt() * (1.0 + CERT_MARGIN) < room {
                Ok(None)
            } else {
                Err(delta)
            };
        }
        let j = id as usize;
        // As the k-d tree computes it (coordinate order, point minus query), so the distance
        // is the search's to the bit.
        let mut d2 = 0.0;
        for c in 0..D {
            let e = pts[j * D + c] - tp[c];
            d2 += e * e;
        }
        if d2.sqrt() * (1.0 + CERT_MARGIN) < room {
            Ok((d2 <= max_sq).then_some((j, d2)))
        } else {
            Err(delta)
        }
    }
}

/// One chunk's sums of the normal equations and residual statistics: plain numbers (`Copy`),
/// local to the accumulation loop, which makes no calls.
#[derive(Clone, Copy)]
struct Sums<const D: usize, const N: usize> {
    h: SMatrix<f64, N, N>,
    /// Rank-one terms, lower triangle only (mirrored at the end).
    hl: SMatrix<f64, N, N>,
    /// Point-to-point's Hessian as moments (`Group::moment_hessian`): `Σk`, `Σkp`, and
    /// `Σk rotation_moment(p)`, added to `h` once at the end.
    mk: f64,
    mkp: SVector<f64, D>,
    mrot: SMatrix<f64, D, D>,
    g: SVector<f64, N>,
    m: SMatrix<f64, N, N>,
    cost: f64,
    count: usize,
    ss: f64,
    irls_ss: f64,
    irls_w: f64,
    dist_ss: f64,
}

impl<const D: usize, const N: usize> Sums<D, N> {
    fn zeros() -> Self {
        Sums {
            h: SMatrix::zeros(),
            hl: SMatrix::zeros(),
            mk: 0.0,
            mkp: SVector::zeros(),
            mrot: SMatrix::zeros(),
            g: SVector::zeros(),
            m: SMatrix::zeros(),
            cost: 0.0,
            count: 0,
            ss: 0.0,
            irls_ss: 0.0,
            irls_w: 0.0,
            dist_ss: 0.0,
        }
    }

    fn add(&mut self, o: &Self) {
        self.h += o.h;
        self.hl += o.hl;
        self.mk += o.mk;
        self.mkp += o.mkp;
        self.mrot += o.mrot;
        self.g += o.g;
        self.m += o.m;
        self.cost += o.cost;
        self.count += o.count;
        self.ss += o.ss;
        self.irls_ss += o.irls_ss;
        self.irls_w += o.irls_w;
        self.dist_ss += o.dist_ss;
    }
}

struct Acc<const D: usize, const N: usize> {
    sums: Sums<D, N>,
    in_gate: usize,
    corr: Vec<u32>,
    certs: Vec<Cert<D>>,
}

impl<const D: usize, const N: usize> Acc<D, N> {
    fn new(keep: usize) -> Self {
        Acc {
            sums: Sums::zeros(),
            in_gate: 0,
            corr: Vec::with_capacity(keep),
            certs: Vec::new(),
        }
    }

    fn merge(mut self, o: Self) -> Self {
        self.sums.add(&o.sums);
        self.in_gate += o.in_gate;
        // Into lists made for them, or (none made: the first chunk) its own taken over.
        if self.corr.capacity() == 0 {
            self.corr = o.corr;
        } else {
            self.corr.extend(o.corr);
        }
        if self.certs.capacity() == 0 {
            self.certs = o.certs;
        } else {
            self.certs.extend(o.certs);
        }
        self
    }
}

/// The pose as `(R, t)`.
#[derive(Clone)]
struct Pose<const D: usize> {
    r: SMatrix<f64, D, D>,
    t: SVector<f64, D>,
}

impl<const D: usize> Pose<D> {
    fn from_flat(flat: &[f64]) -> Self {
        let m = D + 1;
        Pose {
            r: SMatrix::from_fn(|i, j| flat[i * m + j]),
            t: SVector::from_fn(|i, _| flat[i * m + D]),
        }
    }

    fn to_flat(&self) -> Vec<f64> {
        let m = D + 1;
        let mut out = vec![0.0; m * m];
        for i in 0..D {
            for j in 0..D {
                out[i * m + j] = self.r[(i, j)];
            }
            out[i * m + D] = self.t[i];
        }
        out[m * m - 1] = 1.0;
        out
    }

    /// `T · (R_d, t_d)`.
    fn compose(&self, rd: &SMatrix<f64, D, D>, td: &SVector<f64, D>) -> Self {
        Pose {
            r: self.r * rd,
            t: self.r * td + self.t,
        }
    }

    fn is_finite(&self) -> bool {
        self.r.iter().chain(self.t.iter()).all(|v| v.is_finite())
    }
}

/// Inputs of one evaluation, shared by every chunk.
struct Problem<'a> {
    source: &'a [f64],
    source_covs: Option<&'a [f64]>,
    target: &'a Target<'a>,
    method: Method,
    kernel: Kernel,
    max_sq: f64,
    /// See [`NeighborSearch::covariance_group`].
    cov_group: usize,
    /// Skip the searches a [`Cert`] settles (the same answers; off only to test that).
    certify: bool,
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

/// How one correspondence's `JᵀWJ` is added: the per-point `N × N` products were a third of a
/// 3D iteration's time.
enum Curvature<const N: usize> {
    /// Point-to-point: `A(p)ᵀA(p)`, which depends on `p` alone (the caller keeps moments).
    Moments,
    /// Point-to-plane/line: `jᵀj` for the one Jacobian row `j` (lower triangle only).
    RankOne(SVector<f64, N>),
    /// GICP: the full matrix.
    Full(SMatrix<f64, N, N>),
}

/// One factor reduced to what the accumulator needs: `(JᵀWJ, JᵀWr, |r|)`, or `None` when
/// the pair cannot form a factor.
#[inline]
#[allow(clippy::type_complexity)]
fn factor<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    method: Method,
    pose: &Pose<D>,
    i: usize,
    j: usize,
    p: &SVector<f64, D>,
    e: &SVector<f64, D>,
) -> Option<(Curvature<N>, SVector<f64, N>, f64)> {
    let a = G::point_jacobian(p);
    let rt = pose.r.transpose();
    match method {
        Method::PointToPoint => {
            let r = rt * e;
            Some((Curvature::Moments, a.transpose() * r, e.norm()))
        }
        Method::PointToPlane => {
            let n: SVector<f64, D> = vec_at(pr.target.normals?, j);
            if n.norm_squared() < 0.25 {
                return None; // no normal at this target point
            }
            let d = n.dot(e);
            let j = a.transpose() * (rt * n); // the Jacobian row, as a column
            Some((Curvature::RankOne(j), j * d, d.abs()))
        }
        Method::Gicp => {
            let cq: SMatrix<f64, D, D> = mat_at(pr.target.covariances?, j / pr.cov_group);
            let cp: SMatrix<f64, D, D> = mat_at(pr.source_covs?, i);
            let c = cq + pose.r * cp * rt;
            let w = G::inverse(&c)?;
            let wl = rt * w * pose.r; // W in the source frame
            let el = rt * e;
            let wa = wl * a;
            let m2 = el.dot(&(wl * el)).max(0.0);
            Some((
                Curvature::Full(a.transpose() * wa),
                wa.transpose() * el,
                m2.sqrt(),
            ))
        }
    }
}

/// Linearise at `pose`. Correspondences are searched in the tree (starting from `hints`, the
/// previous iteration's correspondences, where given: same result, less search), or taken
/// from `fixed` (one target index per source point, `NONE` for none) and re-gated.
fn evaluate<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    pose: &Pose<D>,
    with_scores: bool,
    keep_correspondences: bool,
    fixed: Option<&[u32]>,
    hints: Option<&[u32]>,
    certs: Option<&[Cert<D>]>,
) -> (Evaluation, Vec<u32>, Vec<Cert<D>>) {
    let n = pr.source.len() / D;
    let tree = pr.target.search;
    // Read once: through the trait object each call is an indirect call, and the registers it
    // clobbers were spilled around it on every point (measured: 4 % of a 2D registration).
    let pts = tree.points();
    // Certificates for the next evaluation: only the iterations' searches need them.
    let certify = pr.certify && tree.certifies() && keep_correspondences && fixed.is_none();
    let gate = pr.max_sq.sqrt();
    // Several chunks are gathered into `whole`'s lists; a single one (a 2D scan) hands its
    // own over (`Acc::merge`), without a second allocation and copy.
    let many = n > chunk_len(n);
    let mut whole = Acc::<D, N>::new(if keep_correspondences && many { n } else { 0 });
    if certify && many {
        whole.certs.reserve_exact(n);
    }
    let acc = chunked_sum(
        n,
        whole,
        |range| {
            let mut acc = Acc::<D, N>::new(if keep_correspondences { range.len() } else { 0 });
            if certify {
                acc.certs.reserve_exact(range.len());
            }
            // The previous source point's correspondence: the hint for a point that has none of
            // its own (the first iteration, or none inside the gate last time). Scans come in
            // beam order, so neighbouring source points usually match neighbouring target
            // points; where they do not, the hint only costs its distance (same result).
            let mut last = NONE;
            // Phase 1, association: each point's correspondence and squared distance (`NONE`:
            // none in the gate). The searches are calls (through the trait object), around which
            // every live float is spilled; phase 2 makes none, and compiles per method and for
            // the kernel-free case (Intel pairs, one thread: point-to-line 4 % less time,
            // point-to-point unchanged; with the kernel-free loop both 4 % less again).
            let mut matches: Vec<(u32, f64)> = Vec::with_capacity(range.len());
            for i in range.clone() {
                let p: SVector<f64, D> = vec_at(pr.source, i);
                let tp = pose.r * p + pose.t;
                let hint = || {
                    let h = hints.map_or(last, |h| if h[i] != NONE { h[i] } else { last });
                    (h != NONE).then_some(h as usize)
                };
                let found = match fixed {
                    None if certify => {
                        // A certificate goes with the correspondence its search found.
                        let prior = certs.zip(hints).map(|(c, h)| (c[i], h[i]));
                        let settled = match prior {
                            Some((c, id)) => c.answer(&tp, id, pts, pr.max_sq),
                            None => Err(f64::INFINITY),
                        };
                        match settled {
                            Ok(answer) => {
                                acc.certs.push(prior.expect("settled by a certificate").0);
                                answer
                            }
                            Err(moved) => {
                                // Search past the answer by twice the point's last move, so the
                                // certificate outlasts a next move as large; while the points
                                // still move far (or before they have moved), no further.
                                let slack = if 2.0 * moved <= CERT_SLACK_MAX * gate {
                                    2.0 * moved
                                } else {
                                    0.0
                                };
                                let (answer, clear_sq) =
                                    tree.nearest_certified(tp.as_slice(), pr.max_sq, hint(), slack);
                                let id = answer.map_or(NONE, |(j, _)| j as u32);
                                acc.certs.push(Cert::new(&tp, id, clear_sq.sqrt(), pts));
                                answer
                            }
                        }
                    }
                    None => tree.nearest_within_hinted(tp.as_slice(), pr.max_sq, hint()),
                    Some(c) if c[i] != NONE => {
                        let j = c[i] as usize;
                        let d2 = (tp - vec_at::<D>(pts, j)).norm_squared();
                        (d2 <= pr.max_sq).then_some((j, d2))
                    }
                    Some(_) => None,
                };
                if let Some((j, d2)) = found {
                    last = j as u32;
                    acc.in_gate += 1;
                    // Kept even without a factor (a target point with no normal): the next
                    // search's hint, and the final evaluation's count of points in the gate.
                    matches.push((j as u32, d2));
                } else {
                    matches.push((NONE, 0.0));
                }
            }
            if keep_correspondences {
                acc.corr.extend(matches.iter().map(|m| m.0));
            }
            // Phase 2, accumulation, in the same order (the same sums to the bit); one loop
            // per method, each free of the others' branches and registers.
            let plain = pr.kernel == Kernel::None;
            let phase2 = match (pr.method, plain) {
                (Method::PointToPoint, false) => accumulate::<G, D, N, 0, false>,
                (Method::PointToPlane, false) => accumulate::<G, D, N, 1, false>,
                (Method::Gicp, false) => accumulate::<G, D, N, 2, false>,
                (Method::PointToPoint, true) => accumulate::<G, D, N, 0, true>,
                (Method::PointToPlane, true) => accumulate::<G, D, N, 1, true>,
                (Method::Gicp, true) => accumulate::<G, D, N, 2, true>,
            };
            let sums = phase2(pr, pose, pts, range, &matches, with_scores);
            acc.sums = sums;
            acc
        },
        Acc::merge,
    );
    let s = &acc.sums;
    let mut hl = s.hl;
    hl.fill_upper_triangle_with_lower_triangle();
    let h = s.h + hl + G::moment_hessian(s.mk, &s.mkp, &s.mrot);
    let eval = Evaluation {
        hessian: h.transpose().iter().copied().collect(),
        gradient: s.g.iter().copied().collect(),
        score_outer: s.m.transpose().iter().copied().collect(),
        cost: s.cost,
        num_correspondences: s.count,
        num_in_gate: acc.in_gate,
        sum_squares: s.ss,
        irls_sum_squares: s.irls_ss,
        irls_weight_sum: s.irls_w,
        sum_squared_distances: s.dist_ss,
    };
    (eval, acc.corr, acc.certs)
}

/// Phase 2 of [`evaluate`]: the sums over one chunk's `matches` (`(target id, squared
/// distance)` per source point of `range`, `NONE`: none), for the method numbered `M` (0
/// point-to-point, 1 point-to-plane/line, 2 GICP: a constant, so each method compiles to its
/// own loop); `PLAIN`: no kernel (weights 1, `ρ = r²/2`, as `Kernel::None` computes them,
/// without its branches).
#[inline(always)]
fn accumulate<G: Group<D, N>, const D: usize, const N: usize, const M: u8, const PLAIN: bool>(
    pr: &Problem<'_>,
    pose: &Pose<D>,
    pts: &[f64],
    range: std::ops::Range<usize>,
    matches: &[(u32, f64)],
    with_scores: bool,
) -> Sums<D, N> {
    let method = [Method::PointToPoint, Method::PointToPlane, Method::Gicp][M as usize];
    let mut sums = Sums::<D, N>::zeros();
    for (i, &(j, d2)) in range.zip(matches) {
        if j == NONE {
            continue;
        }
        let j = j as usize;
        let p: SVector<f64, D> = vec_at(pr.source, i);
        // Recomputed, not kept from phase 1: the same bits, and a 32-byte `matches` entry
        // instead of 16 was slower (Intel point-to-point 81.1 -> 83.0 µs per pair).
        let tp = pose.r * p + pose.t;
        let e = tp - vec_at::<D>(pts, j);
        if let Some((h, g, norm)) = factor::<G, D, N>(pr, method, pose, i, j, &p, &e) {
            let k = if PLAIN { 1.0 } else { pr.kernel.weight(norm) };
            match h {
                Curvature::Full(h) => sums.h += h * k,
                Curvature::RankOne(j) => {
                    let kj = j * k;
                    for c in 0..N {
                        for r in c..N {
                            sums.hl[(r, c)] += kj[r] * j[c];
                        }
                    }
                }
                Curvature::Moments => {
                    sums.mk += k;
                    sums.mkp += p * k;
                    sums.mrot += G::rotation_moment(&p) * k;
                }
            }
            let score = g * k;
            sums.g += score;
            if with_scores {
                sums.m += score * score.transpose();
            }
            sums.cost += if PLAIN {
                0.5 * (norm * norm)
            } else {
                pr.kernel.rho(norm)
            };
            sums.count += 1;
            sums.ss += norm * norm;
            sums.irls_ss += k * norm * norm;
            sums.irls_w += k;
            sums.dist_ss += d2;
        }
    }
    sums
}

/// The robust cost at `pose` over fixed correspondences (LM acceptance test).
fn fixed_cost<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    pose: &Pose<D>,
    corr: &[u32],
) -> f64 {
    let pts = pr.target.search.points();
    chunked_sum(
        corr.len(),
        0.0,
        |range| {
            let mut cost = 0.0;
            for i in range {
                let j = corr[i];
                if j == NONE {
                    continue;
                }
                let j = j as usize;
                let p: SVector<f64, D> = vec_at(pr.source, i);
                let e = pose.r * p + pose.t - vec_at::<D>(pts, j);
                let norm = match pr.method {
                    Method::PointToPoint => e.norm(),
                    Method::PointToPlane => pr
                        .target
                        .normals
                        .map_or(0.0, |n| vec_at::<D>(n, j).dot(&e).abs()),
                    Method::Gicp => {
                        let (Some(tc), Some(sc)) = (pr.target.covariances, pr.source_covs) else {
                            continue;
                        };
                        let c = mat_at::<D>(tc, j / pr.cov_group)
                            + pose.r * mat_at::<D>(sc, i) * pose.r.transpose();
                        match G::inverse(&c) {
                            Some(w) => e.dot(&(w * e)).max(0.0).sqrt(),
                            None => continue,
                        }
                    }
                };
                cost += pr.kernel.rho(norm);
            }
            cost
        },
        |a, b| a + b,
    )
}

/// Besl & McKay's (1992, §IV.C) accelerated ICP, with a safeguard: when two successive small
/// steps point the same way and shrink by `ρ`, the step is lengthened by the rest of the
/// geometric series, `ρ/(1 − ρ)` of it (at most twice, so at most 3× in all), and the next
/// evaluation keeps the stretched pose only if its truncated cost is no higher than the cost
/// where the step started; else it falls back to the plain step (one extra search) and waits
/// two steps. Point-to-point and point-to-plane/line (not GICP, nor under LM): point-to-point
/// iterations end in a long slide of small parallel steps along the surfaces; point-to-plane
/// gains less (its slides are short, and on the outdoor pair the roll steps grow before they
/// shrink): KITTI 7 → 6 and the outdoor pair 9 → 8 at 1e-3 m / 0.1°, 0.88-0.92× the time,
/// the basin of convergence 61 → 62 % (outdoor) and 51 → 52 % (simulated street); in 2D it
/// costs 2 % time for a lower median error (Intel 11.5 → 11.1 mm, simulated 13.4 → 11.8).
struct Extrapolation<const D: usize, const N: usize> {
    on: bool,
    /// The rotation rows of a step times this (the source's RMS radius), so the angle between
    /// two steps weighs a radian as the motion it gives the points.
    lever: f64,
    /// Only steps that move the points by less than this are stretched (a tenth of the
    /// gate): the final slide along the surfaces, not the first large steps, whose stretch
    /// can jump to another basin (measured: the outdoor pair's basin lost 4 of 120 starts).
    small: f64,
    previous: Option<SVector<f64, N>>,
    wait: usize,
    /// The plain pose and the truncated cost where the stretched step started.
    fallback: Option<(Pose<D>, f64)>,
}

impl<const D: usize, const N: usize> Extrapolation<D, N> {
    fn new(on: bool, source: &[f64], gate: f64) -> Self {
        let n = (source.len() / D).max(1) as f64;
        let ss: f64 = source.iter().map(|v| v * v).sum();
        Extrapolation {
            on,
            lever: (ss / n).sqrt().max(1e-12),
            small: 0.1 * gate,
            previous: None,
            wait: 0,
            fallback: None,
        }
    }

    /// At a pose reached by a stretched step: the plain pose to use instead when `energy`
    /// is higher than where the step started.
    fn check(&mut self, energy: f64) -> Option<Pose<D>> {
        let (plain, before) = self.fallback.take()?;
        if energy <= before {
            return None;
        }
        self.wait = 2;
        self.previous = None;
        Some(plain)
    }

    fn pending(&mut self, plain: Pose<D>, energy: f64) {
        self.fallback = Some((plain, energy));
    }

    /// The stretch for the step `d` (1: none).
    fn factor(&mut self, d: &SVector<f64, N>) -> f64 {
        if !self.on {
            return 1.0;
        }
        let mut v = *d;
        for k in D..N {
            v[k] *= self.lever;
        }
        let previous = self.previous.replace(v);
        if self.wait > 0 {
            self.wait -= 1;
            return 1.0;
        }
        let Some(p) = previous else { return 1.0 };
        let (a, b) = (v.norm(), p.norm());
        let rho = a / b;
        if !(v.dot(&p) > 0.95 * a * b && rho < 0.9 && a < self.small) {
            return 1.0;
        }
        self.wait = 1; // never two stretched steps in a row
        1.0 + (rho / (1.0 - rho)).min(2.0)
    }
}

/// The source's centroid, as `p₀ + mean(p − p₀)` (`p₀` the first point): the differences are
/// small wherever the cloud sits, so the sum keeps its precision at map coordinates, and the
/// centroid moves with the cloud to the rounding of its coordinates.
fn centroid<const D: usize>(source: &[f64]) -> SVector<f64, D> {
    let n = source.len() / D;
    if n == 0 {
        return SVector::zeros();
    }
    let p0: SVector<f64, D> = vec_at(source, 0);
    let mut sum = SVector::<f64, D>::zeros();
    for i in 0..n {
        sum += vec_at::<D>(source, i) - p0;
    }
    p0 + sum / n as f64
}

/// `source − c`, point by point (a copy, then in place: the flat iterator was measurably slower
/// on a 2D scan).
fn centred_copy<const D: usize>(source: &[f64], c: &SVector<f64, D>) -> Vec<f64> {
    let mut out = source.to_vec();
    for p in out.chunks_exact_mut(D) {
        for k in 0..D {
            p[k] -= c[k];
        }
    }
    out
}

/// `M` with `δ_c = M δ`: a right-perturbation `δ` of `T` (about the source frame's origin)
/// expressed about the point `c` of the source frame, i.e. of `T · Tr(c)` (`M = Ad(Tr(−c))`:
/// the translation part gains the rotation's lever arm `A(c)`).
fn recentring<G: Group<D, N>, const D: usize, const N: usize>(
    c: &SVector<f64, D>,
) -> SMatrix<f64, N, N> {
    let a = G::point_jacobian(c);
    let mut m = SMatrix::<f64, N, N>::identity();
    for i in 0..D {
        for j in D..N {
            m[(i, j)] = a[(i, j)];
        }
    }
    m
}

/// An evaluation about the centroid (`δ_c`) expressed over `δ` about the source origin, the
/// convention of [`Evaluation`]: with `δ_c = M δ`, `H = MᵀH_cM`, `g = Mᵀg_c`, `S = MᵀS_cM`.
fn express_in_source_frame<const N: usize>(ev: &mut Evaluation, m: &SMatrix<f64, N, N>) {
    let back = |flat: &mut Vec<f64>| {
        if flat.len() == N * N {
            let h = SMatrix::<f64, N, N>::from_row_slice(flat);
            let o = m.transpose() * h * m;
            *flat = o.transpose().iter().copied().collect();
        }
    };
    back(&mut ev.hessian);
    back(&mut ev.score_outer);
    let g = m.transpose() * SVector::<f64, N>::from_column_slice(&ev.gradient);
    ev.gradient = g.iter().copied().collect();
}

/// The iteration of [`register`], in a frame centred on the source's centroid `c`.
///
/// Why: the update `T ← T · exp(δ)` perturbs the pose about the source frame's origin, so far
/// from it (map or UTM coordinates: 10³-10⁷ m) a small rotation carries a translation of
/// `|c| · δθ`: the step bound saw a divergence, the convergence test never passed, and the
/// normal equations (entries ~|c|²) lost the digits the solve needs. Solving for
/// `T_c = T · Tr(c)` on the points `p − c` instead makes every per-point product (Jacobians,
/// `JᵀWJ`, the lever of the step extrapolation) independent of where the clouds sit: the
/// residuals `R(p − c) + t_c − q` still subtract map coordinates, but float64 resolves those to
/// ~1e-9 m at 1e7 m. The step `δ_c` is the motion of the centroid and the rotation, so the
/// step bound (`Diverged`) and the tolerances (`Converged`) act on how far the source points
/// move, wherever the clouds are. The outcome is expressed back: `T = T_c · Tr(−c)`, and the
/// evaluation over `δ` about the source origin (`express_in_source_frame`).
fn run<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    init: &[f64],
    s: &Settings,
) -> Outcome {
    let c = centroid::<D>(pr.source);
    let centred = centred_copy::<D>(pr.source, &c);
    let local = Problem {
        source: &centred,
        ..*pr
    };
    let start = Pose::<D>::from_flat(init);
    let start = Pose {
        t: start.r * c + start.t,
        r: start.r,
    };
    let m = recentring::<G, D, N>(&c);
    let mut out = iterate::<G, D, N>(&local, start, s, &m);
    let mut pose = Pose::<D>::from_flat(&out.pose);
    pose.t -= pose.r * c;
    out.pose = pose.to_flat();
    express_in_source_frame(&mut out.evaluation, &m);
    out
}

/// The normal equations at `pose`, computed about the source's centroid (see [`run`]) and
/// expressed over `δ` about the source origin.
fn evaluate_centred<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    pose: &[f64],
) -> Evaluation {
    let c = centroid::<D>(pr.source);
    let centred = centred_copy::<D>(pr.source, &c);
    let local = Problem {
        source: &centred,
        ..*pr
    };
    let at = Pose::<D>::from_flat(pose);
    let at = Pose {
        t: at.r * c + at.t,
        r: at.r,
    };
    let mut ev = evaluate::<G, D, N>(&local, &at, true, false, None, None, None).0;
    express_in_source_frame(&mut ev, &recentring::<G, D, N>(&c));
    ev
}

/// The loop of [`run`] on a centred problem from `start`; `m` maps a step about the source
/// origin to one about the centroid (the caller's `step_projector` is over the former).
fn iterate<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    start: Pose<D>,
    s: &Settings,
    m: &SMatrix<f64, N, N>,
) -> Outcome {
    let mut pose = start;
    let lm = s.optimizer == Optimizer::LevenbergMarquardt;
    let mut lambda = 1e-4;
    let mut iterations = 0;
    let mut stop = StopReason::MaxIterations;
    let mut times = Vec::with_capacity(s.max_iterations);
    let mut last_corr: Vec<u32> = Vec::new();
    // The previous iteration's correspondences: each search starts from them.
    let mut prev_corr: Vec<u32> = Vec::new();
    // ... and what those searches proved (see `Cert`).
    let mut prev_certs: Vec<Cert<D>> = Vec::new();
    let mut accel = Extrapolation::<D, N>::new(
        matches!(pr.method, Method::PointToPoint | Method::PointToPlane) && !lm && s.extrapolate,
        pr.source,
        pr.max_sq.sqrt(),
    );
    // Consecutive over-long steps (see below).
    let mut overlong = 0;
    // The truncated cost and pose of the last iterations, and whether they cycled (see below).
    let mut orbit: Vec<(f64, Pose<D>)> = Vec::with_capacity(ORBIT_MEMORY);
    let mut cycled = false;
    let n_source = pr.source.len() / D;
    let outside = pr.kernel.rho(pr.max_sq.sqrt());
    // The truncated cost: a point outside the gate counts as at the gate.
    let energy = |e: &Evaluation| e.cost + (n_source - e.num_in_gate) as f64 * outside;
    for _ in 0..s.max_iterations {
        let t0 = Instant::now();
        let (mut lin, mut corr, mut cert) = evaluate::<G, D, N>(
            pr,
            &pose,
            false,
            true,
            None,
            hints(&prev_corr),
            certs(&prev_certs),
        );
        if let Some(plain) = accel.check(energy(&lin)) {
            // The extrapolated pose is worse than the one it left: take the plain step.
            pose = plain;
            (lin, corr, cert) =
                evaluate::<G, D, N>(pr, &pose, false, true, None, hints(&corr), certs(&cert));
        }
        if lin.num_correspondences < s.min_correspondences {
            stop = StopReason::TooFewCorrespondences;
            break;
        }
        // A periodic orbit: Gauss–Newton can cycle among a few correspondence sets near the
        // minimum (a KITTI sweep against the odometry map: five poses a few mm apart, forever).
        // The truncated cost then repeats (to the rounding of the pose's composition); the best
        // pose of the cycle is the answer.
        let e_now = energy(&lin);
        if let Some(k) = orbit
            .iter()
            .position(|(e, _)| (e - e_now).abs() <= ORBIT_MATCH * e_now.abs())
        {
            let (_, best) =
                orbit
                    .drain(k..)
                    .fold((e_now, pose.clone()), |a, b| if b.0 < a.0 { b } else { a });
            pose = best;
            stop = StopReason::Converged;
            cycled = true;
            break;
        }
        if orbit.len() == ORBIT_MEMORY {
            orbit.remove(0);
        }
        orbit.push((e_now, pose.clone()));
        iterations += 1;
        let h = SMatrix::<f64, N, N>::from_row_slice(&lin.hessian);
        let g = SVector::<f64, N>::from_column_slice(&lin.gradient);
        let mut step: Option<SVector<f64, N>> = None;
        let mut at_minimum = false;
        let solve = |hm: &SMatrix<f64, N, N>| match &s.step_projector {
            Some(p) => {
                // The projector is over steps about the source origin: solve there (H = MᵀH_cM,
                // g = Mᵀg_c), then express the step about the centroid.
                let (hm, g) = (m.transpose() * hm * m, m.transpose() * g);
                // Stiffen the weak directions (Q = I − P) so a singular H still solves, then
                // remap: no motion along them.
                let p = SMatrix::<f64, N, N>::from_row_slice(&p[..N * N]);
                let q = SMatrix::<f64, N, N>::identity() - p;
                let stiff = hm.trace().abs().max(1e-300) / N as f64;
                G::solve(&(hm + q.transpose() * q * stiff), &(-g)).map(|d| m * (p * d))
            }
            None => G::solve(hm, &(-g)),
        };
        if lm {
            let max_diag = (0..N).map(|k| h[(k, k)]).fold(0.0, f64::max);
            if max_diag > 0.0 && max_diag.is_finite() {
                loop {
                    let mut hd = h;
                    for k in 0..N {
                        hd[(k, k)] += lambda * h[(k, k)].max(1e-12 * max_diag);
                    }
                    if let Some(d) = solve(&hd) {
                        let (rd, td) = G::exp(&d);
                        let cand = pose.compose(&rd, &td);
                        if fixed_cost::<G, D, N>(pr, &cand, &corr) <= lin.cost {
                            lambda = (lambda / 10.0).max(1e-12);
                            step = Some(d);
                            break;
                        }
                    }
                    lambda *= 10.0;
                    if lambda > 1e8 {
                        at_minimum = true; // no step lowers the cost: a local minimum
                        break;
                    }
                }
            }
        } else {
            step = solve(&h);
        }
        times.push(t0.elapsed().as_secs_f64());
        if at_minimum {
            stop = StopReason::Converged;
            last_corr = corr;
            break;
        }
        let Some(d) = step else {
            stop = StopReason::Degenerate;
            break;
        };
        if d.iter().any(|v| !v.is_finite()) {
            stop = StopReason::Diverged;
            break;
        }
        let (mut d, mut dt, mut dr) = (d, d.rows(0, D).norm(), d.rows(D, N - D).norm());
        // Every correspondence is within the gate, so a sound step moves the source by about the
        // gate at most; a far larger one (or a quarter turn) comes from a near-singular H, as
        // from a start far outside the basin (a guess 70° off). Such a step is shortened to a
        // gate of centroid motion and π/8 of rotation, the region where the linearisation
        // holds, and the loop goes on from there: the start pose is not returned as
        // `Diverged`. Only iterates that keep asking for such steps run away.
        let gate = s.max_correspondence_distance;
        if dt > 10.0 * gate || dr > std::f64::consts::FRAC_PI_2 {
            overlong += 1;
            if overlong >= MAX_OVERLONG_STEPS {
                stop = StopReason::Diverged;
                break;
            }
            let f = (gate / dt).min(std::f64::consts::FRAC_PI_8 / dr).min(1.0);
            (d, dt, dr) = (d * f, dt * f, dr * f);
        } else {
            overlong = 0;
        }
        let converged = dt < s.translation_tolerance && dr < s.rotation_tolerance;

        let (rd, td) = G::exp(&d);
        let next = pose.compose(&rd, &td);
        if !next.is_finite() {
            stop = StopReason::Diverged;
            break;
        }
        let factor = if converged { 1.0 } else { accel.factor(&d) };
        if factor > 1.0 {
            let (re, te) = G::exp(&(d * factor));
            let far = pose.compose(&re, &te);
            if far.is_finite() {
                accel.pending(next.clone(), energy(&lin));
                pose = far;
            } else {
                pose = next;
            }
        } else {
            pose = next;
        }
        if converged {
            stop = StopReason::Converged;
            last_corr = corr;
            break;
        }
        prev_corr = corr;
        prev_certs = cert;
    }
    let t0 = Instant::now();
    // After a converged (sub-tolerance) last step the correspondences cannot have changed
    // meaningfully: re-use them instead of a full search (saves one nearest-neighbour pass).
    // (Not after a cycle: the best pose's correspondences were not kept.)
    let fixed = (stop == StopReason::Converged && !cycled).then_some(last_corr.as_slice());
    let (mut evaluation, mut correspondences, cert) = evaluate::<G, D, N>(
        pr,
        &pose,
        true,
        true,
        fixed,
        hints(&prev_corr),
        certs(&prev_certs),
    );
    // The iteration cap right after a stretched step: it is checked here, like any other.
    if let Some(plain) = accel.check(energy(&evaluation)) {
        pose = plain;
        // (After a fixed evaluation there are no certificates for its correspondences.)
        (evaluation, correspondences, _) = evaluate::<G, D, N>(
            pr,
            &pose,
            true,
            true,
            None,
            hints(&correspondences),
            certs(&cert),
        );
    }
    if evaluation.num_correspondences < s.min_correspondences {
        stop = StopReason::TooFewCorrespondences;
    }
    Outcome {
        pose: pose.to_flat(),
        iterations,
        stop_reason: stop,
        evaluation,
        iteration_seconds: times,
        final_evaluation_seconds: t0.elapsed().as_secs_f64(),
        correspondences,
    }
}

fn check_settings(s: &Settings) -> Result<f64> {
    let max_sq = check_max_distance("max_correspondence_distance", s.max_correspondence_distance)?;
    if let Some(p) = &s.step_projector {
        if p.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid("step_projector", "contains NaN or inf"));
        }
    }
    for (arg, v) in [
        ("translation_tolerance", s.translation_tolerance),
        ("rotation_tolerance", s.rotation_tolerance),
    ] {
        if !v.is_finite() || v <= 0.0 {
            return Err(Error::invalid(
                arg,
                format!("must be finite and > 0, got {v}"),
            ));
        }
    }
    Ok(max_sq)
}

fn check_per_point(
    arg: &'static str,
    data: &[f64],
    n: usize,
    per: usize,
    validated: bool,
) -> Result<()> {
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
    if !validated && data.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(arg, "contains NaN or inf"));
    }
    Ok(())
}

fn problem<'a>(
    source: &'a Source<'a>,
    target: &'a Target<'a>,
    settings: &Settings,
) -> Result<Problem<'a>> {
    let dim = target.search.dim();
    let n = check_points("source", source.points, dim)?;
    let max_sq = check_settings(settings)?;
    let m = target.search.id_count();
    let checked = target.search.attributes_validated();
    match settings.method {
        Method::PointToPoint => {}
        Method::PointToPlane => {
            let nrm = target.normals.ok_or_else(|| {
                Error::invalid("target_normals", "are required for point-to-plane/line")
            })?;
            check_per_point("target_normals", nrm, m, dim, checked)?;
        }
        Method::Gicp => {
            let tc = target
                .covariances
                .ok_or_else(|| Error::invalid("target_covariances", "are required for GICP"))?;
            let rows = m / target.search.covariance_group().max(1);
            check_per_point("target_covariances", tc, rows, dim * dim, checked)?;
            let sc = source
                .covariances
                .ok_or_else(|| Error::invalid("source_covariances", "are required for GICP"))?;
            check_per_point("source_covariances", sc, n, dim * dim, false)?;
        }
    }
    Ok(Problem {
        source: source.points,
        source_covs: source.covariances,
        target,
        method: settings.method,
        kernel: settings.kernel,
        max_sq,
        cov_group: target.search.covariance_group().max(1),
        certify: true,
    })
}

/// Register `source` to `target` from `init` (row-major homogeneous `T_target_source`).
pub fn register(
    source: &Source<'_>,
    target: &Target<'_>,
    init: &[f64],
    settings: &Settings,
) -> Result<Outcome> {
    let dim = target.search.dim();
    let pr = problem(source, target, settings)?;
    split_pose("init", init, dim)?;
    Ok(if dim == 2 {
        run::<Planar, 2, 3>(&pr, init, settings)
    } else {
        run::<Spatial, 3, 6>(&pr, init, settings)
    })
}

/// The normal equations at one pose (with score outer products), without iterating.
pub fn evaluate_at(
    source: &Source<'_>,
    target: &Target<'_>,
    pose: &[f64],
    settings: &Settings,
) -> Result<Evaluation> {
    let dim = target.search.dim();
    let pr = problem(source, target, settings)?;
    split_pose("pose", pose, dim)?;
    Ok(if dim == 2 {
        evaluate_centred::<Planar, 2, 3>(&pr, pose)
    } else {
        evaluate_centred::<Spatial, 3, 6>(&pr, pose)
    })
}

/// The previous iteration's correspondences as search hints (none before the first).
fn hints(prev: &[u32]) -> Option<&[u32]> {
    (!prev.is_empty()).then_some(prev)
}

/// The previous search's certificates (none before the first, or after a fixed evaluation).
fn certs<const D: usize>(prev: &[Cert<D>]) -> Option<&[Cert<D>]> {
    (!prev.is_empty()).then_some(prev)
}

/// Run `f` on a rayon pool of `num_threads` threads (pools are built once per size and kept),
/// or on the global pool when `None`.
pub fn in_pool<T: Send>(num_threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    let Some(n) = num_threads else {
        return Ok(f());
    };
    if n == 0 {
        return Err(Error::invalid("num_threads", "must be >= 1"));
    }
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<ThreadPool>>>> = OnceLock::new();
    let pool = {
        let mut pools = POOLS
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        match pools.get(&n) {
            Some(p) => p.clone(),
            None => {
                let p = Arc::new(
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(n)
                        .build()
                        .map_err(|e| Error::invalid("num_threads", e.to_string()))?,
                );
                pools.insert(n, p.clone());
                p
            }
        }
    };
    Ok(pool.install(f))
}

#[cfg(test)]
mod tests;
