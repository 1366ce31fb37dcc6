//! Bindings for correlative scan matching (`scanreg_core::correlative`).

use crate::convert::{core_err, points_dim};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::correlative::{self, LikelihoodGrid, Window};

/// A reference scan or map rasterised once (likelihood, distance, max-pooled levels).
/// Not frozen: [`CorrelativeGrid::update`] changes it in place.
#[pyclass(module = "scanreg._core")]
pub struct CorrelativeGrid {
    inner: LikelihoodGrid,
}

/// The answer of one correlative search.
#[pyclass(frozen, module = "scanreg._core")]
pub struct CorrelativeMatch {
    #[pyo3(get)]
    pose: Py<PyArray1<f64>>,
    #[pyo3(get)]
    index: (i64, i64, i64),
    #[pyo3(get)]
    sum: f64,
    #[pyo3(get)]
    score: f64,
    #[pyo3(get)]
    fitness: f64,
    #[pyo3(get)]
    covariance: Py<PyArray2<f64>>,
    #[pyo3(get)]
    mean: Py<PyArray1<f64>>,
    #[pyo3(get)]
    evaluated: u64,
    #[pyo3(get)]
    bounds: u64,
    #[pyo3(get)]
    covariance_candidates: u64,
}

fn grid_array(
    py: Python<'_>,
    data: Vec<f32>,
    shape: (usize, usize),
) -> PyResult<Py<PyArray2<f32>>> {
    Ok(data.into_pyarray(py).reshape([shape.1, shape.0])?.unbind())
}

impl CorrelativeGrid {
    /// The core's grid (the wrong-basin probe's restart call searches it).
    pub(crate) fn inner(&self) -> &LikelihoodGrid {
        &self.inner
    }
}

#[pymethods]
impl CorrelativeGrid {
    #[new]
    #[pyo3(signature = (reference, resolution, sigma, levels))]
    fn new(
        py: Python<'_>,
        reference: PyReadonlyArray2<'_, f64>,
        resolution: f64,
        sigma: f64,
        levels: usize,
    ) -> PyResult<Self> {
        let data = points_dim(&reference, "reference", 2)?;
        let inner = py
            .detach(|| LikelihoodGrid::build(data, resolution, sigma, levels))
            .map_err(core_err)?;
        Ok(CorrelativeGrid { inner })
    }

    /// The grid of `reference` (what `CorrelativeGrid(reference, ...)` with this grid's
    /// settings builds, to the bit), computed from this one: only the cells near occupied
    /// cells that changed are rasterised again.
    fn updated(&self, py: Python<'_>, reference: PyReadonlyArray2<'_, f64>) -> PyResult<Self> {
        let data = points_dim(&reference, "reference", 2)?;
        let inner = py.detach(|| self.inner.updated(data)).map_err(core_err)?;
        Ok(CorrelativeGrid { inner })
    }

    /// This grid made the grid of `reference` in place (what `updated` returns, without
    /// copying the rasters first); unchanged on an error.
    fn update(&mut self, py: Python<'_>, reference: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        let data = points_dim(&reference, "reference", 2)?;
        let inner = &mut self.inner;
        py.detach(|| inner.update(data)).map_err(core_err)
    }

    #[getter]
    fn origin(&self) -> (f64, f64) {
        let o = self.inner.origin();
        (o[0], o[1])
    }
    #[getter]
    fn resolution(&self) -> f64 {
        self.inner.resolution()
    }
    #[getter]
    fn sigma(&self) -> f64 {
        self.inner.sigma()
    }
    /// `(width, height)` in cells.
    #[getter]
    fn shape(&self) -> (usize, usize) {
        self.inner.shape()
    }
    #[getter]
    fn levels(&self) -> usize {
        self.inner.levels()
    }
    /// The likelihood, `(height, width)` float32 (row = y).
    #[getter]
    fn likelihood(&self, py: Python<'_>) -> PyResult<Py<PyArray2<f32>>> {
        grid_array(py, self.inner.likelihood(), self.inner.shape())
    }
    /// Squared distance to the nearest occupied cell, cells², `(height, width)` float32; +inf
    /// beyond the likelihood's support (where it is 0 in float32: about 14σ).
    #[getter]
    fn distance_squared(&self, py: Python<'_>) -> PyResult<Py<PyArray2<f32>>> {
        grid_array(py, self.inner.dist2(), self.inner.shape())
    }

    /// Search `(2nx+1)(2ny+1)(2ntheta+1)` candidates around `center` = `[x, y, θ]`;
    /// `penalty`: the motion cost's information matrix over `[x, y, θ]` offsets (row-major 9).
    /// `min_score` (branch and bound only): `None` when no candidate scores that much.
    #[pyo3(signature = (source, center, nx, ny, ntheta, angular_step, method, covariance_radius, penalty=None, min_score=None))]
    #[allow(clippy::too_many_arguments)]
    fn search(
        &self,
        py: Python<'_>,
        source: PyReadonlyArray2<'_, f64>,
        center: (f64, f64, f64),
        nx: i64,
        ny: i64,
        ntheta: i64,
        angular_step: f64,
        method: &str,
        covariance_radius: i64,
        penalty: Option<[f64; 9]>,
        min_score: Option<f64>,
    ) -> PyResult<Option<CorrelativeMatch>> {
        let data = points_dim(&source, "source", 2)?;
        let window = Window {
            center: [center.0, center.1, center.2],
            nx,
            ny,
            ntheta,
            angular_step,
            penalty,
        };
        let found = match (method, min_score) {
            ("exhaustive", None) => {
                py.detach(|| correlative::match_exhaustive(&self.inner, data, &window).map(Some))
            }
            ("exhaustive", Some(_)) => {
                return Err(PyValueError::new_err(
                    "min_score: only the branch_and_bound search prunes with it",
                ))
            }
            ("branch_and_bound", None) => py.detach(|| {
                correlative::match_branch_and_bound(&self.inner, data, &window, covariance_radius)
                    .map(Some)
            }),
            ("branch_and_bound", Some(floor)) => py.detach(|| {
                correlative::match_branch_and_bound_above(
                    &self.inner,
                    data,
                    &window,
                    covariance_radius,
                    floor,
                )
            }),
            (other, _) => {
                return Err(PyValueError::new_err(format!(
                    "method: unknown {other:?}; expected 'exhaustive' or 'branch_and_bound'"
                )))
            }
        }
        .map_err(core_err)?;
        let Some(m) = found else {
            return Ok(None);
        };
        Ok(Some(CorrelativeMatch {
            pose: m.pose.to_vec().into_pyarray(py).unbind(),
            index: (m.index[0], m.index[1], m.index[2]),
            sum: m.sum,
            score: m.score,
            fitness: m.fitness,
            covariance: m
                .covariance
                .to_vec()
                .into_pyarray(py)
                .reshape([3, 3])?
                .unbind(),
            mean: m.mean.to_vec().into_pyarray(py).unbind(),
            evaluated: m.evaluated,
            bounds: m.bounds,
            covariance_candidates: m.covariance_candidates,
        }))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<CorrelativeGrid>()?;
    m.add_class::<CorrelativeMatch>()?;
    Ok(())
}
