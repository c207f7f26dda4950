//! The header of one image object (step 1 of [`super`]): identifiers, the transfer syntax's UID, the pixel format
//! and one placement per frame ([`parse_geometry`]: position, orientation, spacing and rescale, from the per-frame
//! functional groups, the shared ones or the top level).

use std::path::Path;

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::mem::InMemElement;
use dicom_object::{DefaultDicomObject, InMemDicomObject};
use nalgebra::Vector3;

use super::TransferSyntax;
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

/// Position, orientation, spacing and rescale of one slice (a file or one frame).
#[derive(Clone, Debug)]
pub(super) struct SliceGeom {
    pub(super) ipp: [f64; 3],
    pub(super) iop: [f64; 6],
    /// PixelSpacing: (between rows, between columns) in mm.
    pub(super) pixel_spacing: [f64; 2],
    /// SpacingBetweenSlices, else SliceThickness: used only for a single slice.
    pub(super) slice_step_mm: Option<f64>,
    pub(super) slope: f64,
    pub(super) intercept: f64,
    /// A geometry tag that was missing (defaults used); an error unless the series is one slice.
    pub(super) missing: Option<String>,
}

/// The first item of sequence `seq` in `item`.
fn first_item(item: Option<&InMemDicomObject>, seq: Tag) -> Option<&InMemDicomObject> {
    item?.get(seq)?.items()?.first()
}

/// Looks up `tag` for one frame: per-frame functional group, then shared, then the top level.
fn frame_elem<'a>(
    obj: &'a InMemDicomObject,
    per_frame: Option<&'a InMemDicomObject>,
    shared: Option<&'a InMemDicomObject>,
    seq: Tag,
    tag: Tag,
) -> Option<&'a InMemElement> {
    first_item(per_frame, seq)
        .and_then(|i| i.get(tag))
        .or_else(|| first_item(shared, seq).and_then(|i| i.get(tag)))
        .or_else(|| obj.get(tag))
}

pub(super) fn parse_geometry(
    obj: &InMemDicomObject,
    frames: usize,
    notes: &mut Vec<String>,
) -> std::result::Result<Vec<SliceGeom>, String> {
    let per_frame_items = obj.get(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE).and_then(|e| e.items());
    let shared = obj.get(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE).and_then(|e| e.items()).and_then(|i| i.first());
    let enhanced = per_frame_items.is_some() || shared.is_some();
    let geom_frames = if enhanced { frames } else { 1 };
    let mut out = Vec::with_capacity(geom_frames.min(65_536));
    for f in 0..geom_frames {
        let per = per_frame_items.and_then(|items| items.get(f));
        let find = |seq: Tag, tag: Tag| frame_elem(obj, per, shared, seq, tag);
        let need = |seq: Tag, tag: Tag, name: &str, n: usize| -> std::result::Result<Vec<f64>, String> {
            let e = find(seq, tag).ok_or_else(|| {
                let frame = if enhanced { format!(" for frame {}", f + 1) } else { String::new() };
                format!("{} is missing{frame}", tag_label(name, tag))
            })?;
            elem_f64s(e, name, n)
        };
        // A single classic slice without geometry (e.g. a secondary capture) gets the identity
        // placement; `plan_geometry` rejects that for series of more than one slice.
        let mut missing = None;
        let mut need_or = |seq: Tag, tag: Tag, name: &str, default: &[f64]| {
            if !enhanced && frames == 1 && find(seq, tag).is_none() {
                missing.get_or_insert_with(|| format!("{} is missing", tag_label(name, tag)));
                return Ok(default.to_vec());
            }
            need(seq, tag, name, default.len())
        };
        let ipp =
            need_or(tags::PLANE_POSITION_SEQUENCE, tags::IMAGE_POSITION_PATIENT, "ImagePositionPatient", &[0.0; 3])?;
        let iop = need_or(
            tags::PLANE_ORIENTATION_SEQUENCE,
            tags::IMAGE_ORIENTATION_PATIENT,
            "ImageOrientationPatient",
            &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        )?;
        let ps = need_or(tags::PIXEL_MEASURES_SEQUENCE, tags::PIXEL_SPACING, "PixelSpacing", &[1.0, 1.0])?;
        if ps.iter().any(|&s| s <= 0.0) {
            return Err(format!("{} must be positive: {ps:?}", tag_label("PixelSpacing", tags::PIXEL_SPACING)));
        }
        let step = |tag: Tag| {
            find(tags::PIXEL_MEASURES_SEQUENCE, tag)
                .and_then(|e| e.value().to_float64().ok())
                .filter(|s| s.is_finite() && *s > 0.0)
        };
        let slice_step_mm = step(tags::SPACING_BETWEEN_SLICES).or_else(|| step(tags::SLICE_THICKNESS));
        let number = |tag: Tag, name: &str| -> std::result::Result<Option<f64>, String> {
            match find(tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE, tag) {
                None => Ok(None),
                Some(e) if e.value().primitive().is_some_and(|p| p.to_str().trim().is_empty()) => Ok(None),
                Some(e) => elem_f64s(e, name, 1).map(|v| Some(v[0])),
            }
        };
        let slope = number(tags::RESCALE_SLOPE, "RescaleSlope")?.unwrap_or(1.0);
        let intercept = number(tags::RESCALE_INTERCEPT, "RescaleIntercept")?.unwrap_or(0.0);
        let iop: [f64; 6] = std::array::from_fn(|i| iop[i]);
        check_orientation(&iop)?;
        out.push(SliceGeom {
            ipp: [ipp[0], ipp[1], ipp[2]],
            iop,
            pixel_spacing: [ps[0], ps[1]],
            slice_step_mm,
            slope,
            intercept,
            missing,
        });
    }
    if !enhanced && frames > 1 {
        // Classic multi-frame: one position for all frames; stack them along the normal.
        let g = out[0].clone();
        let step = g.slice_step_mm.ok_or_else(|| {
            format!(
                "multi-frame object with {frames} frames has no per-frame positions (no {}) and no {} or {}",
                tag_label("PerFrameFunctionalGroupsSequence", tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE),
                tag_label("SpacingBetweenSlices", tags::SPACING_BETWEEN_SLICES),
                tag_label("SliceThickness", tags::SLICE_THICKNESS)
            )
        })?;
        let n = normal(&g.iop);
        notes.push(format!(
            "multi-frame object without per-frame positions: frames placed {step} mm apart along the slice normal"
        ));
        out = (0..frames)
            .map(|f| {
                let t = step * f as f64;
                SliceGeom { ipp: [g.ipp[0] + t * n[0], g.ipp[1] + t * n[1], g.ipp[2] + t * n[2]], ..g.clone() }
            })
            .collect();
    }
    Ok(out)
}

fn check_orientation(iop: &[f64; 6]) -> std::result::Result<(), String> {
    let r = Vector3::new(iop[0], iop[1], iop[2]);
    let c = Vector3::new(iop[3], iop[4], iop[5]);
    if (r.norm() - 1.0).abs() > 1e-2 || (c.norm() - 1.0).abs() > 1e-2 || r.dot(&c).abs() > 1e-2 {
        return Err(format!(
            "{} is not two orthogonal unit vectors: {iop:?}",
            tag_label("ImageOrientationPatient", tags::IMAGE_ORIENTATION_PATIENT)
        ));
    }
    Ok(())
}

/// n = row × col.
pub(super) fn normal(iop: &[f64; 6]) -> [f64; 3] {
    let n = Vector3::new(iop[0], iop[1], iop[2]).cross(&Vector3::new(iop[3], iop[4], iop[5]));
    [n[0], n[1], n[2]]
}
