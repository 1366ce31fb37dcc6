//! 2D: the shift a sweep's motion distortion gives the estimate, for scans without per-beam
//! time (nothing to deskew with).
//!
//! A laser sweeps its beams one after the other while the sensor moves. A scan reported in
//! the frame of one instant (its middle) carries each beam's point off by the motion between
//! the beam's time and the middle: `d_i = u_i (ω p_i^⊥ + v)` for a sweep motion `ξ T =
//! [vx, vy, ω] · T` (the sensor's tangent over one sweep) and `u_i ∈ [−½, ½]` the beam's
//! time in the sweep, read off its bearing (the beams swept in bearing order over the scan's
//! field of view, which starts after the widest gap in bearing). To first order the
//! estimate moves by `−A⁻¹ Σ J_i r_i` with `r_i = m_i · d_i − n_j · d'_j` (`J_i`, `m_i` as
//! in [`super::scene::sampling_system`]; `d'_j` the target point's own shift when the target
//! was swept too, `n_j` its normal). Which way the beams were swept only flips the sign of
//! the shift, not its outer product, which is what the covariance takes. A map blends the
//! sweeps of several scans, each at its own rate and heading: which of them laid the matched
//! points is not known, so the covariance takes the mean of the outer products over them.

use std::f64::consts::TAU;

/// Each point's time in its sweep, `u ∈ [−½, ½]` (0 at the middle), from its bearing: the
/// sweep covers the bearings from the end of the widest gap between neighbouring bearings
/// (a 180° laser: the half behind it) round to its start. All 0 with fewer than 2 points.
pub fn sweep_fractions(points: &[f64]) -> Vec<f64> {
    let n = points.len() / 2;
    let bearing: Vec<f64> = (0..n)
        .map(|i| points[2 * i + 1].atan2(points[2 * i]))
        .collect();
    if n < 2 {
        return vec![0.0; n];
    }
    let mut sorted = bearing.clone();
    sorted.sort_by(f64::total_cmp);
    // The widest gap, the wrap from the last bearing round to the first included.
    let (mut gap, mut start) = (sorted[0] + TAU - sorted[n - 1], sorted[0]);
    for w in sorted.windows(2) {
        if w[1] - w[0] > gap {
            gap = w[1] - w[0];
            start = w[1];
        }
    }
    let span = TAU - gap;
    if span <= 0.0 {
        return vec![0.0; n];
    }
    bearing
        .iter()
        .map(|&b| ((b - start).rem_euclid(TAU) / span).min(1.0) - 0.5)
        .collect()
}

/// `d = u (ω p^⊥ + v)` of a point `p` at sweep time `u` under sweep motion `[vx, vy, ω]`.
fn shift(p: [f64; 2], u: f64, sweep: &[f64; 3]) -> [f64; 2] {
    [
        u * (-sweep[2] * p[1] + sweep[0]),
        u * (sweep[2] * p[0] + sweep[1]),
    ]
}

/// How the target was swept: its sweep motion `[vx, vy, ω] · T` in its sensor's frame, and
/// that sensor's pose in the target's frame `[c, s, tx, ty]` (`R = [c −s; s c]`; the identity
/// for a scan in its own frame; for a map, the scan that added most recently to it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetSweep {
    pub motion: [f64; 3],
    pub origin: [f64; 4],
}

/// `(H, M)`: `H = Σ J_i J_iᵀ` (3 × 3 row-major) and `M = mean_k g_k g_kᵀ` (3 × 3
/// row-major), `g_k = Σ J_i r_i` over the matched source points whose target has a normal
/// (see the module docs) with the target taken as swept by `target_sweeps[k]`. `source_sweep`:
/// the source's sweep motion `[vx, vy, ω] · T`; `target_sweeps`: how the target may have
/// been swept — one scan in its own frame (one entry), a map whose points came from several
/// sweeps, any of which laid the matched points (one entry each: their shifts' outer
/// products are averaged, since which one did is not known), or none (undistorted).
/// `rotation`: the pose's `R`, row-major. None with fewer than 3 matched points, nothing
/// swept, or mismatched lengths.
pub fn distortion_system(
    source: &[f64],
    target: &[f64],
    correspondences: &[i64],
    rotation: &[f64],
    source_sweep: Option<[f64; 3]>,
    target_sweeps: &[TargetSweep],
    normal_of: impl Fn(usize) -> Option<[f64; 2]>,
) -> Option<([f64; 9], [f64; 9])> {
    let n = source.len() / 2;
    if correspondences.len() != n || rotation.len() < 4 {
        return None;
    }
    if source_sweep.is_none() && target_sweeps.is_empty() {
        return None;
    }
    let u_src = source_sweep.map(|_| sweep_fractions(source));
    // The target in each sweep's sensor frame, `Rᵀ (q − t)`, and its beams' times there.
    let in_sensor = |o: &[f64; 4], j: usize| {
        let (x, y) = (target[2 * j] - o[2], target[2 * j + 1] - o[3]);
        [o[0] * x + o[1] * y, -o[1] * x + o[0] * y]
    };
    let local: Vec<Vec<f64>> = target_sweeps
        .iter()
        .map(|ts| {
            (0..target.len() / 2)
                .flat_map(|j| in_sensor(&ts.origin, j))
                .collect()
        })
        .collect();
    let u_tgt: Vec<Vec<f64>> = local.iter().map(|q| sweep_fractions(q)).collect();
    let alternatives = target_sweeps.len().max(1);
    let mut h = [0.0; 9];
    let mut g = vec![[0.0; 3]; alternatives];
    let mut count = 0usize;
    for i in 0..n {
        let Ok(j) = usize::try_from(correspondences[i]) else {
            continue;
        };
        if 2 * j + 1 >= target.len() {
            continue;
        }
        let Some(nt) = normal_of(j) else {
            continue;
        };
        if !(nt[0].is_finite() && nt[1].is_finite()) {
            continue;
        }
        let mx = rotation[0] * nt[0] + rotation[2] * nt[1];
        let my = rotation[1] * nt[0] + rotation[3] * nt[1];
        let p = [source[2 * i], source[2 * i + 1]];
        let mut r_source = 0.0;
        if let (Some(sw), Some(u)) = (&source_sweep, &u_src) {
            let d = shift(p, u[i], sw);
            r_source = mx * d[0] + my * d[1];
        }
        let jac = [mx, my, -mx * p[1] + my * p[0]];
        for k in 0..alternatives {
            let mut r = r_source;
            if let Some(ts) = target_sweeps.get(k) {
                // The shift in the sensor's frame, turned back into the target's.
                let q = &local[k];
                let d = shift([q[2 * j], q[2 * j + 1]], u_tgt[k][j], &ts.motion);
                let o = &ts.origin;
                let d = [o[0] * d[0] - o[1] * d[1], o[1] * d[0] + o[0] * d[1]];
                r -= nt[0] * d[0] + nt[1] * d[1];
            }
            for a in 0..3 {
                g[k][a] += jac[a] * r;
            }
        }
        for a in 0..3 {
            for b in 0..3 {
                h[3 * a + b] += jac[a] * jac[b];
            }
        }
        count += 1;
    }
    let mut m = [0.0; 9];
    for gk in &g {
        for a in 0..3 {
            for b in 0..3 {
                m[3 * a + b] += gk[a] * gk[b] / alternatives as f64;
            }
        }
    }
    (count >= 3).then_some((h, m))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_half_turn_scan_is_timed_from_its_first_beam() {
        // 181 beams over −90°..90° (bearing order = time order).
        let pts: Vec<f64> = (0..181)
            .flat_map(|k| {
                let a = (k as f64 - 90.0).to_radians();
                [2.0 * a.cos(), 2.0 * a.sin()]
            })
            .collect();
        let u = sweep_fractions(&pts);
        assert!((u[0] + 0.5).abs() < 1e-12 && (u[180] - 0.5).abs() < 1e-12);
        assert!(u[90].abs() < 1e-12);
    }

    #[test]
    fn a_turning_sweep_shifts_a_room_and_a_still_one_does_not() {
        // A square room 4 m across seen from its centre, each wall's normal facing inwards.
        let mut pts = Vec::new();
        let mut normals = Vec::new();
        for k in 0..400 {
            let s = -2.0 + 4.0 * (k % 100) as f64 / 100.0;
            let (p, nrm) = match k / 100 {
                0 => ([2.0, s], [-1.0, 0.0]),
                1 => ([s, 2.0], [0.0, -1.0]),
                2 => ([-2.0, s], [1.0, 0.0]),
                _ => ([s, -2.0], [0.0, 1.0]),
            };
            pts.extend(p);
            normals.push(nrm);
        }
        let corr: Vec<i64> = (0..400).collect();
        let eye = [1.0, 0.0, 0.0, 1.0];
        let nrm = |j: usize| Some(normals[j]);
        let sweep = [0.0, 0.0, 0.1];
        let sum = |m: [f64; 9]| m.iter().map(|v| v.abs()).sum::<f64>();
        let (_, m) = distortion_system(&pts, &pts, &corr, &eye, Some(sweep), &[], nrm).unwrap();
        assert!(sum(m) > 1e-6, "{m:?}");
        // Both swept alike from the same pose: the same point shifts alike, nothing moves.
        let alike = TargetSweep {
            motion: sweep,
            origin: [1.0, 0.0, 0.0, 0.0],
        };
        let (_, m) =
            distortion_system(&pts, &pts, &corr, &eye, Some(sweep), &[alike], nrm).unwrap();
        assert!(sum(m) < 1e-20, "{m:?}");
        // The target's sensor elsewhere (0.5 m off the centre): its beams' times, read from
        // there, are no longer the source's.
        let moved = TargetSweep {
            motion: sweep,
            origin: [1.0, 0.0, 0.5, 0.0],
        };
        let (_, m_moved) =
            distortion_system(&pts, &pts, &corr, &eye, Some(sweep), &[moved], nrm).unwrap();
        assert!(sum(m_moved) > 1e-6, "{m_moved:?}");
        // A map of both sweeps, either of which may have laid the matched points: the mean of
        // the two outer products (the alike one's is zero), so half the moved one's.
        let (_, m_both) =
            distortion_system(&pts, &pts, &corr, &eye, Some(sweep), &[alike, moved], nrm).unwrap();
        for (both, one) in m_both.iter().zip(&m_moved) {
            assert!((both - 0.5 * one).abs() < 1e-15, "{m_both:?} {m_moved:?}");
        }
        let still = [0.0; 3];
        let (_, m) = distortion_system(&pts, &pts, &corr, &eye, Some(still), &[], nrm).unwrap();
        assert!(m.iter().all(|v| *v == 0.0));
        assert!(distortion_system(&pts, &pts, &corr, &eye, None, &[], nrm).is_none());
    }
}
