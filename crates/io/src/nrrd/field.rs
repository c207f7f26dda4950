//! Displacement fields in NRRD, as 3D Slicer and ITK's `NrrdImageIO` write them (Slicer's "grid transform"
//! storage): [`read_displacement_field`], [`write_displacement_field`].
//!
//! ```text
//! NRRD0004
//! type: float                              float (or double, read)
//! dimension: 4
//! space: left-posterior-superior           the vectors and the geometry in LPS
//! sizes: 3 X Y Z                           the vector axis first (fastest): x y z of voxel 0, then voxel 1, …
//! space directions: none (…) (…) (…)       no direction for the vector axis; the grid's lps_from_index columns
//! kinds: vector domain domain domain
//! endian: little
//! encoding: gzip                           raw, gzip, ascii or hex are read
//! space origin: (…)                        the centre of voxel (0, 0, 0)
//! displacement field type:=resampling      Slicer's key (PR #8757): resampling (the default) or modeling
//! ```
//!
//! This is what `itk.imwrite` (ITK 5.4.7) writes for an `Image[Vector[F,3],3]`, less the last line. ITK's NRRD
//! reader converts a right-anterior-superior header's geometry to LPS but takes the vector components as they are
//! (checked with SimpleITK 2.5.7: a RAS file's vector (1, 2, 3) reads back as (1, 2, 3)), while teem would take them
//! in the named space; so a field in any space but LPS is ambiguous, and refused.
//!
//! `displacement field type` is the key/value pair (`key:=value`) with which Slicer (since its PR #8757, 2025) tells
//! a resampling field (output point x to input point x + D(x), ITK's convention, the default when absent) from a
//! modeling one (a point y of the object moves to y + D(y)); [`read_displacement_field`] returns it.

use std::fs::File;
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use crate::pargz::ParGzWriter;
use flate2::Compression;

use super::data::{decode_payload, preflight_size};
use super::header::{Header, SpaceKind, parse_header, read_header_lines};
use crate::displacement::check::first_non_finite;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::nifti::DisplacementField;
use crate::options::LoadOptions;
use crate::sample::StoredType;
use crate::volume::{self, GeometrySource, VoxelData};

/// The key Slicer reads to tell a resampling field from a modeling one.
pub const DISPLACEMENT_FIELD_TYPE_KEY: &str = "displacement field type";

/// What a NRRD displacement field's vectors mean, in Slicer's words (its `displacement field type` key).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NrrdFieldType {
    /// `resampling`: the output point x reads the input at x + D(x) (ITK's convention; a pull-back).
    Resampling,
    /// `modeling`: a point y of the object moves to y + D(y) (a forward map).
    Modeling,
}

impl NrrdFieldType {
    /// The key's value.
    #[must_use]
    pub const fn value(self) -> &'static str {
        match self {
            Self::Resampling => "resampling",
            Self::Modeling => "modeling",
        }
    }
}

/// Reads a NRRD displacement field (attached `.nrrd` or detached `.nhdr`): 4-D, the first axis the 3 vector
/// components (`space directions: none …`, kind `vector` or `3-vector` when kinds are given), space
/// left-posterior-superior, float or double. Returns the field (LPS vectors, as stored) and the
/// `displacement field type` key when the header has one. Errors name the file.
pub fn read_displacement_field(path: &Path) -> Result<(DisplacementField, Option<NrrdFieldType>)> {
    crate::files::check_regular_file(path)?;
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let base = path.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    read_from(path, BufReader::new(file), len, Some(&base))
}

/// [`read_displacement_field`] from memory; `name` is used in errors. Detached data files are refused.
pub fn read_displacement_field_bytes(name: &Path, bytes: &[u8]) -> Result<(DisplacementField, Option<NrrdFieldType>)> {
    read_from(name, bytes, bytes.len() as u64, None)
}

fn read_from<R: BufRead>(
    name: &Path,
    mut r: R,
    total_len: u64,
    base_dir: Option<&Path>,
) -> Result<(DisplacementField, Option<NrrdFieldType>)> {
    let (lines, header_bytes) = read_header_lines(name, &mut r)?;
    let field_type = field_type(name, &lines)?;
    let h = parse_header(name, &lines)?;
    let (dims, lps_from_index) = field_geometry(name, &h)?;
    if !matches!(h.stored, StoredType::F32 | StoredType::F64) {
        return Err(Error::unsupported(name, "a displacement field of integer samples; float and double are read"));
    }
    let limit = volume::DEFAULT_MAX_VOXEL_BYTES;
    preflight_size(name, dims, 12, limit)?;
    // 12 bytes a voxel out; the decoded f32 samples are as many again, stored doubles twice that at most.
    let n = volume::check_allocation(name, dims, 12, limit)?;
    let samples = 3 * n;
    let need = samples as u64 * h.stored.bytes() as u64;
    let mut opts = LoadOptions::new();
    let data = if let Some(df) = &h.data_file {
        let Some(base) = base_dir else {
            return Err(Error::unsupported(name, format!("detached data file {df:?} cannot be read from memory")));
        };
        let data_path = base.join(df);
        crate::files::check_regular_file(&data_path)?;
        let file = File::open(&data_path).map_err(|e| Error::io(&data_path, e))?;
        let len = file.metadata().map_err(|e| Error::io(&data_path, e))?.len();
        decode_payload(&data_path, BufReader::new(file), len, &h, samples, need, &mut opts)?
    } else {
        decode_payload(name, r, total_len.saturating_sub(header_bytes), &h, samples, need, &mut opts)?
    };
    let VoxelData::F32(values) = data else {
        return Err(Error::invalid(name, "float samples did not decode to float"));
    };
    let mut displacements_lps = volume::try_with_capacity(name, n, "the displacement vectors")?;
    displacements_lps.extend(values.chunks_exact(3).map(|v| [v[0], v[1], v[2]]));
    drop(values);
    if let Some(ijk) = first_non_finite(dims, &displacements_lps) {
        return Err(Error::invalid(name, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    let field =
        DisplacementField { dims, lps_from_index, geometry_source: GeometrySource::NrrdSpace, displacements_lps };
    Ok((field, field_type))
}

/// The `displacement field type:=…` key/value pair, if the header has one (an unknown value is an error).
fn field_type(name: &Path, lines: &[String]) -> Result<Option<NrrdFieldType>> {
    for line in lines.iter().skip(1).filter(|l| !l.starts_with('#')) {
        let Some((key, value)) = line.split_once(":=") else { continue };
        if key.trim() != DISPLACEMENT_FIELD_TYPE_KEY {
            continue;
        }
        return match value.trim() {
            "resampling" => Ok(Some(NrrdFieldType::Resampling)),
            "modeling" => Ok(Some(NrrdFieldType::Modeling)),
            other => Err(Error::invalid(
                name,
                format!("\"{DISPLACEMENT_FIELD_TYPE_KEY}:={other}\": Slicer knows resampling and modeling"),
            )),
        };
    }
    Ok(None)
}

/// The grid of a displacement-field header: the three spatial sizes and `lps_from_index`.
fn field_geometry(name: &Path, h: &Header) -> Result<([usize; 3], Transform<Lps, Index>)> {
    const LAYOUT: &str = "a displacement field has sizes 3 X Y Z, space directions none (…) (…) (…)";
    let [components, nx, ny, nz] = h.sizes[..] else {
        return Err(Error::invalid(name, format!("sizes {:?}: {LAYOUT}", h.sizes)));
    };
    if components != 3 {
        return Err(Error::invalid(name, format!("sizes {:?}: {components} components; {LAYOUT}", h.sizes)));
    }
    if let Some(kinds) = &h.kinds {
        let first = kinds.first().map_or("", String::as_str);
        if kinds.len() != 4 || !matches!(first, "vector" | "3-vector") {
            return Err(Error::invalid(
                name,
                format!("kinds {kinds:?}: a displacement field has kinds: vector domain domain domain"),
            ));
        }
    }
    match h.space {
        Some(SpaceKind::Lps | SpaceKind::Unnamed) => {}
        Some(SpaceKind::Ras | SpaceKind::Las) => {
            return Err(Error::unsupported(
                name,
                "a displacement field in a space other than left-posterior-superior: ITK reads its vectors as LPS \
                 whatever the space says, teem in the named space; write the field in left-posterior-superior",
            ));
        }
        None => return Err(Error::invalid(name, "a displacement field needs a \"space\" (its vectors' frame)")),
    }
    let dirs = h.directions.as_deref().unwrap_or_default();
    let (Some(None), Some(Some(di)), Some(Some(dj)), Some(Some(dk))) =
        (dirs.first(), dirs.get(1), dirs.get(2), dirs.get(3))
    else {
        return Err(Error::invalid(name, format!("space directions {dirs:?}: {LAYOUT}")));
    };
    let Some(origin) = h.origin else {
        return Err(Error::invalid(name, "the header has no \"space origin\""));
    };
    let linear = nalgebra::Matrix3::from_columns(&[(*di).into(), (*dj).into(), (*dk).into()]);
    let lps_from_index = Transform::from_linear_translation(linear, origin);
    if !lps_from_index.is_valid_affine() {
        return Err(Error::invalid(name, "the space directions are singular or not finite"));
    }
    Ok(([nx, ny, nz], lps_from_index))
}

/// Writes a displacement field as NRRD0004 (layout in the module docs), atomically: float, the LPS vectors
/// interleaved (the component axis first), gzip-compressed, with `displacement field type:=` `field_type`.
/// Non-finite vectors are refused.
pub fn write_displacement_field(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
    field_type: NrrdFieldType,
) -> Result<()> {
    crate::displacement::check::check_field_to_write(path, dims, lps_from_index, displacements_lps)?;
    let header = header_text(dims, lps_from_index, field_type);
    crate::write_atomic(path, |w| {
        w.write_all(header.as_bytes())?;
        let mut gz = ParGzWriter::new(w, Compression::default());
        write_vectors(&mut gz, displacements_lps)?;
        gz.finish()?;
        Ok(())
    })
}

fn header_text(dims: [usize; 3], lps_from_index: &Transform<Lps, Index>, field_type: NrrdFieldType) -> String {
    use std::fmt::Write as _;
    let l = lps_from_index.linear();
    let o = lps_from_index.translation();
    let col = |c: usize| format!("({:?},{:?},{:?})", l[(0, c)], l[(1, c)], l[(2, c)]);
    let [nx, ny, nz] = dims;
    let mut h = String::from("NRRD0004\n# Complete NRRD file format specification at:\n");
    h.push_str("# http://teem.sourceforge.net/nrrd/format.html\n");
    h.push_str("# warpbench displacement field, LPS mm\n");
    h.push_str("type: float\ndimension: 4\nspace: left-posterior-superior\n");
    let _ = writeln!(h, "sizes: 3 {nx} {ny} {nz}");
    let _ = writeln!(h, "space directions: none {} {} {}", col(0), col(1), col(2));
    h.push_str("kinds: vector domain domain domain\nendian: little\nencoding: gzip\n");
    let _ = writeln!(h, "space origin: ({:?},{:?},{:?})", o[0], o[1], o[2]);
    let _ = writeln!(h, "{DISPLACEMENT_FIELD_TYPE_KEY}:={}", field_type.value());
    h.push('\n');
    h
}

/// Writes the vectors little-endian, interleaved, a bounded chunk at a time.
fn write_vectors(w: &mut dyn Write, displacements_lps: &[[f32; 3]]) -> io::Result<()> {
    let mut buf = Vec::with_capacity(12 << 12);
    for chunk in displacements_lps.chunks(1 << 12) {
        buf.clear();
        for v in chunk.iter().flatten() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&buf)?;
    }
    Ok(())
}
