//! Binding of `scanreg_core::place`: Scan Context descriptors and their database.
//!
//! `ScanContextIndex` is a frozen pyclass around an `RwLock`, like `LocalMap`: queries read
//! it with the GIL released, `add` takes the write lock. Safe to share between threads.

use crate::convert::{c_slice, core_err, points_dim, rows};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::place::{self, ScanContextDatabase, ScanContextParams};
use std::sync::RwLock;

type Matrix = Py<PyArray2<f64>>;
type Vector = Py<PyArray1<f64>>;

/// A `(rings, sectors)` descriptor as a flat slice (the shape checked when `shape` is given:
/// a transposed descriptor has the right length but the wrong layout).
fn descriptor<'a>(
    arr: &'a PyReadonlyArray2<'_, f64>,
    name: &str,
    shape: Option<(usize, usize)>,
) -> PyResult<&'a [f64]> {
    if let Some((r, s)) = shape {
        if arr.shape() != [r, s] {
            return Err(PyValueError::new_err(format!(
                "{name}: expected shape ({r}, {s}), got {:?}",
                arr.shape()
            )));
        }
    }
    c_slice(arr, name)
}

/// `(descriptor (num_rings, num_sectors), ring_key (num_rings,))` of `(N, 3)` sensor-frame
/// points.
#[pyfunction]
fn scan_context(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    num_rings: usize,
    num_sectors: usize,
    max_radius: f64,
    height_offset: f64,
) -> PyResult<(Matrix, Vector)> {
    let data = points_dim(&points_array, "points", 3)?;
    let params = ScanContextParams {
        num_rings,
        num_sectors,
        max_radius,
        height_offset,
    };
    let desc = py
        .detach(|| place::scan_context(data, &params))
        .map_err(core_err)?;
    let key = place::ring_key(&desc, num_rings, num_sectors);
    Ok((rows(py, desc, num_sectors)?, key.into_pyarray(py).unbind()))
}

/// `(distance, yaw, shift)` of the query descriptor against the candidate (same shape).
#[pyfunction]
fn scan_context_distance(
    py: Python<'_>,
    query: PyReadonlyArray2<'_, f64>,
    candidate: PyReadonlyArray2<'_, f64>,
) -> PyResult<(f64, f64, usize)> {
    let shape = query.shape().to_vec();
    if candidate.shape() != shape.as_slice() {
        return Err(PyValueError::new_err(format!(
            "candidate: shape {:?} does not match the query's {:?}",
            candidate.shape(),
            shape
        )));
    }
    let (q, c) = (
        descriptor(&query, "query", None)?,
        descriptor(&candidate, "candidate", None)?,
    );
    let m = py
        .detach(|| place::checked_scan_context_distance(q, c, shape[0], shape[1]))
        .map_err(core_err)?;
    Ok((m.distance, m.yaw, m.shift))
}

/// A growing database of Scan Contexts of one shape, retrieved by ring key then distance.
#[pyclass(frozen, module = "scanreg._core")]
pub struct ScanContextIndex {
    inner: RwLock<ScanContextDatabase>,
}

type QueryResult = (Py<PyArray1<i64>>, Vector, Vector, Vector);

#[pymethods]
impl ScanContextIndex {
    #[new]
    fn new(num_rings: usize, num_sectors: usize) -> PyResult<Self> {
        let db = ScanContextDatabase::new(num_rings, num_sectors).map_err(core_err)?;
        Ok(Self {
            inner: RwLock::new(db),
        })
    }

    fn __len__(&self) -> usize {
        self.inner.read().unwrap_or_else(|e| e.into_inner()).len()
    }

    /// Append a `(num_rings, num_sectors)` descriptor; returns its index.
    fn add(&self, descriptor_array: PyReadonlyArray2<'_, f64>) -> PyResult<usize> {
        let mut db = self.inner.write().unwrap_or_else(|e| e.into_inner());
        let d = descriptor(&descriptor_array, "descriptor", Some(db.shape()))?;
        db.add(d).map_err(core_err)
    }

    /// `(indices, distances, yaws, ring_key_distances)` of the best `top_k` entries, best first.
    #[pyo3(signature = (descriptor_array, num_candidates, top_k, exclude_recent, max_distance))]
    fn query(
        &self,
        py: Python<'_>,
        descriptor_array: PyReadonlyArray2<'_, f64>,
        num_candidates: usize,
        top_k: usize,
        exclude_recent: usize,
        max_distance: f64,
    ) -> PyResult<QueryResult> {
        let shape = self.inner.read().unwrap_or_else(|e| e.into_inner()).shape();
        let d = descriptor(&descriptor_array, "descriptor", Some(shape))?;
        let found = py
            .detach(|| {
                let db = self.inner.read().unwrap_or_else(|e| e.into_inner());
                db.query(d, num_candidates, top_k, exclude_recent, max_distance)
            })
            .map_err(core_err)?;
        let idx: Vec<i64> = found.iter().map(|m| m.index as i64).collect();
        let dist: Vec<f64> = found.iter().map(|m| m.distance).collect();
        let yaw: Vec<f64> = found.iter().map(|m| m.yaw).collect();
        let key: Vec<f64> = found.iter().map(|m| m.ring_key_distance).collect();
        Ok((
            idx.into_pyarray(py).unbind(),
            dist.into_pyarray(py).unbind(),
            yaw.into_pyarray(py).unbind(),
            key.into_pyarray(py).unbind(),
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(scan_context, m)?)?;
    m.add_function(wrap_pyfunction!(scan_context_distance, m)?)?;
    m.add_class::<ScanContextIndex>()?;
    Ok(())
}
