//! DICOM series reader: a folder of slices, a list of files, or one (enhanced) multi-frame object.
//!
//! Entry points: [`read_folder`], [`read_files`], [`read_file_bytes`] and [`list_series`].
//!
//! # Steps
//! 1. **Headers.** Every file is read up to, not including, PixelData (7FE0,0010). In a folder,
//!    files without the `DICM` preamble, DICOMDIR files and objects without Rows (0028,0010)
//!    are skipped; a file that has the preamble but does not parse is an error naming it.
//! 2. **Series.** Files are grouped by SeriesInstanceUID (0020,000E). More than one series and no
//!    [`LoadOptions::series_instance_uid`] gives [`crate::ErrorKind::MultipleSeries`].
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
//!    by [`jpegls`] (each frame's size checked against Rows/Columns first);
//!    JPEG and JPEG 2000 go through `dicom-pixeldata`'s pure-Rust codecs after their frame
//!    headers are checked against Rows/Columns (a mismatch would make the codec adapters panic).
//!    Stored bits are masked to BitsStored and sign-extended for signed data. No LUT or window
//!    is applied. The file's bytes, the volume, the decoded RLE / JPEG-LS frames (and the JPEG-LS
//!    decoder's samples) and a rescaled copy are allocated fallibly ([`volume::try_with_capacity`]):
//!    memory the system refuses is an [`crate::ErrorKind::OutOfMemory`] naming the file and the size, never
//!    an abort. (Buffers that dicom-rs and dicom-pixeldata allocate while parsing and decoding JPEG /
//!    JPEG 2000 are theirs.)
//! 5. **Rescale.** value = RescaleSlope × stored + RescaleIntercept, per slice, in f64. Identity:
//!    u8, i16, u16 kept, i8 → i16, 32-bit → f32. Otherwise: integer slope and intercept with every
//!    value in i16 → i16, else in u16 → u16, else f32.
//!
//! Transfer syntaxes decoded: [`SUPPORTED_TRANSFER_SYNTAXES`], classified once per file as a [`TransferSyntax`]. JPEG-LS (which dicom-rs decodes
//! only through the C++ CharLS library) uses our own pure-Rust decoder, [`jpegls`].

//!
//! # Modules, by stage
//! - `input`: where an object's bytes come from (a file, a buffer, a folder's files), and opening it with
//!   dicom-rs after `prescan` has walked its element lengths;
//! - `header`: the header of one image object (pixel format, identifiers), step 1;
//! - `series`: grouping by series and choosing one, step 2;
//! - `geometry`: each slice's placement and the sorted slice plan with `lps_from_index`, step 3;
//! - `pixels`: decoding the files into one buffer and the rescale, steps 4 and 5;
//! - `codecs`: RLE and the JPEG-LS glue, and the frame-header checks run before dicom-pixeldata's codecs;
//! - `transfer_syntax`: the [`TransferSyntax`] enum;
//! - [`jpegls`]: our pure-Rust JPEG-LS decoder (also at `warpbench_io::jpegls`).

mod codecs;
mod geometry;
mod header;
mod input;
pub mod jpegls;
mod pixels;
mod prescan;
mod series;
mod transfer_syntax;

use std::path::{Path, PathBuf};

pub use geometry::ORIENTATION_TOLERANCE;
pub use transfer_syntax::{SUPPORTED_TRANSFER_SYNTAXES, TransferSyntax};

use crate::error::{Error, Result};
use crate::options::LoadOptions;
use crate::sample;
use crate::series::SeriesSummary;
use crate::volume::{self, Modality, Volume};
use geometry::plan_geometry;
use header::{Header, read_headers};
use input::{Source, folder_files};
use pixels::has_rescale;
use series::{group_series, select_series, summary};

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
        crate::files::check_regular_file(p)?; // a pipe or a device would block or never end
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

/// Opens the regular file `path` as one DICOM object once its element lengths have been checked (the guard every
/// DICOM read goes through), for objects that are not images (a registration, say).
///
/// # Errors
/// A file that is not DICOM, is truncated, or claims lengths its bytes do not have.
pub(crate) fn open_checked(path: &Path) -> Result<dicom_object::DefaultDicomObject> {
    crate::files::check_regular_file(path)?;
    Source::File(path.to_path_buf()).open(false)
}

/// The DICOM image series in folder `dir`, sorted by SeriesNumber then SeriesInstanceUID.
pub fn list_series(dir: &Path) -> Result<Vec<SeriesSummary>> {
    let sources = folder_files(dir)?;
    let headers = read_headers(dir, &sources, true, &mut LoadOptions::new())?;
    Ok(group_series(headers).iter().map(|g| summary(g)).collect())
}

/// Largest decoded-to-encoded size ratio believed for compressed pixel data (deflate peaks near
/// 1032:1; RLE at 64:1; JPEG lossless far lower). Only lossy JPEG 2000 of flat images comes close.
const MAX_COMPRESSION_RATIO: u64 = 2048;

/// Refuses a series whose files cannot hold `decoded_bytes` of pixels: at most their size when
/// uncompressed, at most [`MAX_COMPRESSION_RATIO`] times it when compressed. Runs before the volume
/// is allocated, so a small file that claims huge Rows × Columns × frames fails without allocating.
fn check_files_can_hold(
    label: &Path,
    sources: &[Source],
    series: &[Header],
    syntaxes: &[TransferSyntax],
    decoded_bytes: u64,
) -> Result<()> {
    let mut seen = std::collections::BTreeSet::new();
    let mut capacity = 0u64;
    for (h, syntax) in series.iter().zip(syntaxes) {
        if !seen.insert(h.source) {
            continue;
        }
        let len = sources[h.source].byte_len()?;
        let uncompressed = syntax.is_uncompressed();
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
    // One per header, checked once: the later stages match on it.
    let syntaxes: Vec<TransferSyntax> = series
        .iter()
        .map(|h| transfer_syntax::decodable(sources[h.source].path(), &h.transfer_syntax_uid))
        .collect::<Result<_>>()?;
    let Some(Ok((fmt, _))) = series.first().map(|h| &h.image) else {
        return Err(Error::invalid(label, "the series has no slices"));
    };
    let kind = pixels::stored_type(label, fmt)?;
    let dims = plan.dims;
    let total = volume::check_allocation(label, dims, kind.bytes(), opts.max_voxel_bytes)?;
    check_files_can_hold(label, sources, &series, &syntaxes, (total * kind.bytes()) as u64)?;
    let (data, rescale, mut warnings) = sample::with_stored_type!(kind, T => {
        pixels::decode_series::<T>(label, sources, &series, &syntaxes, &plan, total, opts)?
    });
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
    vol.metadata = volume::Metadata {
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
