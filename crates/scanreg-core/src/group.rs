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
