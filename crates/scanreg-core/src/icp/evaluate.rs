//! One linearisation of the ICP loop at a pose: associate every source point with its nearest
//! target point inside the gate (phase 1), then add each correspondence's factor
//! ([`crate::factor`]) into the normal equations with the deterministic chunked sum of
//! [`crate::reduce`] (phase 2).

use super::certificate::{Cert, CERT_SLACK_MAX};
use super::pose::Pose;
use super::search::Target;
use super::settings::Method;
use crate::factor::{self, has_normal, row_major, Factor, NormalSums};
use crate::group::Group;
use crate::kernel::Kernel;
use crate::points::{mat_at, vec_at};
use crate::reduce::{chunk_len, chunked_sum};
use nalgebra::SVector;

/// Marker for "no correspondence" in the per-point correspondence list.
pub(super) const NONE: u32 = u32::MAX;

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

impl Evaluation {
    /// No evaluation (zeros): an outcome returned without one.
    pub(super) fn empty<const N: usize>() -> Self {
        Evaluation {
            hessian: vec![0.0; N * N],
            gradient: vec![0.0; N],
            score_outer: vec![0.0; N * N],
            cost: 0.0,
            num_correspondences: 0,
            num_in_gate: 0,
            sum_squares: 0.0,
            irls_sum_squares: 0.0,
            irls_weight_sum: 0.0,
            sum_squared_distances: 0.0,
        }
    }
}

/// Inputs of one evaluation, shared by every chunk.
#[derive(Clone, Copy)]
pub(super) struct Problem<'a> {
    pub(super) source: &'a [f64],
    pub(super) source_covs: Option<&'a [f64]>,
    pub(super) target: &'a Target<'a>,
    pub(super) method: Method,
    pub(super) kernel: Kernel,
    pub(super) max_sq: f64,
    /// See [`super::NeighborSearch::covariance_group`].
    pub(super) cov_group: usize,
    /// Skip the searches a [`Cert`] settles (the same answers; off only to test that).
    pub(super) certify: bool,
}

/// A chunk's sums, and the lists the loop keeps per source point.
struct Acc<const D: usize, const N: usize> {
    sums: NormalSums<D, N>,
    in_gate: usize,
    corr: Vec<u32>,
    certs: Vec<Cert<D>>,
}

impl<const D: usize, const N: usize> Acc<D, N> {
    fn new(keep: usize) -> Self {
        Acc {
            sums: NormalSums::zeros(),
            in_gate: 0,
            corr: Vec::with_capacity(keep),
            certs: Vec::new(),
        }
    }

    fn merge(mut self, o: Self) -> Self {
        self.sums.merge(&o.sums);
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

/// The factor of source point `i` (at `p`, error `e` to target point `j`) for `method`, or
/// `None` when the pair forms none (a target point without a normal, a singular GICP sum).
#[inline(always)]
fn factor_of<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    method: Method,
    pose: &Pose<D>,
    i: usize,
    j: usize,
    p: &SVector<f64, D>,
    e: &SVector<f64, D>,
) -> Option<Factor<N>> {
    let rt = pose.r.transpose();
    match method {
        Method::PointToPoint => Some(factor::point_to_point::<G, D, N>(p, &rt, e)),
        Method::PointToPlane => {
            let n: SVector<f64, D> = vec_at(pr.target.normals?, j);
            has_normal(&n).then(|| factor::point_to_plane::<G, D, N>(p, &rt, &n, e))
        }
        Method::Gicp => {
            let cq = mat_at::<D>(pr.target.covariances?, j / pr.cov_group);
            let cp = mat_at::<D>(pr.source_covs?, i);
            let wl = factor::gicp_weight::<G, D, N>(&pose.r, &cq, &cp)?;
            Some(factor::gicp::<G, D, N>(p, &rt, &wl, e))
        }
    }
}

/// Linearise at `pose`. Correspondences are searched in the tree (starting from `hints`, the
/// previous iteration's correspondences, where given: same result, less search), or taken
/// from `fixed` (one target index per source point, `NONE` for none) and re-gated.
pub(super) fn evaluate<G: Group<D, N>, const D: usize, const N: usize>(
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
    let s = &acc.sums;
    let eval = Evaluation {
        hessian: row_major(&s.hessian::<G>()),
        gradient: s.g.iter().copied().collect(),
        score_outer: row_major(&s.m),
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
) -> NormalSums<D, N> {
    let method = [Method::PointToPoint, Method::PointToPlane, Method::Gicp][M as usize];
    let mut sums = NormalSums::<D, N>::zeros();
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
        if let Some(f) = factor_of::<G, D, N>(pr, method, pose, i, j, &p, &e) {
            let norm = f.residual.abs();
            let (k, rho) = if PLAIN {
                (1.0, 0.5 * (norm * norm))
            } else {
                (pr.kernel.weight(norm), pr.kernel.rho(norm))
            };
            sums.add::<G>(&p, &f, 1.0, k, rho, with_scores);
            sums.dist_ss += d2;
        }
    }
    sums
}

/// The robust cost at `pose` over fixed correspondences (the Levenberg–Marquardt acceptance
/// test): the factors' own residuals, without their Jacobians.
pub(super) fn fixed_cost<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    pose: &Pose<D>,
    corr: &[u32],
) -> f64 {
    let pts = pr.target.search.points();
    let rt = pose.r.transpose();
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
                    Method::PointToPlane => {
                        let Some(normals) = pr.target.normals else {
                            continue;
                        };
                        let n = vec_at::<D>(normals, j);
                        if !has_normal(&n) {
                            continue;
                        }
                        n.dot(&e).abs()
                    }
                    Method::Gicp => {
                        let (Some(tc), Some(sc)) = (pr.target.covariances, pr.source_covs) else {
                            continue;
                        };
                        let cq = mat_at::<D>(tc, j / pr.cov_group);
                        let Some(wl) =
                            factor::gicp_weight::<G, D, N>(&pose.r, &cq, &mat_at::<D>(sc, i))
                        else {
                            continue;
                        };
                        factor::gicp_residual(&wl, &(rt * e))
                    }
                };
                cost += pr.kernel.rho(norm);
            }
            cost
        },
        |a, b| a + b,
    )
}

/// The previous iteration's correspondences as search hints (none before the first).
pub(super) fn hints(prev: &[u32]) -> Option<&[u32]> {
    (!prev.is_empty()).then_some(prev)
}

/// The previous search's certificates (none before the first, or after a fixed evaluation).
pub(super) fn certs<const D: usize>(prev: &[Cert<D>]) -> Option<&[Cert<D>]> {
    (!prev.is_empty()).then_some(prev)
}
