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
//! The byte order is that in which `sizeof_hdr` reads 348 (or 540); both orders are read.
//!
//! A **NIfTI pair** (magic `ni1\0` / `ni2\0`, what SPM and older tools write) has the same header alone in a `.hdr`
//! and the samples in a `.img` beside it, from the `.img`'s byte `vox_offset` (0 as a rule); either may be
//! gzip-compressed (`.hdr.gz`, `.img.gz`). [`read()`] takes either name and finds the other beside it, with the same
//! stem and the name's case ([`pair_paths`]). A pair's header in a `.nii`, and a displacement field in a pair, are
//! refused; so is an Analyze 7.5 `.hdr` (no NIfTI magic), whose orientation is not stored: tools guessed it
//! differently (SPM's `defaults.analyze.flip`).
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
//! `lps_from_ras = diag(−1, −1, 1)`, and record which method was used in [`crate::GeometrySource`].
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
//! frame, a file of several frames is [`crate::ErrorKind::FrameRequired`] with the frame count, which each front end
//! words for its own way of choosing (the CLI's `--frame`).
//!
//! # Robustness and memory
//!
//! Only a regular file is opened (a named pipe would block, a device never end). Every header field is
//! validated before anything is allocated from it; sizes are checked with [`volume::check_allocation`]
//! (the [`LoadOptions::max_voxel_bytes`] cap), and for an uncompressed file against the file length. Sample
//! buffers are allocated fallibly ([`volume::try_with_capacity`]): memory the system refuses is an
//! [`crate::ErrorKind::OutOfMemory`] naming the file and the size, never an abort. A gzip
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
//!
//! # Modules
//! `header` parses the fixed header of either version; `layout` checks the grid, the stored type and the data
//! span (shared with displacement fields); `geometry` builds `lps_from_index` (and, for the writer, the qform of
//! a matrix); `samples` decodes and rescales the samples; `write` writes volumes; `field` reads and writes
//! displacement fields; `source` holds the byte sources (a file, plain or gzip, or a buffer), the bound on what
//! each can deliver and the progress reporter. This module holds the volume reader that runs those stages.

pub mod afni_extension;
mod field;
mod fnirt;
mod geometry;
mod header;
mod layout;
mod samples;
mod source;
mod write;

use std::path::Path;

use flate2::read::MultiGzDecoder;

pub use field::{
    DisplacementField, NIFTI_INTENT_DISPVECT, NIFTI_INTENT_VECTOR, NiftiFieldKind, NiftiVectorIntent,
    read_displacement_field, read_displacement_field_bytes, read_frame_vectors, read_frame_vectors_bytes,
    read_vector_field, read_vector_field_bytes, write_afni_warp, write_displacement_field, write_frame_vectors,
    write_vector_field,
};
pub use fnirt::{
    CoefficientField, FSL_CUBIC_SPLINE_COEFFICIENTS, FSL_FNIRT_DISPLACEMENT_FIELD, FSL_INTENTS, FnirtFile, fsl_intent,
    intent_code, read_fnirt_file, read_fnirt_file_bytes, write_deformation_field,
};
pub use header::looks_like_nifti;
pub use write::{WriteOptions, write, write_with};

use crate::error::{Error, Result};
use crate::options::LoadOptions;
use crate::sample::rescale_samples;
use crate::volume::{self, Rescale, Volume};
use geometry::lps_from_index;
use header::read_header;
use layout::layout;
use samples::{CHUNK_BYTES, read_identity, scaling};
use source::{Extent, GZIP_MAGIC, Reporter, Source, fill, open_file};

/// Reads a NIfTI-1/2 file (`.nii` or gzip-compressed `.nii.gz`, detected by content), or a NIfTI pair by the name of
/// either of its files (`.hdr`, `.img`, each perhaps `.gz`).
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    if let Some((hdr, img)) = pair_paths(path)? {
        let (mut header_src, _) = open_file(&hdr)?;
        let h = read_header(&hdr, &mut header_src).map_err(|e| match e.kind {
            crate::ErrorKind::BadMagic { .. } => Error::unsupported(
                &hdr,
                "no NIfTI magic: an Analyze 7.5 header, which stores no orientation (tools guessed it differently, \
                 e.g. SPM's defaults.analyze.flip); warpbench does not guess: convert the pair to NIfTI with the tool \
                 that made it",
            ),
            _ => e,
        })?;
        if !h.pair {
            return Err(Error::invalid(
                &hdr,
                "a .hdr whose magic is a single file's (n+1/n+2): its samples follow it; name the file .nii",
            ));
        }
        let (mut src, extent) = open_file(&img)?;
        return read_samples((&hdr, &img), &h, &mut src, extent, opts);
    }
    let (mut src, extent) = open_file(path)?;
    read_source(path, &mut src, extent, opts)
}

/// The `.hdr` and `.img` of the NIfTI pair `path` names (either of them, each perhaps `.gz`), the other found beside
/// it with the same stem and the name's case: `None` for any other name.
///
/// # Errors
/// The pair's other file is missing.
#[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
pub fn pair_paths(path: &Path) -> Result<Option<(std::path::PathBuf, std::path::PathBuf)>> {
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else { return Ok(None) };
    let lower = name.to_ascii_lowercase();
    let plain = lower.strip_suffix(".gz").unwrap_or(&lower);
    let is_header = plain.ends_with(".hdr");
    if !is_header && !plain.ends_with(".img") {
        return Ok(None);
    }
    let stem_len = plain.len() - 4;
    let (stem, ext) = (&name[..stem_len], &name[stem_len + 1..stem_len + 4]);
    // hdr ↔ img, letter by letter in the name's case.
    let other: String = ext
        .chars()
        .zip(if is_header { "img" } else { "hdr" }.chars())
        .map(|(had, want)| if had.is_ascii_uppercase() { want.to_ascii_uppercase() } else { want })
        .collect();
    let gz = if other.starts_with(char::is_uppercase) { ".GZ" } else { ".gz" };
    let candidates = [format!("{stem}.{other}"), format!("{stem}.{other}{gz}")];
    let found = candidates.iter().map(|c| path.with_file_name(c)).find(|p| p.exists());
    let Some(found) = found else {
        return Err(Error::invalid(
            path,
            format!(
                "a NIfTI pair's {} file is missing: {} (or {}) was looked for beside it",
                if is_header { "samples" } else { "header" },
                candidates[0],
                candidates[1]
            ),
        ));
    };
    Ok(Some(if is_header { (path.to_path_buf(), found) } else { (found, path.to_path_buf()) }))
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

fn read_source<S: Source>(path: &Path, src: &mut S, extent: Extent, opts: &mut LoadOptions) -> Result<Volume> {
    let h = read_header(path, src)?;
    if h.pair {
        return Err(header::pair_error(path, "name the header .hdr, with its .img beside it"));
    }
    read_samples((path, path), &h, src, extent, opts)
}

/// The volume of header `h` whose samples `src` holds after it (a single file, where the header has been read from
/// `src`) or from its start (a pair's `.img`); `header_path` names the header in errors, `data_path` the samples.
fn read_samples<S: Source>(
    (header_path, data_path): (&Path, &Path),
    h: &header::Header,
    src: &mut S,
    extent: Extent,
    opts: &mut LoadOptions,
) -> Result<Volume> {
    let path = header_path;
    let l = layout(data_path, h, opts, extent)?;
    let (lps_from_index, geometry_source, geometry_warning) = lps_from_index(path, h, l.dims)?;
    let scale = scaling(path, h)?;
    let max_voxel_bytes = opts.max_voxel_bytes;
    let consumed = if h.pair { 0 } else { h.version.header_bytes() as u64 };
    let path = data_path;

    let skip = l.frame_offset - consumed;
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
        None => read_identity(src, l.datatype, l.dims, l.frame_bytes, h.big_endian, &mut progress)?,
        Some(slope_inter) => {
            let mut raw = volume::try_with_capacity(path, l.frame_bytes, "the stored samples before rescaling")?;
            raw.resize(l.frame_bytes, 0);
            for chunk in raw.chunks_mut(CHUNK_BYTES) {
                fill(path, src, chunk, "the voxel data")?;
                progress.advance(chunk.len())?;
            }
            crate::sample::with_stored_type!(l.datatype, T => rescale_samples::<T>(path, &raw, l.dims, h.big_endian, slope_inter, max_voxel_bytes)?)
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
