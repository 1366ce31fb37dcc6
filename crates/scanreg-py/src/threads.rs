//! Binding of `scanreg_core::threads`: the process-wide thread budget.

use crate::convert::core_err;
use pyo3::prelude::*;

/// Size rayon's global pool to `num_threads` (once per process; see `scanreg.set_num_threads`).
#[pyfunction]
fn set_num_threads(num_threads: usize) -> PyResult<()> {
    scanreg_core::threads::set_num_threads(num_threads).map_err(core_err)
}

/// Threads of the global pool.
#[pyfunction]
fn get_num_threads() -> usize {
    scanreg_core::threads::num_threads()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(set_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(get_num_threads, m)?)
}
