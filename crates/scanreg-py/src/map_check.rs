//! Binding of `scanreg_core::map_check`: free-space evidence of posed 2D and 3D scans.

use crate::convert::{c_slice, core_err, rows};
use numpy::PyUntypedArrayMethods;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::map_check::{SeeThrough, SeeThroughSettings};

type PerReturn = Py<PyArray1<u32>>;
/// `(world, judged, seen, seen_through)`.
type Judged = (Py<PyArray2<f64>>, Py<PyArray1<i64>>, PerReturn, PerReturn);

/// `(world, judged, seen, seen_through)`: the indices of the returns judged (every
/// `stride`-th) and per judged return its world coordinates, the other scans that saw it and,
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
    let settings = SeeThroughSettings {
        bins,
        margin,
        max_range,
        min_gap,
        stride,
    };
    judged(
        py,
        [&poses, &points],
        3,
        2,
        &offsets,
        sessions.as_ref(),
        |p, x, o, s| scanreg_core::map_check::see_through(p, x, o, s, settings),
    )
}

/// [`see_through`] for 3D scans: `poses` rows of `[R row-major, t]` (12 values, `T_world_scan`),
/// `points` `(N, 3)`, range images of `bins` azimuth by `elevation_bins` elevation bins;
/// `world` is `(N, 3)`.
#[pyfunction]
#[pyo3(signature = (poses, points, offsets, *, bins, elevation_bins, margin, max_range, min_gap, stride=1, sessions=None))]
#[allow(clippy::too_many_arguments)]
fn see_through_3d(
    py: Python<'_>,
    poses: PyReadonlyArray2<'_, f64>,
    points: PyReadonlyArray2<'_, f64>,
    offsets: PyReadonlyArray1<'_, i64>,
    bins: usize,
    elevation_bins: usize,
    margin: f64,
    max_range: f64,
    min_gap: usize,
    stride: usize,
    sessions: Option<PyReadonlyArray1<'_, u32>>,
) -> PyResult<Judged> {
    let settings = SeeThroughSettings {
        bins,
        margin,
        max_range,
        min_gap,
        stride,
    };
    judged(
        py,
        [&poses, &points],
        12,
        3,
        &offsets,
        sessions.as_ref(),
        |p, x, o, s| scanreg_core::map_check::see_through_3d(p, x, o, s, settings, elevation_bins),
    )
}

/// Checks the shapes, converts, runs `judge` with the GIL released, and returns its result.
fn judged(
    py: Python<'_>,
    [poses, points]: [&PyReadonlyArray2<'_, f64>; 2],
    pose_len: usize,
    dim: usize,
    offsets: &PyReadonlyArray1<'_, i64>,
    sessions: Option<&PyReadonlyArray1<'_, u32>>,
    judge: impl Fn(&[f64], &[f64], &[usize], Option<&[u32]>) -> scanreg_core::error::Result<SeeThrough>
        + Send
        + Sync,
) -> PyResult<Judged> {
    for (arr, name, cols) in [(poses, "poses", pose_len), (points, "points", dim)] {
        let s = arr.shape();
        if s[1] != cols {
            return Err(PyValueError::new_err(format!(
                "{name}: expected shape (N, {cols}), got ({}, {})",
                s[0], s[1]
            )));
        }
    }
    let pose_data = c_slice(poses, "poses")?;
    let point_data = c_slice(points, "points")?;
    let offsets: Vec<usize> = c_slice(offsets, "offsets")?
        .iter()
        .map(|&v| usize::try_from(v))
        .collect::<Result<_, _>>()
        .map_err(|_| PyValueError::new_err("offsets: must be >= 0"))?;
    let sessions = match sessions {
        Some(v) => Some(c_slice(v, "sessions")?),
        None => None,
    };
    let g = py
        .detach(|| judge(pose_data, point_data, &offsets, sessions))
        .map_err(core_err)?;
    Ok((
        rows(py, g.world, dim)?,
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
    m.add_function(wrap_pyfunction!(see_through, m)?)?;
    m.add_function(wrap_pyfunction!(see_through_3d, m)?)
}
