//! Binding of `scanreg_core::overlap` and `scanreg_core::normal_noise`: the measurements behind
//! a registration's verdict (overlap) and its covariance and degeneracy threshold (normal noise).

use crate::convert::{
    c_slice, core_err, in_pool_unless_small, points, points_dim, pose, target_search,
};
use crate::knn::KdTree;
use crate::register::IcpOutcome;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::kernel::Kernel;
use scanreg_core::knn::check_max_distance;
use scanreg_core::normal_agreement::{self, AgreementInput};
use scanreg_core::{basin, normal_noise, overlap, symmetry};

/// `(num_found, mean, median, rmse, trimmed_rmse, num_within)` of the distances from each
/// source point, moved by `pose_matrix`, to its nearest target point within `max_distance`;
/// `num_within` counts those within `within` too (default: `max_distance`). `outcome`: the
/// registration of `source` against this `target` whose pose this is (about): its search
/// certificates answer most queries without a search, with the same result.
#[pyfunction]
#[pyo3(signature = (target, source, pose_matrix, max_distance, num_threads=None, hints=None, within=None, outcome=None))]
#[allow(clippy::too_many_arguments)]
fn overlap_statistics(
    py: Python<'_>,
    target: &Bound<'_, PyAny>,
    source: PyReadonlyArray2<'_, f64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    max_distance: f64,
    num_threads: Option<usize>,
    hints: Option<PyReadonlyArray1<'_, i64>>,
    within: Option<f64>,
    outcome: Option<&Bound<'_, IcpOutcome>>,
) -> PyResult<OverlapTuple> {
    let hints = hints.as_ref().map(|h| c_slice(h, "hints")).transpose()?;
    let held = target_search(target)?;
    let search = held.search();
    let dim = search.dim();
    let src = points_dim(&source, "source", dim)?;
    let pm = pose(&pose_matrix, "pose_matrix", dim)?;
    let max_sq = check_max_distance("max_distance", max_distance).map_err(core_err)?;
    let within_sq = match within {
        Some(w) => check_max_distance("within", w).map_err(core_err)?,
        None => max_sq,
    };
    let certificates = outcome.and_then(|o| o.get().certificates.as_ref());
    let o = py
        .detach(|| {
            in_pool_unless_small(src.len() / dim, num_threads, || {
                overlap::overlap(search, src, pm, max_sq, within_sq, hints, certificates)
            })
        })
        .and_then(|r| r)
        .map_err(core_err)?;
    Ok(overlap_tuple(&o))
}

/// `(num_found, mean, median, rmse, trimmed_rmse, num_within)`: what `overlap_statistics`
/// returns, and `trust_analysis` for the overlap pass it runs in the same call.
pub(crate) type OverlapTuple = (usize, f64, f64, f64, f64, usize);

pub(crate) fn overlap_tuple(o: &overlap::Overlap) -> OverlapTuple {
    (
        o.num_found,
        o.mean,
        o.median,
        o.rmse,
        o.trimmed_rmse,
        o.num_within,
    )
}

/// How many `source` points, moved by `pose_matrix`, have a target point within `max_distance`
/// (inclusive): `overlap_statistics`'s `num_found` without its statistics, each query stopping
/// at the first point inside (the wrong-basin screen's tight-gate overlap).
#[pyfunction]
fn count_within(
    py: Python<'_>,
    target: &Bound<'_, PyAny>,
    source: PyReadonlyArray2<'_, f64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    max_distance: f64,
) -> PyResult<usize> {
    let held = target_search(target)?;
    let search = held.search();
    let dim = search.dim();
    let src = points_dim(&source, "source", dim)?;
    let pm = pose(&pose_matrix, "pose_matrix", dim)?;
    let max_sq = check_max_distance("max_distance", max_distance).map_err(core_err)?;
    let (r, t) = scanreg_core::points::split_pose("pose_matrix", pm, dim).map_err(core_err)?;
    py.detach(|| {
        in_pool_unless_small(src.len() / dim, None, || {
            basin::within(search, src, &r, &t, max_sq)
        })
    })
    .map_err(core_err)
}

/// `(mean, median)` halves of `sin²` between the tree's normals and their nearest neighbour's.
#[pyfunction]
fn target_normal_noise(
    py: Python<'_>,
    tree: &Bound<'_, KdTree>,
    normals: PyReadonlyArray2<'_, f64>,
) -> PyResult<(f64, f64)> {
    let tree = &tree.get().inner;
    let nrm = points_dim(&normals, "normals", tree.dim())?;
    py.detach(|| normal_noise::target_normal_noise(tree, nrm))
        .map_err(core_err)
}

/// How much the walls of `points` (normals `normals`) look the same turned by a quarter, half
/// or three quarters of a turn (`scanreg_core::symmetry`).
#[pyfunction]
fn orientation_symmetry(
    points_array: PyReadonlyArray2<'_, f64>,
    normals: PyReadonlyArray2<'_, f64>,
) -> PyResult<f64> {
    let (pts, dim) = points(&points_array, "points")?;
    let nrm = c_slice(&normals, "normals")?;
    symmetry::orientation_symmetry(pts, nrm, dim).map_err(core_err)
}

type Sampled = (Py<PyArray1<i64>>, Py<PyArray2<f64>>);

/// `(indices, normals)` of at most `max_points` evenly spaced points (PCA of `k` neighbours).
#[pyfunction]
fn sampled_normals(
    py: Python<'_>,
    points_array: PyReadonlyArray2<'_, f64>,
    k: usize,
    max_points: usize,
) -> PyResult<Sampled> {
    let (pts, dim) = points(&points_array, "points")?;
    let (idx, nrm) = py
        .detach(|| normal_noise::sampled_normals(pts, dim, k, max_points))
        .map_err(core_err)?;
    let count = idx.len();
    let idx: Vec<i64> = idx.into_iter().map(|i| i as i64).collect();
    Ok((
        idx.into_pyarray(py).unbind(),
        nrm.into_pyarray(py).reshape([count, dim])?.unbind(),
    ))
}

/// Normal direction variance per tangent axis between matched normals of two scans.
#[pyfunction]
fn correspondence_normal_noise(
    sample: PyReadonlyArray1<'_, i64>,
    source_normals: PyReadonlyArray2<'_, f64>,
    target_normals: PyReadonlyArray2<'_, f64>,
    rotation: PyReadonlyArray2<'_, f64>,
    correspondences: PyReadonlyArray1<'_, i64>,
) -> PyResult<f64> {
    let (src, dim) = points(&source_normals, "source_normals")?;
    let tgt = points_dim(&target_normals, "target_normals", dim)?;
    let rot = c_slice(&rotation, "rotation")?;
    let sample: Vec<usize> = c_slice(&sample, "sample")?
        .iter()
        .map(|&i| usize::try_from(i))
        .collect::<Result<_, _>>()
        .map_err(|_| PyValueError::new_err("sample: indices must be >= 0"))?;
    let corr = c_slice(&correspondences, "correspondences")?;
    normal_noise::correspondence_normal_noise(&sample, src, tgt, rot, corr, dim).map_err(core_err)
}

/// `(H_all, g_all, n_all, H_agreeing, g_agreeing, n_agreeing)`: point-to-plane/line normal
/// equations of the sampled pairs at `pose_matrix`, all of them and those whose normals agree.
#[pyfunction]
#[pyo3(signature = (sample, sample_normals, source, target, target_normals, correspondences, pose_matrix, min_agreement, kernel="none", kernel_scale=1.0))]
#[allow(clippy::too_many_arguments)]
fn normal_agreement_systems<'py>(
    py: Python<'py>,
    sample: PyReadonlyArray1<'_, i64>,
    sample_normals: PyReadonlyArray2<'_, f64>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    target_normals: PyReadonlyArray2<'_, f64>,
    correspondences: PyReadonlyArray1<'_, i64>,
    pose_matrix: PyReadonlyArray2<'_, f64>,
    min_agreement: f64,
    kernel: &str,
    kernel_scale: f64,
) -> PyResult<Systems<'py>> {
    let (src, dim) = points(&source, "source")?;
    let input = AgreementInput {
        sample: &c_slice(&sample, "sample")?
            .iter()
            .map(|&i| usize::try_from(i))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|_| PyValueError::new_err("sample: indices must be >= 0"))?,
        sample_normals: points_dim(&sample_normals, "sample_normals", dim)?,
        source: src,
        target: points_dim(&target, "target", dim)?,
        target_normals: points_dim(&target_normals, "target_normals", dim)?,
        correspondences: c_slice(&correspondences, "correspondences")?,
        pose: pose(&pose_matrix, "pose_matrix", dim)?,
        dim,
    };
    let kernel = Kernel::from_name(kernel, kernel_scale).map_err(core_err)?;
    let out = normal_agreement::normal_agreement_systems(&input, min_agreement, kernel)
        .map_err(core_err)?;
    let dof = if dim == 2 { 3 } else { 6 };
    let system = |s: normal_agreement::NormalSystem| -> PyResult<_> {
        Ok((
            s.hessian.into_pyarray(py).reshape([dof, dof])?,
            s.gradient.into_pyarray(py),
            s.count,
        ))
    };
    let (ha, ga, na) = system(out.all)?;
    let (hk, gk, nk) = system(out.agreeing)?;
    Ok((ha, ga, na, hk, gk, nk))
}

type Systems<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    usize,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    usize,
);

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(count_within, m)?)?;
    m.add_function(wrap_pyfunction!(normal_agreement_systems, m)?)?;
    m.add_function(wrap_pyfunction!(overlap_statistics, m)?)?;
    m.add_function(wrap_pyfunction!(target_normal_noise, m)?)?;
    m.add_function(wrap_pyfunction!(sampled_normals, m)?)?;
    m.add_function(wrap_pyfunction!(orientation_symmetry, m)?)?;
    m.add_function(wrap_pyfunction!(correspondence_normal_noise, m)?)?;
    Ok(())
}
