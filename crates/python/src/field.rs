//! Displacement fields in: any file the command line's `--field` reads (ITK's and ANTs' NIfTI, Slicer's NRRD,
//! MetaImage, or an elastix transform parameter file sampled on its fixed grid), as a (ni, nj, nk, 3) float32 array
//! of LPS vectors with its `lps_from_index`.

use std::path::PathBuf;

use numpy::ndarray::{Array4, ShapeBuilder};
use numpy::{PyArray, PyReadonlyArray2, PyReadonlyArray4};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use warpbench_app::project::stack::FieldLayer;
use warpbench_io::displacement::{self, FieldDirection, FieldSource, ReadField};
use warpbench_io::learn2reg as l2r;
use warpbench_solver::field::SampledField;

use crate::errors::{self, guarded};
use crate::volume::{lps_from_index, matrix};

/// A grid from Python: its sizes and its 4×4 `lps_from_index`.
type Grid<'py> = (Vec<usize>, PyReadonlyArray2<'py, f64>);

/// What [`read_field`] returns: the vectors, `lps_from_index`, the source and the direction.
pub type FieldParts = (Py<PyAny>, Py<PyAny>, String, Option<String>, Vec<String>);

/// Reads the displacement field at `path` as `warpbench warp --field` reads it: `(array, lps_from_index, source,
/// direction)`, the array (ni, nj, nk, 3) float32 LPS vectors; `source` the flavour (`itk`, `ants`, `nrrd`,
/// `metaimage`), `elastix` for a transform parameter file, `itk_h5` for ITK's HDF5 transform file, `itk_tfm` for its
/// text file or `dicom` for a DICOM Deformable Spatial Registration; `direction` `pullback` or `forward` where the
/// file says (NRRD, `.h5`, `.tfm`, DICOM), else `None`.
///
/// With `pair`, the fixed and the moving grid (`(dims, lps_from_index)` each), a Learn2Reg `.npz` is read too: its
/// voxel steps turned into the pull-back on the fixed grid (`learn2reg`, direction `pullback`); with `learn2reg`
/// any file is read so (the challenge's NIfTI form says nothing of its units). An FSL FNIRT warp (`--fout`, `--cout`)
/// is read against the two grids too, the fixed one its reference (`fnirt`, direction `pullback`). An ITK transform
/// file of B-splines (`.tfm` or `.h5`), which gives no grid of its own, is sampled on the fixed grid.
#[pyfunction]
#[pyo3(signature = (path, pair = None, learn2reg = false))]
pub fn read_field(
    py: Python<'_>,
    path: PathBuf,
    pair: Option<(Grid<'_>, Grid<'_>)>,
    learn2reg: bool,
) -> PyResult<FieldParts> {
    let three = |side: &str, d: Vec<usize>| -> PyResult<[usize; 3]> {
        d.try_into().map_err(|d: Vec<usize>| {
            PyValueError::new_err(format!("{}: the {side} grid has 3 sizes, not {d:?}", path.display()))
        })
    };
    let pair = match pair {
        Some(((fixed_dims, fixed), (moving_dims, moving))) => Some((
            three("fixed", fixed_dims)?,
            lps_from_index(&path, &fixed)?,
            three("moving", moving_dims)?,
            lps_from_index(&path, &moving)?,
        )),
        None => None,
    };
    let read = guarded(py, || {
        let fnirt = path.is_file() && warpbench_io::nifti::fsl_intent(&path).map_err(errors::io)?.is_some();
        let steps_in_voxels =
            !fnirt && (learn2reg || (path.is_file() && l2r::is_npz_file(&path).map_err(errors::io)?));
        match pair {
            Some((dims, fixed, moving_dims, moving)) if fnirt => {
                let read = warpbench_io::fnirt::read_pullback(&path, (dims, &fixed), (moving_dims, &moving))
                    .map_err(errors::io)?;
                Ok(ReadField {
                    field: read.field,
                    source: FieldSource::Fnirt,
                    direction: Some(FieldDirection::Pullback),
                    warnings: read.warnings,
                })
            }
            Some((dims, fixed, _, moving)) if steps_in_voxels => {
                let steps = l2r::read_voxel_field(&path).map_err(errors::io)?;
                let field = l2r::pullback_from_voxels(&path, &steps, dims, &fixed, &moving).map_err(errors::io)?;
                Ok(ReadField {
                    field,
                    source: FieldSource::Learn2Reg,
                    direction: Some(FieldDirection::Pullback),
                    warnings: Vec::new(),
                })
            }
            None if steps_in_voxels => Err(PyValueError::new_err(format!(
                "{}: a Learn2Reg field holds steps in the voxels of its fixed and moving images: read it with \
                 read_field(path, fixed=..., moving=...{})",
                path.display(),
                if learn2reg { ", learn2reg=True" } else { "" }
            ))),
            // An ITK transform file of B-splines gives no grid of its own: it is sampled on the fixed grid.
            Some((dims, fixed, _, _)) => {
                let geometry_source = warpbench_io::volume::GeometrySource::ItkTransformFile;
                let grid = displacement::SampleGrid { dims, lps_from_index: fixed, geometry_source };
                displacement::read_field_on(&path, Some(&grid)).map_err(errors::io)
            }
            None => displacement::read_field_info(&path).map_err(errors::io),
        }
    })?;
    let field = read.field;
    let [ni, nj, nk] = field.dims;
    let mut flat = Vec::with_capacity(3 * field.displacements_lps.len());
    for a in 0..3 {
        flat.extend(field.displacements_lps.iter().map(|d| d[a]));
    }
    let array = Array4::from_shape_vec((ni, nj, nk, 3).f(), flat)
        .map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))?;
    let source = read.source.name().to_owned();
    let direction = read.direction.map(|d| d.name().to_owned());
    let lps = matrix(py, &field.lps_from_index.rows());
    Ok((PyArray::from_owned_array(py, array).into_any().unbind(), lps, source, direction, read.warnings))
}

/// A `Field`'s parts from Python, as `fit(initial_field=)` takes one: its (ni, nj, nk, 3) float32 LPS vectors, its
/// 4×4 `lps_from_index`, and whether the file said it is the forward map (`direction == "forward"`).
pub type FieldArrays<'py> = (PyReadonlyArray4<'py, f32>, PyReadonlyArray2<'py, f64>, bool);

/// The layer of the warp stack a `Field` is under the landmark fit: its vectors on its grid, as the pull-back F
/// (F(x) = x + D(x)), or as F⁻¹ when it is the forward map. `name` names it in messages.
///
/// # Errors
/// An array that is not (ni, nj, nk, 3), a matrix that is not 4×4 or not invertible, a vector that is not finite.
pub fn field_layer(name: &str, (array, lps, forward): &FieldArrays<'_>) -> PyResult<FieldLayer> {
    let view = array.as_array();
    let shape = view.shape();
    if shape.len() != 4 || shape[3] != 3 {
        return Err(PyValueError::new_err(format!("{name}: the field's array must be (ni, nj, nk, 3), not {shape:?}")));
    }
    let dims = [shape[0], shape[1], shape[2]];
    let lps_from_index = lps_from_index(std::path::Path::new(name), lps)?;
    let mut vectors = Vec::with_capacity(dims.iter().product());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                vectors.push([view[[i, j, k, 0]], view[[i, j, k, 1]], view[[i, j, k, 2]]]);
            }
        }
    }
    let bad = |e: warpbench_solver::SolverError| PyValueError::new_err(format!("{name}: {e}"));
    Ok(if *forward {
        FieldLayer::forward(SampledField::new(dims, lps_from_index, vectors).map_err(bad)?, name)
    } else {
        FieldLayer::pullback(SampledField::new(dims, lps_from_index, vectors).map_err(bad)?, name)
    })
}
