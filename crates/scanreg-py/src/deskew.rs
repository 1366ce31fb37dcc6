//! Binding for motion compensation (`scanreg_core::deskew`).

use crate::convert::{core_err, points, vector};
use numpy::{IntoPyArray, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

/// Points expressed in the sensor frame at `reference_time` under a constant body twist.
#[pyfunction]
#[pyo3(signature = (points_array, timestamps, velocity, reference_time))]
fn deskew(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    timestamps: PyReadonlyArray1<'_, f64>,
    velocity: PyReadonlyArray1<'_, f64>,
    reference_time: f64,
) -> PyResult<Py<PyArray2<f64>>> {
    let (data, dim) = points(&points_array, "points")?;
    let times = vector(&timestamps, "timestamps")?;
    let twist = vector(&velocity, "velocity")?;
    let out = py
        .detach(|| scanreg_core::deskew::deskew(data, dim, times, twist, reference_time))
        .map_err(core_err)?;
    let n = out.len() / dim;
    Ok(out.into_pyarray(py).reshape([n, dim])?.unbind())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(deskew, m)?)
}
