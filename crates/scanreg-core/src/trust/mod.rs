//! The trust arithmetic of one registration result, in one call: from the correspondence
//! analysis at unit variances ([`crate::censi::Analysis`]) and the solve's outcome to the
//! degeneracy, every covariance kind, the conditioning, the chosen covariance's information and
//! the motion χ². `scanreg.trust` keeps the orchestration (which analyses and extra solves run)
//! and the result dataclasses; the models behind each step are documented there and in
//! `docs/calibration.md`.
//!
//! One idea per file: [`association`] (the noise the nearest-neighbour association hides),
//! [`dense`] (eigen, inverse, PSD on `dof × dof`), [`degeneracy`],
//! [`covariance`], [`describe`] (directions named), [`weak`] (the prior along weak directions), [`shift`] (the model-error
//! term), [`conditioning`], [`scene`] (per-point levers, length scale, beam phase), [`distortion`] (a
//! sweep's motion distortion).

pub mod association;
pub mod conditioning;
pub mod covariance;
pub mod degeneracy;
pub mod dense;
pub mod describe;
pub mod distortion;
pub mod scene;
pub mod shift;
pub mod weak;

use crate::censi::Analysis;
use crate::error::{Error, Result};
use crate::icp::Method;
use dense::{all_finite, from_rows, psd, Mat, Vector};

/// Which covariance `chosen` (and its information) is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Hessian,
    Censi,
    Block,
    Calibrated,
}

impl Kind {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "hessian" => Ok(Kind::Hessian),
            "censi" => Ok(Kind::Censi),
            "block" => Ok(Kind::Block),
            "calibrated" => Ok(Kind::Calibrated),
            other => Err(Error::invalid(
                "covariance",
                format!("unknown {other:?}; expected hessian, censi, block or calibrated"),
            )),
        }
    }
}

/// A degeneracy analysed before (the degeneracy-aware solve's first, held along its weak
/// directions): reused as it was, not re-measured at the held pose.
#[derive(Debug, Clone, Copy)]
pub struct Held<'a> {
    /// `Ĝ`, row-major (already scaled and normalised).
    pub information: &'a [f64],
    pub threshold: f64,
    pub normal_noise: f64,
    pub typical_normal_noise: f64,
    pub num_correspondences: usize,
    pub removed_normal_noise: f64,
}

/// Everything one result's arithmetic reads; matrices row-major `dof × dof`.
#[derive(Debug, Clone)]
pub struct Input<'a> {
    pub dim: usize,
    pub method: Method,
    /// The correspondence analysis at unit variances.
    pub analysis: &'a Analysis,
    /// The solve's `JᵀWJ` and its residual variance `σ̂²`.
    pub hessian: &'a [f64],
    pub sigma2: f64,
    /// Under a kernel: `Σ ψψᵀ` and the effective number of scalar residuals (the sandwich).
    pub score_outer: Option<&'a [f64]>,
    pub effective_residuals: f64,
    /// The solve's correspondences and `Σ |e|²` (point variance of point-to-point and GICP).
    pub num_correspondences: usize,
    pub sum_squared_distances: f64,
    pub levers: &'a [f64],
    /// The target's normal noise `(ε̂², ε̃²)`, NaN when not measured.
    pub normal_noise: f64,
    pub typical_normal_noise: f64,
    /// Normal variance measured between the two scans (0 when not measured).
    pub normal_variance: f64,
    pub held: Option<Held<'a>>,
    pub prior: &'a [f64],
    /// Tangent `log(start⁻¹ · pose)`.
    pub drift: &'a [f64],
    /// `((H, g, n) of all sampled pairs, (H, g, n) of the agreeing ones)`.
    pub agreement: Option<(shift::System, shift::System)>,
    pub valley: Option<&'a [f64]>,
    /// 2D: the sampling system `(H, M)` of the source's beam phase, row-major
    /// ([`scene::sampling_system`], [`covariance::sampling`]); without one (no target
    /// normals), `sampling` is added to `calibrated`'s heading instead (the beam-phase
    /// variance `Δα²/12`).
    pub sampling_system: Option<(&'a [f64], &'a [f64])>,
    pub sampling: f64,
    /// 2D point-to-line: the per-coordinate point variance the nearest-neighbour association
    /// hides from the residuals ([`association::hidden_noise_variance`]), added to the
    /// residuals' own; 0 elsewhere.
    pub hidden_noise_variance: f64,
    /// 2D: the distortion system `(H, M)` of a sweep's motion, row-major `H` and `M = E[g gᵀ]`
    /// ([`distortion::distortion_system`], [`covariance::distortion`]): its `E[b bᵀ]` is
    /// added to `calibrated`. None: the scans are taken as instantaneous (or deskewed).
    pub distortion_system: Option<(&'a [f64], &'a [f64])>,
    pub length_scale: f64,
    pub chosen: Kind,
    /// Translation of `start⁻¹ · pose`, for the motion χ² against the prior's translation block.
    pub motion: &'a [f64],
}

#[derive(Debug, Clone)]
pub struct Outcome {
    pub degeneracy: degeneracy::Degeneracy,
    /// Each eigen-direction of the degeneracy named ([`describe::describe`]), weakest first.
    pub descriptions: Vec<String>,
    /// The conditioning's weakest direction named.
    pub weakest_description: String,
    /// Point variance per coordinate: the residuals' plus `hidden_noise_variance`.
    pub point_variance: f64,
    /// The input's [`Input::hidden_noise_variance`], as added.
    pub hidden_noise_variance: f64,
    pub hessian: Mat,
    pub censi: Mat,
    pub block: Mat,
    pub calibrated: Mat,
    pub model_shift: Vector,
    pub conditioning: conditioning::Conditioning,
    /// Information of the chosen covariance (zeros when it is not finite).
    pub information: Mat,
    /// `tᵀ P_t⁻¹ t`, None when the prior's translation block is singular.
    pub motion_nees: Option<f64>,
}

fn check_len(name: &'static str, got: usize, want: usize) -> Result<()> {
    if got != want {
        return Err(Error::invalid(
            name,
            format!("expected {want} values, got {got}"),
        ));
    }
    Ok(())
}

/// Noise variance of one coordinate of a point, half of the residual variance (source and
/// target points are equally noisy).
///
/// Point-to-plane/line and GICP: along the normal, `Σ (nᵀe)² / (n − dof)` — the noise their
/// residual feels (GICP's combined covariances weigh a residual along the surface ~1/(2ε)
/// times less than one along the normal, so its gradient, and Censi's derivatives of it,
/// move with the normal component); GICP at a held pose over the determined pairs only
/// ([`held_determined`]). Point-to-point: `Σ |e|² / (D n − dof)`, the
/// along-surface sampling offsets included (its cost sees them). The Euclidean estimate made
/// GICP 2–8× over-cautious on every axis its bias leaves alone (3D street, tunnel, KITTI
/// halves; 2D corridor 0.16 × dof); what it covered by accident in 3D, a bias along the road
/// and in pitch, is GICP's `model_shift` now (`docs/calibration.md`).
fn point_variance(input: &Input<'_>, dof: usize) -> f64 {
    let a = input.analysis;
    let n_plane = a.num_plane_correspondences;
    let along_normal = matches!(input.method, Method::PointToPlane | Method::Gicp);
    if held_determined(input, dof) {
        let n_det = a.num_determined_correspondences;
        return a.determined_plane_sum_squares / (n_det - dof) as f64 / 2.0;
    }
    if along_normal && n_plane > dof {
        return a.plane_sum_squares / (n_plane - dof) as f64 / 2.0;
    }
    let n = input.num_correspondences;
    let denom = (input.dim * n).saturating_sub(dof).max(1) as f64;
    input.sum_squared_distances / denom / 2.0
}

/// GICP at a held pose (the degeneracy-aware solve's, held along a weak direction) with a
/// target that flags its linear neighbourhoods: the point variance and the `block` scores
/// over the determined pairs only.
///
/// A linear neighbourhood's normal (a ring, a pole) is a guess, so the residual along it
/// carries the along-surface offsets of the sampling. Where the rings lock (the plain solve)
/// those are as small as the noise (tunnel: point variance over the determined pairs
/// 1.7–1.9·10⁻⁴ against 1.6–2.0·10⁻⁴ over all). Held 0.1 m off along the axis, the rings'
/// misfit makes the linear pairs' 40× the lock's, and `censi` and `block` over-covered z,
/// roll and yaw 3–6× (3D tunnel with a prior: 0.37 × dof). That misfit is the effect of the
/// linear pairs on the held estimate, which GICP's `model_shift` (its step without them
/// minus its step with them) already carries, and of holding, which the valley term
/// carries. Point-to-plane keeps every pair: its shift is the normal-agreement one, and
/// without the linear pairs' residuals it is over-confident in pitch (tunnel with a prior
/// 2.1 × dof; `docs/calibration.md`, item 6).
fn held_determined(input: &Input<'_>, dof: usize) -> bool {
    let a = input.analysis;
    input.held.is_some()
        && input.method == Method::Gicp
        && a.linear_known
        && a.num_determined_correspondences > dof
        && a.num_determined_blocks > 0
}

/// GICP's systems for [`shift::model_shift`]: its own normal equations at the final pose over
/// every correspondence and over those whose target neighbourhood is not linear (a sparse
/// LiDAR's rings and poles, whose plane-regularised covariance orients its thin axis at
/// random), when the target says which are (3D, a prepared target).
fn gicp_systems(input: &Input<'_>, dof: usize) -> Option<(shift::System, shift::System)> {
    let a = input.analysis;
    if input.method != Method::Gicp || input.dim != 3 || !a.linear_known || a.score.len() != dof {
        return None;
    }
    let system = |h: &[f64], g: &[f64], count: usize| shift::System {
        hessian: from_rows(dof, h),
        gradient: Vector::from_column_slice(g),
        count,
    };
    Some((
        system(&a.hessian, &a.score, a.num_correspondences),
        system(
            &a.determined_hessian,
            &a.determined_score,
            a.num_determined_pairs,
        ),
    ))
}

/// The whole arithmetic of one result (see the module docs).
pub fn analyse(input: &Input<'_>) -> Result<Outcome> {
    let dim = input.dim;
    if dim != 2 && dim != 3 {
        return Err(Error::invalid("dim", format!("must be 2 or 3, got {dim}")));
    }
    let dof = if dim == 2 { 3 } else { 6 };
    let nn = dof * dof;
    check_len("hessian", input.hessian.len(), nn)?;
    check_len("prior", input.prior.len(), nn)?;
    check_len("drift", input.drift.len(), dof)?;
    check_len("levers", input.levers.len(), dof - dim)?;
    check_len("motion", input.motion.len(), dim)?;
    let a = input.analysis;
    check_len("analysis", a.hessian.len(), nn)?;
    if let Some(s) = input.score_outer {
        check_len("score_outer", s.len(), nn)?;
    }
    if let Some(v) = input.valley {
        check_len("valley", v.len(), nn)?;
    }
    if let Some((hs, ms)) = input.sampling_system {
        check_len("sampling_system", hs.len(), nn)?;
        check_len("sampling_system", ms.len(), nn)?;
    }
    if let Some((hd, md)) = input.distortion_system {
        check_len("distortion_system", hd.len(), nn)?;
        check_len("distortion_system", md.len(), nn)?;
    }
    if let Some(h) = input.held {
        check_len("held", h.information.len(), nn)?;
    }
    let levers = Vector::from_column_slice(input.levers);

    let deg = match input.held {
        Some(h) => degeneracy::from_normalised(
            from_rows(dof, h.information),
            levers,
            h.threshold,
            h.normal_noise,
            h.typical_normal_noise,
            h.num_correspondences,
            h.removed_normal_noise,
        ),
        None if a.num_determined_correspondences > dof => {
            // Judged by the information the normals' noise does not explain (a tunnel's axis
            // gains ε² per correspondence from noisy normals alone), over the correspondences
            // whose normal is determined when the target says which are (linear
            // neighbourhoods' normals are guesses: `degeneracy::MIN_CONSTRAINT`).
            let (g, eps2) = degeneracy::noise_removed(
                &from_rows(dof, &a.plane_information),
                &from_rows(dof, &a.plane_noise_information),
                a.normal_disagreement,
                a.num_normal_pairs,
                dim,
            );
            let mut deg = degeneracy::analyse(
                &g,
                a.num_determined_correspondences,
                dim,
                &levers,
                input.normal_noise,
                input.typical_normal_noise,
                degeneracy::floor(a.linear_known, a.num_determined_correspondences),
            );
            deg.removed_normal_noise = eps2;
            deg
        }
        None => degeneracy::analyse(
            &from_rows(dof, &a.hessian),
            a.num_correspondences.max(1),
            dim,
            &levers,
            input.normal_noise,
            input.typical_normal_noise,
            degeneracy::MIN_CONSTRAINT,
        ),
    };
    let hidden = input.hidden_noise_variance.max(0.0);
    let pv = point_variance(input, dof) + hidden;
    let nv = input.normal_variance;

    let score_outer = input.score_outer.map(|s| from_rows(dof, s));
    let solve_hessian = from_rows(dof, input.hessian);
    let hessian_cov = covariance::of_hessian(
        &solve_hessian,
        input.sigma2,
        score_outer.as_ref(),
        input.effective_residuals,
    );

    let prior = from_rows(dof, input.prior);
    let drift = Vector::from_column_slice(input.drift);
    let shift = match (&input.agreement, gicp_systems(input, dof)) {
        (Some((all, agreeing)), _) => {
            shift::model_shift(all, agreeing, &deg, input.method == Method::PointToPoint)
        }
        (None, Some((all, determined))) => shift::model_shift(&all, &determined, &deg, false),
        (None, None) => Vector::zeros(dof),
    };
    let bad = Mat::from_element(dof, dof, f64::INFINITY);
    let h = from_rows(dof, &a.hessian);
    let meat = (from_rows(dof, &a.source_meat) + from_rows(dof, &a.target_meat)) * pv
        + from_rows(dof, &a.normal_meat) * nv;
    let (censi, block, mut calibrated) = match dense::inverse(&h) {
        Some(h_inv) => {
            let c = covariance::censi_from_inverse(&h_inv, &meat);
            let b = if held_determined(input, dof) {
                covariance::block_from_inverse(
                    &h_inv,
                    &from_rows(dof, &a.determined_block_meat),
                    a.num_determined_blocks,
                )
            } else {
                covariance::block_from_inverse(&h_inv, &from_rows(dof, &a.block_meat), a.num_blocks)
            };
            if all_finite(&c) && all_finite(&b) {
                let u = covariance::upper_bound(&c, &b);
                (c, b, u)
            } else {
                (bad.clone(), bad.clone(), bad.clone())
            }
        }
        None => (bad.clone(), bad.clone(), bad.clone()),
    };
    if deg.num_weak() > 0 && all_finite(&calibrated) {
        // The tilt of the weak axis comes from the target's normal noise; on a map (not
        // measured there) from the noise between the two scans.
        let eps2 = if deg.normal_noise.is_finite() {
            deg.normal_noise
        } else {
            nv
        };
        let valley = input.valley.map(|v| from_rows(dof, v));
        calibrated =
            weak::with_prior_along_weak(&calibrated, &deg, &prior, &drift, eps2, valley.as_ref());
    }
    calibrated += &shift * shift.transpose();
    if all_finite(&calibrated) {
        match input.sampling_system {
            Some((hs, ms)) => {
                let term = covariance::sampling(&from_rows(dof, hs), &from_rows(dof, ms), &deg);
                if let Some(term) = term {
                    calibrated += term;
                }
            }
            None if input.sampling > 0.0 => calibrated[(2, 2)] += input.sampling,
            None => {}
        }
        if let Some((hd, md)) = input.distortion_system {
            let m = from_rows(dof, md);
            if let Some(term) = covariance::distortion(&from_rows(dof, hd), &m, &deg) {
                calibrated += term;
            }
        }
    }
    let (censi, block, calibrated) = (psd(&censi), psd(&block), psd(&calibrated));
    let hessian_cov = psd(&hessian_cov);
    let chosen = match input.chosen {
        Kind::Hessian => &hessian_cov,
        Kind::Censi => &censi,
        Kind::Block => &block,
        Kind::Calibrated => &calibrated,
    };
    let information = if all_finite(chosen) {
        covariance::information(chosen)
    } else {
        Mat::zeros(dof, dof)
    };
    let motion_block = prior.view((0, 0), (dim, dim)).into_owned();
    let t = Vector::from_column_slice(input.motion);
    let motion_nees = dense::solve(&motion_block, &t).map(|x| t.dot(&x));
    let conditioning = conditioning::conditioning(&solve_hessian, dim, input.length_scale);
    let lever_rms =
        (deg.levers.iter().map(|l| l * l).sum::<f64>() / deg.levers.len() as f64).sqrt();
    let descriptions = (0..dof)
        .map(|i| describe::describe(deg.directions.column(i).as_slice(), dim, lever_rms))
        .collect();
    let weakest_description = describe::describe(
        conditioning.weakest.as_slice(),
        dim,
        conditioning.length_scale,
    );
    Ok(Outcome {
        degeneracy: deg,
        descriptions,
        weakest_description,
        point_variance: pv,
        hidden_noise_variance: hidden,
        hessian: hessian_cov,
        censi,
        block,
        calibrated,
        model_shift: shift,
        conditioning,
        information,
        motion_nees,
    })
}

#[cfg(test)]
mod tests;
