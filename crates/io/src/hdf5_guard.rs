//! A guard the HDF5 readers (MINC 2, ITK's `.h5`) put before `hdf5-pure` reads a dataset's values.

use std::path::Path;

use hdf5_pure::Dataset;

use crate::error::{Error, Result};

/// Refuses chunks larger than their dataset (HDF5 allows them only for datasets that may grow, which these are not)
/// or stored past the end of the file: `hdf5-pure` allocates a chunk's stored bytes, and then its size, before reading
/// them, so a chunk index that claims huge ones would exhaust memory (`tests/data/bad/huge_chunk.mnc`).
pub(crate) fn check_chunks(name: &Path, d: &Dataset, at: &str, file_bytes: u64) -> Result<()> {
    let Ok(Some(chunk)) = d.chunk_shape() else { return Ok(()) };
    let stored = d.chunks().map_err(|e| Error::invalid(name, format!("{at}'s chunk index cannot be read: {e}")))?;
    if let Some(c) = stored.iter().find(|c| c.address.checked_add(c.storage_size).is_none_or(|end| end > file_bytes)) {
        return Err(Error::truncated(
            name,
            format!(
                "{at} has a chunk of {} bytes at byte {}, past the end of the file's {file_bytes}",
                c.storage_size, c.address
            ),
        ));
    }
    let shape = d.shape().map_err(|e| Error::invalid(name, format!("{at}'s shape: {e}")))?;
    let element = d.element_size().map_err(|e| Error::invalid(name, format!("{at}'s type: {e}")))?;
    let bytes = |dims: &[u64]| dims.iter().try_fold(u128::from(element), |a, &n| a.checked_mul(u128::from(n)));
    let (chunk_bytes, data_bytes) = (bytes(&chunk).unwrap_or(u128::MAX), bytes(&shape).unwrap_or(u128::MAX));
    if chunk.len() != shape.len() || chunk_bytes > data_bytes.max(1 << 20) {
        return Err(Error::invalid(
            name,
            format!("{at} is stored in chunks of {chunk:?}, larger than the dataset's {shape:?}"),
        ));
    }
    Ok(())
}
