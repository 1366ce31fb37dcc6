//! Bindings for point-cloud reduction (`scanreg_core::downsample`).

use crate::convert::{core_err, points, vector};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::downsample::{self, VoxelMethod};

type IndexArray = Py<PyArray1<i64>>;

fn indices(py: Python<'_>, idx: Vec<usize>) -> IndexArray {
    let v: Vec<i64> = idx.into_iter().map(|i| i as i64).collect();
    v.into_pyarray(py).unbind()
}

/// `(points (M, D), index (M,), count (M,))`, one row per occupied voxel.
#[pyfunction]
#[pyo3(signature = (points_array, voxel_size, method))]
fn voxel_downsample(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    voxel_size: f64,
    method: &str,
) -> PyResult<(Py<PyArray2<f64>>, IndexArray, IndexArray)> {
    let (data, dim) = points(&points_array, "points")?;
    let method = match method {
        "centroid" => VoxelMethod::Centroid,
        "first" => VoxelMethod::First,
        other => {
            return Err(PyValueError::new_err(format!(
                "method: unknown {other:?}; expected 'centroid' or 'first'"
            )))
        }
    };
    let g = py
        .detach(|| downsample::voxel_downsample(data, dim, voxel_size, method))
        .map_err(core_err)?;
    let m = g.index.len();
    Ok((
        g.points.into_pyarray(py).reshape([m, dim])?.unbind(),
        g.index.into_pyarray(py).unbind(),
        g.count.into_pyarray(py).unbind(),
    ))
}

/// `count` sorted distinct indices of `0..n`, seeded.
#[pyfunction]
fn random_subsample_indices(
    py: Python<'_>,
    n: usize,
    count: usize,
    seed: u64,
) -> PyResult<IndexArray> {
    let idx = py
        .detach(|| downsample::random_subsample_indices(n, count, seed))
        .map_err(core_err)?;
    Ok(indices(py, idx))
}

#[pyfunction]
fn crop_range(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    min_distance: f64,
    max_distance: f64,
) -> PyResult<IndexArray> {
    let (data, dim) = points(&points_array, "points")?;
    let idx = py
        .detach(|| downsample::crop_range(data, dim, min_distance, max_distance))
        .map_err(core_err)?;
    Ok(indices(py, idx))
}

#[pyfunction]
fn crop_box(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    min_corner: PyReadonlyArray1<'_, f64>,
    max_corner: PyReadonlyArray1<'_, f64>,
) -> PyResult<IndexArray> {
    let (data, dim) = points(&points_array, "points")?;
    let lo = vector(&min_corner, "min_corner")?;
    let hi = vector(&max_corner, "max_corner")?;
    let idx = py
        .detach(|| downsample::crop_box(data, dim, lo, hi))
        .map_err(core_err)?;
    Ok(indices(py, idx))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(voxel_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(random_subsample_indices, m)?)?;
    m.add_function(wrap_pyfunction!(crop_range, m)?)?;
    m.add_function(wrap_pyfunction!(crop_box, m)?)?;
    Ok(())
}
