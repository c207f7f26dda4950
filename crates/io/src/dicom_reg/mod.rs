//! Writes a registration between two DICOM series as the DICOM objects radiotherapy planning systems, PACS viewers
//! and 3D Slicer's SlicerRT read to put a moving series (an MR, say) onto a fixed one (the planning CT) without
//! resampling either (modality `REG`): a linear one as a **Spatial Registration** ([`write()`], SOP Class
//! 1.2.840.10008.5.1.4.1.1.66.1), any other as a **Deformable Spatial Registration** ([`write_deformable`],
//! 1.2.840.10008.5.1.4.1.1.66.3).
//!
//! # The linear one
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
//! # The deformable one
//! Also in the fixed series' patient, study and frame, its Deformable Registration Sequence has one item: the moving
//! series' frame as the Source Frame of Reference, and a Deformable Registration Grid in the fixed frame (Image
//! Position and Orientation, Grid Dimensions and Resolution) holding a vector D per grid point (Vector Grid Data,
//! float32, x fastest). DICOM reads it as the pull-back (PS3.3 C.20.3.1.1: the source point of a registered point x is
//! x + D(x)), the convention of ITK's displacement fields, so D is what `warpbench field` writes on the same grid. No
//! pre- or post-deformation matrix; the deformation applies to the whole source frame, so no image is referenced. The
//! grid's axes must be perpendicular (DICOM's depth axis is row × column); a grid whose k axis points the other way
//! is written from its last slice.
//!
//! Both are read back too ([`read_affine`], [`read_field`]): a starting transform and a displacement field.
//!
//! Checked with dicom3tools' `dciodvfy` (no error), read back, and against plastimatch 1.9.4, which writes the same
//! matrix for the same transform and the same grid and vectors for the same field (`crates/app/tests/dicom_export.rs`).

mod read;

use std::io::Write;
use std::path::Path;

use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use nalgebra::{Matrix4, Vector3};

use crate::dicom_source::{self, DicomSource};
use crate::dicom_write::{
    PATIENT_STUDY_TYPE2, VERSION, code_item, ds_multi, empty_el, ensure, has_non_ascii, new_uid, one_value,
    reference_item, seq_el, text_el, utc_now,
};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Point3, Transform};

pub use read::{RegistrationKind, looks_like_dicom, read_affine, read_field, registration_kind};

/// The Spatial Registration Storage SOP Class.
pub const SPATIAL_REGISTRATION_STORAGE: &str = "1.2.840.10008.5.1.4.1.1.66.1";

/// The Deformable Spatial Registration Storage SOP Class.
pub const DEFORMABLE_SPATIAL_REGISTRATION_STORAGE: &str = "1.2.840.10008.5.1.4.1.1.66.3";

/// How far from perpendicular a grid's axes may be (the cosine between two of them): DICOM's deformation grid has
/// none of the shear a gantry-tilted CT's grid can have.
const PERPENDICULAR_TOLERANCE: f64 = 1e-4;

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
    let (fixed_frame, moving_frame) = frames(path, reg.fixed, reg.moving)?;
    let m = reg.fixed_from_moving;
    let affine_row = m[(3, 0)] == 0.0 && m[(3, 1)] == 0.0 && m[(3, 2)] == 0.0 && m[(3, 3)].to_bits() == 1f64.to_bits();
    if !m.iter().all(|v| v.is_finite()) || !affine_row || m.fixed_view::<3, 3>(0, 0).determinant().abs() < 1e-12 {
        return Err(Error::invalid(path, format!("the registration matrix is not an invertible affine map: {m}")));
    }
    let matrix_type = MatrixType::of(&m);
    let mut obj = header(SPATIAL_REGISTRATION_STORAGE, reg.fixed, &fixed_frame, &reg.description);
    let identity = Matrix4::identity();
    obj.put(seq_el(
        tags::REGISTRATION_SEQUENCE,
        vec![
            registration_item(reg.fixed, &fixed_frame, &identity, MatrixType::Rigid),
            registration_item(reg.moving, &moving_frame, &reg.fixed_from_moving, matrix_type),
        ],
    ));
    // Its items reference the series' images, which the Common Instance Reference module then lists.
    common_instance_reference(&mut obj, reg.fixed, reg.moving);
    save(path, obj)?;
    Ok(matrix_type)
}

/// A deformable registration between two DICOM series, as [`write_deformable`] writes it: the pull-back sampled on
/// a grid in the fixed series' frame.
#[derive(Clone, Debug)]
pub struct DeformableRegistration<'a> {
    /// The series registered onto (its patient, study and Frame of Reference are the object's).
    pub fixed: &'a DicomSource,
    /// The series registered.
    pub moving: &'a DicomSource,
    /// Grid points along i, j, k.
    pub dims: [usize; 3],
    /// Where grid point (i, j, k) is in the fixed frame, LPS mm; its axes perpendicular.
    pub lps_from_index: Transform<Lps, Index>,
    /// D(x) = u(x) − x at each grid point x, LPS mm, i fastest: x of the fixed frame is x + D(x) in the moving one.
    pub displacements_lps: &'a [[f32; 3]],
    /// The Content Description and Series Description.
    pub description: String,
}

/// Writes `reg` to the file `path` as a Deformable Spatial Registration (module docs), atomically.
///
/// # Errors
/// As [`write()`] for the frames; a grid whose axes are not perpendicular, a count of vectors that is not the grid's,
/// a vector that is not finite; the write's.
pub fn write_deformable(path: &Path, reg: &DeformableRegistration) -> Result<()> {
    let (fixed_frame, moving_frame) = frames(path, reg.fixed, reg.moving)?;
    let [nx, ny, nz] = reg.dims;
    let n = crate::volume::checked_voxel_count(path, reg.dims)?;
    if reg.displacements_lps.len() != n {
        return Err(Error::invalid(path, format!("{} vectors for a grid of {n} points", reg.displacements_lps.len())));
    }
    if reg.displacements_lps.iter().any(|v| !v.iter().all(|x| x.is_finite())) {
        return Err(Error::invalid(path, "a displacement is not finite"));
    }
    let linear = reg.lps_from_index.linear();
    let spacing: [f64; 3] = std::array::from_fn(|a| linear.column(a).norm());
    if !spacing.iter().all(|s| s.is_finite() && *s > 0.0) {
        return Err(Error::invalid(path, format!("the grid's spacing {spacing:?} is not positive")));
    }
    let axes: [Vector3<f64>; 3] = std::array::from_fn(|a| linear.column(a) / spacing[a]);
    let sheared = (0..3).any(|a| (a + 1..3).any(|b| axes[a].dot(&axes[b]).abs() > PERPENDICULAR_TOLERANCE));
    if sheared {
        return Err(Error::unsupported(
            path,
            "the fixed grid's axes are not perpendicular (a tilted gantry's shear), which DICOM's deformation grid \
             cannot hold; export a displacement field (NIfTI, NRRD) instead",
        ));
    }
    // DICOM's grid steps along row × column: when the grid's k axis points the other way, its slices go in reverse.
    let flipped = axes[0].cross(&axes[1]).dot(&axes[2]) < 0.0;
    let first_k = if flipped { nz - 1 } else { 0 };
    let origin = reg.lps_from_index.apply_point(Point3::new(0.0, 0.0, first_k as f64)).coords();
    let mut vectors = Vec::new();
    vectors.try_reserve_exact(3 * n).map_err(|_| Error::invalid(path, "not enough memory for the vectors"))?;
    for step in 0..nz {
        let k = if flipped { nz - 1 - step } else { step };
        for v in &reg.displacements_lps[k * nx * ny..(k + 1) * nx * ny] {
            vectors.extend_from_slice(v);
        }
    }
    let orientation = [axes[0][0], axes[0][1], axes[0][2], axes[1][0], axes[1][1], axes[1][2]];
    let dims = |d: usize| u32::try_from(d).map_err(|_| Error::invalid(path, format!("{d} grid points per axis")));
    let grid = InMemDicomObject::from_element_iter([
        text_el(tags::IMAGE_POSITION_PATIENT, VR::DS, &ds_multi(&origin)),
        text_el(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, &ds_multi(&orientation)),
        DataElement::new(tags::GRID_DIMENSIONS, VR::UL, PrimitiveValue::from([dims(nx)?, dims(ny)?, dims(nz)?])),
        DataElement::new(tags::GRID_RESOLUTION, VR::FD, PrimitiveValue::from(spacing)),
        DataElement::new(tags::VECTOR_GRID_DATA, VR::OF, PrimitiveValue::F32(vectors.into())),
    ]);
    let item = InMemDicomObject::from_element_iter([
        text_el(tags::SOURCE_FRAME_OF_REFERENCE_UID, VR::UI, &moving_frame),
        seq_el(tags::REGISTRATION_TYPE_CODE_SEQUENCE, vec![code_item("125022", "DCM", "Fiducial Alignment")]),
        seq_el(tags::DEFORMABLE_REGISTRATION_GRID_SEQUENCE, vec![grid]),
    ]);
    let mut obj = header(DEFORMABLE_SPATIAL_REGISTRATION_STORAGE, reg.fixed, &fixed_frame, &reg.description);
    obj.put(seq_el(tags::DEFORMABLE_REGISTRATION_SEQUENCE, vec![item]));
    // The deformation applies to the whole source frame, so it names no images, and no Common Instance Reference
    // lists them.
    save(path, obj)
}

/// The two series' Frame of Reference UIDs, which must be valid and differ.
fn frames(path: &Path, fixed: &DicomSource, moving: &DicomSource) -> Result<(String, String)> {
    let frame = |s: &DicomSource| {
        s.frame_of_reference_uid.clone().ok_or_else(|| {
            Error::invalid(
                &s.path,
                "the series has no valid FrameOfReferenceUID (0020,0052), which a DICOM registration names",
            )
        })
    };
    let (fixed_frame, moving_frame) = (frame(fixed)?, frame(moving)?);
    if fixed_frame == moving_frame {
        return Err(Error::invalid(
            path,
            format!(
                "{} and {} share the Frame of Reference {fixed_frame}: the scanner has registered them already",
                fixed.path.display(),
                moving.path.display()
            ),
        ));
    }
    Ok((fixed_frame, moving_frame))
}

/// Adds the character set to `obj` and writes it to `path`, atomically.
fn save(path: &Path, mut obj: InMemDicomObject) -> Result<()> {
    if has_non_ascii(&obj) {
        // Copied names may hold any character: say they are UTF-8.
        obj.put(text_el(tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 192"));
    }
    let file = obj
        .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .map_err(|e| Error::new(path, crate::ErrorKind::Dicom(e.to_string())))?;
    crate::write_atomic(path, |w: &mut dyn Write| file.write_all(w).map_err(std::io::Error::other))
}

/// What both registration IODs share: SOP Common (of `sop_class`), the fixed series' patient and study, a new REG
/// series in the fixed frame, the equipment, and the Content Identification.
fn header(sop_class: &str, fixed: &DicomSource, fixed_frame: &str, description: &str) -> InMemDicomObject {
    let (date, time) = utc_now();
    let mut obj = InMemDicomObject::new_empty();
    // SOP Common.
    obj.put(text_el(tags::SOP_CLASS_UID, VR::UI, sop_class));
    obj.put(text_el(tags::SOP_INSTANCE_UID, VR::UI, &new_uid()));
    obj.put(text_el(tags::INSTANCE_CREATION_DATE, VR::DA, &date));
    obj.put(text_el(tags::INSTANCE_CREATION_TIME, VR::TM, &time));
    obj.put(text_el(tags::TIMEZONE_OFFSET_FROM_UTC, VR::SH, "+0000"));

    // Patient and General Study: the fixed series'; Laterality and the rest of General Series' patient attributes.
    for &tag in dicom_source::PATIENT.iter().chain(dicom_source::STUDY).chain(dicom_source::SERIES) {
        if let Some(e) = fixed.attribute(tag) {
            obj.put(e.clone());
        }
    }
    for (tag, vr) in PATIENT_STUDY_TYPE2 {
        ensure(&mut obj, tag, vr);
    }
    let study_uid = fixed.study_instance_uid.clone().unwrap_or_else(new_uid);
    obj.put(text_el(tags::STUDY_INSTANCE_UID, VR::UI, &study_uid));

    // General Series, Spatial Registration Series, Frame of Reference, General Equipment.
    obj.put(text_el(tags::MODALITY, VR::CS, "REG"));
    obj.put(text_el(tags::SERIES_INSTANCE_UID, VR::UI, &new_uid()));
    obj.put(text_el(tags::SERIES_NUMBER, VR::IS, "9901"));
    obj.put(text_el(tags::SERIES_DATE, VR::DA, &date));
    obj.put(text_el(tags::SERIES_TIME, VR::TM, &time));
    obj.put(text_el(tags::SERIES_DESCRIPTION, VR::LO, &one_value(description, 64)));
    obj.put(text_el(tags::FRAME_OF_REFERENCE_UID, VR::UI, fixed_frame));
    obj.put(empty_el(tags::POSITION_REFERENCE_INDICATOR, VR::LO));
    obj.put(text_el(tags::MANUFACTURER, VR::LO, "warpbench"));
    obj.put(text_el(tags::MANUFACTURER_MODEL_NAME, VR::LO, "warpbench"));
    obj.put(text_el(tags::SOFTWARE_VERSIONS, VR::LO, VERSION));
    // Enhanced General Equipment (the deformable IOD needs it; it does no harm in the other).
    obj.put(text_el(tags::DEVICE_SERIAL_NUMBER, VR::LO, "warpbench"));

    // Spatial Registration: Content Identification, the content's date and time, the two frames.
    obj.put(text_el(tags::INSTANCE_NUMBER, VR::IS, "1"));
    obj.put(text_el(tags::CONTENT_LABEL, VR::CS, "WARPBENCH_REG"));
    obj.put(text_el(tags::CONTENT_DESCRIPTION, VR::LO, &one_value(description, 64)));
    obj.put(empty_el(tags::CONTENT_CREATOR_NAME, VR::PN));
    obj.put(text_el(tags::CONTENT_DATE, VR::DA, &date));
    obj.put(text_el(tags::CONTENT_TIME, VR::TM, &time));
    obj
}

/// The Common Instance Reference module: the fixed series in the object's study (the fixed one's), the moving one
/// there or under its own study.
fn common_instance_reference(obj: &mut InMemDicomObject, fixed: &DicomSource, moving: &DicomSource) {
    let study_uid =
        obj.get(tags::STUDY_INSTANCE_UID).and_then(|e| e.to_str().ok()).map(|s| s.trim_end_matches('\0').to_owned());
    // Common Instance Reference: the fixed series in this study; the moving one here or under its own study. A
    // series is referenced by its images, so one without any (or without a valid UID) is named by its frame only.
    let fixed_series = referenced_series(fixed);
    let moving_series = referenced_series(moving);
    let mut here: Vec<InMemDicomObject> = fixed_series.into_iter().collect();
    match (moving.study_instance_uid.as_deref(), moving_series) {
        (Some(other), Some(series)) if Some(other) != study_uid.as_deref() => {
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
    source.instances.iter().map(reference_item).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    fn sources() -> (DicomSource, DicomSource) {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/dicom");
        let ct = DicomSource::read(&data.join("pydicom_ct5n"), None).expect("CT");
        let mr = DicomSource::read(&data.join("mixed_ct5n_mr_small/MR_small.dcm"), None).expect("MR");
        (ct, mr)
    }

    fn floats(obj: &InMemDicomObject, tag: dicom_core::Tag) -> Vec<f64> {
        let e = obj.get(tag).expect("element");
        e.to_multi_float64().expect("numbers")
    }

    /// A grid whose k axis points against row × column is written from its last slice, so that DICOM's grid point
    /// (i, j, k') is the grid's (i, j, n − 1 − k') and carries that point's vector.
    #[test]
    fn a_grid_stepping_against_the_normal_is_written_from_its_last_slice() {
        let (ct, mr) = sources();
        let dims = [2, 3, 4];
        let linear = Matrix3::from_diagonal(&Vector3::new(1.5, 2.0, -2.5));
        let lps_from_index = Transform::from_linear_translation(linear, [10.0, -20.0, 30.0]);
        let n = 24;
        let vectors: Vec<[f32; 3]> = (0..n).map(|v| [v as f32, 0.5, -(v as f32)]).collect();
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("dsr.dcm");
        let reg = DeformableRegistration {
            fixed: &ct,
            moving: &mr,
            dims,
            lps_from_index,
            displacements_lps: &vectors,
            description: "test".into(),
        };
        write_deformable(&path, &reg).expect("write");
        let obj = dicom_object::open_file(&path).expect("read back");
        let item = &obj.get(tags::DEFORMABLE_REGISTRATION_SEQUENCE).expect("sequence").items().expect("items")[0];
        let grid = &item.get(tags::DEFORMABLE_REGISTRATION_GRID_SEQUENCE).expect("grid").items().expect("items")[0];
        // The first slice written is k = 3, at z = 30 − 3 × 2.5; DICOM's depth axis is +z.
        assert_eq!(floats(grid, tags::IMAGE_POSITION_PATIENT), vec![10.0, -20.0, 22.5]);
        assert_eq!(floats(grid, tags::GRID_RESOLUTION), vec![1.5, 2.0, 2.5]);
        let data = grid.get(tags::VECTOR_GRID_DATA).expect("vectors").to_multi_float32().expect("OF");
        for k_dicom in 0..4 {
            for ij in 0..6 {
                let ours = (3 - k_dicom) * 6 + ij;
                let at = 3 * (k_dicom * 6 + ij);
                assert_eq!(data[at..at + 3], vectors[ours], "DICOM slice {k_dicom}, point {ij}");
            }
        }
    }

    #[test]
    fn a_sheared_grid_a_shared_frame_and_a_short_field_are_refused() {
        let (ct, mr) = sources();
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("bad.dcm");
        let vectors = [[0.0f32; 3]; 8];
        let sheared =
            Transform::from_linear_translation(Matrix3::new(1.0, 0.0, 0.3, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), [0.0; 3]);
        let straight = Transform::from_linear_translation(Matrix3::identity(), [0.0; 3]);
        let reg = |fixed, moving, lps_from_index, n: usize| DeformableRegistration {
            fixed,
            moving,
            dims: [2, 2, 2],
            lps_from_index,
            displacements_lps: &vectors[..n],
            description: String::new(),
        };
        for (r, words) in [
            (reg(&ct, &mr, sheared, 8), "not perpendicular"),
            (reg(&ct, &ct, straight, 8), "share the Frame of Reference"),
            (reg(&ct, &mr, straight, 7), "7 vectors for a grid of 8 points"),
        ] {
            let e = write_deformable(&path, &r).expect_err(words).to_string();
            assert!(e.contains(words), "{e}");
            assert!(!path.exists());
        }
    }

    #[test]
    fn matrices_are_typed_by_their_numbers() {
        let rotation = nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.3).into_inner();
        let of = |m: Matrix3<f64>| {
            let mut h = Matrix4::identity();
            h.fixed_view_mut::<3, 3>(0, 0).copy_from(&m);
            MatrixType::of(&h)
        };
        assert_eq!(of(rotation), MatrixType::Rigid);
        assert_eq!(of(rotation * 1.2), MatrixType::RigidScale);
        assert_eq!(of(rotation * Matrix3::from_diagonal(&Vector3::new(1.0, 1.1, 1.0))), MatrixType::Affine);
        // A reflection is not a rotation.
        assert_eq!(of(Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0))), MatrixType::Affine);
    }
}
