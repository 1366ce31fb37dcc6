//! The iteration: Gauss–Newton or Levenberg–Marquardt steps `T ← T · exp(δ)` on the normal
//! equations of [`super::evaluate`], with the step bound, the convergence and cycle tests, the
//! degeneracy-aware projection and the step extrapolation; then the final evaluation.

use super::certificate::{Cert, Certificates};
use super::evaluate::{certs, evaluate, fixed_cost, hints, Evaluation, Problem};
use super::extrapolation::Extrapolation;
use super::pose::Pose;
use super::settings::{Method, Optimizer, Settings, StopReason};
use crate::group::Group;
use nalgebra::{SMatrix, SVector};
use std::time::Instant;

/// Result of [`super::register`].
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
    /// What the last searches proved about the returned pose's neighbourhoods (see
    /// [`Certificates`]; None where the search gives no certificates): the verdict's overlap
    /// answers most of its queries from them.
    pub certificates: Option<Certificates>,
}

/// Iterations remembered to recognise a periodic orbit (cycles of up to this length).
const ORBIT_MEMORY: usize = 8;

/// Relative match of two truncated costs taken as the same state of a periodic orbit (the
/// cycle's poses differ by the rounding of their compositions: ~1e-15).
const ORBIT_MATCH: f64 = 1e-12;

/// Over-long steps in a row after which the iterates are taken to run away (`Diverged`).
const MAX_OVERLONG_STEPS: usize = 3;

/// Iterations in a row without a truncated cost below the best so far, all by small steps,
/// after which the loop stops at the best iterate (see `iterate`).
const STALL_ITERATIONS: usize = 3;

/// A small step for the stall test: it moves the points by under this fraction of the gate.
/// A step of a tenth of the gate (the extrapolation's "small") still slides along a weak
/// direction while the truncated cost rises only because points leave the gate (KITTI 3 → 2,
/// point-to-plane: the stall would have kept an iterate 11 cm short of the minimum); the
/// orbits this test is for move by millimetres per step (0.2–0.4 % of the gate).
const STALL_STEP: f64 = 0.005;

/// Where a restart stops (see [`super::Home`]), for iterates about `centroid`.
pub(super) struct Arrival<const D: usize> {
    pub(super) home: Pose<D>,
    pub(super) centroid: SVector<f64, D>,
    pub(super) radius: f64,
    pub(super) cos_angle: f64,
}

impl<const D: usize> Arrival<D> {
    /// Whether the centred iterate `p` (`T_c`) is at home.
    fn reached(&self, p: &Pose<D>) -> bool {
        let t = p.t - p.r * self.centroid;
        let rt = self.home.r.transpose();
        let rel_r = rt * p.r;
        let rel_t = rt * (t - self.home.t);
        let cos = (rel_r.trace() - (D as f64 - 2.0)) / 2.0;
        rel_t.norm() <= self.radius && cos >= self.cos_angle
    }
}

/// The loop of [`super::centred::run`] on a centred problem from `start`; `m` maps a step about the source
/// origin to one about the centroid (the caller's `step_projector` is over the former).
pub(super) fn iterate<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    start: Pose<D>,
    s: &Settings,
    m: &SMatrix<f64, N, N>,
    home: Option<&Arrival<D>>,
) -> Outcome {
    let mut pose = start;
    let lm = s.optimizer == Optimizer::LevenbergMarquardt;
    let mut lambda = 1e-4;
    let mut iterations = 0;
    let mut stop = StopReason::MaxIterations;
    let mut times = Vec::with_capacity(s.max_iterations);
    let mut last_corr: Vec<u32> = Vec::new();
    // ... and the certificates of the search that found them (the final evaluation re-uses
    // those correspondences without a search, so these are the ones its pose has).
    let mut last_certs: Vec<Cert<D>> = Vec::new();
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
    // The lowest truncated cost so far and its pose, the iterations since, and the largest
    // step taken since (the points' motion: translation plus rotation times the RMS radius of
    // the centred source); see the stall test below.
    let mut best: Option<(f64, Pose<D>)> = None;
    let mut since_best = 0;
    let mut wandered = 0.0f64;
    let lever = {
        let ss: f64 = pr.source.iter().map(|v| v * v).sum();
        (ss / (pr.source.len() / D).max(1) as f64).sqrt()
    };
    let small = STALL_STEP * pr.max_sq.sqrt();
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
        // A stall: undamped Gauss–Newton near a minimum can also wander among correspondence
        // sets without repeating exactly, its truncated cost going up and down by a percent
        // (KITTI frame 14 against the odometry map: period 5, the orbit recognised only after
        // 15 iterations, and at a higher cost than an iterate it had passed). When the cost has
        // not gone below its best for a few iterations, each a small step (`STALL_STEP`), the
        // loop is at the floor of its basin: the best iterate is the answer (frame 14: 7
        // iterations instead of 15, at a lower cost). A converging run lowers its cost nearly
        // every iteration or still moves by more, and stops on the tolerances as before. 3D
        // only: a 2D scan's few hundred beams plateau over such small steps on their way to
        // convergence (stopping there doubled the simulated 2D mapping's end error after loop
        // closure, tests/test_mapping.py, 0.014 -> 0.037 m).
        match &best {
            Some((e_best, _)) if e_now >= *e_best => since_best += 1,
            _ => {
                best = Some((e_now, pose.clone()));
                since_best = 0;
                wandered = 0.0;
            }
        }
        if D == 3 && since_best >= STALL_ITERATIONS && wandered < small {
            if let Some((_, p)) = best.take() {
                pose = p;
            }
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
            last_certs = cert;
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
        wandered = wandered.max(dt + lever * dr);
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
            // Back at home (a plain step: a stretched one may yet fall back): the answer is
            // known, whatever the remaining iterations would refine.
            if !converged && home.is_some_and(|h| h.reached(&pose)) {
                return Outcome {
                    pose: pose.to_flat(),
                    iterations,
                    stop_reason: StopReason::Converged,
                    evaluation: Evaluation::empty::<N>(),
                    iteration_seconds: times,
                    final_evaluation_seconds: 0.0,
                    correspondences: Vec::new(),
                    certificates: None,
                };
            }
        }
        if converged {
            stop = StopReason::Converged;
            last_corr = corr;
            last_certs = cert;
            break;
        }
        prev_corr = corr;
        prev_certs = cert;
    }
    if home.is_some() && !accel.is_pending() && stop != StopReason::Converged {
        // A restart (the wrong-basin probe's) needs only where it ended: no final evaluation
        // unless a stretched last step waits for its check. (Its stop reason is then the
        // loop's: fewer than `min_correspondences` is judged at its last linearisation.)
        return Outcome {
            pose: pose.to_flat(),
            iterations,
            stop_reason: stop,
            evaluation: Evaluation::empty::<N>(),
            iteration_seconds: times,
            final_evaluation_seconds: 0.0,
            correspondences: Vec::new(),
            certificates: None,
        };
    }
    let t0 = Instant::now();
    // After a converged (sub-tolerance) last step the correspondences cannot have changed
    // meaningfully: re-use them instead of a full search (saves one nearest-neighbour pass).
    // (Not after a cycle: the best pose's correspondences were not kept.)
    let fixed = (stop == StopReason::Converged && !cycled).then_some(last_corr.as_slice());
    let (mut evaluation, mut correspondences, mut cert) = evaluate::<G, D, N>(
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
        (evaluation, correspondences, cert) = evaluate::<G, D, N>(
            pr,
            &pose,
            true,
            true,
            None,
            hints(&correspondences),
            certs(&cert),
        );
    }
    // A searched final evaluation certified its own answers; a fixed one re-used the last
    // search's correspondences, whose certificates still hold wherever they are (a certificate
    // is a statement about space around its anchor, not about one pose).
    let pts = pr.target.search.points();
    let certificates = if cert.is_empty() {
        Certificates::new(&last_certs, &last_corr, pts)
    } else {
        Certificates::new(&cert, &correspondences, pts)
    };
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
        certificates,
    }
}
