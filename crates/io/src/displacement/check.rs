//! The checks the field readers and writers of every flavour share ([`crate::nifti`]'s and [`crate::nrrd::field`]'s):
//! a leaf, so that the flavours depend on it and not on the dispatch in [`crate::displacement`] that calls them.

use std::path::Path;

use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};

/// The checks every field writer makes before it writes anything: one vector per voxel of `dims`, an invertible and
/// finite `lps_from_index`, and finite vectors (the first bad one named by its voxel i, j, k).
pub(crate) fn check_field_to_write(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    let n = crate::volume::checked_voxel_count(path, dims)?;
    if displacements_lps.len() != n {
        return Err(Error::invalid(path, format!("{} displacements for dims {dims:?}", displacements_lps.len())));
    }
    if !lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    if let Some(ijk) = first_non_finite(dims, displacements_lps) {
        return Err(Error::invalid(path, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    Ok(())
}

/// The index (i, j, k) of the first voxel whose vector is not finite, if any; the readers' and writers' check.
pub(crate) fn first_non_finite(dims: [usize; 3], displacements: &[[f32; 3]]) -> Option<[usize; 3]> {
    let n = displacements.iter().position(|d| !d.iter().all(|v| v.is_finite()))?;
    let per_slice = (dims[0] * dims[1]).max(1);
    Some([n % dims[0].max(1), (n % per_slice) / dims[0].max(1), n / per_slice])
}
