//! Bindings for neighbour search and per-point local geometry (`scanreg_core::{knn, normals,
//! outliers, denoise}`).
//!
//! `KdTree` is a frozen (immutable) pyclass: safe to share between Python
//! threads; every query releases the GIL. Other bindings (registration) reach the Rust index
//! through the public `inner` field.

use crate::convert::{core_err, points, points_dim, read_only, rows, vector};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
};
use pyo3::prelude::*;
use scanreg_core::denoise;
use scanreg_core::knn;
use scanreg_core::normals::{self, Regularization};
use scanreg_core::outliers;

type IndexArray = Py<PyArray1<i64>>;
type DistArray = Py<PyArray1<f64>>;
type Rows<T> = Py<PyArray2<T>>;
/// `(constructor, (points,))`: what `pickle` calls to rebuild a tree.
type Reduced<'py> = (Bound<'py, pyo3::types::PyType>, (Rows<f64>,));

/// An immutable k-d tree over `(N, 2)` or `(N, 3)` points. Distances are squared.
#[pyclass(frozen, module = "scanreg._core")]
pub struct KdTree {
    pub inner: knn::KdTree,
}

#[pymethods]
impl KdTree {
    #[new]
    fn new(py: Python<'_>, points_array: PyReadonlyArray2<'_, f64>) -> PyResult<Self> {
        let (data, dim) = points(&points_array, "points")?;
        let inner = py
            .detach(|| knn::KdTree::build(data, dim))
            .map_err(core_err)?;
        Ok(KdTree { inner })
    }

    #[getter]
    fn dim(&self) -> usize {
        self.inner.dim()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// Pickled as its points: the build is deterministic, so the copy is the same tree.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py>> {
        let py = slf.py();
        Ok((slf.get_type(), (slf.get().points(py)?,)))
    }

    /// A read-only copy of the indexed points, `(N, dim)` (what `PreparedTarget.points` keeps).
    #[getter]
    fn points(&self, py: Python<'_>) -> PyResult<Py<PyArray2<f64>>> {
        let arr = rows(py, self.inner.points().to_vec(), self.inner.dim())?;
        Ok(read_only(arr.into_bound(py)))
    }

    /// Nearest neighbour within `max_distance`: `(index (M,), squared_distance (M,))`,
    /// `-1` / `inf` where none.
    #[pyo3(signature = (query_points, max_distance=f64::INFINITY))]
    fn nearest(
        &self,
        py: Python<'_>,
        query_points: PyReadonlyArray2<'_, f64>,
        max_distance: f64,
    ) -> PyResult<(IndexArray, DistArray)> {
        let q = points_dim(&query_points, "query_points", self.inner.dim())?;
        let r = py
            .detach(|| self.inner.nearest_batch(q, max_distance))
            .map_err(core_err)?;
        Ok((
            r.index.into_pyarray(py).unbind(),
            r.squared_distance.into_pyarray(py).unbind(),
        ))
    }

    /// `k` nearest neighbours: `(index (M, k), squared_distance (M, k))`, rows sorted by
    /// (distance, index).
    fn knn(
        &self,
        py: Python<'_>,
        query_points: PyReadonlyArray2<'_, f64>,
        k: usize,
    ) -> PyResult<(Rows<i64>, Rows<f64>)> {
        let q = points_dim(&query_points, "query_points", self.inner.dim())?;
        let (idx, dist) = py.detach(|| self.inner.knn_batch(q, k)).map_err(core_err)?;
        Ok((rows(py, idx, k)?, rows(py, dist, k)?))
    }

    /// All neighbours within `radius`: `(offsets (M+1,), index, squared_distance)`, compressed
    /// rows sorted by (distance, index).
    fn radius(
        &self,
        py: Python<'_>,
        query_points: PyReadonlyArray2<'_, f64>,
        radius: f64,
    ) -> PyResult<(IndexArray, IndexArray, DistArray)> {
        let q = points_dim(&query_points, "query_points", self.inner.dim())?;
        let r = py
            .detach(|| self.inner.radius_batch(q, radius))
            .map_err(core_err)?;
        Ok((
            r.offsets.into_pyarray(py).unbind(),
            r.index.into_pyarray(py).unbind(),
            r.squared_distance.into_pyarray(py).unbind(),
        ))
    }

    /// k-NN PCA of every indexed point: `(normals (N, D) | None, covariances (N, D, D) | None,
    /// valid (N,), linear (N,))`. `regularization=None` skips covariances. `linear` marks the
    /// 3D neighbourhoods that are linear; `drop_linear`: no normal (zero) there (`valid`, a
    /// non-degenerate neighbourhood, unchanged).
    #[pyo3(signature = (k, viewpoint, *, normals=true, regularization=None, epsilon=1e-3, drop_linear=false))]
    #[allow(clippy::type_complexity, clippy::too_many_arguments)]
    fn local_geometry(
        &self,
        py: Python<'_>,
        k: usize,
        viewpoint: PyReadonlyArray1<'_, f64>,
        normals: bool,
        regularization: Option<&str>,
        epsilon: f64,
        drop_linear: bool,
    ) -> PyResult<(
        Option<Py<PyArray2<f64>>>,
        Option<Py<PyArray3<f64>>>,
        Py<PyArray1<bool>>,
        Py<PyArray1<bool>>,
    )> {
        let vp = vector(&viewpoint, "viewpoint")?;
        let reg = regularization
            .map(|name| Regularization::from_name(name, epsilon))
            .transpose()
            .map_err(core_err)?;
        let g = py
            .detach(|| normals::local_geometry_with(&self.inner, k, vp, normals, reg, drop_linear))
            .map_err(core_err)?;
        self.geometry_arrays(py, g)
    }

    /// `local_geometry`, the normals' `(ε̂², ε̃²)` (as `target_normal_noise` of this tree
    /// gives them, read off the same neighbour searches; NaN without normals) and, in 2D, the
    /// points' median spacing (each point's nearest other point from the same searches; NaN in
    /// 3D, where no analysis reads it).
    #[pyo3(signature = (k, viewpoint, *, normals=true, regularization=None, epsilon=1e-3, drop_linear=false))]
    #[allow(clippy::type_complexity, clippy::too_many_arguments)]
    fn local_geometry_noise(
        &self,
        py: Python<'_>,
        k: usize,
        viewpoint: PyReadonlyArray1<'_, f64>,
        normals: bool,
        regularization: Option<&str>,
        epsilon: f64,
        drop_linear: bool,
    ) -> PyResult<(
        Option<Py<PyArray2<f64>>>,
        Option<Py<PyArray3<f64>>>,
        Py<PyArray1<bool>>,
        Py<PyArray1<bool>>,
        (f64, f64),
        f64,
    )> {
        let vp = vector(&viewpoint, "viewpoint")?;
        let reg = regularization
            .map(|name| Regularization::from_name(name, epsilon))
            .transpose()
            .map_err(core_err)?;
        let dim = self.inner.dim();
        let (g, noise, spacing) = py
            .detach(|| -> scanreg_core::Result<_> {
                let g =
                    normals::local_geometry_with(&self.inner, k, vp, normals, reg, drop_linear)?;
                let noise = g.normal_noise(dim).unwrap_or((f64::NAN, f64::NAN));
                let spacing = if dim == 2 {
                    g.spacing(&self.inner)
                } else {
                    f64::NAN
                };
                Ok((g, noise, spacing))
            })
            .map_err(core_err)?;
        let (nrm, cov, valid, linear) = self.geometry_arrays(py, g)?;
        Ok((nrm, cov, valid, linear, noise, spacing))
    }

    /// Statistical outlier removal: `(kept (K,), mean_distance (N,), threshold)`.
    fn statistical_outliers(
        &self,
        py: Python<'_>,
        k: usize,
        std_ratio: f64,
    ) -> PyResult<(IndexArray, DistArray, f64)> {
        let r = py
            .detach(|| outliers::statistical_outliers(&self.inner, k, std_ratio))
            .map_err(core_err)?;
        let kept: Vec<i64> = r.kept.into_iter().map(|i| i as i64).collect();
        Ok((
            kept.into_pyarray(py).unbind(),
            r.mean_distance.into_pyarray(py).unbind(),
            r.threshold,
        ))
    }

    /// Every point projected onto the plane (line in 2D) of its at most `k` nearest points
    /// within `radius`: `(N, D)` in input order (`scanreg_core::denoise`).
    fn project_to_local_planes(
        &self,
        py: Python<'_>,
        k: usize,
        radius: f64,
    ) -> PyResult<Rows<f64>> {
        let out = py
            .detach(|| denoise::project_to_local_planes(&self.inner, k, radius))
            .map_err(core_err)?;
        rows(py, out, self.inner.dim())
    }

    /// Radius outlier removal: kept indices.
    fn radius_outliers(
        &self,
        py: Python<'_>,
        radius: f64,
        min_neighbors: usize,
    ) -> PyResult<IndexArray> {
        let kept = py
            .detach(|| outliers::radius_outliers(&self.inner, radius, min_neighbors))
            .map_err(core_err)?;
        let kept: Vec<i64> = kept.into_iter().map(|i| i as i64).collect();
        Ok(kept.into_pyarray(py).unbind())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<KdTree>()?;
    Ok(())
}

/// `(normals (N, D) | None, covariances (N, D, D) | None, valid (N,), linear (N,))`.
type GeometryArrays = (
    Option<Py<PyArray2<f64>>>,
    Option<Py<PyArray3<f64>>>,
    Py<PyArray1<bool>>,
    Py<PyArray1<bool>>,
);

impl KdTree {
    /// A [`normals::LocalGeometry`] of this tree's points as the arrays `local_geometry` and
    /// `local_geometry_noise` return.
    fn geometry_arrays(
        &self,
        py: Python<'_>,
        g: normals::LocalGeometry,
    ) -> PyResult<GeometryArrays> {
        let dim = self.inner.dim();
        let n = self.inner.len();
        let nrm = g.normals.map(|v| rows(py, v, dim)).transpose()?;
        let cov = g
            .covariances
            .map(|v| -> PyResult<Py<PyArray3<f64>>> {
                Ok(v.into_pyarray(py).reshape([n, dim, dim])?.unbind())
            })
            .transpose()?;
        Ok((
            nrm,
            cov,
            g.valid.into_pyarray(py).unbind(),
            g.linear.into_pyarray(py).unbind(),
        ))
    }
}
