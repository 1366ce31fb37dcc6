//! `scanreg._core`: the thin PyO3 binding of `scanreg-core`.
//!
//! Every function here converts numpy arrays to slices, validates shapes and contiguity,
//! releases the GIL around the core call and maps core errors to `ValueError`. No algorithm.

use pyo3::prelude::*;

mod convert;
mod io;
mod paired;
mod simulate;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    paired::register(m)?;
    simulate::register(m)?;
    io::register(m)?;
    Ok(())
}
