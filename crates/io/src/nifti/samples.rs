//! The samples: the stored types NIfTI names (by their `datatype` codes), streamed into the output type when
//! there is no rescale, or rescaled in float64 into the narrowest type the rules allow.

use std::io::Read;
use std::path::Path;

use super::header::Header;
use super::source::{Reporter, fill};
use crate::error::{Error, Result};
use crate::sample::{self, StoredType};
use crate::volume::{self, Rescale, SampleType, VoxelData};

/// Bytes read between progress reports (a multiple of every sample size).
pub(super) const CHUNK_BYTES: usize = 4 << 20;

/// The NIfTI `datatype` code of each stored type we read (nifti1.h, `DT_*`).
const DATATYPE_CODES: [(i16, StoredType); 10] = [
    (2, StoredType::U8),
    (256, StoredType::I8),
    (4, StoredType::I16),
    (512, StoredType::U16),
    (8, StoredType::I32),
    (768, StoredType::U32),
    (1024, StoredType::I64),
    (1280, StoredType::U64),
    (16, StoredType::F32),
    (64, StoredType::F64),
];

/// The stored type of `datatype` code `code`, or an error naming the code and what it is.
pub(super) fn stored_type_of_code(path: &Path, code: i16) -> Result<StoredType> {
    if let Some(&(_, t)) = DATATYPE_CODES.iter().find(|(c, _)| *c == code) {
        return Ok(t);
    }
    let name = match code {
        0 => "unknown",
        1 => "binary",
        32 => "complex64",
        128 => "RGB24",
        1536 => "float128",
        1792 => "complex128",
        2048 => "complex256",
        2304 => "RGBA32",
        _ => "not a NIfTI datatype code",
    };
    Err(Error::unsupported(
        path,
        format!("unsupported datatype {code} ({name}); readable: u8, i8, i16, u16, i32, u32, i64, u64, f32, f64"),
    ))
}

/// The `datatype` code and `bitpix` that a writer gives samples of type `t`.
pub(super) fn datatype_code(t: SampleType) -> (i16, i16) {
    let stored = StoredType::from(t);
    let code = DATATYPE_CODES.iter().find(|(_, s)| *s == stored).map_or(0, |(c, _)| *c);
    (code, 8 * stored.bytes() as i16)
}

/// `Some((slope, intercept))` when the header asks for a non-identity rescale.
pub(super) fn scaling(path: &Path, h: &Header) -> Result<Option<(f64, f64)>> {
    let (slope, inter) = (h.scl_slope, h.scl_inter);
    if slope == 0.0 || !slope.is_finite() {
        return Ok(None);
    }
    if !inter.is_finite() {
        return Err(Error::invalid(path, format!("valid scl_slope {slope} but scl_inter is {inter}")));
    }
    let identity = Rescale { slope, intercept: inter, applied: false }.is_identity();
    if identity { Ok(None) } else { Ok(Some((slope, inter))) }
}

/// Reads `n_bytes` from `r` chunk by chunk, handing each chunk to `take` and reporting progress.
pub(super) fn stream_chunks(
    r: &mut impl Read,
    n_bytes: usize,
    progress: &mut Reporter,
    mut take: impl FnMut(&[u8]),
) -> Result<()> {
    let mut scratch = vec![0u8; n_bytes.min(CHUNK_BYTES)];
    let mut left = n_bytes;
    while left > 0 {
        let chunk = &mut scratch[..left.min(CHUNK_BYTES)];
        fill(progress.path, r, chunk, "the voxel data")?;
        take(chunk);
        left -= chunk.len();
        progress.advance(chunk.len())?;
    }
    Ok(())
}

/// The samples with no rescale: the stored type, widened or narrowed by the manifest rules
/// ([`StoredType::unscaled`]), decoded chunk by chunk into the output.
pub(super) fn read_identity(
    r: &mut impl Read,
    stored: StoredType,
    dims: [usize; 3],
    frame_bytes: usize,
    big_endian: bool,
    progress: &mut Reporter,
) -> Result<VoxelData> {
    let output = stored.unscaled();
    if output.bytes() > stored.bytes() {
        // A widening (i8 to i16): the output is larger than the stored bytes checked so far.
        volume::check_allocation(progress.path, dims, output.bytes(), progress.opts.max_voxel_bytes)?;
    }
    let mut data = VoxelData::try_empty(progress.path, output, frame_bytes / stored.bytes(), "the voxel samples")?;
    sample::with_stored_type!(stored, T => stream_chunks(r, frame_bytes, progress, |chunk| {
        data.extend_from(sample::decode::<T>(chunk, big_endian));
    }))?;
    Ok(data)
}
