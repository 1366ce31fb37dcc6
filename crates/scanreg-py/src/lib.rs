//! `scanreg._core`: the thin PyO3 binding of `scanreg-core`.
//!
//! Every function here converts numpy arrays to slices, validates shapes and contiguity,
//! releases the GIL around the core call and maps core errors to `ValueError`. No algorithm.

use pyo3::prelude::*;

mod censi;
mod convert;
mod correlative;
mod deskew;
mod global;
mod io;
mod keyframe_map;
pub mod knn;
mod local_map;
mod map_check;
mod measure;
mod ndt2d;
mod ndt3d;
mod paired;
mod place;
mod preprocess;
mod register;
mod simulate;
mod sweep;
mod sweep_residual;
mod threads;
mod trust;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    paired::register(m)?;
    correlative::register(m)?;
    ndt2d::register(m)?;
    ndt3d::register(m)?;
    deskew::register(m)?;
    knn::register(m)?;
    keyframe_map::register(m)?;
    local_map::register(m)?;
    preprocess::register(m)?;
    simulate::register(m)?;
    sweep::register(m)?;
    sweep_residual::register(m)?;
    io::register(m)?;
    register::register(m)?;
    censi::register(m)?;
    measure::register(m)?;
    place::register(m)?;
    threads::register(m)?;
    global::register(m)?;
    trust::register(m)?;
    map_check::register(m)?;
    Ok(())
}
