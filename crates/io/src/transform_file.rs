//! A transform file written by its name: ITK's HDF5 transform file for `.h5`, `.hdf5` or `.hdf` ([`crate::itk_h5`]),
//! else ITK's text `.tfm`, or ANTs' MATLAB `.mat` for a name ending so ([`crate::itk_tfm`]). What every export of an
//! exact transform calls, so that each of them writes every one of these. Read back by content, any of the three, as
//! the chain it holds ([`read_chain`]).

use std::path::Path;

use crate::error::{Error, Result};
use crate::itk_chain::{ItkChain, ItkStep};
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

/// Reads an ITK transform file of any of the three kinds, told apart by content: an `.h5` ([`itk_h5::read`]), a
/// text `.tfm` of one transform or a composite ([`crate::itk_chain::parse_text`]), or an affine `.mat`; as the chain
/// of transforms it holds.
///
/// # Errors
/// What those readers refuse, naming the file.
pub fn read_chain(path: &Path) -> Result<ItkChain> {
    let head = crate::displacement::head(path)?;
    if itk_h5::looks_like_hdf5(&head) {
        return itk_h5::read(path);
    }
    if !itk_tfm::looks_like_text(&head) {
        // An affine .mat (told by its name or its bytes), or what its reader refuses.
        return Ok(ItkChain { steps: vec![ItkStep::Transform(itk_tfm::read(path)?)] });
    }
    let len = crate::files::check_regular_file(path)?.len();
    if len > itk_tfm::MAX_FILE_BYTES {
        return Err(Error::invalid(path, format!("{len} bytes is too long for a transform file")));
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::invalid(path, format!("the transform file is not UTF-8 text ({e})")))?;
    crate::itk_chain::parse_text(path, &text)
}
