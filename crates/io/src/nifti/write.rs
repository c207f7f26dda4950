//! The NIfTI writer: NIfTI-1 (or NIfTI-2 with [`WriteOptions`]), gzip by the name, the volume's sample type and
//! both transforms (see [`super`], "Writing").

use std::io::{self, Write};
use std::path::Path;

use crate::pargz::ParGzWriter;
use flate2::Compression;

use super::geometry::qform_from_linear;
use super::header::{NIFTI1_HEADER_BYTES, NIFTI1_MAGIC, NIFTI2_HEADER_BYTES, NIFTI2_MAGIC};
use super::samples::datatype_code;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Ras, Transform, ras_from_lps};
use crate::volume::{self, Volume, VoxelData};

/// Header plus the 4-byte extension flag: where our writer puts the samples.
pub(super) const NIFTI1_VOX_OFFSET: usize = NIFTI1_HEADER_BYTES + 4;
const NIFTI2_VOX_OFFSET: usize = NIFTI2_HEADER_BYTES + 4;

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
pub(super) fn write_file(
    path: &Path,
    header: &[u8],
    samples: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<()> {
    let gz = path.file_name().is_some_and(|n| n.to_string_lossy().to_ascii_lowercase().ends_with(".gz"));
    crate::write_atomic(path, |w| {
        if gz {
            let mut enc = ParGzWriter::new(w, Compression::default());
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

/// Writes the samples little-endian, a bounded chunk at a time (no full-size byte copy).
fn write_samples(w: &mut dyn Write, data: &VoxelData) -> io::Result<()> {
    data.try_for_each_le_chunk(|b| w.write_all(b))
}

/// Little-endian header fields written at fixed offsets.
struct Put<'a>(&'a mut [u8]);

impl Put<'_> {
    pub(super) fn bytes(&mut self, off: usize, b: &[u8]) {
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
    pub(super) srow: [[f64; 4]; 3],
    pub(super) quatern_bcd: [f64; 3],
    pub(super) qoffset: [f64; 3],
    pub(super) pixdim: [f64; 8],
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
    let what = Nifti1Content {
        type_code: datatype_code(volume.sample_type()),
        descrip: descrip(volume),
        shape: Shape::Scalar,
    };
    nifti1_header_for(path, volume.dims, &volume.lps_from_index, &what)
}

/// What a NIfTI-1 header says besides the grid: the sample type, the description, and what a voxel holds.
pub(super) struct Nifti1Content {
    /// Datatype code and bitpix.
    pub(super) type_code: (i16, i16),
    pub(super) descrip: Vec<u8>,
    pub(super) shape: Shape,
}

/// What a voxel of a NIfTI-1 file holds, and so its `dim` and `intent_code`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Shape {
    /// One sample: dim = [3, X, Y, Z, 1, 1, 1, 1].
    Scalar,
    /// A vector of `components` with `intent_code`, as ITK writes one: dim = [5, X, Y, Z, 1, components, 1, 1].
    Vector { intent_code: i16, components: i16 },
    /// `frames` samples along the fourth axis, as nibabel writes an (X, Y, Z, frames) array: dim =
    /// [4, X, Y, Z, frames, 1, 1, 1], with `intent_code` (0: none; FNIRT's deformation fields carry 2006).
    Frames { frames: i16, intent_code: i16 },
}

pub(super) fn nifti1_header_for(
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
    let dim = match what.shape {
        Shape::Scalar => [3, nx, ny, nz, 1, 1, 1, 1],
        Shape::Vector { intent_code, components } => {
            p.i16(68, intent_code);
            [5, nx, ny, nz, 1, components, 1, 1]
        }
        Shape::Frames { frames, intent_code } => {
            p.i16(68, intent_code);
            [4, nx, ny, nz, frames, 1, 1, 1]
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
    let (datatype, bitpix) = datatype_code(volume.sample_type());
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
