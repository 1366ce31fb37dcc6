//! Bindings for the 2D Normal Distributions Transform (`scanreg_core::ndt2d`).

use crate::convert::{core_err, points_dim};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::ndt2d;

/// The four shifted NDT grids of a reference (immutable; evaluation releases the GIL).
#[pyclass(frozen, module = "scanreg._core")]
pub struct NdtGrid {
    inner: ndt2d::NdtGrid,
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
impl NdtGrid {
    #[new]
    #[pyo3(signature = (reference, cell_size, min_points, min_eigen_ratio))]
    fn new(
        py: Python<'_>,
        reference: PyReadonlyArray2<'_, f64>,
        cell_size: f64,
        min_points: usize,
        min_eigen_ratio: f64,
    ) -> PyResult<Self> {
        let data = points_dim(&reference, "reference", 2)?;
        let inner = py
            .detach(|| ndt2d::NdtGrid::build(data, cell_size, min_points, min_eigen_ratio))
            .map_err(core_err)?;
        Ok(NdtGrid { inner })
    }

    #[getter]
    fn cell_size(&self) -> f64 {
        self.inner.cell_size()
    }

    /// Cells with a Gaussian in each of the four shifted grids.
    #[getter]
    fn num_cells(&self) -> (usize, usize, usize, usize) {
        let n = self.inner.num_cells();
        (n[0], n[1], n[2], n[3])
    }

    /// Means `(K, 2)` and covariances `(K, 2, 2)` of grid `g` (0..4).
    fn cells(&self, py: Python<'_>, g: usize) -> PyResult<Cells> {
        if g >= 4 {
            return Err(PyValueError::new_err(format!("g: expected 0..4, got {g}")));
        }
        let cells = self.inner.cells(g);
        let k = cells.len();
        let means: Vec<f64> = cells.iter().flat_map(|c| c.mean).collect();
        let covs: Vec<f64> = cells.iter().flat_map(|c| c.covariance).collect();
        Ok((
            means.into_pyarray(py).reshape([k, 2])?.unbind(),
            covs.into_pyarray(py).reshape([k, 2, 2])?.unbind(),
        ))
    }

    /// `(cost, gradient (3,), hessian (3, 3), information (3, 3), num_matched)` of `source` at
    /// `[tx, ty, φ]`.
    fn evaluate(
        &self,
        py: Python<'_>,
        source: PyReadonlyArray2<'_, f64>,
        pose: (f64, f64, f64),
    ) -> PyResult<Evaluation> {
        let data = points_dim(&source, "source", 2)?;
        let ev = py
            .detach(|| self.inner.evaluate(data, [pose.0, pose.1, pose.2]))
            .map_err(core_err)?;
        Ok((
            ev.cost,
            ev.gradient.to_vec().into_pyarray(py).unbind(),
            ev.hessian
                .to_vec()
                .into_pyarray(py)
                .reshape([3, 3])?
                .unbind(),
            ev.information
                .to_vec()
                .into_pyarray(py)
                .reshape([3, 3])?
                .unbind(),
            ev.num_matched,
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<NdtGrid>()?;
    Ok(())
}
