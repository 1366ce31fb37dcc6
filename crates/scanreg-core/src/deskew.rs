//! Motion compensation ("deskew") of a sweep from per-point timestamps.
//!
//! A spinning sensor measures each point from the pose it has at that point's time. Under a
//! constant body twist `ξ` (translation first, sensor frame, per second) the pose at time `t`
//! relative to the pose at the reference time is `T_ref_t = exp((t - t_ref) ξ)`, so the point
//! in the reference frame is `T_ref_t p`. This is the motion model of the simulator, whose
//! `points_deskewed` are therefore the exact answer.

use crate::error::{Error, Result};
use crate::lie::{se2_exp, se3_exp};
use crate::points::check_points;
use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;

/// Points per parallel task (no reduction here, so the result never depends on threads).
const CHUNK: usize = 4096;

/// Express `points` (row-major `N x dim`, each measured at `timestamps[i]`) in the sensor frame
/// at `reference_time`, for a sensor moving with the constant body `twist`
/// (`[vx, vy, ω]` in 2D, `[vx, vy, vz, ωx, ωy, ωz]` in 3D; units per second).
pub fn deskew(
    points: &[f64],
    dim: usize,
    timestamps: &[f64],
    twist: &[f64],
    reference_time: f64,
) -> Result<Vec<f64>> {
    let n = check_points("points", points, dim)?;
    if timestamps.len() != n {
        return Err(Error::invalid(
            "timestamps",
            format!(
                "expected {n} timestamps (one per point), got {}",
                timestamps.len()
            ),
        ));
    }
    if let Some(i) = timestamps.iter().position(|t| !t.is_finite()) {
        return Err(Error::invalid(
            "timestamps",
            format!("timestamp {i} is not finite"),
        ));
    }
    let dof = if dim == 2 { 3 } else { 6 };
    if twist.len() != dof {
        return Err(Error::invalid(
            "velocity",
            format!("expected {dof} values for {dim}D, got {}", twist.len()),
        ));
    }
    if twist.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid("velocity", "contains NaN or inf"));
    }
    if !reference_time.is_finite() {
        return Err(Error::invalid("reference_time", "must be finite"));
    }
    let mut out = vec![0.0; points.len()];
    // A spinning LiDAR fires a column of rings at one instant: consecutive points often share a
    // timestamp, so each chunk re-uses the last transform while the time repeats (same result,
    // one exponential per column instead of per point).
    out.par_chunks_mut(CHUNK * dim)
        .zip(points.par_chunks(CHUNK * dim))
        .zip(timestamps.par_chunks(CHUNK))
        .for_each(|((dst, src), times)| {
            if dim == 2 {
                let mut cache: Option<(f64, nalgebra::Matrix2<f64>, Vector2<f64>)> = None;
                for (k, &t) in times.iter().enumerate() {
                    let (r, tr) = match cache {
                        Some((ct, r, tr)) if ct == t => (r, tr),
                        _ => {
                            let dt = t - reference_time;
                            let (r, tr) =
                                se2_exp(Vector2::new(twist[0] * dt, twist[1] * dt), twist[2] * dt);
                            cache = Some((t, r, tr));
                            (r, tr)
                        }
                    };
                    let y = r * Vector2::new(src[2 * k], src[2 * k + 1]) + tr;
                    dst[2 * k..2 * k + 2].copy_from_slice(y.as_slice());
                }
            } else {
                let mut cache = None;
                for (k, &t) in times.iter().enumerate() {
                    let m = match cache {
                        Some((ct, m)) if ct == t => m,
                        _ => {
                            let dt = t - reference_time;
                            let v = Vector3::new(twist[0], twist[1], twist[2]) * dt;
                            let w = Vector3::new(twist[3], twist[4], twist[5]) * dt;
                            let m = se3_exp(v, w);
                            cache = Some((t, m));
                            m
                        }
                    };
                    let y = m.apply(Vector3::new(src[3 * k], src[3 * k + 1], src[3 * k + 2]));
                    dst[3 * k..3 * k + 3].copy_from_slice(y.as_slice());
                }
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pure_translation_moves_points_by_velocity_times_dt() {
        let pts = [1.0, 0.0, 0.0, 2.0, 0.0, 0.0];
        let out = deskew(&pts, 3, &[0.0, 0.1], &[10.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0).unwrap();
        // At t = 0.1 the sensor is 1 m further along x than at t_ref = 0.
        assert_eq!(out, vec![1.0, 0.0, 0.0, 3.0, 0.0, 0.0]);
    }

    #[test]
    fn pure_rotation_in_2d() {
        let out = deskew(
            &[1.0, 0.0],
            2,
            &[0.5],
            &[0.0, 0.0, std::f64::consts::PI],
            0.0,
        )
        .unwrap();
        assert!(
            (out[0]).abs() < 1e-12 && (out[1] - 1.0).abs() < 1e-12,
            "{out:?}"
        );
    }

    #[test]
    fn points_at_the_reference_time_are_unchanged() {
        let pts = [0.3, -1.0, 2.0];
        let out = deskew(&pts, 3, &[7.0], &[1.0, 2.0, 3.0, 0.1, 0.2, 0.3], 7.0).unwrap();
        assert_eq!(out, pts.to_vec());
    }

    #[test]
    fn rejects_bad_input() {
        let e = deskew(&[0.0; 6], 3, &[0.0], &[0.0; 6], 0.0).unwrap_err();
        assert!(e.to_string().starts_with("timestamps: expected 2"), "{e}");
        let e = deskew(&[0.0; 3], 3, &[f64::NAN], &[0.0; 6], 0.0).unwrap_err();
        assert!(e.to_string().starts_with("timestamps: timestamp 0"), "{e}");
        let e = deskew(&[0.0; 3], 3, &[0.0], &[0.0; 3], 0.0).unwrap_err();
        assert!(e.to_string().starts_with("velocity: expected 6"), "{e}");
        let e = deskew(&[0.0; 3], 3, &[0.0], &[0.0; 6], f64::INFINITY).unwrap_err();
        assert!(e.to_string().starts_with("reference_time"), "{e}");
    }
}
