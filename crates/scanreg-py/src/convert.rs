//! Array conversion and validation shared by every binding.

use crate::knn::KdTree;
use crate::local_map::LocalMap;
use numpy::ndarray::{Array2, Dimension};
use numpy::{Element, IntoPyArray, PyArray, PyArray2, PyReadonlyArray};
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use scanreg_core::icp::NeighborSearch;
use scanreg_core::reduce::SEQUENTIAL_MAX;
use scanreg_core::threads::in_pool;
use scanreg_core::voxel_map::VoxelMap;
use std::sync::RwLockReadGuard;

/// Map a core error to `ValueError` (its message already names the argument).
pub fn core_err(e: scanreg_core::Error) -> PyErr {
    PyValueError::new_err(e.to_string())
}

fn not_contiguous(name: &str) -> PyErr {
    PyValueError::new_err(format!(
        "{name}: array is not C-contiguous; pass numpy.ascontiguousarray({name})"
    ))
}

/// The data of a C-contiguous array. numpy's `as_slice` also accepts Fortran order, whose
/// flat layout is transposed, so C order is checked explicitly.
pub fn c_slice<'a, T: Element, D: numpy::ndarray::Dimension>(
    arr: &'a PyReadonlyArray<'_, T, D>,
    name: &str,
) -> PyResult<&'a [T]> {
    if !arr.is_c_contiguous() {
        return Err(not_contiguous(name));
    }
    arr.as_slice().map_err(|_| not_contiguous(name))
}

/// A `(N, 2)` or `(N, 3)` float64 C-contiguous array as a flat slice and its dimension.
pub fn points<'a>(arr: &'a PyReadonlyArray2<'_, f64>, name: &str) -> PyResult<(&'a [f64], usize)> {
    let shape = arr.shape();
    if shape[1] != 2 && shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (N, 2) or (N, 3), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    Ok((c_slice(arr, name)?, shape[1]))
}

/// Points that must have dimension `dim`.
pub fn points_dim<'a>(
    arr: &'a PyReadonlyArray2<'_, f64>,
    name: &str,
    dim: usize,
) -> PyResult<&'a [f64]> {
    let (data, d) = points(arr, name)?;
    if d != dim {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (N, {dim}) to match the other points, got ({}, {d})",
            arr.shape()[0]
        )));
    }
    Ok(data)
}

/// A 1-D float64 C-contiguous array as a slice.
pub fn vector<'a>(arr: &'a PyReadonlyArray1<'_, f64>, name: &str) -> PyResult<&'a [f64]> {
    c_slice(arr, name)
}

/// A square homogeneous pose of size `(dim+1, dim+1)` as a row-major slice.
pub fn pose<'a>(arr: &'a PyReadonlyArray2<'_, f64>, name: &str, dim: usize) -> PyResult<&'a [f64]> {
    let shape = arr.shape();
    if shape[0] != dim + 1 || shape[1] != dim + 1 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected a ({0}, {0}) homogeneous matrix, got ({1}, {2})",
            dim + 1,
            shape[0],
            shape[1]
        )));
    }
    c_slice(arr, name)
}

/// Row-major `flat` as an `(len / cols, cols)` numpy array, made in its shape: a reshape
/// would wrap a second (writable) array object around the first.
pub fn rows<T: Element>(py: Python<'_>, flat: Vec<T>, cols: usize) -> PyResult<Py<PyArray2<T>>> {
    let n = flat.len().checked_div(cols).unwrap_or(0);
    let arr = Array2::from_shape_vec((n, cols), flat)
        .map_err(|e| PyValueError::new_err(format!("internal: {e}")))?;
    Ok(arr.into_pyarray(py).unbind())
}

/// A row-major `n x n` matrix as a numpy array.
pub fn square(py: Python<'_>, flat: Vec<f64>, n: usize) -> PyResult<Py<PyArray2<f64>>> {
    rows(py, flat, n)
}

/// `arr` (freshly made, referenced nowhere else) marked read-only, as the Python side keeps
/// results: one Python call less per array.
pub fn read_only<T: Element, D: Dimension>(arr: Bound<'_, PyArray<T, D>>) -> Py<PyArray<T, D>> {
    // SAFETY: `arr` is a fresh array this binding made and nothing else references yet (no
    // borrow, no view): clearing its WRITEABLE flag directly is what `make_nonwriteable` does
    // after registering an exclusive borrow, which costs more than the rest of a small result's
    // conversion (a 2D analysis hands back ~20 arrays).
    unsafe {
        (*arr.as_array_ptr()).fields.flags &= !numpy::npyffi::NPY_ARRAY_WRITEABLE;
    }
    arr.unbind()
}

/// Optional `(n, dim, dim)` per-point covariances as a flat slice.
pub fn covariances<'a>(
    arr: &'a Option<PyReadonlyArray3<'_, f64>>,
    name: &str,
    n: usize,
    dim: usize,
) -> PyResult<Option<&'a [f64]>> {
    let Some(a) = arr else { return Ok(None) };
    let s = a.shape();
    if s != [n, dim, dim] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape ({n}, {dim}, {dim}), got {s:?}"
        )));
    }
    Ok(Some(c_slice(a, name)?))
}

/// The neighbour search behind a registration target: a `KdTree`, or a `LocalMap` held
/// read-locked (no update can interleave) for as long as this lives.
pub enum TargetSearch<'a> {
    Tree(&'a KdTree),
    Map(RwLockReadGuard<'a, VoxelMap>),
}

impl TargetSearch<'_> {
    pub fn search(&self) -> &dyn NeighborSearch {
        match self {
            TargetSearch::Tree(t) => &t.inner,
            TargetSearch::Map(g) => &**g,
        }
    }
}

/// `target` as a neighbour search; `TypeError` unless it is a `KdTree` or a `LocalMap`.
pub fn target_search<'a>(target: &'a Bound<'_, PyAny>) -> PyResult<TargetSearch<'a>> {
    if let Ok(t) = target.cast::<KdTree>() {
        return Ok(TargetSearch::Tree(t.get()));
    }
    if let Ok(m) = target.cast::<LocalMap>() {
        return Ok(TargetSearch::Map(m.get().read()));
    }
    Err(PyTypeError::new_err(format!(
        "target: expected a KdTree or LocalMap, got {}",
        target.get_type().name()?
    )))
}

/// Run `f` on a pool of `num_threads` threads (`threads::in_pool`), or on the calling thread for
/// an input of `n <= SEQUENTIAL_MAX` points: the core's loops run sequentially there anyway
/// (same chunks, same result), and handing the call to a pool thread cost more than the work
/// on a 2D scan.
pub fn in_pool_unless_small<T: Send>(
    n: usize,
    num_threads: Option<usize>,
    f: impl FnOnce() -> T + Send,
) -> scanreg_core::Result<T> {
    if n <= SEQUENTIAL_MAX && num_threads != Some(0) {
        return Ok(f());
    }
    in_pool(num_threads, f)
}
