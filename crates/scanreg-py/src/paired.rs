//! Bindings for paired alignment sums (`scanreg_core::paired`).

use crate::convert::{core_err, points, points_dim, pose, vector};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::paired::{self, Objective};
use scanreg_core::Kernel;

/// Weighted centroids and centred cross-covariance of paired points.
#[pyclass(frozen, module = "scanreg._core")]
pub struct Moments {
    #[pyo3(get)]
    weight_sum: f64,
    #[pyo3(get)]
    source_mean: Py<PyArray1<f64>>,
    #[pyo3(get)]
    target_mean: Py<PyArray1<f64>>,
    #[pyo3(get)]
    cross_covariance: Py<PyArray2<f64>>,
    #[pyo3(get)]
    source_spread: f64,
    #[pyo3(get)]
    target_spread: f64,
}

/// Gauss–Newton normal equations of paired residuals at one pose.
#[pyclass(frozen, module = "scanreg._core")]
pub struct Linearization {
    #[pyo3(get)]
    hessian: Py<PyArray2<f64>>,
    #[pyo3(get)]
    gradient: Py<PyArray1<f64>>,
    #[pyo3(get)]
    score_outer: Py<PyArray2<f64>>,
    #[pyo3(get)]
    robust_cost: f64,
    #[pyo3(get)]
    weighted_sum_squares: f64,
    #[pyo3(get)]
    irls_sum_squares: f64,
    #[pyo3(get)]
    irls_weight_sum: f64,
    #[pyo3(get)]
    residuals: Py<PyArray1<f64>>,
    #[pyo3(get)]
    kernel_weights: Py<PyArray1<f64>>,
}

fn square(py: Python<'_>, flat: Vec<f64>, n: usize) -> PyResult<Py<PyArray2<f64>>> {
    let arr = flat.into_pyarray(py).reshape([n, n])?;
    Ok(arr.unbind())
}

#[pyfunction]
#[pyo3(signature = (source, target, weights=None))]
fn paired_moments(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    weights: Option<PyReadonlyArray1<'_, f64>>,
) -> PyResult<Moments> {
    let (src, dim) = points(&source, "source")?;
    let tgt = points_dim(&target, "target", dim)?;
    let w = weights.as_ref().map(|w| vector(w, "weights")).transpose()?;
    let m = py
        .detach(|| paired::paired_moments(src, tgt, dim, w))
        .map_err(core_err)?;
    Ok(Moments {
        weight_sum: m.weight_sum,
        source_mean: m.source_mean.into_pyarray(py).unbind(),
        target_mean: m.target_mean.into_pyarray(py).unbind(),
        cross_covariance: square(py, m.cross_covariance, dim)?,
        source_spread: m.source_spread,
        target_spread: m.target_spread,
    })
}

#[pyfunction]
#[pyo3(signature = (source, target, pose_matrix, *, objective, kernel, kernel_scale, weights=None, target_normals=None))]
#[allow(clippy::too_many_arguments)]
fn linearize_paired(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    objective: &str,
    kernel: &str,
    kernel_scale: f64,
    weights: Option<PyReadonlyArray1<'_, f64>>,
    target_normals: Option<PyReadonlyArray2<'_, f64>>,
) -> PyResult<Linearization> {
    let (src, dim) = points(&source, "source")?;
    let tgt = points_dim(&target, "target", dim)?;
    let pose_flat = pose(&pose_matrix, "pose_matrix", dim)?;
    let w = weights.as_ref().map(|w| vector(w, "weights")).transpose()?;
    let nrm = target_normals
        .as_ref()
        .map(|n| points_dim(n, "target_normals", dim))
        .transpose()?;
    let objective = match objective {
        "point_to_point" => Objective::PointToPoint,
        "point_to_plane" => Objective::PointToPlane,
        other => {
            return Err(PyValueError::new_err(format!(
                "objective: unknown {other:?}; expected 'point_to_point' or 'point_to_plane'"
            )))
        }
    };
    let kernel = Kernel::from_name(kernel, kernel_scale).map_err(core_err)?;
    let lin = py
        .detach(|| paired::linearize_paired(src, tgt, nrm, dim, pose_flat, w, objective, kernel))
        .map_err(core_err)?;
    let dof = lin.gradient.len();
    Ok(Linearization {
        hessian: square(py, lin.hessian, dof)?,
        gradient: lin.gradient.into_pyarray(py).unbind(),
        score_outer: square(py, lin.score_outer, dof)?,
        robust_cost: lin.robust_cost,
        weighted_sum_squares: lin.weighted_sum_squares,
        irls_sum_squares: lin.irls_sum_squares,
        irls_weight_sum: lin.irls_weight_sum,
        residuals: lin.residuals.into_pyarray(py).unbind(),
        kernel_weights: lin.kernel_weights.into_pyarray(py).unbind(),
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Moments>()?;
    m.add_class::<Linearization>()?;
    m.add_function(wrap_pyfunction!(paired_moments, m)?)?;
    m.add_function(wrap_pyfunction!(linearize_paired, m)?)?;
    Ok(())
}
