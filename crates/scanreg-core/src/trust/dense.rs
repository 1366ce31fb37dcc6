//! The few dense operations the trust arithmetic needs on `dof × dof` matrices (dof = 3 or 6),
//! with numpy's semantics where the Python reference relied on them: symmetric eigenvalues
//! ascending from the lower triangle, LU with partial pivoting that fails only on an exactly
//! zero pivot (numpy's `LinAlgError`).

use nalgebra::{DMatrix, DVector};

pub type Mat = DMatrix<f64>;
pub type Vector = DVector<f64>;

/// `0.5 (m + mᵀ)`.
pub fn sym(m: &Mat) -> Mat {
    (m + m.transpose()) * 0.5
}

/// Eigenvalues ascending and unit eigenvectors (columns) of the symmetric matrix whose lower
/// triangle is `m`'s. Each eigenvector's sign is fixed (its largest component, the first of
/// equals, positive) so that results never depend on the solver's choice.
pub fn eigh(m: &Mat) -> (Vector, Mat) {
    let n = m.nrows();
    let mut lower = m.clone();
    for i in 0..n {
        for j in (i + 1)..n {
            lower[(i, j)] = m[(j, i)];
        }
    }
    let e = lower.symmetric_eigen();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| e.eigenvalues[a].total_cmp(&e.eigenvalues[b]));
    let vals = Vector::from_iterator(n, order.iter().map(|&i| e.eigenvalues[i]));
    let mut vecs = Mat::zeros(n, n);
    for (c, &i) in order.iter().enumerate() {
        let col = e.eigenvectors.column(i);
        let mut lead = 0;
        for r in 1..n {
            if col[r].abs() > col[lead].abs() {
                lead = r;
            }
        }
        let sign = if col[lead] < 0.0 { -1.0 } else { 1.0 };
        for r in 0..n {
            vecs[(r, c)] = sign * col[r];
        }
    }
    (vals, vecs)
}

/// `m⁻¹` by LU with partial pivoting; `None` when a pivot is exactly zero.
pub fn inverse(m: &Mat) -> Option<Mat> {
    if m.nrows() == 0 {
        return Some(m.clone());
    }
    m.clone().lu().try_inverse()
}

/// `a⁻¹ b` by LU with partial pivoting; `None` when a pivot is exactly zero.
pub fn solve(a: &Mat, b: &Vector) -> Option<Vector> {
    if a.nrows() == 0 {
        return Some(b.clone());
    }
    let lu = a.clone().lu();
    if !lu.is_invertible() {
        return None;
    }
    lu.solve(b)
}

pub fn all_finite(m: &Mat) -> bool {
    m.iter().all(|x| x.is_finite())
}

/// `diag(v) m diag(v)`: `m ∘ v vᵀ`.
pub fn scale_both(m: &Mat, v: &Vector) -> Mat {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] * v[i] * v[j])
}

/// `m / (v vᵀ)` elementwise.
pub fn unscale_both(m: &Mat, v: &Vector) -> Mat {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] / (v[i] * v[j]))
}

/// `vecs` with column `j` times `d[j]` (numpy's `vecs * d`).
pub fn scale_columns(vecs: &Mat, d: &Vector) -> Mat {
    Mat::from_fn(vecs.nrows(), vecs.ncols(), |i, j| vecs[(i, j)] * d[j])
}

/// The leading columns `[from, to)` of `m`.
pub fn columns(m: &Mat, from: usize, to: usize) -> Mat {
    m.columns(from, to - from).into_owned()
}

/// `cov` with round-off negative eigenvalues set to zero (a noise-free fit leaves variances
/// of ±1e-54: a negative one would make its standard deviation NaN). Unchanged when it has
/// none or is not finite.
pub fn psd(cov: &Mat) -> Mat {
    if !all_finite(cov) {
        return cov.clone();
    }
    let (vals, vecs) = eigh(&sym(cov));
    if vals[0] >= 0.0 {
        return cov.clone();
    }
    let clipped = vals.map(|v| v.max(0.0));
    scale_columns(&vecs, &clipped) * vecs.transpose()
}

/// Row-major flat copy.
pub fn flat(m: &Mat) -> Vec<f64> {
    let mut out = Vec::with_capacity(m.nrows() * m.ncols());
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            out.push(m[(i, j)]);
        }
    }
    out
}

pub fn from_rows(n: usize, values: &[f64]) -> Mat {
    Mat::from_row_slice(n, n, values)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigh_is_ascending_with_fixed_signs() {
        let m = from_rows(3, &[2.0, 1.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 5.0]);
        let (vals, vecs) = eigh(&m);
        assert!((vals[0] - 1.0).abs() < 1e-14 && (vals[2] - 5.0).abs() < 1e-14);
        for c in 0..3 {
            let col = vecs.column(c);
            let lead = col
                .iter()
                .cloned()
                .fold(0.0_f64, |a, x| if x.abs() > a.abs() { x } else { a });
            assert!(lead > 0.0);
            let back = &m * col - col * vals[c];
            assert!(back.norm() < 1e-13);
        }
    }

    #[test]
    fn singular_inverse_is_none_and_psd_clips() {
        let z = Mat::zeros(3, 3);
        assert!(inverse(&z).is_none());
        let m = from_rows(2, &[1.0, 0.0, 0.0, -1e-20]);
        let p = psd(&m);
        assert_eq!(p[(1, 1)], 0.0);
        assert_eq!(p[(0, 0)], 1.0);
    }
}
