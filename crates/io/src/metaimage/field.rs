//! Displacement fields in MetaImage, as ITK writes an `Image<Vector<float, 3>, 3>` and as elastix's transformix
//! writes its `deformationField.mhd` (`transformix -def all`): [`read_displacement_field`],
//! [`write_displacement_field`].
//!
//! The header is a volume's (see [`super`]) with `ElementNumberOfChannels = 3` before `ElementType`; the samples are
//! the three components of each voxel's vector, interleaved (x, y, z of voxel 0, then voxel 1, …), i fastest. This is
//! what SimpleITK 2.5.7 writes for a vector image:
//!
//! ```text
//! ObjectType = Image
//! NDims = 3
//! …                                        as a volume: geometry in ITK's LPS
//! DimSize = 4 3 2
//! ElementNumberOfChannels = 3
//! ElementType = MET_FLOAT                  MET_FLOAT or MET_DOUBLE are read; MET_FLOAT is written
//! ElementDataFile = LOCAL
//! ```
//!
//! The vectors are LPS mm, as stored: MetaImage's space is ITK's, so no component is flipped. MetaImage has nowhere
//! to say which way a field maps; ITK's `DisplacementFieldTransform` and transformix take it as a pull-back (the
//! output point x reads the input at x + D(x)), and so does [`crate::displacement::read_field_info`].

use std::io::{BufRead, Write};
use std::path::Path;

use super::data::FrameChoice;
use super::header::{parse_header, read_header_lines};
use super::write::{MetaImageWriteOptions, Samples, write_image};
use crate::displacement::check::{check_field_to_write, first_non_finite};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::nifti::DisplacementField;
use crate::options::LoadOptions;
use crate::sample::StoredType;
use crate::volume::{self, GeometrySource, VoxelData};

/// Reads a MetaImage displacement field (`.mha`, or a `.mhd` with its data file): 3-D, three channels, float or
/// double. Returns the field, LPS vectors as stored. Errors name the file.
pub fn read_displacement_field(path: &Path) -> Result<DisplacementField> {
    crate::files::read_header_file(path, |r, len, folder| read_from(path, r, len, Some(folder)))
}

/// [`read_displacement_field`] from memory; `name` is used in errors. A detached data file is refused.
pub fn read_displacement_field_bytes(name: &Path, bytes: &[u8]) -> Result<DisplacementField> {
    read_from(name, bytes, bytes.len() as u64, None)
}

fn read_from<R: BufRead>(name: &Path, mut r: R, total_len: u64, base_dir: Option<&Path>) -> Result<DisplacementField> {
    let (lines, header_bytes) = read_header_lines(name, &mut r)?;
    let h = parse_header(name, &lines)?;
    if h.ndims != 3 || h.channels != 3 {
        return Err(Error::invalid(
            name,
            format!(
                "NDims = {} and ElementNumberOfChannels = {}: a displacement field is a 3-D image of 3-vectors \
                 (NDims = 3, ElementNumberOfChannels = 3)",
                h.ndims, h.channels
            ),
        ));
    }
    if !matches!(h.stored, StoredType::F32 | StoredType::F64) {
        return Err(Error::unsupported(
            name,
            "a displacement field of integer samples; MET_FLOAT and MET_DOUBLE are read",
        ));
    }
    let g = super::geometry::geometry(name, &h)?;
    if !g.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(name, "the TransformMatrix and ElementSpacing are singular or not finite"));
    }
    let limit = volume::DEFAULT_MAX_VOXEL_BYTES;
    // 12 bytes a voxel out; the decoded f32 samples are as many again, stored doubles twice that at most.
    let n = volume::check_allocation(name, g.dims, 12, limit)?;
    volume::check_allocation(name, g.dims, 3 * h.stored.bytes(), limit)?;
    let f = FrameChoice { n: 3 * n, frame: 0, frames: 1 };
    let mut opts = LoadOptions::new();
    let data = super::data::samples(name, r, total_len.saturating_sub(header_bytes), base_dir, &h, f, &mut opts)?;
    let VoxelData::F32(values) = data else {
        return Err(Error::invalid(name, "float samples did not decode to float"));
    };
    let mut displacements_lps = volume::try_with_capacity(name, n, "the displacement vectors")?;
    displacements_lps.extend(values.chunks_exact(3).map(|v| [v[0], v[1], v[2]]));
    drop(values);
    if let Some(ijk) = first_non_finite(g.dims, &displacements_lps) {
        return Err(Error::invalid(name, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    Ok(DisplacementField {
        dims: g.dims,
        lps_from_index: g.lps_from_index,
        geometry_source: GeometrySource::MetaImage,
        displacements_lps,
    })
}

/// Writes a displacement field as MetaImage (module docs), atomically: `MET_FLOAT`, the LPS vectors interleaved;
/// `.mha` zlib-compressed after the header, `.mhd` with an uncompressed `.raw` beside it (as transformix writes its
/// `deformationField.mhd`). Non-finite vectors are refused, naming the voxel.
pub fn write_displacement_field(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    check_field_to_write(path, dims, lps_from_index, displacements_lps)?;
    let write_le = |w: &mut dyn Write| {
        let mut buf = Vec::with_capacity(12 << 12);
        for chunk in displacements_lps.chunks(1 << 12) {
            buf.clear();
            buf.extend(chunk.iter().flatten().flat_map(|v| v.to_le_bytes()));
            w.write_all(&buf)?;
        }
        Ok(())
    };
    let samples = Samples { element_type: "MET_FLOAT", channels: 3, write_le: &write_le };
    write_image(path, dims, lps_from_index, &samples, MetaImageWriteOptions::for_path(path))
}
