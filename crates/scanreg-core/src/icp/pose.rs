//! The pose the loop iterates on, as `(R, t)`.

use nalgebra::{SMatrix, SVector};

/// The pose as `(R, t)`.
#[derive(Clone)]
pub(super) struct Pose<const D: usize> {
    pub(super) r: SMatrix<f64, D, D>,
    pub(super) t: SVector<f64, D>,
}

impl<const D: usize> Pose<D> {
    pub(super) fn from_flat(flat: &[f64]) -> Self {
        let m = D + 1;
        Pose {
            r: SMatrix::from_fn(|i, j| flat[i * m + j]),
            t: SVector::from_fn(|i, _| flat[i * m + D]),
        }
    }

    pub(super) fn to_flat(&self) -> Vec<f64> {
        let m = D + 1;
        let mut out = vec![0.0; m * m];
        for i in 0..D {
            for j in 0..D {
                out[i * m + j] = self.r[(i, j)];
            }
            out[i * m + D] = self.t[i];
        }
        out[m * m - 1] = 1.0;
        out
    }

    /// `T · (R_d, t_d)`.
    pub(super) fn compose(&self, rd: &SMatrix<f64, D, D>, td: &SVector<f64, D>) -> Self {
        Pose {
            r: self.r * rd,
            t: self.r * td + self.t,
        }
    }

    pub(super) fn is_finite(&self) -> bool {
        self.r.iter().chain(self.t.iter()).all(|v| v.is_finite())
    }
}
