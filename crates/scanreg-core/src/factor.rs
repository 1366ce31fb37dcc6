//! One factor per cost: its residual and Jacobian in the right-perturbation convention, and the
//! one accumulator of the normal equations they go into. Shared by the ICP loop ([`crate::icp`],
//! correspondences searched) and the paired solve ([`crate::paired`], correspondences given),
//! so both linearise a pair the same way.
//!
//! With `e = R p + t − q` and `A(p) = ∂(p ⊕ δ)/∂δ` ([`Group::point_jacobian`]: `[I, −[p]×]` in
//! 3D, `[I, p⊥]` in 2D):
//! * point-to-point: `r = Rᵀe`, `J = A` (the residual rotated into the source frame, which
//!   leaves `|r|` and `JᵀJ` unchanged);
//! * point-to-plane (3D) / point-to-line (2D): `r = nᵀe`, `J = (Rᵀn)ᵀ A`;
//! * GICP (Segal et al. 2009, eq. 2): `r = e` weighted by `W = (C_q + R C_p Rᵀ)⁻¹`, `J = R A`;
//!   `W` is held fixed while linearising (as in the paper and its implementations).

use crate::group::Group;
use nalgebra::{SMatrix, SVector};

/// How one factor's `JᵀWJ` is added: the per-point `N × N` products were a third of a 3D ICP
/// iteration's time.
pub enum Curvature<const N: usize> {
    /// Point-to-point: `A(p)ᵀA(p)`, which depends on `p` alone (the sums keep its moments).
    Moments,
    /// Point-to-plane/line: `jᵀj` for the one Jacobian row `j` (lower triangle only).
    RankOne(SVector<f64, N>),
    /// GICP: the full matrix.
    Full(SMatrix<f64, N, N>),
}

/// One factor reduced to what the accumulator needs.
pub struct Factor<const N: usize> {
    pub curvature: Curvature<N>,
    /// `JᵀW r`.
    pub gradient: SVector<f64, N>,
    /// `|r|` (point-to-point; the Mahalanobis `sqrt(rᵀWr)` for GICP), or the signed `nᵀe`
    /// (point-to-plane/line): the kernel weighs its absolute value.
    pub residual: f64,
}

/// Point-to-point at source point `p` (`rt = Rᵀ`).
#[inline(always)]
pub fn point_to_point<G: Group<D, N>, const D: usize, const N: usize>(
    p: &SVector<f64, D>,
    rt: &SMatrix<f64, D, D>,
    e: &SVector<f64, D>,
) -> Factor<N> {
    let r = rt * e;
    Factor {
        curvature: Curvature::Moments,
        gradient: G::point_jacobian(p).transpose() * r,
        residual: e.norm(),
    }
}

/// Point-to-plane/line against the unit target normal `n`.
#[inline(always)]
pub fn point_to_plane<G: Group<D, N>, const D: usize, const N: usize>(
    p: &SVector<f64, D>,
    rt: &SMatrix<f64, D, D>,
    n: &SVector<f64, D>,
    e: &SVector<f64, D>,
) -> Factor<N> {
    let d = n.dot(e);
    let j = G::point_jacobian(p).transpose() * (rt * n); // the Jacobian row, as a column
    Factor {
        curvature: Curvature::RankOne(j),
        gradient: j * d,
        residual: d,
    }
}

/// Whether a target normal is usable (a zero normal marks a point without one).
#[inline(always)]
pub fn has_normal<const D: usize>(n: &SVector<f64, D>) -> bool {
    n.norm_squared() >= 0.25
}

/// GICP's weight `W = (C_q + R C_p Rᵀ)⁻¹` in the source frame (`RᵀWR`), from the target and
/// source covariances `cq`, `cp`; `None` when the sum is singular.
#[inline(always)]
pub fn gicp_weight<G: Group<D, N>, const D: usize, const N: usize>(
    r: &SMatrix<f64, D, D>,
    cq: &SMatrix<f64, D, D>,
    cp: &SMatrix<f64, D, D>,
) -> Option<SMatrix<f64, D, D>> {
    let rt = r.transpose();
    let w = G::inverse(&(cq + mul(&mul(r, cp), &rt)))?;
    Some(mul(&mul(&rt, &w), r))
}

/// `a b`, each entry summed over `k` in order from the first product, as nalgebra's product
/// sums it (the same bits), but always inlined: the per-correspondence 3 × 3 products were
/// calls into nalgebra's generic product.
#[inline(always)]
pub fn mul<const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<f64, R, K>,
    b: &SMatrix<f64, K, C>,
) -> SMatrix<f64, R, C> {
    SMatrix::<f64, R, C>::from_fn(|i, j| {
        let mut s = a[(i, 0)] * b[(0, j)];
        for k in 1..K {
            s += a[(i, k)] * b[(k, j)];
        }
        s
    })
}

/// GICP's Mahalanobis residual `sqrt(eᵀWe)` from the source-frame weight `wl` and error
/// `el = Rᵀe`.
#[inline(always)]
pub fn gicp_residual<const D: usize>(wl: &SMatrix<f64, D, D>, el: &SVector<f64, D>) -> f64 {
    el.dot(&(wl * el)).max(0.0).sqrt()
}

/// GICP with the source-frame weight `wl` ([`gicp_weight`]).
#[inline(always)]
pub fn gicp<G: Group<D, N>, const D: usize, const N: usize>(
    p: &SVector<f64, D>,
    rt: &SMatrix<f64, D, D>,
    wl: &SMatrix<f64, D, D>,
    e: &SVector<f64, D>,
) -> Factor<N> {
    let el = rt * e;
    let wa = G::mul_jacobian(wl, p);
    Factor {
        curvature: Curvature::Full(G::jacobian_t_mul(p, &wa)),
        gradient: wa.transpose() * el,
        residual: gicp_residual(wl, &el),
    }
}

/// The normal equations and residual statistics summed over factors: plain numbers (`Copy`),
/// so a chunk's sums live in registers through a loop that makes no calls.
#[derive(Clone, Copy)]
pub struct NormalSums<const D: usize, const N: usize> {
    /// `Σ wk JᵀWJ` of the full-matrix factors.
    pub h: SMatrix<f64, N, N>,
    /// Rank-one terms, lower triangle only (mirrored by [`Self::hessian`]).
    pub hl: SMatrix<f64, N, N>,
    /// Point-to-point's Hessian as moments (`Group::moment_hessian`): `Σ wk`, `Σ wk p`, and
    /// `Σ wk rotation_moment(p)`.
    pub mk: f64,
    pub mkp: SVector<f64, D>,
    pub mrot: SMatrix<f64, D, D>,
    /// `Σ wk JᵀW r`.
    pub g: SVector<f64, N>,
    /// `Σ ψψᵀ`, `ψ = wk JᵀW r` (when asked for).
    pub m: SMatrix<f64, N, N>,
    /// `Σ w ρ(|r|)`.
    pub cost: f64,
    pub count: usize,
    /// `Σ w |r|²`.
    pub ss: f64,
    /// `Σ wk |r|²`.
    pub irls_ss: f64,
    /// `Σ wk`.
    pub irls_w: f64,
    /// `Σ |R p + t − q|²` (the ICP loop's Euclidean inlier error; the caller adds it).
    pub dist_ss: f64,
}

impl<const D: usize, const N: usize> NormalSums<D, N> {
    pub fn zeros() -> Self {
        NormalSums {
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

    /// Add factor `f` of source point `p` with weight `wk` (the pair's own weight `w` times
    /// its kernel weight) and cost `w ρ` (`rho_w`, as the caller computes it); `w` scales the
    /// sum of squares. Score outer products only `with_scores`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn add<G: Group<D, N>>(
        &mut self,
        p: &SVector<f64, D>,
        f: &Factor<N>,
        w: f64,
        wk: f64,
        rho_w: f64,
        with_scores: bool,
    ) {
        match &f.curvature {
            Curvature::Full(h) => self.h += h * wk,
            Curvature::RankOne(j) => {
                let kj = j * wk;
                for c in 0..N {
                    for r in c..N {
                        self.hl[(r, c)] += kj[r] * j[c];
                    }
                }
            }
            Curvature::Moments => {
                self.mk += wk;
                self.mkp += p * wk;
                self.mrot += G::rotation_moment(p) * wk;
            }
        }
        let score = f.gradient * wk;
        self.g += score;
        if with_scores {
            self.m += score * score.transpose();
        }
        let norm = f.residual.abs();
        self.cost += rho_w;
        self.count += 1;
        self.ss += w * norm * norm;
        self.irls_ss += wk * norm * norm;
        self.irls_w += wk;
    }

    /// Add another chunk's sums.
    pub fn merge(&mut self, o: &Self) {
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

    /// `Σ wk JᵀWJ`: the three kinds of curvature together.
    pub fn hessian<G: Group<D, N>>(&self) -> SMatrix<f64, N, N> {
        let mut hl = self.hl;
        hl.fill_upper_triangle_with_lower_triangle();
        self.h + hl + G::moment_hessian(self.mk, &self.mkp, &self.mrot)
    }
}

/// A square matrix as a row-major flat list.
pub fn row_major<const N: usize>(m: &SMatrix<f64, N, N>) -> Vec<f64> {
    m.transpose().iter().copied().collect()
}
