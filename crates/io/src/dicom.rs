//! DICOM series reader: a folder of slices, a list of files, or one (enhanced) multi-frame object.
//!
//! Entry points: [`read_folder`], [`read_files`], [`read_file_bytes`] and [`list_series`].
//!
//! # Steps
//! 1. **Headers.** Every file is read up to, not including, PixelData (7FE0,0010). In a folder,
//!    files without the `DICM` preamble, DICOMDIR files and objects without Rows (0028,0010)
//!    are skipped; a file that has the preamble but does not parse is an error naming it.
//! 2. **Series.** Files are grouped by SeriesInstanceUID (0020,000E). More than one series and no
//!    [`LoadOptions::series_instance_uid`] gives [`ErrorKind::MultipleSeries`].
//! 3. **Geometry** (the rule of `docs/fixture-manifest.md`). Each slice (a file, or a frame of a
//!    multi-frame object) has a position p = ImagePositionPatient (0020,0032), an orientation
//!    (r, c) = ImageOrientationPatient (0020,0037) and PixelSpacing (0028,0030) = (Δrow, Δcol).
//!    With the slice normal n = r × c, slices are sorted ascending by d = p · n, and
//!
//!    ```text
//!    lps_from_index = [ r·Δcol | c·Δrow | (p_last − p_first)/(N − 1) | p_first ]
//!    ```
//!
//!    i.e. column i of the image moves along r by PixelSpacing\[1\], row j along c by
//!    PixelSpacing\[0\], and k along the mean slice step. The spacing comes from the positions,
//!    never from SliceThickness. One slice: k = n × SpacingBetweenSlices, else SliceThickness,
//!    else 1 mm. Orientations that differ by more than [`ORIENTATION_TOLERANCE`] are rejected
//!    ("not parallel"), as are duplicate positions and gaps (a step more than 1.5 × the median
//!    step). Steps that differ by more than 1 % of the mean give a warning in
//!    `metadata.warnings`. Enhanced multi-frame objects take p, (r, c), the spacing and the
//!    rescale per frame from PerFrameFunctionalGroupsSequence (5200,9230), then
//!    SharedFunctionalGroupsSequence (5200,9229), then the top level.
//! 4. **Pixels.** Files are decoded one at a time (in sorted order) into one preallocated buffer
//!    of the stored type, then dropped, so the peak is about the voxel data plus one file.
//!    Native syntaxes are read straight from the PixelData element; RLE is decoded here, JPEG-LS
//!    by [`crate::jpegls`] (each frame's size checked against Rows/Columns first);
//!    JPEG and JPEG 2000 go through `dicom-pixeldata`'s pure-Rust codecs after their frame
//!    headers are checked against Rows/Columns (a mismatch would make the codec adapters panic).
//!    Stored bits are masked to BitsStored and sign-extended for signed data. No LUT or window
//!    is applied. The file's bytes, the volume, the decoded RLE / JPEG-LS frames (and the JPEG-LS
//!    decoder's samples) and a rescaled copy are allocated fallibly ([`volume::try_with_capacity`]):
//!    memory the system refuses is an [`ErrorKind::OutOfMemory`] naming the file and the size, never
//!    an abort. (Buffers that dicom-rs and dicom-pixeldata allocate while parsing and decoding JPEG /
//!    JPEG 2000 are theirs.)
//! 5. **Rescale.** value = RescaleSlope × stored + RescaleIntercept, per slice, in f64. Identity:
//!    u8, i16, u16 kept, i8 → i16, 32-bit → f32. Otherwise: integer slope and intercept with every
//!    value in i16 → i16, else in u16 → u16, else f32.
//!
//! Transfer syntaxes decoded: [`SUPPORTED_TRANSFER_SYNTAXES`]. JPEG-LS (which dicom-rs decodes
//! only through the C++ CharLS library) uses our own pure-Rust decoder, [`crate::jpegls`].

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use dicom_core::value::Value;
use dicom_core::{PrimitiveValue, Tag};
use dicom_dictionary_std::tags;
use dicom_object::file::ReadPreamble;
use dicom_object::mem::InMemElement;
use dicom_object::{DefaultDicomObject, InMemDicomObject, OpenFileOptions};
use dicom_pixeldata::PixelDecoder;
use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::jpegls;
use crate::options::LoadOptions;
use crate::series::SeriesSummary;
use crate::volume::{self, GeometrySource, Modality, Rescale, Volume, VoxelData};

/// Transfer syntaxes this reader decodes, as (UID, name).
pub const SUPPORTED_TRANSFER_SYNTAXES: &[(&str, &str)] = &[
    ("1.2.840.10008.1.2", "Implicit VR Little Endian"),
    ("1.2.840.10008.1.2.1", "Explicit VR Little Endian"),
    ("1.2.840.10008.1.2.2", "Explicit VR Big Endian"),
    ("1.2.840.10008.1.2.1.99", "Deflated Explicit VR Little Endian"),
    ("1.2.840.10008.1.2.1.98", "Encapsulated Uncompressed Explicit VR Little Endian"),
    ("1.2.840.10008.1.2.5", "RLE Lossless"),
    ("1.2.840.10008.1.2.4.50", "JPEG Baseline (Process 1)"),
    ("1.2.840.10008.1.2.4.51", "JPEG Extended (Process 2 & 4)"),
    ("1.2.840.10008.1.2.4.57", "JPEG Lossless, Non-Hierarchical (Process 14)"),
    ("1.2.840.10008.1.2.4.70", "JPEG Lossless, Non-Hierarchical, First-Order Prediction (Process 14, SV1)"),
    ("1.2.840.10008.1.2.4.80", "JPEG-LS Lossless"),
    ("1.2.840.10008.1.2.4.81", "JPEG-LS Lossy (Near-Lossless)"),
    ("1.2.840.10008.1.2.4.90", "JPEG 2000 Image Compression (Lossless Only)"),
    ("1.2.840.10008.1.2.4.91", "JPEG 2000 Image Compression"),
    ("1.2.840.10008.1.2.4.201", "High-Throughput JPEG 2000 Image Compression (Lossless Only)"),
    ("1.2.840.10008.1.2.4.202", "High-Throughput JPEG 2000 with RPCL Options Image Compression (Lossless Only)"),
    ("1.2.840.10008.1.2.4.203", "High-Throughput JPEG 2000 Image Compression"),
    ("1.2.840.10008.1.2.8.1", "Deflated Image Frame Compression"),
];

/// Names of transfer syntaxes we know but do not decode, for error messages.
const UNSUPPORTED_TRANSFER_SYNTAXES: &[(&str, &str)] = &[
    ("1.2.840.10008.1.2.4.92", "JPEG 2000 Part 2 Multi-component (Lossless Only)"),
    ("1.2.840.10008.1.2.4.93", "JPEG 2000 Part 2 Multi-component"),
    ("1.2.840.10008.1.2.4.94", "JPIP Referenced"),
    ("1.2.840.10008.1.2.4.95", "JPIP Referenced Deflate"),
    ("1.2.840.10008.1.2.4.110", "JPEG XL Lossless"),
    ("1.2.840.10008.1.2.4.111", "JPEG XL JPEG Recompression"),
    ("1.2.840.10008.1.2.4.112", "JPEG XL"),
    ("1.2.840.10008.1.2.4.100", "MPEG2 Main Profile / Main Level"),
    ("1.2.840.10008.1.2.4.101", "MPEG2 Main Profile / High Level"),
    ("1.2.840.10008.1.2.4.102", "MPEG-4 AVC/H.264 High Profile"),
    ("1.2.840.10008.1.2.4.103", "MPEG-4 AVC/H.264 BD-compatible High Profile"),
    ("1.2.840.10008.1.2.4.107", "HEVC/H.265 Main Profile"),
    ("1.2.840.10008.1.2.4.108", "HEVC/H.265 Main 10 Profile"),
];

/// Largest difference between two ImageOrientationPatient components still called parallel.
pub const ORIENTATION_TOLERANCE: f64 = 1e-4;
/// A step larger than this times the median step is a gap (missing slices).
const GAP_FACTOR: f64 = 1.5;
/// Consecutive steps differing by more than this fraction of the mean give a warning.
const UNEVEN_FRACTION: f64 = 0.01;
/// Two slices closer than this along the normal (mm) are duplicates.
const DUPLICATE_MM: f64 = 1e-3;

const RLE_LOSSLESS: &str = "1.2.840.10008.1.2.5";
const JPEG_LS_SYNTAXES: &[&str] = &["1.2.840.10008.1.2.4.80", "1.2.840.10008.1.2.4.81"];
const MEDIA_STORAGE_DIRECTORY: &str = "1.2.840.10008.1.3.10";
const NATIVE_SYNTAXES: &[&str] =
    &["1.2.840.10008.1.2", "1.2.840.10008.1.2.1", "1.2.840.10008.1.2.2", "1.2.840.10008.1.2.1.99"];
const JPEG_SYNTAXES: &[&str] =
    &["1.2.840.10008.1.2.4.50", "1.2.840.10008.1.2.4.51", "1.2.840.10008.1.2.4.57", "1.2.840.10008.1.2.4.70"];
const J2K_SYNTAXES: &[&str] = &[
    "1.2.840.10008.1.2.4.90",
    "1.2.840.10008.1.2.4.91",
    "1.2.840.10008.1.2.4.201",
    "1.2.840.10008.1.2.4.202",
    "1.2.840.10008.1.2.4.203",
];

// ---------------------------------------------------------------------------------------------
// Public API
// ---------------------------------------------------------------------------------------------

/// Reads the DICOM series in folder `path` (not recursive). With several series, choose one with
/// [`LoadOptions::series_instance_uid`] (see [`list_series`]).
pub fn read_folder(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    let sources = folder_files(path)?;
    let headers = read_headers(path, &sources, true, opts)?;
    if headers.is_empty() {
        return Err(Error::invalid(path, "no DICOM image files in the folder"));
    }
    read_series(path, &sources, headers, opts)
}

/// Reads the DICOM files `paths` as one series: several slices, one slice, or one multi-frame object.
pub fn read_files(paths: &[PathBuf], opts: &mut LoadOptions) -> Result<Volume> {
    let Some(first) = paths.first() else {
        return Err(Error::invalid(Path::new(""), "no DICOM files given"));
    };
    let label =
        if paths.len() == 1 { first.clone() } else { first.parent().map(Path::to_path_buf).unwrap_or_default() };
    for p in paths {
        crate::check_regular_file(p)?; // a pipe or a device would block or never end
    }
    let sources: Vec<Source> = paths.iter().map(|p| Source::File(p.clone())).collect();
    let headers = read_headers(&label, &sources, false, opts)?;
    if headers.is_empty() {
        return Err(Error::invalid(&label, "not a DICOM image (no Rows (0028,0010) / PixelData)"));
    }
    read_series(&label, &sources, headers, opts)
}

/// Reads one DICOM file held in memory (`name` is used in errors only).
pub fn read_file_bytes(name: &Path, bytes: &[u8], opts: &mut LoadOptions) -> Result<Volume> {
    let sources = [Source::Bytes(name.to_path_buf(), bytes)];
    let headers = read_headers(name, &sources, false, opts)?;
    if headers.is_empty() {
        return Err(Error::invalid(name, "not a DICOM image (no Rows (0028,0010) / PixelData)"));
    }
    read_series(name, &sources, headers, opts)
}

/// The DICOM image series in folder `dir`, sorted by SeriesNumber then SeriesInstanceUID.
pub fn list_series(dir: &Path) -> Result<Vec<SeriesSummary>> {
    let sources = folder_files(dir)?;
    let headers = read_headers(dir, &sources, true, &mut LoadOptions::new())?;
    Ok(group_series(headers).iter().map(|g| summary(g)).collect())
}

// ---------------------------------------------------------------------------------------------
// Sources and headers
// ---------------------------------------------------------------------------------------------

/// Where one DICOM object comes from.
enum Source<'a> {
    File(PathBuf),
    Bytes(PathBuf, &'a [u8]),
}

impl Source<'_> {
    fn path(&self) -> &Path {
        match self {
            Self::File(p) | Self::Bytes(p, _) => p,
        }
    }

    /// Bytes the source holds (the file size on disk).
    fn byte_len(&self) -> Result<u64> {
        match self {
            Self::File(p) => std::fs::metadata(p).map(|m| m.len()).map_err(|e| Error::io(p, e)),
            Self::Bytes(_, b) => Ok(b.len() as u64),
        }
    }

    /// True when the data carries the 128-byte preamble and `DICM`.
    fn has_preamble(&self) -> Result<bool> {
        match self {
            Self::File(p) => {
                let mut head = [0u8; 132];
                let mut f = std::fs::File::open(p).map_err(|e| Error::io(p, e))?;
                let n = crate::read_up_to(&mut f, &mut head).map_err(|e| Error::io(p, e))?;
                Ok(n == 132 && &head[128..132] == b"DICM")
            }
            Self::Bytes(_, b) => Ok(b.len() >= 132 && &b[128..132] == b"DICM"),
        }
    }

    /// The file's bytes, after checking the preamble and every element length ([`check_lengths`]).
    fn read_checked(&self) -> Result<(Cow<'_, [u8]>, Checked)> {
        let path = self.path();
        let bytes: Cow<'_, [u8]> = match self {
            Self::File(p) => Cow::Owned(read_whole_file(p)?),
            Self::Bytes(_, b) => Cow::Borrowed(b),
        };
        if bytes.len() < 132 || &bytes[128..132] != b"DICM" {
            return Err(Error::new(
                path,
                ErrorKind::BadMagic { format: "DICOM", detail: "no 'DICM' after the 128-byte preamble".into() },
            ));
        }
        let checked = check_lengths(&bytes[128..]).map_err(|(truncated, msg)| {
            if truncated { Error::truncated(path, msg) } else { Error::new(path, ErrorKind::Dicom(msg)) }
        })?;
        Ok((bytes, checked))
    }

    /// Opens the object; `header_only` stops before PixelData, otherwise right after it.
    ///
    /// The element lengths are checked first ([`check_lengths`]): dicom-rs allocates whatever a
    /// length field claims (up to 4 GiB) before reading, and reads on past PixelData into any
    /// trailing padding. The parser gets the bytes up to the end of the top-level PixelData only.
    fn open(&self, header_only: bool) -> Result<DefaultDicomObject> {
        let (bytes, checked) = self.read_checked()?;
        let data = checked.replacement.as_deref().unwrap_or(&bytes[128..]);
        let options = OpenFileOptions::new().read_preamble(ReadPreamble::Never);
        let options =
            if header_only { options.read_until(tags::PIXEL_DATA) } else { options.read_to(tags::PIXEL_DATA) };
        options
            .from_reader(&data[..checked.end])
            .map_err(|e| Error::new(self.path(), ErrorKind::Dicom(error_chain(&e))))
    }

    /// For native (uncompressed) pixel data with a defined length: the header parsed by dicom-rs,
    /// and the file's bytes with the PixelData value's range in them. The pixels are not copied
    /// into a parsed object, so a large multi-frame file costs its size once, not twice.
    fn open_native_pixels(&self) -> Result<(DefaultDicomObject, Cow<'_, [u8]>, Range<usize>)> {
        let (bytes, checked) = self.read_checked()?;
        let Some(value) = checked.pixel_value.clone() else {
            return Err(Error::invalid(self.path(), "PixelData (7FE0,0010) is missing or has no defined length"));
        };
        let options = OpenFileOptions::new().read_preamble(ReadPreamble::Never).read_until(tags::PIXEL_DATA);
        let obj = options
            .from_reader(&bytes[128..128 + checked.end])
            .map_err(|e| Error::new(self.path(), ErrorKind::Dicom(error_chain(&e))))?;
        Ok((obj, bytes, 128 + value.start..128 + value.end))
    }
}

/// The bytes of the file at `path`, into a buffer allocated fallibly for its length: memory the system refuses is
/// an [`ErrorKind::OutOfMemory`] naming the file.
fn read_whole_file(path: &Path) -> Result<Vec<u8>> {
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let capacity =
        usize::try_from(len).map_err(|_| Error::invalid(path, format!("{len} bytes do not fit in memory")))?;
    let mut bytes = volume::try_with_capacity(path, capacity, "the file's bytes")?;
    // At most the length seen (a file that grows meanwhile is read as it was).
    (&mut file).take(len).read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    Ok(bytes)
}

/// What [`check_lengths`] found: where the top-level PixelData ends (or the data ends), and the
/// range of its value when it has a defined length (native pixel data).
#[derive(Clone, Debug)]
struct Checked {
    end: usize,
    pixel_value: Option<Range<usize>>,
    /// For a deflated data set with bytes after PixelData: the data (from `DICM`) re-deflated up to
    /// the end of PixelData, to be parsed instead of the file's.
    replacement: Option<Vec<u8>>,
}

/// Deepest sequence nesting accepted (dicom-rs builds nested objects recursively).
const MAX_DEPTH: usize = 32;

/// Walks the element headers of `data` (starting at `DICM`) without reading values and checks
/// that every defined length fits in the data. Returns where the top-level PixelData ends (or the
/// data ends). Errors are `(is_truncation, message)`. A deflated data set is checked up to the
/// file meta group only.
fn check_lengths(data: &[u8]) -> std::result::Result<Checked, (bool, String)> {
    let mut w = Walker { data, explicit: true, big_endian: false, pixel_end: None, pixel_value: None };
    // File meta group, explicit VR little endian. As dicom-rs reads it (dicom-object `meta.rs`):
    // (0002,0000) with a 4-byte group length first, then elements of any group until that many
    // bytes are consumed. (A walk that stopped at the first element outside group 0002 would
    // leave elements that dicom-rs still reads unchecked: a fuzzer found a 1 KB file whose meta
    // group length covered a (0003,0012) element, so that the data set dicom-rs inflated, unlike
    // ours, declared a 3 GB element.)
    let (tag, len, header) = w.header(4)?;
    if tag != (0x0002, 0x0000) || len != 4 || header != 8 {
        return Err((
            false,
            format!(
                "the file meta group does not start with its group length (0002,0000) but with ({:04X},{:04X})",
                tag.0, tag.1
            ),
        ));
    }
    let group_length = w.u32_at(4 + header, true)?;
    let mut pos = 4 + header + 4;
    let mut consumed = 0u64;
    let mut ts = String::new();
    while consumed < u64::from(group_length) {
        let (tag, len, header) = w.header(pos)?;
        if len == UNDEFINED {
            return Err((false, format!("file meta element ({:04X},{:04X}) has an undefined length", tag.0, tag.1)));
        }
        let value = w.value_range(tag, pos + header, len, data.len())?;
        if tag == (0x0002, 0x0010) {
            ts =
                String::from_utf8_lossy(&data[value.clone()]).trim_matches(|c: char| c == '\0' || c == ' ').to_string();
        }
        consumed += (header as u64) + u64::from(len);
        pos = value.end;
    }
    match ts.as_str() {
        "1.2.840.10008.1.2.1.99" => {
            // dicom-rs inflates the data set and then trusts its lengths (a fuzzer found a 5 KB
            // file claiming a 1.9 GB element). Inflate it here, bounded by deflate's largest
            // expansion, and walk the result, so no length can claim more than the data holds.
            let cap = (data.len() as u64).saturating_mul(1032).saturating_add(1024);
            let mut inflated = Vec::new();
            flate2::read::DeflateDecoder::new(&data[pos..])
                .take(cap)
                .read_to_end(&mut inflated)
                .map_err(|e| (false, format!("the deflated data set does not inflate: {e}")))?;
            let mut inner =
                Walker { data: &inflated, explicit: true, big_endian: false, pixel_end: None, pixel_value: None };
            inner.elements(0, inflated.len(), 0, false)?;
            // As for the other syntaxes, dicom-rs must not read past PixelData (trailing padding or
            // garbage): a deflated stream cannot be cut, so re-deflate the part up to its end.
            let replacement = match inner.pixel_end {
                Some(end) if end < inflated.len() => {
                    let mut enc = flate2::write::DeflateEncoder::new(data[..pos].to_vec(), flate2::Compression::fast());
                    enc.write_all(&inflated[..end])
                        .and_then(|()| enc.finish())
                        .map(Some)
                        .map_err(|e| (false, format!("cannot re-deflate the data set: {e}")))?
                }
                _ => None,
            };
            let end = replacement.as_ref().map_or(data.len(), Vec::len);
            return Ok(Checked { end, pixel_value: None, replacement });
        }
        "1.2.840.10008.1.2" => w.explicit = false,
        "1.2.840.10008.1.2.2" => w.big_endian = true,
        _ => {}
    }
    w.elements(pos, data.len(), 0, false)?;
    Ok(Checked { end: w.pixel_end.unwrap_or(data.len()), pixel_value: w.pixel_value, replacement: None })
}

/// Explicit VRs with a 16-bit length field (PS3.5 Table 7.1-2).
const SHORT_VRS: [&[u8; 2]; 21] = [
    b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FL", b"FD", b"IS", b"LO", b"LT", b"PN", b"SH", b"SL", b"SS",
    b"ST", b"TM", b"UI", b"UL", b"US",
];

struct Walker<'a> {
    data: &'a [u8],
    explicit: bool,
    big_endian: bool,
    pixel_end: Option<usize>,
    /// The top-level PixelData value, when its length is defined.
    pixel_value: Option<Range<usize>>,
}

type WalkResult<T> = std::result::Result<T, (bool, String)>;

const UNDEFINED: u32 = u32::MAX;

impl Walker<'_> {
    fn u16_at(&self, pos: usize, le: bool) -> WalkResult<u16> {
        let b = self.data.get(pos..pos + 2).ok_or_else(|| Self::short(pos))?;
        Ok(if le { u16::from_le_bytes([b[0], b[1]]) } else { u16::from_be_bytes([b[0], b[1]]) })
    }
    fn u32_at(&self, pos: usize, le: bool) -> WalkResult<u32> {
        let b = self.data.get(pos..pos + 4).ok_or_else(|| Self::short(pos))?;
        let a = [b[0], b[1], b[2], b[3]];
        Ok(if le { u32::from_le_bytes(a) } else { u32::from_be_bytes(a) })
    }
    fn short(pos: usize) -> (bool, String) {
        (true, format!("the data ends inside an element header at byte {}", pos + 128))
    }

    /// Reads an element or item header at `pos`: (tag, length, header size).
    fn header(&self, pos: usize) -> WalkResult<((u16, u16), u32, usize)> {
        // The file meta group is always little endian.
        let le = !self.big_endian || self.u16_at(pos, true)? == 0x0002;
        let tag = (self.u16_at(pos, le)?, self.u16_at(pos + 2, le)?);
        let explicit = self.explicit || tag.0 == 0x0002;
        if tag.0 == 0xFFFE || !explicit {
            return Ok((tag, self.u32_at(pos + 4, le)?, 8));
        }
        let vr = self.data.get(pos + 4..pos + 6).ok_or_else(|| Self::short(pos))?;
        // As dicom-rs (dicom-encoding explicit_le/_be): these VRs have a 16-bit length; all others,
        // unknown ones included (read as UN), have 2 reserved bytes and a 32-bit length.
        if SHORT_VRS.iter().any(|s| s.as_slice() == vr) {
            Ok((tag, u32::from(self.u16_at(pos + 6, le)?), 8))
        } else {
            Ok((tag, self.u32_at(pos + 8, le)?, 12))
        }
    }

    fn value_range(&self, tag: (u16, u16), start: usize, len: u32, limit: usize) -> WalkResult<std::ops::Range<usize>> {
        let end = start.checked_add(len as usize).filter(|&e| e <= limit).ok_or_else(|| {
            (
                limit == self.data.len(),
                format!(
                    "element ({:04X},{:04X}) at byte {} declares {len} bytes, but only {} remain",
                    tag.0,
                    tag.1,
                    start + 128,
                    limit.saturating_sub(start)
                ),
            )
        })?;
        Ok(start..end)
    }

    fn is_sequence(&self, pos: usize, tag: (u16, u16)) -> bool {
        if self.explicit {
            self.data.get(pos + 4..pos + 6) == Some(b"SQ")
        } else {
            use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
            matches!(
                dicom_dictionary_std::StandardDataDictionary.by_tag(Tag(tag.0, tag.1)).map(DataDictionaryEntry::vr),
                Some(VirtualVr::Exact(dicom_core::VR::SQ))
            )
        }
    }

    /// Walks data elements from `pos` to `end` (or to an item delimiter when `until_delimiter`).
    /// Returns the position after the last element (after the delimiter).
    fn elements(&mut self, mut pos: usize, end: usize, depth: usize, until_delimiter: bool) -> WalkResult<usize> {
        if depth > MAX_DEPTH {
            return Err((false, format!("sequences nested deeper than {MAX_DEPTH}")));
        }
        while pos < end {
            if depth == 0 && end - pos < 8 && self.data[pos..end].iter().all(|&b| b == 0) {
                return Ok(end); // trailing zero padding
            }
            let (tag, len, header) = self.header(pos)?;
            let start = pos + header;
            if tag == (0xFFFE, 0xE00D) {
                if until_delimiter {
                    return Ok(start);
                }
                pos = start; // stray item delimiter: dicom-rs skips it
                continue;
            }
            if len == UNDEFINED {
                pos = self.items(start, end, depth + 1, tag == (0x7FE0, 0x0010))?;
            } else {
                let value = self.value_range(tag, start, len, end)?;
                if self.is_sequence(pos, tag) {
                    self.defined_items(value.clone(), depth + 1)?;
                }
                if depth == 0 && tag == (0x7FE0, 0x0010) {
                    self.pixel_value = Some(value.clone());
                }
                pos = value.end;
            }
            if depth == 0 && tag == (0x7FE0, 0x0010) {
                self.pixel_end = Some(pos);
                return Ok(pos);
            }
        }
        if until_delimiter {
            return Err((true, "the data ends inside a sequence item (no item delimiter)".into()));
        }
        Ok(pos)
    }

    /// Items of a defined-length sequence in `range`.
    fn defined_items(&mut self, range: std::ops::Range<usize>, depth: usize) -> WalkResult<()> {
        let mut pos = range.start;
        while pos < range.end {
            let (tag, len, header) = self.header(pos)?;
            let start = pos + header;
            if tag != (0xFFFE, 0xE000) {
                return Err((
                    false,
                    format!("expected a sequence item at byte {}, found ({:04X},{:04X})", pos + 128, tag.0, tag.1),
                ));
            }
            pos = if len == UNDEFINED {
                self.elements(start, range.end, depth, true)?
            } else {
                let value = self.value_range(tag, start, len, range.end)?;
                self.elements(value.start, value.end, depth, false)?;
                value.end
            };
        }
        Ok(())
    }

    /// Items of an undefined-length sequence (or pixel fragments) up to the sequence delimiter.
    fn items(&mut self, mut pos: usize, end: usize, depth: usize, fragments: bool) -> WalkResult<usize> {
        loop {
            if pos >= end {
                return Err((true, "the data ends inside a sequence (no sequence delimiter)".into()));
            }
            let (tag, len, header) = self.header(pos)?;
            let start = pos + header;
            match tag {
                (0xFFFE, 0xE0DD) => return Ok(start),
                (0xFFFE, 0xE000) if len == UNDEFINED && !fragments => pos = self.elements(start, end, depth, true)?,
                (0xFFFE, 0xE000) if len != UNDEFINED => {
                    let value = self.value_range(tag, start, len, end)?;
                    if !fragments {
                        self.elements(value.start, value.end, depth, false)?;
                    }
                    pos = value.end;
                }
                _ => {
                    return Err((
                        false,
                        format!("expected a sequence item at byte {}, found ({:04X},{:04X})", pos + 128, tag.0, tag.1),
                    ));
                }
            }
        }
    }
}

/// An error and its sources, joined with ": ".
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let t = c.to_string();
        if !s.contains(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        cur = c.source();
    }
    s
}

/// The regular files of a folder, sorted by name.
fn folder_files(dir: &Path) -> Result<Vec<Source<'static>>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let p = entry.path();
        if std::fs::metadata(&p).is_ok_and(|m| m.is_file()) {
            files.push(p);
        }
    }
    files.sort();
    Ok(files.into_iter().map(Source::File).collect())
}

/// What the header of one image object says about its pixels.
#[derive(Clone, Debug, PartialEq)]
struct PixelFormat {
    rows: usize,
    cols: usize,
    frames: usize,
    samples_per_pixel: u16,
    photometric: String,
    bits_allocated: u16,
    bits_stored: u16,
    high_bit: u16,
    signed: bool,
}

/// Position, orientation, spacing and rescale of one slice (a file or one frame).
#[derive(Clone, Debug)]
struct SliceGeom {
    ipp: [f64; 3],
    iop: [f64; 6],
    /// PixelSpacing: (between rows, between columns) in mm.
    pixel_spacing: [f64; 2],
    /// SpacingBetweenSlices, else SliceThickness: used only for a single slice.
    slice_step_mm: Option<f64>,
    slope: f64,
    intercept: f64,
    /// A geometry tag that was missing (defaults used); an error unless the series is one slice.
    missing: Option<String>,
}

/// The header of one image object.
#[derive(Debug)]
struct Header {
    source: usize,
    series_uid: String,
    study_uid: Option<String>,
    patient_id: Option<String>,
    series_number: Option<i64>,
    description: Option<String>,
    modality: String,
    rescale_type: Option<String>,
    transfer_syntax: String,
    /// The pixel format and one geometry per frame, or the first problem (naming the tag).
    image: std::result::Result<(PixelFormat, Vec<SliceGeom>), String>,
    /// Notes about this file (e.g. frame positions derived from SpacingBetweenSlices).
    notes: Vec<String>,
}

fn read_headers(label: &Path, sources: &[Source], skip_non_dicom: bool, opts: &mut LoadOptions) -> Result<Vec<Header>> {
    let n = sources.len() as u64;
    let mut headers = Vec::new();
    for (i, src) in sources.iter().enumerate() {
        opts.report(label, "reading DICOM headers", i as u64, n)?;
        if !src.has_preamble()? {
            if skip_non_dicom {
                continue;
            }
            return Err(Error::new(
                src.path(),
                ErrorKind::BadMagic { format: "DICOM", detail: "no 'DICM' after the 128-byte preamble".into() },
            ));
        }
        let obj = src.open(true)?;
        if obj.meta().media_storage_sop_class_uid() == MEDIA_STORAGE_DIRECTORY || obj.get(tags::ROWS).is_none() {
            // DICOMDIR or a non-image object (report, presentation state, ...).
            continue;
        }
        headers.push(parse_header(i, &obj, src.byte_len()?));
    }
    opts.report(label, "reading DICOM headers", n, n)?;
    Ok(headers)
}

/// The header of the object `obj`, read from a file of `byte_len` bytes.
fn parse_header(source: usize, obj: &DefaultDicomObject, byte_len: u64) -> Header {
    let mut notes = Vec::new();
    let image = parse_pixel_format(obj).and_then(|fmt| {
        check_frame_count(&fmt, byte_len, obj.meta().transfer_syntax())?;
        let geoms = parse_geometry(obj, fmt.frames, &mut notes)?;
        Ok((fmt, geoms))
    });
    Header {
        source,
        series_uid: get_str(obj, tags::SERIES_INSTANCE_UID).unwrap_or_default(),
        study_uid: get_str(obj, tags::STUDY_INSTANCE_UID),
        patient_id: get_str(obj, tags::PATIENT_ID),
        series_number: get_int(obj, tags::SERIES_NUMBER),
        description: get_str(obj, tags::SERIES_DESCRIPTION),
        modality: get_str(obj, tags::MODALITY).unwrap_or_default(),
        rescale_type: get_str(obj, tags::RESCALE_TYPE),
        transfer_syntax: obj.meta().transfer_syntax().to_string(),
        image,
        notes,
    }
}

/// Refuses more frames than a file of `byte_len` bytes can hold, before a geometry record is built for each: a
/// frame takes at least its own size in native pixel data, at least an 8-byte fragment item when encapsulated,
/// and a deflated data set inflates at most 1032-fold. (A 2 KB file claiming 20 million frames made the header
/// reader allocate 2.9 GB; the pixel data are checked against the files' size again before the volume is
/// allocated, in [`check_files_can_hold`].)
fn check_frame_count(fmt: &PixelFormat, byte_len: u64, transfer_syntax: &str) -> std::result::Result<(), String> {
    let frame_bytes = (fmt.rows * fmt.cols) as u64
        * u64::from(fmt.samples_per_pixel.max(1))
        * u64::from(fmt.bits_allocated.div_ceil(8).max(1));
    let data_bytes = if transfer_syntax.trim_end_matches(['\0', ' ']) == "1.2.840.10008.1.2.1.99" {
        byte_len.saturating_mul(1032)
    } else {
        byte_len
    };
    let most = data_bytes / frame_bytes.min(8);
    if fmt.frames as u64 > most {
        return Err(format!(
            "{} {} is more than a file of {byte_len} bytes can hold ({most} frames of {}x{} at most)",
            tag_label("NumberOfFrames", tags::NUMBER_OF_FRAMES),
            fmt.frames,
            fmt.cols,
            fmt.rows
        ));
    }
    Ok(())
}

/// "Name (gggg,eeee)" for messages.
fn tag_label(name: &str, tag: Tag) -> String {
    format!("{name} ({:04X},{:04X})", tag.group(), tag.element())
}

fn get_str(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    let s = obj.get(tag)?.value().to_str().ok()?;
    let s = s.trim_matches(|c: char| c.is_whitespace() || c == '\0');
    (!s.is_empty()).then(|| s.to_string())
}

fn get_int(obj: &InMemDicomObject, tag: Tag) -> Option<i64> {
    obj.get(tag)?.value().to_int::<i64>().ok()
}

/// The numbers of an element, checked to be `n` finite values.
fn elem_f64s(e: &InMemElement, name: &str, n: usize) -> std::result::Result<Vec<f64>, String> {
    let label = tag_label(name, e.header().tag);
    let v = e.value().to_multi_float64().map_err(|err| format!("{label} is not a list of numbers: {err}"))?;
    if v.len() < n {
        return Err(format!("{label} has {} values, expected {n}", v.len()));
    }
    if v.iter().take(n).any(|x| !x.is_finite()) {
        return Err(format!("{label} has a value that is not finite: {v:?}"));
    }
    Ok(v[..n].to_vec())
}

fn required_u16(obj: &InMemDicomObject, tag: Tag, name: &str) -> std::result::Result<u16, String> {
    let e = obj.get(tag).ok_or_else(|| format!("{} is missing", tag_label(name, tag)))?;
    e.value().to_int::<u16>().map_err(|err| format!("{} is not a valid number: {err}", tag_label(name, tag)))
}

fn parse_pixel_format(obj: &InMemDicomObject) -> std::result::Result<PixelFormat, String> {
    let rows = required_u16(obj, tags::ROWS, "Rows")?;
    let cols = required_u16(obj, tags::COLUMNS, "Columns")?;
    let samples_per_pixel = if obj.get(tags::SAMPLES_PER_PIXEL).is_some() {
        required_u16(obj, tags::SAMPLES_PER_PIXEL, "SamplesPerPixel")?
    } else {
        1
    };
    let bits_allocated = required_u16(obj, tags::BITS_ALLOCATED, "BitsAllocated")?;
    let bits_stored = if obj.get(tags::BITS_STORED).is_some() {
        required_u16(obj, tags::BITS_STORED, "BitsStored")?
    } else {
        bits_allocated
    };
    let high_bit = if obj.get(tags::HIGH_BIT).is_some() {
        required_u16(obj, tags::HIGH_BIT, "HighBit")?
    } else {
        bits_stored.saturating_sub(1)
    };
    let signed = if obj.get(tags::PIXEL_REPRESENTATION).is_some() {
        required_u16(obj, tags::PIXEL_REPRESENTATION, "PixelRepresentation")? == 1
    } else {
        false
    };
    let frames = match obj.get(tags::NUMBER_OF_FRAMES) {
        Some(e) => e.value().to_int::<i64>().ok().filter(|&n| n >= 1 && n <= i64::from(u32::MAX)).ok_or_else(|| {
            format!("{} is not a positive number", tag_label("NumberOfFrames", tags::NUMBER_OF_FRAMES))
        })? as usize,
        None => 1,
    };
    if rows == 0 || cols == 0 {
        return Err(format!("the image is empty: Rows {rows}, Columns {cols}"));
    }
    Ok(PixelFormat {
        rows: rows as usize,
        cols: cols as usize,
        frames,
        samples_per_pixel,
        photometric: get_str(obj, tags::PHOTOMETRIC_INTERPRETATION).unwrap_or_default(),
        bits_allocated,
        bits_stored,
        high_bit,
        signed,
    })
}

/// The first item of sequence `seq` in `item`.
fn first_item(item: Option<&InMemDicomObject>, seq: Tag) -> Option<&InMemDicomObject> {
    item?.get(seq)?.items()?.first()
}

/// Looks up `tag` for one frame: per-frame functional group, then shared, then the top level.
fn frame_elem<'a>(
    obj: &'a InMemDicomObject,
    per_frame: Option<&'a InMemDicomObject>,
    shared: Option<&'a InMemDicomObject>,
    seq: Tag,
    tag: Tag,
) -> Option<&'a InMemElement> {
    first_item(per_frame, seq)
        .and_then(|i| i.get(tag))
        .or_else(|| first_item(shared, seq).and_then(|i| i.get(tag)))
        .or_else(|| obj.get(tag))
}

fn parse_geometry(
    obj: &InMemDicomObject,
    frames: usize,
    notes: &mut Vec<String>,
) -> std::result::Result<Vec<SliceGeom>, String> {
    let per_frame_items = obj.get(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE).and_then(|e| e.items());
    let shared = obj.get(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE).and_then(|e| e.items()).and_then(|i| i.first());
    let enhanced = per_frame_items.is_some() || shared.is_some();
    let geom_frames = if enhanced { frames } else { 1 };
    let mut out = Vec::with_capacity(geom_frames.min(65_536));
    for f in 0..geom_frames {
        let per = per_frame_items.and_then(|items| items.get(f));
        let find = |seq: Tag, tag: Tag| frame_elem(obj, per, shared, seq, tag);
        let need = |seq: Tag, tag: Tag, name: &str, n: usize| -> std::result::Result<Vec<f64>, String> {
            let e = find(seq, tag).ok_or_else(|| {
                let frame = if enhanced { format!(" for frame {}", f + 1) } else { String::new() };
                format!("{} is missing{frame}", tag_label(name, tag))
            })?;
            elem_f64s(e, name, n)
        };
        // A single classic slice without geometry (e.g. a secondary capture) gets the identity
        // placement; `plan_geometry` rejects that for series of more than one slice.
        let mut missing = None;
        let mut need_or = |seq: Tag, tag: Tag, name: &str, default: &[f64]| {
            if !enhanced && frames == 1 && find(seq, tag).is_none() {
                missing.get_or_insert_with(|| format!("{} is missing", tag_label(name, tag)));
                return Ok(default.to_vec());
            }
            need(seq, tag, name, default.len())
        };
        let ipp =
            need_or(tags::PLANE_POSITION_SEQUENCE, tags::IMAGE_POSITION_PATIENT, "ImagePositionPatient", &[0.0; 3])?;
        let iop = need_or(
            tags::PLANE_ORIENTATION_SEQUENCE,
            tags::IMAGE_ORIENTATION_PATIENT,
            "ImageOrientationPatient",
            &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        )?;
        let ps = need_or(tags::PIXEL_MEASURES_SEQUENCE, tags::PIXEL_SPACING, "PixelSpacing", &[1.0, 1.0])?;
        if ps.iter().any(|&s| s <= 0.0) {
            return Err(format!("{} must be positive: {ps:?}", tag_label("PixelSpacing", tags::PIXEL_SPACING)));
        }
        let step = |tag: Tag| {
            find(tags::PIXEL_MEASURES_SEQUENCE, tag)
                .and_then(|e| e.value().to_float64().ok())
                .filter(|s| s.is_finite() && *s > 0.0)
        };
        let slice_step_mm = step(tags::SPACING_BETWEEN_SLICES).or_else(|| step(tags::SLICE_THICKNESS));
        let number = |tag: Tag, name: &str| -> std::result::Result<Option<f64>, String> {
            match find(tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE, tag) {
                None => Ok(None),
                Some(e) if e.value().primitive().is_some_and(|p| p.to_str().trim().is_empty()) => Ok(None),
                Some(e) => elem_f64s(e, name, 1).map(|v| Some(v[0])),
            }
        };
        let slope = number(tags::RESCALE_SLOPE, "RescaleSlope")?.unwrap_or(1.0);
        let intercept = number(tags::RESCALE_INTERCEPT, "RescaleIntercept")?.unwrap_or(0.0);
        let iop: [f64; 6] = std::array::from_fn(|i| iop[i]);
        check_orientation(&iop)?;
        out.push(SliceGeom {
            ipp: [ipp[0], ipp[1], ipp[2]],
            iop,
            pixel_spacing: [ps[0], ps[1]],
            slice_step_mm,
            slope,
            intercept,
            missing,
        });
    }
    if !enhanced && frames > 1 {
        // Classic multi-frame: one position for all frames; stack them along the normal.
        let g = out[0].clone();
        let step = g.slice_step_mm.ok_or_else(|| {
            format!(
                "multi-frame object with {frames} frames has no per-frame positions (no {}) and no {} or {}",
                tag_label("PerFrameFunctionalGroupsSequence", tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE),
                tag_label("SpacingBetweenSlices", tags::SPACING_BETWEEN_SLICES),
                tag_label("SliceThickness", tags::SLICE_THICKNESS)
            )
        })?;
        let n = normal(&g.iop);
        notes.push(format!(
            "multi-frame object without per-frame positions: frames placed {step} mm apart along the slice normal"
        ));
        out = (0..frames)
            .map(|f| {
                let t = step * f as f64;
                SliceGeom { ipp: [g.ipp[0] + t * n[0], g.ipp[1] + t * n[1], g.ipp[2] + t * n[2]], ..g.clone() }
            })
            .collect();
    }
    Ok(out)
}

fn check_orientation(iop: &[f64; 6]) -> std::result::Result<(), String> {
    let r = Vector3::new(iop[0], iop[1], iop[2]);
    let c = Vector3::new(iop[3], iop[4], iop[5]);
    if (r.norm() - 1.0).abs() > 1e-2 || (c.norm() - 1.0).abs() > 1e-2 || r.dot(&c).abs() > 1e-2 {
        return Err(format!(
            "{} is not two orthogonal unit vectors: {iop:?}",
            tag_label("ImageOrientationPatient", tags::IMAGE_ORIENTATION_PATIENT)
        ));
    }
    Ok(())
}

/// n = row × col.
fn normal(iop: &[f64; 6]) -> [f64; 3] {
    let n = Vector3::new(iop[0], iop[1], iop[2]).cross(&Vector3::new(iop[3], iop[4], iop[5]));
    [n[0], n[1], n[2]]
}

// ---------------------------------------------------------------------------------------------
// Series
// ---------------------------------------------------------------------------------------------

/// Groups headers by SeriesInstanceUID, sorted by SeriesNumber (missing last) then UID.
fn group_series(headers: Vec<Header>) -> Vec<Vec<Header>> {
    let mut by_uid: BTreeMap<String, Vec<Header>> = BTreeMap::new();
    for h in headers {
        by_uid.entry(h.series_uid.clone()).or_default().push(h);
    }
    let mut groups: Vec<Vec<Header>> = by_uid.into_values().collect();
    groups.sort_by(|a, b| {
        let key = |g: &[Header]| (g[0].series_number.is_none(), g[0].series_number, g[0].series_uid.clone());
        key(a).cmp(&key(b))
    });
    groups
}

fn summary(group: &[Header]) -> SeriesSummary {
    let h = &group[0];
    SeriesSummary {
        series_instance_uid: h.series_uid.clone(),
        series_number: h.series_number,
        modality: h.modality.clone(),
        description: h.description.clone().unwrap_or_default(),
        files: group.len(),
    }
}

fn select_series(label: &Path, headers: Vec<Header>, opts: &LoadOptions) -> Result<Vec<Header>> {
    let mut groups = group_series(headers);
    match &opts.series_instance_uid {
        Some(uid) => {
            let wanted = uid.trim();
            if let Some(i) = groups.iter().position(|g| g[0].series_uid == wanted) {
                return Ok(groups.swap_remove(i));
            }
            let found: Vec<String> = groups.iter().map(|g| summary(g).to_string()).collect();
            Err(Error::invalid(
                label,
                format!("no series with SeriesInstanceUID {wanted}; found:\n  {}", found.join("\n  ")),
            ))
        }
        None if groups.len() > 1 => {
            Err(Error::new(label, ErrorKind::MultipleSeries(groups.iter().map(|g| summary(g)).collect())))
        }
        None => Ok(groups.pop().unwrap_or_default()),
    }
}

// ---------------------------------------------------------------------------------------------
// Geometry plan
// ---------------------------------------------------------------------------------------------

/// One slice of the output: which header (index into the series) and which frame.
#[derive(Clone, Debug)]
struct Slot {
    header: usize,
    frame: usize,
    geom: SliceGeom,
    d: f64,
}

#[derive(Debug)]
struct Plan {
    dims: [usize; 3],
    lps_from_index: Transform<Lps, Index>,
    /// Sorted ascending along the normal; index = k.
    slots: Vec<Slot>,
    warnings: Vec<String>,
    /// `Assumed` when a single slice lacks position, orientation or spacing.
    geometry_source: GeometrySource,
}

fn plan_geometry(label: &Path, sources: &[Source], series: &[Header]) -> Result<Plan> {
    let name = |h: usize| sources[series[h].source].path().display().to_string();
    let mut slots = Vec::new();
    let mut first_fmt: Option<(usize, &PixelFormat)> = None;
    for (hi, h) in series.iter().enumerate() {
        let path = sources[h.source].path();
        let (fmt, geoms) = h.image.as_ref().map_err(|e| Error::invalid(path, e.clone()))?;
        if fmt.samples_per_pixel != 1 || is_colour(&fmt.photometric) {
            return Err(Error::unsupported(
                path,
                format!(
                    "colour images ({} samples per pixel, PhotometricInterpretation {}); only greyscale volumes are read",
                    fmt.samples_per_pixel, fmt.photometric
                ),
            ));
        }
        if let Some((f0, fmt0)) = first_fmt {
            for (what, a, b) in [
                ("Rows (0028,0010)", fmt0.rows, fmt.rows),
                ("Columns (0028,0011)", fmt0.cols, fmt.cols),
                ("BitsAllocated (0028,0100)", fmt0.bits_allocated as usize, fmt.bits_allocated as usize),
                ("PixelRepresentation (0028,0103)", usize::from(fmt0.signed), usize::from(fmt.signed)),
            ] {
                if a != b {
                    return Err(Error::invalid(path, format!("{what} is {b} but {a} in {}", name(f0))));
                }
            }
        } else {
            first_fmt = Some((hi, fmt));
        }
        for (frame, g) in geoms.iter().enumerate() {
            slots.push(Slot { header: hi, frame, geom: g.clone(), d: 0.0 });
        }
    }
    let Some(first) = slots.first().cloned() else {
        return Err(Error::invalid(label, "the series has no slices"));
    };
    let Some((_, fmt)) = first_fmt else {
        return Err(Error::invalid(label, "the series has no slices"));
    };

    let mut warnings: Vec<String> = Vec::new();
    let mut geometry_source = GeometrySource::DicomPatient;
    if let Some(s) = slots.iter().find(|s| s.geom.missing.is_some()) {
        let what = s.geom.missing.clone().unwrap_or_default();
        if slots.len() > 1 {
            return Err(Error::invalid(sources[series[s.header].source].path(), what));
        }
        warnings.push(format!(
            "{what}: the single slice is placed at the origin, axis-aligned, with 1 mm pixels where spacing is missing"
        ));
        geometry_source = GeometrySource::Assumed;
    }

    // Same orientation and pixel spacing everywhere.
    for s in &slots {
        let diff = first.geom.iop.iter().zip(&s.geom.iop).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if diff > ORIENTATION_TOLERANCE {
            return Err(Error::invalid(
                sources[series[s.header].source].path(),
                format!(
                    "slice orientations are not parallel: ImageOrientationPatient {:?} here but {:?} in {} \
                     (differs by {diff:.3e}, tolerance {ORIENTATION_TOLERANCE:e})",
                    s.geom.iop,
                    first.geom.iop,
                    name(first.header)
                ),
            ));
        }
        let ps_diff = (0..2).map(|i| (first.geom.pixel_spacing[i] - s.geom.pixel_spacing[i]).abs()).fold(0.0, f64::max);
        if ps_diff > 1e-4 * first.geom.pixel_spacing[0].max(first.geom.pixel_spacing[1]) {
            return Err(Error::invalid(
                sources[series[s.header].source].path(),
                format!(
                    "PixelSpacing (0028,0030) is {:?} here but {:?} in {}",
                    s.geom.pixel_spacing,
                    first.geom.pixel_spacing,
                    name(first.header)
                ),
            ));
        }
    }

    let n = normal(&first.geom.iop);
    for s in &mut slots {
        s.d = s.geom.ipp[0] * n[0] + s.geom.ipp[1] * n[1] + s.geom.ipp[2] * n[2];
    }
    // Stable sort: equal positions keep file order, then are rejected below as duplicates.
    slots.sort_by(|a, b| a.d.total_cmp(&b.d));

    let where_ = |s: &Slot| {
        let multi = series[s.header].image.as_ref().is_ok_and(|(f, _)| f.frames > 1);
        if multi { format!("{} frame {}", name(s.header), s.frame + 1) } else { name(s.header) }
    };
    for h in series {
        warnings.extend(h.notes.iter().cloned());
    }
    let count = slots.len();
    let steps: Vec<f64> = slots.windows(2).map(|w| w[1].d - w[0].d).collect();
    for (i, &s) in steps.iter().enumerate() {
        if s < DUPLICATE_MM {
            return Err(Error::invalid(
                label,
                format!(
                    "duplicate slice position {:.4} mm along the normal: {} and {}",
                    slots[i].d,
                    where_(&slots[i]),
                    where_(&slots[i + 1])
                ),
            ));
        }
    }
    let last = slots[count - 1].clone();
    let k_col = if count > 1 {
        let mut sorted = steps.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        for (i, &s) in steps.iter().enumerate() {
            if s > GAP_FACTOR * median {
                return Err(Error::invalid(
                    label,
                    format!(
                        "missing slices: a gap of {s:.4} mm between positions {:.4} and {:.4} mm along the \
                         slice normal ({} and {}); the median spacing is {median:.4} mm",
                        slots[i].d,
                        slots[i + 1].d,
                        where_(&slots[i]),
                        where_(&slots[i + 1])
                    ),
                ));
            }
        }
        let mean = (last.d - first_d(&slots)) / (count - 1) as f64;
        if steps.windows(2).any(|w| (w[1] - w[0]).abs() > UNEVEN_FRACTION * mean) {
            warnings.push(format!(
                "uneven slice spacing: steps from {:.4} to {:.4} mm (mean {mean:.4} mm); the volume uses the mean",
                sorted[0],
                sorted[sorted.len() - 1]
            ));
        }
        let p0 = slots[0].geom.ipp;
        let k: [f64; 3] = std::array::from_fn(|a| (last.geom.ipp[a] - p0[a]) / (count - 1) as f64);
        // Positions off the line p0 + k·t (in-plane shifts) cannot be represented: warn.
        let r = &first.geom.iop[0..3];
        let c = &first.geom.iop[3..6];
        let off = slots
            .iter()
            .map(|s| {
                let t = (s.d - slots[0].d) / (last.d - slots[0].d) * (count - 1) as f64;
                let e: [f64; 3] = std::array::from_fn(|a| s.geom.ipp[a] - (p0[a] + t * k[a]));
                (e[0] * r[0] + e[1] * r[1] + e[2] * r[2]).abs().max((e[0] * c[0] + e[1] * c[1] + e[2] * c[2]).abs())
            })
            .fold(0.0, f64::max);
        if off > 0.1 * first.geom.pixel_spacing[0].min(first.geom.pixel_spacing[1]) {
            warnings.push(format!(
                "slice positions are not on one line: up to {off:.4} mm in-plane from the line through the first and last"
            ));
        }
        k
    } else {
        let step = first.geom.slice_step_mm.unwrap_or(1.0);
        [n[0] * step, n[1] * step, n[2] * step]
    };

    let g = &slots[0].geom;
    let [row_mm, col_mm] = g.pixel_spacing;
    let i_col = Vector3::new(g.iop[0], g.iop[1], g.iop[2]) * col_mm;
    let j_col = Vector3::new(g.iop[3], g.iop[4], g.iop[5]) * row_mm;
    let linear = Matrix3::from_columns(&[i_col, j_col, Vector3::from(k_col)]);
    let lps_from_index = Transform::from_linear_translation(linear, g.ipp);
    Ok(Plan { dims: [fmt.cols, fmt.rows, count], lps_from_index, slots, warnings, geometry_source })
}

fn first_d(slots: &[Slot]) -> f64 {
    slots.first().map_or(0.0, |s| s.d)
}

fn is_colour(photometric: &str) -> bool {
    !(photometric.is_empty() || photometric == "MONOCHROME1" || photometric == "MONOCHROME2")
}

// ---------------------------------------------------------------------------------------------
// Reading a series
// ---------------------------------------------------------------------------------------------

/// Largest decoded-to-encoded size ratio believed for compressed pixel data (deflate peaks near
/// 1032:1; RLE at 64:1; JPEG lossless far lower). Only lossy JPEG 2000 of flat images comes close.
const MAX_COMPRESSION_RATIO: u64 = 2048;

/// Refuses a series whose files cannot hold `decoded_bytes` of pixels: at most their size when
/// uncompressed, at most [`MAX_COMPRESSION_RATIO`] times it when compressed. Runs before the volume
/// is allocated, so a small file that claims huge Rows × Columns × frames fails without allocating.
fn check_files_can_hold(label: &Path, sources: &[Source], series: &[Header], decoded_bytes: u64) -> Result<()> {
    let mut seen = std::collections::BTreeSet::new();
    let mut capacity = 0u64;
    for h in series {
        if !seen.insert(h.source) {
            continue;
        }
        let len = sources[h.source].byte_len()?;
        let uncompressed = matches!(
            h.transfer_syntax.as_str(),
            "1.2.840.10008.1.2" | "1.2.840.10008.1.2.1" | "1.2.840.10008.1.2.2" | "1.2.840.10008.1.2.1.98"
        );
        capacity = capacity.saturating_add(if uncompressed { len } else { len.saturating_mul(MAX_COMPRESSION_RATIO) });
    }
    if decoded_bytes > capacity {
        return Err(Error::truncated(
            label,
            format!(
                "Rows × Columns × frames need {decoded_bytes} bytes of pixels, but the {} file(s) can hold at most \
                 {capacity}",
                seen.len()
            ),
        ));
    }
    Ok(())
}

fn read_series(label: &Path, sources: &[Source], headers: Vec<Header>, opts: &mut LoadOptions) -> Result<Volume> {
    let series = select_series(label, headers, opts)?;
    let plan = plan_geometry(label, sources, &series)?;
    for h in &series {
        check_transfer_syntax(sources[h.source].path(), &h.transfer_syntax)?;
    }
    let Some(Ok((fmt, _))) = series.first().map(|h| &h.image) else {
        return Err(Error::invalid(label, "the series has no slices"));
    };
    let kind = StoredKind::of(label, fmt)?;
    let dims = plan.dims;
    let slice_len = dims[0] * dims[1];
    let total = volume::check_allocation(label, dims, kind.bytes(), opts.max_voxel_bytes)?;
    check_files_can_hold(label, sources, &series, (total * kind.bytes()) as u64)?;
    let mut stored = Stored::zeros(label, kind, total)?;
    let mut ranges = vec![(0i64, 0i64); dims[2]];

    // Decode file by file in the order of their first slice; each file is dropped before the next.
    let mut slots_of: Vec<Vec<(usize, usize)>> = vec![Vec::new(); series.len()];
    for (k, s) in plan.slots.iter().enumerate() {
        slots_of[s.header].push((s.frame, k));
    }
    let mut order: Vec<usize> = (0..series.len()).collect();
    order.sort_by_key(|&h| slots_of[h].iter().map(|&(_, k)| k).min().unwrap_or(usize::MAX));
    let n_files = order.len() as u64;
    for (done, &hi) in order.iter().enumerate() {
        opts.report(label, "decoding slices", done as u64, n_files)?;
        let h = &series[hi];
        let src = &sources[h.source];
        let Ok((hfmt, _)) = &h.image else { continue };
        decode_file(src, h, hfmt, &slots_of[hi], slice_len, &mut stored, &mut ranges)?;
    }
    opts.report(label, "decoding slices", n_files, n_files)?;

    let rescales: Vec<(f64, f64)> = plan.slots.iter().map(|s| (s.geom.slope, s.geom.intercept)).collect();
    let (data, rescale, mut warnings) = finalize(label, stored, slice_len, &rescales, &ranges, dims, opts)?;
    let mut vol = Volume::new(label, dims, data, plan.lps_from_index, plan.geometry_source)?;
    let h = &series[0];
    vol.modality = Modality::from_dicom(&h.modality);
    vol.rescale = rescale;
    let units = match h.rescale_type.as_deref() {
        Some(t) if t != "US" => Some(t.to_string()),
        _ if vol.modality == Modality::Ct && (rescale.applied || has_rescale(&plan)) => Some("HU".to_string()),
        _ => None,
    };
    let mut all_warnings = plan.warnings;
    all_warnings.append(&mut warnings);
    vol.metadata = crate::volume::Metadata {
        description: h.description.clone(),
        series_instance_uid: (!h.series_uid.is_empty()).then(|| h.series_uid.clone()),
        study_instance_uid: h.study_uid.clone(),
        patient_id: h.patient_id.clone(),
        series_number: h.series_number,
        value_units: units,
        warnings: all_warnings,
    };
    Ok(vol)
}

/// True when any slice has a non-identity rescale (CT values are then HU).
fn has_rescale(plan: &Plan) -> bool {
    plan.slots.iter().any(|s| !is_identity(s.geom.slope, s.geom.intercept))
}

/// Exactly slope 1 and intercept 0 (the manifest rule compares exactly).
#[allow(clippy::float_cmp)]
fn is_identity(slope: f64, intercept: f64) -> bool {
    slope == 1.0 && intercept == 0.0
}

fn transfer_syntax_name(uid: &str) -> Option<&'static str> {
    SUPPORTED_TRANSFER_SYNTAXES.iter().chain(UNSUPPORTED_TRANSFER_SYNTAXES).find(|(u, _)| *u == uid).map(|(_, n)| *n)
}

fn check_transfer_syntax(path: &Path, uid: &str) -> Result<()> {
    if SUPPORTED_TRANSFER_SYNTAXES.iter().any(|(u, _)| *u == uid) {
        return Ok(());
    }
    let name = transfer_syntax_name(uid).unwrap_or("(unknown)");
    Err(Error::unsupported(path, format!("unsupported transfer syntax {name} ({uid})")))
}

// ---------------------------------------------------------------------------------------------
// Pixels
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum StoredKind {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
}

impl StoredKind {
    fn of(path: &Path, fmt: &PixelFormat) -> Result<Self> {
        Ok(match (fmt.bits_allocated, fmt.signed) {
            (8, false) => Self::U8,
            (8, true) => Self::I8,
            (16, false) => Self::U16,
            (16, true) => Self::I16,
            (32, false) => Self::U32,
            (32, true) => Self::I32,
            (b, _) => {
                return Err(Error::unsupported(path, format!("BitsAllocated (0028,0100) {b} (only 8, 16 and 32)")));
            }
        })
    }
    fn bytes(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 => 4,
        }
    }
}

/// The volume in its stored type, before rescale.
enum Stored {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    I32(Vec<i32>),
}

impl Stored {
    /// `n` zero samples of `kind`, allocated fallibly: memory the system refuses is an
    /// [`ErrorKind::OutOfMemory`] naming `path`, not an abort.
    fn zeros(path: &Path, kind: StoredKind, n: usize) -> Result<Self> {
        const WHAT: &str = "the stored pixels";
        Ok(match kind {
            StoredKind::U8 => Self::U8(try_zeros(path, n, WHAT)?),
            StoredKind::I8 => Self::I8(try_zeros(path, n, WHAT)?),
            StoredKind::U16 => Self::U16(try_zeros(path, n, WHAT)?),
            StoredKind::I16 => Self::I16(try_zeros(path, n, WHAT)?),
            StoredKind::U32 => Self::U32(try_zeros(path, n, WHAT)?),
            StoredKind::I32 => Self::I32(try_zeros(path, n, WHAT)?),
        })
    }
}

/// `n` zeros, allocated fallibly ([`volume::try_with_capacity`]): `vec![0; n]` would abort the process when
/// the memory cannot be had.
fn try_zeros<T: Copy + Default>(path: &Path, n: usize, what: &str) -> Result<Vec<T>> {
    let mut v = volume::try_with_capacity(path, n, what)?;
    v.resize(n, T::default());
    Ok(v)
}

/// `f(i, v[i])` for every sample, into a buffer allocated fallibly. When `S` and `T` have the same layout, std
/// collects a vector's own `into_iter` in place (no second buffer, nothing to allocate); otherwise the output is
/// allocated with [`volume::try_with_capacity`].
fn try_convert<S, T>(path: &Path, v: Vec<S>, f: impl FnMut((usize, S)) -> T) -> Result<Vec<T>> {
    if size_of::<S>() == size_of::<T>() && align_of::<S>() == align_of::<T>() {
        return Ok(v.into_iter().enumerate().map(f).collect());
    }
    let mut out = volume::try_with_capacity(path, v.len(), "the converted samples")?;
    out.extend(v.into_iter().enumerate().map(f));
    Ok(out)
}

/// How to turn the raw bits of one sample into its value.
#[derive(Clone, Copy, Debug)]
struct BitLayout {
    shift: u32,
    bits: u32,
    signed: bool,
}

impl BitLayout {
    fn new(path: &Path, fmt: &PixelFormat, native: bool) -> Result<Self> {
        let (alloc, stored, high) =
            (u32::from(fmt.bits_allocated), u32::from(fmt.bits_stored), u32::from(fmt.high_bit));
        if stored == 0 || stored > alloc {
            return Err(Error::invalid(path, format!("BitsStored (0028,0101) {stored} with BitsAllocated {alloc}")));
        }
        // Codecs return values in the low bits; native data may place them at HighBit.
        let shift = if native && high < alloc && high + 1 >= stored { high + 1 - stored } else { 0 };
        Ok(Self { shift, bits: stored, signed: fmt.signed })
    }

    #[inline]
    fn value(self, raw: u32) -> i64 {
        let v = (raw >> self.shift) & (u32::MAX >> (32 - self.bits));
        if self.signed && self.bits > 0 && (v >> (self.bits - 1)) & 1 == 1 {
            i64::from(v) - (1i64 << self.bits)
        } else {
            i64::from(v)
        }
    }
}

/// The samples of one frame, as found: bytes (little-endian) or 16-bit words.
#[derive(Clone, Copy)]
enum FrameSamples<'a> {
    Bytes(&'a [u8]),
    Words(&'a [u16]),
}

/// Writes one frame into slice `k` of `dst`; returns the (min, max) of the stored values.
fn store_frame(dst: &mut Stored, k: usize, n: usize, src: FrameSamples, bytes: usize, layout: BitLayout) -> (i64, i64) {
    fn fill<T: Copy>(
        dst: &mut [T],
        raws: impl Iterator<Item = u32>,
        layout: BitLayout,
        cast: impl Fn(i64) -> T,
    ) -> (i64, i64) {
        let mut lo = i64::MAX;
        let mut hi = i64::MIN;
        for (d, raw) in dst.iter_mut().zip(raws) {
            let v = layout.value(raw);
            lo = lo.min(v);
            hi = hi.max(v);
            *d = cast(v);
        }
        (lo, hi)
    }
    fn dispatch(
        dst: &mut Stored,
        range: std::ops::Range<usize>,
        raws: impl Iterator<Item = u32>,
        l: BitLayout,
    ) -> (i64, i64) {
        match dst {
            Stored::U8(v) => fill(&mut v[range], raws, l, |x| x as u8),
            Stored::I8(v) => fill(&mut v[range], raws, l, |x| x as i8),
            Stored::U16(v) => fill(&mut v[range], raws, l, |x| x as u16),
            Stored::I16(v) => fill(&mut v[range], raws, l, |x| x as i16),
            Stored::U32(v) => fill(&mut v[range], raws, l, |x| x as u32),
            Stored::I32(v) => fill(&mut v[range], raws, l, |x| x as i32),
        }
    }
    let range = k * n..(k + 1) * n;
    match (src, bytes) {
        (FrameSamples::Bytes(b), 1) => dispatch(dst, range, b.iter().map(|&x| u32::from(x)), layout),
        (FrameSamples::Bytes(b), 2) => {
            dispatch(dst, range, b.chunks_exact(2).map(|c| u32::from(u16::from_le_bytes([c[0], c[1]]))), layout)
        }
        (FrameSamples::Bytes(b), _) => {
            dispatch(dst, range, b.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])), layout)
        }
        (FrameSamples::Words(w), 2) => dispatch(dst, range, w.iter().map(|&x| u32::from(x)), layout),
        (FrameSamples::Words(w), _) => {
            dispatch(dst, range, w.chunks_exact(2).map(|c| u32::from(c[0]) | (u32::from(c[1]) << 16)), layout)
        }
    }
}

/// Opens one file fully, decodes its frames and stores them at their slots.
fn decode_file(
    src: &Source,
    h: &Header,
    fmt: &PixelFormat,
    slots: &[(usize, usize)],
    slice_len: usize,
    dst: &mut Stored,
    ranges: &mut [(i64, i64)],
) -> Result<()> {
    let path = src.path();
    let ts = h.transfer_syntax.as_str();
    let native = NATIVE_SYNTAXES.contains(&ts);
    // Little-endian native pixels are copied straight from the file's bytes (peak: file + volume);
    // big-endian ones go through dicom-rs, which swaps the words, and deflated data sets through
    // dicom-rs, which inflates them.
    let (mut obj, raw) = if matches!(ts, "1.2.840.10008.1.2" | "1.2.840.10008.1.2.1") {
        let (obj, bytes, range) = src.open_native_pixels()?;
        (obj, Some((bytes, range)))
    } else {
        (src.open(false)?, None)
    };
    // The file is read again: check that it still matches its header.
    let now = parse_pixel_format(&obj).map_err(|e| Error::invalid(path, e))?;
    if now != *fmt {
        return Err(Error::invalid(path, "the file changed while it was being read"));
    }
    let layout = BitLayout::new(path, fmt, native)?;
    let bytes = usize::from(fmt.bits_allocated / 8);
    let frame_bytes = slice_len * bytes;
    let needed = frame_bytes.checked_mul(fmt.frames).ok_or_else(|| Error::invalid(path, "frame size overflows"))?;
    let truncated = |have: usize| {
        Error::truncated(
            path,
            format!(
                "PixelData (7FE0,0010) has {have} bytes, {needed} needed for {} frame(s) of {}x{}x{} bits",
                fmt.frames, fmt.cols, fmt.rows, fmt.bits_allocated
            ),
        )
    };
    let decoded: Vec<u8>;
    let samples: FrameData = if let Some((bytes, range)) = &raw {
        FrameData::Bytes(Cow::Borrowed(&bytes[range.clone()]))
    } else {
        let pixel =
            obj.get(tags::PIXEL_DATA).ok_or_else(|| Error::invalid(path, "PixelData (7FE0,0010) is missing"))?;
        match pixel.value() {
            Value::Primitive(p) if native => match p {
                PrimitiveValue::U16(w) if bytes >= 2 => FrameData::Words(w),
                PrimitiveValue::U8(b) => FrameData::Bytes(Cow::Borrowed(b)),
                other => FrameData::Bytes(other.to_bytes()),
            },
            Value::PixelSequence(seq) if !native && ts == RLE_LOSSLESS => {
                decoded = decode_rle(path, seq.fragments(), fmt, bytes)?;
                FrameData::Bytes(Cow::Borrowed(&decoded))
            }
            Value::PixelSequence(seq) if !native && JPEG_LS_SYNTAXES.contains(&ts) => {
                decoded = decode_jpeg_ls(path, seq.fragments(), fmt, bytes)?;
                FrameData::Bytes(Cow::Borrowed(&decoded))
            }
            Value::PixelSequence(seq) if !native => {
                if JPEG_SYNTAXES.contains(&ts) {
                    check_jpeg(path, seq.fragments(), fmt)?;
                } else if J2K_SYNTAXES.contains(&ts) {
                    check_j2k(path, seq.fragments(), fmt)?;
                }
                // dicom-pixeldata also parses windows, LUTs and rescale (and fails on odd ones): we read
                // those ourselves, so remove them before decoding.
                for tag in [
                    tags::WINDOW_CENTER,
                    tags::WINDOW_WIDTH,
                    tags::VOILUT_FUNCTION,
                    tags::VOILUT_SEQUENCE,
                    tags::RESCALE_INTERCEPT,
                    tags::RESCALE_SLOPE,
                    tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
                    tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
                ] {
                    obj.remove_element(tag);
                }
                let name = transfer_syntax_name(ts).unwrap_or(ts);
                let pd = obj.decode_pixel_data().map_err(|e| {
                    Error::new(path, ErrorKind::Dicom(format!("cannot decode {name} pixel data: {}", error_chain(&e))))
                })?;
                decoded = pd.into_data();
                FrameData::Bytes(Cow::Borrowed(&decoded))
            }
            _ => {
                return Err(Error::invalid(
                    path,
                    format!(
                        "PixelData (7FE0,0010) is {} for transfer syntax {ts}",
                        if native { "encapsulated" } else { "not encapsulated" }
                    ),
                ));
            }
        }
    };
    let have = samples.len_bytes();
    if have < needed {
        return Err(truncated(have));
    }
    for &(frame, k) in slots {
        let frame_src = samples.frame(frame, frame_bytes, bytes);
        ranges[k] = store_frame(dst, k, slice_len, frame_src, bytes, layout);
    }
    Ok(())
}

/// All frames of one object.
enum FrameData<'a> {
    Bytes(Cow<'a, [u8]>),
    Words(&'a [u16]),
}

impl FrameData<'_> {
    fn len_bytes(&self) -> usize {
        match self {
            Self::Bytes(b) => b.len(),
            Self::Words(w) => w.len() * 2,
        }
    }
    /// Frame `f`; the caller has checked the length.
    fn frame(&self, f: usize, frame_bytes: usize, bytes: usize) -> FrameSamples<'_> {
        match self {
            Self::Bytes(b) => FrameSamples::Bytes(&b[f * frame_bytes..(f + 1) * frame_bytes]),
            Self::Words(w) => {
                let _ = bytes; // words only hold 16- and 32-bit samples (bytes >= 2)
                let words = frame_bytes / 2;
                FrameSamples::Words(&w[f * words..(f + 1) * words])
            }
        }
    }
}

/// Applies the rescale and picks the output sample type (docs/fixture-manifest.md).
fn finalize(
    label: &Path,
    stored: Stored,
    slice_len: usize,
    rescales: &[(f64, f64)],
    ranges: &[(i64, i64)],
    dims: [usize; 3],
    opts: &LoadOptions,
) -> Result<(VoxelData, Rescale, Vec<String>)> {
    let mut warnings = Vec::new();
    let identity = rescales.iter().all(|&(s, b)| is_identity(s, b));
    let (slope0, intercept0) = rescales.first().copied().unwrap_or((1.0, 0.0));
    if rescales.iter().any(|&r| r != (slope0, intercept0)) {
        warnings.push(format!(
            "RescaleSlope/RescaleIntercept differ between slices; each slice was rescaled with its own \
             (the first is slope {slope0}, intercept {intercept0})"
        ));
    }
    let check_f32 = || volume::check_allocation(label, dims, 4, opts.max_voxel_bytes);
    if identity {
        let data = match stored {
            Stored::U8(v) => VoxelData::U8(v),
            Stored::U16(v) => VoxelData::U16(v),
            Stored::I16(v) => VoxelData::I16(v),
            Stored::I8(v) => {
                volume::check_allocation(label, dims, 2, opts.max_voxel_bytes)?;
                VoxelData::I16(try_convert(label, v, |(_, x)| i16::from(x))?)
            }
            Stored::U32(v) => {
                check_f32()?;
                VoxelData::F32(try_convert(label, v, |(_, x)| x as f32)?)
            }
            Stored::I32(v) => {
                check_f32()?;
                VoxelData::F32(try_convert(label, v, |(_, x)| x as f32)?)
            }
        };
        return Ok((data, Rescale::IDENTITY, warnings));
    }
    let integer =
        rescales.iter().all(|&(s, b)| s.fract() == 0.0 && b.fract() == 0.0 && s.abs() < 1e9 && b.abs() < 1e12);
    let (lo, hi) =
        rescales.iter().zip(ranges).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (&(s, b), &(a, z))| {
            let (p, q) = (s * a as f64 + b, s * z as f64 + b);
            (lo.min(p).min(q), hi.max(p).max(q))
        });
    let rescale = Rescale { slope: slope0, intercept: intercept0, applied: true };
    let map = |x: i64, i: usize| {
        let (s, b) = rescales[i / slice_len];
        s * x as f64 + b
    };
    macro_rules! convert {
        ($v:expr, $f:expr) => {
            try_convert(label, $v, |(i, x)| $f(map(i64::from(x), i)))?
        };
    }
    macro_rules! all_types {
        ($f:expr, $variant:ident) => {
            match stored {
                Stored::U8(v) => VoxelData::$variant(convert!(v, $f)),
                Stored::I8(v) => VoxelData::$variant(convert!(v, $f)),
                Stored::U16(v) => VoxelData::$variant(convert!(v, $f)),
                Stored::I16(v) => VoxelData::$variant(convert!(v, $f)),
                Stored::U32(v) => VoxelData::$variant(convert!(v, $f)),
                Stored::I32(v) => VoxelData::$variant(convert!(v, $f)),
            }
        };
    }
    let data = if integer && lo >= f64::from(i16::MIN) && hi <= f64::from(i16::MAX) {
        volume::check_allocation(label, dims, 2, opts.max_voxel_bytes)?;
        all_types!(|y: f64| y as i16, I16)
    } else if integer && lo >= 0.0 && hi <= f64::from(u16::MAX) {
        volume::check_allocation(label, dims, 2, opts.max_voxel_bytes)?;
        all_types!(|y: f64| y as u16, U16)
    } else {
        check_f32()?;
        all_types!(|y: f64| y as f32, F32)
    };
    Ok((data, rescale, warnings))
}

// ---------------------------------------------------------------------------------------------
// Codecs: RLE and JPEG-LS decoded here; JPEG / JPEG 2000 frame headers checked before dicom-pixeldata runs
// ---------------------------------------------------------------------------------------------

/// Decodes RLE Lossless (PS3.5 Annex G): one fragment per frame, 64-byte header, one PackBits
/// segment per byte of the sample, most significant first. Output is little-endian.
fn decode_rle(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat, bytes: usize) -> Result<Vec<u8>> {
    let bad = |m: String| Error::new(path, ErrorKind::Dicom(format!("RLE Lossless: {m}")));
    if fragments.len() < fmt.frames {
        return Err(bad(format!("{} fragments for {} frames (one per frame expected)", fragments.len(), fmt.frames)));
    }
    let pixels = fmt.rows * fmt.cols;
    let mut out = try_zeros(path, pixels * bytes * fmt.frames, "the decoded pixel data")?;
    for (f, frag) in fragments.iter().take(fmt.frames).enumerate() {
        let header = frag.get(..64).ok_or_else(|| bad(format!("frame {}: fragment shorter than the header", f + 1)))?;
        let word =
            |i: usize| u32::from_le_bytes([header[4 * i], header[4 * i + 1], header[4 * i + 2], header[4 * i + 3]]);
        let segments = word(0) as usize;
        if segments != bytes {
            return Err(bad(format!("frame {}: {segments} segments, {bytes} expected", f + 1)));
        }
        let out_frame = &mut out[f * pixels * bytes..(f + 1) * pixels * bytes];
        for s in 0..segments {
            let start = word(1 + s) as usize;
            let end = if s + 1 < segments { word(2 + s) as usize } else { frag.len() };
            let seg = frag.get(start..end).ok_or_else(|| {
                bad(format!("frame {}: segment {} offsets {start}..{end} out of range", f + 1, s + 1))
            })?;
            // Segment 0 holds the most significant byte.
            let byte_pos = bytes - 1 - s;
            let written = packbits(seg, |i, v| out_frame[i * bytes + byte_pos] = v, pixels);
            if written < pixels {
                return Err(bad(format!("frame {}: segment {} decodes to {written} of {pixels} bytes", f + 1, s + 1)));
            }
        }
    }
    Ok(out)
}

/// Decodes JPEG-LS (PS3.5 Section 8.2.3, ISO/IEC 14495-1) with [`jpegls`]: one codestream per
/// frame, in one fragment or several. Each frame header is checked against Rows, Columns,
/// SamplesPerPixel and BitsAllocated before its samples are decoded. Output is little-endian.
fn decode_jpeg_ls(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat, bytes: usize) -> Result<Vec<u8>> {
    let bad = |m: String| Error::new(path, ErrorKind::Dicom(format!("JPEG-LS: {m}")));
    if bytes > 2 {
        return Err(Error::unsupported(path, format!("JPEG-LS with BitsAllocated (0028,0100) {}", fmt.bits_allocated)));
    }
    let frames = jpeg_ls_frames(fragments, fmt.frames).map_err(bad)?;
    let pixels = fmt.rows * fmt.cols;
    let mut out = try_zeros(path, pixels * bytes * fmt.frames, "the decoded pixel data")?;
    for (f, (data, out_frame)) in frames.iter().zip(out.chunks_exact_mut(pixels * bytes)).enumerate() {
        let codec = |e: jpegls::JpegLsError| {
            let m = format!("JPEG-LS frame {}: {e}", f + 1);
            match e {
                jpegls::JpegLsError::Truncated(_) => Error::truncated(path, m),
                jpegls::JpegLsError::Unsupported(_) => Error::unsupported(path, m),
                jpegls::JpegLsError::OutOfMemory { bytes } => Error::new(
                    path,
                    ErrorKind::OutOfMemory { what: format!("the samples of JPEG-LS frame {}", f + 1), bytes },
                ),
                _ => Error::new(path, ErrorKind::Dicom(m)),
            }
        };
        let h = jpegls::read_header(data).map_err(codec)?;
        if h.width != fmt.cols || h.height != fmt.rows || u16::from(h.components) != fmt.samples_per_pixel {
            return Err(Error::invalid(
                path,
                format!(
                    "JPEG-LS frame {} is {}x{} with {} component(s), but Columns x Rows is {}x{} with {} sample(s)",
                    f + 1,
                    h.width,
                    h.height,
                    h.components,
                    fmt.cols,
                    fmt.rows,
                    fmt.samples_per_pixel
                ),
            ));
        }
        if usize::from(h.precision) > 8 * bytes {
            return Err(Error::unsupported(
                path,
                format!("JPEG-LS precision {} bits with BitsAllocated (0028,0100) {}", h.precision, fmt.bits_allocated),
            ));
        }
        let spec = jpegls::FrameSpec { width: fmt.cols, height: fmt.rows, max_precision: 8 * bytes as u8 };
        let samples = jpegls::decode(data, spec).map_err(codec)?;
        if bytes == 1 {
            for (o, &v) in out_frame.iter_mut().zip(&samples) {
                *o = v as u8;
            }
        } else {
            for (o, &v) in out_frame.chunks_exact_mut(2).zip(&samples) {
                o.copy_from_slice(&v.to_le_bytes());
            }
        }
    }
    Ok(out)
}

/// Splits the fragments into one codestream per frame: one fragment each, all of them for a
/// single frame, or else a new frame at each fragment that starts with SOI.
fn jpeg_ls_frames(fragments: &[Vec<u8>], frames: usize) -> std::result::Result<Vec<Cow<'_, [u8]>>, String> {
    if fragments.len() == frames {
        return Ok(fragments.iter().map(|f| Cow::Borrowed(f.as_slice())).collect());
    }
    if frames == 1 {
        return Ok(vec![Cow::Owned(fragments.concat())]);
    }
    let mut out: Vec<Cow<[u8]>> = Vec::new();
    for frag in fragments {
        match out.last_mut() {
            Some(last) if !frag.starts_with(&[0xFF, 0xD8]) => last.to_mut().extend_from_slice(frag),
            _ => out.push(Cow::Borrowed(frag)),
        }
    }
    if out.len() != frames {
        return Err(format!("{} fragments hold {} codestreams for {frames} frames", fragments.len(), out.len()));
    }
    Ok(out)
}

/// PackBits: writes at most `limit` bytes through `put`; returns how many were written.
fn packbits(seg: &[u8], mut put: impl FnMut(usize, u8), limit: usize) -> usize {
    let mut i = 0;
    let mut o = 0;
    while i < seg.len() && o < limit {
        let n = seg[i] as i8;
        i += 1;
        if n >= 0 {
            let count = n as usize + 1;
            for _ in 0..count {
                let Some(&v) = seg.get(i) else { return o };
                if o < limit {
                    put(o, v);
                    o += 1;
                }
                i += 1;
            }
        } else if n != -128 {
            let count = 1 - isize::from(n);
            let Some(&v) = seg.get(i) else { return o };
            i += 1;
            for _ in 0..count {
                if o < limit {
                    put(o, v);
                    o += 1;
                }
            }
        }
    }
    o
}

/// Checks every JPEG frame header (SOF) against Rows, Columns, SamplesPerPixel and BitsAllocated.
///
/// Walks the marker segments (skipping each payload by its length, and entropy-coded data up to
/// the next marker), so bytes inside tables are never taken for markers.
fn check_jpeg(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat) -> Result<()> {
    let data: Vec<u8> = fragments.iter().flatten().copied().collect();
    let mut found = 0usize;
    let mut i = 0usize;
    while i + 1 < data.len() {
        let m = data[i + 1];
        if data[i] != 0xFF || m == 0x00 || m == 0xFF || (0xD0..=0xD7).contains(&m) {
            // entropy-coded data, stuffing, restart markers or fill bytes
            i += 1;
            continue;
        }
        if m == 0xD8 || m == 0xD9 || m == 0x01 {
            i += 2; // SOI, EOI, TEM: no payload
            continue;
        }
        let Some(&[l1, l0]) = data.get(i + 2..i + 4) else { break };
        let len = usize::from(u16::from_be_bytes([l1, l0]));
        // SOF markers: C0..CF except DHT (C4), JPG (C8) and DAC (CC)
        if (0xC0..=0xCF).contains(&m) && m != 0xC4 && m != 0xC8 && m != 0xCC {
            let Some(&[precision, h1, h0, w1, w0, comps]) = data.get(i + 4..i + 10) else { break };
            let h = usize::from(u16::from_be_bytes([h1, h0]));
            let w = usize::from(u16::from_be_bytes([w1, w0]));
            if (h != fmt.rows && h != 0) || w != fmt.cols || u16::from(comps) != fmt.samples_per_pixel {
                return Err(Error::invalid(
                    path,
                    format!(
                        "JPEG frame is {w}x{h} with {comps} component(s), but Columns x Rows is {}x{} with {} sample(s)",
                        fmt.cols, fmt.rows, fmt.samples_per_pixel
                    ),
                ));
            }
            let bits_needed = if precision <= 8 { 8 } else { 16 };
            if bits_needed != fmt.bits_allocated {
                return Err(Error::unsupported(
                    path,
                    format!("JPEG precision {precision} bits with BitsAllocated (0028,0100) {}", fmt.bits_allocated),
                ));
            }
            found += 1;
        }
        i += 2 + len.max(2);
    }
    if found == 0 {
        return Err(Error::new(path, ErrorKind::Dicom("JPEG pixel data has no frame header (SOF)".into())));
    }
    Ok(())
}

/// Checks each JPEG 2000 codestream's SIZ segment against Rows, Columns and SamplesPerPixel.
fn check_j2k(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat) -> Result<()> {
    let mut found = 0usize;
    for frag in fragments {
        let start = if frag.starts_with(&[0xFF, 0x4F, 0xFF, 0x51]) {
            Some(0)
        } else if frag.starts_with(&[0, 0, 0, 0x0C, 0x6A, 0x50, 0x20, 0x20]) {
            frag.windows(4).position(|w| w == [0xFF, 0x4F, 0xFF, 0x51])
        } else {
            None // a continuation fragment
        };
        let Some(s) = start else { continue };
        let siz = frag.get(s + 4..s + 42).ok_or_else(|| Error::truncated(path, "JPEG 2000 SIZ segment"))?;
        let u32_at = |o: usize| u32::from_be_bytes([siz[o], siz[o + 1], siz[o + 2], siz[o + 3]]);
        let (xsiz, ysiz, xo, yo) = (u32_at(4), u32_at(8), u32_at(12), u32_at(16));
        let comps = u16::from_be_bytes([siz[36], siz[37]]);
        let w = xsiz.saturating_sub(xo) as usize;
        let h = ysiz.saturating_sub(yo) as usize;
        if w != fmt.cols || h != fmt.rows || comps != fmt.samples_per_pixel {
            return Err(Error::invalid(
                path,
                format!(
                    "JPEG 2000 codestream is {w}x{h} with {comps} component(s), but Columns x Rows is {}x{} with {} sample(s)",
                    fmt.cols, fmt.rows, fmt.samples_per_pixel
                ),
            ));
        }
        // Subsampled components would also be written out of bounds.
        let comp =
            frag.get(s + 42..s + 42 + 3 * usize::from(comps)).ok_or_else(|| Error::truncated(path, "JPEG 2000 SIZ"))?;
        if comp.chunks_exact(3).any(|c| c[1] != 1 || c[2] != 1) {
            return Err(Error::unsupported(path, "subsampled JPEG 2000 components"));
        }
        found += 1;
    }
    if found < fmt.frames {
        return Err(Error::new(
            path,
            ErrorKind::Dicom(format!("{found} JPEG 2000 codestreams for {} frames", fmt.frames)),
        ));
    }
    Ok(())
}
