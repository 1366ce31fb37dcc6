//! Local registration: the ICP family (point-to-point, point-to-plane / point-to-line, GICP)
//! against a k-d tree or a voxel map, with robust kernels, Gauss–Newton or Levenberg–Marquardt
//! on the manifold.
//!
//! One iteration = for every source point, transform it by the current pose, find its nearest
//! target point within the gate (`evaluate`; without a search when the last one's certificate
//! settles it, `certificate`), linearise one factor ([`crate::factor`], shared with the paired
//! solve) and add it into the normal equations `H = Σ k JᵀWJ`, `g = Σ k JᵀW r` with the
//! deterministic chunked sum of [`crate::reduce`]; then solve for `δ` and update
//! `T ← T · exp(δ)` (`solver`). The whole loop runs here, so a registration is one call from
//! Python. It runs in a frame centred on the source's centroid (`centred`), so results do not
//! depend on where the clouds sit (map coordinates included).
//!
//! A robust kernel re-weights each factor by `k(|r|)` (`|r|` is the Mahalanobis norm
//! `sqrt(rᵀWr)` for GICP): IRLS.
//!
//! Files, one idea each: `settings` (what is asked, why it stopped), `search` (where
//! correspondences come from), `certificate` (skipping searches that cannot change),
//! `evaluate` (one linearisation), `extrapolation` (stretched steps), `solver` (the loop),
//! `centred` (the frame it runs in), `pose`.

mod centred;
mod certificate;
mod evaluate;
mod extrapolation;
mod pose;
mod search;
mod settings;
mod solver;

pub use certificate::Certificates;
pub use evaluate::Evaluation;
pub use search::{NeighborSearch, Source, Target};
pub use settings::{Method, Optimizer, Settings, StopReason};
pub use solver::Outcome;

use crate::error::{Error, Result};
use crate::group::{Planar, Spatial};
use crate::points::{check_points, split_pose};
use evaluate::Problem;
use settings::check_settings;

fn check_per_point(
    arg: &'static str,
    data: &[f64],
    n: usize,
    per: usize,
    validated: bool,
) -> Result<()> {
    if data.len() != n * per {
        return Err(Error::invalid(
            arg,
            format!(
                "expected {} values ({n} points x {per}), got {}",
                n * per,
                data.len()
            ),
        ));
    }
    if !validated && !crate::points::all_finite(data) {
        return Err(Error::invalid(arg, "contains NaN or inf"));
    }
    Ok(())
}

fn problem<'a>(
    source: &'a Source<'a>,
    target: &'a Target<'a>,
    settings: &Settings,
) -> Result<Problem<'a>> {
    let dim = target.search.dim();
    let n = check_points("source", source.points, dim)?;
    let max_sq = check_settings(settings)?;
    let m = target.search.id_count();
    let checked = target.search.attributes_validated();
    match settings.method {
        Method::PointToPoint => {}
        Method::PointToPlane => {
            let nrm = target.normals.ok_or_else(|| {
                Error::invalid("target_normals", "are required for point-to-plane/line")
            })?;
            check_per_point("target_normals", nrm, m, dim, checked)?;
        }
        Method::Gicp => {
            let tc = target
                .covariances
                .ok_or_else(|| Error::invalid("target_covariances", "are required for GICP"))?;
            let rows = m / target.search.covariance_group().max(1);
            check_per_point("target_covariances", tc, rows, dim * dim, checked)?;
            let sc = source
                .covariances
                .ok_or_else(|| Error::invalid("source_covariances", "are required for GICP"))?;
            check_per_point("source_covariances", sc, n, dim * dim, false)?;
        }
    }
    Ok(Problem {
        source: source.points,
        source_covs: source.covariances,
        target,
        method: settings.method,
        kernel: settings.kernel,
        max_sq,
        cov_group: target.search.covariance_group().max(1),
        certify: true,
    })
}

/// Register `source` to `target` from `init` (row-major homogeneous `T_target_source`).
pub fn register(
    source: &Source<'_>,
    target: &Target<'_>,
    init: &[f64],
    settings: &Settings,
) -> Result<Outcome> {
    let dim = target.search.dim();
    let pr = problem(source, target, settings)?;
    split_pose("init", init, dim)?;
    Ok(if dim == 2 {
        centred::run::<Planar, 2, 3>(&pr, init, settings)
    } else {
        centred::run::<Spatial, 3, 6>(&pr, init, settings)
    })
}

/// [`register`] from one start after another, the problem (its checks of the inputs) built
/// once: the wrong-basin probe ([`crate::basin::probe_restarts`]) solves its restarts in
/// order and stops as soon as one settles the verdict. Each outcome is the one [`register`]
/// gives from that start alone (the solves share nothing but the read-only inputs).
///
/// `home`: a pose where a solve stops on arrival (see [`Home`]): the probe's result, which a
/// restart that comes back to it has answered — it returns that iterate, `Converged`, without
/// the final evaluation (its `evaluation` empty), instead of iterating on to the same pose.
pub struct Restarts<'a> {
    pr: Problem<'a>,
    settings: &'a Settings,
    home: Option<&'a Home>,
    dim: usize,
}

impl<'a> Restarts<'a> {
    /// Checks the inputs as [`register`] does, and `home` (see [`Home`]).
    pub fn new(
        source: &'a Source<'a>,
        target: &'a Target<'a>,
        settings: &'a Settings,
        home: Option<&'a Home>,
    ) -> Result<Self> {
        let dim = target.search.dim();
        let mut pr = problem(source, target, settings)?;
        if let Some(h) = home {
            // A restart is read for where it ends: certificates would only serve a final
            // evaluation it skips, and never settle a search when the start moves this far.
            pr.certify = false;
            split_pose("home", &h.pose, dim)?;
            if !(h.radius.is_finite() && h.radius >= 0.0 && h.cos_angle.is_finite()) {
                return Err(Error::invalid(
                    "home",
                    "radius must be finite and >= 0, cos_angle finite",
                ));
            }
        }
        Ok(Restarts {
            pr,
            settings,
            home,
            dim,
        })
    }

    /// The registration from `init` (checked by the caller: a valid homogeneous pose).
    pub fn solve(&self, init: &[f64]) -> Outcome {
        if self.dim == 2 {
            centred::run_home::<Planar, 2, 3>(&self.pr, init, self.settings, self.home)
        } else {
            centred::run_home::<Spatial, 3, 6>(&self.pr, init, self.settings, self.home)
        }
    }
}

/// A pose [`Restarts`]' solves stop at on arrival: within `radius` (translation of
/// `home⁻¹ · T`, in the points' units) and at a rotation whose cosine is at least `cos_angle`
/// (the angle's cosine in 2D; `(trace(R) − 1) / 2` in 3D).
#[derive(Debug, Clone, PartialEq)]
pub struct Home {
    /// Row-major homogeneous `T_target_source`.
    pub pose: Vec<f64>,
    pub radius: f64,
    pub cos_angle: f64,
}

/// The normal equations at one pose (with score outer products), without iterating.
pub fn evaluate_at(
    source: &Source<'_>,
    target: &Target<'_>,
    pose: &[f64],
    settings: &Settings,
) -> Result<Evaluation> {
    let dim = target.search.dim();
    let pr = problem(source, target, settings)?;
    split_pose("pose", pose, dim)?;
    Ok(if dim == 2 {
        centred::evaluate_centred::<Planar, 2, 3>(&pr, pose)
    } else {
        centred::evaluate_centred::<Spatial, 3, 6>(&pr, pose)
    })
}

#[cfg(test)]
mod tests;
