//! # warpbench-python
//!
//! The extension module `warpbench._warpbench` under the Python package `warpbench` (`python/warpbench/`). It is a
//! thin layer: every number comes from the code the command line runs (`warpbench_app`, built without the window),
//! so a Python call and the CLI on the same inputs give the same numbers and the same bytes.
//!
//! - [`volume`]: volumes in and out, as numpy arrays in i-j-k order (the reader's vector becomes the array's buffer,
//!   no copy) and their `lps_from_index`.
//! - [`field`](mod@field): displacement fields in, in every flavour `--field` reads (elastix transforms too).
//! - [`landmarks`](mod@landmarks): landmark pairs in and out in every format the CLI reads and writes.
//! - [`warp`](mod@warp): `Warp`, a fit of landmark pairs (on a starting transform), and what it maps, samples,
//!   resamples and writes.
//! - [`command`]: the subcommands with a `--json` report (`align`, `register`, `suggest`, …) run in process on an
//!   argument list, their report returned as the same JSON text.
//! - [`errors`]: the CLI's failures as Python exceptions (`ValueError` for bad input, `OSError` for files that cannot
//!   be read or written, `RuntimeError` for internal errors and panics); long work releases the GIL.

#![allow(clippy::needless_pass_by_value, reason = "pyo3 extracts every argument of a Python function by value")]

use pyo3::prelude::*;

pub mod command;
pub mod errors;
pub mod field;
pub mod landmarks;
pub mod volume;
pub mod warp;

/// The extension module.
#[pymodule]
fn _warpbench(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(volume::read_volume, m)?)?;
    m.add_function(wrap_pyfunction!(volume::write_volume, m)?)?;
    m.add_function(wrap_pyfunction!(field::read_field, m)?)?;
    m.add_function(wrap_pyfunction!(landmarks::read_landmarks, m)?)?;
    m.add_function(wrap_pyfunction!(landmarks::write_landmarks, m)?)?;
    m.add_function(wrap_pyfunction!(command::run_command, m)?)?;
    m.add_function(wrap_pyfunction!(errors::panic_for_test, m)?)?;
    m.add_class::<warp::Warp>()?;
    Ok(())
}
