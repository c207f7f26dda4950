//! Writes a [`Volume`] as DICOM objects that validators and archives accept (dicom3tools'
//! `dciodvfy` finds no error in them), Explicit VR Little Endian, new series and instance UIDs.
//!
//! # Which IOD
//! The IOD is the one the data can honestly fill:
//! - **CT Image** (one single-frame file per slice) when the modality is CT: every type 1 attribute
//!   is known (ImageType, the pixel module, the rescale), the acquisition attributes come from the
//!   [`DicomSeriesOptions::source`] or are written empty (KVP, AcquisitionNumber are type 2);
//! - **MR Image** (likewise) when the modality is MR *and* the source says how it was acquired
//!   (ScanningSequence and SequenceVariant are type 1; they cannot be made up);
//! - otherwise (a NIfTI or NRRD input, an MR without a DICOM source, any other modality) one
//!   **Multi-frame Grayscale Byte** (u8) or **Word** (16-bit) **Secondary Capture** object, with
//!   ConversionType WSD and the geometry in its functional groups (Pixel Measures, Plane
//!   Orientation, Plane Position per frame) and a Frame of Reference. The single-frame SC IOD has no
//!   Image Plane module, so GDCM and ITK ignore its positions; the multi-frame SC IODs carry them.
//!
//! # Attributes
//! With a source (the DICOM series the voxels came from, [`crate::dicom_source::DicomSource`]) the
//! patient, study (the series joins the source's study when its StudyInstanceUID is valid),
//! Laterality, PatientPosition, BodyPartExamined and equipment attributes are copied, and for the
//! CT and MR IODs the acquisition attributes of the CT/MR Image module. Type 2 attributes the
//! source lacks are written empty; without a source the patient is
//! [`DicomSeriesOptions::patient_name`] / [`DicomSeriesOptions::patient_id`], the study is new
//! (dated now) and the equipment is warpbench.
//!
//! # Derivation
//! Every image is ImageType `DERIVED\SECONDARY` (CT adds `AXIAL`, MR `OTHER`), with a
//! DerivationDescription (the series description and the warpbench version), a Derivation Code
//! Sequence (DCM 113085 "Spatial resampling"), warpbench as Contributing Equipment (DCM 109102
//! "Processing Equipment") and, with a source, a Source Image Sequence naming every image of the
//! source series (DCM 121322 "Source image for image processing operation"). The Frame of
//! Reference is new: the grid is not the source's.
//!
//! # Geometry
//! ImageOrientationPatient is the unit direction of +i and +j in LPS, PixelSpacing is
//! `[|j column|, |i column|]` (row spacing first, as DICOM orders it), and slice k sits at
//! ImagePositionPatient = `lps_from_index · (0, 0, k, 1)`. Slices (files or frames) are written in
//! ascending order along the normal ImageOrientationPatient row × column, as readers that take the
//! first two positions for the slice step expect; when the volume's k axis points the other way the
//! slices are written from the last k. A reader that takes the k step from IPP differences (ours
//! does) gets the same voxels at the same LPS positions, sheared k columns included.
//!
//! # Values
//! stored = (value − intercept) / slope with slope 1 and the intercept from
//! [`DicomSeriesOptions::rescale_intercept`] (CT scanners commonly store HU + 1024 as unsigned
//! with intercept −1024). The stored type is u8 (Secondary Capture only), u16 or i16; the CT and
//! MR IODs store 16 bits. The MR Image IOD has no rescale: MR values are stored as they are. f32
//! volumes are refused (convert first).
//!
//! The series appears atomically: it is written into a hidden sibling folder that is renamed to
//! `dir` at the end, so a failure never leaves a partial series.

use std::io::Write;
use std::path::{Path, PathBuf};

use dicom_core::value::DataSetSequence;
use dicom_core::{DataElement, PrimitiveValue, Tag, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

use crate::dicom_source::{self, DicomSource};
use crate::error::{Error, Result};
use crate::geometry::{Point3, direction_cosines, spacing_mm};
use crate::sample::{self, Stored, StoredType};
use crate::volume::{Modality, Volume, VoxelData};

/// What to put in the written series besides the voxels and the geometry.
#[derive(Clone, Debug)]
pub struct DicomSeriesOptions {
    /// Chooses the IOD (module docs): CT, MR (with a source that says how it was acquired), else
    /// Secondary Capture.
    pub modality: Modality,
    /// SeriesDescription (cut to 64 characters); the DerivationDescription starts with it.
    pub series_description: String,
    /// PatientName and PatientID when there is no [`Self::source`] (a source's patient is copied).
    pub patient_name: String,
    pub patient_id: String,
    pub series_number: i32,
    /// RescaleIntercept (CT and Secondary Capture): samples are stored as `value − intercept`.
    pub rescale_intercept: f64,
    /// The DICOM series the voxels were computed from: its patient, study, equipment and
    /// acquisition attributes are copied and its images referenced (module docs).
    pub source: Option<DicomSource>,
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
            source: None,
        }
    }
}

/// A new globally unique UID under the `2.25` (UUID-derived) root.
pub(crate) fn new_uid() -> String {
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
pub(crate) fn ds(x: f64) -> String {
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

pub(crate) fn ds_multi(xs: &[f64]) -> String {
    xs.iter().map(|&x| ds(x)).collect::<Vec<_>>().join("\\")
}

fn choose_stored(path: &Path, v: &Volume, intercept: f64) -> Result<StoredType> {
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
        (VoxelData::U8(_), true) => Ok(StoredType::U8),
        (VoxelData::U16(_), true) => Ok(StoredType::U16),
        (VoxelData::I16(_), true) => Ok(StoredType::I16),
        _ if lo >= 0.0 && hi <= f64::from(u16::MAX) => Ok(StoredType::U16),
        _ if lo >= f64::from(i16::MIN) && hi <= f64::from(i16::MAX) => Ok(StoredType::I16),
        _ => {
            Err(Error::invalid(path, format!("values {lo}..{hi} minus intercept {intercept} fit neither u16 nor i16")))
        }
    }
}

/// Writes `volume` as a new DICOM series in `dir`, which must not exist yet (or be an empty folder).
/// Returns the written files (one per slice, in slice order, or one multi-frame file).
pub fn write_series(dir: &Path, volume: &Volume, opts: &DicomSeriesOptions) -> Result<Vec<PathBuf>> {
    if dir.exists() && std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?.next().is_some() {
        return Err(Error::invalid(dir, "the output folder exists and is not empty"));
    }
    let plan = Plan::new(dir, volume, opts)?;
    let staging = crate::atomic::StagingDir::new_beside(dir)?;

    let mut files = Vec::with_capacity(plan.file_count());
    for n in 0..plan.file_count() {
        let file = plan
            .object(dir, volume, n)?
            .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
            .map_err(|e| Error::new(dir, crate::ErrorKind::Dicom(e.to_string())))?;
        let name = format!("IM{:05}.dcm", n + 1);
        crate::write_atomic(&staging.path().join(&name), |w: &mut dyn Write| {
            file.write_all(w).map_err(std::io::Error::other)
        })?;
        files.push(dir.join(name));
    }
    staging.persist(dir)?;
    Ok(files)
}

/// The IOD a volume is written as (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Iod {
    Ct,
    Mr,
    MultiFrameSc,
}

impl Iod {
    fn choose(opts: &DicomSeriesOptions) -> Self {
        let acquired =
            |s: &DicomSource| s.text(tags::SCANNING_SEQUENCE).is_some() && s.text(tags::SEQUENCE_VARIANT).is_some();
        match opts.modality {
            Modality::Ct => Self::Ct,
            Modality::Mr if opts.source.as_ref().is_some_and(acquired) => Self::Mr,
            _ => Self::MultiFrameSc,
        }
    }
}

/// How the samples are stored: the type and the RescaleIntercept (slope 1).
#[derive(Clone, Copy, Debug)]
struct Layout {
    stored: StoredType,
    intercept: f64,
}

impl Layout {
    fn choose(path: &Path, v: &Volume, iod: Iod, intercept: f64) -> Result<Self> {
        // The MR Image IOD has no rescale: values are stored as they are.
        let intercept = if iod == Iod::Mr { 0.0 } else { intercept };
        match choose_stored(path, v, intercept)? {
            // The CT and MR Image IODs store 16 bits; only Secondary Capture has a byte form.
            StoredType::U8 if iod != Iod::MultiFrameSc => Ok(Self { stored: StoredType::U16, intercept }),
            // Multi-frame Grayscale Word SC stores unsigned samples: shift them by the smallest value,
            // which the RescaleIntercept adds back (the i16 range spans at most 65535).
            StoredType::I16 if iod == Iod::MultiFrameSc => {
                let lo = v.data.finite_range().map_or(0.0, |(lo, _)| lo);
                Ok(Self { stored: StoredType::U16, intercept: intercept + (lo - intercept).floor() })
            }
            stored => Ok(Self { stored, intercept }),
        }
    }

    const fn bits(self) -> u16 {
        if matches!(self.stored, StoredType::U8) { 8 } else { 16 }
    }
}

/// Everything needed to write the files: the IOD, the layout, the slice order and the attributes
/// every file shares.
struct Plan {
    iod: Iod,
    layout: Layout,
    /// The k of each slice, in the order written (ascending along the image normal).
    k_order: Vec<usize>,
    /// The attributes shared by every file (all but the per-slice ones and the pixels).
    common: InMemDicomObject,
}

/// The patient, study and series attributes of type 2 that every object written has, empty when unknown.
pub(crate) const PATIENT_STUDY_TYPE2: [(Tag, VR); 10] = [
    (tags::PATIENT_NAME, VR::PN),
    (tags::PATIENT_ID, VR::LO),
    (tags::PATIENT_BIRTH_DATE, VR::DA),
    (tags::PATIENT_SEX, VR::CS),
    (tags::STUDY_DATE, VR::DA),
    (tags::STUDY_TIME, VR::TM),
    (tags::REFERRING_PHYSICIAN_NAME, VR::PN),
    (tags::STUDY_ID, VR::SH),
    (tags::ACCESSION_NUMBER, VR::SH),
    (tags::LATERALITY, VR::CS),
];

/// Puts `tag`, empty, into `obj` unless it is there (a type 2 attribute whose value is not known).
pub(crate) fn ensure(obj: &mut InMemDicomObject, tag: Tag, vr: VR) {
    if obj.get(tag).is_none() {
        obj.put(empty_el(tag, vr));
    }
}

/// An image reference: its Referenced SOP Class UID and Referenced SOP Instance UID.
pub(crate) fn reference_item(i: &dicom_source::SourceInstance) -> InMemDicomObject {
    InMemDicomObject::from_element_iter([
        text_el(tags::REFERENCED_SOP_CLASS_UID, VR::UI, &i.sop_class_uid),
        text_el(tags::REFERENCED_SOP_INSTANCE_UID, VR::UI, &i.sop_instance_uid),
    ])
}

/// Shortest names for building elements.
pub(crate) fn text_el(tag: Tag, vr: VR, s: &str) -> DataElement<InMemDicomObject> {
    DataElement::new(tag, vr, PrimitiveValue::from(s.to_string()))
}

pub(crate) fn multi_el(tag: Tag, vr: VR, values: &[&str]) -> DataElement<InMemDicomObject> {
    DataElement::new(tag, vr, PrimitiveValue::Strs(values.iter().map(|s| (*s).to_string()).collect()))
}

pub(crate) fn empty_el(tag: Tag, vr: VR) -> DataElement<InMemDicomObject> {
    DataElement::new(tag, vr, PrimitiveValue::Empty)
}

fn us_el(tag: Tag, value: u16) -> DataElement<InMemDicomObject> {
    DataElement::new(tag, VR::US, PrimitiveValue::from(value))
}

pub(crate) fn seq_el(tag: Tag, items: Vec<InMemDicomObject>) -> DataElement<InMemDicomObject> {
    DataElement::new(tag, VR::SQ, DataSetSequence::from(items))
}

/// A code sequence item: (code value, coding scheme, meaning).
pub(crate) fn code_item(value: &str, scheme: &str, meaning: &str) -> InMemDicomObject {
    InMemDicomObject::from_element_iter([
        text_el(tags::CODE_VALUE, VR::SH, value),
        text_el(tags::CODING_SCHEME_DESIGNATOR, VR::SH, scheme),
        text_el(tags::CODE_MEANING, VR::LO, meaning),
    ])
}

/// Text fit for a one-valued string VR of at most `max` bytes: no backslash (the value
/// separator) or control characters, cut at a character boundary.
pub(crate) fn one_value(s: &str, max: usize) -> String {
    let clean: String = s.chars().map(|c| if c == '\\' || c.is_control() { ' ' } else { c }).collect();
    let clean = clean.trim();
    let mut end = clean.len().min(max);
    while !clean.is_char_boundary(end) {
        end -= 1;
    }
    clean[..end].trim_end().to_string()
}

/// A Modality (CS) value: upper-case letters, digits, space and underscore, at most 16.
fn modality_code(m: &Modality) -> String {
    let code = match m {
        Modality::Ct => "CT".to_string(),
        Modality::Mr => "MR".to_string(),
        Modality::Other(s) => s
            .trim()
            .to_ascii_uppercase()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == ' ' || *c == '_')
            .take(16)
            .collect(),
        Modality::Unknown => String::new(),
    };
    if code.trim().is_empty() { "OT".into() } else { code }
}

/// PatientOrientation's letters for a direction in LPS: the axes it leans along, the strongest
/// first (+x = L, +y = P, +z = H), as PS3.3 C.7.6.1.1.1 writes oblique directions.
fn orientation_letters(v: [f64; 3]) -> String {
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&a, &b| v[b].abs().total_cmp(&v[a].abs()));
    let letters = [('L', 'R'), ('P', 'A'), ('H', 'F')];
    let s: String = axes
        .iter()
        .filter(|&&a| v[a].abs() > 1e-3)
        .map(|&a| if v[a] > 0.0 { letters[a].0 } else { letters[a].1 })
        .collect();
    if s.is_empty() { "L".into() } else { s }
}

/// Now, in UTC: (DA `YYYYMMDD`, TM `HHMMSS`). Civil date from days since 1970 (H. Hinnant's
/// `civil_from_days`).
pub(crate) fn utc_now() -> (String, String) {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    (format!("{year:04}{month:02}{day:02}"), format!("{:02}{:02}{:02}", rem / 3600, rem / 60 % 60, rem % 60))
}

/// True when some text in `obj` (nested items included) is not ASCII.
pub(crate) fn has_non_ascii(obj: &InMemDicomObject) -> bool {
    obj.iter().any(|e| match e.value() {
        dicom_core::value::Value::Sequence(seq) => seq.items().iter().any(has_non_ascii),
        v => v.to_str().is_ok_and(|s| !s.is_ascii()),
    })
}

pub(crate) const VERSION: &str = env!("CARGO_PKG_VERSION");

impl Plan {
    fn new(dir: &Path, volume: &Volume, opts: &DicomSeriesOptions) -> Result<Self> {
        let iod = Iod::choose(opts);
        let layout = Layout::choose(dir, volume, iod, opts.rescale_intercept)?;
        let [nx, ny, nz] = volume.dims;
        let (rows, cols) = (
            u16::try_from(ny).map_err(|_| Error::invalid(dir, format!("{ny} rows do not fit DICOM's u16")))?,
            u16::try_from(nx).map_err(|_| Error::invalid(dir, format!("{nx} columns do not fit DICOM's u16")))?,
        );
        if iod == Iod::MultiFrameSc {
            // One object holds every frame: its PixelData length is a u32 (and 0xFFFFFFFF means undefined).
            let bytes = (nx * ny * nz).checked_mul(usize::from(layout.bits() / 8));
            if bytes.is_none_or(|b| b >= u32::MAX as usize - 1) {
                return Err(Error::invalid(
                    dir,
                    format!("{nx}×{ny}×{nz} voxels do not fit one multi-frame DICOM object (4 GiB of pixel data)"),
                ));
            }
        }
        let dirs = direction_cosines(&volume.lps_from_index);
        let spacing = spacing_mm(&volume.lps_from_index);
        let (row, col) = ([dirs[(0, 0)], dirs[(1, 0)], dirs[(2, 0)]], [dirs[(0, 1)], dirs[(1, 1)], dirs[(2, 1)]]);
        let normal =
            [row[1] * col[2] - row[2] * col[1], row[2] * col[0] - row[0] * col[2], row[0] * col[1] - row[1] * col[0]];
        let k_step = volume.lps_from_index.linear().column(2).into_owned();
        let ascending = normal[0] * k_step[0] + normal[1] * k_step[1] + normal[2] * k_step[2] >= 0.0;
        let k_order: Vec<usize> = if ascending { (0..nz).collect() } else { (0..nz).rev().collect() };

        let source = opts.source.as_ref();
        let (date, time) = utc_now();
        let mut obj = InMemDicomObject::new_empty();
        let sop_class = match (iod, layout.stored) {
            (Iod::Ct, _) => uids::CT_IMAGE_STORAGE,
            (Iod::Mr, _) => uids::MR_IMAGE_STORAGE,
            (Iod::MultiFrameSc, StoredType::U8) => uids::MULTI_FRAME_GRAYSCALE_BYTE_SECONDARY_CAPTURE_IMAGE_STORAGE,
            (Iod::MultiFrameSc, _) => uids::MULTI_FRAME_GRAYSCALE_WORD_SECONDARY_CAPTURE_IMAGE_STORAGE,
        };
        // SOP Common.
        obj.put(text_el(tags::SOP_CLASS_UID, VR::UI, sop_class));
        obj.put(text_el(tags::INSTANCE_CREATION_DATE, VR::DA, &date));
        obj.put(text_el(tags::INSTANCE_CREATION_TIME, VR::TM, &time));
        obj.put(text_el(tags::TIMEZONE_OFFSET_FROM_UTC, VR::SH, "+0000"));
        let contributing = InMemDicomObject::from_element_iter([
            text_el(tags::MANUFACTURER, VR::LO, "warpbench"),
            text_el(tags::MANUFACTURER_MODEL_NAME, VR::LO, "warpbench"),
            text_el(tags::SOFTWARE_VERSIONS, VR::LO, VERSION),
            text_el(tags::CONTRIBUTION_DATE_TIME, VR::DT, &format!("{date}{time}+0000")),
            text_el(tags::CONTRIBUTION_DESCRIPTION, VR::ST, "resampled through a landmark-based warp"),
            seq_el(tags::PURPOSE_OF_REFERENCE_CODE_SEQUENCE, vec![code_item("109102", "DCM", "Processing Equipment")]),
        ]);
        obj.put(seq_el(tags::CONTRIBUTING_EQUIPMENT_SEQUENCE, vec![contributing]));

        // Patient, study, series-level patient attributes and equipment: copied, or empty (type 2).
        let copy = |obj: &mut InMemDicomObject, list: &[Tag]| {
            for &tag in list {
                if let Some(e) = source.and_then(|s| s.attribute(tag)) {
                    obj.put(e.clone());
                }
            }
        };
        copy(&mut obj, dicom_source::PATIENT);
        copy(&mut obj, dicom_source::STUDY);
        copy(&mut obj, dicom_source::SERIES);
        copy(&mut obj, dicom_source::EQUIPMENT);
        if source.is_none() {
            obj.put(text_el(tags::PATIENT_NAME, VR::PN, &one_value(&opts.patient_name, 64)));
            obj.put(text_el(tags::PATIENT_ID, VR::LO, &one_value(&opts.patient_id, 64)));
            // A new study, made now.
            obj.put(text_el(tags::STUDY_DATE, VR::DA, &date));
            obj.put(text_el(tags::STUDY_TIME, VR::TM, &time));
            obj.put(text_el(tags::MANUFACTURER, VR::LO, "warpbench"));
            obj.put(text_el(tags::MANUFACTURER_MODEL_NAME, VR::LO, "warpbench"));
            obj.put(text_el(tags::SOFTWARE_VERSIONS, VR::LO, VERSION));
        }
        for (tag, vr) in PATIENT_STUDY_TYPE2.into_iter().chain([(tags::MANUFACTURER, VR::LO)]) {
            ensure(&mut obj, tag, vr);
        }
        if iod != Iod::MultiFrameSc {
            ensure(&mut obj, tags::PATIENT_POSITION, VR::CS);
        }
        let study_uid = source.and_then(|s| s.study_instance_uid.clone()).unwrap_or_else(new_uid);
        obj.put(text_el(tags::STUDY_INSTANCE_UID, VR::UI, &study_uid));

        // General Series and Frame of Reference (new: the grid is not the source's).
        obj.put(text_el(tags::MODALITY, VR::CS, &modality_code(&opts.modality)));
        obj.put(text_el(tags::SERIES_INSTANCE_UID, VR::UI, &new_uid()));
        obj.put(text_el(tags::SERIES_NUMBER, VR::IS, &opts.series_number.to_string()));
        obj.put(text_el(tags::SERIES_DATE, VR::DA, &date));
        obj.put(text_el(tags::SERIES_TIME, VR::TM, &time));
        obj.put(text_el(tags::SERIES_DESCRIPTION, VR::LO, &one_value(&opts.series_description, 64)));
        obj.put(text_el(tags::FRAME_OF_REFERENCE_UID, VR::UI, &new_uid()));
        obj.put(empty_el(tags::POSITION_REFERENCE_INDICATOR, VR::LO));

        // General Image and General Reference: derived, how, and from what.
        obj.put(multi_el(tags::PATIENT_ORIENTATION, VR::CS, &[&orientation_letters(row), &orientation_letters(col)]));
        obj.put(text_el(tags::CONTENT_DATE, VR::DA, &date));
        obj.put(text_el(tags::CONTENT_TIME, VR::TM, &time));
        let image_type: &[&str] = match iod {
            Iod::Ct => &["DERIVED", "SECONDARY", "AXIAL"],
            Iod::Mr => &["DERIVED", "SECONDARY", "OTHER"],
            Iod::MultiFrameSc => &["DERIVED", "SECONDARY"],
        };
        obj.put(multi_el(tags::IMAGE_TYPE, VR::CS, image_type));
        let derivation = format!("{} (resampled by warpbench {VERSION})", opts.series_description);
        obj.put(text_el(tags::DERIVATION_DESCRIPTION, VR::ST, &one_value(&derivation, 1024)));
        obj.put(seq_el(tags::DERIVATION_CODE_SEQUENCE, vec![code_item("113085", "DCM", "Spatial resampling")]));
        if let Some(s) = source
            && !s.instances.is_empty()
        {
            let items = s
                .instances
                .iter()
                .map(|i| {
                    let mut item = reference_item(i);
                    item.put(seq_el(
                        tags::PURPOSE_OF_REFERENCE_CODE_SEQUENCE,
                        vec![code_item("121322", "DCM", "Source image for image processing operation")],
                    ));
                    item
                })
                .collect();
            obj.put(seq_el(tags::SOURCE_IMAGE_SEQUENCE, items));
        }

        // Image Pixel.
        obj.put(us_el(tags::SAMPLES_PER_PIXEL, 1));
        obj.put(text_el(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2"));
        obj.put(us_el(tags::ROWS, rows));
        obj.put(us_el(tags::COLUMNS, cols));
        let bits = layout.bits();
        obj.put(us_el(tags::BITS_ALLOCATED, bits));
        obj.put(us_el(tags::BITS_STORED, bits));
        obj.put(us_el(tags::HIGH_BIT, bits - 1));
        obj.put(us_el(tags::PIXEL_REPRESENTATION, u16::from(layout.stored == StoredType::I16)));

        let iop = [row[0], row[1], row[2], col[0], col[1], col[2]];
        let pixel_spacing = ds_multi(&[spacing[1], spacing[0]]);
        match iod {
            Iod::Ct | Iod::Mr => {
                // Image Plane (positions per slice).
                obj.put(text_el(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, &ds_multi(&iop)));
                obj.put(text_el(tags::PIXEL_SPACING, VR::DS, &pixel_spacing));
                obj.put(text_el(tags::SLICE_THICKNESS, VR::DS, &ds(spacing[2])));
            }
            Iod::MultiFrameSc => {
                // Geometry in the shared functional groups; positions per frame.
                let measures = InMemDicomObject::from_element_iter([
                    text_el(tags::PIXEL_SPACING, VR::DS, &pixel_spacing),
                    text_el(tags::SLICE_THICKNESS, VR::DS, &ds(spacing[2])),
                ]);
                let orientation = InMemDicomObject::from_element_iter([text_el(
                    tags::IMAGE_ORIENTATION_PATIENT,
                    VR::DS,
                    &ds_multi(&iop),
                )]);
                let shared = InMemDicomObject::from_element_iter([
                    seq_el(tags::PIXEL_MEASURES_SEQUENCE, vec![measures]),
                    seq_el(tags::PLANE_ORIENTATION_SEQUENCE, vec![orientation]),
                ]);
                obj.put(seq_el(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE, vec![shared]));
                // SC Equipment, SC Image, SC Multi-frame Image.
                obj.put(text_el(tags::CONVERSION_TYPE, VR::CS, "WSD"));
                obj.put(text_el(tags::SECONDARY_CAPTURE_DEVICE_MANUFACTURER, VR::LO, "warpbench"));
                obj.put(text_el(tags::SECONDARY_CAPTURE_DEVICE_MANUFACTURER_MODEL_NAME, VR::LO, "warpbench"));
                obj.put(text_el(tags::SECONDARY_CAPTURE_DEVICE_SOFTWARE_VERSIONS, VR::LO, VERSION));
                obj.put(text_el(tags::DATE_OF_SECONDARY_CAPTURE, VR::DA, &date));
                obj.put(text_el(tags::TIME_OF_SECONDARY_CAPTURE, VR::TM, &time));
                obj.put(text_el(tags::BURNED_IN_ANNOTATION, VR::CS, "NO"));
                // Frames step along the normal: the increment is their SliceLocationVector (mm along
                // it). One frame has no increment, and then the pointer must be absent.
                if k_order.len() > 1 {
                    obj.put(DataElement::new(
                        tags::FRAME_INCREMENT_POINTER,
                        VR::AT,
                        PrimitiveValue::Tags([tags::SLICE_LOCATION_VECTOR].into_iter().collect()),
                    ));
                    let locations: Vec<f64> = k_order
                        .iter()
                        .map(|&k| {
                            let p = volume.lps_from_index.apply_point(Point3::new(0.0, 0.0, k as f64)).coords();
                            p[0] * normal[0] + p[1] * normal[1] + p[2] * normal[2]
                        })
                        .collect();
                    obj.put(text_el(tags::SLICE_LOCATION_VECTOR, VR::DS, &ds_multi(&locations)));
                }
                obj.put(text_el(tags::PRESENTATION_LUT_SHAPE, VR::CS, "IDENTITY"));
            }
        }
        match iod {
            Iod::Ct => {
                obj.put(text_el(tags::RESCALE_INTERCEPT, VR::DS, &ds(layout.intercept)));
                obj.put(text_el(tags::RESCALE_SLOPE, VR::DS, "1"));
                copy(&mut obj, dicom_source::CT_ACQUISITION);
                ensure(&mut obj, tags::KVP, VR::DS);
                ensure(&mut obj, tags::ACQUISITION_NUMBER, VR::IS);
            }
            Iod::Mr => {
                copy(&mut obj, dicom_source::MR_ACQUISITION);
                for (tag, vr) in [
                    (tags::SCAN_OPTIONS, VR::CS),
                    (tags::MR_ACQUISITION_TYPE, VR::CS),
                    (tags::REPETITION_TIME, VR::DS),
                    (tags::ECHO_TIME, VR::DS),
                    (tags::ECHO_TRAIN_LENGTH, VR::IS),
                ] {
                    ensure(&mut obj, tag, vr);
                }
                let inversion = source.and_then(|s| s.text(tags::SCANNING_SEQUENCE)).is_some_and(|s| s.contains("IR"));
                if inversion {
                    ensure(&mut obj, tags::INVERSION_TIME, VR::DS);
                }
            }
            Iod::MultiFrameSc => {
                obj.put(text_el(tags::RESCALE_INTERCEPT, VR::DS, &ds(layout.intercept)));
                obj.put(text_el(tags::RESCALE_SLOPE, VR::DS, "1"));
                obj.put(text_el(tags::RESCALE_TYPE, VR::LO, "US"));
            }
        }
        if has_non_ascii(&obj) {
            // dicom-rs encodes the text in the character set the data set names.
            obj.put(text_el(tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 192"));
        }
        Ok(Self { iod, layout, k_order, common: obj })
    }

    fn file_count(&self) -> usize {
        if self.iod == Iod::MultiFrameSc { 1 } else { self.k_order.len() }
    }

    /// The `n`-th object of the series (in writing order).
    fn object(&self, dir: &Path, volume: &Volume, n: usize) -> Result<InMemDicomObject> {
        let mut obj = self.common.clone();
        obj.put(text_el(tags::SOP_INSTANCE_UID, VR::UI, &new_uid()));
        let number = i32::try_from(n + 1).unwrap_or(i32::MAX);
        obj.put(text_el(tags::INSTANCE_NUMBER, VR::IS, &number.to_string()));
        let ipp = |k: usize| ds_multi(&volume.lps_from_index.apply_point(Point3::new(0.0, 0.0, k as f64)).coords());
        let slice_bytes = volume.dims[0] * volume.dims[1] * usize::from(self.layout.bits() / 8);
        let pixels = if self.iod == Iod::MultiFrameSc {
            let frames = self.k_order.len();
            let mut pixels = Vec::new();
            pixels.try_reserve_exact(slice_bytes * frames + 1).map_err(|_| {
                Error::new(
                    dir,
                    crate::ErrorKind::OutOfMemory {
                        what: "the DICOM pixel data".into(),
                        bytes: (slice_bytes * frames) as u128,
                    },
                )
            })?;
            let per_frame = self
                .k_order
                .iter()
                .map(|&k| {
                    let position =
                        InMemDicomObject::from_element_iter([text_el(tags::IMAGE_POSITION_PATIENT, VR::DS, &ipp(k))]);
                    InMemDicomObject::from_element_iter([seq_el(tags::PLANE_POSITION_SEQUENCE, vec![position])])
                })
                .collect();
            obj.put(seq_el(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE, per_frame));
            obj.put(text_el(tags::NUMBER_OF_FRAMES, VR::IS, &frames.to_string()));
            for &k in &self.k_order {
                push_slice(&mut pixels, volume, k, self.layout);
            }
            if pixels.len() % 2 == 1 {
                pixels.push(0);
            }
            pixels
        } else {
            let k = self.k_order[n];
            obj.put(text_el(tags::IMAGE_POSITION_PATIENT, VR::DS, &ipp(k)));
            let mut pixels = Vec::with_capacity(slice_bytes);
            push_slice(&mut pixels, volume, k, self.layout);
            pixels
        };
        let vr = if self.layout.bits() == 8 { VR::OB } else { VR::OW };
        obj.put(DataElement::new(tags::PIXEL_DATA, vr, PrimitiveValue::from(pixels)));
        Ok(obj)
    }
}

/// Appends slice `k` of `volume`, stored as `layout` says (the value minus the intercept), little-endian.
fn push_slice(pixels: &mut Vec<u8>, volume: &Volume, k: usize, layout: Layout) {
    let slice_len = volume.dims[0] * volume.dims[1];
    let shift = layout.intercept;
    sample::with_stored_type!(layout.stored, T => {
        for i in k * slice_len..(k + 1) * slice_len {
            T::from_f64(volume.data.get_f64(i) - shift).put_le(pixels);
        }
    });
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
