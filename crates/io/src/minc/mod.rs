//! MINC volumes (`.mnc`), the format of the Montreal Neurological Institute's tools (minc-toolkit, CIVET,
//! BrainWeb's simulated brains) and one ITK reads: MINC 1, a netCDF classic file, and MINC 2, an HDF5 file; either may
//! be gzip-compressed (`.mnc.gz`). Both are read ([`read()`], [`read_bytes`]); MINC 2 is written ([`write()`],
//! [`to_bytes`]: the volume in its own sample type, as libminc lays a file out).
//!
//! # The model both share
//!
//! A volume is the variable `image`, whose dimensions are named in file order, slowest first (`zspace,yspace,xspace`
//! is the usual one): three spatial ones, `xspace`, `yspace` and `zspace`, and perhaps `time`. Each spatial dimension
//! has a `start`, a `step` and `direction_cosines` (MINC's defaults where missing: 0, 1 and the axis itself, with a
//! warning). Its samples are read in file order, so the fastest spatial dimension is warpbench's i, the next j, the
//! slowest k, and no sample moves: i's column of `ras_from_index` is its cosines times its step, and voxel 0 is at
//! Σ cosines · start over the three (as nibabel's `Minc1File.get_affine` and ITK's `MINCImageIO` build it). MINC's
//! world is RAS (x from left to right, y from posterior to anterior, z upwards); the volume's LPS geometry is that,
//! flipped.
//!
//! Integer samples stand for real values by a linear map per slice: `image-min` and `image-max` give the real range,
//! over a leading part of the image's dimensions (one value per `zspace` slice, usually), and the image's
//! `valid_range` (or the type's range) the stored one; a sample is clipped to the valid range, then mapped,
//! `real = clip(v) · slope + inter` with `slope = (max − min) / (valid_max − valid_min)` and
//! `inter = min − valid_min · slope`, in f64 as nibabel does. Float samples are their values. The volume's type then
//! follows the rules of every reader (`docs/formats.md`, "Sample types and rescale").
//!
//! A `time` dimension gives frames, chosen as for a 4-D NIfTI ([`LoadOptions::frame`]); any other dimension must have
//! one sample (a `vector_dimension`, RGB for instance, is refused).

mod minc1;
mod minc2;
mod model;
mod netcdf;
mod write;

pub use write::{grid_to_bytes, to_bytes, write};

use std::io::Read;
use std::path::Path;

use flate2::read::MultiGzDecoder;

use crate::error::{Error, ErrorKind, Result};
use crate::nifti::DisplacementField;
use crate::options::LoadOptions;
use crate::stream::GZIP_MAGIC;
use crate::volume::{GeometrySource, Volume};
use model::{Decoded, Want};

/// The largest MINC file read (compressed or not): a 512 × 512 × 300 volume of doubles is 630 MB.
const MAX_FILE_BYTES: u64 = 4 << 30;

/// Whether `path`'s name is a MINC file's: `.mnc` or `.mnc.gz`, case ignored.
#[must_use]
#[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
pub fn has_minc_name(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    name.ends_with(".mnc") || name.ends_with(".mnc.gz")
}

/// Whether `head`, a file's first bytes, starts as a MINC 1 file does (netCDF classic or 64-bit offset: `CDF` 1 or 2).
#[must_use]
pub fn looks_like_minc1(head: &[u8]) -> bool {
    head.starts_with(b"CDF\x01") || head.starts_with(b"CDF\x02")
}

/// Reads the MINC file at `path` (module docs).
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    read_bytes(path, file_bytes(path)?, opts)
}

/// The bytes of the regular file `path`, at most [`MAX_FILE_BYTES`].
fn file_bytes(path: &Path) -> Result<Vec<u8>> {
    let len = crate::files::check_regular_file(path)?.len();
    if len > MAX_FILE_BYTES {
        return Err(Error::invalid(
            path,
            format!("{len} bytes is more than the {MAX_FILE_BYTES} a MINC file may have"),
        ));
    }
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// [`read()`] of a file's bytes; `name` is used in errors.
///
/// # Errors
/// As [`read()`].
pub fn read_bytes(name: &Path, bytes: Vec<u8>, opts: &mut LoadOptions) -> Result<Volume> {
    opts.report(name, "reading", 0, 1)?;
    let volume = match read_as(name, bytes, opts, Want::Volume)? {
        Decoded::Volume(volume) => *volume,
        Decoded::Vectors(..) => return Err(Error::invalid(name, "a displacement grid, not a volume")),
    };
    opts.report(name, "reading", 1, 1)?;
    Ok(volume)
}

/// The displacement grid at `path`: a MINC file of vectors (a `vector_dimension` of 3 beside the spatial ones, as
/// minc-toolkit writes a `Grid_Transform`'s `Displacement_Volume`), the vectors converted from RAS to LPS mm.
///
/// # Errors
/// As [`read()`]; a file without 3 vector components, or one that does not give its geometry.
pub fn read_displacements(path: &Path) -> Result<DisplacementField> {
    read_displacements_bytes(path, file_bytes(path)?, &LoadOptions::new())
}

/// [`read_displacements`] of a file's bytes; `name` is used in errors.
///
/// # Errors
/// As [`read_displacements`].
pub fn read_displacements_bytes(name: &Path, bytes: Vec<u8>, opts: &LoadOptions) -> Result<DisplacementField> {
    let ((dims, lps_from_index), displacements_lps) = match read_as(name, bytes, opts, Want::Vectors)? {
        Decoded::Vectors(grid, vectors) => (grid, vectors),
        Decoded::Volume(_) => return Err(Error::invalid(name, "a volume, not a displacement grid")),
    };
    Ok(DisplacementField { dims, lps_from_index, geometry_source: GeometrySource::Minc, displacements_lps })
}

/// The file's bytes read as `want` says, gzip-compressed or not, MINC 1 or 2 by the magic.
fn read_as(name: &Path, bytes: Vec<u8>, opts: &LoadOptions, want: Want) -> Result<Decoded> {
    let bytes = if bytes.starts_with(&GZIP_MAGIC) { gunzip(name, &bytes, opts.max_voxel_bytes)? } else { bytes };
    if looks_like_minc1(&bytes) {
        minc1::read(name, bytes, opts, want)
    } else if crate::itk_h5::looks_like_hdf5(&bytes) {
        minc2::read(name, bytes, opts, want)
    } else {
        Err(Error::new(
            name,
            ErrorKind::BadMagic {
                format: "MINC",
                detail: "it is neither a MINC 1 (netCDF, CDF) nor a MINC 2 (HDF5) file, nor gzip of one".to_string(),
            },
        ))
    }
}

/// The inflated bytes of a gzip-compressed MINC file, at most what the voxel cap and a header allow.
fn gunzip(name: &Path, bytes: &[u8], max_voxel_bytes: u64) -> Result<Vec<u8>> {
    let cap = max_voxel_bytes.saturating_add(64 << 20).min(MAX_FILE_BYTES);
    let mut out = Vec::new();
    let mut reader = MultiGzDecoder::new(bytes).take(cap + 1);
    reader.read_to_end(&mut out).map_err(|e| crate::stream::read_error(name, e, "the gzip-compressed MINC file"))?;
    if out.len() as u64 > cap {
        return Err(Error::new(
            name,
            ErrorKind::TooLarge { what: "the inflated MINC file".to_string(), bytes: u128::from(cap) + 1, limit: cap },
        ));
    }
    Ok(out)
}
