//! Slice geometry (step 3 of [`super`]): the series' slices (each placed by its header, see
//! [`super::header::parse_geometry`]) sorted along the normal, checked for parallel orientations, duplicates and
//! gaps, and placed by one `lps_from_index` ([`plan_geometry`]).

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use super::header::{Header, PixelFormat, SliceGeom, normal};
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
