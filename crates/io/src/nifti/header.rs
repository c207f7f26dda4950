//! The fixed header of NIfTI-1 (348 bytes) and NIfTI-2 (540 bytes), in either byte order, widened to one
//! [`Header`] of NIfTI-2 types.

use std::io::Read;
use std::path::Path;

use super::source::fill;
use crate::error::{Error, ErrorKind, Result};

pub(super) const NIFTI1_HEADER_BYTES: usize = 348;
pub(super) const NIFTI2_HEADER_BYTES: usize = 540;
pub(super) const NIFTI1_MAGIC: &[u8; 4] = b"n+1\0";
const NIFTI1_PAIR_MAGIC: &[u8; 4] = b"ni1\0";
pub(super) const NIFTI2_MAGIC: &[u8; 8] = b"n+2\0\r\n\x1a\n";
const NIFTI2_PAIR_MAGIC: &[u8; 8] = b"ni2\0\r\n\x1a\n";

/// True when `head` (the first bytes of an uncompressed file, 4 or more) looks like a NIfTI-1/2 header.
///
/// `sizeof_hdr` must be 348 or 540 in either byte order; the magic is checked where `head` reaches it.
#[must_use]
pub fn looks_like_nifti(head: &[u8]) -> bool {
    let Some(first) = head.first_chunk::<4>() else { return false };
    let (le, be) = (i32::from_le_bytes(*first), i32::from_be_bytes(*first));
    if le == 348 || be == 348 {
        return head.get(344..348).is_none_or(|m| m == NIFTI1_MAGIC || m == NIFTI1_PAIR_MAGIC);
    }
    if le == 540 || be == 540 {
        return head.get(4..8).is_none_or(|m| m == &NIFTI2_MAGIC[..4] || m == &NIFTI2_PAIR_MAGIC[..4]);
    }
    false
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Version {
    Nifti1,
    Nifti2,
}

impl Version {
    pub(super) const fn header_bytes(self) -> usize {
        match self {
            Self::Nifti1 => NIFTI1_HEADER_BYTES,
            Self::Nifti2 => NIFTI2_HEADER_BYTES,
        }
    }
    const fn name(self) -> &'static str {
        match self {
            Self::Nifti1 => "NIfTI-1",
            Self::Nifti2 => "NIfTI-2",
        }
    }
}

/// The header fields we use, widened to the NIfTI-2 types.
#[derive(Clone, Debug)]
pub(super) struct Header {
    pub(super) version: Version,
    pub(super) big_endian: bool,
    pub(super) dim: [i64; 8],
    pub(super) datatype: i16,
    pub(super) bitpix: i16,
    pub(super) intent_code: i32,
    /// `intent_p1`, `intent_p2`, `intent_p3`: the intent's parameters (FNIRT keeps its reference's voxel sizes there).
    pub(super) intent_p: [f64; 3],
    pub(super) pixdim: [f64; 8],
    pub(super) vox_offset: f64,
    pub(super) scl_slope: f64,
    pub(super) scl_inter: f64,
    pub(super) xyzt_units: i32,
    pub(super) qform_code: i32,
    pub(super) sform_code: i32,
    pub(super) quatern_bcd: [f64; 3],
    pub(super) qoffset: [f64; 3],
    pub(super) srow: [[f64; 4]; 3],
    pub(super) descrip: String,
    /// The magic says `ni1` / `ni2`: the samples are in a separate `.img` file (a NIfTI pair).
    pub(super) pair: bool,
}

/// Reads fixed-offset fields of one byte order from a header buffer.
struct Fields<'a> {
    b: &'a [u8],
    big_endian: bool,
}

macro_rules! field_readers {
    ($($name:ident: $t:ty),*) => {$(
        fn $name(&self, off: usize) -> $t {
            let mut a = [0u8; size_of::<$t>()];
            a.copy_from_slice(&self.b[off..off + size_of::<$t>()]);
            if self.big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
        }
    )*};
}

impl Fields<'_> {
    field_readers!(i16: i16, i32: i32, i64: i64, f32: f32, f64: f64);
    fn f32s<const N: usize>(&self, off: usize) -> [f64; N] {
        std::array::from_fn(|i| f64::from(self.f32(off + 4 * i)))
    }
    fn f64s<const N: usize>(&self, off: usize) -> [f64; N] {
        std::array::from_fn(|i| self.f64(off + 8 * i))
    }
    fn text(&self, off: usize, len: usize) -> String {
        let raw = &self.b[off..off + len];
        let end = raw.iter().position(|&c| c == 0).unwrap_or(len);
        String::from_utf8_lossy(&raw[..end]).trim().to_string()
    }
}

pub(super) fn read_header(path: &Path, r: &mut impl Read) -> Result<Header> {
    let mut buf = [0u8; NIFTI2_HEADER_BYTES];
    fill(path, r, &mut buf[..4], "the header")?;
    let first = [buf[0], buf[1], buf[2], buf[3]];
    let (le, be) = (i32::from_le_bytes(first), i32::from_be_bytes(first));
    let (version, big_endian) = match (le, be) {
        (348, _) => (Version::Nifti1, false),
        (_, 348) => (Version::Nifti1, true),
        (540, _) => (Version::Nifti2, false),
        (_, 540) => (Version::Nifti2, true),
        _ => {
            return Err(Error::new(
                path,
                ErrorKind::BadMagic {
                    format: "NIfTI",
                    detail: format!("sizeof_hdr is {le} (little-endian) / {be} (big-endian), expected 348 or 540"),
                },
            ));
        }
    };
    let size = version.header_bytes();
    fill(path, r, &mut buf[4..size], &format!("the {}-byte {} header", size, version.name()))?;
    let f = Fields { b: &buf[..size], big_endian };
    match version {
        Version::Nifti1 => parse_nifti1(path, &f),
        Version::Nifti2 => parse_nifti2(path, &f),
    }
}

fn bad_magic(path: &Path, version: Version, found: &[u8]) -> Error {
    Error::new(
        path,
        ErrorKind::BadMagic {
            format: "NIfTI",
            detail: format!(
                "{} sizeof_hdr but the magic is {:?}; an Analyze 7.5 file or a corrupt header",
                version.name(),
                String::from_utf8_lossy(found)
            ),
        },
    )
}

/// Refuses a NIfTI pair's header where one file is expected (`what` says where: a `.nii` name, a displacement field).
pub(super) fn pair_error(path: &Path, what: &str) -> Error {
    Error::unsupported(
        path,
        format!("the header's magic (ni1/ni2) says its samples are in a separate .img file (a NIfTI pair): {what}"),
    )
}

/// NIfTI-1 layout (nifti1.h, `struct nifti_1_header`).
fn parse_nifti1(path: &Path, f: &Fields) -> Result<Header> {
    let magic = &f.b[344..348];
    if magic != NIFTI1_MAGIC && magic != NIFTI1_PAIR_MAGIC {
        return Err(bad_magic(path, Version::Nifti1, magic));
    }
    Ok(Header {
        version: Version::Nifti1,
        big_endian: f.big_endian,
        dim: std::array::from_fn(|i| i64::from(f.i16(40 + 2 * i))),
        datatype: f.i16(70),
        bitpix: f.i16(72),
        intent_code: i32::from(f.i16(68)),
        intent_p: f.f32s(56),
        pixdim: f.f32s(76),
        vox_offset: f64::from(f.f32(108)),
        scl_slope: f64::from(f.f32(112)),
        scl_inter: f64::from(f.f32(116)),
        xyzt_units: i32::from(f.b[123]),
        qform_code: i32::from(f.i16(252)),
        sform_code: i32::from(f.i16(254)),
        quatern_bcd: f.f32s(256),
        qoffset: f.f32s(268),
        srow: [f.f32s(280), f.f32s(296), f.f32s(312)],
        descrip: f.text(148, 80),
        pair: magic == NIFTI1_PAIR_MAGIC,
    })
}

/// NIfTI-2 layout (nifti2.h, `struct nifti_2_header`).
fn parse_nifti2(path: &Path, f: &Fields) -> Result<Header> {
    let magic = &f.b[4..12];
    if magic != NIFTI2_MAGIC && magic != NIFTI2_PAIR_MAGIC {
        if magic[..4] == NIFTI2_MAGIC[..4] {
            return Err(Error::new(
                path,
                ErrorKind::BadMagic {
                    format: "NIfTI-2",
                    detail: "the magic's \\r\\n\\x1a\\n bytes are altered: the file was probably \
                             transferred in text mode"
                        .to_string(),
                },
            ));
        }
        return Err(bad_magic(path, Version::Nifti2, magic));
    }
    Ok(Header {
        version: Version::Nifti2,
        big_endian: f.big_endian,
        dim: std::array::from_fn(|i| f.i64(16 + 8 * i)),
        datatype: f.i16(12),
        bitpix: f.i16(14),
        intent_code: f.i32(504),
        intent_p: f.f64s(80),
        pixdim: f.f64s(104),
        vox_offset: f.i64(168) as f64,
        scl_slope: f.f64(176),
        scl_inter: f.f64(184),
        xyzt_units: f.i32(500),
        qform_code: f.i32(344),
        sform_code: f.i32(348),
        quatern_bcd: f.f64s(352),
        qoffset: f.f64s(376),
        srow: [f.f64s(400), f.f64s(432), f.f64s(464)],
        descrip: f.text(240, 80),
        pair: magic == NIFTI2_PAIR_MAGIC,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn looks_like_nifti_checks_size_and_magic() {
        let mut h = vec![0u8; 348];
        h[..4].copy_from_slice(&348i32.to_le_bytes());
        h[344..].copy_from_slice(NIFTI1_MAGIC);
        assert!(looks_like_nifti(&h));
        assert!(looks_like_nifti(&h[..132]));
        h[344] = b'x';
        assert!(!looks_like_nifti(&h));
        assert!(!looks_like_nifti(&[1, 2]));
        let mut h2 = vec![0u8; 12];
        h2[..4].copy_from_slice(&540i32.to_be_bytes());
        h2[4..12].copy_from_slice(NIFTI2_MAGIC);
        assert!(looks_like_nifti(&h2));
    }
}
