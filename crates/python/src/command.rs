//! The command line's subcommands run in process: the Python functions with a CLI twin (`align`, `register`,
//! `suggest`, …) build its argument list and take back its `--json` report, the same text the CLI prints.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use warpbench_app::cli::{self, Headless};

use crate::errors::{guarded, to_py};

/// Runs `warpbench <argv…>` in this process and returns what it printed on stdout (the JSON report with
/// `--json`). Usage errors raise `ValueError` with clap's message; failures raise as the module `errors` says.
#[pyfunction]
pub fn run_command(py: Python<'_>, argv: Vec<String>) -> PyResult<String> {
    let parsed = <Headless as clap::Parser>::try_parse_from(std::iter::once("warpbench".to_owned()).chain(argv))
        .map_err(|e| PyValueError::new_err(e.render().to_string().trim_end().to_owned()))?;
    guarded(py, || {
        let mut out = Vec::new();
        cli::run(parsed.command, &mut out).map_err(|f| to_py(&f))?;
        String::from_utf8(out).map_err(|e| PyValueError::new_err(format!("the report is not UTF-8: {e}")))
    })
}
