//! Bindings for the 3D Normal Distributions Transform (`scanreg_core::ndt3d`).

use crate::convert::{core_err, points_dim, pose, rows, square};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use scanreg_core::ndt3d;

/// The voxel Gaussians of a 3D target (immutable; evaluation releases the GIL).
#[pyclass(frozen, module = "scanreg._core")]
pub struct NdtGrid3 {
    inner: ndt3d::NdtGrid3,
}

type Cells = (Py<PyArray2<f64>>, Py<numpy::PyArray3<f64>>);
type Evaluation = (
    f64,
    Py<PyArray1<f64>>,
    Py<PyArray2<f64>>,
    Py<PyArray2<f64>>,
    usize,
);

#[pymethods]
impl NdtGrid3 {
    #[new]
    #[pyo3(signature = (target, cell_size, min_points, min_eigen_ratio))]
    fn new(
        py: Python<'_>,
        target: PyReadonlyArray2<'_, f64>,
        cell_size: f64,
        min_points: usize,
        min_eigen_ratio: f64,
    ) -> PyResult<Self> {
        let data = points_dim(&target, "target", 3)?;
        let inner = py
            .detach(|| ndt3d::NdtGrid3::build(data, cell_size, min_points, min_eigen_ratio))
            .map_err(core_err)?;
        Ok(NdtGrid3 { inner })
    }

    #[getter]
    fn cell_size(&self) -> f64 {
        self.inner.cell_size()
    }

    #[getter]
    fn num_cells(&self) -> usize {
        self.inner.num_cells()
    }

    /// Means `(K, 3)` and covariances `(K, 3, 3)` of every voxel Gaussian, in key order.
    fn cells(&self, py: Python<'_>) -> PyResult<Cells> {
        let cells = self.inner.cells();
        let k = cells.len();
        let means: Vec<f64> = cells.iter().flat_map(|c| c.mean).collect();
        let covs: Vec<f64> = cells.iter().flat_map(|c| c.covariance).collect();
        Ok((
            rows(py, means, 3)?,
            covs.into_pyarray(py).reshape([k, 3, 3])?.unbind(),
        ))
    }

    /// `(cost, gradient (6,), hessian (6, 6), information (6, 6), num_matched)` of `source` at
    /// `pose` (4×4), over the right-perturbation tangent `[ρ, φ]`.
    fn evaluate(
        &self,
        py: Python<'_>,
        source: PyReadonlyArray2<'_, f64>,
        pose_matrix: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<Evaluation> {
        let data = points_dim(&source, "source", 3)?;
        let m = pose(&pose_matrix, "pose", 3)?;
        let ev = py
            .detach(|| self.inner.evaluate(data, m))
            .map_err(core_err)?;
        Ok((
            ev.cost,
            ev.gradient.to_vec().into_pyarray(py).unbind(),
            square(py, ev.hessian.to_vec(), 6)?,
            square(py, ev.information.to_vec(), 6)?,
            ev.num_matched,
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<NdtGrid3>()?;
    Ok(())
}
