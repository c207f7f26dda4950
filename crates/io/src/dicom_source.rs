//! [`DicomSource`]: what a derived DICOM series takes from the DICOM series it was computed from.
//!
//! A warped volume written with [`crate::dicom_write::write_series`] belongs to the patient and the
//! study of the series its voxels came from (the moving volume), was acquired the way that series
//! was, and says which images it was derived from. [`DicomSource::read`] collects exactly that from
//! a series on disk:
//!
//! - the patient, study, series-level (Laterality, PatientPosition, BodyPartExamined) and equipment
//!   attributes, and the acquisition attributes of the CT and MR Image modules, as read from the
//!   first image of the series (in file-name order); nothing geometric (positions, orientations,
//!   spacings, matrices) and nothing private is kept;
//! - every image of the series as a (SOP Class UID, SOP Instance UID) pair, for the Source Image
//!   Sequence.
//!
//! The files are parsed only after the DICOM reader has checked them (element lengths and sequence
//! nesting, the guards of [`crate::dicom`]), so a hostile file is refused, never parsed blindly.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

/// The tag type and the standard tag names that [`DicomSource::attribute`] and [`DicomSource::text`] take,
/// re-exported so that callers need no DICOM crate of their own.
pub use dicom_core::Tag;
pub use dicom_dictionary_std::tags;
use dicom_object::mem::InMemElement;
use dicom_object::{InMemDicomObject, OpenFileOptions};

use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::volume::Volume;

/// Patient module (and Patient Study) attributes copied into a derived series.
pub(crate) const PATIENT: &[Tag] = &[
    tags::PATIENT_NAME,
    tags::PATIENT_ID,
    tags::ISSUER_OF_PATIENT_ID,
    tags::PATIENT_BIRTH_DATE,
    tags::PATIENT_BIRTH_TIME,
    tags::PATIENT_SEX,
    tags::OTHER_PATIENT_I_DS_SEQUENCE,
    tags::PATIENT_AGE,
    tags::PATIENT_SIZE,
    tags::PATIENT_WEIGHT,
    tags::PATIENT_IDENTITY_REMOVED,
    tags::DEIDENTIFICATION_METHOD,
    tags::DEIDENTIFICATION_METHOD_CODE_SEQUENCE,
];

/// General Study attributes copied (the StudyInstanceUID is handled on its own: it must be valid).
pub(crate) const STUDY: &[Tag] = &[
    tags::STUDY_DATE,
    tags::STUDY_TIME,
    tags::REFERRING_PHYSICIAN_NAME,
    tags::STUDY_ID,
    tags::ACCESSION_NUMBER,
    tags::STUDY_DESCRIPTION,
];

/// General Series attributes that describe the patient, not the series: copied.
pub(crate) const SERIES: &[Tag] = &[tags::LATERALITY, tags::PATIENT_POSITION, tags::BODY_PART_EXAMINED];

/// General Equipment attributes copied: the equipment that acquired the data.
pub(crate) const EQUIPMENT: &[Tag] = &[
    tags::MANUFACTURER,
    tags::INSTITUTION_NAME,
    tags::INSTITUTION_ADDRESS,
    tags::STATION_NAME,
    tags::INSTITUTIONAL_DEPARTMENT_NAME,
    tags::MANUFACTURER_MODEL_NAME,
    tags::DEVICE_SERIAL_NUMBER,
    tags::SOFTWARE_VERSIONS,
];

/// CT Image module (and Contrast/Bolus) acquisition attributes copied into a CT Image.
pub(crate) const CT_ACQUISITION: &[Tag] = &[
    tags::KVP,
    tags::ACQUISITION_NUMBER,
    tags::SCAN_OPTIONS,
    tags::DATA_COLLECTION_DIAMETER,
    tags::EXPOSURE_TIME,
    tags::X_RAY_TUBE_CURRENT,
    tags::EXPOSURE,
    tags::FILTER_TYPE,
    tags::CONVOLUTION_KERNEL,
    tags::CONTRAST_BOLUS_AGENT,
];

/// MR Image module (and Contrast/Bolus) acquisition attributes copied into an MR Image.
pub(crate) const MR_ACQUISITION: &[Tag] = &[
    tags::SCANNING_SEQUENCE,
    tags::SEQUENCE_VARIANT,
    tags::SCAN_OPTIONS,
    tags::MR_ACQUISITION_TYPE,
    tags::SEQUENCE_NAME,
    tags::ANGIO_FLAG,
    tags::REPETITION_TIME,
    tags::ECHO_TIME,
    tags::INVERSION_TIME,
    tags::NUMBER_OF_AVERAGES,
    tags::IMAGING_FREQUENCY,
    tags::IMAGED_NUCLEUS,
    tags::ECHO_NUMBERS,
    tags::MAGNETIC_FIELD_STRENGTH,
    tags::ECHO_TRAIN_LENGTH,
    tags::FLIP_ANGLE,
    tags::RECEIVE_COIL_NAME,
    tags::TRANSMIT_COIL_NAME,
    tags::ACQUISITION_NUMBER,
    tags::CONTRAST_BOLUS_AGENT,
];

/// One image of the source series, as a Source Image Sequence item names it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SourceInstance {
    pub sop_class_uid: String,
    pub sop_instance_uid: String,
}

/// The attributes a derived series copies from its DICOM source, and the source's images.
#[derive(Clone, Debug)]
pub struct DicomSource {
    /// The folder or file the source was read from (for messages).
    pub path: PathBuf,
    /// Modality (0008,0060) of the source, e.g. `CT`.
    pub modality: String,
    pub series_instance_uid: String,
    /// StudyInstanceUID (0020,000D), when the source has a valid one (a derived series joins that study).
    pub study_instance_uid: Option<String>,
    /// FrameOfReferenceUID (0020,0052), when the source has a valid one: the patient coordinate system its positions
    /// are in, which a spatial registration names ([`crate::dicom_reg`]).
    pub frame_of_reference_uid: Option<String>,
    /// Every image of the series that has valid UIDs, in file-name order.
    pub instances: Vec<SourceInstance>,
    /// The copied attributes (the lists above), from the first image.
    attributes: InMemDicomObject,
}

impl DicomSource {
    /// The source of `volume` read from `path`: `Ok(None)` unless `path` is DICOM (a folder or a
    /// `.dcm`/DICM file); the series is the volume's (its SeriesInstanceUID).
    pub fn for_volume(path: &Path, volume: &Volume) -> Result<Option<Self>> {
        if crate::Format::detect(path)? != crate::Format::Dicom {
            return Ok(None);
        }
        Self::read(path, volume.metadata.series_instance_uid.as_deref()).map(Some)
    }

    /// Reads the source series at `path` (a folder, or one DICOM file). In a folder with several
    /// series, `series_instance_uid` chooses one (else the error lists them).
    pub fn read(path: &Path, series_instance_uid: Option<&str>) -> Result<Self> {
        let files = checked_files(path, series_instance_uid)?;
        let mut first: Option<(PathBuf, InMemDicomObject)> = None;
        let mut instances = Vec::new();
        let mut series_uid = String::new();
        for file in files {
            let obj = OpenFileOptions::new()
                .read_until(tags::PIXEL_DATA)
                .open_file(&file)
                .map_err(|e| Error::new(&file, ErrorKind::Dicom(e.to_string())))?;
            if obj.meta().media_storage_sop_class_uid() == MEDIA_STORAGE_DIRECTORY || obj.get(tags::ROWS).is_none() {
                continue;
            }
            let uid = text(&obj, tags::SERIES_INSTANCE_UID).unwrap_or_default();
            if series_instance_uid.is_some_and(|want| want != uid) {
                continue;
            }
            if first.is_none() {
                series_uid.clone_from(&uid);
            }
            // An image whose UIDs are not valid cannot be referenced (validators reject the reference).
            if let (Some(sop_class_uid), Some(sop_instance_uid)) =
                (text(&obj, tags::SOP_CLASS_UID), text(&obj, tags::SOP_INSTANCE_UID))
                && is_valid_uid(&sop_class_uid)
                && is_valid_uid(&sop_instance_uid)
            {
                instances.push(SourceInstance { sop_class_uid, sop_instance_uid });
            }
            if first.is_none() {
                first = Some((file, obj.into_inner()));
            }
        }
        let Some((_, obj)) = first else {
            return Err(Error::invalid(path, "no DICOM image of the series to take the patient and study from"));
        };
        let mut attributes = InMemDicomObject::new_empty();
        for &tag in
            PATIENT.iter().chain(STUDY).chain(SERIES).chain(EQUIPMENT).chain(CT_ACQUISITION).chain(MR_ACQUISITION)
        {
            if let Some(e) = obj.get(tag) {
                attributes.put(e.clone());
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            modality: text(&obj, tags::MODALITY).unwrap_or_default(),
            series_instance_uid: series_uid,
            study_instance_uid: text(&obj, tags::STUDY_INSTANCE_UID).filter(|u| is_valid_uid(u)),
            frame_of_reference_uid: text(&obj, tags::FRAME_OF_REFERENCE_UID).filter(|u| is_valid_uid(u)),
            instances,
            attributes,
        })
    }

    /// A copied attribute, as read (`None` when the source lacks it or it is not one that is copied).
    #[must_use]
    pub fn attribute(&self, tag: Tag) -> Option<&InMemElement> {
        self.attributes.get(tag)
    }

    /// A copied attribute's text, trimmed; `None` when absent or empty.
    #[must_use]
    pub fn text(&self, tag: Tag) -> Option<String> {
        text(&self.attributes, tag)
    }
}

const MEDIA_STORAGE_DIRECTORY: &str = "1.2.840.10008.1.3.10";

fn text(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    let s = obj.get(tag)?.value().to_str().ok()?;
    let s = s.trim_matches(|c: char| c.is_whitespace() || c == '\0');
    (!s.is_empty()).then(|| s.to_string())
}

/// The files of the source at `path`, after the DICOM reader has checked their headers: for a
/// folder [`crate::dicom::list_series`] (which also resolves a missing `series_instance_uid`
/// when there is one series), for a file the reader up to its first decoding step.
fn checked_files(path: &Path, series_instance_uid: Option<&str>) -> Result<Vec<PathBuf>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_dir() {
        if !meta.is_file() {
            return Err(Error::new(path, ErrorKind::NotARegularFile { what: "not a file or a folder" }));
        }
        // The reader checks the headers, then reports "decoding slices": stop it there (a renamed
        // stage would only cost a full decode).
        let mut opts = LoadOptions::new().progress(|p: crate::Progress| {
            if p.stage == "decoding slices" { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
        });
        return match crate::dicom::read_files(&[path.to_path_buf()], &mut opts) {
            Ok(_) => Ok(vec![path.to_path_buf()]),
            Err(e) if matches!(e.kind, ErrorKind::Cancelled) => Ok(vec![path.to_path_buf()]),
            Err(e) => Err(e),
        };
    }
    let series = crate::dicom::list_series(path)?;
    match series_instance_uid {
        Some(uid) if !series.iter().any(|s| s.series_instance_uid == uid) => {
            return Err(Error::invalid(path, format!("no DICOM series with SeriesInstanceUID {uid}")));
        }
        None if series.len() > 1 => return Err(Error::new(path, ErrorKind::MultipleSeries(series))),
        _ => {}
    }
    let mut files = Vec::new();
    for entry in std::fs::read_dir(path).map_err(|e| Error::io(path, e))? {
        let p = entry.map_err(|e| Error::io(path, e))?.path();
        if std::fs::metadata(&p).is_ok_and(|m| m.is_file()) && has_preamble(&p) {
            files.push(p);
        }
    }
    files.sort();
    Ok(files)
}

/// True when the file carries the 128-byte preamble and `DICM` (as the reader requires in a folder).
fn has_preamble(p: &Path) -> bool {
    let mut head = [0u8; 132];
    std::fs::File::open(p).and_then(|mut f| crate::files::read_up_to(&mut f, &mut head)).is_ok_and(|n| n == 132)
        && crate::files::has_dicom_preamble(&head)
}

/// A UID as PS3.5 §9.1 allows it, with a registered root (1 = ISO, 2 = joint ISO/ITU-T; arc 0, ITU-T, is
/// not used for DICOM UIDs and validators reject it): at most 64 characters, components of digits
/// without leading zeros, at least two of them.
#[must_use]
pub fn is_valid_uid(uid: &str) -> bool {
    let parts: Vec<&str> = uid.split('.').collect();
    uid.len() <= 64
        && parts.len() >= 2
        && matches!(parts[0], "1" | "2")
        && parts
            .iter()
            .all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()) && (p == &"0" || !p.starts_with('0')))
}

#[cfg(test)]
mod tests {
    use super::is_valid_uid;

    #[test]
    fn uids_follow_the_standard() {
        for ok in ["1.2.840.10008.1.2.1", "2.25.123456789", "1.3.6.1.4.1.5962.1.2.0.977067310.6001.0"] {
            assert!(is_valid_uid(ok), "{ok}");
        }
        for bad in ["", "1", "0.0.0.0.2.8811.20010413115754.12432", "1.02.3", "1..2", "1.2.a", &"1.2".repeat(40)] {
            assert!(!is_valid_uid(bad), "{bad}");
        }
    }
}
