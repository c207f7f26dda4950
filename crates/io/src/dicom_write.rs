//! Writes a [`Volume`] as a classic DICOM series: one single-frame image per k slice, Explicit VR
//! Little Endian, new UIDs.
//!
//! Geometry: ImageOrientationPatient is the unit direction of +i and +j in LPS, PixelSpacing is
//! `[|j column|, |i column|]` (row spacing first, as DICOM orders it), and slice k sits at
//! ImagePositionPatient = `lps_from_index · (0, 0, k, 1)`. A reader that takes the k step from IPP
//! differences (ours does) gets `lps_from_index` back, sheared k columns included.
//!
//! Values: stored = (value − intercept) / slope with slope 1 and the intercept from
//! [`DicomSeriesOptions::rescale_intercept`] (CT scanners commonly store HU + 1024 as unsigned with
//! intercept −1024). The stored type is u8, u16 or i16; f32 volumes are refused (convert first).
//!
//! The series appears atomically: it is written into a hidden sibling folder that is renamed to
//! `dir` at the end, so a failure never leaves a partial series.

use std::io::Write;
use std::path::{Path, PathBuf};

use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

use crate::error::{Error, Result};
use crate::geometry::{Point3, direction_cosines, spacing_mm};
use crate::volume::{Modality, Volume, VoxelData};

/// What to put in the written series besides the voxels and the geometry.
#[derive(Clone, Debug)]
pub struct DicomSeriesOptions {
    pub modality: Modality,
    pub series_description: String,
    pub patient_name: String,
    pub patient_id: String,
    pub series_number: i32,
    /// RescaleIntercept: samples are stored as `value − intercept`.
    pub rescale_intercept: f64,
}

impl Default for DicomSeriesOptions {
    fn default() -> Self {
        Self {
            modality: Modality::Ct,
            series_description: "warpbench".into(),
            patient_name: "Anonymous".into(),
            patient_id: "warpbench".into(),
            series_number: 1,
            rescale_intercept: 0.0,
        }
    }
}

/// The stored pixel representation chosen for a volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stored {
    U8,
    U16,
    I16,
}

/// A new globally unique UID under the `2.25` (UUID-derived) root.
fn new_uid() -> String {
    use std::collections::hash_map::RandomState;
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let mut words = [0u64; 2];
    for w in &mut words {
        let mut h = RandomState::new().build_hasher();
        h.write_u128(nanos);
        h.write_u32(std::process::id());
        h.write_u64(COUNTER.fetch_add(1, Ordering::Relaxed));
        *w = h.finish();
    }
    format!("2.25.{}", (u128::from(words[0]) << 64) | u128::from(words[1]))
}

/// A DS (decimal string) value of at most 16 characters, as precise as fits.
fn ds(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return "0".into();
    }
    for prec in (0..=15).rev() {
        let s = format!("{x:.prec$}");
        let s = if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s };
        if s.len() <= 16 {
            return if s == "-0" { "0".into() } else { s };
        }
    }
    format!("{x:.6e}")
}

fn ds_multi(xs: &[f64]) -> String {
    xs.iter().map(|&x| ds(x)).collect::<Vec<_>>().join("\\")
}

fn choose_stored(path: &Path, v: &Volume, intercept: f64) -> Result<Stored> {
    if intercept.fract() != 0.0 || !intercept.is_finite() {
        return Err(Error::invalid(path, format!("the rescale intercept must be an integer, not {intercept}")));
    }
    let Some((lo, hi)) = v.data.finite_range() else {
        return Err(Error::invalid(path, "the volume has no finite samples"));
    };
    let (lo, hi) = (lo - intercept, hi - intercept);
    match (&v.data, intercept == 0.0) {
        (VoxelData::F32(_), _) => {
            Err(Error::unsupported(path, "writing f32 volumes as DICOM; convert to an integer sample type first"))
        }
        (VoxelData::U8(_), true) => Ok(Stored::U8),
        (VoxelData::U16(_), true) => Ok(Stored::U16),
        (VoxelData::I16(_), true) => Ok(Stored::I16),
        _ if lo >= 0.0 && hi <= f64::from(u16::MAX) => Ok(Stored::U16),
        _ if lo >= f64::from(i16::MIN) && hi <= f64::from(i16::MAX) => Ok(Stored::I16),
        _ => {
            Err(Error::invalid(path, format!("values {lo}..{hi} minus intercept {intercept} fit neither u16 nor i16")))
        }
    }
}

/// Writes `volume` as a new DICOM series in `dir`, which must not exist yet (or be an empty folder).
/// Returns the written files, in slice order.
pub fn write_series(dir: &Path, volume: &Volume, opts: &DicomSeriesOptions) -> Result<Vec<PathBuf>> {
    if dir.exists() && std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?.next().is_some() {
        return Err(Error::invalid(dir, "the output folder exists and is not empty"));
    }
    let stored = choose_stored(dir, volume, opts.rescale_intercept)?;
    let staging = crate::atomic::StagingDir::new_beside(dir)?;

    let [nx, ny, nz] = volume.dims;
    let dirs = direction_cosines(&volume.lps_from_index);
    let spacing = spacing_mm(&volume.lps_from_index);
    let iop = [dirs[(0, 0)], dirs[(1, 0)], dirs[(2, 0)], dirs[(0, 1)], dirs[(1, 1)], dirs[(2, 1)]];
    let (study_uid, series_uid, frame_uid) = (new_uid(), new_uid(), new_uid());
    let (sop_class, modality) = match &volume.modality {
        Modality::Ct => (uids::CT_IMAGE_STORAGE, "CT"),
        Modality::Mr => (uids::MR_IMAGE_STORAGE, "MR"),
        Modality::Other(_) | Modality::Unknown => (uids::SECONDARY_CAPTURE_IMAGE_STORAGE, "OT"),
    };
    let (rows, cols) = (
        u16::try_from(ny).map_err(|_| Error::invalid(dir, format!("{ny} rows do not fit DICOM's u16")))?,
        u16::try_from(nx).map_err(|_| Error::invalid(dir, format!("{nx} columns do not fit DICOM's u16")))?,
    );
    let bits: u16 = if stored == Stored::U8 { 8 } else { 16 };
    let slice_len = nx * ny;
    let mut files = Vec::with_capacity(nz);
    for k in 0..nz {
        let ipp = volume.lps_from_index.apply_point(Point3::new(0.0, 0.0, k as f64)).coords();
        let mut pixels = Vec::with_capacity(slice_len * usize::from(bits / 8));
        let range = k * slice_len..(k + 1) * slice_len;
        let shift = opts.rescale_intercept;
        match (&volume.data, stored) {
            (VoxelData::U8(v), Stored::U8) => pixels.extend_from_slice(&v[range]),
            (data, Stored::U16) => {
                for i in range {
                    pixels.extend_from_slice(&((data.get_f64(i) - shift) as u16).to_le_bytes());
                }
            }
            (data, Stored::I16) => {
                for i in range {
                    pixels.extend_from_slice(&((data.get_f64(i) - shift) as i16).to_le_bytes());
                }
            }
            (_, Stored::U8) => unreachable!("u8 storage is chosen only for u8 volumes"),
        }
        let sop_uid = new_uid();
        let number = i32::try_from(k + 1).unwrap_or(i32::MAX);
        let str_el = |tag, vr, s: &str| DataElement::new(tag, vr, PrimitiveValue::from(s.to_string()));
        let obj = InMemDicomObject::from_element_iter([
            str_el(tags::SOP_CLASS_UID, VR::UI, sop_class),
            str_el(tags::SOP_INSTANCE_UID, VR::UI, &sop_uid),
            str_el(tags::MODALITY, VR::CS, modality),
            str_el(tags::PATIENT_NAME, VR::PN, &opts.patient_name),
            str_el(tags::PATIENT_ID, VR::LO, &opts.patient_id),
            str_el(tags::STUDY_INSTANCE_UID, VR::UI, &study_uid),
            str_el(tags::SERIES_INSTANCE_UID, VR::UI, &series_uid),
            str_el(tags::FRAME_OF_REFERENCE_UID, VR::UI, &frame_uid),
            str_el(tags::SERIES_DESCRIPTION, VR::LO, &opts.series_description),
            str_el(tags::SERIES_NUMBER, VR::IS, &opts.series_number.to_string()),
            str_el(tags::INSTANCE_NUMBER, VR::IS, &number.to_string()),
            str_el(tags::IMAGE_POSITION_PATIENT, VR::DS, &ds_multi(&ipp)),
            str_el(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, &ds_multi(&iop)),
            str_el(tags::PIXEL_SPACING, VR::DS, &ds_multi(&[spacing[1], spacing[0]])),
            str_el(tags::SLICE_THICKNESS, VR::DS, &ds(spacing[2])),
            DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
            str_el(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2"),
            DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(rows)),
            DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(cols)),
            DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(bits)),
            DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(bits)),
            DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(bits - 1)),
            DataElement::new(
                tags::PIXEL_REPRESENTATION,
                VR::US,
                PrimitiveValue::from(u16::from(stored == Stored::I16)),
            ),
            str_el(tags::RESCALE_INTERCEPT, VR::DS, &ds(opts.rescale_intercept)),
            str_el(tags::RESCALE_SLOPE, VR::DS, "1"),
            DataElement::new(tags::PIXEL_DATA, if bits == 8 { VR::OB } else { VR::OW }, PrimitiveValue::from(pixels)),
        ]);
        let file = obj
            .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
            .map_err(|e| Error::new(dir, crate::ErrorKind::Dicom(e.to_string())))?;
        let name = format!("IM{:05}.dcm", k + 1);
        crate::write_atomic(&staging.path().join(&name), |w: &mut dyn Write| {
            file.write_all(w).map_err(std::io::Error::other)
        })?;
        files.push(dir.join(name));
    }
    staging.persist(dir)?;
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::ds;

    #[test]
    fn decimal_strings_fit_sixteen_characters() {
        for x in [0.0, -146.123_456_789_012_34, 0.570_312_5, 1e-20, -777.5, 123_456_789.123_456, 5.0] {
            let s = ds(x);
            assert!(s.len() <= 16, "{s}");
            let back: f64 = s.parse().expect("parses");
            assert!((back - x).abs() <= 1e-9 * x.abs().max(1.0) || x.abs() < 1e-15, "{x} -> {s}");
        }
        assert_eq!(ds(5.0), "5");
        assert_eq!(ds(-1024.0), "-1024");
    }
}
