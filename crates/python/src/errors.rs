//! The CLI's failures as Python exceptions, and the guard every call runs under.
//!
//! | CLI | Python |
//! |---|---|
//! | exit 2, a file that cannot be opened, read or written (the OS said no) | `OSError` (with `errno`) |
//! | exit 2, any other bad input or usage | `ValueError` |
//! | exit 1, an internal error; a panic | `RuntimeError` |
//!
//! The message is the CLI's (`warpbench: …` less the prefix): it names the file, or the landmark (1-based), and the
//! problem.

use std::panic::{AssertUnwindSafe, catch_unwind};

use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use warpbench_app::exit::Failure;

/// `failure` as the exception a Python user expects (module docs).
#[must_use]
pub fn to_py(failure: &Failure) -> PyErr {
    let message = failure.message();
    match failure {
        Failure::BadInput(e) => match os_error(e) {
            Some(errno) => PyOSError::new_err((errno, message)),
            None => PyValueError::new_err(message),
        },
        Failure::Internal(_) | Failure::AccuracyGate(_) | Failure::Cancelled(_) => PyRuntimeError::new_err(message),
    }
}

/// An `anyhow` error from the modules the subcommands share (always about the input).
#[must_use]
pub fn bad_input(e: anyhow::Error) -> PyErr {
    to_py(&Failure::BadInput(e))
}

/// A reader's or writer's error.
#[must_use]
pub fn io(e: warpbench_io::Error) -> PyErr {
    to_py(&Failure::from(e))
}

/// The OS error number when the root of `e` is the operating system refusing a file (not found, no permission, …).
fn os_error(e: &anyhow::Error) -> Option<i32> {
    e.chain().find_map(|cause| {
        if let Some(io) = cause.downcast_ref::<std::io::Error>() {
            return Some(io.raw_os_error().unwrap_or(0));
        }
        match &cause.downcast_ref::<warpbench_io::Error>()?.kind {
            warpbench_io::ErrorKind::Io(io) => Some(io.raw_os_error().unwrap_or(0)),
            _ => None,
        }
    })
}

/// Runs `work` without the GIL (other Python threads and Dask's workers go on meanwhile), turning a panic into a
/// `RuntimeError` instead of letting it cross into the interpreter.
pub fn guarded<T: Send>(py: Python<'_>, work: impl FnOnce() -> PyResult<T> + Send) -> PyResult<T> {
    py.detach(|| catch_unwind(AssertUnwindSafe(work))).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(ToString::to_string)
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".to_owned());
        Err(PyRuntimeError::new_err(format!("internal error in warpbench (a bug; please report it): {what}")))
    })
}

/// Panics inside [`guarded`]: how the tests check that a panic reaches Python as a `RuntimeError` and the
/// interpreter goes on. Not part of the package's API (the Python side does not export it).
#[pyfunction]
pub fn panic_for_test(py: Python<'_>) -> PyResult<()> {
    guarded(py, || -> PyResult<()> { panic!("the panic check of the Python package") })
}
