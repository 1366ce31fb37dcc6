//! Safeguarded step extrapolation (Besl & McKay 1992) for the Gauss–Newton loop.

use super::pose::Pose;
use nalgebra::SVector;

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
pub(super) struct Extrapolation<const D: usize, const N: usize> {
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
    pub(super) fn new(on: bool, source: &[f64], gate: f64) -> Self {
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
    pub(super) fn check(&mut self, energy: f64) -> Option<Pose<D>> {
        let (plain, before) = self.fallback.take()?;
        if energy <= before {
            return None;
        }
        self.wait = 2;
        self.previous = None;
        Some(plain)
    }

    /// Whether a stretched step waits for its [`Self::check`].
    pub(super) fn is_pending(&self) -> bool {
        self.fallback.is_some()
    }

    pub(super) fn pending(&mut self, plain: Pose<D>, energy: f64) {
        self.fallback = Some((plain, energy));
    }

    /// The stretch for the step `d` (1: none).
    pub(super) fn factor(&mut self, d: &SVector<f64, N>) -> f64 {
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
