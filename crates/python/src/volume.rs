//! Volumes in and out. A volume crosses as a numpy array of shape (ni, nj, nk) in Fortran order (i fastest, as
//! every reader stores it and as nibabel presents it), in its stored type (uint8, int16, uint16 or float32, after
//! the rescale; the rules of docs/formats.md), with its 4×4 `lps_from_index`.
//!
//! Reading hands the reader's sample vector to numpy as the array's buffer: no copy. The other way, an array is
//! copied once into the writer's or the resampler's volume.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use numpy::ndarray::{Array2, Array3, ShapeBuilder};
use numpy::{PyArray, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::volume::{GeometrySource, Modality, VoxelData};
use warpbench_io::{LoadOptions, Part, Volume};

use crate::errors::{self, guarded};

/// Reads a volume in any format the command line reads (NIfTI, NRRD, DICOM series folder or file, MetaImage):
/// `(array, lps_from_index, header)`, the header a JSON text (geometry source, modality, rescale, metadata).
/// `frame` chooses a frame of a 4-D file, `series` a series of a DICOM folder of several (by its SeriesInstanceUID).
#[pyfunction]
#[pyo3(signature = (path, frame = None, series = None))]
pub fn read_volume(
    py: Python<'_>,
    path: PathBuf,
    frame: Option<usize>,
    series: Option<String>,
) -> PyResult<(Py<PyAny>, Py<PyAny>, String)> {
    if frame.is_some() && series.is_some() {
        return Err(PyValueError::new_err(format!(
            "{}: pass frame= (a frame of a 4-D file) or series= (a series of a DICOM folder), not both",
            path.display()
        )));
    }
    let part = frame.map(Part::Frame).or(series.map(Part::Series));
    let volume = guarded(py, || {
        LoadOptions::new().part(part.as_ref()).open(&path).map_err(|e| match &e.kind {
            &warpbench_io::ErrorKind::FrameRequired { frames } => PyValueError::new_err(format!(
                "{}: 4-D file with {frames} frames: pass frame=N (0 to {}) to read one",
                path.display(),
                frames.saturating_sub(1)
            )),
            warpbench_io::ErrorKind::MultipleSeries(_) => {
                PyValueError::new_err(format!("{e}\npass series=UID to read one"))
            }
            _ => errors::io(e),
        })
    })?;
    let header = serde_json::json!({
        "geometry_source": volume.geometry_source,
        "modality": modality_name(&volume.modality),
        "rescale": volume.rescale,
        "metadata": volume.metadata,
    })
    .to_string();
    let lps = matrix(py, &volume.lps_from_index.rows());
    Ok((samples_to_numpy(py, volume.dims, volume.data)?, lps, header))
}

/// Writes `array` with `lps_from_index` as the command line writes volumes: NIfTI-1 (`.nii`, `.nii.gz`), NRRD
/// (`.nrrd`) or MetaImage (`.mha`, `.mhd`), chosen by the name, atomically (an interrupted write leaves no partial
/// file).
#[pyfunction]
#[pyo3(signature = (path, array, lps_from_index, modality = None))]
pub fn write_volume(
    py: Python<'_>,
    path: PathBuf,
    array: &Bound<'_, PyAny>,
    lps_from_index: PyReadonlyArray2<'_, f64>,
    modality: Option<&str>,
) -> PyResult<()> {
    let mut volume = volume_from_numpy(&path, array, &lps_from_index)?;
    volume.modality = modality.map_or(Modality::Unknown, Modality::from_dicom);
    guarded(py, || warpbench_io::write_volume(&path, &volume).map_err(errors::io))
}

/// The DICOM-style name of a modality (`CT`, `MR`, another code, or `None` when unknown).
#[must_use]
pub fn modality_name(m: &Modality) -> Option<String> {
    match m {
        Modality::Ct => Some("CT".into()),
        Modality::Mr => Some("MR".into()),
        Modality::Other(code) => Some(code.clone()),
        Modality::Unknown => None,
    }
}

/// A 4×4 matrix as a numpy array.
#[must_use]
pub fn matrix(py: Python<'_>, rows: &[[f64; 4]; 4]) -> Py<PyAny> {
    let array = Array2::from_shape_fn((4, 4), |(r, c)| rows[r][c]);
    PyArray::from_owned_array(py, array).into_any().unbind()
}

/// The samples as a (ni, nj, nk) Fortran-order array that owns the reader's vector.
pub fn samples_to_numpy(py: Python<'_>, dims: [usize; 3], data: VoxelData) -> PyResult<Py<PyAny>> {
    fn wrap<T: numpy::Element>(py: Python<'_>, dims: [usize; 3], v: Vec<T>) -> PyResult<Py<PyAny>> {
        let array = Array3::from_shape_vec((dims[0], dims[1], dims[2]).f(), v)
            .map_err(|e| PyValueError::new_err(format!("samples do not fill {dims:?}: {e}")))?;
        Ok(PyArray::from_owned_array(py, array).into_any().unbind())
    }
    match data {
        VoxelData::U8(v) => wrap(py, dims, v),
        VoxelData::I16(v) => wrap(py, dims, v),
        VoxelData::U16(v) => wrap(py, dims, v),
        VoxelData::F32(v) => wrap(py, dims, v),
    }
}

/// A 4×4 `lps_from_index` from numpy, checked.
pub fn lps_from_index(path: &Path, m: &PyReadonlyArray2<'_, f64>) -> PyResult<Transform<Lps, Index>> {
    let view = m.as_array();
    if view.shape() != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "{}: lps_from_index must be a 4×4 matrix, not {:?}",
            path.display(),
            view.shape()
        )));
    }
    Ok(Transform::from_matrix(Matrix4::from_fn(|r, c| view[[r, c]])))
}

/// A volume from a (ni, nj, nk) array of uint8, int16, uint16 or float32 (any memory layout) and its
/// `lps_from_index`; `path` names it in messages. The samples are copied once, i fastest.
pub fn volume_from_numpy(path: &Path, array: &Bound<'_, PyAny>, lps: &PyReadonlyArray2<'_, f64>) -> PyResult<Volume> {
    fn take<T: numpy::Element + Copy>(a: &Bound<'_, PyAny>) -> Option<PyResult<([usize; 3], Vec<T>)>> {
        let a = a.cast::<PyArray<T, numpy::Ix3>>().ok()?;
        let a: PyReadonlyArray3<'_, T> = a.readonly();
        let shape = a.shape();
        let dims = [shape[0], shape[1], shape[2]];
        // The transposed view iterates in the original's Fortran order: i fastest.
        Some(Ok((dims, a.as_array().t().iter().copied().collect())))
    }
    let (dims, data) = if let Some(r) = take::<u8>(array) {
        let (d, v) = r?;
        (d, VoxelData::U8(v))
    } else if let Some(r) = take::<i16>(array) {
        let (d, v) = r?;
        (d, VoxelData::I16(v))
    } else if let Some(r) = take::<u16>(array) {
        let (d, v) = r?;
        (d, VoxelData::U16(v))
    } else if let Some(r) = take::<f32>(array) {
        let (d, v) = r?;
        (d, VoxelData::F32(v))
    } else {
        return Err(PyValueError::new_err(format!(
            "{}: a volume is a 3-D array of uint8, int16, uint16 or float32",
            path.display()
        )));
    };
    let transform = lps_from_index(path, lps)?;
    Volume::new(path, dims, data, transform, GeometrySource::NiftiSform { code: 1 }).map_err(errors::io)
}
