//! A transform file written by its name: ITK's HDF5 transform file for `.h5`, `.hdf5` or `.hdf` ([`crate::itk_h5`]),
//! else ITK's text `.tfm`, or ANTs' MATLAB `.mat` for a name ending so ([`crate::itk_tfm`]). What every export of an
//! exact transform calls, so that each of them writes every one of these. Read back by content, any of the three, as
//! the chain it holds ([`read_chain`]).

use std::path::Path;

use crate::error::Result;
use crate::itk_chain::{ItkChain, ItkStep};
use crate::itk_h5::{self, H5Transform};
use crate::itk_tfm::{self, ItkTransform};

/// Writes `transform` to `path` in the ITK file its name asks for (module docs), atomically.
///
/// # Errors
/// What [`itk_h5::write`] or [`itk_tfm::write`] refuse (a transform ITK cannot take, a spline in a `.mat`), or the
/// write itself; nothing is written then.
pub fn write(path: &Path, transform: &ItkTransform) -> Result<()> {
    if crate::afni::is_afni_name(path) {
        return Err(crate::Error::invalid(
            path,
            "a name ending .1D is AFNI's matrix file, not an ITK transform file: name it .tfm, .h5 or .mat, or write \
             AFNI's file (transform --format afni)",
        ));
    }
    if crate::lta::is_lta_name(path) {
        return Err(crate::Error::invalid(
            path,
            "a name ending .lta is FreeSurfer's transform file, not an ITK one: name it .tfm, .h5 or .mat, or write \
             FreeSurfer's file (transform --format lta)",
        ));
    }
    if crate::mni_xfm::is_xfm_name(path) {
        return Err(crate::Error::invalid(
            path,
            "a name ending .xfm is an MNI (MINC) transform file, which ITK reads as one: name it .tfm, .h5 or .mat, or \
             write the MNI file (transform --format minc)",
        ));
    }
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
    match itk_tfm::read_file(path)? {
        itk_tfm::Contents::Mat(bytes) => {
            let affine = itk_tfm::parse_mat(path, &bytes)?;
            Ok(ItkChain { steps: vec![ItkStep::Transform(ItkTransform::Affine(affine))] })
        }
        itk_tfm::Contents::Text(text) => crate::itk_chain::parse_text(path, &text),
    }
}
