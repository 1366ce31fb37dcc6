//! Robust M-estimator kernels, applied to a residual norm `r >= 0` with scale `c > 0`.
//!
//! Each kernel gives the loss `rho(r)` (normalised so that `rho(r) ≈ r²/2` for `r << c`)
//! and the IRLS weight `w(r) = rho'(r) / r`, used to re-weight `JᵀJ` and `Jᵀr`
//! (Zhang 1997, "Parameter estimation techniques: a tutorial with application to conic
//! fitting", table 1; Barron 2019 for the Geman–McClure/Welsch normalisation).

use crate::error::{Error, Result};

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kernel {
    /// Plain least squares.
    None,
    Huber(f64),
    Cauchy(f64),
    Tukey(f64),
    GemanMcClure(f64),
    Welsch(f64),
}

impl Kernel {
    /// Build a kernel from its name (as used by the Python API) and scale.
    pub fn from_name(name: &str, scale: f64) -> Result<Self> {
        if name != "none" && (!scale.is_finite() || scale <= 0.0) {
            return Err(Error::invalid(
                "kernel_scale",
                format!("must be finite and > 0, got {scale}"),
            ));
        }
        Ok(match name {
            "none" => Kernel::None,
            "huber" => Kernel::Huber(scale),
            "cauchy" => Kernel::Cauchy(scale),
            "tukey" => Kernel::Tukey(scale),
            "geman_mcclure" => Kernel::GemanMcClure(scale),
            "welsch" => Kernel::Welsch(scale),
            other => {
                return Err(Error::invalid(
                    "kernel",
                    format!(
                        "unknown kernel {other:?}; expected one of none, huber, cauchy, tukey, geman_mcclure, welsch"
                    ),
                ))
            }
        })
    }

    /// Loss `rho(r)`.
    pub fn rho(&self, r: f64) -> f64 {
        let r2 = r * r;
        match *self {
            Kernel::None => 0.5 * r2,
            Kernel::Huber(c) => {
                if r <= c {
                    0.5 * r2
                } else {
                    c * (r - 0.5 * c)
                }
            }
            Kernel::Cauchy(c) => 0.5 * c * c * (1.0 + r2 / (c * c)).ln(),
            Kernel::Tukey(c) => {
                let c2 = c * c;
                if r <= c {
                    let u = 1.0 - r2 / c2;
                    c2 / 6.0 * (1.0 - u * u * u)
                } else {
                    c2 / 6.0
                }
            }
            Kernel::GemanMcClure(c) => {
                let c2 = c * c;
                0.5 * c2 * r2 / (c2 + r2)
            }
            Kernel::Welsch(c) => {
                let c2 = c * c;
                0.5 * c2 * (1.0 - (-r2 / c2).exp())
            }
        }
    }

    /// IRLS weight `rho'(r) / r`.
    pub fn weight(&self, r: f64) -> f64 {
        let r2 = r * r;
        match *self {
            Kernel::None => 1.0,
            Kernel::Huber(c) => {
                if r <= c {
                    1.0
                } else {
                    c / r
                }
            }
            Kernel::Cauchy(c) => 1.0 / (1.0 + r2 / (c * c)),
            Kernel::Tukey(c) => {
                if r <= c {
                    let u = 1.0 - r2 / (c * c);
                    u * u
                } else {
                    0.0
                }
            }
            Kernel::GemanMcClure(c) => {
                let c2 = c * c;
                let d = c2 + r2;
                c2 * c2 / (d * d)
            }
            Kernel::Welsch(c) => (-r2 / (c * c)).exp(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [&str; 6] = [
        "none",
        "huber",
        "cauchy",
        "tukey",
        "geman_mcclure",
        "welsch",
    ];

    #[test]
    fn weight_is_derivative_of_rho_over_r() {
        for name in ALL {
            let k = Kernel::from_name(name, 0.7).unwrap();
            for &r in &[0.05, 0.3, 0.69, 0.71, 1.5, 4.0] {
                let h = 1e-6;
                let drho = (k.rho(r + h) - k.rho(r - h)) / (2.0 * h);
                assert!(
                    (drho / r - k.weight(r)).abs() < 1e-6,
                    "{name} at r={r}: {} vs {}",
                    drho / r,
                    k.weight(r)
                );
            }
        }
    }

    #[test]
    fn quadratic_near_zero() {
        for name in ALL {
            let k = Kernel::from_name(name, 2.0).unwrap();
            let r = 1e-3;
            assert!((k.rho(r) / (0.5 * r * r) - 1.0).abs() < 1e-5, "{name}");
            assert!((k.weight(r) - 1.0).abs() < 1e-5, "{name}");
        }
    }

    #[test]
    fn rejects_bad_names_and_scales() {
        assert!(Kernel::from_name("hubr", 1.0).is_err());
        assert!(Kernel::from_name("huber", 0.0).is_err());
        assert!(Kernel::from_name("huber", f64::NAN).is_err());
        assert!(Kernel::from_name("none", f64::NAN).is_ok());
    }
}
