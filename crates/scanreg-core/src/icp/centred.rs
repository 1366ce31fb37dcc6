//! Solving about the source's centroid, so that results do not depend on where the clouds sit
//! (map or UTM coordinates), and expressing the outcome back about the source frame's origin.

use super::evaluate::{evaluate, Evaluation, Problem};
use super::pose::Pose;
use super::settings::Settings;
use super::solver::{iterate, Arrival, Outcome};
use crate::group::Group;
use crate::points::vec_at;
use nalgebra::{SMatrix, SVector};

/// The source's centroid, as `p₀ + mean(p − p₀)` (`p₀` the first point): the differences are
/// small wherever the cloud sits, so the sum keeps its precision at map coordinates, and the
/// centroid moves with the cloud to the rounding of its coordinates.
pub(super) fn centroid<const D: usize>(source: &[f64]) -> SVector<f64, D> {
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
pub(super) fn run<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    init: &[f64],
    s: &Settings,
) -> Outcome {
    run_home::<G, D, N>(pr, init, s, None)
}

/// [`run`], stopping on arrival at `home` (see [`super::Home`]).
pub(super) fn run_home<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    init: &[f64],
    s: &Settings,
    home: Option<&super::Home>,
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
    // The iterates are about the centroid: `T = T_c · Tr(−c)` is compared with home.
    let arrival = home.map(|h| Arrival {
        home: Pose::<D>::from_flat(&h.pose),
        centroid: c,
        radius: h.radius,
        cos_angle: h.cos_angle,
    });
    let mut out = iterate::<G, D, N>(&local, start, s, &m, arrival.as_ref());
    let mut pose = Pose::<D>::from_flat(&out.pose);
    pose.t -= pose.r * c;
    out.pose = pose.to_flat();
    express_in_source_frame(&mut out.evaluation, &m);
    out
}

/// The normal equations at `pose`, computed about the source's centroid (see [`run`]) and
/// expressed over `δ` about the source origin.
pub(super) fn evaluate_centred<G: Group<D, N>, const D: usize, const N: usize>(
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
