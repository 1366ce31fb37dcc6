//! Small Lie-group helpers shared by the core: rigid transforms and exponential maps.
//!
//! Tangent vectors are translation first (`[ρ, φ]`, `[ρx, ρy, θ]`), as everywhere in scanreg.

use crate::error::{Error, Result};
use nalgebra::{Matrix2, Matrix3, Rotation3, Vector2, Vector3};

/// A rigid transform `p ↦ R p + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    pub r: Matrix3<f64>,
    pub t: Vector3<f64>,
}

impl Rigid {
    pub fn identity() -> Self {
        Rigid {
            r: Matrix3::identity(),
            t: Vector3::zeros(),
        }
    }

    pub fn compose(&self, other: &Rigid) -> Rigid {
        Rigid {
            r: self.r * other.r,
            t: self.r * other.t + self.t,
        }
    }

    pub fn inverse(&self) -> Rigid {
        let rt = self.r.transpose();
        Rigid {
            r: rt,
            t: -(rt * self.t),
        }
    }

    pub fn apply(&self, p: Vector3<f64>) -> Vector3<f64> {
        self.r * p + self.t
    }

    /// From a row-major 4x4 homogeneous matrix (validated: finite, last row, orthonormal).
    pub fn from_matrix(arg: &'static str, m: &[f64]) -> Result<Rigid> {
        if m.len() != 16 {
            return Err(Error::invalid(
                arg,
                format!("expected 16 values (4x4), got {}", m.len()),
            ));
        }
        if m.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(arg, "pose has a non-finite entry"));
        }
        let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
        let err = (r.transpose() * r - Matrix3::identity()).abs().max();
        if err > 1e-6 || r.determinant() < 0.0 {
            return Err(Error::invalid(
                arg,
                "rotation block is not a rotation matrix",
            ));
        }
        if (m[12].abs() + m[13].abs() + m[14].abs() + (m[15] - 1.0).abs()) > 1e-9 {
            return Err(Error::invalid(arg, "last row must be [0, 0, 0, 1]"));
        }
        Ok(Rigid {
            r,
            t: Vector3::new(m[3], m[7], m[11]),
        })
    }
}

pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `exp` of an se(3) tangent `[ρ, φ]`: `R = exp(φ^)`, `t = J_l(φ) ρ`.
pub fn se3_exp(rho: Vector3<f64>, phi: Vector3<f64>) -> Rigid {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let k = hat(&phi);
    let k2 = k * k;
    // Series below 1e-4 rad: the next terms are O(θ⁴) < 1e-16.
    let (a, b, c) = if theta < 1e-4 {
        (
            1.0 - theta2 / 6.0,
            0.5 - theta2 / 24.0,
            1.0 / 6.0 - theta2 / 120.0,
        )
    } else {
        let (s, co) = theta.sin_cos();
        (
            s / theta,
            (1.0 - co) / theta2,
            (theta - s) / (theta2 * theta),
        )
    };
    let eye = Matrix3::identity();
    Rigid {
        r: eye + k * a + k2 * b,
        t: (eye + k * b + k2 * c) * rho,
    }
}

/// The rotation nearest (in the Frobenius norm) to the 2×2 matrix `[[a, b], [c, d]]`, as
/// `(cos θ, sin θ)`: the SVD projection onto SO(2) in closed form.
pub fn nearest_rotation_2d(a: f64, b: f64, c: f64, d: f64) -> (f64, f64) {
    let (s, co) = (c - b).atan2(a + d).sin_cos();
    (co, s)
}

/// `exp` of an se(2) tangent `[ρx, ρy, θ]`: `R = R(θ)`, `t = V(θ) ρ`.
pub fn se2_exp(rho: Vector2<f64>, theta: f64) -> (Matrix2<f64>, Vector2<f64>) {
    let (s, c) = theta.sin_cos();
    // V = [[a, -b], [b, a]] with a = sin θ / θ, b = (1 - cos θ) / θ = 2 sin²(θ/2) / θ.
    let (a, b) = if theta.abs() < 1e-4 {
        (
            1.0 - theta * theta / 6.0,
            0.5 * theta - theta.powi(3) / 24.0,
        )
    } else {
        (s / theta, 2.0 * (0.5 * theta).sin().powi(2) / theta)
    };
    (
        Matrix2::new(c, -s, s, c),
        Vector2::new(a * rho.x - b * rho.y, b * rho.x + a * rho.y),
    )
}

/// `log` of a 2D rigid transform `(R, t)` (`R` row-major): `[ρx, ρy, θ]` with `ρ = V(θ)⁻¹ t`,
/// the inverse of [`se2_exp`].
pub fn se2_log(r: [f64; 4], t: [f64; 2]) -> [f64; 3] {
    let theta = r[2].atan2(r[0]);
    let (a, b) = if theta.abs() < 1e-9 {
        (1.0, 0.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta)
    };
    let d = a * a + b * b;
    [(a * t[0] + b * t[1]) / d, (a * t[1] - b * t[0]) / d, theta]
}

/// `log` of a 3D rigid transform: `[ρ, φ]`, `ρ = J_l(φ)⁻¹ t`, the inverse of [`se3_exp`].
pub fn se3_log(r: Matrix3<f64>, t: Vector3<f64>) -> [f64; 6] {
    let phi = Rotation3::from_matrix_unchecked(r).scaled_axis();
    let theta = phi.norm();
    let k = hat(&phi);
    let d = if theta < 1e-4 {
        1.0 / 12.0 + theta.powi(2) / 720.0 + theta.powi(4) / 30240.0
    } else {
        (1.0 - theta * theta.sin() / (2.0 * (1.0 - theta.cos()))) / (theta * theta)
    };
    let jinv = Matrix3::identity() - 0.5 * k + d * (k * k);
    let rho = jinv * t;
    [rho[0], rho[1], rho[2], phi[0], phi[1], phi[2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `log` inverts `exp` in 2D and 3D, small angles (the series branches) included.
    #[test]
    fn logs_invert_the_exponentials() {
        for &th in &[0.0, 1e-6, 0.3, -2.5, 3.1] {
            let (r, t) = se2_exp(Vector2::new(0.7, -1.2), th);
            let e = se2_log([r[(0, 0)], r[(0, 1)], r[(1, 0)], r[(1, 1)]], [t.x, t.y]);
            // (1 − cos θ)/θ loses digits near θ = 1e-6: 5e-11 there, 1e-15 elsewhere.
            for (v, w) in e.iter().zip([0.7, -1.2, th]) {
                assert!((v - w).abs() < 1e-10, "{th}: {e:?}");
            }
        }
        for &scale in &[0.0, 1e-6, 0.4, 2.0] {
            let (rho, phi) = (
                Vector3::new(0.5, -0.2, 1.1),
                Vector3::new(0.3, -0.6, 0.2) * scale,
            );
            let g = se3_exp(rho, phi);
            let e = se3_log(g.r, g.t);
            for (v, w) in e.iter().zip(rho.iter().chain(phi.iter())) {
                assert!((v - w).abs() < 1e-9, "{scale}: {e:?}");
            }
        }
    }

    /// The closed form equals the SVD projection `U Vᵀ` (nalgebra) on perturbed rotations, and
    /// returns an exact rotation's own angle.
    #[test]
    fn nearest_rotation_2d_is_the_svd_projection() {
        let angles: [f64; 6] = [-3.1, -1.0, 0.0, 0.3, std::f64::consts::FRAC_PI_2, 2.9];
        for (i, &th) in angles.iter().enumerate() {
            let (s, c) = th.sin_cos();
            let (co, si) = nearest_rotation_2d(c, -s, s, c);
            assert!((co - c).abs() < 1e-15 && (si - s).abs() < 1e-15, "{th}");
            // A perturbed (non-orthonormal) matrix: compare with the SVD's U Vᵀ.
            let e = 1e-3 * (i as f64 + 1.0);
            let m = Matrix2::new(c + e, -s + 0.5 * e, s - 0.3 * e, c + 0.7 * e);
            let svd = m.svd(true, true);
            let r = svd.u.unwrap() * svd.v_t.unwrap();
            let (co, si) = nearest_rotation_2d(m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)]);
            assert!(r.determinant() > 0.0);
            for (got, want) in [
                (co, r[(0, 0)]),
                (-si, r[(0, 1)]),
                (si, r[(1, 0)]),
                (co, r[(1, 1)]),
            ] {
                assert!((got - want).abs() < 1e-12, "{th}: {got} vs {want}");
            }
        }
    }
}
