//! Writes a linear registration as a DICOM **Spatial Registration** object (SOP Class 1.2.840.10008.5.1.4.1.1.66.1,
//! modality `REG`): what radiotherapy planning systems, PACS viewers and 3D Slicer's SlicerRT read to put a moving
//! series (an MR, say) onto a fixed one (the planning CT) without resampling either.
//!
//! # What it holds
//! The object belongs to the fixed series' patient and study and lives in the fixed series' Frame of Reference (the
//! *registration* coordinate system). Its Registration Sequence has two items, each naming a Frame of Reference and
//! the images in it, with a 4 × 4 Frame of Reference Transformation Matrix:
//!
//! 1. the fixed series' frame, with the identity;
//! 2. the moving series' frame, with M = `fixed_from_moving`: M maps a point of the moving series' patient
//!    coordinates (LPS mm) to the fixed series' (PS3.3 C.20.2.1.1: the matrix transforms the *registered* frame into
//!    the *registration* frame). It is the inverse of the pull-back u = `moving_from_fixed` that ITK's files hold.
//!
//! The Frame of Reference Transformation Matrix Type says what M is, read from its numbers ([`MatrixType::of`]):
//! `RIGID` (a rotation and a translation), `RIGID_SCALE` (and one scale) or `AFFINE`. The Registration Type Code
//! Sequence says how it was found (DCM 125022 "Fiducial Alignment" for landmarks), and the Common Instance Reference
//! module lists every image of both series (the moving one under its own study when that differs).
//!
//! Deformable registrations (DICOM's Deformable Spatial Registration) are not written.
//!
//! Checked with dicom3tools' `dciodvfy` (no error), read back through GDCM, and against the matrix plastimatch 1.9.4
//! writes for the same transform (`crates/app/tests/dicom_reg.rs`).

use std::io::Write;
use std::path::Path;

use dicom_core::VR;
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use nalgebra::Matrix4;

use crate::dicom_source::{self, DicomSource};
use crate::dicom_write::{
    VERSION, code_item, ds_multi, empty_el, has_non_ascii, new_uid, one_value, seq_el, text_el, utc_now,
};
use crate::error::{Error, Result};

/// The Spatial Registration Storage SOP Class.
pub const SPATIAL_REGISTRATION_STORAGE: &str = "1.2.840.10008.5.1.4.1.1.66.1";

/// How far the linear part may be from a rotation (or a scaled one) and still be called one: far below what a
/// registration can tell (a 1e-6 relative error is 0.1 µm over 100 mm) and far above f64 rounding.
const RIGID_TOLERANCE: f64 = 1e-6;

/// The Frame of Reference Transformation Matrix Type (0070,030C).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MatrixType {
    /// A rotation and a translation.
    Rigid,
    /// A rotation, one scale and a translation.
    RigidScale,
    /// Any other invertible affine map.
    Affine,
}

impl MatrixType {
    /// The DICOM value: `RIGID`, `RIGID_SCALE` or `AFFINE`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Rigid => "RIGID",
            Self::RigidScale => "RIGID_SCALE",
            Self::Affine => "AFFINE",
        }
    }

    /// What `m`'s linear part is: Mᵀ M = s² I with det M > 0 is a scaled rotation, and a rotation when s = 1 (both
    /// within a relative 1e-6, far below what a registration can tell and far above f64 rounding).
    #[must_use]
    pub fn of(m: &Matrix4<f64>) -> Self {
        let a = m.fixed_view::<3, 3>(0, 0).into_owned();
        let gram = a.transpose() * a;
        let s2 = gram.trace() / 3.0;
        let scaled_rotation = a.determinant() > 0.0
            && s2 > 0.0
            && (gram - nalgebra::Matrix3::identity() * s2).iter().all(|v| v.abs() <= RIGID_TOLERANCE * s2);
        if !scaled_rotation {
            Self::Affine
        } else if (s2.sqrt() - 1.0).abs() <= RIGID_TOLERANCE {
            Self::Rigid
        } else {
            Self::RigidScale
        }
    }
}

/// A linear registration between two DICOM series, as [`write()`] writes it.
#[derive(Clone, Debug)]
pub struct SpatialRegistration<'a> {
    /// The series registered onto (its patient, study and Frame of Reference are the object's).
    pub fixed: &'a DicomSource,
    /// The series registered.
    pub moving: &'a DicomSource,
    /// M: moving patient coordinates → fixed patient coordinates, LPS mm (module docs). Its last row is (0, 0, 0, 1).
    pub fixed_from_moving: Matrix4<f64>,
    /// The Content Description and Series Description, e.g. the method and the number of pairs.
    pub description: String,
}

/// Writes `reg` to the file `path` (atomically; Explicit VR Little Endian, new Series and SOP Instance UIDs) and
/// returns the matrix type it wrote.
///
/// # Errors
/// A series without a valid Frame of Reference UID, both series in one Frame of Reference (they are registered
/// already), a matrix that is not finite or not invertible, or the write's.
pub fn write(path: &Path, reg: &SpatialRegistration) -> Result<MatrixType> {
    let frame = |s: &DicomSource| {
        s.frame_of_reference_uid.clone().ok_or_else(|| {
            Error::invalid(
                &s.path,
                "the series has no valid FrameOfReferenceUID (0020,0052), which a DICOM registration names",
            )
        })
    };
    let (fixed_frame, moving_frame) = (frame(reg.fixed)?, frame(reg.moving)?);
    if fixed_frame == moving_frame {
        return Err(Error::invalid(
            path,
            format!(
                "{} and {} share the Frame of Reference {fixed_frame}: the scanner has registered them already",
                reg.fixed.path.display(),
                reg.moving.path.display()
            ),
        ));
    }
    let m = reg.fixed_from_moving;
    let affine_row = m[(3, 0)] == 0.0 && m[(3, 1)] == 0.0 && m[(3, 2)] == 0.0 && m[(3, 3)].to_bits() == 1f64.to_bits();
    if !m.iter().all(|v| v.is_finite()) || !affine_row || m.fixed_view::<3, 3>(0, 0).determinant().abs() < 1e-12 {
        return Err(Error::invalid(path, format!("the registration matrix is not an invertible affine map: {m}")));
    }
    let matrix_type = MatrixType::of(&m);
    let obj = object(reg, &fixed_frame, &moving_frame, matrix_type);
    let file = obj
        .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .map_err(|e| Error::new(path, crate::ErrorKind::Dicom(e.to_string())))?;
    crate::write_atomic(path, |w: &mut dyn Write| file.write_all(w).map_err(std::io::Error::other))?;
    Ok(matrix_type)
}

/// The Spatial Registration IOD's attributes (module docs).
fn object(
    reg: &SpatialRegistration,
    fixed_frame: &str,
    moving_frame: &str,
    matrix_type: MatrixType,
) -> InMemDicomObject {
    let (date, time) = utc_now();
    let mut obj = InMemDicomObject::new_empty();
    // SOP Common.
    obj.put(text_el(tags::SOP_CLASS_UID, VR::UI, SPATIAL_REGISTRATION_STORAGE));
    obj.put(text_el(tags::SOP_INSTANCE_UID, VR::UI, &new_uid()));
    obj.put(text_el(tags::INSTANCE_CREATION_DATE, VR::DA, &date));
    obj.put(text_el(tags::INSTANCE_CREATION_TIME, VR::TM, &time));
    obj.put(text_el(tags::TIMEZONE_OFFSET_FROM_UTC, VR::SH, "+0000"));

    // Patient and General Study: the fixed series'; Laterality and the rest of General Series' patient attributes.
    for &tag in dicom_source::PATIENT.iter().chain(dicom_source::STUDY).chain(dicom_source::SERIES) {
        if let Some(e) = reg.fixed.attribute(tag) {
            obj.put(e.clone());
        }
    }
    for (tag, vr) in [
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
    ] {
        if obj.get(tag).is_none() {
            obj.put(empty_el(tag, vr));
        }
    }
    let study_uid = reg.fixed.study_instance_uid.clone().unwrap_or_else(new_uid);
    obj.put(text_el(tags::STUDY_INSTANCE_UID, VR::UI, &study_uid));

    // General Series, Spatial Registration Series, Frame of Reference, General Equipment.
    obj.put(text_el(tags::MODALITY, VR::CS, "REG"));
    obj.put(text_el(tags::SERIES_INSTANCE_UID, VR::UI, &new_uid()));
    obj.put(text_el(tags::SERIES_NUMBER, VR::IS, "9901"));
    obj.put(text_el(tags::SERIES_DATE, VR::DA, &date));
    obj.put(text_el(tags::SERIES_TIME, VR::TM, &time));
    obj.put(text_el(tags::SERIES_DESCRIPTION, VR::LO, &one_value(&reg.description, 64)));
    obj.put(text_el(tags::FRAME_OF_REFERENCE_UID, VR::UI, fixed_frame));
    obj.put(empty_el(tags::POSITION_REFERENCE_INDICATOR, VR::LO));
    obj.put(text_el(tags::MANUFACTURER, VR::LO, "warpbench"));
    obj.put(text_el(tags::MANUFACTURER_MODEL_NAME, VR::LO, "warpbench"));
    obj.put(text_el(tags::SOFTWARE_VERSIONS, VR::LO, VERSION));

    // Spatial Registration: Content Identification, the content's date and time, the two frames.
    obj.put(text_el(tags::INSTANCE_NUMBER, VR::IS, "1"));
    obj.put(text_el(tags::CONTENT_LABEL, VR::CS, "WARPBENCH_REG"));
    obj.put(text_el(tags::CONTENT_DESCRIPTION, VR::LO, &one_value(&reg.description, 64)));
    obj.put(empty_el(tags::CONTENT_CREATOR_NAME, VR::PN));
    obj.put(text_el(tags::CONTENT_DATE, VR::DA, &date));
    obj.put(text_el(tags::CONTENT_TIME, VR::TM, &time));
    let identity = Matrix4::identity();
    obj.put(seq_el(
        tags::REGISTRATION_SEQUENCE,
        vec![
            registration_item(reg.fixed, fixed_frame, &identity, MatrixType::Rigid),
            registration_item(reg.moving, moving_frame, &reg.fixed_from_moving, matrix_type),
        ],
    ));

    // Common Instance Reference: the fixed series in this study; the moving one here or under its own study. A
    // series is referenced by its images, so one without any (or without a valid UID) is named by its frame only.
    let fixed_series = referenced_series(reg.fixed);
    let moving_series = referenced_series(reg.moving);
    let mut here: Vec<InMemDicomObject> = fixed_series.into_iter().collect();
    match (reg.moving.study_instance_uid.as_deref(), moving_series) {
        (Some(other), Some(series)) if other != study_uid => {
            let study = InMemDicomObject::from_element_iter([
                text_el(tags::STUDY_INSTANCE_UID, VR::UI, other),
                seq_el(tags::REFERENCED_SERIES_SEQUENCE, vec![series]),
            ]);
            obj.put(seq_el(tags::STUDIES_CONTAINING_OTHER_REFERENCED_INSTANCES_SEQUENCE, vec![study]));
        }
        (_, series) => here.extend(series),
    }
    if !here.is_empty() {
        obj.put(seq_el(tags::REFERENCED_SERIES_SEQUENCE, here));
    }
    if has_non_ascii(&obj) {
        // Copied names may hold any character: say they are UTF-8.
        obj.put(text_el(tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 192"));
    }
    obj
}

/// One Registration Sequence item: the frame, its images, and the matrix into the registration frame.
fn registration_item(source: &DicomSource, frame: &str, m: &Matrix4<f64>, kind: MatrixType) -> InMemDicomObject {
    let rows: Vec<f64> = (0..4).flat_map(|r| (0..4).map(move |c| m[(r, c)])).collect();
    let matrix = InMemDicomObject::from_element_iter([
        text_el(tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX, VR::DS, &ds_multi(&rows)),
        text_el(tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX_TYPE, VR::CS, kind.name()),
    ]);
    let registration = InMemDicomObject::from_element_iter([
        seq_el(tags::REGISTRATION_TYPE_CODE_SEQUENCE, vec![code_item("125022", "DCM", "Fiducial Alignment")]),
        seq_el(tags::MATRIX_SEQUENCE, vec![matrix]),
    ]);
    let mut item = InMemDicomObject::from_element_iter([
        text_el(tags::FRAME_OF_REFERENCE_UID, VR::UI, frame),
        seq_el(tags::MATRIX_REGISTRATION_SEQUENCE, vec![registration]),
    ]);
    if !source.instances.is_empty() {
        item.put(seq_el(tags::REFERENCED_IMAGE_SEQUENCE, instance_items(source)));
    }
    item
}

/// A Referenced Series Sequence item: the series and every image of it; `None` for a series without a valid UID or
/// without images.
fn referenced_series(source: &DicomSource) -> Option<InMemDicomObject> {
    (dicom_source::is_valid_uid(&source.series_instance_uid) && !source.instances.is_empty()).then(|| {
        InMemDicomObject::from_element_iter([
            text_el(tags::SERIES_INSTANCE_UID, VR::UI, &source.series_instance_uid),
            seq_el(tags::REFERENCED_INSTANCE_SEQUENCE, instance_items(source)),
        ])
    })
}

/// (Referenced SOP Class UID, Referenced SOP Instance UID) of every image of `source`.
fn instance_items(source: &DicomSource) -> Vec<InMemDicomObject> {
    source
        .instances
        .iter()
        .map(|i| {
            InMemDicomObject::from_element_iter([
                text_el(tags::REFERENCED_SOP_CLASS_UID, VR::UI, &i.sop_class_uid),
                text_el(tags::REFERENCED_SOP_INSTANCE_UID, VR::UI, &i.sop_instance_uid),
            ])
        })
        .collect()
}
