//! Binding of `scanreg_core::censi`: the per-point sums behind Censi's closed-form covariance,
//! the block-score sandwich and the plane information, at one pose.

use crate::convert::{
    c_slice, core_err, covariances, in_pool_unless_small, points_dim, pose, square,
};
use numpy::{PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::censi::{self, Input, Options, NONE};
use scanreg_core::icp::Method;
use scanreg_core::Kernel;

#[pyclass(frozen, module = "scanreg._core")]
pub struct CensiAnalysis {
    #[pyo3(get)]
    hessian: Py<PyArray2<f64>>,
    #[pyo3(get)]
    censi_meat: Py<PyArray2<f64>>,
    #[pyo3(get)]
    source_meat: Py<PyArray2<f64>>,
    #[pyo3(get)]
    target_meat: Py<PyArray2<f64>>,
    #[pyo3(get)]
    normal_meat: Py<PyArray2<f64>>,
    #[pyo3(get)]
    plane_sum_squares: f64,
    #[pyo3(get)]
    determined_plane_sum_squares: f64,
    #[pyo3(get)]
    block_meat: Py<PyArray2<f64>>,
    #[pyo3(get)]
    num_blocks: usize,
    #[pyo3(get)]
    determined_block_meat: Py<PyArray2<f64>>,
    #[pyo3(get)]
    num_determined_blocks: usize,
    #[pyo3(get)]
    plane_information: Py<PyArray2<f64>>,
    #[pyo3(get)]
    num_plane_correspondences: usize,
    #[pyo3(get)]
    num_determined_correspondences: usize,
    #[pyo3(get)]
    linear_known: bool,
    #[pyo3(get)]
    num_correspondences: usize,
    #[pyo3(get)]
    plane_noise_information: Py<PyArray2<f64>>,
    #[pyo3(get)]
    normal_disagreement: f64,
    #[pyo3(get)]
    num_normal_pairs: usize,
    #[pyo3(get)]
    score: Py<PyArray1<f64>>,
    #[pyo3(get)]
    determined_hessian: Py<PyArray2<f64>>,
    #[pyo3(get)]
    determined_score: Py<PyArray1<f64>>,
    #[pyo3(get)]
    num_determined_pairs: usize,
    /// The same sums for `trust_numbers`, without a round trip through numpy.
    pub(crate) inner: censi::Analysis,
}

#[pyfunction]
#[pyo3(signature = (
    source, target, pose_matrix, correspondences, *, method, kernel, kernel_scale,
    source_variance, target_variance, block_size, normal_variance=0.0, target_normals=None, source_covariances=None,
    target_covariances=None, num_threads=None, source_normals=None, target_linear=None
))]
#[allow(clippy::too_many_arguments)]
fn censi_analysis(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    correspondences: PyReadonlyArray1<'_, i64>,
    method: &str,
    kernel: &str,
    kernel_scale: f64,
    source_variance: f64,
    target_variance: f64,
    block_size: f64,
    normal_variance: f64,
    target_normals: Option<PyReadonlyArray2<'_, f64>>,
    source_covariances: Option<PyReadonlyArray3<'_, f64>>,
    target_covariances: Option<PyReadonlyArray3<'_, f64>>,
    num_threads: Option<usize>,
    source_normals: Option<PyReadonlyArray2<'_, f64>>,
    target_linear: Option<PyReadonlyArray1<'_, bool>>,
) -> PyResult<CensiAnalysis> {
    let (src, dim) = crate::convert::points(&source, "source")?;
    let tgt = points_dim(&target, "target", dim)?;
    let pm = pose(&pose_matrix, "pose_matrix", dim)?;
    let n = src.len() / dim;
    let m = tgt.len() / dim;
    let corr: Vec<u32> = c_slice(&correspondences, "correspondences")?
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
    let nrm = target_normals
        .as_ref()
        .map(|a| points_dim(a, "target_normals", dim))
        .transpose()?;
    // NaN rows mark points without a normal: not the finite check `points_dim` makes.
    let src_nrm = source_normals
        .as_ref()
        .map(|a| c_slice(a, "source_normals"))
        .transpose()?;
    let linear = target_linear
        .as_ref()
        .map(|a| c_slice(a, "target_linear"))
        .transpose()?;
    let input = Input {
        source: src,
        source_covariances: covariances(&source_covariances, "source_covariances", n, dim)?,
        target: tgt,
        target_normals: nrm,
        target_covariances: covariances(&target_covariances, "target_covariances", m, dim)?,
        correspondences: &corr,
        source_normals: src_nrm,
        target_linear: linear,
    };
    let opts = Options {
        method: Method::from_name(method).map_err(core_err)?,
        kernel: Kernel::from_name(kernel, kernel_scale).map_err(core_err)?,
        source_variance,
        target_variance,
        normal_variance,
        block_size,
    };
    let out = py
        .detach(|| {
            in_pool_unless_small(n, num_threads, || censi::analyse(&input, pm, dim, &opts))
                .and_then(|r| r)
        })
        .map_err(core_err)?;
    let dof = if dim == 2 { 3 } else { 6 };
    Ok(CensiAnalysis {
        hessian: square(py, out.hessian.clone(), dof)?,
        censi_meat: square(py, out.censi_meat.clone(), dof)?,
        source_meat: square(py, out.source_meat.clone(), dof)?,
        target_meat: square(py, out.target_meat.clone(), dof)?,
        normal_meat: square(py, out.normal_meat.clone(), dof)?,
        plane_sum_squares: out.plane_sum_squares,
        determined_plane_sum_squares: out.determined_plane_sum_squares,
        block_meat: square(py, out.block_meat.clone(), dof)?,
        num_blocks: out.num_blocks,
        determined_block_meat: square(py, out.determined_block_meat.clone(), dof)?,
        num_determined_blocks: out.num_determined_blocks,
        plane_information: square(py, out.plane_information.clone(), dof)?,
        num_plane_correspondences: out.num_plane_correspondences,
        num_determined_correspondences: out.num_determined_correspondences,
        linear_known: out.linear_known,
        num_correspondences: out.num_correspondences,
        plane_noise_information: square(py, out.plane_noise_information.clone(), dof)?,
        normal_disagreement: out.normal_disagreement,
        num_normal_pairs: out.num_normal_pairs,
        score: PyArray1::from_vec(py, out.score.clone()).unbind(),
        determined_hessian: square(py, out.determined_hessian.clone(), dof)?,
        determined_score: PyArray1::from_vec(py, out.determined_score.clone()).unbind(),
        num_determined_pairs: out.num_determined_pairs,
        inner: out,
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<CensiAnalysis>()?;
    m.add_function(wrap_pyfunction!(censi_analysis, m)?)?;
    Ok(())
}
