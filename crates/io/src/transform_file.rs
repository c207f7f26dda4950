//! A transform file written by its name: ITK's HDF5 transform file for `.h5`, `.hdf5` or `.hdf` ([`crate::itk_h5`]),
//! else ITK's text `.tfm`, or ANTs' MATLAB `.mat` for a name ending so ([`crate::itk_tfm`]). What every export of an
//! exact transform calls, so that each of them writes every one of these.

use std::path::Path;

use crate::error::Result;
use crate::itk_h5::{self, H5Transform};
use crate::itk_tfm::{self, ItkTransform};

/// Writes `transform` to `path` in the ITK file its name asks for (module docs), atomically.
///
/// # Errors
/// What [`itk_h5::write`] or [`itk_tfm::write`] refuse (a transform ITK cannot take, a spline in a `.mat`), or the
/// write itself; nothing is written then.
pub fn write(path: &Path, transform: &ItkTransform) -> Result<()> {
    if itk_tfm::is_hdf5_name(path) {
        itk_h5::write(path, &[H5Transform::Transform(transform)])
    } else {
        itk_tfm::write(path, transform)
    }
}
