//! The samples: the stored types NIfTI names, decoded from either byte order, streamed into the output type
//! when there is no rescale, or rescaled in float64 into the narrowest type the rules allow.

use std::io::Read;
use std::path::Path;

use super::header::Header;
use super::layout::Layout;
use super::{Reporter, fill};
use crate::error::{Error, Result};
use crate::volume::{self, Rescale, SampleType, VoxelData};

/// Bytes read between progress reports (a multiple of every sample size).
pub(super) const CHUNK_BYTES: usize = 4 << 20;

/// A stored NIfTI sample type we can read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum DataType {
    U8,
    I8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl DataType {
    pub(super) fn from_code(path: &Path, code: i16) -> Result<Self> {
        Ok(match code {
            2 => Self::U8,
            256 => Self::I8,
            4 => Self::I16,
            512 => Self::U16,
            8 => Self::I32,
            768 => Self::U32,
            1024 => Self::I64,
            1280 => Self::U64,
            16 => Self::F32,
            64 => Self::F64,
            other => {
                let name = match other {
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
                return Err(Error::unsupported(
                    path,
                    format!(
                        "unsupported datatype {other} ({name}); readable: u8, i8, i16, u16, i32, u32, i64, \
                         u64, f32, f64"
                    ),
                ));
            }
        })
    }

    pub(super) const fn bytes(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }
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

/// A stored sample type, decoded from bytes of either order.
pub(super) trait Stored: Copy {
    const BYTES: usize;
    fn decode(b: &[u8], big_endian: bool) -> Self;
    fn to_f64(self) -> f64;
}

macro_rules! stored {
    ($($t:ty),*) => {$(
        #[allow(clippy::unnecessary_cast)]
        impl Stored for $t {
            const BYTES: usize = size_of::<$t>();
            fn decode(b: &[u8], big_endian: bool) -> Self {
                let mut a = [0u8; size_of::<$t>()];
                a.copy_from_slice(b);
                if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
            }
            fn to_f64(self) -> f64 {
                self as f64
            }
        }
    )*};
}
stored!(u8, i8, i16, u16, i32, u32, i64, u64, f32, f64);

/// Runs `$body` with `$t` the Rust type of the stored `$dt`.
macro_rules! with_stored {
    ($dt:expr, $t:ident => $body:expr) => {
        match $dt {
            DataType::U8 => {
                type $t = u8;
                $body
            }
            DataType::I8 => {
                type $t = i8;
                $body
            }
            DataType::I16 => {
                type $t = i16;
                $body
            }
            DataType::U16 => {
                type $t = u16;
                $body
            }
            DataType::I32 => {
                type $t = i32;
                $body
            }
            DataType::U32 => {
                type $t = u32;
                $body
            }
            DataType::I64 => {
                type $t = i64;
                $body
            }
            DataType::U64 => {
                type $t = u64;
                $body
            }
            DataType::F32 => {
                type $t = f32;
                $body
            }
            DataType::F64 => {
                type $t = f64;
                $body
            }
        }
    };
}
pub(super) use with_stored;

/// Reads `n_bytes` of `S` samples chunk by chunk, converting each into the output as it arrives.
pub(super) fn stream_convert<S: Stored, O>(
    r: &mut impl Read,
    n_bytes: usize,
    big_endian: bool,
    progress: &mut Reporter,
    convert: impl Fn(S) -> O,
) -> Result<Vec<O>> {
    let mut out = volume::try_with_capacity(progress.path, n_bytes / S::BYTES, "the voxel samples")?;
    let mut scratch = vec![0u8; n_bytes.min(CHUNK_BYTES)];
    let mut left = n_bytes;
    while left > 0 {
        let chunk = &mut scratch[..left.min(CHUNK_BYTES)];
        fill(progress.path, r, chunk, "the voxel data")?;
        out.extend(chunk.chunks_exact(S::BYTES).map(|b| convert(S::decode(b, big_endian))));
        left -= chunk.len();
        progress.advance(chunk.len())?;
    }
    Ok(out)
}

/// The samples with no rescale: the stored type, widened or narrowed by the manifest rules.
pub(super) fn read_identity(
    r: &mut impl Read,
    l: &Layout,
    big_endian: bool,
    progress: &mut Reporter,
) -> Result<VoxelData> {
    let n = l.frame_bytes;
    if l.datatype == DataType::I8 {
        // The only widening without a rescale: the output is twice the stored bytes.
        volume::check_allocation(progress.path, l.dims, 2, progress.opts.max_voxel_bytes)?;
    }
    Ok(match l.datatype {
        DataType::U8 => VoxelData::U8(stream_convert(r, n, big_endian, progress, |x: u8| x)?),
        DataType::I8 => VoxelData::I16(stream_convert(r, n, big_endian, progress, |x: i8| i16::from(x))?),
        DataType::I16 => VoxelData::I16(stream_convert(r, n, big_endian, progress, |x: i16| x)?),
        DataType::U16 => VoxelData::U16(stream_convert(r, n, big_endian, progress, |x: u16| x)?),
        DataType::F32 => VoxelData::F32(stream_convert(r, n, big_endian, progress, |x: f32| x)?),
        DataType::I32 => VoxelData::F32(stream_convert(r, n, big_endian, progress, |x: i32| x as f32)?),
        DataType::U32 => VoxelData::F32(stream_convert(r, n, big_endian, progress, |x: u32| x as f32)?),
        DataType::I64 => VoxelData::F32(stream_convert(r, n, big_endian, progress, |x: i64| x as f32)?),
        DataType::U64 => VoxelData::F32(stream_convert(r, n, big_endian, progress, |x: u64| x as f32)?),
        DataType::F64 => VoxelData::F32(stream_convert(r, n, big_endian, progress, |x: f64| x as f32)?),
    })
}

/// The rescaled samples `slope · stored + intercept` (float64), in the narrowest type of the rules.
pub(super) fn rescale_samples<S: Stored>(
    path: &Path,
    raw: &[u8],
    dims: [usize; 3],
    big_endian: bool,
    (slope, inter): (f64, f64),
    limit: u64,
) -> Result<VoxelData> {
    let values = || raw.chunks_exact(S::BYTES).map(|b| slope * S::decode(b, big_endian).to_f64() + inter);
    let mut target = SampleType::F32;
    if slope.fract() == 0.0 && inter.fract() == 0.0 {
        let (integral, lo, hi) = values().fold((true, f64::INFINITY, f64::NEG_INFINITY), |(int, lo, hi), v| {
            (int && v.fract() == 0.0, lo.min(v), hi.max(v))
        });
        if integral && lo >= f64::from(i16::MIN) && hi <= f64::from(i16::MAX) {
            target = SampleType::I16;
        } else if integral && lo >= 0.0 && hi <= f64::from(u16::MAX) {
            target = SampleType::U16;
        }
    }
    let n = volume::check_allocation(path, dims, target.bytes(), limit)?;
    let what = "the rescaled samples";
    Ok(match target {
        SampleType::I16 => {
            VoxelData::I16(extend(volume::try_with_capacity(path, n, what)?, values().map(|v| v as i16)))
        }
        SampleType::U16 => {
            VoxelData::U16(extend(volume::try_with_capacity(path, n, what)?, values().map(|v| v as u16)))
        }
        _ => VoxelData::F32(extend(volume::try_with_capacity(path, n, what)?, values().map(|v| v as f32))),
    })
}

/// `v` with `items` appended (into the room already reserved).
fn extend<T>(mut v: Vec<T>, items: impl Iterator<Item = T>) -> Vec<T> {
    v.extend(items);
    v
}
