//! Slice geometry (step 3 of [`super`]): each slice's position, orientation, spacing and rescale from its header
//! ([`parse_geometry`]), then the series' slices sorted along the normal, checked for parallel orientations,
//! duplicates and gaps, and placed by one `lps_from_index` ([`plan_geometry`]).

use std::path::Path;

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;
use dicom_object::mem::InMemElement;
use nalgebra::{Matrix3, Vector3};

use super::header::{Header, PixelFormat, elem_f64s, tag_label};
use super::input::Source;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::volume::GeometrySource;

/// Largest difference between two ImageOrientationPatient components still called parallel.
pub const ORIENTATION_TOLERANCE: f64 = 1e-4;
/// A step larger than this times the median step is a gap (missing slices).
const GAP_FACTOR: f64 = 1.5;
/// Consecutive steps differing by more than this fraction of the mean give a warning.
const UNEVEN_FRACTION: f64 = 0.01;
/// Two slices closer than this along the normal (mm) are duplicates.
const DUPLICATE_MM: f64 = 1e-3;

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
fn normal(iop: &[f64; 6]) -> [f64; 3] {
    let n = Vector3::new(iop[0], iop[1], iop[2]).cross(&Vector3::new(iop[3], iop[4], iop[5]));
    [n[0], n[1], n[2]]
}

/// One slice of the output: which header (index into the series) and which frame.
#[derive(Clone, Debug)]
pub(super) struct Slot {
    pub(super) header: usize,
    pub(super) frame: usize,
    pub(super) geom: SliceGeom,
    pub(super) d: f64,
}

#[derive(Debug)]
pub(super) struct Plan {
    pub(super) dims: [usize; 3],
    pub(super) lps_from_index: Transform<Lps, Index>,
    /// Sorted ascending along the normal; index = k.
    pub(super) slots: Vec<Slot>,
    pub(super) warnings: Vec<String>,
    /// `Assumed` when a single slice lacks position, orientation or spacing.
    pub(super) geometry_source: GeometrySource,
}

pub(super) fn plan_geometry(label: &Path, sources: &[Source], series: &[Header]) -> Result<Plan> {
    let name = |h: usize| sources[series[h].source].path().display().to_string();
    let mut slots = Vec::new();
    let mut first_fmt: Option<(usize, &PixelFormat)> = None;
    for (hi, h) in series.iter().enumerate() {
        let path = sources[h.source].path();
        let (fmt, geoms) = h.image.as_ref().map_err(|e| Error::invalid(path, e.clone()))?;
        if fmt.samples_per_pixel != 1 || is_colour(&fmt.photometric) {
            return Err(Error::unsupported(
                path,
                format!(
                    "colour images ({} samples per pixel, PhotometricInterpretation {}); only greyscale volumes are read",
                    fmt.samples_per_pixel, fmt.photometric
                ),
            ));
        }
        if let Some((f0, fmt0)) = first_fmt {
            for (what, a, b) in [
                ("Rows (0028,0010)", fmt0.rows, fmt.rows),
                ("Columns (0028,0011)", fmt0.cols, fmt.cols),
                ("BitsAllocated (0028,0100)", fmt0.bits_allocated as usize, fmt.bits_allocated as usize),
                ("PixelRepresentation (0028,0103)", usize::from(fmt0.signed), usize::from(fmt.signed)),
            ] {
                if a != b {
                    return Err(Error::invalid(path, format!("{what} is {b} but {a} in {}", name(f0))));
                }
            }
        } else {
            first_fmt = Some((hi, fmt));
        }
        for (frame, g) in geoms.iter().enumerate() {
            slots.push(Slot { header: hi, frame, geom: g.clone(), d: 0.0 });
        }
    }
    let Some(first) = slots.first().cloned() else {
        return Err(Error::invalid(label, "the series has no slices"));
    };
    let Some((_, fmt)) = first_fmt else {
        return Err(Error::invalid(label, "the series has no slices"));
    };

    let mut warnings: Vec<String> = Vec::new();
    let mut geometry_source = GeometrySource::DicomPatient;
    if let Some(s) = slots.iter().find(|s| s.geom.missing.is_some()) {
        let what = s.geom.missing.clone().unwrap_or_default();
        if slots.len() > 1 {
            return Err(Error::invalid(sources[series[s.header].source].path(), what));
        }
        warnings.push(format!(
            "{what}: the single slice is placed at the origin, axis-aligned, with 1 mm pixels where spacing is missing"
        ));
        geometry_source = GeometrySource::Assumed;
    }

    // Same orientation and pixel spacing everywhere.
    for s in &slots {
        let diff = first.geom.iop.iter().zip(&s.geom.iop).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        if diff > ORIENTATION_TOLERANCE {
            return Err(Error::invalid(
                sources[series[s.header].source].path(),
                format!(
                    "slice orientations are not parallel: ImageOrientationPatient {:?} here but {:?} in {} \
                     (differs by {diff:.3e}, tolerance {ORIENTATION_TOLERANCE:e})",
                    s.geom.iop,
                    first.geom.iop,
                    name(first.header)
                ),
            ));
        }
        let ps_diff = (0..2).map(|i| (first.geom.pixel_spacing[i] - s.geom.pixel_spacing[i]).abs()).fold(0.0, f64::max);
        if ps_diff > 1e-4 * first.geom.pixel_spacing[0].max(first.geom.pixel_spacing[1]) {
            return Err(Error::invalid(
                sources[series[s.header].source].path(),
                format!(
                    "PixelSpacing (0028,0030) is {:?} here but {:?} in {}",
                    s.geom.pixel_spacing,
                    first.geom.pixel_spacing,
                    name(first.header)
                ),
            ));
        }
    }

    let n = normal(&first.geom.iop);
    for s in &mut slots {
        s.d = s.geom.ipp[0] * n[0] + s.geom.ipp[1] * n[1] + s.geom.ipp[2] * n[2];
    }
    // Stable sort: equal positions keep file order, then are rejected below as duplicates.
    slots.sort_by(|a, b| a.d.total_cmp(&b.d));

    let where_ = |s: &Slot| {
        let multi = series[s.header].image.as_ref().is_ok_and(|(f, _)| f.frames > 1);
        if multi { format!("{} frame {}", name(s.header), s.frame + 1) } else { name(s.header) }
    };
    for h in series {
        warnings.extend(h.notes.iter().cloned());
    }
    let count = slots.len();
    let steps: Vec<f64> = slots.windows(2).map(|w| w[1].d - w[0].d).collect();
    for (i, &s) in steps.iter().enumerate() {
        if s < DUPLICATE_MM {
            return Err(Error::invalid(
                label,
                format!(
                    "duplicate slice position {:.4} mm along the normal: {} and {}",
                    slots[i].d,
                    where_(&slots[i]),
                    where_(&slots[i + 1])
                ),
            ));
        }
    }
    let last = slots[count - 1].clone();
    let k_col = if count > 1 {
        let mut sorted = steps.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        for (i, &s) in steps.iter().enumerate() {
            if s > GAP_FACTOR * median {
                return Err(Error::invalid(
                    label,
                    format!(
                        "missing slices: a gap of {s:.4} mm between positions {:.4} and {:.4} mm along the \
                         slice normal ({} and {}); the median spacing is {median:.4} mm",
                        slots[i].d,
                        slots[i + 1].d,
                        where_(&slots[i]),
                        where_(&slots[i + 1])
                    ),
                ));
            }
        }
        let mean = (last.d - first_d(&slots)) / (count - 1) as f64;
        if steps.windows(2).any(|w| (w[1] - w[0]).abs() > UNEVEN_FRACTION * mean) {
            warnings.push(format!(
                "uneven slice spacing: steps from {:.4} to {:.4} mm (mean {mean:.4} mm); the volume uses the mean",
                sorted[0],
                sorted[sorted.len() - 1]
            ));
        }
        let p0 = slots[0].geom.ipp;
        let k: [f64; 3] = std::array::from_fn(|a| (last.geom.ipp[a] - p0[a]) / (count - 1) as f64);
        // Positions off the line p0 + k·t (in-plane shifts) cannot be represented: warn.
        let r = &first.geom.iop[0..3];
        let c = &first.geom.iop[3..6];
        let off = slots
            .iter()
            .map(|s| {
                let t = (s.d - slots[0].d) / (last.d - slots[0].d) * (count - 1) as f64;
                let e: [f64; 3] = std::array::from_fn(|a| s.geom.ipp[a] - (p0[a] + t * k[a]));
                (e[0] * r[0] + e[1] * r[1] + e[2] * r[2]).abs().max((e[0] * c[0] + e[1] * c[1] + e[2] * c[2]).abs())
            })
            .fold(0.0, f64::max);
        if off > 0.1 * first.geom.pixel_spacing[0].min(first.geom.pixel_spacing[1]) {
            warnings.push(format!(
                "slice positions are not on one line: up to {off:.4} mm in-plane from the line through the first and last"
            ));
        }
        k
    } else {
        let step = first.geom.slice_step_mm.unwrap_or(1.0);
        [n[0] * step, n[1] * step, n[2] * step]
    };

    let g = &slots[0].geom;
    let [row_mm, col_mm] = g.pixel_spacing;
    let i_col = Vector3::new(g.iop[0], g.iop[1], g.iop[2]) * col_mm;
    let j_col = Vector3::new(g.iop[3], g.iop[4], g.iop[5]) * row_mm;
    let linear = Matrix3::from_columns(&[i_col, j_col, Vector3::from(k_col)]);
    let lps_from_index = Transform::from_linear_translation(linear, g.ipp);
    Ok(Plan { dims: [fmt.cols, fmt.rows, count], lps_from_index, slots, warnings, geometry_source })
}

fn first_d(slots: &[Slot]) -> f64 {
    slots.first().map_or(0.0, |s| s.d)
}

fn is_colour(photometric: &str) -> bool {
    !(photometric.is_empty() || photometric == "MONOCHROME1" || photometric == "MONOCHROME2")
}
