//! A Deformable Spatial Registration with pre- and post-deformation matrices (what Velocity and MIM write when a
//! rigid registration came first) reads as the map PS3.3 C.20.3.1.1 defines: a registered point x samples the source
//! point M_post (M_pre x + D(x)). plastimatch's DSR of a known field, given matrices, is checked against that
//! formula at its grid points and between them.

use std::path::{Path, PathBuf};

use dicom_core::value::DataSetSequence;
use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;
use nalgebra::{Matrix4, Vector4};
use warpbench_io::dicom_reg;
use warpbench_io::elastix::{FieldInterpolation, FieldStep};
use warpbench_io::geometry::Point3;

fn plastimatch_dsr() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/dicom_reg/plastimatch_dsr.dcm")
}

/// A matrix item: `matrix` row by row, of type `kind`.
fn matrix_item(matrix: &Matrix4<f64>, kind: &str) -> InMemDicomObject {
    let values: Vec<String> = (0..4).flat_map(|r| (0..4).map(move |c| format!("{}", matrix[(r, c)]))).collect();
    InMemDicomObject::from_element_iter([
        DataElement::new(tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX, VR::DS, PrimitiveValue::Strs(values.into())),
        DataElement::new(tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX_TYPE, VR::CS, PrimitiveValue::from(kind)),
    ])
}

/// plastimatch's DSR with `pre` and `post` put into its grid's item, written to `out`.
fn with_matrices(out: &Path, pre: &Matrix4<f64>, post: &Matrix4<f64>) {
    let mut obj = dicom_object::open_file(plastimatch_dsr()).expect("the fixture");
    let mut registrations: Vec<InMemDicomObject> =
        obj.element(tags::DEFORMABLE_REGISTRATION_SEQUENCE).expect("registrations").items().expect("items").to_vec();
    let item = registrations
        .iter_mut()
        .find(|i| i.get(tags::DEFORMABLE_REGISTRATION_GRID_SEQUENCE).is_some())
        .expect("the grid's item");
    for (tag, m, kind) in [
        (tags::PRE_DEFORMATION_MATRIX_REGISTRATION_SEQUENCE, pre, "RIGID"),
        (tags::POST_DEFORMATION_MATRIX_REGISTRATION_SEQUENCE, post, "AFFINE"),
    ] {
        item.put(DataElement::new(tag, VR::SQ, DataSetSequence::from(vec![matrix_item(m, kind)])));
    }
    obj.put(DataElement::new(tags::DEFORMABLE_REGISTRATION_SEQUENCE, VR::SQ, DataSetSequence::from(registrations)));
    obj.write_to_file(out).expect("write");
}

/// A rotation of 0.2 rad about an oblique axis and a translation of several centimetres, as a rigid pre-registration.
fn rigid() -> Matrix4<f64> {
    let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(0.3, -0.5, 0.8));
    let r = nalgebra::Rotation3::from_axis_angle(&axis, 0.2);
    let mut m = r.to_homogeneous();
    m[(0, 3)] = 31.5;
    m[(1, 3)] = -12.25;
    m[(2, 3)] = 48.0;
    m
}

/// A small scaling and shear with a shift, as a post-registration.
fn affine() -> Matrix4<f64> {
    Matrix4::new(1.02, 0.01, 0.0, -3.0, 0.0, 0.97, 0.02, 1.5, -0.01, 0.0, 1.01, 2.25, 0.0, 0.0, 0.0, 1.0)
}

fn apply(m: &Matrix4<f64>, x: [f64; 3], w: f64) -> Vector4<f64> {
    m * Vector4::new(x[0], x[1], x[2], w)
}

#[test]
fn pre_and_post_matrices_compose_as_the_standard_orders_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let plain = dicom_reg::read_field(&plastimatch_dsr()).expect("plastimatch's DSR");
    let out = dir.path().join("with_matrices.dcm");
    let (pre, post) = (rigid(), affine());
    with_matrices(&out, &pre, &post);
    let read = dicom_reg::read_field(&out).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(read.dims, plain.dims);
    assert!(read.lps_from_index.max_abs_diff(&plain.lps_from_index) == 0.0, "the grid is the registered one");
    let [nx, ny, _] = plain.dims;
    let mut largest = 0.0f64;
    for (v, (d, d0)) in read.displacements_lps.iter().zip(&plain.displacements_lps).enumerate() {
        let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
        let x = plain.lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        // Source = M_post (M_pre x + D): the deformation offsets are added to the pre-transformed point.
        let moved = apply(&pre, x, 1.0) + Vector4::new(f64::from(d0[0]), f64::from(d0[1]), f64::from(d0[2]), 0.0);
        let source = post * moved;
        for a in 0..3 {
            let want = source[a] - x[a];
            // f32 storage of vectors up to ~60 mm: 2⁻²⁴ of that is 4e-6 mm.
            assert!((f64::from(d[a]) - want).abs() < 1e-5, "grid point {ijk:?}: {d:?}, the standard {want}");
            largest = largest.max(want.abs());
        }
    }
    assert!(largest > 20.0, "the matrices move the points ({largest} mm)");
    // Between grid points, the vectors read trilinearly (ITK's rule) give the standard's map with D interpolated.
    let step = |f| FieldStep::new(&out, out.clone(), f, FieldInterpolation::Linear).expect("a field step");
    let (with, without) = (step(read.clone()), step(plain.clone()));
    let dims = plain.dims.map(|n| n as f64);
    for n in 0..50 {
        let c = [0.37, 0.61, 0.83].map(|f: f64| ((n as f64 + 1.0) * f).fract());
        let ijk: [f64; 3] = std::array::from_fn(|a| c[a] * (dims[a] - 1.0));
        let x = plain.lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let d = without.apply(x);
        let moved = apply(&pre, x, 1.0) + Vector4::new(d[0] - x[0], d[1] - x[1], d[2] - x[2], 0.0);
        let want = post * moved;
        let got = with.apply(x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-4), "at {ijk:?}: {got:?}, the standard {want:?}");
    }
}

#[test]
fn a_matrix_that_is_not_affine_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("projective.dcm");
    let mut bad = rigid();
    bad[(3, 0)] = 0.01;
    with_matrices(&out, &bad, &Matrix4::identity());
    let e = dicom_reg::read_field(&out).expect_err("projective").to_string();
    assert!(e.contains("projective.dcm") && e.contains("pre-deformation matrix") && e.contains("not affine"), "{e}");
}
