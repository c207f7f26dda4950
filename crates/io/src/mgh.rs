//! FreeSurfer's MGH volumes (`.mgh`) and their gzip-compressed form (`.mgz`, also `.mgh.gz`): [`read()`],
//! [`read_bytes`], [`write()`], [`to_bytes`].
//!
//! # The format
//!
//! An MGH file is a big-endian header, the samples from byte [`HEADER_BYTES`] (284), then optional scan parameters and
//! tags (FreeSurfer's `mghRead` and `mghWrite` in `utils/mriio.cpp`; nibabel's `nibabel/freesurfer/mghformat.py`;
//! <https://surfer.nmr.mgh.harvard.edu/fswiki/FsTutorial/MghFormat>):
//!
//! ```text
//! byte  type     field
//!    0  i32      version: 1
//!    4  i32 × 4  width, height, depth, nframes
//!   20  i32      type: 0 UCHAR (u8), 1 INT (i32), 3 FLOAT (f32), 4 SHORT (i16), 10 USHRT (u16)
//!   24  i32      dof
//!   28  i16      goodRASflag
//!   30  f32 × 3  delta: the voxel sizes, mm
//!   42  f32 × 9  x_ras, y_ras, z_ras: the RAS directions of the i, j and k axes (the columns of Mdc)
//!   78  f32 × 3  c_ras (Pxyz_c): the RAS position of the centre voxel
//!   90           zeros up to 284
//!  284           the samples, i fastest, then j, k and the frame (Fortran order)
//!                then TR, flip angle, TE, TI and FoV (f32 each) and FreeSurfer's tags, all optional
//! ```
//!
//! A `.mgz` is those bytes gzip-compressed; the name decides, as it does for FreeSurfer and nibabel.
//!
//! # Geometry
//!
//! With D = diag(delta) and N = (width, height, depth), FreeSurfer's vox2ras for 0-based indices is
//!
//! ```text
//! ras_from_index = [ Mdc·D | P₀ ],   P₀ = c_ras − Mdc·D·(N / 2)
//! ```
//!
//! with N / 2 in real numbers (2.5 for a width of 5): c_ras is the position of the continuous index N / 2, as in
//! FreeSurfer's `load_mgh.m` and nibabel's `MGHHeader.get_affine`. We keep LPS inside, so `lps_from_index =
//! diag(−1, −1, 1) · ras_from_index` ([`GeometrySource::Mgh`]), computed in f64 from the stored f32 fields.
//!
//! When goodRASflag ≤ 0 the file holds no orientation. FreeSurfer's `mghRead` then ignores delta, Mdc and c_ras and
//! sets its CORONAL default: 1 mm voxels, x_ras = (−1, 0, 0), y_ras = (0, 0, −1), z_ras = (0, 1, 0) (LIA), c_ras = 0.
//! We do the same ([`CORONAL_MDC`]) and say so in `metadata.warnings`. nibabel 5.4.2 differs twice: it assumes a
//! default only for a flag of exactly 0 (a negative flag keeps the stored fields), and its default direction is LSP
//! (its default `Mdc` field, `[[-1, 0, 0], [0, 0, 1], [0, -1, 0]]`, holds FreeSurfer's matrix as rows where the file
//! holds the columns).
//!
//! # Samples
//!
//! Type codes 0, 1, 3, 4 and 10, the ones nibabel reads (and FreeSurfer's MATLAB `load_mgh.m`); the others (2 LONG,
//! 5 BITMAP, 6 TENSOR, 7 FLOAT_COMPLEX, 8 DOUBLE_COMPLEX, 9 RGB) are refused with an error naming the code. The
//! volume's sample type follows `docs/fixture-manifest.md` ([`StoredType::unscaled`]): u8, i16, u16 and f32 are
//! kept, i32 becomes f32 (rounded to nearest). MGH has no rescale. A file of several frames gives one, chosen by
//! [`LoadOptions::frame`] as for a 4-D NIfTI; without a choice it is [`crate::ErrorKind::FrameRequired`]. The scan
//! parameters and tags after the samples are not read. The version must be 1, as nibabel requires.
//!
//! # Robustness
//!
//! Only a regular file is opened. The header is checked before anything is allocated from it: each size at least 1,
//! the frame's samples under [`LoadOptions::max_voxel_bytes`] ([`volume::check_allocation`]), inside the file for a
//! `.mgh`, and within what gzip can inflate from the file's length for a `.mgz`. A file that ends early is
//! [`crate::ErrorKind::Truncated`]; a `.mgz` that is not gzip, or a `.mgh` that is, is refused by name. The samples are
//! decoded a chunk at a time into a buffer allocated fallibly.
//!
//! # Writing
//!
//! [`write()`] writes version 1, the volume's dims with one frame, its sample type (u8 as UCHAR, i16 SHORT, u16 USHRT,
//! f32 FLOAT: every volume type has an MGH type, so nothing is converted), dof 0, goodRASflag 1, delta = the lengths
//! of `ras_from_index`'s columns, Mdc = the columns over their lengths, c_ras = `ras_from_index` at N / 2, as nibabel's
//! `MGHImage._affine2header` does; then the samples and, as nibabel writes them, five zero scan parameters; gzip for a
//! `.mgz` or `.mgh.gz`; atomically ([`crate::write_atomic`]). The geometry is stored as f32, so it reads back within
//! f32 rounding (about 6·10⁻⁸ relative), not bit for bit. nibabel and current FreeSurfer read USHRT (10), for u16; an
//! old FreeSurfer release may not.

use std::fs::File;
use std::io::{self, BufReader, Seek, SeekFrom, Write};
use std::path::Path;

use crate::pargz::ParGzWriter;
use flate2::Compression;
use flate2::read::MultiGzDecoder;
use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Point3, Ras, Transform, lps_from_ras, ras_from_lps};
use crate::options::LoadOptions;
use crate::sample::{self, StoredType};
use crate::stream::{Extent, GZIP_MAGIC, MAX_DEFLATE_RATIO, Source, fill, read_error};
use crate::volume::{self, GeometrySource, SampleType, Volume, VoxelData};

/// Where the samples start: the header, its unused space included.
pub const HEADER_BYTES: usize = 284;

/// The scan parameters after the samples that nibabel writes (TR, flip angle, TE, TI, FoV; f32 each).
const SCAN_PARAMETER_BYTES: usize = 20;

/// FreeSurfer's CORONAL default direction, assumed when goodRASflag ≤ 0: the columns x_ras, y_ras, z_ras (LIA).
pub const CORONAL_MDC: [[f64; 3]; 3] = [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]];

/// The MGH type codes read, their stored types and FreeSurfer's names (`MRI_*` in `include/mri.h`).
const TYPE_CODES: [(i32, StoredType, &str); 5] = [
    (0, StoredType::U8, "UCHAR"),
    (1, StoredType::I32, "INT"),
    (3, StoredType::F32, "FLOAT"),
    (4, StoredType::I16, "SHORT"),
    (10, StoredType::U16, "USHRT"),
];

/// Bytes read between progress reports (a multiple of every sample size).
const CHUNK_BYTES: usize = 4 << 20;

/// Reads the MGH (`.mgh`) or gzip-compressed MGH (`.mgz`, `.mgh.gz`) file at `path`.
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    crate::files::check_regular_file(path)?;
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    if is_gzip_name(path) {
        let mut magic = [0u8; 2];
        let n = crate::files::read_up_to(&mut file, &mut magic).map_err(|e| Error::io(path, e))?;
        check_gzip_magic(path, &magic[..n])?;
        file.seek(SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
        let mut src = MultiGzDecoder::new(BufReader::new(file));
        read_source(path, &mut src, Extent::Gzip(len), opts)
    } else {
        read_source(path, &mut BufReader::new(file), Extent::Exact(len), opts)
    }
}

/// Reads an MGH file held in memory: gzip-compressed when `name` ends in `.mgz` or `.mgh.gz`, as [`read()`] decides;
/// `name` is also used in errors.
pub fn read_bytes(name: &Path, bytes: &[u8], opts: &mut LoadOptions) -> Result<Volume> {
    if is_gzip_name(name) {
        check_gzip_magic(name, bytes)?;
        read_source(name, &mut MultiGzDecoder::new(bytes), Extent::Gzip(bytes.len() as u64), opts)
    } else {
        let mut src = bytes;
        read_source(name, &mut src, Extent::Exact(bytes.len() as u64), opts)
    }
}

/// Writes `volume` as MGH at `path`: `.mgh` raw, `.mgz` or `.mgh.gz` gzip-compressed (module docs, "Writing").
/// Atomic; any other name is an error.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    let gzip = match name_kind(path) {
        Some(NameKind::Plain) => false,
        Some(NameKind::Gzip) => true,
        None => {
            return Err(Error::invalid(path, "an MGH file is named .mgh, or .mgz (or .mgh.gz) when gzip-compressed"));
        }
    };
    let header = header_of(path, volume)?;
    crate::write_atomic(path, |w| write_to(w, &header, &volume.data, gzip))
}

/// The bytes [`write()`] would put in a file (gzip-compressed when `gzip`), in memory; `name` is used in errors.
pub fn to_bytes(name: &Path, volume: &Volume, gzip: bool) -> Result<Vec<u8>> {
    let header = header_of(name, volume)?;
    let mut out = Vec::new();
    write_to(&mut out, &header, &volume.data, gzip).map_err(|e| Error::io(name, e))?;
    Ok(out)
}

/// What a name says a file is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum NameKind {
    Plain,
    Gzip,
}

/// `.mgh` plain, `.mgz` or `.mgh.gz` gzip (case ignored), else `None`.
#[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
fn name_kind(path: &Path) -> Option<NameKind> {
    let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
    if name.ends_with(".mgz") || name.ends_with(".mgh.gz") {
        Some(NameKind::Gzip)
    } else if name.ends_with(".mgh") {
        Some(NameKind::Plain)
    } else {
        None
    }
}

fn is_gzip_name(path: &Path) -> bool {
    name_kind(path) == Some(NameKind::Gzip)
}

/// Whether `path`'s name is an MGH file's (`.mgh`, `.mgz`, `.mgh.gz`, case ignored): what [`crate::Format::detect`]
/// goes by (an MGH file has no magic bytes).
#[must_use]
pub fn has_mgh_name(path: &Path) -> bool {
    name_kind(path).is_some()
}

fn check_gzip_magic(name: &Path, head: &[u8]) -> Result<()> {
    if head.starts_with(&GZIP_MAGIC) {
        return Ok(());
    }
    Err(Error::new(
        name,
        ErrorKind::BadMagic {
            format: "gzip-compressed MGH (.mgz)",
            detail: "it does not start with gzip's magic bytes 1f 8b (a plain MGH file is named .mgh)".to_string(),
        },
    ))
}

/// The fixed fields of the header.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Header {
    version: i32,
    /// width, height, depth, nframes.
    dims: [i32; 4],
    type_code: i32,
    good_ras_flag: i16,
    delta: [f32; 3],
    /// x_ras, y_ras, z_ras: the columns of Mdc.
    mdc: [[f32; 3]; 3],
    c_ras: [f32; 3],
}

impl Header {
    fn parse(b: &[u8; HEADER_BYTES]) -> Self {
        let i32_at = |o: usize| i32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let f32_at = |o: usize| f32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let f32s = |o: usize| -> [f32; 3] { std::array::from_fn(|k| f32_at(o + 4 * k)) };
        Self {
            version: i32_at(0),
            dims: std::array::from_fn(|k| i32_at(4 + 4 * k)),
            type_code: i32_at(20),
            good_ras_flag: i16::from_be_bytes([b[28], b[29]]),
            delta: f32s(30),
            mdc: std::array::from_fn(|c| f32s(42 + 12 * c)),
            c_ras: f32s(78),
        }
    }

    fn to_bytes(self) -> [u8; HEADER_BYTES] {
        let mut b = [0u8; HEADER_BYTES];
        let mut put = |o: usize, bytes: &[u8]| b[o..o + bytes.len()].copy_from_slice(bytes);
        put(0, &self.version.to_be_bytes());
        for (k, d) in self.dims.iter().enumerate() {
            put(4 + 4 * k, &d.to_be_bytes());
        }
        put(20, &self.type_code.to_be_bytes());
        put(28, &self.good_ras_flag.to_be_bytes());
        let floats = self.delta.iter().chain(self.mdc.iter().flatten()).chain(self.c_ras.iter());
        for (k, x) in floats.enumerate() {
            put(30 + 4 * k, &x.to_be_bytes());
        }
        b
    }

    /// The spatial sizes and the frame count, each checked to be at least 1.
    fn sizes(&self, name: &Path) -> Result<([usize; 3], usize)> {
        let [w, h, d, f] = self.dims;
        if self.dims.iter().any(|&n| n < 1) {
            let what = if self.dims.contains(&0) { "zero" } else { "negative" };
            return Err(Error::invalid(
                name,
                format!(
                    "a dimension is {what}: width {w}, height {h}, depth {d}, frames {f} (each must be at least 1)"
                ),
            ));
        }
        Ok(([w as usize, h as usize, d as usize], f as usize))
    }

    /// The stored type of the type code, or an error naming the code.
    fn stored_type(&self, name: &Path) -> Result<StoredType> {
        let code = self.type_code;
        if let Some(&(_, t, _)) = TYPE_CODES.iter().find(|(c, _, _)| *c == code) {
            return Ok(t);
        }
        let what = match code {
            2 => "MRI_LONG",
            5 => "MRI_BITMAP",
            6 => "MRI_TENSOR",
            7 => "MRI_FLOAT_COMPLEX",
            8 => "MRI_DOUBLE_COMPLEX",
            9 => "MRI_RGB",
            _ => "not an MGH type code",
        };
        Err(Error::unsupported(
            name,
            format!(
                "MGH data type {code} ({what}); readable: 0 UCHAR (u8), 1 INT (i32), 3 FLOAT (f32), 4 SHORT (i16), \
                 10 USHRT (u16)"
            ),
        ))
    }

    /// `ras_from_index` (module docs, "Geometry"), and the warning when the file holds no orientation.
    fn ras_from_index(&self, dims: [usize; 3]) -> (Transform<Ras, Index>, Option<String>) {
        let (delta, mdc, c_ras, warning) = if self.good_ras_flag > 0 {
            (self.delta.map(f64::from), self.mdc.map(|c| c.map(f64::from)), self.c_ras.map(f64::from), None)
        } else {
            let warning = format!(
                "goodRASflag is {}: the file holds no orientation; FreeSurfer's coronal default is assumed, as its \
                 mghRead does: LIA, 1 mm voxels, the centre voxel at RAS (0, 0, 0)",
                self.good_ras_flag
            );
            ([1.0; 3], CORONAL_MDC, [0.0; 3], Some(warning))
        };
        let linear = Matrix3::from_fn(|r, c| mdc[c][r] * delta[c]);
        let centre_from_origin = linear * Vector3::from(dims.map(|n| n as f64 / 2.0));
        let p0 = std::array::from_fn(|r| c_ras[r] - centre_from_origin[r]);
        (Transform::from_linear_translation(linear, p0), warning)
    }
}

fn read_source<S: Source>(name: &Path, src: &mut S, extent: Extent, opts: &mut LoadOptions) -> Result<Volume> {
    const WHAT: &str = "the 284-byte MGH header";
    let mut head = [0u8; HEADER_BYTES];
    let got = crate::files::read_up_to(src, &mut head).map_err(|e| read_error(name, e, WHAT))?;
    let gzip_hint =
        if head[..got].starts_with(&GZIP_MAGIC) { " (the file is gzip-compressed: name it .mgz)" } else { "" };
    let h = Header::parse(&head);
    if got < HEADER_BYTES || h.version != 1 {
        let detail = if got < HEADER_BYTES {
            format!("the file ends inside {WHAT}, after {got} bytes{gzip_hint}")
        } else {
            format!("version {}, expected 1{gzip_hint}", h.version)
        };
        return Err(if got < HEADER_BYTES && gzip_hint.is_empty() {
            Error::truncated(name, detail)
        } else {
            Error::new(name, ErrorKind::BadMagic { format: "MGH", detail })
        });
    }
    let (dims, frames) = h.sizes(name)?;
    let stored = h.stored_type(name)?;
    let frame = match (opts.frame, frames) {
        (None, 1) => 0,
        (None, frames) => return Err(Error::new(name, ErrorKind::FrameRequired { frames })),
        (Some(t), n) if t >= n => {
            return Err(Error::invalid(name, format!("frame {t} is out of range: the file has {n} frame(s)")));
        }
        (Some(t), _) => t,
    };
    // The output (i32 → f32) is never wider than the stored samples.
    let n = volume::check_allocation(name, dims, stored.bytes(), opts.max_voxel_bytes)?;
    let frame_bytes = n * stored.bytes(); // under max_voxel_bytes, checked above
    let skip = frame as u128 * frame_bytes as u128;
    let end = HEADER_BYTES as u128 + skip + frame_bytes as u128;
    let type_name = TYPE_CODES.iter().find(|(c, _, _)| *c == h.type_code).map_or("", |(_, _, t)| *t);
    let detail = format!("{}×{}×{} {type_name} samples of frame {frame}", dims[0], dims[1], dims[2]);
    match extent {
        Extent::Exact(len) if end > u128::from(len) => {
            return Err(Error::truncated(name, format!("the {detail} end at byte {end} but the file has {len} bytes")));
        }
        Extent::Gzip(len) if end > u128::from(len) * u128::from(MAX_DEFLATE_RATIO) => {
            return Err(Error::truncated(
                name,
                format!(
                    "the {detail} end at byte {end} but a {len}-byte gzip stream inflates to at most \
                     {MAX_DEFLATE_RATIO} times that"
                ),
            ));
        }
        _ => {}
    }
    let skip = u64::try_from(skip).unwrap_or(u64::MAX); // below `end`, which the extent bounds
    let seeks = src.seek_forward(skip).map_err(|e| Error::io(name, e))?;
    let total = frame_bytes as u64 + if seeks { 0 } else { skip };
    let mut done = 0u64;
    opts.report(name, "reading", done, total)?;
    let mut scratch = vec![0u8; frame_bytes.min(CHUNK_BYTES)];
    if !seeks {
        let mut left = skip;
        while left > 0 {
            let k = usize::try_from(left).unwrap_or(usize::MAX).min(CHUNK_BYTES);
            fill(name, src, &mut scratch[..k], "the frames before the one chosen")?;
            left -= k as u64;
            done += k as u64;
            opts.report(name, "reading", done, total)?;
        }
    }
    let mut data = VoxelData::try_empty(name, stored.unscaled(), n, "the voxel samples")?;
    let mut left = frame_bytes;
    while left > 0 {
        let chunk = &mut scratch[..left.min(CHUNK_BYTES)];
        fill(name, src, chunk, "the voxel data")?;
        sample::with_stored_type!(stored, T => data.extend_from(sample::decode::<T>(chunk, true)));
        left -= chunk.len();
        done += chunk.len() as u64;
        opts.report(name, "reading", done, total)?;
    }
    let (ras_from_index, warning) = h.ras_from_index(dims);
    let mut volume = Volume::new(name, dims, data, lps_from_ras() * ras_from_index, GeometrySource::Mgh)?;
    volume.metadata.warnings.extend(warning);
    Ok(volume)
}

/// The header [`write()`] writes for `volume`, after checking the volume and that its geometry survives MGH's f32
/// fields (the reader must find the same, valid, grid).
fn header_of(name: &Path, volume: &Volume) -> Result<Header> {
    let n = volume::checked_voxel_count(name, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(name, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    if !volume.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(name, "the voxel-to-patient matrix is singular or not finite"));
    }
    let [w, h, d] = volume.dims.map(|n| i32::try_from(n).unwrap_or(-1));
    if [w, h, d].contains(&-1) {
        return Err(Error::unsupported(name, format!("dims {:?} do not fit MGH's 32-bit sizes", volume.dims)));
    }
    let ras_from_index = ras_from_lps() * volume.lps_from_index;
    let linear = ras_from_index.linear();
    let delta: [f64; 3] = std::array::from_fn(|c| linear.column(c).norm());
    let c_ras = ras_from_index.apply_point(Point3::new(w as f64 / 2.0, h as f64 / 2.0, d as f64 / 2.0)).coords();
    let type_code = match volume.sample_type() {
        SampleType::U8 => 0,
        SampleType::I16 => 4,
        SampleType::U16 => 10,
        SampleType::F32 => 3,
    };
    let header = Header {
        version: 1,
        dims: [w, h, d, 1],
        type_code,
        good_ras_flag: 1,
        delta: delta.map(|x| x as f32),
        mdc: std::array::from_fn(|c| std::array::from_fn(|r| (linear[(r, c)] / delta[c]) as f32)),
        c_ras: c_ras.map(|x| x as f32),
    };
    if !header.ras_from_index(volume.dims).0.is_valid_affine() {
        return Err(Error::unsupported(
            name,
            format!(
                "the geometry does not fit MGH's float32 fields: voxel sizes {delta:?} mm, centre voxel at RAS \
                 {c_ras:?} mm"
            ),
        ));
    }
    Ok(header)
}

/// Writes the header, the samples big-endian a bounded chunk at a time, and the zero scan parameters.
fn write_to(w: &mut dyn Write, header: &Header, data: &VoxelData, gzip: bool) -> io::Result<()> {
    if gzip {
        let mut enc = ParGzWriter::new(w, Compression::default());
        write_plain(&mut enc, header, data)?;
        enc.finish()?;
        Ok(())
    } else {
        write_plain(w, header, data)
    }
}

fn write_plain(w: &mut dyn Write, header: &Header, data: &VoxelData) -> io::Result<()> {
    const CHUNK_SAMPLES: usize = 1 << 16;
    fn each<T: Copy, const N: usize>(w: &mut dyn Write, v: &[T], be: impl Fn(T) -> [u8; N]) -> io::Result<()> {
        let mut buf = Vec::with_capacity(CHUNK_SAMPLES.min(v.len()) * N);
        for chunk in v.chunks(CHUNK_SAMPLES) {
            buf.clear();
            buf.extend(chunk.iter().flat_map(|&x| be(x)));
            w.write_all(&buf)?;
        }
        Ok(())
    }
    w.write_all(&header.to_bytes())?;
    match data {
        VoxelData::U8(v) => w.write_all(v)?,
        VoxelData::I16(v) => each(w, v, i16::to_be_bytes)?,
        VoxelData::U16(v) => each(w, v, u16::to_be_bytes)?,
        VoxelData::F32(v) => each(w, v, f32::to_be_bytes)?,
    }
    w.write_all(&[0u8; SCAN_PARAMETER_BYTES])
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "the expected values are exact in binary floating point")]
mod tests {
    use super::*;

    #[test]
    fn names_decide_compression() {
        assert_eq!(name_kind(Path::new("a/orig.mgz")), Some(NameKind::Gzip));
        assert_eq!(name_kind(Path::new("T1.MGH.GZ")), Some(NameKind::Gzip));
        assert_eq!(name_kind(Path::new("brain.Mgh")), Some(NameKind::Plain));
        assert_eq!(name_kind(Path::new("brain.nii.gz")), None);
        assert_eq!(name_kind(Path::new("mgz")), None);
    }

    /// The header's fields sit at the offsets of FreeSurfer's layout and read back as written.
    #[test]
    fn header_fields_round_trip_at_their_offsets() {
        let h = Header {
            version: 1,
            dims: [5, 4, 3, 2],
            type_code: 10,
            good_ras_flag: -1,
            delta: [0.5, 1.5, 2.5],
            mdc: [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]],
            c_ras: [-1.0, -2.0, -3.0],
        };
        let b = h.to_bytes();
        assert_eq!(b[0..4], [0, 0, 0, 1]);
        assert_eq!(b[16..20], [0, 0, 0, 2], "nframes");
        assert_eq!(b[28..30], [0xff, 0xff], "goodRASflag");
        assert_eq!(b[42..46], 1f32.to_be_bytes(), "x_r");
        assert_eq!(b[54..58], 4f32.to_be_bytes(), "y_r");
        assert_eq!(b[86..90], (-3f32).to_be_bytes(), "c_s");
        assert!(b[90..].iter().all(|&x| x == 0));
        assert_eq!(Header::parse(&b), h);
    }

    /// Without an orientation, FreeSurfer's coronal default: index (N/2) at RAS 0, +i to the left, +j inferior,
    /// +k anterior, 1 mm.
    #[test]
    fn no_orientation_is_freesurfers_coronal_default() {
        let mut b = [0u8; HEADER_BYTES];
        b[3] = 1;
        let mut h = Header::parse(&b);
        h.delta = [3.0; 3];
        let (ras_from_index, warning) = h.ras_from_index([4, 6, 8]);
        assert!(warning.is_some_and(|w| w.contains("goodRASflag is 0")));
        let at = |i: f64, j: f64, k: f64| ras_from_index.apply_point(Point3::new(i, j, k)).coords();
        assert_eq!(at(2.0, 3.0, 4.0), [0.0; 3]);
        assert_eq!(at(3.0, 3.0, 4.0), [-1.0, 0.0, 0.0]);
        assert_eq!(at(2.0, 4.0, 4.0), [0.0, 0.0, -1.0]);
        assert_eq!(at(2.0, 3.0, 5.0), [0.0, 1.0, 0.0]);
    }
}
