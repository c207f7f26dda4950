//! NIfTI-1 and NIfTI-2 volumes (`.nii`, `.nii.gz`): [`read()`], [`read_bytes`], [`write()`], [`write_with`]; and
//! displacement fields: [`write_displacement_field`], [`read_displacement_field`].
//!
//! # The format
//!
//! A single-file NIfTI volume is a fixed binary header, an optional extension block, then the voxel
//! samples at byte `vox_offset`, i fastest (Fortran order), optionally gzip-compressed as a whole.
//!
//! - **NIfTI-1** (`nifti1.h`, <https://nifti.nimh.nih.gov/pub/dist/src/niftilib/nifti1.h>): a 348-byte
//!   header, magic `n+1\0` at byte 344; 16-bit `dim`, 32-bit float `pixdim`, `srow_*`, `vox_offset`.
//! - **NIfTI-2** (`nifti2.h`, <https://nifti.nimh.nih.gov/pub/dist/doc/nifti2.h>): a 540-byte header,
//!   magic `n+2\0\r\n\x1a\n` at byte 4; 64-bit `dim` and float64 geometry.
//!
//! The byte order is that in which `sizeof_hdr` reads 348 (or 540); both orders are read. The magics
//! `ni1\0` / `ni2\0` mark separate `.hdr`/`.img` pair files, which we reject with a clear error.
//!
//! # Geometry
//!
//! With (i, j, k) the voxel index (0 = centre of the first voxel), the header gives `ras_from_index`
//! by the first of the spec's three methods that applies:
//!
//! - **sform** (method 3, `sform_code > 0`): `[x y z]ᵀ = [srow_x; srow_y; srow_z] · [i j k 1]ᵀ`.
//! - **qform** (method 2, else `qform_code > 0`): `[x y z]ᵀ = R · [Δi·i, Δj·j, qfac·Δk·k]ᵀ + qoffset`,
//!   with Δ = `|pixdim[1..3]|`, qfac = −1 if `pixdim[0] < 0` else 1, and R the rotation of the unit
//!   quaternion (a, b, c, d), a = √(1 − b² − c² − d²):
//!
//!   ```text
//!   R = [ a²+b²−c²−d²   2(bc−ad)      2(bd+ac)    ]
//!       [ 2(bc+ad)      a²+c²−b²−d²   2(cd−ab)    ]
//!       [ 2(bd−ac)      2(cd+ab)      a²+d²−c²−b² ]
//!   ```
//!
//!   When b² + c² + d² ≥ 1 − 10⁻⁷, (b, c, d) is normalised and a = 0 (a 180° turn), as
//!   `nifti_quatern_to_mat44` in `nifti1_io.c` does. nibabel rejects a negative pixdim here and
//!   `nifti1_io.c` replaces it by 1; we take its magnitude (the sign of the k axis is `qfac`'s job).
//! - **pixdim** (method 1, both codes 0): `diag(|pixdim[1]|, |pixdim[2]|, |pixdim[3]|)`, origin 0.
//!   This is the spec's method, not nibabel's centred fallback.
//!
//! We keep patient space in LPS, so `lps_from_index = lps_from_ras · ras_from_index` with
//! `lps_from_ras = diag(−1, −1, 1)`, and record which method was used in [`GeometrySource`].
//! A non-finite or zero spacing used by the geometry, or a non-finite or singular matrix, is an error.
//!
//! When both codes are set, the sform is used (as nibabel does) but ITK and SimpleITK use the qform, so a file
//! whose two transforms differ lands in two places. We compare them at the centres of the grid's 8 corner
//! voxels: farther apart than 0.1 mm anywhere, or of opposite handedness (det < 0 for one only), and
//! `metadata.warnings` names both codes, the largest distance and the handedness, and says the sform is used.
//! Spatial units other than mm (`xyzt_units`) are noted in `metadata.warnings` but not applied,
//! as nibabel and ITK do.
//!
//! # Samples
//!
//! Stored types u8, i8, i16, u16, i32, u32, i64, u64, f32 and f64 are read; complex, RGB and the
//! rest are refused. `value = scl_slope · stored + scl_inter` in float64 (slope 0 or not finite:
//! no scaling). The output sample type follows `docs/fixture-manifest.md`:
//!
//! - identity rescale: u8, i16, u16, f32 stay; i8 becomes i16; u32, i32, i64, u64 and f64 become f32
//!   (rounded to nearest);
//! - otherwise i16 if slope and intercept are integers and every value is an integer within i16,
//!   else u16 likewise, else f32.
//!
//! A 4-D file gives one frame, chosen by [`LoadOptions::frame`]; dims beyond the 4th must be 1. Without a
//! frame, a file of several frames is [`ErrorKind::FrameRequired`] with the frame count, which each front end
//! words for its own way of choosing (the CLI's `--frame`).
//!
//! # Robustness and memory
//!
//! Only a regular file is opened (a named pipe would block, a device never end). Every header field is
//! validated before anything is allocated from it; sizes are checked with [`volume::check_allocation`]
//! (the [`LoadOptions::max_voxel_bytes`] cap), and for an uncompressed file against the file length. Sample
//! buffers are allocated fallibly ([`volume::try_with_capacity`]): memory the system refuses is an
//! [`ErrorKind::OutOfMemory`] naming the file and the size, never an abort. A gzip
//! stream is decompressed straight into the final buffer, reading exactly the bytes needed. With no
//! rescale the samples are decoded chunk by chunk into the output (peak ≈ 1× the output); with a
//! rescale the raw frame is read first, then converted (peak ≤ 2×).
//!
//! We parse by hand, with only `flate2`, because the `nifti` crate (0.18) has no NIfTI-2 support
//! and panics on some bad headers (e.g. a negative pixdim).
//!
//! # Writing
//!
//! [`write()`] writes NIfTI-1 (gzip when the name ends in `.gz`) with the volume's sample type,
//! `scl_slope` 1 and `scl_inter` 0 (the samples are the volume's values), `vox_offset` 352, empty
//! extension flag, `xyzt_units` = mm, and both transforms with code 1 (scanner anatomical):
//!
//! - the sform holds `ras_from_index` exactly up to float32 rounding: the round-trip error is below
//!   10⁻⁴ mm for coordinates within ±1000 mm. [`write_with`] with `nifti2: true` writes NIfTI-2,
//!   whose float64 sform round-trips exactly;
//! - the qform holds the nearest rotation (polar decomposition, as `nifti_mat44_to_quatern`), the
//!   column lengths as `pixdim[1..3]` and `qfac` = −1 for an improper (left-handed) matrix. A sheared
//!   direction matrix has no exact qform: readers that prefer the qform see an approximation,
//!   readers that follow the spec (sform first) see the exact matrix. Near a 180° turn the
//!   quaternion's a = √(1 − b² − c² − d²) is recomputed from float32 b, c, d and loses about half
//!   its digits (10⁻⁴ rad): a limit of NIfTI-1's qform, and one more reason the sform is primary.
//!
//! # Displacement fields
//!
//! A displacement field D over a grid is what ITK's `DisplacementFieldTransform` takes: the output point x maps
//! to the input point x + D(x) (for a registration, x in the fixed volume and x + D(x) in the moving one, the
//! pull-back). ITK, ANTs and 3D Slicer store it as a NIfTI vector image: `dim = [5, X, Y, Z, 1, 3, 1, 1]` (the
//! components in the 5th dimension, the slowest, so all x components come first, then all y, then all z),
//! `intent_code` 1006 (`NIFTI_INTENT_DISPVECT`), and the grid's sform/qform as for any volume.
//!
//! **The vectors are RAS in the file.** ITK works in LPS and flips the first two components of a `DISPVECT`
//! image on read and on write. In `Modules/IO/NIFTI/src/itkNiftiImageIO.cxx` (ITK PR #3884 by A. Lasso, "Fix
//! read/write of displacement field in NIFTI file format", merged January 2023; read here in the Slicer backport,
//! `ltracegeo/ITK` at `eeb7f43c`), `ReadImageInformation` has
//!
//! ```text
//! case NIFTI_INTENT_DISPVECT:
//!   this->SetPixelType(IOPixelEnum::VECTOR);
//!   this->m_ConvertRAS = m_ConvertRASDisplacementVectors;
//! ```
//!
//! and `Read` then calls `ConvertRASToFromLPS_CXYZT`, which does `buffer[0] *= -1; buffer[1] *= -1;` for every
//! 3-vector ("Internal function to convert vectors between RAS and LPS coordinate systems"); `Write` applies
//! `ConvertRASToFromLPS_XYZTC` ("Flip the sign of the first two components (L<->R, P<->A)"). Intent 1007
//! (`NIFTI_INTENT_VECTOR`) is not flipped by default, which is why we write 1006 with RAS vectors.
//! [`write_displacement_field`] therefore writes (−dx, −dy, dz) of each LPS displacement, float32, and
//! [`read_displacement_field`] undoes it. SimpleITK 2.5.7 reads our files back to the same LPS vectors
//! (`data-scripts/check_field_sitk.py`; `tests/data/PROVENANCE.md`, "ITK displacement-field reference").

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom, Write};
use std::path::Path;

use flate2::Compression;
use flate2::read::MultiGzDecoder;
use flate2::write::GzEncoder;
use nalgebra::{Matrix3, Matrix4};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Ras, Transform, lps_from_ras, ras_from_lps};
use crate::options::LoadOptions;
use crate::volume::{self, GeometrySource, Rescale, SampleType, Volume, VoxelData};

const NIFTI1_HEADER_BYTES: usize = 348;
const NIFTI2_HEADER_BYTES: usize = 540;
/// Header plus the 4-byte extension flag: where our writer puts the samples.
const NIFTI1_VOX_OFFSET: usize = NIFTI1_HEADER_BYTES + 4;
const NIFTI2_VOX_OFFSET: usize = NIFTI2_HEADER_BYTES + 4;
const NIFTI1_MAGIC: &[u8; 4] = b"n+1\0";
const NIFTI1_PAIR_MAGIC: &[u8; 4] = b"ni1\0";
const NIFTI2_MAGIC: &[u8; 8] = b"n+2\0\r\n\x1a\n";
const NIFTI2_PAIR_MAGIC: &[u8; 8] = b"ni2\0\r\n\x1a\n";
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];
/// Bytes read between progress reports (a multiple of every sample size).
const CHUNK_BYTES: usize = 4 << 20;

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

/// What bounds the bytes a source can deliver, checked before the voxel buffer is allocated.
#[derive(Clone, Copy, Debug)]
enum Extent {
    /// An uncompressed file or buffer of this many bytes: the data must end inside it.
    Exact(u64),
    /// A gzip stream of this many compressed bytes: it cannot inflate to more than
    /// [`MAX_DEFLATE_RATIO`] times that, so a tiny `.nii.gz` claiming gigabytes fails early.
    Gzip(u64),
}

/// Deflate's largest expansion: 258-byte matches coded in about 2 bits give about 1032:1.
const MAX_DEFLATE_RATIO: u64 = 1032;

/// Reads a NIfTI-1/2 file (`.nii` or gzip-compressed `.nii.gz`, detected by content).
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    crate::check_regular_file(path)?;
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut magic = [0u8; 2];
    let n = crate::read_up_to(&mut file, &mut magic).map_err(|e| Error::io(path, e))?;
    file.seek(SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
    if n == 2 && magic == GZIP_MAGIC {
        read_source(path, &mut MultiGzDecoder::new(BufReader::new(file)), Extent::Gzip(file_len), opts)
    } else {
        read_source(path, &mut BufReader::new(file), Extent::Exact(file_len), opts)
    }
}

/// Reads a NIfTI-1/2 volume from memory (gzip detected by the magic bytes 1f 8b); `name` is used in errors.
pub fn read_bytes(name: &Path, bytes: &[u8], opts: &mut LoadOptions) -> Result<Volume> {
    if bytes.starts_with(&GZIP_MAGIC) {
        read_source(name, &mut MultiGzDecoder::new(bytes), Extent::Gzip(bytes.len() as u64), opts)
    } else {
        let mut src = bytes;
        read_source(name, &mut src, Extent::Exact(bytes.len() as u64), opts)
    }
}

// ---------------------------------------------------------------------------------------------
// Byte sources
// ---------------------------------------------------------------------------------------------

/// A byte stream that may be able to skip forward without reading.
trait Source: Read {
    /// Skips `n` bytes if the source can seek; `Ok(false)` means the caller must read through them.
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        let _ = n;
        Ok(false)
    }
}

impl Source for BufReader<File> {
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        self.seek_relative(i64::try_from(n).map_err(io::Error::other)?)?;
        Ok(true)
    }
}

impl Source for &[u8] {
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        let n = usize::try_from(n).unwrap_or(usize::MAX).min(self.len());
        *self = &self[n..];
        Ok(true)
    }
}

impl<R: Read> Source for MultiGzDecoder<R> {}

/// Fills `buf` from `r`; a short stream is a truncated file, a corrupt gzip stream invalid data.
fn fill(path: &Path, r: &mut impl Read, buf: &mut [u8], what: &str) -> Result<()> {
    r.read_exact(buf).map_err(|e| match e.kind() {
        io::ErrorKind::UnexpectedEof => Error::truncated(path, format!("the file ends inside {what}")),
        io::ErrorKind::InvalidData | io::ErrorKind::InvalidInput => {
            Error::invalid(path, format!("corrupt compressed data in {what}: {e}"))
        }
        _ => Error::io(path, e),
    })
}

/// Reports `"reading"` progress every [`CHUNK_BYTES`] and at the end.
struct Reporter<'o, 'a> {
    path: &'o Path,
    opts: &'o mut LoadOptions<'a>,
    done: u64,
    total: u64,
}

impl Reporter<'_, '_> {
    fn advance(&mut self, n: usize) -> Result<()> {
        self.done += n as u64;
        self.opts.report(self.path, "reading", self.done, self.total)
    }
}

// ---------------------------------------------------------------------------------------------
// Header
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Version {
    Nifti1,
    Nifti2,
}

impl Version {
    const fn header_bytes(self) -> usize {
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
struct Header {
    version: Version,
    big_endian: bool,
    dim: [i64; 8],
    datatype: i16,
    bitpix: i16,
    intent_code: i32,
    pixdim: [f64; 8],
    vox_offset: f64,
    scl_slope: f64,
    scl_inter: f64,
    xyzt_units: i32,
    qform_code: i32,
    sform_code: i32,
    quatern_bcd: [f64; 3],
    qoffset: [f64; 3],
    srow: [[f64; 4]; 3],
    descrip: String,
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

fn read_header(path: &Path, r: &mut impl Read) -> Result<Header> {
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

fn pair_error(path: &Path) -> Error {
    Error::unsupported(
        path,
        "separate .hdr/.img pair files are not supported; convert to a single .nii or .nii.gz file",
    )
}

/// NIfTI-1 layout (nifti1.h, `struct nifti_1_header`).
fn parse_nifti1(path: &Path, f: &Fields) -> Result<Header> {
    let magic = &f.b[344..348];
    if magic == NIFTI1_PAIR_MAGIC {
        return Err(pair_error(path));
    }
    if magic != NIFTI1_MAGIC {
        return Err(bad_magic(path, Version::Nifti1, magic));
    }
    Ok(Header {
        version: Version::Nifti1,
        big_endian: f.big_endian,
        dim: std::array::from_fn(|i| i64::from(f.i16(40 + 2 * i))),
        datatype: f.i16(70),
        bitpix: f.i16(72),
        intent_code: i32::from(f.i16(68)),
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
    })
}

/// NIfTI-2 layout (nifti2.h, `struct nifti_2_header`).
fn parse_nifti2(path: &Path, f: &Fields) -> Result<Header> {
    let magic = &f.b[4..12];
    if magic == NIFTI2_PAIR_MAGIC {
        return Err(pair_error(path));
    }
    if magic != NIFTI2_MAGIC {
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
    })
}

// ---------------------------------------------------------------------------------------------
// Validation: what to read, where
// ---------------------------------------------------------------------------------------------

/// A stored NIfTI sample type we can read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DataType {
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
    fn from_code(path: &Path, code: i16) -> Result<Self> {
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

    const fn bytes(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }
}

/// Where the chosen frame lies and what it holds.
#[derive(Clone, Copy, Debug)]
struct Layout {
    dims: [usize; 3],
    datatype: DataType,
    /// Byte offset of the chosen frame from the start of the (decompressed) file.
    frame_offset: u64,
    frame_bytes: usize,
}

fn layout(path: &Path, h: &Header, opts: &LoadOptions, extent: Extent) -> Result<Layout> {
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
    if let Some(i) = (5..=ndim).find(|&i| dims[i] != 1) {
        return Err(Error::unsupported(
            path,
            format!("{ndim}-D data (dim[{i}] = {}); only 3-D and 4-D volumes are read", dims[i]),
        ));
    }
    let datatype = DataType::from_code(path, h.datatype)?;
    if i64::from(h.bitpix) != 8 * datatype.bytes() as i64 {
        return Err(Error::invalid(
            path,
            format!("bitpix {} does not match datatype {} ({} bits)", h.bitpix, h.datatype, 8 * datatype.bytes()),
        ));
    }
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
    // Exact size arithmetic in u128 (cannot overflow: three factors below 2^64 times 8 can, so check).
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
    let header_bytes = h.version.header_bytes() as f64;
    if !h.vox_offset.is_finite() || h.vox_offset < header_bytes || h.vox_offset > 2f64.powi(62) {
        return Err(Error::invalid(
            path,
            format!("vox_offset {} is not a byte offset past the {header_bytes}-byte header", h.vox_offset),
        ));
    }
    // nifti1_io and nibabel truncate a fractional offset.
    let vox_offset = h.vox_offset as u64;
    let frame_offset = (frame as u128 * frame_bytes_wide + u128::from(vox_offset)).min(u128::from(u64::MAX)) as u64;
    let end = u128::from(frame_offset) + frame_bytes_wide;
    if let Extent::Gzip(len) = extent
        && end > u128::from(len) * u128::from(MAX_DEFLATE_RATIO)
    {
        return Err(Error::truncated(
            path,
            format!(
                "the voxel data needs {end} bytes (dims {dims3:?}, frame {frame}) but a {len}-byte gzip stream \
                 inflates to at most {MAX_DEFLATE_RATIO} times that"
            ),
        ));
    }
    if let Extent::Exact(len) = extent
        && end > u128::from(len)
    {
        return Err(Error::truncated(
            path,
            format!(
                "the voxel data needs bytes {frame_offset}..{end} (dims {dims3:?}, frame {frame}, vox_offset \
                 {vox_offset}) but the file has {len} bytes"
            ),
        ));
    }
    Ok(Layout { dims: dims3, datatype, frame_offset, frame_bytes })
}

/// `Some((slope, intercept))` when the header asks for a non-identity rescale.
fn scaling(path: &Path, h: &Header) -> Result<Option<(f64, f64)>> {
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

// ---------------------------------------------------------------------------------------------
// Geometry
// ---------------------------------------------------------------------------------------------

/// One voxel spacing from pixdim[axis] (1 to 3): its magnitude. A zero or non-finite spacing is an
/// error on an axis the file uses; beyond dim[0] the axis has one voxel and we take 1.
fn spacing(path: &Path, h: &Header, axis: usize) -> Result<f64> {
    let p = h.pixdim[axis];
    if h.dim[0] < axis as i64 && !(p.is_finite() && p != 0.0) {
        return Ok(1.0);
    }
    if !p.is_finite() || p == 0.0 {
        return Err(Error::invalid(
            path,
            format!("pixdim[{axis}] is {p}: the voxel spacing must be finite and non-zero"),
        ));
    }
    Ok(p.abs())
}

/// The qform's `ras_from_index` (NIfTI-1 method 2; `nifti_quatern_to_mat44` in nifti1_io.c).
fn ras_from_index_qform(bcd: [f64; 3], qoffset: [f64; 3], spacing: [f64; 3], qfac: f64) -> Matrix4<f64> {
    let [mut b, mut c, mut d] = bcd;
    let bcd2 = b * b + c * c + d * d;
    let a = if 1.0 - bcd2 < 1e-7 {
        let n = bcd2.sqrt();
        if n > 0.0 {
            (b, c, d) = (b / n, c / n, d / n);
        }
        0.0
    } else {
        (1.0 - bcd2).sqrt()
    };
    let rotation = Matrix3::new(
        a * a + b * b - c * c - d * d,
        2.0 * (b * c - a * d),
        2.0 * (b * d + a * c),
        2.0 * (b * c + a * d),
        a * a + c * c - b * b - d * d,
        2.0 * (c * d - a * b),
        2.0 * (b * d - a * c),
        2.0 * (c * d + a * b),
        a * a + d * d - c * c - b * b,
    );
    let scale = Matrix3::from_diagonal(&nalgebra::Vector3::new(spacing[0], spacing[1], qfac * spacing[2]));
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rotation * scale));
    for r in 0..3 {
        m[(r, 3)] = qoffset[r];
    }
    m
}

/// The qform's `ras_from_index` from the header's quaternion, qoffset and pixdim, checked for finite values.
fn qform(path: &Path, h: &Header) -> Result<Matrix4<f64>> {
    let spacing = [spacing(path, h, 1)?, spacing(path, h, 2)?, spacing(path, h, 3)?];
    let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
    if !h.quatern_bcd.iter().chain(&h.qoffset).all(|v| v.is_finite()) {
        return Err(Error::invalid(
            path,
            format!("the qform is not finite: quatern_b/c/d {:?}, qoffset {:?}", h.quatern_bcd, h.qoffset),
        ));
    }
    Ok(ras_from_index_qform(h.quatern_bcd, h.qoffset, spacing, qfac))
}

/// Two mappings of the same grid closer than this everywhere on it (and of the same handedness) agree: float32
/// storage and the qform's float32 quaternion (whose a loses digits near a 180° turn) differ by less.
const SFORM_QFORM_TOL_MM: f64 = 0.1;

/// When both the sform and the qform are set, a warning if they place the `dims` grid differently: how far apart
/// the two mappings are at the grid's 8 corner voxels (mm), whether one is the mirror image of the other, and
/// which one is used. nibabel (and we) use the sform; ITK and SimpleITK use the qform.
fn sform_qform_disagreement(path: &Path, h: &Header, sform: &Matrix4<f64>, dims: [usize; 3]) -> Option<String> {
    let (s_code, q_code) = (h.sform_code, h.qform_code);
    let q = match qform(path, h) {
        Ok(q) => q,
        Err(e) => {
            return Some(format!(
                "qform_code is {q_code} but the qform is unusable ({}); the sform (code {s_code}) is used",
                e.kind
            ));
        }
    };
    let (sform, qform): (Transform<Ras, Index>, Transform<Ras, Index>) =
        (Transform::from_matrix(*sform), Transform::from_matrix(q));
    let apart_mm = volume::corner_indices(dims)
        .into_iter()
        .map(|p| sform.apply_point(p).distance(&qform.apply_point(p)))
        .fold(0.0, f64::max);
    let mirrored = (sform.linear().determinant() < 0.0) != (qform.linear().determinant() < 0.0);
    if apart_mm <= SFORM_QFORM_TOL_MM && !mirrored {
        return None;
    }
    let handedness = if mirrored {
        "and of opposite handedness (one is the mirror image of the other, e.g. a left-right flip)"
    } else {
        "with the same handedness"
    };
    Some(format!(
        "the sform (code {s_code}) and the qform (code {q_code}) disagree: they are up to {apart_mm:.2} mm apart at \
         the volume's corners, {handedness}; the sform is used, as nibabel does (ITK and SimpleITK use the qform, \
         so they place this volume elsewhere)"
    ))
}

/// `lps_from_index`, where it came from, and a warning when the sform and the qform are both set but disagree.
fn lps_from_index(
    path: &Path,
    h: &Header,
    dims: [usize; 3],
) -> Result<(Transform<Lps, Index>, GeometrySource, Option<String>)> {
    let mut warning = None;
    let (ras_from_index, source, what) = if h.sform_code > 0 {
        let mut m = Matrix4::identity();
        for (r, row) in h.srow.iter().enumerate() {
            for (c, &v) in row.iter().enumerate() {
                m[(r, c)] = v;
            }
        }
        if h.qform_code > 0 {
            warning = sform_qform_disagreement(path, h, &m, dims);
        }
        (m, GeometrySource::NiftiSform { code: h.sform_code }, "sform (srow_x/y/z)")
    } else if h.qform_code > 0 {
        (qform(path, h)?, GeometrySource::NiftiQform { code: h.qform_code }, "qform")
    } else {
        let spacing = [spacing(path, h, 1)?, spacing(path, h, 2)?, spacing(path, h, 3)?];
        let m = Matrix4::from_diagonal(&nalgebra::Vector4::new(spacing[0], spacing[1], spacing[2], 1.0));
        (m, GeometrySource::NiftiPixdim, "pixdim")
    };
    let ras_from_index: Transform<Ras, Index> = Transform::from_matrix(ras_from_index);
    if !ras_from_index.is_valid_affine() {
        return Err(Error::invalid(
            path,
            format!("the {what} voxel-to-world matrix is singular or not finite: {:?}", ras_from_index.rows()),
        ));
    }
    Ok((lps_from_ras() * ras_from_index, source, warning))
}

// ---------------------------------------------------------------------------------------------
// Samples
// ---------------------------------------------------------------------------------------------

/// A stored sample type, decoded from bytes of either order.
trait Stored: Copy {
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

/// Reads `n_bytes` of `S` samples chunk by chunk, converting each into the output as it arrives.
fn stream_convert<S: Stored, O>(
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
fn read_identity(r: &mut impl Read, l: &Layout, big_endian: bool, progress: &mut Reporter) -> Result<VoxelData> {
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
fn rescale_samples<S: Stored>(
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

fn read_source<S: Source>(path: &Path, src: &mut S, extent: Extent, opts: &mut LoadOptions) -> Result<Volume> {
    let h = read_header(path, src)?;
    let l = layout(path, &h, opts, extent)?;
    let (lps_from_index, geometry_source, geometry_warning) = lps_from_index(path, &h, l.dims)?;
    let scale = scaling(path, &h)?;
    let max_voxel_bytes = opts.max_voxel_bytes;

    let skip = l.frame_offset - h.version.header_bytes() as u64;
    let seeks = src.seek_forward(skip).map_err(|e| Error::io(path, e))?;
    let total = l.frame_bytes as u64 + if seeks { 0 } else { skip };
    let mut progress = Reporter { path, opts, done: 0, total };
    progress.advance(0)?;
    if !seeks {
        let mut scratch = vec![0u8; usize::try_from(skip).unwrap_or(usize::MAX).min(CHUNK_BYTES)];
        let mut left = skip;
        while left > 0 {
            let n = usize::try_from(left).unwrap_or(usize::MAX).min(CHUNK_BYTES);
            fill(path, src, &mut scratch[..n], "the extensions or earlier frames")?;
            left -= n as u64;
            progress.advance(n)?;
        }
    }

    let data = match scale {
        None => read_identity(src, &l, h.big_endian, &mut progress)?,
        Some(slope_inter) => {
            let mut raw = volume::try_with_capacity(path, l.frame_bytes, "the stored samples before rescaling")?;
            raw.resize(l.frame_bytes, 0);
            for chunk in raw.chunks_mut(CHUNK_BYTES) {
                fill(path, src, chunk, "the voxel data")?;
                progress.advance(chunk.len())?;
            }
            with_stored!(l.datatype, T => rescale_samples::<T>(path, &raw, l.dims, h.big_endian, slope_inter, max_voxel_bytes)?)
        }
    };

    let mut volume = Volume::new(path, l.dims, data, lps_from_index, geometry_source)?;
    if let Some((slope, intercept)) = scale {
        volume.rescale = Rescale { slope, intercept, applied: true };
    }
    if !h.descrip.is_empty() {
        volume.metadata.description = Some(h.descrip.clone());
    }
    volume.metadata.warnings.extend(geometry_warning);
    match h.xyzt_units & 0x07 {
        1 => volume.metadata.warnings.push("xyzt_units says metres; coordinates are used as mm".to_string()),
        3 => volume.metadata.warnings.push("xyzt_units says micrometres; coordinates are used as mm".to_string()),
        _ => {}
    }
    Ok(volume)
}

// ---------------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------------

/// Options for [`write_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// Write NIfTI-2 (float64 geometry, 64-bit dims) instead of NIfTI-1.
    pub nifti2: bool,
}

/// Writes `volume` as NIfTI-1 (`.nii`, or gzip when the name ends in `.gz`), atomically.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    write_with(path, volume, WriteOptions::default())
}

/// Writes `volume` as NIfTI-1 or NIfTI-2 (see [`WriteOptions`]), gzip when the name ends in `.gz`.
pub fn write_with(path: &Path, volume: &Volume, opts: WriteOptions) -> Result<()> {
    let n = volume::checked_voxel_count(path, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(path, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    if !volume.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    let header = if opts.nifti2 { nifti2_header(volume) } else { nifti1_header(path, volume)? };
    write_file(path, &header, |w| write_samples(w, &volume.data))
}

/// Writes `header` then the samples from `samples` to `path`, atomically; gzip when the name ends in `.gz`.
fn write_file(path: &Path, header: &[u8], samples: impl FnOnce(&mut dyn Write) -> io::Result<()>) -> Result<()> {
    let gz = path.file_name().is_some_and(|n| n.to_string_lossy().to_ascii_lowercase().ends_with(".gz"));
    crate::write_atomic(path, |w| {
        if gz {
            let mut enc = GzEncoder::new(w, Compression::default());
            enc.write_all(header)?;
            samples(&mut enc)?;
            enc.finish()?;
            Ok(())
        } else {
            w.write_all(header)?;
            samples(w)
        }
    })
}

fn write_samples(w: &mut dyn Write, data: &VoxelData) -> io::Result<()> {
    fn le<T: Copy, const N: usize>(w: &mut dyn Write, v: &[T], bytes: fn(T) -> [u8; N]) -> io::Result<()> {
        let mut buf = Vec::with_capacity(64 << 10);
        for chunk in v.chunks((64 << 10) / N) {
            buf.clear();
            for &x in chunk {
                buf.extend_from_slice(&bytes(x));
            }
            w.write_all(&buf)?;
        }
        Ok(())
    }
    match data {
        VoxelData::U8(v) => w.write_all(v),
        VoxelData::I16(v) => le(w, v, i16::to_le_bytes),
        VoxelData::U16(v) => le(w, v, u16::to_le_bytes),
        VoxelData::F32(v) => le(w, v, f32::to_le_bytes),
    }
}

/// NIfTI datatype code and bitpix of a sample type.
const fn type_code(t: SampleType) -> (i16, i16) {
    match t {
        SampleType::U8 => (2, 8),
        SampleType::I16 => (4, 16),
        SampleType::U16 => (512, 16),
        SampleType::F32 => (16, 32),
    }
}

/// The qform of a linear part: quaternion (b, c, d) of the nearest rotation, qfac, and column lengths.
///
/// As `nifti_mat44_to_quatern` (nifti1_io.c): normalise the columns, take the orthogonal polar factor
/// (exact for a rigid direction matrix, the nearest rotation for a sheared one), flip the k column
/// when the determinant is negative (qfac = −1), then extract the quaternion with a ≥ 0.
fn qform_from_linear(linear: &Matrix3<f64>) -> ([f64; 3], f64, [f64; 3]) {
    let spacing = [linear.column(0).norm(), linear.column(1).norm(), linear.column(2).norm()];
    let mut r = *linear;
    for (mut col, s) in r.column_iter_mut().zip(spacing) {
        col /= s;
    }
    if let Some(svd) = r.try_svd(true, true, 1e-15, 200)
        && let (Some(u), Some(v_t)) = (svd.u, svd.v_t)
    {
        r = u * v_t;
    }
    let mut qfac = 1.0;
    if r.determinant() < 0.0 {
        qfac = -1.0;
        r.column_mut(2).neg_mut();
    }
    let (r11, r12, r13) = (r[(0, 0)], r[(0, 1)], r[(0, 2)]);
    let (r21, r22, r23) = (r[(1, 0)], r[(1, 1)], r[(1, 2)]);
    let (r31, r32, r33) = (r[(2, 0)], r[(2, 1)], r[(2, 2)]);
    let trace1 = r11 + r22 + r33 + 1.0;
    let (a, b, c, d);
    if trace1 > 0.5 {
        a = 0.5 * trace1.sqrt();
        b = 0.25 * (r32 - r23) / a;
        c = 0.25 * (r13 - r31) / a;
        d = 0.25 * (r21 - r12) / a;
    } else {
        let xd = 1.0 + r11 - (r22 + r33);
        let yd = 1.0 + r22 - (r11 + r33);
        let zd = 1.0 + r33 - (r11 + r22);
        if xd > 1.0 {
            b = 0.5 * xd.sqrt();
            c = 0.25 * (r12 + r21) / b;
            d = 0.25 * (r13 + r31) / b;
            a = 0.25 * (r32 - r23) / b;
        } else if yd > 1.0 {
            c = 0.5 * yd.sqrt();
            b = 0.25 * (r12 + r21) / c;
            d = 0.25 * (r23 + r32) / c;
            a = 0.25 * (r13 - r31) / c;
        } else {
            d = 0.5 * zd.sqrt();
            b = 0.25 * (r13 + r31) / d;
            c = 0.25 * (r23 + r32) / d;
            a = 0.25 * (r21 - r12) / d;
        }
    }
    let sign = if a < 0.0 { -1.0 } else { 1.0 };
    ([sign * b, sign * c, sign * d], qfac, spacing)
}

/// Little-endian header fields written at fixed offsets.
struct Put<'a>(&'a mut [u8]);

impl Put<'_> {
    fn bytes(&mut self, off: usize, b: &[u8]) {
        self.0[off..off + b.len()].copy_from_slice(b);
    }
    fn i16(&mut self, off: usize, v: i16) {
        self.bytes(off, &v.to_le_bytes());
    }
    fn i32(&mut self, off: usize, v: i32) {
        self.bytes(off, &v.to_le_bytes());
    }
    fn i64(&mut self, off: usize, v: i64) {
        self.bytes(off, &v.to_le_bytes());
    }
    fn f32(&mut self, off: usize, v: f64) {
        self.bytes(off, &(v as f32).to_le_bytes());
    }
    fn f64(&mut self, off: usize, v: f64) {
        self.bytes(off, &v.to_le_bytes());
    }
}

/// What both header versions hold, in RAS.
struct WriteGeometry {
    srow: [[f64; 4]; 3],
    quatern_bcd: [f64; 3],
    qoffset: [f64; 3],
    pixdim: [f64; 8],
}

fn write_geometry(lps_from_index: &Transform<Lps, Index>) -> WriteGeometry {
    let ras_from_index: Transform<Ras, Index> = ras_from_lps() * *lps_from_index;
    let rows = ras_from_index.rows();
    let (quatern_bcd, qfac, spacing) = qform_from_linear(&ras_from_index.linear());
    WriteGeometry {
        srow: [rows[0], rows[1], rows[2]],
        quatern_bcd,
        qoffset: ras_from_index.translation(),
        pixdim: [qfac, spacing[0], spacing[1], spacing[2], 1.0, 1.0, 1.0, 1.0],
    }
}

/// The description, cut to at most 79 bytes at a character boundary.
fn descrip(volume: &Volume) -> Vec<u8> {
    let mut s = volume.metadata.description.clone().unwrap_or_default();
    while s.len() > 79 {
        s.pop();
    }
    s.into_bytes()
}

fn nifti1_header(path: &Path, volume: &Volume) -> Result<Vec<u8>> {
    let what = Nifti1Content { type_code: type_code(volume.sample_type()), descrip: descrip(volume), vector: None };
    nifti1_header_for(path, volume.dims, &volume.lps_from_index, &what)
}

/// What a NIfTI-1 header says besides the grid: the sample type, the description, and for a vector image its
/// intent and component count (`dim[5]`).
struct Nifti1Content {
    /// Datatype code and bitpix.
    type_code: (i16, i16),
    descrip: Vec<u8>,
    /// `(intent_code, components)`: written as dim = [5, X, Y, Z, 1, components, 1, 1].
    vector: Option<(i16, i16)>,
}

fn nifti1_header_for(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    what: &Nifti1Content,
) -> Result<Vec<u8>> {
    let dims16: Vec<i16> = dims.iter().filter_map(|&d| i16::try_from(d).ok()).collect();
    let [nx, ny, nz] = dims16[..] else {
        return Err(Error::unsupported(
            path,
            format!(
                "dims {dims:?} exceed NIfTI-1's limit of 32767 per axis; write NIfTI-2 (WriteOptions {{ nifti2: true }})"
            ),
        ));
    };
    let g = write_geometry(lps_from_index);
    let (datatype, bitpix) = what.type_code;
    let mut buf = vec![0u8; NIFTI1_VOX_OFFSET];
    let mut p = Put(&mut buf);
    p.i32(0, NIFTI1_HEADER_BYTES as i32);
    p.bytes(38, b"r"); // `regular`, as nibabel writes
    let dim = match what.vector {
        None => [3, nx, ny, nz, 1, 1, 1, 1],
        Some((intent_code, components)) => {
            p.i16(68, intent_code);
            [5, nx, ny, nz, 1, components, 1, 1]
        }
    };
    for (i, d) in dim.into_iter().enumerate() {
        p.i16(40 + 2 * i, d);
    }
    p.i16(70, datatype);
    p.i16(72, bitpix);
    for (i, &v) in g.pixdim.iter().enumerate() {
        p.f32(76 + 4 * i, v);
    }
    p.f32(108, NIFTI1_VOX_OFFSET as f64);
    p.f32(112, 1.0); // scl_slope
    p.f32(116, 0.0); // scl_inter
    p.bytes(123, &[2]); // xyzt_units: mm, time unknown
    p.bytes(148, &what.descrip);
    p.i16(252, 1); // qform_code: scanner anatomical
    p.i16(254, 1); // sform_code: scanner anatomical
    for i in 0..3 {
        p.f32(256 + 4 * i, g.quatern_bcd[i]);
        p.f32(268 + 4 * i, g.qoffset[i]);
    }
    for (r, row) in g.srow.iter().enumerate() {
        for (c, &v) in row.iter().enumerate() {
            p.f32(280 + 16 * r + 4 * c, v);
        }
    }
    p.bytes(344, NIFTI1_MAGIC);
    Ok(buf)
}

fn nifti2_header(volume: &Volume) -> Vec<u8> {
    let g = write_geometry(&volume.lps_from_index);
    let (datatype, bitpix) = type_code(volume.sample_type());
    let mut buf = vec![0u8; NIFTI2_VOX_OFFSET];
    let mut p = Put(&mut buf);
    p.i32(0, NIFTI2_HEADER_BYTES as i32);
    p.bytes(4, NIFTI2_MAGIC);
    p.i16(12, datatype);
    p.i16(14, bitpix);
    let [nx, ny, nz] = volume.dims.map(|d| d as i64);
    for (i, d) in [3, nx, ny, nz, 1, 1, 1, 1].into_iter().enumerate() {
        p.i64(16 + 8 * i, d);
    }
    for (i, &v) in g.pixdim.iter().enumerate() {
        p.f64(104 + 8 * i, v);
    }
    p.i64(168, NIFTI2_VOX_OFFSET as i64);
    p.f64(176, 1.0); // scl_slope
    p.f64(184, 0.0); // scl_inter
    p.bytes(240, &descrip(volume));
    p.i32(344, 1); // qform_code
    p.i32(348, 1); // sform_code
    for i in 0..3 {
        p.f64(352 + 8 * i, g.quatern_bcd[i]);
        p.f64(376 + 8 * i, g.qoffset[i]);
    }
    for (r, row) in g.srow.iter().enumerate() {
        for (c, &v) in row.iter().enumerate() {
            p.f64(400 + 32 * r + 8 * c, v);
        }
    }
    p.i32(500, 2); // xyzt_units: mm
    buf
}

// ---------------------------------------------------------------------------------------------
// Displacement fields (NIFTI_INTENT_DISPVECT)
// ---------------------------------------------------------------------------------------------

/// `NIFTI_INTENT_DISPVECT` (nifti1.h): each voxel holds a displacement vector.
pub const NIFTI_INTENT_DISPVECT: i16 = 1006;

/// The sign that takes a vector component between LPS (inside) and RAS (in the file), either way.
const LPS_RAS_SIGN: [f32; 3] = [-1.0, -1.0, 1.0];

/// A displacement field read by [`read_displacement_field`]: one vector per voxel of a grid.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacementField {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    pub lps_from_index: Transform<Lps, Index>,
    pub geometry_source: GeometrySource,
    /// The displacement at each voxel centre in LPS mm, i fastest (as [`Volume::data`]).
    pub displacements_lps: Vec<[f32; 3]>,
}

/// Writes a displacement field as NIfTI-1 (`.nii`, or gzip when the name ends in `.gz`), atomically: float32,
/// `dim = [5, X, Y, Z, 1, 3, 1, 1]`, `intent_code` 1006 (`NIFTI_INTENT_DISPVECT`), the grid's sform and qform as
/// [`write()`] writes them, and the vectors in **RAS** (the first two components of each LPS vector negated), the
/// component planes one after the other (all x, then all y, then all z). See the module docs, "Displacement fields".
pub fn write_displacement_field(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    let n = volume::checked_voxel_count(path, dims)?;
    if displacements_lps.len() != n {
        return Err(Error::invalid(path, format!("{} displacements for dims {dims:?}", displacements_lps.len())));
    }
    if !lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    if let Some(i) = displacements_lps.iter().position(|d| !d.iter().all(|v| v.is_finite())) {
        return Err(Error::invalid(
            path,
            format!("the displacement at voxel {i} is not finite: {:?}", displacements_lps[i]),
        ));
    }
    let what = Nifti1Content {
        type_code: type_code(SampleType::F32),
        descrip: b"warpbench displacement field u(x) - x, RAS mm".to_vec(),
        vector: Some((NIFTI_INTENT_DISPVECT, 3)),
    };
    let header = nifti1_header_for(path, dims, lps_from_index, &what)?;
    write_file(path, &header, |w| {
        let mut buf = Vec::with_capacity(64 << 10);
        for (c, sign) in LPS_RAS_SIGN.into_iter().enumerate() {
            for chunk in displacements_lps.chunks(16 << 10) {
                buf.clear();
                for d in chunk {
                    buf.extend_from_slice(&(sign * d[c]).to_le_bytes());
                }
                w.write_all(&buf)?;
            }
        }
        Ok(())
    })
}

/// Reads a displacement field written by [`write_displacement_field`] or by ITK, ANTs or Slicer: NIfTI-1 or -2,
/// intent 1006, shape [X, Y, Z, 1, 3], float32 or float64, RAS vectors (returned in LPS). Errors name the file.
pub fn read_displacement_field(path: &Path) -> Result<DisplacementField> {
    crate::check_regular_file(path)?;
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut magic = [0u8; 2];
    let n = crate::read_up_to(&mut file, &mut magic).map_err(|e| Error::io(path, e))?;
    file.seek(SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
    if n == 2 && magic == GZIP_MAGIC {
        read_field_source(path, &mut MultiGzDecoder::new(BufReader::new(file)), Extent::Gzip(file_len))
    } else {
        read_field_source(path, &mut BufReader::new(file), Extent::Exact(file_len))
    }
}

/// [`read_displacement_field`] from memory (gzip detected by the magic bytes); `name` is used in errors.
pub fn read_displacement_field_bytes(name: &Path, bytes: &[u8]) -> Result<DisplacementField> {
    if bytes.starts_with(&GZIP_MAGIC) {
        read_field_source(name, &mut MultiGzDecoder::new(bytes), Extent::Gzip(bytes.len() as u64))
    } else {
        let mut src = bytes;
        read_field_source(name, &mut src, Extent::Exact(bytes.len() as u64))
    }
}

fn read_field_source<S: Source>(path: &Path, src: &mut S, extent: Extent) -> Result<DisplacementField> {
    let h = read_header(path, src)?;
    if h.intent_code != i32::from(NIFTI_INTENT_DISPVECT) {
        return Err(Error::invalid(
            path,
            format!("intent_code is {}, not NIFTI_INTENT_DISPVECT (1006): not a displacement field", h.intent_code),
        ));
    }
    if h.dim[0] != 5 || h.dim[4] != 1 || h.dim[5] != 3 || h.dim[1..4].iter().any(|&d| d < 1) {
        return Err(Error::invalid(
            path,
            format!("dim = {:?}; a 3-D displacement field has dim = [5, X, Y, Z, 1, 3, …]", h.dim),
        ));
    }
    let mut dims = [0usize; 3];
    for (a, d) in dims.iter_mut().enumerate() {
        *d = usize::try_from(h.dim[a + 1]).map_err(|_| {
            Error::invalid(path, format!("dim[{}] = {} does not fit this platform", a + 1, h.dim[a + 1]))
        })?;
    }
    let datatype = DataType::from_code(path, h.datatype)?;
    if !matches!(datatype, DataType::F32 | DataType::F64) {
        return Err(Error::unsupported(
            path,
            format!("displacement field of datatype {}; float32 and float64 are read", h.datatype),
        ));
    }
    if i64::from(h.bitpix) != 8 * datatype.bytes() as i64 {
        return Err(Error::invalid(path, format!("bitpix {} does not match datatype {}", h.bitpix, h.datatype)));
    }
    if scaling(path, &h)?.is_some() {
        return Err(Error::unsupported(
            path,
            format!("a scaled displacement field (scl_slope {}, scl_inter {})", h.scl_slope, h.scl_inter),
        ));
    }
    let (lps_from_index, geometry_source, _) = lps_from_index(path, &h, dims)?;
    // The output is 12 bytes a voxel; a stored plane is at most 8 bytes a voxel, so both fit once this passes.
    let n = volume::check_allocation(path, dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let plane_bytes = n * datatype.bytes();
    let header_bytes = h.version.header_bytes() as f64;
    if !h.vox_offset.is_finite() || h.vox_offset < header_bytes || h.vox_offset > 2f64.powi(62) {
        return Err(Error::invalid(
            path,
            format!("vox_offset {} is not a byte offset past the {header_bytes}-byte header", h.vox_offset),
        ));
    }
    let vox_offset = h.vox_offset as u64;
    let end = u128::from(vox_offset) + 3 * plane_bytes as u128;
    match extent {
        Extent::Exact(len) if end > u128::from(len) => {
            return Err(Error::truncated(
                path,
                format!(
                    "the displacement field needs {end} bytes (dims {dims:?}, 3 components) but the file has {len}"
                ),
            ));
        }
        Extent::Gzip(len) if end > u128::from(len) * u128::from(MAX_DEFLATE_RATIO) => {
            return Err(Error::truncated(
                path,
                format!("the displacement field needs {end} bytes but a {len}-byte gzip stream cannot hold them"),
            ));
        }
        _ => {}
    }
    let mut opts = LoadOptions::new();
    let skip = vox_offset - h.version.header_bytes() as u64;
    if !src.seek_forward(skip).map_err(|e| Error::io(path, e))? {
        io::copy(&mut src.by_ref().take(skip), &mut io::sink()).map_err(|e| Error::io(path, e))?;
    }
    let mut progress = Reporter { path, opts: &mut opts, done: 0, total: 3 * plane_bytes as u64 };
    let mut displacements_lps = volume::try_with_capacity(path, n, "the displacement vectors")?;
    displacements_lps.resize(n, [0.0f32; 3]);
    for (c, sign) in LPS_RAS_SIGN.into_iter().enumerate() {
        let plane: Vec<f32> = if datatype == DataType::F32 {
            stream_convert(src, plane_bytes, h.big_endian, &mut progress, |x: f32| x)?
        } else {
            stream_convert(src, plane_bytes, h.big_endian, &mut progress, |x: f64| x as f32)?
        };
        for (d, v) in displacements_lps.iter_mut().zip(plane) {
            d[c] = sign * v;
        }
    }
    Ok(DisplacementField { dims, lps_from_index, geometry_source, displacements_lps })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_round_trip_for_proper_and_improper_rotations() {
        let theta: f64 = 0.3;
        let (s, c) = theta.sin_cos();
        let rot = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        for flip in [1.0, -1.0] {
            let linear = rot * Matrix3::from_diagonal(&nalgebra::Vector3::new(0.5, 0.7, 2.0 * flip));
            let (bcd, qfac, spacing) = qform_from_linear(&linear);
            assert!((qfac - flip).abs() < f64::EPSILON);
            let m = ras_from_index_qform(bcd, [0.0; 3], spacing, qfac);
            let back = m.fixed_view::<3, 3>(0, 0).into_owned();
            assert!((back - linear).abs().max() < 1e-12, "{back} vs {linear}");
        }
        // A 180° turn about x: a = 0, the second branch.
        let linear = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, -1.0, -1.0));
        let (bcd, qfac, spacing) = qform_from_linear(&linear);
        let back = ras_from_index_qform(bcd, [0.0; 3], spacing, qfac).fixed_view::<3, 3>(0, 0).into_owned();
        assert!((back - linear).abs().max() < 1e-12);
    }

    /// A small oblique grid and a field whose components differ in every voxel.
    fn sample_field() -> ([usize; 3], Transform<Lps, Index>, Vec<[f32; 3]>) {
        let (s, c) = 0.4f64.sin_cos();
        let linear = Matrix3::new(c * 1.5, -s * 2.0, 0.0, s * 1.5, c * 2.0, 0.0, 0.0, 0.0, 2.5);
        let lps_from_index = Transform::from_linear_translation(linear, [-30.0, 12.5, 7.25]);
        let dims = [3, 4, 2];
        let field = (0..24).map(|i| [i as f32 * 0.25 - 3.0, 1.0 - i as f32 * 0.125, (i * i) as f32 * 0.01]).collect();
        (dims, lps_from_index, field)
    }

    #[test]
    fn displacement_field_round_trips_with_ras_vectors_on_disk() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (dims, lps_from_index, field) = sample_field();
        for name in ["field.nii", "field.nii.gz"] {
            let path = dir.path().join(name);
            write_displacement_field(&path, dims, &lps_from_index, &field).expect("write");
            let back = read_displacement_field(&path).expect("read back");
            assert_eq!(back.dims, dims);
            assert!(back.lps_from_index.max_abs_diff(&lps_from_index) < 1e-4, "{:?}", back.lps_from_index);
            assert_eq!(back.geometry_source, GeometrySource::NiftiSform { code: 1 });
            // Negation is exact, so the vectors come back bit for bit.
            let bits = |v: &[[f32; 3]]| v.iter().flat_map(|d| d.map(|x| (x + 0.0).to_bits())).collect::<Vec<_>>();
            assert_eq!(bits(&back.displacements_lps), bits(&field), "{name}");
        }
        // The raw file: the header fields ITK reads, and the planes in RAS (x and y negated), x plane first.
        let raw = std::fs::read(dir.path().join("field.nii")).expect("read raw");
        let i16_at = |o: usize| i16::from_le_bytes([raw[o], raw[o + 1]]);
        let f32_at = |o: usize| f32::from_le_bytes([raw[o], raw[o + 1], raw[o + 2], raw[o + 3]]);
        assert_eq!((0..8).map(|i| i16_at(40 + 2 * i)).collect::<Vec<_>>(), [5, 3, 4, 2, 1, 3, 1, 1]);
        assert_eq!((i16_at(68), i16_at(70), i16_at(72)), (1006, 16, 32));
        assert!((f32_at(76 + 16) - 1.0).abs() < f32::EPSILON && (f32_at(76 + 20) - 1.0).abs() < f32::EPSILON);
        assert_eq!(raw.len(), NIFTI1_VOX_OFFSET + 24 * 3 * 4);
        let plane = |c: usize, i: usize| f32_at(NIFTI1_VOX_OFFSET + 4 * (c * 24 + i));
        for i in [0, 5, 23] {
            assert_eq!(plane(0, i).to_bits(), (-field[i][0]).to_bits());
            assert_eq!(plane(1, i).to_bits(), (-field[i][1]).to_bits());
            assert_eq!(plane(2, i).to_bits(), field[i][2].to_bits());
        }
        // The volume reader refuses the 5-D file rather than misreading it.
        let e = read_bytes(Path::new("field.nii"), &raw, &mut LoadOptions::new()).expect_err("5-D");
        assert!(e.to_string().contains("dim[5] = 3"), "{e}");
    }

    #[test]
    fn displacement_field_reader_refuses_truncated_and_wrong_intent_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (dims, lps_from_index, field) = sample_field();
        let path = dir.path().join("field.nii");
        write_displacement_field(&path, dims, &lps_from_index, &field).expect("write");
        let raw = std::fs::read(&path).expect("read raw");

        let cut = dir.path().join("cut.nii");
        std::fs::write(&cut, &raw[..raw.len() - 10]).expect("write cut");
        let e = read_displacement_field(&cut).expect_err("truncated");
        assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");
        assert!(e.to_string().starts_with(&format!("{}: ", cut.display())), "{e}");

        let mut gz = Vec::new();
        let mut enc = GzEncoder::new(&mut gz, Compression::default());
        enc.write_all(&raw[..raw.len() - 10]).expect("gzip");
        enc.finish().expect("gzip");
        let e = read_displacement_field_bytes(Path::new("cut.nii.gz"), &gz).expect_err("truncated gzip");
        assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");

        let mut vector = raw.clone();
        vector[68..70].copy_from_slice(&1007i16.to_le_bytes());
        let e = read_displacement_field_bytes(Path::new("vector.nii"), &vector).expect_err("intent 1007");
        assert!(e.to_string().starts_with("vector.nii: ") && e.to_string().contains("intent_code is 1007"), "{e}");

        let scalar = dir.path().join("scalar.nii");
        let v = Volume::new(&scalar, dims, VoxelData::U8(vec![1; 24]), lps_from_index, GeometrySource::NiftiPixdim)
            .expect("volume");
        write(&scalar, &v).expect("write scalar");
        let e = read_displacement_field(&scalar).expect_err("a scalar volume");
        assert!(e.to_string().contains("intent_code is 0"), "{e}");

        let mut two = raw.clone();
        two[50..52].copy_from_slice(&2i16.to_le_bytes()); // dim[5] = 2 components
        let e = read_displacement_field_bytes(Path::new("two.nii"), &two).expect_err("2 components");
        assert!(e.to_string().contains("[5, X, Y, Z, 1, 3"), "{e}");

        let mut huge = raw;
        for a in 0..3 {
            huge[42 + 2 * a..44 + 2 * a].copy_from_slice(&32000i16.to_le_bytes());
        }
        let e = read_displacement_field_bytes(Path::new("huge.nii"), &huge).expect_err("too large");
        assert!(matches!(e.kind, ErrorKind::TooLarge { .. } | ErrorKind::Truncated(_)), "{e}");

        let bad = dir.path().join("nan.nii");
        let mut nan = field.clone();
        nan[3][1] = f32::NAN;
        let e = write_displacement_field(&bad, dims, &lps_from_index, &nan).expect_err("NaN");
        assert!(e.to_string().contains("voxel 3"), "{e}");
        assert!(!bad.exists());
    }

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
