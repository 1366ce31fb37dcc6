//! Bindings for global 3D registration (`scanreg_core::global`).

use crate::convert::{core_err, points_dim, rows};
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::global::{self, GlobalSettings, Hypothesis, StageSeconds};
use scanreg_core::knn::KdTree;

/// Hypotheses of a global registration, best first, and what they came from.
#[pyclass(frozen, module = "scanreg._core")]
pub struct GlobalMatch {
    /// `(K, 4, 4)` `T_target_source` per hypothesis.
    #[pyo3(get)]
    poses: Py<PyArray3<f64>>,
    /// `(K,)` correspondences in each hypothesis's clique.
    #[pyo3(get)]
    clique_sizes: Py<PyArray1<i64>>,
    /// `(K,)` correspondences within the noise bound at each pose.
    #[pyo3(get)]
    num_inliers: Py<PyArray1<i64>>,
    /// `(K,)` whether each clique search finished within its budget.
    #[pyo3(get)]
    exact: Py<PyArray1<bool>>,
    /// `(M, 3)` keypoints of the source (voxel centroids); empty for paired input.
    #[pyo3(get)]
    source_keypoints: Py<PyArray2<f64>>,
    #[pyo3(get)]
    target_keypoints: Py<PyArray2<f64>>,
    /// Keypoints with a descriptor.
    #[pyo3(get)]
    num_source_descriptors: usize,
    #[pyo3(get)]
    num_target_descriptors: usize,
    /// `(C, 2)` mutual nearest-neighbour pairs (source keypoint, target keypoint).
    #[pyo3(get)]
    correspondences: Py<PyArray2<i64>>,
    /// `(stage, seconds)` in pipeline order; empty for paired input.
    #[pyo3(get)]
    stage_seconds: Vec<(String, f64)>,
    /// `(stage, seconds)` of process CPU time (all threads), in the same order; empty for
    /// paired input, NaN where the platform has no process CPU clock.
    #[pyo3(get)]
    stage_cpu_seconds: Vec<(String, f64)>,
}

fn stage_list(seconds: Option<StageSeconds>) -> Vec<(String, f64)> {
    seconds.map_or_else(Vec::new, |s| {
        [
            ("keypoints", s.keypoints),
            ("descriptors", s.descriptors),
            ("matching", s.matching),
            ("pruning", s.pruning),
            ("solve", s.solve),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    })
}

fn build(
    py: Python<'_>,
    hyps: Vec<Hypothesis>,
    source_keypoints: Vec<f64>,
    target_keypoints: Vec<f64>,
    descriptors: (usize, usize),
    pairs: Vec<(u32, u32)>,
    seconds: Option<(StageSeconds, StageSeconds)>,
) -> PyResult<GlobalMatch> {
    let k = hyps.len();
    let flat: Vec<f64> = hyps.iter().flat_map(|h| h.pose).collect();
    let poses = Array3::from_shape_vec((k, 4, 4), flat)
        .map_err(|e| PyValueError::new_err(format!("internal: {e}")))?;
    let pair_flat: Vec<i64> = pairs
        .iter()
        .flat_map(|&(i, j)| [i as i64, j as i64])
        .collect();
    Ok(GlobalMatch {
        poses: poses.into_pyarray(py).unbind(),
        clique_sizes: hyps
            .iter()
            .map(|h| h.clique_size as i64)
            .collect::<Vec<_>>()
            .into_pyarray(py)
            .unbind(),
        num_inliers: hyps
            .iter()
            .map(|h| h.num_inliers as i64)
            .collect::<Vec<_>>()
            .into_pyarray(py)
            .unbind(),
        exact: hyps
            .iter()
            .map(|h| h.exact)
            .collect::<Vec<_>>()
            .into_pyarray(py)
            .unbind(),
        source_keypoints: rows(py, source_keypoints, 3)?,
        target_keypoints: rows(py, target_keypoints, 3)?,
        num_source_descriptors: descriptors.0,
        num_target_descriptors: descriptors.1,
        correspondences: rows(py, pair_flat, 2)?,
        stage_seconds: stage_list(seconds.map(|s| s.0)),
        stage_cpu_seconds: stage_list(seconds.map(|s| s.1)),
    })
}

#[pyfunction]
#[pyo3(signature = (source, target, *, voxel_size, feature_radius, noise_bound,
    normal_neighbors=30, max_feature_neighbors=100, max_hypotheses=3,
    clique_search_budget=50_000_000))]
#[allow(clippy::too_many_arguments)]
fn register_global(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    voxel_size: f64,
    feature_radius: f64,
    noise_bound: f64,
    normal_neighbors: usize,
    max_feature_neighbors: usize,
    max_hypotheses: usize,
    clique_search_budget: usize,
) -> PyResult<GlobalMatch> {
    let src = points_dim(&source, "source", 3)?;
    let tgt = points_dim(&target, "target", 3)?;
    let settings = GlobalSettings {
        voxel_size,
        normal_neighbors,
        feature_radius,
        max_feature_neighbors,
        noise_bound,
        max_hypotheses,
        clique_search_budget,
    };
    let out = py
        .detach(|| global::register_global(src, tgt, &settings))
        .map_err(core_err)?;
    let counts = (
        out.source.valid.iter().filter(|&&v| v).count(),
        out.target.valid.iter().filter(|&&v| v).count(),
    );
    build(
        py,
        out.hypotheses,
        out.source.points,
        out.target.points,
        counts,
        out.correspondences,
        Some((out.seconds, out.cpu_seconds)),
    )
}

#[pyfunction]
#[pyo3(signature = (source, target, *, noise_bound, max_hypotheses=3,
    clique_search_budget=50_000_000))]
fn solve_correspondences(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    noise_bound: f64,
    max_hypotheses: usize,
    clique_search_budget: usize,
) -> PyResult<GlobalMatch> {
    let src = points_dim(&source, "source", 3)?;
    let tgt = points_dim(&target, "target", 3)?;
    if max_hypotheses == 0 || clique_search_budget == 0 {
        return Err(PyValueError::new_err(
            "max_hypotheses, clique_search_budget: must be >= 1",
        ));
    }
    let hyps = py
        .detach(|| {
            global::solve_correspondences(
                src,
                tgt,
                noise_bound,
                max_hypotheses,
                clique_search_budget,
            )
        })
        .map_err(core_err)?;
    build(py, hyps, Vec::new(), Vec::new(), (0, 0), Vec::new(), None)
}

/// FPFH rows and whether each is defined.
type Descriptors<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<bool>>);

#[pyfunction]
#[pyo3(signature = (points, normals, *, radius, max_neighbors=100))]
fn fpfh<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    normals: PyReadonlyArray2<'py, f64>,
    radius: f64,
    max_neighbors: usize,
) -> PyResult<Descriptors<'py>> {
    let pts = points_dim(&points, "points", 3)?;
    let nrm = points_dim(&normals, "normals", 3)?;
    if nrm.len() != pts.len() {
        return Err(PyValueError::new_err(format!(
            "normals: expected {} rows to match points, got {}",
            pts.len() / 3,
            nrm.len() / 3
        )));
    }
    let (desc, valid) = py
        .detach(|| {
            let tree = KdTree::build(pts, 3)?;
            global::fpfh::fpfh(&tree, nrm, radius, max_neighbors)
        })
        .map_err(core_err)?;
    let d = rows(py, desc, global::fpfh::FPFH_DIM)?.into_bound(py);
    Ok((d, valid.into_pyarray(py)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<GlobalMatch>()?;
    m.add_function(wrap_pyfunction!(register_global, m)?)?;
    m.add_function(wrap_pyfunction!(solve_correspondences, m)?)?;
    m.add_function(wrap_pyfunction!(fpfh, m)?)?;
    Ok(())
}
