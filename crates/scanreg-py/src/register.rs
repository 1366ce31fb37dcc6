//! Binding of the local registration loop (`scanreg_core::icp`): one call per registration,
//! the GIL released for the whole loop, on a pool of `num_threads` threads (a source of at most
//! `SEQUENTIAL_MAX` points on the calling thread, where the loop is sequential anyway).

use crate::convert::{
    c_slice, core_err, covariances, in_pool_unless_small, points_dim, pose, read_only, square,
    target_search, TargetSearch,
};
use numpy::PyUntypedArrayMethods;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use scanreg_core::basin;
use scanreg_core::icp::{self, Method, Optimizer, Settings, Source, Target};
use scanreg_core::lie::nearest_rotation_2d;
use scanreg_core::threads::in_pool;
use scanreg_core::Kernel;

/// What the core returns for one registration (or one evaluation). `pose`, `score_outer` and
/// `correspondences`, which only the trust analysis reads, become arrays when read (a new one
/// per read): on a 2D scan, making every array up front was a tenth of the call's fixed cost.
#[pyclass(frozen, module = "scanreg._core")]
pub struct IcpOutcome {
    pose: Vec<f64>,
    dim: usize,
    /// `pose`'s rotation, read-only; in 2D projected onto SO(2) (`[[c, -s], [s, c]]`, what
    /// `SE2` holds), in 3D as computed (the Python side projects it).
    #[pyo3(get)]
    rotation: Py<PyArray2<f64>>,
    /// `pose`'s translation, read-only.
    #[pyo3(get)]
    translation: Py<PyArray1<f64>>,
    #[pyo3(get)]
    iterations: usize,
    #[pyo3(get)]
    stop_reason: &'static str,
    #[pyo3(get)]
    hessian: Py<PyArray2<f64>>,
    #[pyo3(get)]
    gradient: Py<PyArray1<f64>>,
    score_outer: Vec<f64>,
    #[pyo3(get)]
    cost: f64,
    #[pyo3(get)]
    num_correspondences: usize,
    /// Source points with their nearest target point inside the gate (with or without a
    /// factor: a target point without a normal forms none).
    #[pyo3(get)]
    num_in_gate: usize,
    #[pyo3(get)]
    sum_squares: f64,
    #[pyo3(get)]
    irls_sum_squares: f64,
    #[pyo3(get)]
    irls_weight_sum: f64,
    #[pyo3(get)]
    sum_squared_distances: f64,
    /// Seconds per iteration, a tuple (what `RegistrationTiming.iterations` holds).
    #[pyo3(get)]
    iteration_seconds: Py<PyTuple>,
    #[pyo3(get)]
    final_evaluation_seconds: f64,
    /// Target index per source point at `pose` (`u32::MAX`: none).
    correspondences: Vec<u32>,
    /// What the last searches proved (`scanreg_core::icp::Certificates`): `overlap_statistics`
    /// at this pose answers most queries from them.
    pub(crate) certificates: Option<icp::Certificates>,
}

#[pymethods]
impl IcpOutcome {
    /// The homogeneous `(dim+1, dim+1)` pose, as the core computed it.
    #[getter]
    fn pose(&self, py: Python<'_>) -> PyResult<Py<PyArray2<f64>>> {
        square(py, self.pose.clone(), self.dim + 1)
    }

    /// `Σ s sᵀ` of the per-correspondence scores, `(dof, dof)`.
    #[getter]
    fn score_outer(&self, py: Python<'_>) -> PyResult<Py<PyArray2<f64>>> {
        let dof = if self.dim == 2 { 3 } else { 6 };
        square(py, self.score_outer.clone(), dof)
    }

    /// Target index per source point at `pose`, -1 for none.
    #[getter]
    fn correspondences(&self, py: Python<'_>) -> Py<PyArray1<i64>> {
        self.correspondences
            .iter()
            .map(|&j| if j == u32::MAX { -1 } else { i64::from(j) })
            .collect::<Vec<i64>>()
            .into_pyarray(py)
            .unbind()
    }
}

/// The rotation and translation of a homogeneous `(dim+1)²` pose. In 2D the rotation is
/// the nearest one (closed form), after checking the core kept it orthonormal to 1e-6 (a
/// core bug otherwise, never the user's input).
pub(crate) fn rigid_parts(pose: &[f64], dim: usize) -> PyResult<(Vec<f64>, Vec<f64>)> {
    let m = dim + 1;
    let translation: Vec<f64> = (0..dim).map(|i| pose[i * m + dim]).collect();
    if dim != 2 {
        let rotation = (0..dim)
            .flat_map(|i| pose[i * m..i * m + dim].iter().copied())
            .collect();
        return Ok((rotation, translation));
    }
    let (a, b, c, d) = (pose[0], pose[1], pose[m], pose[m + 1]);
    let err = (a * a + c * c - 1.0)
        .abs()
        .max((b * b + d * d - 1.0).abs())
        .max((a * b + c * d).abs());
    if err.is_nan() || err > 1e-6 {
        return Err(PyValueError::new_err(format!(
            "pose: not orthonormal (max |RᵀR - I| = {err:.2e})"
        )));
    }
    let (co, s) = nearest_rotation_2d(a, b, c, d);
    Ok((vec![co, -s, s, co], translation))
}

fn projector(arr: &Option<PyReadonlyArray2<'_, f64>>, dim: usize) -> PyResult<Option<[f64; 36]>> {
    let Some(a) = arr else { return Ok(None) };
    let dof = if dim == 2 { 3 } else { 6 };
    if a.shape() != [dof, dof] {
        return Err(PyValueError::new_err(format!(
            "step_projector: expected shape ({dof}, {dof}), got {:?}",
            a.shape()
        )));
    }
    let mut out = [0.0; 36];
    out[..dof * dof].copy_from_slice(c_slice(a, "step_projector")?);
    Ok(Some(out))
}

/// The inputs every registration binding converts the same way (`starts(dim)` checks the
/// start poses), and `solve` run on them with the GIL released: on the pool of `num_threads`,
/// or, for one solve on a small source, on the calling thread.
#[allow(clippy::too_many_arguments)]
fn with_inputs<A: Send, T: Send>(
    py: Python<'_>,
    source: &PyReadonlyArray2<'_, f64>,
    starts: impl FnOnce(usize) -> PyResult<A>,
    // Several solves share out over the pool even on a small source.
    parallel_starts: bool,
    target: &Bound<'_, PyAny>,
    method: &str,
    kernel: &str,
    kernel_scale: f64,
    max_correspondence_distance: f64,
    max_iterations: usize,
    translation_tolerance: f64,
    rotation_tolerance: f64,
    optimizer: &str,
    min_correspondences: usize,
    num_threads: Option<usize>,
    source_covariances: &Option<PyReadonlyArray3<'_, f64>>,
    target_normals: &Option<PyReadonlyArray2<'_, f64>>,
    target_covariances: &Option<PyReadonlyArray3<'_, f64>>,
    step_projector: &Option<PyReadonlyArray2<'_, f64>>,
    extrapolate: bool,
    solve: impl FnOnce(A, &Source<'_>, &Target<'_>, &Settings) -> scanreg_core::Result<T> + Send,
) -> PyResult<(usize, T)> {
    // The target is a k-d tree over a fixed cloud (attributes passed in) or a local map
    // (attributes stored in it, read under its lock for the whole registration).
    let held = target_search(target)?;
    let search = held.search();
    let map_guard = match &held {
        TargetSearch::Map(g) => Some(g),
        TargetSearch::Tree(_) => None,
    };
    if map_guard.is_some() && (target_normals.is_some() || target_covariances.is_some()) {
        return Err(PyValueError::new_err(
            "target_normals/target_covariances: a LocalMap target carries its own",
        ));
    }
    let dim = search.dim();
    let src = points_dim(source, "source", dim)?;
    let init = starts(dim)?;
    let nrm = match &map_guard {
        Some(g) => g.normals(),
        None => target_normals
            .as_ref()
            .map(|a| points_dim(a, "target_normals", dim))
            .transpose()?,
    };
    let tcov = match &map_guard {
        Some(g) => g.covariances(),
        None => covariances(
            target_covariances,
            "target_covariances",
            search.id_count(),
            dim,
        )?,
    };
    let scov = covariances(
        source_covariances,
        "source_covariances",
        src.len() / dim,
        dim,
    )?;
    let settings = Settings {
        method: Method::from_name(method).map_err(core_err)?,
        kernel: Kernel::from_name(kernel, kernel_scale).map_err(core_err)?,
        max_correspondence_distance,
        max_iterations,
        translation_tolerance,
        rotation_tolerance,
        optimizer: Optimizer::from_name(optimizer).map_err(core_err)?,
        min_correspondences,
        step_projector: projector(step_projector, dim)?,
        extrapolate,
    };
    let src_in = Source {
        points: src,
        covariances: scov,
    };
    let tgt_in = Target {
        search,
        normals: nrm,
        covariances: tcov,
    };
    let out = py
        .detach(|| {
            let run = || solve(init, &src_in, &tgt_in, &settings);
            if parallel_starts {
                in_pool(num_threads, run)
            } else {
                in_pool_unless_small(src.len() / dim, num_threads, run)
            }
            .and_then(|r| r)
        })
        .map_err(core_err)?;
    Ok((dim, out))
}

#[pyfunction]
// No `*`: `register()` passes every argument by position, in this order (PyO3 matches each
// keyword against the names one by one: a call with all 20 arguments took 2.39 µs with 17 of
// them named, 1.65 µs by position); other callers name them.
#[pyo3(signature = (
    source, target, init_pose, method, kernel, kernel_scale, max_correspondence_distance,
    max_iterations, translation_tolerance, rotation_tolerance, optimizer, min_correspondences,
    num_threads=None, source_covariances=None, target_normals=None, target_covariances=None,
    iterate=true, step_projector=None, extrapolate=true
))]
#[allow(clippy::too_many_arguments)]
fn register_icp(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: &Bound<'_, PyAny>,
    init_pose: PyReadonlyArray2<'_, f64>,
    method: &str,
    kernel: &str,
    kernel_scale: f64,
    max_correspondence_distance: f64,
    max_iterations: usize,
    translation_tolerance: f64,
    rotation_tolerance: f64,
    optimizer: &str,
    min_correspondences: usize,
    num_threads: Option<usize>,
    source_covariances: Option<PyReadonlyArray3<'_, f64>>,
    target_normals: Option<PyReadonlyArray2<'_, f64>>,
    target_covariances: Option<PyReadonlyArray3<'_, f64>>,
    iterate: bool,
    step_projector: Option<PyReadonlyArray2<'_, f64>>,
    extrapolate: bool,
) -> PyResult<IcpOutcome> {
    let (dim, out) = with_inputs(
        py,
        &source,
        |dim| pose(&init_pose, "init_pose", dim),
        false,
        target,
        method,
        kernel,
        kernel_scale,
        max_correspondence_distance,
        max_iterations,
        translation_tolerance,
        rotation_tolerance,
        optimizer,
        min_correspondences,
        num_threads,
        &source_covariances,
        &target_normals,
        &target_covariances,
        &step_projector,
        extrapolate,
        |init, src_in, tgt_in, settings| {
            if iterate {
                icp::register(src_in, tgt_in, init, settings)
            } else {
                icp::evaluate_at(src_in, tgt_in, init, settings).map(|evaluation| icp::Outcome {
                    pose: init.to_vec(),
                    iterations: 0,
                    stop_reason: icp::StopReason::MaxIterations,
                    evaluation,
                    iteration_seconds: Vec::new(),
                    final_evaluation_seconds: 0.0,
                    correspondences: Vec::new(),
                    certificates: None,
                })
            }
        },
    )?;
    let dof = out.evaluation.gradient.len();
    let (rotation, translation) = rigid_parts(&out.pose, dim)?;
    let ev = out.evaluation;
    Ok(IcpOutcome {
        pose: out.pose,
        dim,
        rotation: read_only(square(py, rotation, dim)?.into_bound(py)),
        translation: read_only(translation.into_pyarray(py)),
        iterations: out.iterations,
        stop_reason: out.stop_reason.name(),
        hessian: read_only(square(py, ev.hessian, dof)?.into_bound(py)),
        gradient: read_only(ev.gradient.into_pyarray(py)),
        score_outer: ev.score_outer,
        cost: ev.cost,
        num_correspondences: ev.num_correspondences,
        num_in_gate: ev.num_in_gate,
        sum_squares: ev.sum_squares,
        irls_sum_squares: ev.irls_sum_squares,
        irls_weight_sum: ev.irls_weight_sum,
        sum_squared_distances: ev.sum_squared_distances,
        iteration_seconds: PyTuple::new(py, out.iteration_seconds)?.unbind(),
        final_evaluation_seconds: out.final_evaluation_seconds,
        correspondences: out.correspondences,
        certificates: out.certificates,
    })
}

/// A `(D+1, D+1)` or `(dof, dof)` array's values, checked for its shape.
fn square_of<'a>(
    a: &'a Option<PyReadonlyArray2<'_, f64>>,
    arg: &'static str,
    n: usize,
) -> PyResult<Option<&'a [f64]>> {
    a.as_ref()
        .map(|a| {
            if a.shape() != [n, n] {
                return Err(PyValueError::new_err(format!(
                    "{arg}: expected shape ({n}, {n}), got {:?}",
                    a.shape()
                )));
            }
            c_slice(a, arg)
        })
        .transpose()
}

type Probed<'py> = (
    Vec<u8>,
    Bound<'py, PyArray2<f64>>,
    Vec<f64>,
    Bound<'py, PyArray3<f64>>,
);

#[pyfunction]
// By position, as `register_icp` up to `extrapolate` (`init_pose` replaced by the restarts'
// `init_poses`, no `iterate`); then the probe's own.
#[pyo3(signature = (
    source, target, init_poses, method, kernel, kernel_scale, max_correspondence_distance,
    max_iterations, translation_tolerance, rotation_tolerance, optimizer, min_correspondences,
    num_threads, source_covariances, target_normals, target_covariances, step_projector,
    extrapolate, result, home_radius, home_cos_angle, grid, stride, half_width, ntheta,
    angular_step, tight, covariance, chi2, here, stop_ratio, near_move, near_turn,
    implausible_start, implausible_information, implausible_chi2
))]
#[allow(clippy::too_many_arguments)]
/// The wrong-basin probe's restart path in one call (`scanreg_core::basin::probe_restarts`):
/// the correlative start on `grid` (2D, when given), the registration from it and from each of
/// `init_poses` (`(K, D+1, D+1)`; a solve that comes back within `home_radius` and a rotation
/// of cosine `home_cos_angle` of `result` stops there), each outcome compared with `result`
/// as `compare_basin_outcomes` does, and no more restarts after the first far distinct one
/// (beyond `near_move` / `near_turn`, not beyond `implausible_chi2` of `implausible_start`)
/// explaining more than `stop_ratio × here`. Returns `(kinds, offsets (K', dof), fractions,
/// poses (K', D+1, D+1))` for the `K'` outcomes read, the correlative start's first.
fn probe_restarts<'py>(
    py: Python<'py>,
    source: PyReadonlyArray2<'_, f64>,
    target: &Bound<'_, PyAny>,
    init_poses: PyReadonlyArray3<'_, f64>,
    method: &str,
    kernel: &str,
    kernel_scale: f64,
    max_correspondence_distance: f64,
    max_iterations: usize,
    translation_tolerance: f64,
    rotation_tolerance: f64,
    optimizer: &str,
    min_correspondences: usize,
    num_threads: Option<usize>,
    source_covariances: Option<PyReadonlyArray3<'_, f64>>,
    target_normals: Option<PyReadonlyArray2<'_, f64>>,
    target_covariances: Option<PyReadonlyArray3<'_, f64>>,
    step_projector: Option<PyReadonlyArray2<'_, f64>>,
    extrapolate: bool,
    result: PyReadonlyArray2<'_, f64>,
    home_radius: f64,
    home_cos_angle: f64,
    grid: Option<PyRef<'_, crate::correlative::CorrelativeGrid>>,
    stride: usize,
    half_width: i64,
    ntheta: i64,
    angular_step: f64,
    tight: f64,
    covariance: Option<PyReadonlyArray2<'_, f64>>,
    chi2: f64,
    here: f64,
    stop_ratio: f64,
    near_move: f64,
    near_turn: f64,
    implausible_start: Option<PyReadonlyArray2<'_, f64>>,
    implausible_information: Option<PyReadonlyArray2<'_, f64>>,
    implausible_chi2: f64,
) -> PyResult<Probed<'py>> {
    let correlative = grid.as_ref().map(|g| basin::CorrelativeStart {
        grid: g.inner(),
        stride,
        half_width,
        ntheta,
        angular_step,
    });
    let (dim, out) = with_inputs(
        py,
        &source,
        |dim| {
            let shape = init_poses.shape();
            if shape[1] != dim + 1 || shape[2] != dim + 1 {
                return Err(PyValueError::new_err(format!(
                    "init_poses: expected shape (K, {0}, {0}), got {shape:?}",
                    dim + 1
                )));
            }
            let dof = if dim == 2 { 3 } else { 6 };
            let res = pose(&result, "result", dim)?;
            let cov = square_of(&covariance, "covariance", dof)?;
            let implausible = match (
                square_of(&implausible_start, "implausible_start", dim + 1)?,
                square_of(&implausible_information, "implausible_information", dof)?,
            ) {
                (Some(start), Some(information)) => Some(basin::Implausible {
                    start,
                    information,
                    chi2: implausible_chi2,
                }),
                (None, None) => None,
                _ => {
                    return Err(PyValueError::new_err(
                        "implausible_start, implausible_information: give both or neither",
                    ))
                }
            };
            Ok((c_slice(&init_poses, "init_poses")?, res, cov, implausible))
        },
        true,
        target,
        method,
        kernel,
        kernel_scale,
        max_correspondence_distance,
        max_iterations,
        translation_tolerance,
        rotation_tolerance,
        optimizer,
        min_correspondences,
        num_threads,
        &source_covariances,
        &target_normals,
        &target_covariances,
        &step_projector,
        extrapolate,
        |(inits, res, cov, implausible), src_in, tgt_in, settings| {
            let stop = basin::Stop {
                here,
                stop_ratio,
                near_move,
                near_turn,
                implausible,
            };
            basin::probe_restarts(
                src_in,
                tgt_in,
                settings,
                res,
                inits,
                correlative.as_ref(),
                home_radius,
                home_cos_angle,
                tight,
                cov,
                chi2,
                &stop,
            )
        },
    )?;
    let dof = if dim == 2 { 3 } else { 6 };
    let m = dim + 1;
    let k = out.outcomes.kinds.len();
    let offsets = numpy::ndarray::Array2::from_shape_vec((k, dof), out.outcomes.offsets)
        .map_err(|e| PyValueError::new_err(format!("internal: {e}")))?;
    let poses = numpy::ndarray::Array3::from_shape_vec((k, m, m), out.poses)
        .map_err(|e| PyValueError::new_err(format!("internal: {e}")))?;
    Ok((
        out.outcomes.kinds.into_iter().map(|v| v as u8).collect(),
        offsets.into_pyarray(py),
        out.outcomes.fractions,
        poses.into_pyarray(py),
    ))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<IcpOutcome>()?;
    m.add_function(wrap_pyfunction!(register_icp, m)?)?;
    m.add_function(wrap_pyfunction!(probe_restarts, m)?)?;
    Ok(())
}
