//! What differs between SE(2) and SE(3) for a solver: the point Jacobian of the right
//! perturbation, the exponential, the normal-equation solve and the point-to-point moments.
//! Shared by the ICP loop (`icp`) and the paired solve (`paired`), so both linearise a point
//! the same way.

use crate::lie;
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};

/// What differs between SE(2) and SE(3).
pub trait Group<const D: usize, const N: usize> {
    /// `A(p) = ∂(exp(δ) p)/∂δ` at `δ = 0`.
    fn point_jacobian(p: &SVector<f64, D>) -> SMatrix<f64, D, N>;
    /// `exp(δ)` as `(R, t)`.
    fn exp(delta: &SVector<f64, N>) -> (SMatrix<f64, D, D>, SVector<f64, D>);
    fn inverse(m: &SMatrix<f64, D, D>) -> Option<SMatrix<f64, D, D>>;
    fn solve(h: &SMatrix<f64, N, N>, rhs: &SVector<f64, N>) -> Option<SVector<f64, N>>;
    /// The rotation block of `A(p)ᵀA(p)` (`[p]×ᵀ[p]×` in 3D; `|p|²` at `[0, 0]` in 2D), each
    /// entry as a sum of products (no `|p|² − x²` cancellation far from the origin).
    fn rotation_moment(p: &SVector<f64, D>) -> SMatrix<f64, D, D>;
    /// `Σ kᵢ A(pᵢ)ᵀA(pᵢ)` from `Σ kᵢ`, `Σ kᵢ pᵢ` and `Σ kᵢ rotation_moment(pᵢ)`: the
    /// point-to-point Hessian without a `N × N` product per point.
    fn moment_hessian(k: f64, kp: &SVector<f64, D>, rot: &SMatrix<f64, D, D>)
        -> SMatrix<f64, N, N>;

    /// `A(p)ᵀ M`. Each entry is the sum nalgebra's product forms, in its order, with the terms
    /// of `A`'s structural zeros and the products by its ones left out: `x·0` is a zero and
    /// `x·1` is `x` exactly, so a nonzero entry comes out to the bit (an exact zero may change
    /// its sign; inputs are finite). GICP's per-correspondence products in 3D, which were
    /// most of a factor's arithmetic.
    #[inline(always)]
    fn jacobian_t_mul<const C: usize>(
        p: &SVector<f64, D>,
        m: &SMatrix<f64, D, C>,
    ) -> SMatrix<f64, N, C> {
        Self::point_jacobian(p).transpose() * m
    }

    /// `M A(p)`, as [`Self::jacobian_t_mul`].
    #[inline(always)]
    fn mul_jacobian<const R: usize>(
        m: &SMatrix<f64, R, D>,
        p: &SVector<f64, D>,
    ) -> SMatrix<f64, R, N> {
        m * Self::point_jacobian(p)
    }
}

pub struct Planar;
pub struct Spatial;

impl Group<2, 3> for Planar {
    #[inline]
    fn point_jacobian(p: &Vector2<f64>) -> SMatrix<f64, 2, 3> {
        SMatrix::<f64, 2, 3>::new(1.0, 0.0, -p.y, 0.0, 1.0, p.x)
    }

    fn exp(d: &SVector<f64, 3>) -> (Matrix2<f64>, Vector2<f64>) {
        lie::se2_exp(Vector2::new(d[0], d[1]), d[2])
    }

    fn inverse(m: &Matrix2<f64>) -> Option<Matrix2<f64>> {
        m.try_inverse()
    }

    fn solve(h: &SMatrix<f64, 3, 3>, rhs: &SVector<f64, 3>) -> Option<SVector<f64, 3>> {
        h.cholesky().map(|c| c.solve(rhs))
    }

    #[inline]
    fn rotation_moment(p: &Vector2<f64>) -> Matrix2<f64> {
        Matrix2::new(p.x * p.x + p.y * p.y, 0.0, 0.0, 0.0)
    }

    fn moment_hessian(k: f64, kp: &Vector2<f64>, rot: &Matrix2<f64>) -> SMatrix<f64, 3, 3> {
        SMatrix::<f64, 3, 3>::new(k, 0.0, -kp.y, 0.0, k, kp.x, -kp.y, kp.x, rot[(0, 0)])
    }
}

impl Group<3, 6> for Spatial {
    #[inline]
    fn point_jacobian(p: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
        #[rustfmt::skip]
        let a = SMatrix::<f64, 3, 6>::new(
            1.0, 0.0, 0.0, 0.0, p.z, -p.y,
            0.0, 1.0, 0.0, -p.z, 0.0, p.x,
            0.0, 0.0, 1.0, p.y, -p.x, 0.0,
        );
        a
    }

    fn exp(d: &SVector<f64, 6>) -> (Matrix3<f64>, Vector3<f64>) {
        let t = lie::se3_exp(
            Vector3::new(d[0], d[1], d[2]),
            Vector3::new(d[3], d[4], d[5]),
        );
        (t.r, t.t)
    }

    fn inverse(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
        m.try_inverse()
    }

    fn solve(h: &SMatrix<f64, 6, 6>, rhs: &SVector<f64, 6>) -> Option<SVector<f64, 6>> {
        h.cholesky().map(|c| c.solve(rhs))
    }

    #[inline]
    fn rotation_moment(p: &Vector3<f64>) -> Matrix3<f64> {
        let (x, y, z) = (p.x, p.y, p.z);
        #[rustfmt::skip]
        let b = Matrix3::new(
            y * y + z * z, -x * y, -x * z,
            -x * y, x * x + z * z, -y * z,
            -x * z, -y * z, x * x + y * y,
        );
        b
    }

    #[inline(always)]
    fn jacobian_t_mul<const C: usize>(
        p: &Vector3<f64>,
        m: &SMatrix<f64, 3, C>,
    ) -> SMatrix<f64, 6, C> {
        // Aᵀ = [I; [p]×]: row k < 3 is m's row k; the rotation rows pair the two nonzero
        // entries of A's column in nalgebra's order (row 0, 1, 2 of m).
        let (x, y, z) = (p.x, p.y, p.z);
        SMatrix::<f64, 6, C>::from_fn(|r, c| match r {
            0..=2 => m[(r, c)],
            3 => -z * m[(1, c)] + y * m[(2, c)],
            4 => z * m[(0, c)] + -x * m[(2, c)],
            _ => -y * m[(0, c)] + x * m[(1, c)],
        })
    }

    #[inline(always)]
    fn mul_jacobian<const R: usize>(
        m: &SMatrix<f64, R, 3>,
        p: &Vector3<f64>,
    ) -> SMatrix<f64, R, 6> {
        // A = [I, −[p]×], columns as in `jacobian_t_mul`.
        let (x, y, z) = (p.x, p.y, p.z);
        SMatrix::<f64, R, 6>::from_fn(|r, c| match c {
            0..=2 => m[(r, c)],
            3 => m[(r, 1)] * -z + m[(r, 2)] * y,
            4 => m[(r, 0)] * z + m[(r, 2)] * -x,
            _ => m[(r, 0)] * -y + m[(r, 1)] * x,
        })
    }

    fn moment_hessian(k: f64, kp: &Vector3<f64>, rot: &Matrix3<f64>) -> SMatrix<f64, 6, 6> {
        // A = [I, −[p]×]: AᵀA = [[I, −[p]×], [[p]×, [p]×ᵀ[p]×]].
        let mut h = SMatrix::<f64, 6, 6>::zeros();
        let c = lie::hat(kp);
        h.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
        h.fixed_view_mut::<3, 3>(0, 0).scale_mut(k);
        h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-c));
        h.fixed_view_mut::<3, 3>(3, 0).copy_from(&c);
        h.fixed_view_mut::<3, 3>(3, 3).copy_from(rot);
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic stream of values in [-50, 50) (xorshift).
    fn values(seed: u64, count: usize) -> Vec<f64> {
        let mut s = seed;
        (0..count)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64 * 100.0 - 50.0
            })
            .collect()
    }

    /// The structured products equal nalgebra's full products with `A(p)` to the bit (for
    /// nonzero entries, which random data gives everywhere).
    #[test]
    fn structured_jacobian_products_equal_the_full_products() {
        for seed in 1..400u64 {
            let v = values(seed, 3 + 9 + 18);
            let p = Vector3::new(v[0], v[1], v[2]);
            let m = Matrix3::from_row_slice(&v[3..12]);
            let m63 = SMatrix::<f64, 6, 3>::from_row_slice(&v[12..30]);
            let a = Spatial::point_jacobian(&p);
            let full = a.transpose() * m;
            let fast = Spatial::jacobian_t_mul(&p, &m);
            assert_eq!(
                full.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                fast.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
            let full = m * a;
            let fast = Spatial::mul_jacobian(&m, &p);
            assert_eq!(
                full.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                fast.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
            let full = m63 * a;
            let fast = Spatial::mul_jacobian(&m63, &p);
            assert_eq!(
                full.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                fast.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
            let full = m63 * m;
            let fast = crate::factor::mul(&m63, &m);
            assert_eq!(
                full.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                fast.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
            let vec = Vector3::new(v[3], v[4], v[5]);
            let full = a.transpose() * vec;
            let fast = Spatial::jacobian_t_mul(&p, &vec);
            assert_eq!(
                full.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                fast.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
        }
    }
}
