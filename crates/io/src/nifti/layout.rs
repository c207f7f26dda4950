//! Where the samples lie and what they are, checked before anything is allocated from the header: the grid
//! ([`grid`]), the stored type ([`stored_type`]) and the data span ([`data_span`]), shared by the volume reader
//! ([`layout`]) and the displacement-field reader.

use std::path::Path;

use super::header::Header;
use super::samples::stored_type_of_code;
use super::source::{Extent, MAX_DEFLATE_RATIO};
use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::sample::StoredType;
use crate::volume;

/// Where the chosen frame lies and what it holds.
#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    pub(super) dims: [usize; 3],
    pub(super) datatype: StoredType,
    /// Byte offset of the chosen frame from the start of the (decompressed) file.
    pub(super) frame_offset: u64,
    pub(super) frame_bytes: usize,
}

/// `dim[1..=7]` as sizes (1 beyond `dim[0]`), each checked to be at least 1 and to fit a `usize`.
pub(super) fn grid(path: &Path, h: &Header) -> Result<[usize; 8]> {
    let ndim = h.dim[0];
    if !(1..=7).contains(&ndim) {
        return Err(Error::invalid(path, format!("dim[0] = {ndim}, expected 1 to 7 dimensions")));
    }
    let ndim = ndim as usize;
    let mut dims = [1usize; 8];
    for (i, (&d, size)) in h.dim.iter().zip(dims.iter_mut()).enumerate().take(ndim + 1).skip(1) {
        if d < 1 {
            return Err(Error::invalid(path, format!("dim[{i}] = {d}, expected at least 1 (dim = {:?})", h.dim)));
        }
        *size = usize::try_from(d)
            .map_err(|_| Error::invalid(path, format!("dim[{i}] = {d} does not fit this platform's usize")))?;
    }
    Ok(dims)
}

/// The stored sample type of `datatype`, checked against `bitpix`.
pub(super) fn stored_type(path: &Path, h: &Header) -> Result<StoredType> {
    let datatype = stored_type_of_code(path, h.datatype)?;
    if i64::from(h.bitpix) != 8 * datatype.bytes() as i64 {
        return Err(Error::invalid(
            path,
            format!("bitpix {} does not match datatype {} ({} bits)", h.bitpix, h.datatype, 8 * datatype.bytes()),
        ));
    }
    Ok(datatype)
}

/// The samples to be read, for [`data_span`] and its messages.
pub(super) struct Span {
    /// Bytes from `vox_offset` to where they start.
    pub(super) skip: u128,
    pub(super) bytes: u128,
    /// What they are ("the voxel data") and a detail for messages ("dims [2, 2, 2], frame 0").
    pub(super) what: &'static str,
    pub(super) detail: String,
}

/// Checks `vox_offset` and that the source can hold `span`; returns where the span starts in the (decompressed)
/// file. An uncompressed source must hold it; a gzip stream cannot inflate to more than [`MAX_DEFLATE_RATIO`]
/// times its size, so a tiny `.nii.gz` claiming gigabytes fails before anything is allocated.
pub(super) fn data_span(path: &Path, h: &Header, extent: Extent, span: &Span) -> Result<u64> {
    // A pair's samples are in their own file, from its byte vox_offset; a single file's follow the header.
    let header_bytes = if h.pair { 0.0 } else { h.version.header_bytes() as f64 };
    if !h.vox_offset.is_finite() || h.vox_offset < header_bytes || h.vox_offset > 2f64.powi(62) {
        let after = if h.pair { "of the .img file".to_owned() } else { format!("past the {header_bytes}-byte header") };
        return Err(Error::invalid(path, format!("vox_offset {} is not a byte offset {after}", h.vox_offset)));
    }
    // nifti1_io and nibabel truncate a fractional offset.
    let vox_offset = h.vox_offset as u64;
    let start = (span.skip + u128::from(vox_offset)).min(u128::from(u64::MAX)) as u64;
    let end = u128::from(start) + span.bytes;
    let Span { what, detail, .. } = span;
    match extent {
        Extent::Gzip(len) if end > u128::from(len) * u128::from(MAX_DEFLATE_RATIO) => Err(Error::truncated(
            path,
            format!(
                "{what} needs {end} bytes ({detail}) but a {len}-byte gzip stream inflates to at most \
                 {MAX_DEFLATE_RATIO} times that"
            ),
        )),
        Extent::Exact(len) if end > u128::from(len) => Err(Error::truncated(
            path,
            format!(
                "{what} needs bytes {start}..{end} ({detail}, vox_offset {vox_offset}) but the file has {len} bytes"
            ),
        )),
        _ => Ok(start),
    }
}

/// The layout of one 3-D frame of a volume (the frame chosen by [`LoadOptions::frame`] in a 4-D file).
pub(super) fn layout(path: &Path, h: &Header, opts: &LoadOptions, extent: Extent) -> Result<Layout> {
    let dims = grid(path, h)?;
    let ndim = h.dim[0] as usize;
    if let Some(i) = (5..=ndim).find(|&i| dims[i] != 1) {
        return Err(Error::unsupported(
            path,
            format!("{ndim}-D data (dim[{i}] = {}); only 3-D and 4-D volumes are read", dims[i]),
        ));
    }
    let datatype = stored_type(path, h)?;
    let frames = dims[4];
    let frame = match (opts.frame, frames) {
        (None, 1) => 0,
        (None, frames) => return Err(Error::new(path, ErrorKind::FrameRequired { frames })),
        (Some(t), n) if t >= n => {
            return Err(Error::invalid(path, format!("frame {t} is out of range: the file has {n} frame(s)")));
        }
        (Some(t), _) => t,
    };
    let dims3 = [dims[1], dims[2], dims[3]];
    // Exact size arithmetic in u128: three dims below 2^64 and the sample size can overflow u64.
    let frame_bytes_wide =
        dims3.iter().try_fold(datatype.bytes() as u128, |acc, &d| acc.checked_mul(d as u128)).unwrap_or(u128::MAX);
    if frame_bytes_wide > u128::from(opts.max_voxel_bytes) {
        return Err(Error::new(
            path,
            ErrorKind::TooLarge {
                what: format!("dims {dims3:?}"),
                bytes: frame_bytes_wide,
                limit: opts.max_voxel_bytes,
            },
        ));
    }
    volume::check_allocation(path, dims3, datatype.bytes(), opts.max_voxel_bytes)?;
    let frame_bytes = frame_bytes_wide as usize; // ≤ max_voxel_bytes and a voxel count that fits usize
    let span = Span {
        skip: frame as u128 * frame_bytes_wide,
        bytes: frame_bytes_wide,
        what: "the voxel data",
        detail: format!("dims {dims3:?}, frame {frame}"),
    };
    let frame_offset = data_span(path, h, extent, &span)?;
    Ok(Layout { dims: dims3, datatype, frame_offset, frame_bytes })
}
