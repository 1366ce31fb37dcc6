//! Bindings for file-format helpers (`scanreg_core::lzf`).

use crate::convert::core_err;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use scanreg_core::lzf;

/// Decompress an LZF stream that must expand to exactly `expected_size` bytes.
#[pyfunction]
fn lzf_decompress<'py>(
    py: Python<'py>,
    data: &[u8],
    expected_size: usize,
) -> PyResult<Bound<'py, PyBytes>> {
    let out = py
        .detach(|| lzf::decompress(data, expected_size))
        .map_err(core_err)?;
    Ok(PyBytes::new(py, &out))
}

/// Compress bytes into an LZF stream.
#[pyfunction]
fn lzf_compress<'py>(py: Python<'py>, data: &[u8]) -> Bound<'py, PyBytes> {
    let out = py.detach(|| lzf::compress(data));
    PyBytes::new(py, &out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(lzf_decompress, m)?)?;
    m.add_function(wrap_pyfunction!(lzf_compress, m)?)?;
    Ok(())
}
