//! Reading the registration objects back: a Spatial Registration as the affine pull-back u it holds
//! ([`read_affine`], a starting transform), a Deformable Spatial Registration as its grid of pull-back vectors
//! ([`read_field`], a displacement field). Either is told by its SOP Class UID ([`registration_kind`]).
//!
//! **Spatial.** Each Registration Sequence item names a Frame of Reference and the matrix Mᵢ that carries it into
//! the object's own (the registration frame; the Matrix Sequence's matrices are applied in their order). The item
//! in the object's frame is the fixed series' (the identity when absent); the one other item is the moving
//! series'. A fixed point x is M_f x in the registration frame, and the moving point there is M_m y, so
//! u(x) = M_m⁻¹ M_f x.
//!
//! **Deformable.** The item with a Deformable Registration Grid: a registered point x of the grid reads the source
//! point x + D(x) (PS3.3 C.20.3.1.1), the pull-back's displacement on that grid. With a pre- and a post-deformation
//! matrix (what planning systems write when a rigid registration came first: Velocity and MIM put it in the pre
//! matrix), the standard applies them to the registered point in this order: the source point is
//! M_post (M_pre x + D(x)). It is read as the pull-back's displacement at each grid point, M_post (M_pre x + D) − x;
//! between grid points trilinear interpolation of those vectors is the standard's map exactly, since it reproduces
//! the affine part and D enters linearly. Outside the grid a field is zero (the identity), where the standard leaves
//! the map to the implementation.

use std::path::Path;

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

use crate::error::{Error, Result};
use crate::geometry::{Point3, Transform};
use crate::itk_tfm::ItkAffine;
use crate::nifti::DisplacementField;
use crate::volume::{self, GeometrySource};

/// The two registration SOP Classes (the writer's constants, repeated so that this module imports nothing of its
/// parent).
const SPATIAL: &str = "1.2.840.10008.5.1.4.1.1.66.1";
const DEFORMABLE: &str = "1.2.840.10008.5.1.4.1.1.66.3";

/// Which registration a DICOM file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RegistrationKind {
    /// A Spatial Registration: matrices.
    Spatial,
    /// A Deformable Spatial Registration: a grid of vectors.
    Deformable,
}

/// Whether `head` (a file's first bytes) is a DICOM file: the preamble's `DICM`.
#[must_use]
pub fn looks_like_dicom(head: &[u8]) -> bool {
    crate::files::has_dicom_preamble(head)
}

/// The registration the DICOM file at `path` holds, by its SOP Class UID; `None` for any other object.
///
/// # Errors
/// A file that is not DICOM or cannot be parsed (the reader's guards first).
pub fn registration_kind(path: &Path) -> Result<Option<RegistrationKind>> {
    let obj = crate::dicom::open_checked(path)?;
    Ok(match text(&obj, tags::SOP_CLASS_UID).as_deref() {
        Some(SPATIAL) => Some(RegistrationKind::Spatial),
        Some(DEFORMABLE) => Some(RegistrationKind::Deformable),
        _ => None,
    })
}

/// Reads a Spatial Registration as the pull-back u = `moving_from_fixed` it holds (module docs).
///
/// # Errors
/// Another object, a registration of more than one moving frame, a matrix that is not 16 finite numbers or not an
/// invertible affine map; the file named.
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    let obj = object_of(path, SPATIAL, "a Spatial Registration (a matrix)")?;
    let own = text(&obj, tags::FRAME_OF_REFERENCE_UID).unwrap_or_default();
    let mut fixed = Matrix4::identity();
    let mut moving = Vec::new();
    for (n, item) in items(path, &obj, tags::REGISTRATION_SEQUENCE)?.iter().enumerate() {
        let m = item_matrix(path, item, n + 1)?;
        if text(item, tags::FRAME_OF_REFERENCE_UID).is_some_and(|f| f == own) {
            fixed = m;
        } else {
            moving.push(m);
        }
    }
    let [m] = moving.as_slice() else {
        return Err(Error::unsupported(
            path,
            format!("it registers {} frames onto its own; warpbench reads one moving frame", moving.len()),
        ));
    };
    let inverse = m.try_inverse().filter(|i| i.iter().all(|v| v.is_finite()));
    let u = inverse.ok_or_else(|| Error::invalid(path, "the moving frame's matrix is not invertible"))? * fixed;
    Ok(ItkAffine::from_offset(u.fixed_view::<3, 3>(0, 0).into_owned(), [u[(0, 3)], u[(1, 3)], u[(2, 3)]]))
}

/// Reads a Deformable Spatial Registration as its grid of pull-back vectors (module docs).
///
/// # Errors
/// Another object, no grid, a pre- or post-deformation matrix that is not affine, a grid whose numbers do not fit
/// together, vectors that are not finite, a grid too large for memory; the file named.
pub fn read_field(path: &Path) -> Result<DisplacementField> {
    let obj = object_of(path, DEFORMABLE, "a Deformable Spatial Registration (a grid of vectors)")?;
    let registrations = items(path, &obj, tags::DEFORMABLE_REGISTRATION_SEQUENCE)?;
    let with_grid: Vec<&InMemDicomObject> =
        registrations.iter().filter(|i| i.get(tags::DEFORMABLE_REGISTRATION_GRID_SEQUENCE).is_some()).collect();
    let [item] = with_grid.as_slice() else {
        return Err(Error::unsupported(path, format!("{} deformation grids; warpbench reads one", with_grid.len())));
    };
    let [pre, post] = [
        (tags::PRE_DEFORMATION_MATRIX_REGISTRATION_SEQUENCE, "pre"),
        (tags::POST_DEFORMATION_MATRIX_REGISTRATION_SEQUENCE, "post"),
    ]
    .map(|(tag, name)| match item.get(tag) {
        Some(_) => matrix_of(path, &items(path, item, tag)?[0], &format!("the {name}-deformation matrix")),
        None => Ok(Matrix4::identity()),
    });
    let (pre, post) = (pre?, post?);
    let grid = &items(path, item, tags::DEFORMABLE_REGISTRATION_GRID_SEQUENCE)?[0];
    let position = numbers(path, grid, tags::IMAGE_POSITION_PATIENT, 3)?;
    let orientation = numbers(path, grid, tags::IMAGE_ORIENTATION_PATIENT, 6)?;
    let spacing = numbers(path, grid, tags::GRID_RESOLUTION, 3)?;
    let dims: Vec<u32> = element(path, grid, tags::GRID_DIMENSIONS)?
        .to_multi_int()
        .map_err(|e| Error::invalid(path, format!("Grid Dimensions: {e}")))?;
    let dims: [usize; 3] = match dims.as_slice() {
        [x, y, z] => [*x as usize, *y as usize, *z as usize],
        other => return Err(Error::invalid(path, format!("Grid Dimensions holds {} numbers, not 3", other.len()))),
    };
    let n = volume::check_allocation(path, dims, 24, volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let row = Vector3::new(orientation[0], orientation[1], orientation[2]);
    let column = Vector3::new(orientation[3], orientation[4], orientation[5]);
    if !spacing.iter().all(|s| *s > 0.0) || (row.norm() - 1.0).abs() > 1e-3 || (column.norm() - 1.0).abs() > 1e-3 {
        return Err(Error::invalid(path, format!("the grid's orientation {orientation:?} or resolution {spacing:?}")));
    }
    let depth = row.cross(&column);
    let linear = Matrix3::from_columns(&[row * spacing[0], column * spacing[1], depth * spacing[2]]);
    let vectors = element(path, grid, tags::VECTOR_GRID_DATA)?
        .to_multi_float32()
        .map_err(|e| Error::invalid(path, format!("Vector Grid Data: {e}")))?;
    if vectors.len() != 3 * n {
        return Err(Error::invalid(
            path,
            format!("Vector Grid Data holds {} numbers, not 3 per point of {dims:?}", vectors.len()),
        ));
    }
    if let Some(i) = vectors.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(path, format!("the vector of grid point {} is not finite (undefined)", i / 3 + 1)));
    }
    let lps_from_index = Transform::from_linear_translation(linear, [position[0], position[1], position[2]]);
    let mut displacements_lps: Vec<[f32; 3]> = vectors.chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect();
    if pre != Matrix4::identity() || post != Matrix4::identity() {
        let [nx, ny, _] = dims;
        for (v, d) in displacements_lps.iter_mut().enumerate() {
            let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
            let [px, py, pz] = lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
            let x = Vector4::new(px, py, pz, 1.0);
            let moved = pre * x + Vector4::new(f64::from(d[0]), f64::from(d[1]), f64::from(d[2]), 0.0);
            let source = post * moved;
            *d = std::array::from_fn(|a| (source[a] - x[a]) as f32);
            if !d.iter().all(|c| c.is_finite()) {
                return Err(Error::invalid(
                    path,
                    format!("the source point of grid point {} is out of range ({source:?})", v + 1),
                ));
            }
        }
    }
    Ok(DisplacementField { dims, lps_from_index, geometry_source: GeometrySource::DicomPatient, displacements_lps })
}

/// The object at `path`, which must be of SOP Class `class` (`what`, in messages).
fn object_of(path: &Path, class: &str, what: &str) -> Result<dicom_object::DefaultDicomObject> {
    let obj = crate::dicom::open_checked(path)?;
    match text(&obj, tags::SOP_CLASS_UID) {
        Some(c) if c == class => Ok(obj),
        Some(c) => Err(Error::unsupported(path, format!("a DICOM object of SOP Class {c}, not {what}"))),
        None => Err(Error::invalid(path, "no SOP Class UID")),
    }
}

/// The product of an item's Matrix Registration Sequence's matrices, applied in their order (item `n`, 1-based).
fn item_matrix(path: &Path, item: &InMemDicomObject, n: usize) -> Result<Matrix4<f64>> {
    let registration = &items(path, item, tags::MATRIX_REGISTRATION_SEQUENCE)?[0];
    let mut m = Matrix4::identity();
    for (k, matrix) in items(path, registration, tags::MATRIX_SEQUENCE)?.iter().enumerate() {
        m = matrix_of(path, matrix, &format!("registration {n}'s matrix {}", k + 1))? * m;
    }
    Ok(m)
}

/// A Frame of Reference Transformation Matrix: 16 finite numbers, row by row, the last row (0, 0, 0, 1).
fn matrix_of(path: &Path, obj: &InMemDicomObject, what: &str) -> Result<Matrix4<f64>> {
    let v = numbers(path, obj, tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX, 16)?;
    let m = Matrix4::from_row_slice(&v);
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)] - 1.0];
    if last.iter().any(|x| x.abs() > 1e-9) {
        return Err(Error::invalid(path, format!("{what} is not affine: its last row is {:?}", &v[12..])));
    }
    Ok(m)
}

fn element<'a>(path: &Path, obj: &'a InMemDicomObject, tag: Tag) -> Result<&'a dicom_object::mem::InMemElement> {
    obj.get(tag).ok_or_else(|| Error::invalid(path, format!("{tag} is missing")))
}

/// The items of the sequence `tag`, at least one.
fn items<'a>(path: &Path, obj: &'a InMemDicomObject, tag: Tag) -> Result<&'a [InMemDicomObject]> {
    element(path, obj, tag)?
        .items()
        .filter(|i| !i.is_empty())
        .ok_or_else(|| Error::invalid(path, format!("{tag} is not a sequence with items")))
}

/// Exactly `count` finite numbers of the decimal-string (or binary) element `tag`.
fn numbers(path: &Path, obj: &InMemDicomObject, tag: Tag, count: usize) -> Result<Vec<f64>> {
    let v = element(path, obj, tag)?.to_multi_float64().map_err(|e| Error::invalid(path, format!("{tag}: {e}")))?;
    if v.len() != count || !v.iter().all(|x| x.is_finite()) {
        return Err(Error::invalid(path, format!("{tag} holds {v:?}, not {count} finite numbers")));
    }
    Ok(v)
}

fn text(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    let s = obj.get(tag)?.value().to_str().ok()?;
    let s = s.trim_matches(|c: char| c.is_whitespace() || c == '\0');
    (!s.is_empty()).then(|| s.to_owned())
}
