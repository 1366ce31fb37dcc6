//! Binding of `scanreg_core::trust`: the per-result trust arithmetic in one call, and the
//! per-point scene quantities it reads. Converts and validates only.

use crate::censi::CensiAnalysis;
use crate::convert::{
    c_slice, core_err, covariances, in_pool_unless_small, points, points_dim, pose, read_only,
};
use crate::knn::KdTree as PyKdTree;
use crate::measure::{overlap_tuple, OverlapTuple};
use crate::register::{rigid_parts, IcpOutcome};
use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::censi::{self, NONE};
use scanreg_core::icp::Method;
use scanreg_core::knn::{check_max_distance, KdTree};
use scanreg_core::normal_agreement::{self, AgreementInput};
use scanreg_core::normal_noise;
use scanreg_core::overlap;
use scanreg_core::trust::dense::{flat, Mat, Vector};
use scanreg_core::trust::{self, association, distortion, scene, shift::System, Held, Input, Kind};
use scanreg_core::Kernel;

/// A source's sampled normals `(indices, normals)`, as `sampled_normals` returns them.
type Sampled = (Py<PyArray1<i64>>, Py<PyArray2<f64>>);

#[pyclass(frozen, module = "scanreg._core")]
pub struct TrustNumbers {
    /// `Ĝ`, its eigenvalues (ascending), eigenvectors (scaled coordinates) and the
    /// eigen-directions in tangent units (columns).
    #[pyo3(get)]
    degeneracy_information: Py<PyArray2<f64>>,
    #[pyo3(get)]
    degeneracy_eigenvalues: Py<PyArray1<f64>>,
    #[pyo3(get)]
    degeneracy_eigenvectors: Py<PyArray2<f64>>,
    #[pyo3(get)]
    degeneracy_directions: Py<PyArray2<f64>>,
    /// Each eigen-direction named, weakest first.
    #[pyo3(get)]
    degeneracy_descriptions: Vec<String>,
    #[pyo3(get)]
    degeneracy_threshold: f64,
    #[pyo3(get)]
    degeneracy_count: usize,
    #[pyo3(get)]
    degeneracy_removed_normal_noise: f64,
    #[pyo3(get)]
    point_variance: f64,
    /// Of `point_variance`, what the nearest-neighbour association hid from the residuals.
    #[pyo3(get)]
    hidden_noise_variance: f64,
    #[pyo3(get)]
    hessian: Py<PyArray2<f64>>,
    #[pyo3(get)]
    censi: Py<PyArray2<f64>>,
    #[pyo3(get)]
    block: Py<PyArray2<f64>>,
    #[pyo3(get)]
    calibrated: Py<PyArray2<f64>>,
    #[pyo3(get)]
    model_shift: Py<PyArray1<f64>>,
    #[pyo3(get)]
    information: Py<PyArray2<f64>>,
    #[pyo3(get)]
    motion_nees: Option<f64>,
    #[pyo3(get)]
    conditioning_eigenvalues: Py<PyArray1<f64>>,
    #[pyo3(get)]
    conditioning_eigenvectors: Py<PyArray2<f64>>,
    #[pyo3(get)]
    condition_number: f64,
    #[pyo3(get)]
    length_scale: f64,
    #[pyo3(get)]
    scaled_eigenvalues: Py<PyArray1<f64>>,
    #[pyo3(get)]
    scaled_condition_number: f64,
    #[pyo3(get)]
    weakest: Py<PyArray1<f64>>,
    #[pyo3(get)]
    weakest_ratio: f64,
    #[pyo3(get)]
    weakest_description: String,
    /// The correspondence analysis's spatial blocks and plane correspondences.
    #[pyo3(get)]
    num_blocks: usize,
    #[pyo3(get)]
    num_plane_correspondences: usize,
    /// The normal variance between the two scans the covariances used (rad², 0 if not measured).
    #[pyo3(get)]
    normal_variance: f64,
    /// `trust_analysis`: the source's sampled normals `(indices, normals)` it measured or was
    /// given (for the next analysis of the same source), None if it needed none.
    #[pyo3(get)]
    source_normals: Option<Sampled>,
    /// `trust_analysis` with `target_spacing`: the source's median spacing it measured (NaN
    /// otherwise, or with fewer than 2 points).
    #[pyo3(get)]
    source_spacing: f64,
    /// `trust_analysis` with `overlap_target`: `overlap_statistics` at the outcome's pose (what
    /// the verdict reads), from the same call; None otherwise.
    #[pyo3(get)]
    overlap: Option<OverlapTuple>,
    /// `trust_analysis` in 2D with a sampling system: the source is not one scan in bearing
    /// order from one viewpoint (`scene::sampling_model`: a map, merged submaps, wall
    /// samples); false otherwise.
    #[pyo3(get)]
    source_is_cloud: bool,
    /// `trust_analysis` without `levers`: `trust_scene(source, scene_gate, beam_phase=False)`'s
    /// tuple, measured in the same call; None otherwise.
    #[pyo3(get)]
    scene: Option<Scene>,
}

fn mat(py: Python<'_>, m: &Mat) -> PyResult<Py<PyArray2<f64>>> {
    let arr = Array2::from_shape_vec((m.nrows(), m.ncols()), flat(m))
        .map_err(|e| PyValueError::new_err(format!("internal: {e}")))?;
    Ok(read_only(arr.into_pyarray(py)))
}

fn vec1(py: Python<'_>, v: &Vector) -> Py<PyArray1<f64>> {
    read_only(v.as_slice().to_vec().into_pyarray(py))
}

fn square_slice<'a>(
    arr: &'a PyReadonlyArray2<'_, f64>,
    name: &str,
    dof: usize,
) -> PyResult<&'a [f64]> {
    let s = c_slice(arr, name)?;
    if s.len() != dof * dof {
        return Err(PyValueError::new_err(format!(
            "{name}: expected a ({dof}, {dof}) matrix, got {} values",
            s.len()
        )));
    }
    Ok(s)
}

type Agreement<'py> = (
    PyReadonlyArray2<'py, f64>,
    PyReadonlyArray1<'py, f64>,
    usize,
    PyReadonlyArray2<'py, f64>,
    PyReadonlyArray1<'py, f64>,
    usize,
);

type Holding<'py> = (PyReadonlyArray2<'py, f64>, f64, f64, f64, usize, f64);

fn system(
    h: &PyReadonlyArray2<'_, f64>,
    g: &PyReadonlyArray1<'_, f64>,
    n: usize,
    dof: usize,
) -> PyResult<System> {
    let hs = square_slice(h, "agreement", dof)?;
    let gs = c_slice(g, "agreement")?;
    if gs.len() != dof {
        return Err(PyValueError::new_err(format!(
            "agreement: expected gradients of {dof} values, got {}",
            gs.len()
        )));
    }
    Ok(System {
        hessian: Mat::from_row_slice(dof, dof, hs),
        gradient: Vector::from_column_slice(gs),
        count: n,
    })
}

/// The trust arithmetic of one result (`scanreg_core::trust::analyse`).
#[pyfunction]
#[pyo3(signature = (
    analysis, hessian, sigma2, *, method, levers, prior, drift, motion, length_scale, covariance,
    num_correspondences, sum_squared_distances, score_outer=None, effective_residuals=0.0,
    normal_noise=f64::NAN, typical_normal_noise=f64::NAN, normal_variance=0.0, agreement=None,
    valley=None, sampling_system=None, sampling=0.0, held=None, hidden_noise_variance=0.0
))]
#[allow(clippy::too_many_arguments)]
fn trust_numbers(
    py: Python<'_>,
    analysis: PyRef<'_, CensiAnalysis>,
    hessian: PyReadonlyArray2<'_, f64>,
    sigma2: f64,
    method: &str,
    levers: PyReadonlyArray1<'_, f64>,
    prior: PyReadonlyArray2<'_, f64>,
    drift: PyReadonlyArray1<'_, f64>,
    motion: PyReadonlyArray1<'_, f64>,
    length_scale: f64,
    covariance: &str,
    num_correspondences: usize,
    sum_squared_distances: f64,
    score_outer: Option<PyReadonlyArray2<'_, f64>>,
    effective_residuals: f64,
    normal_noise: f64,
    typical_normal_noise: f64,
    normal_variance: f64,
    agreement: Option<Agreement<'_>>,
    valley: Option<PyReadonlyArray2<'_, f64>>,
    sampling_system: Option<(PyReadonlyArray2<'_, f64>, PyReadonlyArray2<'_, f64>)>,
    sampling: f64,
    held: Option<Holding<'_>>,
    hidden_noise_variance: f64,
) -> PyResult<TrustNumbers> {
    let a = &analysis.inner;
    let dof = (a.hessian.len() as f64).sqrt() as usize;
    let dim = if dof == 3 { 2 } else { 3 };
    let agreement = agreement
        .as_ref()
        .map(|(ha, ga, na, hk, gk, nk)| -> PyResult<_> {
            Ok((system(ha, ga, *na, dof)?, system(hk, gk, *nk, dof)?))
        })
        .transpose()?;
    let held = held
        .as_ref()
        .map(
            |(g, threshold, eps2, eps2t, count, removed)| -> PyResult<_> {
                Ok(Held {
                    information: square_slice(g, "held", dof)?,
                    threshold: *threshold,
                    normal_noise: *eps2,
                    typical_normal_noise: *eps2t,
                    num_correspondences: *count,
                    removed_normal_noise: *removed,
                })
            },
        )
        .transpose()?;
    let input = Input {
        dim,
        method: Method::from_name(method).map_err(core_err)?,
        analysis: a,
        hessian: square_slice(&hessian, "hessian", dof)?,
        sigma2,
        score_outer: score_outer
            .as_ref()
            .map(|s| square_slice(s, "score_outer", dof))
            .transpose()?,
        effective_residuals,
        num_correspondences,
        sum_squared_distances,
        levers: c_slice(&levers, "levers")?,
        normal_noise,
        typical_normal_noise,
        normal_variance,
        held,
        prior: square_slice(&prior, "prior", dof)?,
        drift: c_slice(&drift, "drift")?,
        agreement,
        valley: valley
            .as_ref()
            .map(|v| square_slice(v, "valley", dof))
            .transpose()?,
        sampling_system: sampling_system
            .as_ref()
            .map(|(h, m)| -> PyResult<_> {
                Ok((
                    square_slice(h, "sampling_system", dof)?,
                    square_slice(m, "sampling_system", dof)?,
                ))
            })
            .transpose()?,
        sampling,
        // Measured by `trust_analysis` (`scanreg_core::trust::association`); given here.
        hidden_noise_variance,
        distortion_system: None,
        length_scale,
        chosen: Kind::from_name(covariance).map_err(core_err)?,
        motion: c_slice(&motion, "motion")?,
    };
    let out = trust::analyse(&input).map_err(core_err)?;
    numbers(py, &out, a, normal_variance, None, f64::NAN)
}

fn numbers(
    py: Python<'_>,
    out: &trust::Outcome,
    analysis: &scanreg_core::censi::Analysis,
    normal_variance: f64,
    source_normals: Option<Sampled>,
    source_spacing: f64,
) -> PyResult<TrustNumbers> {
    let deg = &out.degeneracy;
    let cond = &out.conditioning;
    Ok(TrustNumbers {
        degeneracy_information: mat(py, &deg.information)?,
        degeneracy_eigenvalues: vec1(py, &deg.eigenvalues),
        degeneracy_eigenvectors: mat(py, &deg.eigenvectors)?,
        degeneracy_directions: mat(py, &deg.directions)?,
        degeneracy_descriptions: out.descriptions.clone(),
        degeneracy_threshold: deg.threshold,
        degeneracy_count: deg.num_correspondences,
        degeneracy_removed_normal_noise: deg.removed_normal_noise,
        point_variance: out.point_variance,
        hidden_noise_variance: out.hidden_noise_variance,
        hessian: mat(py, &out.hessian)?,
        censi: mat(py, &out.censi)?,
        block: mat(py, &out.block)?,
        calibrated: mat(py, &out.calibrated)?,
        model_shift: vec1(py, &out.model_shift),
        information: mat(py, &out.information)?,
        motion_nees: out.motion_nees,
        conditioning_eigenvalues: vec1(py, &cond.eigenvalues),
        conditioning_eigenvectors: mat(py, &cond.eigenvectors)?,
        condition_number: cond.condition_number,
        length_scale: cond.length_scale,
        scaled_eigenvalues: vec1(py, &cond.scaled_eigenvalues),
        scaled_condition_number: cond.scaled_condition_number,
        weakest: vec1(py, &cond.weakest),
        weakest_ratio: cond.weakest_ratio,
        weakest_description: out.weakest_description.clone(),
        num_blocks: analysis.num_blocks,
        num_plane_correspondences: analysis.num_plane_correspondences,
        normal_variance,
        source_normals,
        source_spacing,
        overlap: None,
        source_is_cloud: false,
        scene: None,
    })
}

/// The source's sampled normals as the Python side caches them: `(indices, normals)`.
type SampledNormals<'py> = (PyReadonlyArray1<'py, i64>, PyReadonlyArray2<'py, f64>);

/// The whole correspondence analysis of one outcome and its arithmetic, in one call (what
/// `scanreg.trust.correspondence_analysis` runs): the source's sampled normals (given, or
/// measured here with `num_neighbors`), the normal noise between the two scans, the normal
/// agreement systems, the 2D sampling system, Censi's and the block sums at unit variances and
/// `trust::analyse`; the sampling system's `M` times `sampling_scale`, or, given
/// `target_spacing` (the target's median spacing), times `min(1, target_spacing /
/// source_spacing)²` with the source's spacing read off the same k-d tree and searches as its
/// sampled normals (`scanreg_core::normal_noise::sampled_normals_and_spacing`).
/// `beam_phase_variance` NaN: measured here, where it is used (no sampling system). `target*`
/// are the matched rows' storage (a map's gathered rows), the correspondences index them. The
/// same arithmetic as the separate calls, to the bit.
#[pyfunction]
#[pyo3(signature = (
    source, target, pose_matrix, correspondences, method, kernel, kernel_scale, block_size,
    num_neighbors, target_normals, target_covariances, source_covariances, num_threads,
    hessian, sigma2, levers, prior, drift, motion, length_scale, covariance,
    num_correspondences, sum_squared_distances, score_outer, effective_residuals,
    normal_noise, typical_normal_noise, beam_phase_variance, max_step, min_agreement,
    sampling_scale, source_normals=None, valley=None, held=None, target_linear=None,
    target_spacing=None, overlap_target=None, overlap_gate=None, outcome=None, scene_gate=None,
    sweep_motion=None, target_sweep_motion=None, target_sweep_origin=None
))]
#[allow(clippy::too_many_arguments)]
fn trust_analysis(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    correspondences: PyReadonlyArray1<'_, i64>,
    method: &str,
    kernel: &str,
    kernel_scale: f64,
    block_size: f64,
    num_neighbors: usize,
    target_normals: Option<PyReadonlyArray2<'_, f64>>,
    target_covariances: Option<PyReadonlyArray3<'_, f64>>,
    source_covariances: Option<PyReadonlyArray3<'_, f64>>,
    num_threads: Option<usize>,
    hessian: PyReadonlyArray2<'_, f64>,
    sigma2: f64,
    levers: Option<PyReadonlyArray1<'_, f64>>,
    prior: Option<PyReadonlyArray2<'_, f64>>,
    drift: PyReadonlyArray1<'_, f64>,
    motion: PyReadonlyArray1<'_, f64>,
    length_scale: Option<f64>,
    covariance: &str,
    num_correspondences: usize,
    sum_squared_distances: f64,
    score_outer: Option<PyReadonlyArray2<'_, f64>>,
    effective_residuals: f64,
    normal_noise: f64,
    typical_normal_noise: f64,
    beam_phase_variance: f64,
    max_step: f64,
    min_agreement: f64,
    sampling_scale: f64,
    source_normals: Option<SampledNormals<'_>>,
    valley: Option<PyReadonlyArray2<'_, f64>>,
    held: Option<Holding<'_>>,
    target_linear: Option<PyReadonlyArray1<'_, bool>>,
    target_spacing: Option<f64>,
    overlap_target: Option<&Bound<'_, PyKdTree>>,
    overlap_gate: Option<f64>,
    outcome: Option<&Bound<'_, IcpOutcome>>,
    scene_gate: Option<f64>,
    sweep_motion: Option<PyReadonlyArray1<'_, f64>>,
    target_sweep_motion: Option<PyReadonlyArray2<'_, f64>>,
    target_sweep_origin: Option<PyReadonlyArray2<'_, f64>>,
) -> PyResult<TrustNumbers> {
    let (src, dim) = points(&source, "source")?;
    let n = src.len() / dim;
    let dof = if dim == 2 { 3 } else { 6 };
    let tgt = points_dim(&target, "target", dim)?;
    let m = tgt.len() / dim;
    let pm = pose(&pose_matrix, "pose_matrix", dim)?;
    let corr = c_slice(&correspondences, "correspondences")?;
    if corr.len() != n {
        return Err(PyValueError::new_err(format!(
            "correspondences: expected {n} values (one per source point), got {}",
            corr.len()
        )));
    }
    // The verdict's overlap pass in the same call (2D: the pose is the outcome's with its
    // rotation projected as `SE2` holds it, what `pose.as_matrix()` gives the separate call).
    let overlap_in = match overlap_target {
        None => None,
        Some(tree) => {
            if dim != 2 {
                return Err(PyValueError::new_err("overlap_target: 2D only"));
            }
            let gate = overlap_gate.ok_or_else(|| {
                PyValueError::new_err("overlap_gate: required with overlap_target")
            })?;
            let max_sq = check_max_distance("overlap_gate", gate).map_err(core_err)?;
            let (r, t) = rigid_parts(pm, dim)?;
            let overlap_pose = [r[0], r[1], t[0], r[2], r[3], t[1], 0.0, 0.0, 1.0];
            let certificates = outcome.and_then(|o| o.get().certificates.as_ref());
            Some((&tree.get().inner, max_sq, overlap_pose, certificates))
        }
    };
    let method = Method::from_name(method).map_err(core_err)?;
    let kernel = Kernel::from_name(kernel, kernel_scale).map_err(core_err)?;
    let sweep = |a: &Option<PyReadonlyArray1<'_, f64>>, name: &str| -> PyResult<Option<[f64; 3]>> {
        let Some(a) = a else { return Ok(None) };
        let v = c_slice(a, name)?;
        match (dim, v) {
            (2, &[vx, vy, w]) if v.iter().all(|x| x.is_finite()) => Ok(Some([vx, vy, w])),
            (2, _) => Err(PyValueError::new_err(format!(
                "{name}: expected 3 finite values [vx, vy, ω]·T, got {v:?}"
            ))),
            _ => Err(PyValueError::new_err(format!("{name}: 2D scans only"))),
        }
    };
    let source_sweep = sweep(&sweep_motion, "sweep_motion")?;
    // The target's sweeps (one row each: a scan, or the keyframes of a map), `[x, y, θ]`
    // of each sweep's sensor in the target's frame (none: the target frame's origin).
    let target_sweeps = match &target_sweep_motion {
        None => Vec::new(),
        Some(_) if dim != 2 => {
            return Err(PyValueError::new_err("target_sweep_motion: 2D scans only"))
        }
        Some(motions) => {
            let shape = motions.shape();
            let mv = c_slice(motions, "target_sweep_motion")?;
            if shape[1] != 3 || mv.iter().any(|x| !x.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "target_sweep_motion: expected rows of 3 finite values [vx, vy, ω]·T, \
                     got shape {shape:?}"
                )));
            }
            let origins = match &target_sweep_origin {
                None => vec![0.0; mv.len()],
                Some(o) => {
                    let ov = c_slice(o, "target_sweep_origin")?;
                    if o.shape() != shape || ov.iter().any(|x| !x.is_finite()) {
                        return Err(PyValueError::new_err(format!(
                            "target_sweep_origin: expected one finite [x, y, θ] per sweep \
                             (shape {shape:?}), got shape {:?}",
                            o.shape()
                        )));
                    }
                    ov.to_vec()
                }
            };
            mv.chunks_exact(3)
                .zip(origins.chunks_exact(3))
                .map(|(m, o)| distortion::TargetSweep {
                    motion: [m[0], m[1], m[2]],
                    origin: [o[2].cos(), o[2].sin(), o[0], o[1]],
                })
                .collect()
        }
    };
    let tn = target_normals
        .as_ref()
        .map(|a| points_dim(a, "target_normals", dim))
        .transpose()?;
    if let Some(t) = tn {
        if t.len() != tgt.len() {
            return Err(PyValueError::new_err(format!(
                "target_normals: expected one row per target point ({m}), got {}",
                t.len() / dim
            )));
        }
    }
    let tc = covariances(&target_covariances, "target_covariances", m, dim)?;
    let sc = covariances(&source_covariances, "source_covariances", n, dim)?;
    let linear = target_linear
        .as_ref()
        .map(|a| c_slice(a, "target_linear"))
        .transpose()?;
    if let Some(l) = linear {
        if l.len() != m {
            return Err(PyValueError::new_err(format!(
                "target_linear: expected one flag per target point ({m}), got {}",
                l.len()
            )));
        }
    }
    let corr32: Vec<u32> = corr
        .iter()
        .map(|&j| {
            if j < 0 {
                Ok(NONE)
            } else {
                u32::try_from(j).ok().filter(|&v| v != NONE).ok_or_else(|| {
                    PyValueError::new_err(format!("correspondences: index {j} out of range"))
                })
            }
        })
        .collect::<PyResult<_>>()?;
    let given = source_normals
        .as_ref()
        .map(|(idx, nrm)| -> PyResult<(Vec<usize>, &[f64])> {
            let idx = c_slice(idx, "source_normals")?
                .iter()
                .map(|&i| usize::try_from(i).ok().filter(|&i| i < n))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| PyValueError::new_err("source_normals: index out of range"))?;
            let nrm = c_slice(nrm, "source_normals")?;
            if nrm.len() != idx.len() * dim {
                return Err(PyValueError::new_err(format!(
                    "source_normals: expected {} values, got {}",
                    idx.len() * dim,
                    nrm.len()
                )));
            }
            Ok((idx, nrm))
        })
        .transpose()?;
    let held = held
        .as_ref()
        .map(
            |(g, threshold, eps2, eps2t, count, removed)| -> PyResult<_> {
                Ok(Held {
                    information: square_slice(g, "held", dof)?,
                    threshold: *threshold,
                    normal_noise: *eps2,
                    typical_normal_noise: *eps2t,
                    num_correspondences: *count,
                    removed_normal_noise: *removed,
                })
            },
        )
        .transpose()?;
    let hessian = square_slice(&hessian, "hessian", dof)?;
    let score_outer = score_outer
        .as_ref()
        .map(|s| square_slice(s, "score_outer", dof))
        .transpose()?;
    // The scene pass (`trust_scene`) in the same call where the caller has not run it: the
    // rotation levers, the length scale and the gate-wide prior of `scene_gate`.
    let scene_own = match &levers {
        Some(_) => None,
        None => {
            if n == 0 {
                return Err(PyValueError::new_err("source: is empty"));
            }
            let gate = scene_gate
                .ok_or_else(|| PyValueError::new_err("scene_gate: required without levers"))?;
            let own = scene::rotation_levers(src, dim);
            let default = scene::default_prior(dim, &own, gate);
            Some((own, scene::length_scale(src, dim), default))
        }
    };
    let levers = match (&levers, &scene_own) {
        (Some(a), _) => c_slice(a, "levers")?,
        (None, Some((own, _, _))) => &own[..],
        (None, None) => unreachable!("the scene is measured without levers"),
    };
    let prior = match (&prior, &scene_own) {
        (Some(a), _) => square_slice(a, "prior", dof)?,
        (None, Some((_, _, default))) => &default[..],
        (None, None) => return Err(PyValueError::new_err("prior: required with levers")),
    };
    let length_scale = match (length_scale, &scene_own) {
        (Some(l), _) => l,
        (None, Some((_, l, _))) => *l,
        (None, None) => {
            return Err(PyValueError::new_err("length_scale: required with levers"));
        }
    };
    let drift = c_slice(&drift, "drift")?;
    let motion = c_slice(&motion, "motion")?;
    let valley = valley
        .as_ref()
        .map(|v| square_slice(v, "valley", dof))
        .transpose()?;
    let chosen = Kind::from_name(covariance).map_err(core_err)?;
    let rot: Vec<f64> = (0..dim)
        .flat_map(|r| (0..dim).map(move |c| pm[r * (dim + 1) + c]))
        .collect();
    let is_gicp = method == Method::Gicp;
    let is_p2p = method == Method::PointToPoint;
    // The source's normals are measured only where something reads them: the normal noise and
    // agreement need target normals; 3D's plane information falls back on them.
    let wants_normals = !is_gicp && n > dim && (dim == 3 || tn.is_some());
    let run = || -> scanreg_core::Result<_> {
        let mut source_spacing = f64::NAN;
        let sampled: Option<(Vec<usize>, std::borrow::Cow<'_, [f64]>)> = if !wants_normals {
            None
        } else if let Some((idx, nrm)) = &given {
            Some((idx.clone(), std::borrow::Cow::Borrowed(*nrm)))
        } else if target_spacing.is_some() {
            // One k-d tree and one neighbour search of the source for both.
            let (idx, nrm, spacing) =
                normal_noise::sampled_normals_and_spacing(src, dim, num_neighbors, 1500)?;
            source_spacing = spacing;
            Some((idx, std::borrow::Cow::Owned(nrm)))
        } else {
            let (idx, nrm) = normal_noise::sampled_normals(src, dim, num_neighbors, 1500)?;
            Some((idx, std::borrow::Cow::Owned(nrm)))
        };
        let sampling_scale = match target_spacing {
            Some(target) => {
                if source_spacing.is_nan() && n >= 2 {
                    source_spacing = scene::median_spacing(&KdTree::build(src, dim)?);
                }
                let ratio = if source_spacing.is_finite() && source_spacing > 0.0 {
                    (target / source_spacing).min(1.0)
                } else {
                    1.0
                };
                ratio * ratio
            }
            None => sampling_scale,
        };
        let mut normal_variance = 0.0;
        let mut agreement = None;
        if let (Some((idx, nrm)), Some(tn)) = (&sampled, tn) {
            if !is_p2p {
                let v = normal_noise::correspondence_normal_noise(idx, nrm, tn, &rot, corr, dim)?;
                normal_variance = if v.is_finite() { v } else { 0.0 };
            }
            let input = AgreementInput {
                sample: idx,
                sample_normals: nrm,
                source: src,
                target: tgt,
                target_normals: tn,
                correspondences: corr,
                pose: pm,
                dim,
            };
            let out = normal_agreement::normal_agreement_systems(&input, min_agreement, kernel)?;
            let system = |s: normal_agreement::NormalSystem| System {
                hessian: Mat::from_row_slice(dof, dof, &s.hessian),
                gradient: Vector::from_column_slice(&s.gradient),
                count: s.count,
            };
            agreement = Some((system(out.all), system(out.agreeing)));
        }
        // Scaled as the caller says (the target's sampling density relative to the source's).
        let scaled = |(h, m): ([f64; 9], [f64; 9])| (h, m.map(|v| v * sampling_scale));
        // The target's normal of row `j` (or its covariances' least-spread axis).
        let normal_2d = |j: usize| -> Option<[f64; 2]> {
            match (tn, tc) {
                (Some(nr), _) => (2 * j + 1 < nr.len()).then(|| [nr[2 * j], nr[2 * j + 1]]),
                (None, Some(c)) => {
                    (4 * j + 3 < c.len()).then(|| scene::smallest_axis_2d(&c[4 * j..4 * j + 4]))
                }
                (None, None) => None,
            }
        };
        let has_normals = tn.is_some() || tc.is_some();
        let sampled_surfaces = if dim == 2 && has_normals {
            scene::sampling_system(src, dim, corr, &rot, max_step, normal_2d)
        } else {
            None
        };
        let sampling_system = sampled_surfaces.map(|s| scaled((s.hessian, s.meat)));
        let source_is_cloud = sampled_surfaces
            .as_ref()
            .is_some_and(|s| s.model == scene::SamplingModel::Cloud);
        // 2D point-to-line: the noise the nearest-neighbour association hides, against the
        // target's step along its surfaces (the source's, times how much finer the target
        // samples them).
        let hidden_noise_variance = match (&sampled_surfaces, tn) {
            (Some(s), Some(_)) if method == Method::PointToPlane => {
                association::hidden_noise_variance(
                    src,
                    tgt,
                    corr,
                    pm,
                    s.mean_step * sampling_scale.sqrt(),
                    s.surface_noise,
                    normal_2d,
                )
            }
            _ => 0.0,
        };
        let distortion_system = if dim == 2 && has_normals {
            distortion::distortion_system(
                src,
                tgt,
                corr,
                &rot,
                source_sweep,
                &target_sweeps,
                normal_2d,
            )
        } else {
            None
        };
        // 3D: the sampled normals in full (NaN rows: none) for the plane information.
        let full_normals = match (&sampled, dim) {
            (Some((idx, nrm)), 3) => {
                let mut full = vec![f64::NAN; n * dim];
                for (s, &i) in idx.iter().enumerate() {
                    full[i * dim..(i + 1) * dim].copy_from_slice(&nrm[s * dim..(s + 1) * dim]);
                }
                Some(full)
            }
            _ => None,
        };
        let input = censi::Input {
            source: src,
            source_covariances: sc,
            target: tgt,
            target_normals: tn,
            // Point-to-point in 3D: a covariance-only target gives the plane normals.
            target_covariances: if is_gicp || (is_p2p && dim == 3) {
                tc
            } else {
                None
            },
            correspondences: &corr32,
            source_normals: full_normals.as_deref(),
            target_linear: linear,
        };
        let opts = censi::Options {
            method,
            kernel,
            source_variance: 1.0,
            target_variance: 1.0,
            normal_variance: 1.0,
            block_size,
        };
        let analysis = censi::analyse(&input, pm, dim, &opts)?;
        let sampling_flat = sampling_system.as_ref().map(|(h, m)| (&h[..], &m[..]));
        let distortion_flat = distortion_system.as_ref().map(|(h, g)| (&h[..], &g[..]));
        let input = Input {
            dim,
            method,
            analysis: &analysis,
            hessian,
            sigma2,
            score_outer,
            effective_residuals,
            num_correspondences,
            sum_squared_distances,
            levers,
            normal_noise,
            typical_normal_noise,
            normal_variance,
            held,
            prior,
            drift,
            agreement,
            valley,
            sampling_system: sampling_flat,
            hidden_noise_variance,
            // NaN: measured here, only where it is used (a 2D result without a sampling
            // system): the scan's angular sort is most of the scene pass.
            sampling: match (sampling_system.is_none(), beam_phase_variance.is_nan()) {
                (false, _) => 0.0,
                (true, false) => beam_phase_variance,
                (true, true) => scene::beam_phase_variance(src, dim),
            },
            distortion_system: distortion_flat,
            length_scale,
            chosen,
            motion,
        };
        let out = trust::analyse(&input)?;
        let sampled = sampled.map(|(idx, nrm)| (idx, nrm.into_owned()));
        let overlap = overlap_in
            .as_ref()
            .map(|(tree, max_sq, pose, certificates)| {
                let hints = Some(corr);
                overlap::overlap(*tree, src, pose, *max_sq, *max_sq, hints, *certificates)
                    .map(|o| overlap_tuple(&o))
            })
            .transpose()?;
        Ok((
            out,
            analysis,
            normal_variance,
            sampled,
            source_spacing,
            overlap,
            source_is_cloud,
        ))
    };
    let (out, analysis, normal_variance, sampled, source_spacing, overlap, source_is_cloud) = py
        .detach(|| in_pool_unless_small(n, num_threads, run).and_then(|r| r))
        .map_err(core_err)?;
    let sampled = sampled
        .map(|(idx, nrm)| -> PyResult<_> {
            let count = idx.len();
            let idx: Vec<i64> = idx.into_iter().map(|i| i as i64).collect();
            Ok((
                read_only(idx.into_pyarray(py)),
                read_only(nrm.into_pyarray(py).reshape([count, dim])?),
            ))
        })
        .transpose()?;
    let mut numbers = numbers(
        py,
        &out,
        &analysis,
        normal_variance,
        sampled,
        source_spacing,
    )?;
    numbers.overlap = overlap;
    numbers.source_is_cloud = source_is_cloud;
    numbers.scene = scene_own
        .map(|(own, length, default)| -> PyResult<Scene> {
            let k = dim + own.len();
            Ok((
                read_only(own.into_pyarray(py)),
                length,
                f64::NAN,
                mat(py, &Mat::from_row_slice(k, k, &default))?,
            ))
        })
        .transpose()?;
    Ok(numbers)
}

/// `(levers, length_scale, beam_phase_variance, default_prior)`.
type Scene = (Py<PyArray1<f64>>, f64, f64, Py<PyArray2<f64>>);

/// `(levers, length_scale, beam_phase_variance, default_prior)` of a source cloud; the prior
/// is the gate-wide one for `gate` (`scanreg_core::trust::scene`). `beam_phase=False`: the
/// phase is not measured (NaN; `trust_analysis` measures it where it is used).
#[pyfunction]
#[pyo3(signature = (source, gate, *, beam_phase=true))]
fn trust_scene<'py>(
    py: Python<'py>,
    source: PyReadonlyArray2<'_, f64>,
    gate: f64,
    beam_phase: bool,
) -> PyResult<Scene> {
    let (pts, dim) = points(&source, "source")?;
    if pts.is_empty() {
        return Err(PyValueError::new_err("source: is empty"));
    }
    let levers = scene::rotation_levers(pts, dim);
    let length = scene::length_scale(pts, dim);
    let phase = if beam_phase {
        scene::beam_phase_variance(pts, dim)
    } else {
        f64::NAN
    };
    let dof = dim + levers.len();
    let prior = Mat::from_row_slice(dof, dof, &scene::default_prior(dim, &levers, gate));
    Ok((
        read_only(levers.into_pyarray(py)),
        length,
        phase,
        mat(py, &prior)?,
    ))
}

/// `(H, M)`, each `(3, 3)`.
type SamplingSystem = (Py<PyArray2<f64>>, Py<PyArray2<f64>>);

/// `(H, M)`: the 2D sampling system of the source's beam phase at the final pose, steps up to
/// `max_step`
/// (`scanreg_core::trust::scene::sampling_system`), from the target's normals or, without
/// them, the least-spread axis of its covariances; None in 3D, with neither, or with fewer
/// than 3 matched points.
#[pyfunction]
#[pyo3(signature = (
    source, correspondences, rotation, max_step, *, target_normals=None, target_covariances=None
))]
fn trust_sampling(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    correspondences: PyReadonlyArray1<'_, i64>,
    rotation: PyReadonlyArray2<'_, f64>,
    max_step: f64,
    target_normals: Option<PyReadonlyArray2<'_, f64>>,
    target_covariances: Option<PyReadonlyArray3<'_, f64>>,
) -> PyResult<Option<SamplingSystem>> {
    let (pts, dim) = points(&source, "source")?;
    let corr = c_slice(&correspondences, "correspondences")?;
    if corr.len() * dim != pts.len() {
        return Err(PyValueError::new_err(format!(
            "correspondences: expected {} values (one per source point), got {}",
            pts.len() / dim,
            corr.len()
        )));
    }
    let rot = square_slice(&rotation, "rotation", dim)?;
    if dim != 2 {
        return Ok(None);
    }
    let normals = target_normals
        .as_ref()
        .map(|n| points_dim(n, "target_normals", 2))
        .transpose()?;
    let covs = match &target_covariances {
        Some(c) => covariances(&target_covariances, "target_covariances", c.shape()[0], 2)?,
        None => None,
    };
    let out = match (normals, covs) {
        (Some(n), _) => scene::sampling_system(pts, dim, corr, rot, max_step, |j| {
            (2 * j + 1 < n.len()).then(|| [n[2 * j], n[2 * j + 1]])
        }),
        (None, Some(c)) => scene::sampling_system(pts, dim, corr, rot, max_step, |j| {
            (4 * j + 3 < c.len()).then(|| scene::smallest_axis_2d(&c[4 * j..4 * j + 4]))
        }),
        (None, None) => None,
    };
    out.map(|s| {
        Ok((
            mat(py, &Mat::from_row_slice(3, 3, &s.hessian))?,
            mat(py, &Mat::from_row_slice(3, 3, &s.meat))?,
        ))
    })
    .transpose()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(trust_sampling, m)?)?;
    m.add_class::<TrustNumbers>()?;
    m.add_function(wrap_pyfunction!(trust_numbers, m)?)?;
    m.add_function(wrap_pyfunction!(trust_analysis, m)?)?;
    m.add_function(wrap_pyfunction!(trust_scene, m)?)?;
    Ok(())
}
