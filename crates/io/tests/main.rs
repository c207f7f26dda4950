//! The io crate's integration tests, one module per file beside this one, built as one test binary: each binary
//! would link the crate again and compile its generics again at the crate's opt-level, 13 times over.
//!
//! Run one file's tests with its module name as the filter, e.g. `cargo test -p warpbench-io --test io nifti::`.

mod afni;
mod afni_dataset;
mod ants_mat;
mod bad_inputs;
mod dicom;
mod dicom_conformance;
mod dicom_reg;
mod elastix;
mod elastix_points;
mod fnirt;
mod fsl;
mod itk_chain;
mod itk_h5;
mod itk_h5_write;
mod itk_linear;
mod itk_tps;
mod jpegls;
mod landmarks;
mod learn2reg;
mod lta;
mod metaimage;
mod mgh;
mod minc;
mod mni;
mod ngff;
mod nifti;
mod nifti_pair;
mod nrrd;
mod support;
