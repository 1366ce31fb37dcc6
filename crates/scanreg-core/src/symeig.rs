//! Closed-form eigen-decomposition of real symmetric 2x2 and 3x3 matrices (k-NN PCA).
//!
//! nalgebra's general `SymmetricEigen` (Householder tridiagonalisation + implicit QR sweeps)
//! was about a third of the normals/covariances time; these solvers do a fixed amount of work:
//!
//! * 2x2: one Jacobi rotation (Golub & Van Loan, *Matrix Computations*, §8.5.2, `sym.schur2`),
//!   exact up to rounding for any pair of eigenvalues, equal ones included.
//! * 3x3: the eigenvalues from the trigonometric solution of the characteristic cubic (Smith,
//!   CACM 1961) select the eigenvalue farthest from the middle one; its eigenvector is the
//!   longest cross product of two rows of `A − λI` (rank 2 there, with both non-zero singular
//!   values at least half the spread); the other two come from the 2x2 problem in its
//!   orthogonal complement, solved by one Jacobi rotation. All eigenvalues are then Rayleigh
//!   quotients of an exactly orthonormal basis, so repeated or nearly repeated eigenvalues
//!   (discs, lines, isotropic blobs) cost no accuracy: the worst case is the same
//!   `O(ε‖A‖)` backward error as QR. The same structure as D. Eberly's "A Robust Eigensolver
//!   for 3x3 Symmetric Matrices" (2014), written from the description.
//!
//! Eigenvalues are returned ascending, with unit eigenvectors `vecs[j]` for `vals[j]`.

/// `[[a, b], [b, c]]`: eigenvalues ascending and unit eigenvectors.
#[inline]
pub fn sym2(a: f64, b: f64, c: f64) -> ([f64; 2], [[f64; 2]; 2]) {
    if b == 0.0 {
        return if a <= c {
            ([a, c], [[1.0, 0.0], [0.0, 1.0]])
        } else {
            ([c, a], [[0.0, 1.0], [1.0, 0.0]])
        };
    }
    // J = [[cs, sn], [−sn, cs]] diagonalises: JᵀAJ = diag(a − t b, c + t b), with t = tan θ the
    // smaller root of t² + 2τt − 1 = 0, τ = (c − a) / 2b (|θ| <= π/4).
    let tau = (c - a) / (2.0 * b);
    let t = if tau.abs() > 1e150 {
        0.5 / tau
    } else if tau >= 0.0 {
        1.0 / (tau + (1.0 + tau * tau).sqrt())
    } else {
        -1.0 / (-tau + (1.0 + tau * tau).sqrt())
    };
    let cs = 1.0 / (1.0 + t * t).sqrt();
    let sn = t * cs;
    let (l0, l1) = (a - t * b, c + t * b);
    let (v0, v1) = ([cs, -sn], [sn, cs]);
    if l0 <= l1 {
        ([l0, l1], [v0, v1])
    } else {
        ([l1, l0], [v1, v0])
    }
}

#[inline(always)]
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline(always)]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `A x` for the symmetric matrix given by its upper triangle `(a00, a01, a02, a11, a12, a22)`.
#[inline(always)]
fn mul(m: &[f64; 6], x: [f64; 3]) -> [f64; 3] {
    [
        m[0] * x[0] + m[1] * x[1] + m[2] * x[2],
        m[1] * x[0] + m[3] * x[1] + m[4] * x[2],
        m[2] * x[0] + m[4] * x[1] + m[5] * x[2],
    ]
}

/// A unit eigenvector of the symmetric `b` for its eigenvalue `mu`, assumed simple (the rank of
/// `b − μI` is 2): the longest cross product of two of its rows.
#[inline(always)]
fn kernel_vector(b: &[f64; 6], mu: f64) -> [f64; 3] {
    let r0 = [b[0] - mu, b[1], b[2]];
    let r1 = [b[1], b[3] - mu, b[4]];
    let r2 = [b[2], b[4], b[5] - mu];
    let c01 = cross(r0, r1);
    let c02 = cross(r0, r2);
    let c12 = cross(r1, r2);
    let (n01, n02, n12) = (dot(c01, c01), dot(c02, c02), dot(c12, c12));
    let (c, n) = if n01 >= n02 && n01 >= n12 {
        (c01, n01)
    } else if n02 >= n12 {
        (c02, n02)
    } else {
        (c12, n12)
    };
    if n > 0.0 && n.is_finite() {
        let s = 1.0 / n.sqrt();
        [c[0] * s, c[1] * s, c[2] * s]
    } else {
        [1.0, 0.0, 0.0] // only for exactly repeated eigenvalues, where any unit vector fits
    }
}

/// `2^-⌈log2 x⌉` for a finite `x > 0`, from the bits of a normal `x` (`log2`, `ceil` and
/// `powi` were a tenth of the k-NN covariances' eigen time); a subnormal `x` takes the libm
/// route. The same power wherever `log2` rounds as it should; where it cannot (`x` a few ulps
/// above a power of two, `log2 x` rounded down onto the integer) the two differ by one
/// binade, and an exact power-of-two scaling changes none of [`sym3`]'s roundings.
#[inline(always)]
fn inverse_power_ceiling(x: f64) -> f64 {
    const MANTISSA: u64 = (1 << 52) - 1;
    let bits = x.to_bits();
    let biased = (bits >> 52) as i32; // sign bit clear: x > 0
    if biased == 0 {
        return 2f64.powi(-(x.log2().ceil() as i32));
    }
    // x = 1.m × 2^e: ⌈log2 x⌉ is e for m = 0, else e + 1.
    let e = biased - 1023 + i32::from(bits & MANTISSA != 0);
    // 2^-e for -e in the normal range (|e| <= 1023 here: x is at most f64::MAX < 2^1024).
    let m = -e;
    if m >= -1022 {
        f64::from_bits(((m + 1023) as u64) << 52)
    } else {
        2f64.powi(m)
    }
}

/// Row-major symmetric 3x3 `m` (only the upper triangle is read): eigenvalues ascending and
/// unit eigenvectors forming a right-handed orthonormal basis.
pub fn sym3(m: &[f64; 9]) -> ([f64; 3], [[f64; 3]; 3]) {
    let upper = [m[0], m[1], m[2], m[4], m[5], m[8]];
    const ID: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    if upper.iter().any(|v| !v.is_finite()) {
        return ([f64::NAN; 3], ID);
    }
    let amax = upper.iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
    if amax == 0.0 {
        return ([0.0; 3], ID);
    }
    // Scale by a power of two (exact) so that the largest entry is in [0.5, 1]: no overflow or
    // underflow in the cubic's coefficients.
    let scale = inverse_power_ceiling(amax);
    let a = upper.map(|v| v * scale);
    // Shift by the mean eigenvalue: B = A − qI, p² = tr(B²)/6.
    let q = (a[0] + a[3] + a[5]) / 3.0;
    let b = [a[0] - q, a[1], a[2], a[3] - q, a[4], a[5] - q];
    let off = a[1] * a[1] + a[2] * a[2] + a[4] * a[4];
    let p2 = (b[0] * b[0] + b[3] * b[3] + b[5] * b[5] + 2.0 * off) / 6.0;
    if p2 == 0.0 {
        let v = a[0] / scale;
        return ([v; 3], ID);
    }
    let p = p2.sqrt();
    // det(B / p) / 2 = cos 3φ; the eigenvalues of B are 2p cos(φ + 2πk/3).
    let det = b[0] * (b[3] * b[5] - b[4] * b[4]) - b[1] * (b[1] * b[5] - b[4] * b[2])
        + b[2] * (b[1] * b[4] - b[3] * b[2]);
    let r = (det / (2.0 * p2 * p)).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let hi = 2.0 * p * phi.cos();
    let lo = 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let mid = -hi - lo; // tr(B) = 0
                        // The eigenvector of the eigenvalue farther from the middle one first (well separated).
    let mu = if hi - mid >= mid - lo { hi } else { lo };
    let v = kernel_vector(&b, mu);
    // An orthonormal basis (u, w) of v's complement, and the 2x2 problem there.
    let u = if v[0].abs() > v[1].abs() {
        let s = 1.0 / (v[0] * v[0] + v[2] * v[2]).sqrt();
        [-v[2] * s, 0.0, v[0] * s]
    } else {
        let s = 1.0 / (v[1] * v[1] + v[2] * v[2]).sqrt();
        [0.0, v[2] * s, -v[1] * s]
    };
    let w = cross(v, u);
    let au = mul(&a, u);
    let aw = mul(&a, w);
    let (mvals, mvecs) = sym2(dot(u, au), dot(u, aw), dot(w, aw));
    let y = mvecs.map(|c| {
        [
            c[0] * u[0] + c[1] * w[0],
            c[0] * u[1] + c[1] * w[1],
            c[0] * u[2] + c[1] * w[2],
        ]
    });
    let lv = dot(v, mul(&a, v));
    // Three (value, vector) pairs; mvals is ascending, so one insertion orders them.
    let mut out = [(mvals[0], y[0]), (mvals[1], y[1]), (lv, v)];
    if out[2].0 < out[1].0 {
        out.swap(1, 2);
        if out[1].0 < out[0].0 {
            out.swap(0, 1);
        }
    }
    let inv = 1.0 / scale;
    let vals = [out[0].0 * inv, out[1].0 * inv, out[2].0 * inv];
    let mut vecs = [out[0].1, out[1].1, out[2].1];
    // Right-handed: v2 = v0 × v1 (only a sign, the vectors are orthonormal already).
    if dot(cross(vecs[0], vecs[1]), vecs[2]) < 0.0 {
        vecs[2] = vecs[2].map(|x| -x);
    }
    (vals, vecs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Matrix3, SymmetricEigen};

    /// Small deterministic generator (tests only).
    struct Lcg(u64);
    impl Lcg {
        fn unit(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn normal(&mut self) -> f64 {
            let (u, v) = (self.unit().max(1e-300), self.unit());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
        /// A uniformly random rotation (normalised Gaussian quaternion).
        fn rotation(&mut self) -> Matrix3<f64> {
            let q = nalgebra::Quaternion::new(
                self.normal(),
                self.normal(),
                self.normal(),
                self.normal(),
            );
            nalgebra::UnitQuaternion::from_quaternion(q)
                .to_rotation_matrix()
                .into_inner()
        }
    }

    fn flat(m: &Matrix3<f64>) -> [f64; 9] {
        let mut f = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                f[r * 3 + c] = m[(r, c)];
            }
        }
        f
    }

    /// Checks one matrix: against nalgebra's eigenvalues (Weyl: always well-conditioned),
    /// orthonormality, the residual ‖A v − λ v‖ (backward error), and the eigenvectors whose
    /// eigenvalue is separated from the others by `gap` (angle <= tol ‖A‖ / gap).
    fn check3(m: &Matrix3<f64>, tol: f64) {
        let (vals, vecs) = sym3(&flat(m));
        let norm = m.abs().max().max(f64::MIN_POSITIVE);
        let e = SymmetricEigen::new(*m);
        let mut want: Vec<(f64, usize)> = (0..3).map(|i| (e.eigenvalues[i], i)).collect::<Vec<_>>();
        want.sort_by(|a, b| a.0.total_cmp(&b.0));
        for j in 0..3 {
            assert!(vals[j] <= vals[(j + 1).min(2)], "not ascending: {vals:?}");
            assert!(
                (vals[j] - want[j].0).abs() <= tol * norm,
                "eigenvalue {j}: {} vs nalgebra {} (A = {m})",
                vals[j],
                want[j].0
            );
            let v = nalgebra::Vector3::from(vecs[j]);
            assert!((v.norm() - 1.0).abs() <= tol, "not unit: {v}");
            for &other in &vecs[..j] {
                let vk = nalgebra::Vector3::from(other);
                assert!(v.dot(&vk).abs() <= tol, "not orthogonal");
            }
            let res = (m * v - v * vals[j]).norm();
            assert!(res <= tol * norm, "residual {res} for λ{j} (A = {m})");
            let gap = (0..3)
                .filter(|&k| k != j)
                .map(|k| (want[k].0 - want[j].0).abs())
                .fold(f64::INFINITY, f64::min);
            if gap > 1e-6 * norm {
                let r = e.eigenvectors.column(want[j].1);
                let sin = v.cross(&r).norm();
                assert!(
                    sin <= tol * norm / gap,
                    "eigenvector {j}: sin {sin}, gap {gap}"
                );
            }
        }
        let v = Matrix3::from_columns(&vecs.map(nalgebra::Vector3::from));
        assert!((v.determinant() - 1.0).abs() < 1e-12, "not right-handed");
    }

    #[test]
    fn random_spectra_match_nalgebra() {
        let mut g = Lcg(1);
        for case in 0..20_000 {
            let r = g.rotation();
            // Spectra: generic, planar (one ~0), linear (two ~0), disc (two equal),
            // needle (two equal small), isotropic (three equal), near-equal, exact zero,
            // negative (indefinite), huge and tiny scales.
            let s = 10f64.powf(g.unit() * 40.0 - 20.0);
            let x = g.unit();
            let lam = match case % 10 {
                0 => [g.unit(), g.unit(), g.unit()],
                1 => [1e-9 * x, g.unit() + 0.1, g.unit() + 0.1],
                2 => [1e-12 * x, 1e-12 * g.unit(), 1.0],
                3 => [1e-6 * x, 1.0, 1.0],
                4 => [0.01, 0.01, 1.0],
                5 => [1.0, 1.0, 1.0],
                6 => [1.0, 1.0 + 1e-9 * x, 1.0 + 2e-9 * g.unit()],
                7 => [0.0, 0.0, x],
                8 => [-g.unit(), g.unit(), -2.0 * g.unit()],
                _ => [x, x, g.unit()],
            };
            let d = Matrix3::from_diagonal(&nalgebra::Vector3::from(lam.map(|l| l * s)));
            let mut m = r * d * r.transpose();
            m = (m + m.transpose()) * 0.5;
            check3(&m, 1e-13);
        }
    }

    #[test]
    fn sample_covariances_match_nalgebra() {
        // Covariances of k = 20 points as normals.rs builds them: far from the origin
        // (cancellation), noisy planes, lines and blobs.
        let mut g = Lcg(7);
        for case in 0..5_000 {
            let r = g.rotation();
            let sd = match case % 4 {
                0 => [0.3, 0.2, 1e-3],
                1 => [0.5, 1e-4, 1e-4],
                2 => [0.1, 0.1, 0.1],
                _ => [0.4, 0.3, 0.0],
            };
            let o = nalgebra::Vector3::new(1e3 * g.normal(), 1e3 * g.normal(), 10.0 * g.normal());
            let pts: Vec<nalgebra::Vector3<f64>> = (0..20)
                .map(|_| {
                    o + r * nalgebra::Vector3::new(
                        sd[0] * g.normal(),
                        sd[1] * g.normal(),
                        sd[2] * g.normal(),
                    )
                })
                .collect();
            let mean = pts.iter().sum::<nalgebra::Vector3<f64>>() / 20.0;
            let c = pts
                .iter()
                .map(|p| (p - mean) * (p - mean).transpose())
                .sum::<Matrix3<f64>>()
                / 20.0;
            check3(&c, 1e-13);
        }
    }

    #[test]
    fn exact_special_matrices() {
        let id = Matrix3::identity();
        check3(&id, 1e-15);
        check3(&Matrix3::zeros(), 1e-15);
        check3(
            &Matrix3::from_diagonal(&nalgebra::Vector3::new(3.0, 1.0, 2.0)),
            1e-15,
        );
        check3(
            &Matrix3::from_diagonal(&nalgebra::Vector3::new(0.0, 0.0, 5.0)),
            1e-15,
        );
        check3(
            &Matrix3::new(2.0, 1.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 3.0),
            1e-15,
        );
        check3(
            &Matrix3::new(1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0),
            1e-15,
        );
        check3(&(id * 1e-300), 1e-15);
        check3(&(id * 1e300), 1e-15);
        let (vals, _) = sym3(&[f64::NAN, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
        assert!(vals.iter().all(|v| v.is_nan()));
    }

    #[test]
    fn two_by_two_matches_nalgebra() {
        let mut g = Lcg(3);
        for case in 0..20_000 {
            let s = 10f64.powf(g.unit() * 40.0 - 20.0);
            let (a, b, c) = match case % 5 {
                0 => (g.normal(), g.normal(), g.normal()),
                1 => (1.0, 0.0, 1.0),
                2 => (1.0, 1e-12 * g.normal(), 1.0 + 1e-12 * g.normal()),
                3 => (g.unit(), 1e-200, g.unit()),
                _ => (1e-9 * g.unit(), 1e-5 * g.normal(), 1.0),
            };
            let (a, b, c) = (a * s, b * s, c * s);
            let m = Matrix2::new(a, b, b, c);
            let (vals, vecs) = sym2(a, b, c);
            let norm = m.abs().max();
            let e = SymmetricEigen::new(m);
            let (w0, w1) = if e.eigenvalues[0] <= e.eigenvalues[1] {
                (e.eigenvalues[0], e.eigenvalues[1])
            } else {
                (e.eigenvalues[1], e.eigenvalues[0])
            };
            assert!(vals[0] <= vals[1]);
            assert!((vals[0] - w0).abs() <= 1e-14 * norm && (vals[1] - w1).abs() <= 1e-14 * norm);
            for j in 0..2 {
                let v = nalgebra::Vector2::from(vecs[j]);
                assert!((v.norm() - 1.0).abs() < 1e-14);
                assert!((m * v - v * vals[j]).norm() <= 1e-14 * norm);
            }
            assert!(
                nalgebra::Vector2::from(vecs[0])
                    .dot(&nalgebra::Vector2::from(vecs[1]))
                    .abs()
                    < 1e-14
            );
        }
    }

    #[test]
    fn inverse_power_ceiling_is_the_libm_power() {
        // Powers of two, their neighbours, subnormals and the extremes: 2^-⌈log2 x⌉ exactly
        // (the libm route, where log2 rounds onto the integer only for powers of two here).
        let mut xs = vec![
            f64::MIN_POSITIVE,
            f64::MAX,
            5e-324,
            1e-310,
            0.1,
            0.3,
            1.0,
            3.0,
        ];
        for e in -1074..1024 {
            let x = 2f64.powi(e);
            xs.extend([
                x,
                x * 1.5,
                x * (1.0 + 2f64.powi(-20)),
                x * (2.0 - 2f64.powi(-20)),
            ]);
        }
        let mut g = Lcg(7);
        xs.extend((0..10_000).map(|_| 2f64.powf(80.0 * g.unit() - 40.0)));
        for x in xs.into_iter().filter(|x| *x > 0.0 && x.is_finite()) {
            let libm = 2f64.powi(-(x.log2().ceil() as i32));
            let y = inverse_power_ceiling(x);
            assert_eq!(y.to_bits(), libm.to_bits(), "x = {x:e}");
            // The scaled value is in (0.5, 1] as the solver wants (where the power itself is
            // a finite non-zero double: all but the extreme binades).
            if y.is_finite() && y > 0.0 {
                assert!(x * y <= 1.0 && x * y > 0.5, "x = {x:e}");
            }
        }
    }
}
