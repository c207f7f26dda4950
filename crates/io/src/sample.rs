//! Stored samples, shared by every reader and writer: [`StoredType`] names a sample type as a file stores it
//! (NIfTI's `datatype`, NRRD's `type`, DICOM's BitsAllocated and PixelRepresentation), [`Stored`] is the Rust
//! type of each, decoded from bytes of either order, and `with_stored_type!` is the one dispatch from the
//! first to the second. The volume's own sample types ([`SampleType`]) are a subset, chosen by the rules of
//! `docs/fixture-manifest.md`: [`StoredType::unscaled`] without a rescale, [`rescaled_type`] with one.

use std::path::Path;

use crate::error::Result;
use crate::volume::{SampleType, VoxelData, try_with_capacity};

/// A sample type as a file stores it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoredType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    U64,
    I64,
    F32,
    F64,
}

impl StoredType {
    #[must_use]
    pub const fn bytes(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 | Self::F32 => 4,
            Self::U64 | Self::I64 | Self::F64 => 8,
        }
    }

    /// The volume's sample type for these samples when no rescale applies: u8, i16, u16 and f32 stay, i8 widens
    /// to i16, the 32- and 64-bit integers and f64 become f32 (rounded to nearest).
    #[must_use]
    pub const fn unscaled(self) -> SampleType {
        match self {
            Self::U8 => SampleType::U8,
            Self::I8 | Self::I16 => SampleType::I16,
            Self::U16 => SampleType::U16,
            Self::U32 | Self::I32 | Self::U64 | Self::I64 | Self::F32 | Self::F64 => SampleType::F32,
        }
    }
}

impl From<SampleType> for StoredType {
    fn from(t: SampleType) -> Self {
        match t {
            SampleType::U8 => Self::U8,
            SampleType::I16 => Self::I16,
            SampleType::U16 => Self::U16,
            SampleType::F32 => Self::F32,
        }
    }
}

/// The volume's sample type for rescaled values in `lo..=hi`: i16 when they are `integral` and fit, else u16
/// likewise, else f32.
#[must_use]
pub fn rescaled_type(integral: bool, lo: f64, hi: f64) -> SampleType {
    if integral && lo >= f64::from(i16::MIN) && hi <= f64::from(i16::MAX) {
        SampleType::I16
    } else if integral && lo >= 0.0 && hi <= f64::from(u16::MAX) {
        SampleType::U16
    } else {
        SampleType::F32
    }
}

/// The Rust type of one [`StoredType`]. The conversions are Rust's `as` casts: exact where the value fits,
/// saturating from floats, rounding to nearest into f32; the rules only ask for the ones that fit.
pub trait Stored: Copy + Send + 'static {
    const TYPE: StoredType;
    const BYTES: usize;
    /// One sample from `b` (exactly [`Self::BYTES`] long) in the given byte order.
    fn decode(b: &[u8], big_endian: bool) -> Self;
    fn to_f64(self) -> f64;
    fn to_i64(self) -> i64;
    fn from_i64(v: i64) -> Self;
    fn from_f64(v: f64) -> Self;
    fn as_u8(self) -> u8;
    fn as_i16(self) -> i16;
    fn as_u16(self) -> u16;
    fn as_f32(self) -> f32;
    /// Appends the little-endian bytes.
    fn put_le(self, out: &mut Vec<u8>);
    /// `v` as the volume's samples when this is one of their types, without a copy; `Err(v)` otherwise.
    fn into_voxels(v: Vec<Self>) -> std::result::Result<VoxelData, Vec<Self>>;
}

macro_rules! stored {
    ($($t:ty => $variant:ident, $voxels:expr);* $(;)?) => {$(
        #[allow(clippy::cast_lossless, clippy::unnecessary_cast, reason = "one macro for every type")]
        impl Stored for $t {
            const TYPE: StoredType = StoredType::$variant;
            const BYTES: usize = size_of::<$t>();
            fn decode(b: &[u8], big_endian: bool) -> Self {
                let mut a = [0u8; size_of::<$t>()];
                a.copy_from_slice(b);
                if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
            }
            fn to_f64(self) -> f64 { self as f64 }
            fn to_i64(self) -> i64 { self as i64 }
            fn from_i64(v: i64) -> Self { v as $t }
            fn from_f64(v: f64) -> Self { v as $t }
            fn as_u8(self) -> u8 { self as u8 }
            fn as_i16(self) -> i16 { self as i16 }
            fn as_u16(self) -> u16 { self as u16 }
            fn as_f32(self) -> f32 { self as f32 }
            fn put_le(self, out: &mut Vec<u8>) { out.extend_from_slice(&self.to_le_bytes()); }
            fn into_voxels(v: Vec<Self>) -> std::result::Result<VoxelData, Vec<Self>> { $voxels(v) }
        }
    )*};
}

stored! {
    u8 => U8, |v| Ok(VoxelData::U8(v));
    i8 => I8, Err;
    u16 => U16, |v| Ok(VoxelData::U16(v));
    i16 => I16, |v| Ok(VoxelData::I16(v));
    u32 => U32, Err;
    i32 => I32, Err;
    u64 => U64, Err;
    i64 => I64, Err;
    f32 => F32, |v| Ok(VoxelData::F32(v));
    f64 => F64, Err;
}

/// Runs `$body` with `$t` the Rust type ([`Stored`]) of the [`StoredType`] `$stored`.
macro_rules! with_stored_type {
    ($stored:expr, $t:ident => $body:expr) => {
        match $stored {
            $crate::sample::StoredType::U8 => {
                type $t = u8;
                $body
            }
            $crate::sample::StoredType::I8 => {
                type $t = i8;
                $body
            }
            $crate::sample::StoredType::U16 => {
                type $t = u16;
                $body
            }
            $crate::sample::StoredType::I16 => {
                type $t = i16;
                $body
            }
            $crate::sample::StoredType::U32 => {
                type $t = u32;
                $body
            }
            $crate::sample::StoredType::I32 => {
                type $t = i32;
                $body
            }
            $crate::sample::StoredType::U64 => {
                type $t = u64;
                $body
            }
            $crate::sample::StoredType::I64 => {
                type $t = i64;
                $body
            }
            $crate::sample::StoredType::F32 => {
                type $t = f32;
                $body
            }
            $crate::sample::StoredType::F64 => {
                type $t = f64;
                $body
            }
        }
    };
}
pub(crate) use with_stored_type;

/// The samples of `bytes`, decoded as `S` in the given byte order.
pub(crate) fn decode<S: Stored>(bytes: &[u8], big_endian: bool) -> impl Iterator<Item = S> + '_ {
    bytes.chunks_exact(S::BYTES).map(move |b| S::decode(b, big_endian))
}

/// The rescaled samples `slope · stored + intercept` (float64), in the narrowest type of the rules.
pub(crate) fn rescale_samples<S: Stored>(
    path: &Path,
    raw: &[u8],
    dims: [usize; 3],
    big_endian: bool,
    (slope, inter): (f64, f64),
    limit: u64,
) -> Result<VoxelData> {
    let values = || decode::<S>(raw, big_endian).map(|x| slope * x.to_f64() + inter);
    let mut target = SampleType::F32;
    if slope.fract() == 0.0 && inter.fract() == 0.0 {
        let (integral, lo, hi) = values().fold((true, f64::INFINITY, f64::NEG_INFINITY), |(int, lo, hi), v| {
            (int && v.fract() == 0.0, lo.min(v), hi.max(v))
        });
        target = rescaled_type(integral, lo, hi);
    }
    let n = crate::volume::check_allocation(path, dims, target.bytes(), limit)?;
    let mut data = VoxelData::try_empty(path, target, n, "the rescaled samples")?;
    data.extend_from(values());
    Ok(data)
}

impl VoxelData {
    /// No samples of type `t`, with room for `n`, allocated fallibly ([`try_with_capacity`]).
    pub(crate) fn try_empty(path: &Path, t: SampleType, n: usize, what: &str) -> Result<Self> {
        Ok(match t {
            SampleType::U8 => Self::U8(try_with_capacity(path, n, what)?),
            SampleType::I16 => Self::I16(try_with_capacity(path, n, what)?),
            SampleType::U16 => Self::U16(try_with_capacity(path, n, what)?),
            SampleType::F32 => Self::F32(try_with_capacity(path, n, what)?),
        })
    }

    /// Appends `samples`, each cast to this data's type.
    pub(crate) fn extend_from<S: Stored>(&mut self, samples: impl Iterator<Item = S>) {
        match self {
            Self::U8(v) => v.extend(samples.map(S::as_u8)),
            Self::I16(v) => v.extend(samples.map(S::as_i16)),
            Self::U16(v) => v.extend(samples.map(S::as_u16)),
            Self::F32(v) => v.extend(samples.map(S::as_f32)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dispatch_reaches_the_rust_type_of_every_stored_type() {
        let all = [
            StoredType::U8,
            StoredType::I8,
            StoredType::U16,
            StoredType::I16,
            StoredType::U32,
            StoredType::I32,
            StoredType::U64,
            StoredType::I64,
            StoredType::F32,
            StoredType::F64,
        ];
        for t in all {
            let (ty, bytes) = with_stored_type!(t, T => (T::TYPE, T::BYTES));
            assert_eq!((ty, bytes), (t, t.bytes()));
        }
    }

    #[test]
    fn samples_decode_in_either_byte_order_and_follow_the_output_rules() {
        let be: Vec<i16> = decode(&[0xFF, 0xFE, 0x00, 0x05], true).collect();
        assert_eq!(be, [-2, 5]);
        let le: Vec<u32> = decode(&[1, 0, 0, 0], false).collect();
        assert_eq!(le, [1]);
        assert_eq!(StoredType::I8.unscaled(), SampleType::I16);
        assert_eq!(StoredType::F64.unscaled(), SampleType::F32);
        assert_eq!(rescaled_type(true, -1024.0, 3071.0), SampleType::I16);
        assert_eq!(rescaled_type(true, 0.0, 40_000.0), SampleType::U16);
        assert_eq!(rescaled_type(false, 0.0, 1.0), SampleType::F32);
        let mut data = VoxelData::try_empty(Path::new("x"), SampleType::I16, 2, "test").expect("room");
        data.extend_from([-3i8, 7].into_iter());
        assert_eq!(data, VoxelData::I16(vec![-3, 7]));
    }
}
