//! Landmark pairs in and out, through the command line's own reader and writer (`warpbench landmarks`): BigWarp
//! CSV and JSON, plain CSV of pairs, a Slicer pair of point lists (`.mrk.json`, `.fcsv`) and window sessions.
//!
//! Pairs cross as two N×3 float64 arrays of LPS mm (moving, fixed; NaN where a half is not placed yet), the names and
//! the active flags.

use std::path::PathBuf;

use numpy::ndarray::Array2;
use numpy::{PyArray, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use warpbench_app::inputs::LandmarkSource;
use warpbench_app::landmarks::{LandmarkOutput, PairFileFormat, read_pairs, write_pairs};
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::LandmarkPair;

use crate::errors::{guarded, to_py};

/// What [`read_landmarks`] returns: moving (N×3), fixed (N×3), names, active flags, and the format's name.
type PairArrays = (Py<PyAny>, Py<PyAny>, Vec<String>, Vec<bool>, String);

/// Reads landmark pairs: one file of pairs (BigWarp CSV or JSON, plain CSV, a `.warpbench.json` session), or with
/// `fixed_path` a Slicer pair (`path` the moving list). `ras`: a BigWarp file's coordinates are RAS.
#[pyfunction]
#[pyo3(signature = (path, fixed_path = None, ras = false))]
pub fn read_landmarks(py: Python<'_>, path: PathBuf, fixed_path: Option<PathBuf>, ras: bool) -> PyResult<PairArrays> {
    let source = match fixed_path {
        Some(fixed) => LandmarkSource::SlicerPair { moving: path, fixed },
        None if path.to_string_lossy().to_ascii_lowercase().ends_with(".warpbench.json") => {
            LandmarkSource::Session(path)
        }
        None => LandmarkSource::Pairs(path),
    };
    let (pairs, format) = guarded(py, || read_pairs(&source, ras).map_err(|f| to_py(&f)))?;
    let side = |half: fn(&LandmarkPair) -> Option<Point3<Lps>>| {
        let array =
            Array2::from_shape_fn((pairs.len(), 3), |(i, a)| half(&pairs[i]).map_or(f64::NAN, |p| p.coords()[a]));
        PyArray::from_owned_array(py, array).into_any().unbind()
    };
    let moving = side(|p| p.moving);
    let fixed = side(|p| p.fixed);
    let names = pairs.iter().map(|p| p.name.clone()).collect();
    let active = pairs.iter().map(|p| p.active).collect();
    Ok((moving, fixed, names, active, format))
}

/// The pairs of two N×3 arrays (NaN rows: a half not placed), names and active flags; `what` names them in messages.
pub fn pairs_from_arrays(
    what: &str,
    moving: &PyReadonlyArray2<'_, f64>,
    fixed: &PyReadonlyArray2<'_, f64>,
    names: &[String],
    active: &[bool],
) -> PyResult<Vec<LandmarkPair>> {
    let (m, f) = (moving.as_array(), fixed.as_array());
    let n = m.nrows();
    if m.ncols() != 3 || f.ncols() != 3 || f.nrows() != n || names.len() != n || active.len() != n {
        return Err(PyValueError::new_err(format!(
            "{what}: moving and fixed must be N×3 with N names and N active flags (moving {:?}, fixed {:?}, {} \
             names, {} flags)",
            m.shape(),
            f.shape(),
            names.len(),
            active.len()
        )));
    }
    let point = |a: &numpy::ndarray::ArrayView2<'_, f64>, i: usize| {
        let c = [a[[i, 0]], a[[i, 1]], a[[i, 2]]];
        (!c.iter().all(|v| v.is_nan())).then(|| Point3::from_array(c))
    };
    Ok((0..n)
        .map(|i| LandmarkPair { name: names[i].clone(), active: active[i], moving: point(&m, i), fixed: point(&f, i) })
        .collect())
}

/// Writes pairs as `warpbench landmarks --out` does: BigWarp CSV (`.csv`) or JSON (`.json`), or `format`
/// (`bigwarp-csv`, `bigwarp-json`, `plain-csv`, `mni-tag`); with `fixed_path`, a Slicer pair (`path` the moving list). `ras`:
/// write BigWarp and plain CSV coordinates in RAS.
#[pyfunction]
#[pyo3(signature = (path, moving, fixed, names, active, fixed_path = None, format = None, ras = false))]
#[allow(clippy::too_many_arguments, reason = "the Python signature: the pairs' four arrays and the output's options")]
pub fn write_landmarks(
    py: Python<'_>,
    path: PathBuf,
    moving: PyReadonlyArray2<'_, f64>,
    fixed: PyReadonlyArray2<'_, f64>,
    names: Vec<String>,
    active: Vec<bool>,
    fixed_path: Option<PathBuf>,
    format: Option<&str>,
    ras: bool,
) -> PyResult<()> {
    let pairs = pairs_from_arrays(&path.display().to_string(), &moving, &fixed, &names, &active)?;
    let output = if let Some(fixed) = fixed_path {
        LandmarkOutput::SlicerPair { moving: path, fixed }
    } else {
        let format = match format {
            Some(name) => <PairFileFormat as clap::ValueEnum>::from_str(name, true).map_err(|_| {
                PyValueError::new_err(format!("format={name:?}: give bigwarp-csv, bigwarp-json, plain-csv or mni-tag"))
            })?,
            None => PairFileFormat::from_name(&path).map_err(|f| to_py(&f))?,
        };
        LandmarkOutput::Pairs { path, format }
    };
    guarded(py, || write_pairs(&output, &pairs, ras).map_err(|f| to_py(&f)))
}
