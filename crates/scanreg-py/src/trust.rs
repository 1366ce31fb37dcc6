//! Binding of `scanreg_core::trust`: the per-result trust arithmetic in one call, and the
//! per-point scene quantities it reads. Converts and validates only.

use crate::censi::CensiAnalysis;
use crate::convert::{c_slice, core_err, covariances, points, points_dim, read_only};
use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::icp::Method;
use scanreg_core::trust::dense::{flat, Mat, Vector};
use scanreg_core::trust::{self, scene, shift::System, Held, Input, Kind};

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
    valley=None, sampling_system=None, sampling=0.0, held=None
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
        length_scale,
        chosen: Kind::from_name(covariance).map_err(core_err)?,
        motion: c_slice(&motion, "motion")?,
    };
    let out = trust::analyse(&input).map_err(core_err)?;
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
    })
}

/// `(levers, length_scale, beam_phase_variance, default_prior)`.
type Scene = (Py<PyArray1<f64>>, f64, f64, Py<PyArray2<f64>>);

/// `(levers, length_scale, beam_phase_variance, default_prior)` of a source cloud; the prior
/// is the gate-wide one for `gate` (`scanreg_core::trust::scene`).
#[pyfunction]
#[pyo3(signature = (source, gate))]
fn trust_scene<'py>(
    py: Python<'py>,
    source: PyReadonlyArray2<'_, f64>,
    gate: f64,
) -> PyResult<Scene> {
    let (pts, dim) = points(&source, "source")?;
    if pts.is_empty() {
        return Err(PyValueError::new_err("source: is empty"));
    }
    let levers = scene::rotation_levers(pts, dim);
    let length = scene::length_scale(pts, dim);
    let phase = scene::beam_phase_variance(pts, dim);
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
    out.map(|(h, m)| {
        Ok((
            mat(py, &Mat::from_row_slice(3, 3, &h))?,
            mat(py, &Mat::from_row_slice(3, 3, &m))?,
        ))
    })
    .transpose()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(trust_sampling, m)?)?;
    m.add_class::<TrustNumbers>()?;
    m.add_function(wrap_pyfunction!(trust_numbers, m)?)?;
    m.add_function(wrap_pyfunction!(trust_scene, m)?)?;
    Ok(())
}
