//! Binding of `scanreg_core::keyframe_map::KeyframeMap`: `Odometry2D`'s local map, updated
//! per keyframe (module docs of the core).

use crate::convert::{core_err, points_dim, read_only, rows, vector};
use crate::knn::KdTree;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use scanreg_core::keyframe_map;

/// `(tree, normals (M, dim), valid (M,), (ε̂², ε̃²), spacing, num_updated)` after an insert.
type Inserted = (
    Py<KdTree>,
    Py<PyArray2<f64>>,
    Py<PyArray1<bool>>,
    (f64, f64),
    f64,
    usize,
);

/// The last `max_keyframes` keyframes voxel-downsampled into one map, with normals recomputed
/// only where a keyframe changed the map. Mutable: one owner (the odometry) updates it.
#[pyclass(module = "scanreg._core")]
pub struct KeyframeMap {
    inner: keyframe_map::KeyframeMap,
}

#[pymethods]
impl KeyframeMap {
    #[new]
    fn new(
        dim: usize,
        voxel_size: f64,
        num_neighbors: usize,
        max_keyframes: usize,
        viewpoint: PyReadonlyArray1<'_, f64>,
    ) -> PyResult<Self> {
        let vp = vector(&viewpoint, "viewpoint")?;
        let inner =
            keyframe_map::KeyframeMap::new(dim, voxel_size, num_neighbors, max_keyframes, vp)
                .map_err(core_err)?;
        Ok(KeyframeMap { inner })
    }

    #[getter]
    fn dim(&self) -> usize {
        self.inner.dim()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    #[getter]
    fn num_keyframes(&self) -> usize {
        self.inner.num_keyframes()
    }

    /// Add a keyframe's `(N, dim)` world-frame points (dropping the oldest keyframe when the
    /// window is full): `(tree over the map, normals, valid, normal noise (as
    /// `target_normal_noise` of the two), median nearest-neighbour spacing, voxels whose normal
    /// was computed)`.
    fn insert(
        &mut self,
        py: Python<'_>,
        points_array: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<Inserted> {
        let dim = self.inner.dim();
        let data = points_dim(&points_array, "points", dim)?;
        let inner = &mut self.inner;
        let state = py.detach(|| inner.insert(data)).map_err(core_err)?;
        let normals = rows(py, state.normals, dim)?;
        let valid = state.valid.into_pyarray(py);
        Ok((
            Py::new(py, KdTree { inner: state.tree })?,
            read_only(normals.into_bound(py)),
            read_only(valid),
            state.normal_noise,
            state.spacing,
            state.num_updated,
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<KeyframeMap>()?;
    Ok(())
}
