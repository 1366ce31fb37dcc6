//! scanreg-core: the per-point loops of scanreg, in plain Rust.
//!
//! Conventions shared by every module (stated once, here):
//! * Points are flat, row-major `f64` slices of `N * D` values, `D` = 2 or 3.
//! * A pose is `T_target_source`: `p_T = R p_S + t`, passed as a row-major homogeneous
//!   matrix (`(D+1) * (D+1)` values).
//! * Tangent vectors are ordered `[translation, rotation]` (`[ρx, ρy, θ]` in 2D,
//!   `[ρx, ρy, ρz, φx, φy, φz]` in 3D) and perturb a pose on the **right**:
//!   `T ⊕ δ = T · exp(δ)`. Jacobians, Hessians and gradients are with respect to that δ.
//! * Parallel sums split the input into fixed chunks and add the partial sums in chunk
//!   order, so results do not depend on the number of threads.
//!
//! Nothing here panics on user input: every entry point validates and returns [`Error`].

pub mod basin;
pub mod censi;
pub mod correlative;
pub mod denoise;
pub mod deskew;
pub mod downsample;
pub mod error;
pub mod factor;
pub mod global;
pub mod group;
pub mod icp;
pub mod kernel;
pub mod keyframe_map;
pub mod knn;
pub mod lie;
pub mod lzf;
pub mod map_check;
pub mod ndt2d;
pub mod ndt3d;
pub mod normal_agreement;
pub mod normal_noise;
pub mod normals;
pub mod outliers;
pub mod overlap;
pub mod paired;
pub mod place;
pub mod points;
pub mod reduce;
pub mod simulate;
pub mod sweep;
pub mod sweep_residual;
pub mod symeig;
pub mod symmetry;
pub mod threads;
pub mod trust;
pub mod voxel_map;

pub use error::{Error, Result};
pub use kernel::Kernel;
