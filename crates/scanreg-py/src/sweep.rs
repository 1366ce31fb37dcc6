//! Binding of `scanreg_core::sweep`: the odometry front end's crop + two grids in one call.

use crate::convert::{core_err, points};
use numpy::{IntoPyArray, PyArray2, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use scanreg_core::sweep;

type Grid = Py<PyArray2<f64>>;

/// `(fine, coarse, num_in_range)`: centroid grids of the points within the range bounds.
#[pyfunction]
fn sweep_grids(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    min_range: f64,
    max_range: f64,
    fine_voxel: f64,
    coarse_voxel: f64,
) -> PyResult<(Grid, Grid, usize)> {
    let (data, dim) = points(&points_array, "points")?;
    let g = py
        .detach(|| sweep::sweep_grids(data, dim, min_range, max_range, fine_voxel, coarse_voxel))
        .map_err(core_err)?;
    let rows = |v: Vec<f64>| -> PyResult<Grid> {
        let n = v.len() / dim;
        Ok(v.into_pyarray(py).reshape([n, dim])?.unbind())
    };
    Ok((rows(g.fine)?, rows(g.coarse)?, g.num_in_range))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(sweep_grids, m)?)?;
    Ok(())
}
