//! Displacement fields in: any file the command line's `--field` reads (ITK's and ANTs' NIfTI, Slicer's NRRD,
//! MetaImage, or an elastix transform parameter file sampled on its fixed grid), as a (ni, nj, nk, 3) float32 array
//! of LPS vectors with its `lps_from_index`.

use std::path::PathBuf;

use numpy::PyArray;
use numpy::ndarray::{Array4, ShapeBuilder};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use warpbench_io::displacement::{self, FieldSource};

use crate::errors::{self, guarded};
use crate::volume::matrix;

/// What [`read_field`] returns: the vectors, `lps_from_index`, the source and the direction.
pub type FieldParts = (Py<PyAny>, Py<PyAny>, String, Option<String>);

/// Reads the displacement field at `path` as `warpbench warp --field` reads it: `(array, lps_from_index, source,
/// direction)`, the array (ni, nj, nk, 3) float32 LPS vectors; `source` the flavour (`itk`, `ants`, `nrrd`,
/// `metaimage`), `elastix` for a transform parameter file, `itk_h5` for ITK's HDF5 transform file or `dicom` for a DICOM
/// Deformable Spatial Registration; `direction` `pullback` or `forward` where the file says (NRRD, `.h5`, DICOM), else
/// `None`.
#[pyfunction]
pub fn read_field(py: Python<'_>, path: PathBuf) -> PyResult<FieldParts> {
    let read = guarded(py, || displacement::read_field_info(&path).map_err(errors::io))?;
    let field = read.field;
    let [ni, nj, nk] = field.dims;
    let mut flat = Vec::with_capacity(3 * field.displacements_lps.len());
    for a in 0..3 {
        flat.extend(field.displacements_lps.iter().map(|d| d[a]));
    }
    let array = Array4::from_shape_vec((ni, nj, nk, 3).f(), flat)
        .map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))?;
    let source = match read.source {
        FieldSource::Field(format) => format.name().to_owned(),
        FieldSource::ElastixTransform => "elastix".to_owned(),
        FieldSource::ItkHdf5 => "itk_h5".to_owned(),
        FieldSource::DicomRegistration => "dicom".to_owned(),
    };
    let direction = read.direction.map(|d| d.name().to_owned());
    let lps = matrix(py, &field.lps_from_index.rows());
    Ok((PyArray::from_owned_array(py, array).into_any().unbind(), lps, source, direction))
}
