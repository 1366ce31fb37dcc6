//! Binding of `scanreg_core::sweep`: the odometry front end's crop + two grids in one call.

use crate::convert::{core_err, points};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use scanreg_core::sweep;

type Grid = Py<PyArray2<f64>>;
type Covariances = Option<Py<PyArray3<f64>>>;

/// `(fine, coarse, num_in_range, coarse_covariances)`: centroid grids of the points within the
/// range bounds, and (when asked) the plane-regularised covariance of each coarse point's fine
/// points.
#[pyfunction]
#[pyo3(signature = (points_array, min_range, max_range, fine_voxel, coarse_voxel, coarse_covariances=false))]
fn sweep_grids(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    min_range: f64,
    max_range: f64,
    fine_voxel: f64,
    coarse_voxel: f64,
    coarse_covariances: bool,
) -> PyResult<(Grid, Grid, usize, Covariances)> {
    let (data, dim) = points(&points_array, "points")?;
    let g = py
        .detach(|| {
            sweep::sweep_grids(
                data,
                dim,
                min_range,
                max_range,
                fine_voxel,
                coarse_voxel,
                coarse_covariances,
            )
        })
        .map_err(core_err)?;
    let rows = |v: Vec<f64>| -> PyResult<Grid> {
        let n = v.len() / dim;
        Ok(v.into_pyarray(py).reshape([n, dim])?.unbind())
    };
    let covs = match g.coarse_covariances {
        Some(v) => {
            let n = v.len() / (dim * dim);
            Some(v.into_pyarray(py).reshape([n, dim, dim])?.unbind())
        }
        None => None,
    };
    Ok((rows(g.fine)?, rows(g.coarse)?, g.num_in_range, covs))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(sweep_grids, m)?)?;
    Ok(())
}
