//! The header of one image object (step 1 of [`super`]): identifiers, the transfer syntax's UID, the pixel format
//! and, through [`super::geometry::parse_geometry`], one placement per frame.

use std::path::Path;

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::mem::InMemElement;
use dicom_object::{DefaultDicomObject, InMemDicomObject};

use super::TransferSyntax;
use super::geometry::{SliceGeom, parse_geometry};
use super::input::Source;
use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;

/// SOP Class UID of a DICOMDIR (Media Storage Directory Storage), which holds no image.
const MEDIA_STORAGE_DIRECTORY: &str = "1.2.840.10008.1.3.10";

/// What the header of one image object says about its pixels.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct PixelFormat {
    pub(super) rows: usize,
    pub(super) cols: usize,
    pub(super) frames: usize,
    pub(super) samples_per_pixel: u16,
    pub(super) photometric: String,
    pub(super) bits_allocated: u16,
    pub(super) bits_stored: u16,
    pub(super) high_bit: u16,
    pub(super) signed: bool,
}

/// The header of one image object.
#[derive(Debug)]
pub(super) struct Header {
    pub(super) source: usize,
    pub(super) series_uid: String,
    pub(super) study_uid: Option<String>,
    pub(super) patient_id: Option<String>,
    pub(super) series_number: Option<i64>,
    pub(super) description: Option<String>,
    pub(super) modality: String,
    pub(super) rescale_type: Option<String>,
    /// The transfer syntax's UID as the file meta group gives it (trimmed), checked against
    /// [`TransferSyntax`] once the series is chosen.
    pub(super) transfer_syntax_uid: String,
    /// The pixel format and one geometry per frame, or the first problem (naming the tag).
    pub(super) image: std::result::Result<(PixelFormat, Vec<SliceGeom>), String>,
    /// Notes about this file (e.g. frame positions derived from SpacingBetweenSlices).
    pub(super) notes: Vec<String>,
}

pub(super) fn read_headers(
    label: &Path,
    sources: &[Source],
    skip_non_dicom: bool,
    opts: &mut LoadOptions,
) -> Result<Vec<Header>> {
    let n = sources.len() as u64;
    let mut headers = Vec::new();
    for (i, src) in sources.iter().enumerate() {
        opts.report(label, "reading DICOM headers", i as u64, n)?;
        if !src.has_preamble()? {
            if skip_non_dicom {
                continue;
            }
            return Err(Error::new(
                src.path(),
                ErrorKind::BadMagic { format: "DICOM", detail: "no 'DICM' after the 128-byte preamble".into() },
            ));
        }
        let obj = src.open(true)?;
        if obj.meta().media_storage_sop_class_uid() == MEDIA_STORAGE_DIRECTORY || obj.get(tags::ROWS).is_none() {
            // DICOMDIR or a non-image object (report, presentation state, ...).
            continue;
        }
        headers.push(parse_header(i, &obj, src.byte_len()?));
    }
    opts.report(label, "reading DICOM headers", n, n)?;
    Ok(headers)
}

/// The header of the object `obj`, read from a file of `byte_len` bytes.
fn parse_header(source: usize, obj: &DefaultDicomObject, byte_len: u64) -> Header {
    let mut notes = Vec::new();
    let image = parse_pixel_format(obj).and_then(|fmt| {
        check_frame_count(&fmt, byte_len, TransferSyntax::from_uid(obj.meta().transfer_syntax()))?;
        let geoms = parse_geometry(obj, fmt.frames, &mut notes)?;
        Ok((fmt, geoms))
    });
    Header {
        source,
        series_uid: get_str(obj, tags::SERIES_INSTANCE_UID).unwrap_or_default(),
        study_uid: get_str(obj, tags::STUDY_INSTANCE_UID),
        patient_id: get_str(obj, tags::PATIENT_ID),
        series_number: get_int(obj, tags::SERIES_NUMBER),
        description: get_str(obj, tags::SERIES_DESCRIPTION),
        modality: get_str(obj, tags::MODALITY).unwrap_or_default(),
        rescale_type: get_str(obj, tags::RESCALE_TYPE),
        transfer_syntax_uid: obj.meta().transfer_syntax().to_string(),
        image,
        notes,
    }
}

/// Refuses more frames than a file of `byte_len` bytes can hold, before a geometry record is built for each: a
/// frame takes at least its own size in native pixel data, at least an 8-byte fragment item when encapsulated,
/// and a deflated data set inflates at most 1032-fold. (Without it a 2 KB file claiming 20 million frames makes
/// the header reader allocate 2.9 GB; the pixel data are checked against the files' size again before the volume
/// is allocated, in [`super::check_files_can_hold`].)
fn check_frame_count(
    fmt: &PixelFormat,
    byte_len: u64,
    transfer_syntax: Option<TransferSyntax>,
) -> std::result::Result<(), String> {
    let frame_bytes = (fmt.rows * fmt.cols) as u64
        * u64::from(fmt.samples_per_pixel.max(1))
        * u64::from(fmt.bits_allocated.div_ceil(8).max(1));
    let data_bytes = if transfer_syntax == Some(TransferSyntax::DeflatedExplicitVrLittleEndian) {
        byte_len.saturating_mul(1032)
    } else {
        byte_len
    };
    let most = data_bytes / frame_bytes.min(8);
    if fmt.frames as u64 > most {
        return Err(format!(
            "{} {} is more than a file of {byte_len} bytes can hold ({most} frames of {}x{} at most)",
            tag_label("NumberOfFrames", tags::NUMBER_OF_FRAMES),
            fmt.frames,
            fmt.cols,
            fmt.rows
        ));
    }
    Ok(())
}

/// "Name (gggg,eeee)" for messages.
pub(super) fn tag_label(name: &str, tag: Tag) -> String {
    format!("{name} ({:04X},{:04X})", tag.group(), tag.element())
}

fn get_str(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    let s = obj.get(tag)?.value().to_str().ok()?;
    let s = s.trim_matches(|c: char| c.is_whitespace() || c == '\0');
    (!s.is_empty()).then(|| s.to_string())
}

fn get_int(obj: &InMemDicomObject, tag: Tag) -> Option<i64> {
    obj.get(tag)?.value().to_int::<i64>().ok()
}

/// The numbers of an element, checked to be `n` finite values.
pub(super) fn elem_f64s(e: &InMemElement, name: &str, n: usize) -> std::result::Result<Vec<f64>, String> {
    let label = tag_label(name, e.header().tag);
    let v = e.value().to_multi_float64().map_err(|err| format!("{label} is not a list of numbers: {err}"))?;
    if v.len() < n {
        return Err(format!("{label} has {} values, expected {n}", v.len()));
    }
    if v.iter().take(n).any(|x| !x.is_finite()) {
        return Err(format!("{label} has a value that is not finite: {v:?}"));
    }
    Ok(v[..n].to_vec())
}

fn required_u16(obj: &InMemDicomObject, tag: Tag, name: &str) -> std::result::Result<u16, String> {
    let e = obj.get(tag).ok_or_else(|| format!("{} is missing", tag_label(name, tag)))?;
    e.value().to_int::<u16>().map_err(|err| format!("{} is not a valid number: {err}", tag_label(name, tag)))
}

pub(super) fn parse_pixel_format(obj: &InMemDicomObject) -> std::result::Result<PixelFormat, String> {
    let rows = required_u16(obj, tags::ROWS, "Rows")?;
    let cols = required_u16(obj, tags::COLUMNS, "Columns")?;
    let samples_per_pixel = if obj.get(tags::SAMPLES_PER_PIXEL).is_some() {
        required_u16(obj, tags::SAMPLES_PER_PIXEL, "SamplesPerPixel")?
    } else {
        1
    };
    let bits_allocated = required_u16(obj, tags::BITS_ALLOCATED, "BitsAllocated")?;
    let bits_stored = if obj.get(tags::BITS_STORED).is_some() {
        required_u16(obj, tags::BITS_STORED, "BitsStored")?
    } else {
        bits_allocated
    };
    let high_bit = if obj.get(tags::HIGH_BIT).is_some() {
        required_u16(obj, tags::HIGH_BIT, "HighBit")?
    } else {
        bits_stored.saturating_sub(1)
    };
    let signed = if obj.get(tags::PIXEL_REPRESENTATION).is_some() {
        required_u16(obj, tags::PIXEL_REPRESENTATION, "PixelRepresentation")? == 1
    } else {
        false
    };
    let frames = match obj.get(tags::NUMBER_OF_FRAMES) {
        Some(e) => e.value().to_int::<i64>().ok().filter(|&n| n >= 1 && n <= i64::from(u32::MAX)).ok_or_else(|| {
            format!("{} is not a positive number", tag_label("NumberOfFrames", tags::NUMBER_OF_FRAMES))
        })? as usize,
        None => 1,
    };
    if rows == 0 || cols == 0 {
        return Err(format!("the image is empty: Rows {rows}, Columns {cols}"));
    }
    Ok(PixelFormat {
        rows: rows as usize,
        cols: cols as usize,
        frames,
        samples_per_pixel,
        photometric: get_str(obj, tags::PHOTOMETRIC_INTERPRETATION).unwrap_or_default(),
        bits_allocated,
        bits_stored,
        high_bit,
        signed,
    })
}
