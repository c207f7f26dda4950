//! # warpbench-io
//!
//! Readers and writers for the volumes and landmarks that warpbench registers, all placed in one
//! patient space: **LPS, in mm** (see `docs/spaces.md`).
//!
//! - [`open`] / [`LoadOptions::open`]: read a NIfTI-1/2 (`.nii`, `.nii.gz`), NRRD (`.nrrd`, `.nhdr`)
//!   file, a DICOM series folder or a single DICOM file into a [`Volume`].
//! - [`nifti`], [`nrrd`], [`dicom`]: the format modules, with their writers.
//! - [`landmarks`]: landmark pairs, BigWarp CSV and Slicer `.mrk.json` / `.fcsv`.
//! - [`geometry`]: points, vectors and transforms that carry their space in the type.
//! - [`itk_tfm`]: ITK transform files (`.tfm`) holding one transform: affine, thin-plate spline or cubic B-spline.
//!
//! Every error names the file and the problem ([`Error`]); bad input never panics, sizes are
//! checked before allocating, and writers replace their output atomically ([`write_atomic`]).

pub mod atomic;
pub mod dicom;
pub mod dicom_source;
pub mod dicom_write;
pub mod displacement;
pub mod error;
pub mod geometry;
pub mod itk_tfm;
pub mod landmarks;
pub mod nifti;
pub mod nrrd;
pub mod options;
pub mod sample;
pub mod series;
pub mod volume;

use std::io::Read;
use std::path::Path;

pub use atomic::write_atomic;
/// The DICOM reader's JPEG-LS decoder, which benches and tests also call on its own.
pub use dicom::jpegls;
pub use error::{Error, ErrorKind, Result};
pub use options::{LoadOptions, Progress};
pub use series::SeriesSummary;
pub use volume::{GeometrySource, Metadata, Modality, Rescale, SampleType, Volume, VoxelData};

/// A volume file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Nifti,
    Nrrd,
    /// A DICOM series folder, or one DICOM file (possibly enhanced multi-frame).
    Dicom,
}

impl Format {
    /// Detects the format of `path`: folders are DICOM series; files by extension, then by magic bytes.
    #[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
    pub fn detect(path: &Path) -> Result<Self> {
        if check_file_or_folder(path)?.is_dir() {
            return Ok(Self::Dicom);
        }
        // Lowercased above, so the comparisons below are case-insensitive.
        let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            return Ok(Self::Nifti);
        }
        if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            return Ok(Self::Nrrd);
        }
        if name.ends_with(".dcm") {
            return Ok(Self::Dicom);
        }
        let mut head = [0u8; 132];
        let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let n = read_up_to(&mut f, &mut head).map_err(|e| Error::io(path, e))?;
        let head = &head[..n];
        if head.starts_with(b"NRRD") {
            Ok(Self::Nrrd)
        } else if head.len() == 132 && &head[128..132] == b"DICM" {
            Ok(Self::Dicom)
        } else if head.starts_with(&[0x1f, 0x8b]) || nifti::looks_like_nifti(head) {
            Ok(Self::Nifti)
        } else {
            Err(Error::unsupported(path, "unknown file format (expected NIfTI, NRRD or DICOM)"))
        }
    }
}

/// Refuses `path` unless it is a regular file (following symbolic links), before anything opens it: a named
/// pipe blocks in `open`, a device such as `/dev/zero` never ends. Returns the file's metadata (its length bounds
/// every read and skip that follows).
pub(crate) fn check_regular_file(path: &Path) -> Result<std::fs::Metadata> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() {
        return Ok(meta);
    }
    let what = if meta.is_dir() { "a folder" } else { special_kind(&meta) };
    Err(Error::new(path, ErrorKind::NotARegularFile { what }))
}

/// [`check_regular_file`], but a folder (a DICOM series) is accepted too.
pub(crate) fn check_file_or_folder(path: &Path) -> Result<std::fs::Metadata> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() || meta.is_dir() {
        return Ok(meta);
    }
    Err(Error::new(path, ErrorKind::NotARegularFile { what: special_kind(&meta) }))
}

/// What a file that is neither regular nor a folder is, in words.
fn special_kind(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a named pipe (FIFO)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    let _ = meta;
    "a special file"
}

/// Reads as many bytes as are there, up to `buf.len()` (retrying interrupted reads); the shared
/// helper of every reader that must tell a short file from a full one.
pub(crate) fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Reads the volume at `path` with default options. Same as `LoadOptions::new().open(path)`.
pub fn open(path: impl AsRef<Path>) -> Result<Volume> {
    LoadOptions::new().open(path)
}

impl LoadOptions<'_> {
    /// Reads the volume at `path` (a file or a DICOM series folder).
    pub fn open(&mut self, path: impl AsRef<Path>) -> Result<Volume> {
        let path = path.as_ref();
        let mut volume = match Format::detect(path)? {
            Format::Nifti => nifti::read(path, self),
            Format::Nrrd => nrrd::read(path, self),
            Format::Dicom if path.is_dir() => dicom::read_folder(path, self),
            Format::Dicom => dicom::read_files(&[path.to_path_buf()], self),
        }?;
        // Every format's volume gets the same geometry warnings (a reader that sets its own metadata keeps them).
        volume.note_geometry_warnings();
        Ok(volume)
    }
}
