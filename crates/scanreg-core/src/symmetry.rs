//! How much a scene's walls look the same turned by 90°, 180° or 270°: the wrong-basin screen's
//! symmetry signal (`scanreg.basin.orientation_symmetry`). One pass over the points into a
//! histogram of wall directions, then its circular autocorrelation at those shifts.

use crate::error::{Error, Result};
use std::f64::consts::PI;

/// Bins of the wall-direction histogram: 5°, walls of a real room are straight to a few degrees.
const BINS: usize = 72;

/// The circular autocorrelation of the histogram of wall directions at a quarter, a half and
/// three quarters of a turn, over its value at zero (0–1; 0 for fewer than 8 points or an empty
/// histogram). Each normal is turned toward the sensor at the origin (`-n` where `n · p > 0`);
/// its direction is that of its first two components; its weight is the wall length the point
/// stands for: its range in 2D (one beam step of arc), in 3D 1 for a wall (`|n_z| < 0.7`) and
/// 0 otherwise. Non-finite directions or weights are left out. Each bin is smoothed by half of
/// each neighbour's count (one bin of tolerance).
pub fn orientation_symmetry(points: &[f64], normals: &[f64], dim: usize) -> Result<f64> {
    if dim != 2 && dim != 3 {
        return Err(Error::invalid("points", "must be 2D or 3D"));
    }
    if points.len() != normals.len() || !points.len().is_multiple_of(dim) {
        return Err(Error::invalid(
            "normals",
            "must have the points' shape (N, D)",
        ));
    }
    let n = points.len() / dim;
    if n < 8 {
        return Ok(0.0);
    }
    let mut hist = [0.0f64; BINS];
    let scale = BINS as f64 / (2.0 * PI);
    for (p, v) in points.chunks_exact(dim).zip(normals.chunks_exact(dim)) {
        let dot: f64 = p.iter().zip(v).map(|(a, b)| a * b).sum();
        let sign = if dot > 0.0 { -1.0 } else { 1.0 };
        let weight = if dim == 2 {
            p[0].hypot(p[1])
        } else if v[2].abs() < 0.7 {
            1.0
        } else {
            0.0
        };
        let angle = (sign * v[1]).atan2(sign * v[0]);
        if !(angle.is_finite() && weight.is_finite()) {
            continue;
        }
        // angle + π >= 0: truncation is the floor.
        let bin = (((angle + PI) * scale) as usize).min(BINS - 1);
        hist[bin] += weight;
    }
    let mut smooth = [0.0f64; BINS];
    for (i, s) in smooth.iter_mut().enumerate() {
        let prev = hist[(i + BINS - 1) % BINS];
        let next = hist[(i + 1) % BINS];
        *s = hist[i] + 0.5 * (prev + next);
    }
    let shifted = |k: usize| -> f64 { (0..BINS).map(|i| smooth[i] * smooth[(i + k) % BINS]).sum() };
    let zero = shifted(0);
    if zero <= 0.0 {
        return Ok(0.0);
    }
    let quarter = BINS / 4;
    let best = (1..4)
        .map(|k| shifted(k * quarter))
        .fold(f64::NEG_INFINITY, f64::max);
    Ok(best / zero)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square room's walls seen from its centre: every quarter turn is the same.
    #[test]
    fn a_square_room_is_symmetric_and_a_lone_wall_is_not() {
        let mut pts = Vec::new();
        let mut nrm = Vec::new();
        for i in 0..40 {
            let s = -1.0 + 2.0 * i as f64 / 39.0;
            for (p, q) in [
                ([s, 1.0], [0.0, 1.0]),
                ([s, -1.0], [0.0, -1.0]),
                ([1.0, s], [1.0, 0.0]),
                ([-1.0, s], [-1.0, 0.0]),
            ] {
                pts.extend(p);
                nrm.extend(q);
            }
        }
        let room = orientation_symmetry(&pts, &nrm, 2).unwrap();
        assert!(room > 0.99, "{room}");
        // One wall: its direction turned by any quarter is empty.
        let line: Vec<f64> = (0..40)
            .flat_map(|i| [2.0, -1.0 + i as f64 / 20.0])
            .collect();
        let facing: Vec<f64> = (0..40).flat_map(|_| [1.0, 0.0]).collect();
        let wall = orientation_symmetry(&line, &facing, 2).unwrap();
        assert!(wall < 1e-12, "{wall}");
        assert_eq!(
            orientation_symmetry(&pts[..14], &nrm[..14], 2).unwrap(),
            0.0
        );
        assert!(orientation_symmetry(&pts, &nrm[..10], 2).is_err());
    }
}
