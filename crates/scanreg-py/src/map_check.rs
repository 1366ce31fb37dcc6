//! Binding of `scanreg_core::map_check`: free-space evidence of posed 2D scans.

use crate::convert::{c_slice, core_err, rows};
use numpy::PyUntypedArrayMethods;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::map_check::SeeThroughSettings;

type PerReturn = Py<PyArray1<u32>>;
/// `(world, judged, seen, seen_through)`.
type Judged = (Py<PyArray2<f64>>, Py<PyArray1<i64>>, PerReturn, PerReturn);

/// `(world, judged, seen, seen_through)`: every return in the world frame, the indices of the
/// returns judged (every `stride`-th), and per judged return the other scans that saw it and,
/// of those, the scans that saw through it.
#[pyfunction]
#[pyo3(signature = (poses, points, offsets, *, bins, margin, max_range, min_gap, stride=1, sessions=None))]
#[allow(clippy::too_many_arguments)]
fn see_through(
    py: Python<'_>,
    poses: PyReadonlyArray2<'_, f64>,
    points: PyReadonlyArray2<'_, f64>,
    offsets: PyReadonlyArray1<'_, i64>,
    bins: usize,
    margin: f64,
    max_range: f64,
    min_gap: usize,
    stride: usize,
    sessions: Option<PyReadonlyArray1<'_, u32>>,
) -> PyResult<Judged> {
    for (arr, name, cols) in [(&poses, "poses", 3), (&points, "points", 2)] {
        let s = arr.shape();
        if s[1] != cols {
            return Err(PyValueError::new_err(format!(
                "{name}: expected shape (N, {cols}), got ({}, {})",
                s[0], s[1]
            )));
        }
    }
    let pose_data = c_slice(&poses, "poses")?;
    let point_data = c_slice(&points, "points")?;
    let offsets: Vec<usize> = c_slice(&offsets, "offsets")?
        .iter()
        .map(|&v| usize::try_from(v))
        .collect::<Result<_, _>>()
        .map_err(|_| PyValueError::new_err("offsets: must be >= 0"))?;
    let sessions = match &sessions {
        Some(v) => Some(c_slice(v, "sessions")?),
        None => None,
    };
    let g = py
        .detach(|| {
            let settings = SeeThroughSettings {
                bins,
                margin,
                max_range,
                min_gap,
                stride,
            };
            scanreg_core::map_check::see_through(
                pose_data, point_data, &offsets, sessions, settings,
            )
        })
        .map_err(core_err)?;
    Ok((
        rows(py, g.world, 2)?,
        g.judged
            .into_iter()
            .map(|i| i as i64)
            .collect::<Vec<_>>()
            .into_pyarray(py)
            .unbind(),
        g.seen.into_pyarray(py).unbind(),
        g.seen_through.into_pyarray(py).unbind(),
    ))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(see_through, m)?)
}
