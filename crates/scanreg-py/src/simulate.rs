//! Binding of the ray caster (`scanreg_core::simulate`).

use crate::convert::{core_err, rows};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::simulate::geometry::PRIM_COLUMNS;
use scanreg_core::simulate::motion::Motion;
use scanreg_core::simulate::{self, Beams, RangeModel};

/// Per-beam output of `cast_rays`, in beam order.
#[pyclass(frozen, module = "scanreg._core")]
pub struct CastResult {
    #[pyo3(get)]
    true_range: Py<PyArray1<f64>>,
    #[pyo3(get)]
    range: Py<PyArray1<f64>>,
    #[pyo3(get)]
    status: Py<PyArray1<u8>>,
    #[pyo3(get)]
    hit: Py<PyArray1<i64>>,
    #[pyo3(get)]
    points: Py<PyArray2<f64>>,
    #[pyo3(get)]
    points_reference: Py<PyArray2<f64>>,
}

fn not_contiguous(name: &str) -> PyErr {
    PyValueError::new_err(format!(
        "{name}: array is not C-contiguous; pass numpy.ascontiguousarray({name})"
    ))
}

/// A C-contiguous float64 `(N, cols)` table as a flat row-major slice. (`as_slice` alone
/// would also accept Fortran order, whose flat layout is transposed.)
fn table<'a>(arr: &'a PyReadonlyArray2<'_, f64>, name: &str, cols: usize) -> PyResult<&'a [f64]> {
    let shape = arr.shape();
    if shape[1] != cols {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (N, {cols}), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    if !arr.is_c_contiguous() {
        return Err(not_contiguous(name));
    }
    arr.as_slice().map_err(|_| not_contiguous(name))
}

/// A contiguous float64 vector as a slice.
fn vector<'a>(arr: &'a PyReadonlyArray1<'_, f64>, name: &str) -> PyResult<&'a [f64]> {
    arr.as_slice().map_err(|_| not_contiguous(name))
}

#[pyfunction]
#[pyo3(signature = (
    primitives, directions, time_offsets, *, start_time, knot_times, knot_poses, twists,
    reference_time, min_range, max_range, range_sigma, dropout_probability, seed
))]
#[allow(clippy::too_many_arguments)]
fn cast_rays(
    py: Python<'_>,
    primitives: PyReadonlyArray2<'_, f64>,
    directions: PyReadonlyArray2<'_, f64>,
    time_offsets: PyReadonlyArray1<'_, f64>,
    start_time: f64,
    knot_times: PyReadonlyArray1<'_, f64>,
    knot_poses: PyReadonlyArray2<'_, f64>,
    twists: PyReadonlyArray2<'_, f64>,
    reference_time: f64,
    min_range: f64,
    max_range: f64,
    range_sigma: f64,
    dropout_probability: f64,
    seed: u64,
) -> PyResult<CastResult> {
    let prims = table(&primitives, "primitives", PRIM_COLUMNS)?;
    let dirs = table(&directions, "directions", 3)?;
    let offsets = vector(&time_offsets, "time_offsets")?;
    let knots = vector(&knot_times, "knot_times")?;
    let poses = table(&knot_poses, "knot_poses", 16)?;
    let tw = table(&twists, "twists", 6)?;
    let model = RangeModel {
        min_range,
        max_range,
        range_sigma,
        dropout_probability,
        seed,
    };
    let out = py
        .detach(|| {
            let motion = Motion::new(knots, poses, tw)?;
            let beams = Beams {
                directions: dirs,
                time_offsets: offsets,
            };
            simulate::cast(prims, beams, start_time, &motion, reference_time, &model)
        })
        .map_err(core_err)?;
    Ok(CastResult {
        true_range: out.true_range.into_pyarray(py).unbind(),
        range: out.range.into_pyarray(py).unbind(),
        status: out.status.into_pyarray(py).unbind(),
        hit: out.hit.into_pyarray(py).unbind(),
        points: rows(py, out.points, 3)?,
        points_reference: rows(py, out.points_reference, 3)?,
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<CastResult>()?;
    m.add_function(wrap_pyfunction!(cast_rays, m)?)?;
    m.add("SIMULATE_PRIMITIVE_COLUMNS", PRIM_COLUMNS)?;
    Ok(())
}
