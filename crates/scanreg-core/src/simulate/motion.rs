//! Sensor motion during a scan: a piecewise constant-twist trajectory.
//!
//! Segment `k` starts at time `times[k]` with pose `T_k` (T_world_sensor) and body twist
//! `ξ_k = [v, ω]` (translation first, sensor frame); inside it
//! `T(t) = T_k · exp((t − times[k]) ξ_k)`. Times before the first knot or after the last
//! extrapolate the first or last segment. This is exactly the model of
//! `scanreg.simulate.Trajectory`, so the per-beam poses here are the ground truth there.

use crate::error::{Error, Result};
pub use crate::lie::{se3_exp, Rigid};
use nalgebra::Vector3;

/// A validated piecewise constant-twist trajectory.
pub struct Motion {
    times: Vec<f64>,
    starts: Vec<Rigid>,
    twists: Vec<[f64; 6]>,
}

impl Motion {
    /// `times`: `K + 1` strictly increasing knots; `poses`: `K` row-major 4x4 matrices;
    /// `twists`: `K` body twists `[vx, vy, vz, ωx, ωy, ωz]`.
    pub fn new(times: &[f64], poses: &[f64], twists: &[f64]) -> Result<Motion> {
        if times.len() < 2 {
            return Err(Error::invalid(
                "knot_times",
                "need at least 2 knots (one segment)",
            ));
        }
        if times.iter().any(|t| !t.is_finite()) {
            return Err(Error::invalid("knot_times", "contains NaN or inf"));
        }
        if times.windows(2).any(|w| w[1] <= w[0]) {
            return Err(Error::invalid("knot_times", "must be strictly increasing"));
        }
        let k = times.len() - 1;
        if poses.len() != 16 * k {
            return Err(Error::invalid(
                "knot_poses",
                format!(
                    "expected {k} 4x4 poses ({} values), got {}",
                    16 * k,
                    poses.len()
                ),
            ));
        }
        if twists.len() != 6 * k {
            return Err(Error::invalid(
                "twists",
                format!(
                    "expected {k} twists ({} values), got {}",
                    6 * k,
                    twists.len()
                ),
            ));
        }
        if twists.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid("twists", "contains NaN or inf"));
        }
        let starts = poses
            .chunks_exact(16)
            .map(|m| Rigid::from_matrix("knot_poses", m))
            .collect::<Result<Vec<_>>>()?;
        let twists = twists
            .chunks_exact(6)
            .map(|c| [c[0], c[1], c[2], c[3], c[4], c[5]])
            .collect();
        Ok(Motion {
            times: times.to_vec(),
            starts,
            twists,
        })
    }

    /// A motionless sensor at `pose`.
    pub fn fixed(pose: Rigid) -> Motion {
        Motion {
            times: vec![0.0, 1.0],
            starts: vec![pose],
            twists: vec![[0.0; 6]],
        }
    }

    /// `T_world_sensor(t)`.
    pub fn pose_at(&self, t: f64) -> Rigid {
        let k = self.times[1..self.times.len() - 1].partition_point(|&knot| knot <= t);
        let dt = t - self.times[k];
        let x = &self.twists[k];
        let step = se3_exp(
            Vector3::new(x[0], x[1], x[2]) * dt,
            Vector3::new(x[3], x[4], x[5]) * dt,
        );
        self.starts[k].compose(&step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_of_planar_arc_matches_circle() {
        // v = 2 m/s forward, ω = 0.5 rad/s for 1 s: arc of radius 4.
        let p = se3_exp(Vector3::new(2.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.5));
        let r = 4.0;
        assert!((p.t.x - r * 0.5f64.sin()).abs() < 1e-12);
        assert!((p.t.y - r * (1.0 - 0.5f64.cos())).abs() < 1e-12);
        assert!(p.t.z.abs() < 1e-15);
        // Tiny angle goes through the series branch and agrees with the closed form.
        let a = se3_exp(Vector3::new(1.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 1e-5));
        assert!((a.t.y - 0.5e-5).abs() < 1e-12);
    }

    #[test]
    fn pose_is_continuous_across_knots() {
        let first = Rigid::identity();
        let twist = [1.0, 0.0, 0.0, 0.0, 0.0, 0.2];
        let end = first.compose(&se3_exp(
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 0.0, 0.2),
        ));
        let mut poses = Vec::new();
        for p in [first, end] {
            for row in 0..3 {
                poses.extend_from_slice(&[p.r[(row, 0)], p.r[(row, 1)], p.r[(row, 2)], p.t[row]]);
            }
            poses.extend_from_slice(&[0.0, 0.0, 0.0, 1.0]);
        }
        let m = Motion::new(&[0.0, 1.0, 2.0], &poses, &[twist, twist].concat()).unwrap();
        let a = m.pose_at(1.0 - 1e-12);
        let b = m.pose_at(1.0);
        assert!((a.t - b.t).norm() < 1e-9);
        // Extrapolation past the last knot continues the last segment.
        let c = m.pose_at(3.0);
        let full = se3_exp(Vector3::new(3.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.6));
        assert!((c.t - full.t).norm() < 1e-9);
    }

    #[test]
    fn rejects_bad_knots() {
        let eye = [
            1.0, 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
        ];
        assert!(Motion::new(&[0.0], &[], &[]).is_err());
        let e = Motion::new(&[1.0, 0.0], &eye, &[0.0; 6])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("knot_times"), "{e}");
        let e = Motion::new(&[0.0, 1.0], &eye, &[f64::NAN; 6])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("twists"), "{e}");
        let mut bad = eye;
        bad[0] = 2.0;
        let e = Motion::new(&[0.0, 1.0], &bad, &[0.0; 6])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("knot_poses"), "{e}");
    }
}
