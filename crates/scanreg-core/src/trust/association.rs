//! 2D point-to-line: the point noise the nearest-neighbour association hides from the
//! residuals.
//!
//! Each source point is matched to its nearest target point, and where the noise is not small
//! against the target's sampling step that choice reads the noise: among the target points
//! within a step or so along the surface, the nearest is the one whose offset along the normal
//! is closest to the source point's. The residuals then shrink, and the point variance read off
//! them ([`super::point_variance`]) with them, while the estimate still carries the full noise
//! of both clouds. A 1D Monte Carlo (a line sampled twice, Poisson or regular steps `h`,
//! Gaussian noise `σ`, ICP to convergence with Euclidean nearest neighbours) gives residual
//! variances 0.91 / 0.80 / 0.54 / 0.33 of the true `2σ²` at `σ/h` = 0.1 / 0.2 / 0.5 / 1, and an
//! estimate's spread that follows `σ²`, not the shrunk residuals. What the residuals hide is
//! close to `a σ̂⁴ / h²` in the noise `σ̂²` they show (per coordinate, from the median squared
//! residual, so clutter and model error do not enter): `a` 7.4–8.5 under Poisson steps,
//! 3–8 under regular ones; [`HIDDEN_NOISE_GAIN`] between the two. A room sampled along its
//! walls at 2 cm with 1 cm noise: the residuals' point variance 0.55 of the truth, mean NEES
//! 6.8 against 3 (`benchmarks/cloud_covariance.py`).

/// `a` of `a σ̂⁴ / h²` (see the module docs).
pub const HIDDEN_NOISE_GAIN: f64 = 6.0;

/// Median of χ²(1): a Gaussian residual's median square over its variance.
pub(crate) const MEDIAN_CHI2_1: f64 = 0.454_936_423_119_572_8;

/// The largest `σ̂² / h²` the Monte Carlo covered (`σ/h` = 1.5: a point variance 3.8–4.7× the
/// residuals'); beyond it the model is not extrapolated.
pub const MAX_NOISE_TO_STEP: f64 = 0.46;

/// The per-coordinate point variance the association hides, `a σ̂⁴ / h²` (see the module docs),
/// `σ̂²/h²` at most [`MAX_NOISE_TO_STEP`], with `σ̂²` half the median squared point-to-line
/// residual over `median(χ²₁)`, at most `surface_noise` (the source's own noise about its
/// surfaces, [`super::scene::SamplingSystem::surface_noise`]; NaN: no bound), and `step` `h`
/// the target's mean sampling step along its surfaces. The bound keeps residuals that are not
/// noise out: a misfit, surfaces seen in one cloud only (two merged submaps: residuals 4 cm
/// where the points lie within 1 cm of their surfaces). `pose` row-major `3 × 3`;
/// `normal_of(j)` target row `j`'s normal. Zero with fewer than 3 residuals or no step.
pub fn hidden_noise_variance(
    source: &[f64],
    target: &[f64],
    correspondences: &[i64],
    pose: &[f64],
    step: f64,
    surface_noise: f64,
    normal_of: impl Fn(usize) -> Option<[f64; 2]>,
) -> f64 {
    if !(step.is_finite() && step > 0.0) || pose.len() < 9 {
        return 0.0;
    }
    let mut squares: Vec<f64> = correspondences
        .iter()
        .enumerate()
        .filter_map(|(i, &c)| {
            let j = usize::try_from(c).ok()?;
            let n = normal_of(j)?;
            let (p, q) = (source.get(2 * i..2 * i + 2)?, target.get(2 * j..2 * j + 2)?);
            let x = pose[0] * p[0] + pose[1] * p[1] + pose[2] - q[0];
            let y = pose[3] * p[0] + pose[4] * p[1] + pose[5] - q[1];
            let r = n[0] * x + n[1] * y;
            r.is_finite().then_some(r * r)
        })
        .collect();
    if squares.len() < 3 {
        return 0.0;
    }
    let mid = squares.len() / 2;
    let (_, &mut median, _) = squares.select_nth_unstable_by(mid, f64::total_cmp);
    let mut noise = median / MEDIAN_CHI2_1 / 2.0;
    if surface_noise < noise {
        noise = surface_noise;
    }
    HIDDEN_NOISE_GAIN * noise * (noise / (step * step)).min(MAX_NOISE_TO_STEP)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_against_the_step_is_hidden_in_proportion_and_clean_samples_hide_none() {
        let eye = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        // Source points 1 cm off a wall at y = 0 (alternating sides), matched to target points
        // on it: σ̂² = 1e-4 / 0.4549 / 2 per coordinate.
        let n = 101;
        let source: Vec<f64> = (0..n)
            .flat_map(|i| [i as f64 * 0.02, if i % 2 == 0 { 0.01 } else { -0.01 }])
            .collect();
        let target: Vec<f64> = (0..n).flat_map(|i| [i as f64 * 0.02, 0.0]).collect();
        let corr: Vec<i64> = (0..n as i64).collect();
        let up = |_| Some([0.0, 1.0]);
        let got = hidden_noise_variance(&source, &target, &corr, &eye, 0.02, f64::NAN, up);
        let s2 = 1e-4 / MEDIAN_CHI2_1 / 2.0;
        assert!((got - HIDDEN_NOISE_GAIN * s2 * s2 / 4e-4).abs() < 1e-15);
        // Ten times the step: a hundredth of it.
        let far = hidden_noise_variance(&source, &target, &corr, &eye, 0.2, f64::NAN, up);
        assert!((far / got - 0.01).abs() < 1e-12);
        // On the wall exactly, or without a step or matches: nothing.
        let on: Vec<f64> = target.clone();
        assert_eq!(
            hidden_noise_variance(&on, &target, &corr, &eye, 0.02, f64::NAN, up),
            0.0
        );
        assert_eq!(
            hidden_noise_variance(&source, &target, &corr, &eye, f64::NAN, f64::NAN, up),
            0.0
        );
        let none = vec![-1i64; n];
        assert_eq!(
            hidden_noise_variance(&source, &target, &none, &eye, 0.02, f64::NAN, up),
            0.0
        );
        // The pose applies to the source: moved 1 cm up, the even points 2 cm off the wall and
        // the odd ones on it, the median square 4e-4 instead of 1e-4.
        let lift = [1.0, 0.0, 0.0, 0.0, 1.0, 0.01, 0.0, 0.0, 1.0];
        let moved = hidden_noise_variance(&source, &target, &corr, &lift, 0.2, f64::NAN, up);
        assert!((moved / far - 16.0).abs() < 1e-9);
        // Bounded by the surface noise given, and by the largest noise-to-step covered.
        let bounded = hidden_noise_variance(&source, &target, &corr, &eye, 0.02, 0.5 * s2, up);
        assert!((bounded / got - 0.25).abs() < 1e-12);
        let coarse = hidden_noise_variance(&source, &target, &corr, &eye, 0.001, f64::NAN, up);
        assert!((coarse - HIDDEN_NOISE_GAIN * MAX_NOISE_TO_STEP * s2).abs() < 1e-15);
    }
}
