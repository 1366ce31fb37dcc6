//! Binding of `scanreg_core::sweep_residual`: the per-point sums of the deskew residual's loop
//! covariance term.

use crate::convert::{c_slice, core_err, points, pose, square, vector};
use numpy::{
    PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3, ToPyArray,
};
use pyo3::prelude::*;
use scanreg_core::sweep_residual::{sweep_sums, TargetSweeps};

type Square = Py<numpy::PyArray2<f64>>;
/// `(matched, A, B, C)`.
type Sums = (usize, Square, Option<Square>, Option<Py<PyArray3<f64>>>);

/// `(matched, A, B, C)` or None with fewer than 3 matched points: `B` None unless
/// `source_fractions` is given, `C` (`(K, 3, 3)`) None unless `target_slots` is.
#[pyfunction]
#[pyo3(signature = (
    source, nearest, target_points, target_normals, pose_matrix, source_fractions=None,
    target_slots=None, target_fractions=None, node_poses=None, mean_fractions=None
))]
#[allow(clippy::too_many_arguments)]
fn sweep_residual_sums(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    nearest: PyReadonlyArray1<'_, i64>,
    target_points: PyReadonlyArray2<'_, f64>,
    target_normals: PyReadonlyArray2<'_, f64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    source_fractions: Option<PyReadonlyArray1<'_, f64>>,
    target_slots: Option<PyReadonlyArray1<'_, i64>>,
    target_fractions: Option<PyReadonlyArray1<'_, f64>>,
    node_poses: Option<PyReadonlyArray3<'_, f64>>,
    mean_fractions: Option<PyReadonlyArray1<'_, f64>>,
) -> PyResult<Option<Sums>> {
    let (src, _) = points(&source, "source")?;
    let near = c_slice(&nearest, "nearest")?;
    let (tp, _) = points(&target_points, "target_points")?;
    let (tn, _) = points(&target_normals, "target_normals")?;
    let pose = pose(&pose_matrix, "pose_matrix", 2)?;
    let fractions = source_fractions
        .as_ref()
        .map(|f| vector(f, "source_fractions"))
        .transpose()?;
    let target =
        match (
            &target_slots,
            &target_fractions,
            &node_poses,
            &mean_fractions,
        ) {
            (Some(s), Some(f), Some(p), Some(m)) => Some(TargetSweeps {
                slots: c_slice(s, "target_slots")?,
                fractions: vector(f, "target_fractions")?,
                node_poses: c_slice(p, "node_poses")?,
                mean_fractions: vector(m, "mean_fractions")?,
            }),
            (None, None, None, None) => None,
            _ => return Err(pyo3::exceptions::PyValueError::new_err(
                "target_slots, target_fractions, node_poses, mean_fractions: give all four or none",
            )),
        };
    let sums = py
        .detach(|| sweep_sums(src, near, tp, tn, pose, fractions, target.as_ref()))
        .map_err(core_err)?;
    let Some(s) = sums else { return Ok(None) };
    let a = square(py, s.information.to_vec(), 3)?;
    let b = s.source.map(|b| square(py, b.to_vec(), 3)).transpose()?;
    let c = if target.is_some() {
        let flat: Vec<f64> = s.nodes.iter().flatten().copied().collect();
        let k = s.nodes.len();
        Some(flat.to_pyarray(py).reshape([k, 3, 3])?.unbind())
    } else {
        None
    };
    Ok(Some((s.matched, a, b, c)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(sweep_residual_sums, m)?)
}
