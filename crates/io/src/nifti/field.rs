//! Displacement fields as ITK, ANTs and 3D Slicer store them in NIfTI (see [`super`], "Displacement fields"):
//! `NIFTI_INTENT_DISPVECT` (1006) with RAS vectors in the file, as ITK ≥ 5.3 and Slicer read and write it, and
//! `NIFTI_INTENT_VECTOR` (1007) with LPS vectors, what ITK's writer makes of any vector image and so what ANTs'
//! `*Warp.nii.gz` files are. Inside, the vectors are always LPS.

use std::io::{self, Read, Write};
use std::path::Path;

use flate2::read::MultiGzDecoder;

use super::afni_extension::{WARP_LABELS, append_warp_extension, are_warp_labels, brick_labels, read_afni_extension};
use super::geometry::lps_from_index;
use super::header::{pair_error, read_header};
use super::layout::{Span, data_span, grid, stored_type};
use super::samples::{datatype_code, scaling, stream_chunks};
use super::source::{Extent, GZIP_MAGIC, Reporter, Source, open_file};
use super::write::{Nifti1Content, Shape, nifti1_header_for, write_file};
use crate::displacement::check::first_non_finite;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::options::LoadOptions;
use crate::sample::{self, Stored, StoredType};
use crate::volume::{self, GeometrySource, SampleType};

/// `NIFTI_INTENT_DISPVECT` (nifti1.h): each voxel holds a displacement vector.
pub const NIFTI_INTENT_DISPVECT: i16 = 1006;

/// `NIFTI_INTENT_VECTOR` (nifti1.h): each voxel holds a vector; ITK writes every vector image with it.
pub const NIFTI_INTENT_VECTOR: i16 = 1007;

/// The sign that takes a vector component between LPS (inside) and RAS (in the file), either way.
const LPS_RAS_SIGN: [f32; 3] = [-1.0, -1.0, 1.0];

/// The two NIfTI conventions for a displacement field: which intent the header carries, and so in which frame ITK's
/// reader takes the vectors.
///
/// ITK 5.4's `NiftiImageIO` negates the first two components of a `DISPVECT` image on read and on write
/// (`m_ConvertRASDisplacementVectors`, on by default) and leaves a `VECTOR` image's components alone. Its writer gives
/// a vector image intent `VECTOR` unless the image's metadata asks for 1006, which ANTs' writers do not: checked with
/// the `itk` 5.4.7 wheel (`itk.imwrite` of an `Image[Vector[F,3],3]` gives intent 1007, dim `[5, X, Y, Z, 1, 3, 1, 1]`
/// and the components as they were; a 1006 copy of the same bytes reads back with x and y negated).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NiftiVectorIntent {
    /// Intent 1006, RAS vectors in the file: ITK ≥ 5.3 and 3D Slicer (`--format itk`).
    DispvectRas,
    /// Intent 1007, LPS vectors in the file: ANTs' `*Warp.nii.gz`, and ITK's default for any vector image
    /// (`--format ants`).
    VectorLps,
}

impl NiftiVectorIntent {
    /// The header's `intent_code`.
    #[must_use]
    pub const fn intent_code(self) -> i16 {
        match self {
            Self::DispvectRas => NIFTI_INTENT_DISPVECT,
            Self::VectorLps => NIFTI_INTENT_VECTOR,
        }
    }

    /// The signs that take a component between LPS (inside) and the file's frame, either way.
    const fn signs(self) -> [f32; 3] {
        match self {
            Self::DispvectRas => LPS_RAS_SIGN,
            Self::VectorLps => [1.0, 1.0, 1.0],
        }
    }

    const fn frame(self) -> &'static str {
        match self {
            Self::DispvectRas => "RAS",
            Self::VectorLps => "LPS",
        }
    }
}

/// What a NIfTI displacement field's header says its vectors are ([`read_vector_field`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NiftiFieldKind {
    /// A vector intent, 1006 or 1007 ([`NiftiVectorIntent`]).
    Intent(NiftiVectorIntent),
    /// No vector intent, but AFNI's extension labels the three components `x_delta`, `y_delta`, `z_delta`: a
    /// `3dQwarp` warp saved as NIfTI, its vectors in DICOM order, LPS ([`super::afni_extension`]).
    AfniWarp,
}

/// A displacement field read by [`read_displacement_field`]: one vector per voxel of a grid.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacementField {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    pub lps_from_index: Transform<Lps, Index>,
    pub geometry_source: GeometrySource,
    /// The displacement at each voxel centre in LPS mm, i fastest (as [`crate::Volume::data`]).
    pub displacements_lps: Vec<[f32; 3]>,
}

/// Writes a displacement field as NIfTI-1 (`.nii`, or gzip when the name ends in `.gz`), atomically: float32,
/// `dim = [5, X, Y, Z, 1, 3, 1, 1]`, `intent_code` 1006 (`NIFTI_INTENT_DISPVECT`), the grid's sform and qform as
/// [`super::write()`] writes them, and the vectors in **RAS** (the first two components of each LPS vector negated), the
/// component planes one after the other (all x, then all y, then all z). See the module docs, "Displacement fields".
pub fn write_displacement_field(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    write_vector_field(path, dims, lps_from_index, displacements_lps, NiftiVectorIntent::DispvectRas)
}

/// Writes a displacement field as NIfTI-1 with either intent ([`NiftiVectorIntent`]), atomically: as
/// [`write_displacement_field`] for [`NiftiVectorIntent::DispvectRas`]; for [`NiftiVectorIntent::VectorLps`]
/// intent 1007 and the LPS vectors as they are (ANTs' layout). Non-finite vectors are refused.
pub fn write_vector_field(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
    intent: NiftiVectorIntent,
) -> Result<()> {
    crate::displacement::check::check_field_to_write(path, dims, lps_from_index, displacements_lps)?;
    let what = Nifti1Content {
        type_code: datatype_code(SampleType::F32),
        descrip: format!("warpbench displacement field, {} mm", intent.frame()).into_bytes(),
        shape: Shape::Vector { intent_code: intent.intent_code(), components: 3 },
    };
    let header = nifti1_header_for(path, dims, lps_from_index, &what)?;
    write_file(path, &header, |w| write_planes(w, displacements_lps, intent.signs()))
}

/// Writes a pull-back as AFNI's `3dQwarp` saves a warp named `.nii` or `.nii.gz` (gzip by the name), atomically:
/// float32, dim = [5, X, Y, Z, 1, 3, 1, 1], no intent, the grid's sform and qform (scanner: AFNI's `+orig` view), the
/// LPS vectors as they are (AFNI's DICOM order) one component plane after another, and AFNI's extension naming the
/// sub-bricks `x_delta`, `y_delta`, `z_delta` ([`super::afni_extension`]). `3dNwarpApply -nwarp PATH` applies it;
/// non-finite vectors are refused.
pub fn write_afni_warp(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    crate::displacement::check::check_field_to_write(path, dims, lps_from_index, displacements_lps)?;
    let what = Nifti1Content {
        type_code: datatype_code(SampleType::F32),
        descrip: b"warpbench warp for AFNI, LPS (DICOM) mm".to_vec(),
        shape: Shape::Vector { intent_code: 0, components: 3 },
    };
    let mut header = nifti1_header_for(path, dims, lps_from_index, &what)?;
    append_warp_extension(&mut header, dims);
    write_file(path, &header, |w| write_planes(w, displacements_lps, [1.0; 3]))
}

/// Writes Learn2Reg's NIfTI form of a field ([`crate::learn2reg`]), atomically: float32, dim = [4, X, Y, Z, 3, 1, 1,
/// 1] (the three components as frames, as nibabel writes an (X, Y, Z, 3) array), no intent, the grid's sform and
/// qform, and `vectors` as they are (the challenge's voxel steps). Non-finite vectors are refused.
pub fn write_frame_vectors(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    vectors: &[[f32; 3]],
    descrip: &str,
) -> Result<()> {
    write_frames_with_intent(path, (dims, lps_from_index), vectors, descrip, 0)
}

/// [`write_frame_vectors`] with `intent_code` in the header (FNIRT's deformation fields: 2006).
pub(super) fn write_frames_with_intent(
    path: &Path,
    (dims, lps_from_index): ([usize; 3], &Transform<Lps, Index>),
    vectors: &[[f32; 3]],
    descrip: &str,
    intent_code: i16,
) -> Result<()> {
    crate::displacement::check::check_field_to_write(path, dims, lps_from_index, vectors)?;
    let what = Nifti1Content {
        type_code: datatype_code(SampleType::F32),
        descrip: descrip.bytes().take(79).collect(),
        shape: Shape::Frames { frames: 3, intent_code },
    };
    let header = nifti1_header_for(path, dims, lps_from_index, &what)?;
    write_file(path, &header, |w| write_planes(w, vectors, [1.0; 3]))
}

/// The component planes one after the other (all x, then all y, then all z), each component times its sign.
fn write_planes(w: &mut dyn Write, vectors: &[[f32; 3]], signs: [f32; 3]) -> io::Result<()> {
    let mut buf = Vec::with_capacity(64 << 10);
    for (c, sign) in signs.into_iter().enumerate() {
        for chunk in vectors.chunks(16 << 10) {
            buf.clear();
            for d in chunk {
                buf.extend_from_slice(&(sign * d[c]).to_le_bytes());
            }
            w.write_all(&buf)?;
        }
    }
    Ok(())
}

/// Reads a displacement field written by [`write_displacement_field`] or by ITK, ANTs or Slicer: NIfTI-1 or -2,
/// intent 1006, shape [X, Y, Z, 1, 3], float32 or float64, RAS vectors (returned in LPS). Errors name the file.
pub fn read_displacement_field(path: &Path) -> Result<DisplacementField> {
    let (mut src, extent) = open_file(path)?;
    read_field_source(path, &mut src, extent, false).map(|(field, _)| field)
}

/// [`read_displacement_field`] from memory (gzip detected by the magic bytes); `name` is used in errors.
pub fn read_displacement_field_bytes(name: &Path, bytes: &[u8]) -> Result<DisplacementField> {
    read_vector_field_bytes_with(name, bytes, false).map(|(field, _)| field)
}

/// Reads a displacement field of either intent ([`NiftiVectorIntent`]): 1006 with RAS vectors (ITK ≥ 5.3, Slicer,
/// `warpbench field --format itk`) or 1007 with LPS vectors (ANTs, `--format ants`), shape [X, Y, Z, 1, 3], float32
/// or float64; the vectors are returned in LPS, with the intent found. Non-finite vectors are refused, naming the
/// voxel.
pub fn read_vector_field(path: &Path) -> Result<(DisplacementField, NiftiFieldKind)> {
    let (mut src, extent) = open_file(path)?;
    read_field_source(path, &mut src, extent, true)
}

/// [`read_vector_field`] from memory (gzip detected by the magic bytes); `name` is used in errors.
pub fn read_vector_field_bytes(name: &Path, bytes: &[u8]) -> Result<(DisplacementField, NiftiFieldKind)> {
    read_vector_field_bytes_with(name, bytes, true)
}

fn read_vector_field_bytes_with(
    name: &Path,
    bytes: &[u8],
    vector_too: bool,
) -> Result<(DisplacementField, NiftiFieldKind)> {
    if bytes.starts_with(&GZIP_MAGIC) {
        read_field_source(name, &mut MultiGzDecoder::new(bytes), Extent::Gzip(bytes.len() as u64), vector_too)
    } else {
        let mut src = bytes;
        read_field_source(name, &mut src, Extent::Exact(bytes.len() as u64), vector_too)
    }
}

/// Reads the field; `vector_too` accepts intent 1007 (LPS vectors) and AFNI's warps besides 1006.
fn read_field_source<S: Source>(
    path: &Path,
    src: &mut S,
    extent: Extent,
    vector_too: bool,
) -> Result<(DisplacementField, NiftiFieldKind)> {
    let h = read_header(path, src)?;
    if h.pair {
        return Err(pair_error(path, "a displacement field is read from one .nii or .nii.gz file"));
    }
    let vector_dims = h.dim[0] == 5 && h.dim[4] == 1 && h.dim[5] == 3;
    let intent_given = [NIFTI_INTENT_DISPVECT, NIFTI_INTENT_VECTOR].map(i32::from).contains(&h.intent_code);
    let mut consumed = 0;
    if vector_too && vector_dims && !intent_given {
        let (afni, n) = read_afni_extension(path, src, &h)?;
        consumed = n;
        match afni.as_deref().map(brick_labels) {
            Some(Some(labels)) if are_warp_labels(&labels) => {
                let dims = field_dims(path, &h)?;
                let (lps_from_index, geometry_source, _) = lps_from_index(path, &h, dims)?;
                let displacements_lps = read_planes(path, src, extent, &h, dims, [1.0; 3], consumed)?;
                let field = DisplacementField { dims, lps_from_index, geometry_source, displacements_lps };
                return Ok((field, NiftiFieldKind::AfniWarp));
            }
            Some(Some(labels)) => {
                return Err(Error::invalid(
                    path,
                    format!(
                        "an AFNI dataset of three sub-bricks labelled {labels:?}, not a 3dQwarp warp (whose are \
                         {WARP_LABELS:?}): not a displacement field"
                    ),
                ));
            }
            _ => {}
        }
    }
    let intent = match h.intent_code {
        c if c == i32::from(NIFTI_INTENT_DISPVECT) => NiftiVectorIntent::DispvectRas,
        c if c == i32::from(NIFTI_INTENT_VECTOR) && vector_too => NiftiVectorIntent::VectorLps,
        c if vector_too && h.dim[0] == 4 && h.dim[4] == 3 => {
            return Err(Error::invalid(
                path,
                format!(
                    "intent_code is {c} and dim = {:?}: an (X, Y, Z, 3) array without a vector intent, as \
                     Learn2Reg's fields are (steps in voxels, not mm; docs/formats.md). If it is one, read it as \
                     Learn2Reg's against its fixed and moving volumes (command line: --field-format learn2reg, or \
                     --initial-field-format learn2reg under the landmarks; \
                     Python: read_field(path, fixed=..., moving=..., learn2reg=True); window: tick Learn2Reg steps \
                     in voxels)",
                    h.dim
                ),
            ));
        }
        c if vector_too => {
            return Err(Error::invalid(
                path,
                format!(
                    "intent_code is {c}, neither NIFTI_INTENT_DISPVECT (1006, ITK and Slicer) nor \
                     NIFTI_INTENT_VECTOR (1007, ANTs), and no AFNI extension labels it a 3dQwarp warp (x_delta, \
                     y_delta, z_delta): not a displacement field"
                ),
            ));
        }
        c => {
            return Err(Error::invalid(
                path,
                format!("intent_code is {c}, not NIFTI_INTENT_DISPVECT (1006): not a displacement field"),
            ));
        }
    };
    if h.dim[0] != 5 || h.dim[4] != 1 || h.dim[5] != 3 || h.dim[1..4].iter().any(|&d| d < 1) {
        return Err(Error::invalid(
            path,
            format!("dim = {:?}; a 3-D displacement field has dim = [5, X, Y, Z, 1, 3, …]", h.dim),
        ));
    }
    let dims = field_dims(path, &h)?;
    let (lps_from_index, geometry_source, _) = lps_from_index(path, &h, dims)?;
    let displacements_lps = read_planes(path, src, extent, &h, dims, intent.signs(), consumed)?;
    Ok((DisplacementField { dims, lps_from_index, geometry_source, displacements_lps }, NiftiFieldKind::Intent(intent)))
}

/// Reads Learn2Reg's NIfTI form of a field ([`crate::learn2reg`]): dim = [4, X, Y, Z, 3], float32 or float64,
/// unscaled, the three components as frames. Returns the grid's dims and the vectors as they are, i fastest. The
/// header's geometry is not read: the challenge's files carry the fixed image's, the identity or none, and its
/// evaluation ignores it. Errors name the file: another shape (an ITK or ANTs field in mm is named as such), a
/// vector that is not finite.
pub fn read_frame_vectors(path: &Path) -> Result<([usize; 3], Vec<[f32; 3]>)> {
    let (mut src, extent) = open_file(path)?;
    read_frames_source(path, &mut src, extent)
}

/// [`read_frame_vectors`] from memory (gzip detected by the magic bytes); `name` is used in errors.
pub fn read_frame_vectors_bytes(name: &Path, bytes: &[u8]) -> Result<([usize; 3], Vec<[f32; 3]>)> {
    if bytes.starts_with(&GZIP_MAGIC) {
        read_frames_source(name, &mut MultiGzDecoder::new(bytes), Extent::Gzip(bytes.len() as u64))
    } else {
        let mut src = bytes;
        read_frames_source(name, &mut src, Extent::Exact(bytes.len() as u64))
    }
}

fn read_frames_source<S: Source>(path: &Path, src: &mut S, extent: Extent) -> Result<([usize; 3], Vec<[f32; 3]>)> {
    let h = read_header(path, src)?;
    if h.pair {
        return Err(pair_error(path, "a field of frames is read from one .nii or .nii.gz file"));
    }
    if [NIFTI_INTENT_DISPVECT, NIFTI_INTENT_VECTOR].iter().any(|&c| i32::from(c) == h.intent_code) {
        return Err(Error::invalid(
            path,
            format!(
                "intent_code {}: an ITK or ANTs displacement field in mm, not Learn2Reg's steps in voxels; read it \
                 as a field of its own flavour",
                h.intent_code
            ),
        ));
    }
    if h.dim[0] != 4 || h.dim[4] != 3 || h.dim[1..4].iter().any(|&d| d < 1) {
        return Err(Error::invalid(
            path,
            format!("dim = {:?}; Learn2Reg's NIfTI field is an (X, Y, Z, 3) array, dim = [4, X, Y, Z, 3, …]", h.dim),
        ));
    }
    let dims = field_dims(path, &h)?;
    let vectors = read_planes(path, src, extent, &h, dims, [1.0; 3], 0)?;
    Ok((dims, vectors))
}

/// The field's grid from `h`, once its datatype (float32 or float64) and its lack of scaling are checked.
pub(super) fn field_dims(path: &Path, h: &super::header::Header) -> Result<[usize; 3]> {
    let grid = grid(path, h)?;
    let datatype = stored_type(path, h)?;
    if !matches!(datatype, StoredType::F32 | StoredType::F64) {
        return Err(Error::unsupported(
            path,
            format!("displacement field of datatype {}; float32 and float64 are read", h.datatype),
        ));
    }
    if scaling(path, h)?.is_some() {
        return Err(Error::unsupported(
            path,
            format!("a scaled displacement field (scl_slope {}, scl_inter {})", h.scl_slope, h.scl_inter),
        ));
    }
    Ok([grid[1], grid[2], grid[3]])
}

/// Reads the three component planes after the header (`consumed` bytes after it already read), each times its sign;
/// refuses a vector that is not finite.
pub(super) fn read_planes<S: Source>(
    path: &Path,
    src: &mut S,
    extent: Extent,
    h: &super::header::Header,
    dims: [usize; 3],
    signs: [f32; 3],
    consumed: u64,
) -> Result<Vec<[f32; 3]>> {
    let datatype = stored_type(path, h)?;
    // The output is 12 bytes a voxel; a stored plane is at most 8 bytes a voxel, so both fit once this passes.
    let n = volume::check_allocation(path, dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let plane_bytes = n * datatype.bytes();
    let span = Span {
        skip: 0,
        bytes: 3 * plane_bytes as u128,
        what: "the displacement field",
        detail: format!("dims {dims:?}, 3 components"),
    };
    let vox_offset = data_span(path, h, extent, &span)?;
    let mut opts = LoadOptions::new();
    let skip = vox_offset - h.version.header_bytes() as u64 - consumed;
    if !src.seek_forward(skip).map_err(|e| Error::io(path, e))? {
        io::copy(&mut src.by_ref().take(skip), &mut io::sink()).map_err(|e| Error::io(path, e))?;
    }
    let mut progress = Reporter { path, opts: &mut opts, done: 0, total: 3 * plane_bytes as u64 };
    let mut displacements_lps = volume::try_with_capacity(path, n, "the displacement vectors")?;
    displacements_lps.resize(n, [0.0f32; 3]);
    for (c, sign) in signs.into_iter().enumerate() {
        let mut plane: Vec<f32> = volume::try_with_capacity(path, n, "the voxel samples")?;
        sample::with_stored_type!(datatype, T => stream_chunks(src, plane_bytes, &mut progress, |chunk| {
            plane.extend(sample::decode::<T>(chunk, h.big_endian).map(T::as_f32));
        }))?;
        for (d, v) in displacements_lps.iter_mut().zip(plane) {
            d[c] = sign * v;
        }
    }
    if let Some(ijk) = first_non_finite(dims, &displacements_lps) {
        return Err(Error::invalid(path, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    Ok(displacements_lps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use flate2::Compression;
    use flate2::write::GzEncoder;
    use nalgebra::Matrix3;
    use std::io::Write;

    use super::super::read_bytes;
    use super::super::write::{NIFTI1_VOX_OFFSET, write};
    use crate::ErrorKind;
    use crate::volume::{Volume, VoxelData};

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
        assert!(e.to_string().contains("voxel [0, 1, 0] (i, j, k)"), "{e}");
        assert!(!bad.exists());
    }

    /// What the writer writes reads back as AFNI's warp: the same vectors, LPS, no intent, the extension at its place.
    #[test]
    fn a_written_warp_reads_back_as_afnis() {
        let dir = tempfile::tempdir().expect("tempdir");
        let dims = [4, 3, 2];
        let grid = Transform::from_scale_translation([2.0, -2.5, 3.0], [10.0, -5.0, 7.0]);
        let vectors: Vec<[f32; 3]> = (0..24).map(|k| [k as f32 * 0.25, -(k as f32), 1.5]).collect();
        for name in ["w.nii", "w.nii.gz"] {
            let path = dir.path().join(name);
            write_afni_warp(&path, dims, &grid, &vectors).expect("write");
            assert!(super::super::afni_extension::is_afni_warp(&path).expect("read"));
            let (field, kind) = read_vector_field(&path).expect("read back");
            assert_eq!(kind, NiftiFieldKind::AfniWarp);
            assert_eq!((field.dims, field.displacements_lps.as_slice()), (dims, vectors.as_slice()));
        }
        let raw = std::fs::read(dir.path().join("w.nii")).expect("read");
        let vox_offset = f32::from_le_bytes([raw[108], raw[109], raw[110], raw[111]]) as usize;
        assert_eq!((raw[348], vox_offset % 16, raw.len() - vox_offset), (1, 0, 24 * 12));
        assert_eq!(i16::from_le_bytes([raw[68], raw[69]]), 0, "no intent");
        assert_eq!(
            i32::from_le_bytes([raw[356], raw[357], raw[358], raw[359]]),
            super::super::afni_extension::NIFTI_ECODE_AFNI
        );
    }
}
