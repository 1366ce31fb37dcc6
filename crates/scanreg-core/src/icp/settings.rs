//! What a registration is asked to do: the cost, the optimizer, the gate and the stopping
//! rules, and why it stopped.

use crate::error::{Error, Result};
use crate::kernel::Kernel;
use crate::knn::check_max_distance;

/// Which factor each correspondence contributes (see [`crate::factor`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    PointToPoint,
    /// Point-to-plane in 3D, point-to-line in 2D (needs target normals).
    PointToPlane,
    /// Plane-to-plane (3D) / line-to-line (2D) GICP (needs source and target covariances).
    Gicp,
}

impl Method {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "point_to_point" => Ok(Method::PointToPoint),
            "point_to_plane" | "point_to_line" => Ok(Method::PointToPlane),
            "gicp" => Ok(Method::Gicp),
            other => Err(Error::invalid(
                "method",
                format!(
                    "unknown {other:?}; expected point_to_point, point_to_plane, point_to_line or gicp"
                ),
            )),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Optimizer {
    /// Take the Gauss–Newton step at every iteration (classic ICP).
    GaussNewton,
    /// Marquardt damping `H + λ diag(H)`; a step is accepted only if it lowers the cost over the
    /// iteration's correspondences, otherwise `λ ← 10 λ` and retry.
    LevenbergMarquardt,
}

impl Optimizer {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "gauss_newton" => Ok(Optimizer::GaussNewton),
            "levenberg_marquardt" => Ok(Optimizer::LevenbergMarquardt),
            other => Err(Error::invalid(
                "optimizer",
                format!("unknown {other:?}; expected gauss_newton or levenberg_marquardt"),
            )),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    pub method: Method,
    pub kernel: Kernel,
    /// The gate: a source point has a correspondence only if its nearest target point is at
    /// most this far (same units as the points).
    pub max_correspondence_distance: f64,
    pub max_iterations: usize,
    /// Converged when the last step moved the source's centroid less than this (units)...
    pub translation_tolerance: f64,
    /// ... and rotated less than this (radians).
    pub rotation_tolerance: f64,
    pub optimizer: Optimizer,
    /// Fewer correspondences than this stops the loop (`TooFewCorrespondences`).
    pub min_correspondences: usize,
    /// Degeneracy-aware solve (solution remapping, Zhang, Kaess & Singh 2016, §IV): every step
    /// `δ` is replaced by `P δ`, `P` (row-major `dof x dof`, first `dof²` values used) the
    /// projector onto the well-constrained directions along the weak ones, so the estimate
    /// keeps its initial value along weak directions. `None`: plain steps.
    pub step_projector: Option<[f64; 36]>,
    /// Point-to-point and point-to-plane/line under Gauss–Newton: stretch steps along a
    /// consistent direction (safeguarded Besl–McKay extrapolation, see `Extrapolation`).
    pub extrapolate: bool,
}

/// Why the iteration loop stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// The last step was below both tolerances (or, under LM, no step lowered the cost: a
    /// minimum).
    Converged,
    MaxIterations,
    TooFewCorrespondences,
    /// The step was non-finite, or the iterates ran away: three steps in a row implausibly
    /// large for the gate (moving the source's centroid over ten gates, or rotating over 90°:
    /// a near-singular `H`; a single one is shortened and the loop goes on); the pose before
    /// that step is returned.
    Diverged,
    /// `H` is singular: the correspondences do not determine the pose (e.g. all on one plane
    /// for point-to-plane).
    Degenerate,
}

impl StopReason {
    pub fn name(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::MaxIterations => "max_iterations",
            StopReason::TooFewCorrespondences => "too_few_correspondences",
            StopReason::Diverged => "diverged",
            StopReason::Degenerate => "degenerate",
        }
    }
}

/// The squared gate, once the settings are checked.
pub(super) fn check_settings(s: &Settings) -> Result<f64> {
    let max_sq = check_max_distance("max_correspondence_distance", s.max_correspondence_distance)?;
    if let Some(p) = &s.step_projector {
        if p.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid("step_projector", "contains NaN or inf"));
        }
    }
    for (arg, v) in [
        ("translation_tolerance", s.translation_tolerance),
        ("rotation_tolerance", s.rotation_tolerance),
    ] {
        if !v.is_finite() || v <= 0.0 {
            return Err(Error::invalid(
                arg,
                format!("must be finite and > 0, got {v}"),
            ));
        }
    }
    Ok(max_sq)
}
