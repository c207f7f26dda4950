//! ITK's HDF5 transform files (`.h5`) against SimpleITK: its files (`data-scripts/itk_h5_sitk.py`: an affine, a
//! displacement field, a composite of the two as ANTs writes it, a composite of two affines) map points where
//! SimpleITK's `TransformPoint` maps them, and sample to the field its `TransformToDisplacementField` gives; bad
//! files are refused naming the file and the problem.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::displacement::{self, FieldDirection, FieldSource};
use warpbench_io::geometry::Point3;
use warpbench_io::itk_h5;

use crate::support::numbers;

fn itk_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk")
}

fn reference() -> Value {
    let text = std::fs::read_to_string(itk_dir().join("h5_reference.json")).expect("reference");
    serde_json::from_str(&text).expect("JSON")
}

fn case(name: &str) -> Value {
    reference()["cases"].as_array().expect("cases").iter().find(|c| c["file"] == name).expect("case").clone()
}

fn triples(v: &Value) -> Vec<[f64; 3]> {
    v.as_array().expect("array").iter().map(|p| numbers(p).try_into().expect("three numbers")).collect()
}

fn max_diff(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max)
}

/// The bound where a displacement field is involved: warpbench keeps a field's vectors in f32 (the field's own and
/// the sampled one), whose rounding is at most 2⁻²⁴ of a vector's length, here at most 10 mm: under 1e-6 mm a
/// vector, a few of them summed by the trilinear weights and the affine after it.
const FIELD_MM: f64 = 1e-5;

/// The bound for affines alone: read as doubles, composed in another order than ITK composes them.
const AFFINE_MM: f64 = 1e-9;

#[test]
fn every_file_maps_points_where_simpleitk_maps_them() {
    for case in reference()["cases"].as_array().expect("cases") {
        let file = case["file"].as_str().expect("file");
        let chain = itk_h5::read(&itk_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        let classes: Vec<String> =
            case["classes"].as_array().expect("classes").iter().map(|c| c.as_str().expect("class").into()).collect();
        assert_eq!(chain.steps.len(), classes.len(), "{file}: {classes:?}");
        let bound = if classes.iter().any(|c| c.contains("Displacement")) { FIELD_MM } else { AFFINE_MM };
        let points = triples(&case["points"]);
        let mut outside = 0;
        for (p, q) in points.iter().zip(triples(&case["transformed"])) {
            let y = chain.apply(*p);
            assert!(max_diff(y, q) < bound, "{file}: T({p:?}) = {y:?}, SimpleITK {q:?}");
            // Outside the field's grid ITK's T is the identity: SimpleITK gave the point back unchanged.
            outside += usize::from(file == "h5_field.h5" && max_diff(*p, q) == 0.0);
        }
        if file == "h5_field.h5" {
            // The points reach past the grid on every side: the law holds where the field is 0 and where it is not.
            assert!(outside > 0 && outside < points.len(), "{file}: {outside} of {} points outside", points.len());
        }
    }
}

#[test]
fn linear_files_read_as_one_affine_and_a_field_is_not_one() {
    for file in ["h5_affine.h5", "h5_linear_composite.h5"] {
        let case = case(file);
        let a = itk_h5::read_affine(&itk_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        for (p, q) in triples(&case["points"]).iter().zip(triples(&case["transformed"])) {
            assert!(max_diff(a.apply(*p), q) < AFFINE_MM, "{file}: {p:?}");
        }
    }
    let path = itk_dir().join("h5_composite.h5");
    let e = itk_h5::read_affine(&path).expect_err("a field is not a starting transform").to_string();
    assert!(e.contains("h5_composite.h5") && e.contains("DisplacementFieldTransform"), "{e}");
}

#[test]
fn fields_sample_as_simpleitks_transform_to_displacement_field() {
    for file in ["h5_field.h5", "h5_composite.h5"] {
        let case = case(file);
        let path = itk_dir().join(file);
        // Told apart by content, as every field: the name plays no part.
        let read = displacement::read_field_info(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((read.source, read.direction), (FieldSource::ItkHdf5, Some(FieldDirection::Pullback)), "{file}");
        let grid = &case["grid"];
        let size: Vec<usize> = numbers(&grid["size"]).iter().map(|&v| v as usize).collect();
        assert_eq!(read.field.dims.to_vec(), size, "{file}: dims");
        let (origin, spacing, direction) =
            (numbers(&grid["origin"]), numbers(&grid["spacing"]), numbers(&grid["direction"]));
        let want = triples(&case["displacements"]);
        assert_eq!(read.field.displacements_lps.len(), want.len(), "{file}");
        let [nx, ny, _] = read.field.dims;
        for (v, (d, q)) in read.field.displacements_lps.iter().zip(&want).enumerate() {
            let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
            // The voxel centre by SimpleITK's geometry, to check the grid as well as the vectors.
            let x: [f64; 3] = std::array::from_fn(|r| {
                origin[r] + (0..3).map(|c| direction[3 * r + c] * spacing[c] * ijk[c]).sum::<f64>()
            });
            let ours = read.field.lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
            assert!(max_diff(ours, x) < AFFINE_MM, "{file}: voxel {ijk:?} at {ours:?}, SimpleITK {x:?}");
            let d = d.map(f64::from);
            assert!(max_diff(d, *q) < FIELD_MM, "{file}: D at voxel {ijk:?} = {d:?}, SimpleITK {q:?}");
        }
    }
    let e = displacement::read_field_info(&itk_dir().join("h5_affine.h5")).expect_err("no field").to_string();
    assert!(e.contains("h5_affine.h5") && e.contains("--initial"), "{e}");
}

/// Writes an HDF5 file with the datasets `build` adds, the way a tool other than ITK might.
fn hdf5_file(dir: &Path, name: &str, build: impl FnOnce(&mut hdf5_pure::FileBuilder)) -> PathBuf {
    let mut b = hdf5_pure::FileBuilder::new();
    build(&mut b);
    let path = dir.join(name);
    b.write(&path).expect("write");
    path
}

/// One group `0` of `/TransformGroup` holding `kind` with `fixed` and `params`.
fn one_transform(b: &mut hdf5_pure::FileBuilder, kind: &str, fixed: &[f64], params: &[f64]) {
    let mut group = b.create_group("TransformGroup");
    let mut zero = group.create_group("0");
    zero.create_dataset("TransformType").with_vlen_strings(&[kind]);
    zero.create_dataset("TransformFixedParameters").with_f64_data(fixed);
    zero.create_dataset("TransformParameters").with_f64_data(params);
    group.add_group(zero.finish());
    b.add_group(group.finish());
}

#[test]
fn bad_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let refused = |path: &Path, words: &[&str]| {
        let e = itk_h5::read(path).expect_err("refused").to_string();
        let name = path.file_name().expect("name").to_string_lossy();
        assert!(e.contains(name.as_ref()), "{e}");
        for w in words {
            assert!(e.contains(w), "{name}: {e:?} lacks {w:?}");
        }
    };
    // A truncated ITK file.
    let bytes = std::fs::read(itk_dir().join("h5_composite.h5")).expect("fixture");
    for (i, len) in [8, 600, 2000, bytes.len() / 2].into_iter().enumerate() {
        let path = dir.path().join(format!("cut{i}.h5"));
        std::fs::write(&path, &bytes[..len]).expect("write");
        assert!(itk_h5::read(&path).expect_err("truncated").to_string().contains(&format!("cut{i}.h5")));
    }
    refused(
        &hdf5_file(dir.path(), "data.h5", |b| {
            b.create_dataset("data").with_f64_data(&[1.0, 2.0]);
        }),
        &["/TransformGroup"],
    );
    let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    refused(
        &hdf5_file(dir.path(), "short.h5", |b| {
            one_transform(b, "AffineTransform_double_3_3", &[0.0; 3], &identity[..11]);
        }),
        &["Parameters", "11 numbers, expected 12"],
    );
    refused(
        &hdf5_file(dir.path(), "nan.h5", |b| {
            let mut p = identity;
            p[4] = f64::NAN;
            one_transform(b, "AffineTransform_double_3_3", &[0.0; 3], &p);
        }),
        &["TransformParameters", "number 5 is not finite"],
    );
    refused(
        &hdf5_file(dir.path(), "skew.h5", |b| {
            one_transform(b, "QuaternionRigidTransform_double_3_3", &[0.0; 3], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        }),
        &["QuaternionRigidTransform_double_3_3", "AffineTransform_double_3_3"],
    );
    let field_fixed = [2.0, 2.0, 2.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    refused(
        &hdf5_file(dir.path(), "slicer.h5", |b| {
            one_transform(b, "InverseThinPlateSplineKernelTransform_double_3_3", &[0.0; 3], &[0.0; 3]);
        }),
        &["InverseThinPlateSplineKernelTransform_double_3_3", "Slicer", "B-splines and displacement fields"],
    );
    refused(
        &hdf5_file(dir.path(), "field.h5", |b| {
            one_transform(b, "DisplacementFieldTransform_double_3_3", &field_fixed, &[0.0; 21]);
        }),
        &["TransformParameters", "21 numbers, expected 24"],
    );
    let mut huge = field_fixed;
    huge[..3].copy_from_slice(&[1e6, 1e6, 1e6]);
    refused(
        &hdf5_file(dir.path(), "huge.h5", |b| {
            one_transform(b, "DisplacementFieldTransform_double_3_3", &huge, &[0.0; 3]);
        }),
        &["1000000"],
    );
}

/// 3D Slicer's `InverseDisplacementFieldTransform` (`h5_field_slicer_inverse.h5`: SimpleITK's `h5_field.h5` under
/// Slicer's class, `data-scripts/slicer_transforms.py`) is read as the forward field it holds: the same grid and
/// vectors as SimpleITK's file (which it samples to SimpleITK's `TransformToDisplacementField`, above), stated to map
/// moving points to fixed ones. Read as a chain of transforms, it is that field's inverse: it takes F(y) back to y.
#[test]
fn slicers_inverse_field_is_the_forward_field_it_holds() {
    let path = itk_dir().join("h5_field_slicer_inverse.h5");
    let read = displacement::read_field_info(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((read.source, read.direction), (FieldSource::ItkHdf5, Some(FieldDirection::Forward)));
    let plain = displacement::read_field_info(&itk_dir().join("h5_field.h5")).expect("plain");
    assert_eq!(read.field.dims, plain.field.dims);
    assert_eq!(read.field.lps_from_index.rows(), plain.field.lps_from_index.rows());
    assert_eq!(read.field.displacements_lps, plain.field.displacements_lps);
    let (inverse, forward) = (itk_h5::read(&path).expect("a chain"), itk_h5::read(&itk_dir().join("h5_field.h5")));
    let forward = forward.expect("the plain field");
    let g = plain.field.lps_from_index;
    // This field folds (its vectors reach a voxel), so a point may have two preimages: the law is F(T(x)) = x.
    for ijk in [[1.0, 1.0, 1.0], [2.5, 3.0, 1.5], [4.0, 2.0, 2.25]] {
        let x = g.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let y = inverse.apply(x);
        assert!(max_diff(forward.apply(y), x) < 1e-6, "F({y:?}) = {:?}, not {x:?}", forward.apply(y));
        assert!(max_diff(x, y) > 0.1, "the inverse moves {x:?}");
    }
}

/// A composite as 3D Slicer saves one with non-linear members in their modeling direction
/// (`h5_composite_slicer_inverse.h5`, `data-scripts/slicer_inverse_composite.py`: ITK's composite of an affine A, a
/// B-spline B and a field F, B's and F's classes renamed to Slicer's `InverseBSplineTransform` and
/// `InverseDisplacementFieldTransform`) is the transform A(B⁻¹(F⁻¹(x))): at ITK's x = F(B(y)) it gives ITK's A(y),
/// within the inverse's tolerance (10⁻⁶ mm of residual) carried through A. It is no affine, and written again it reads
/// back to the same transform under the same classes.
#[test]
fn slicers_inverse_members_in_a_composite_are_the_inverses_itk_maps_back() {
    let path = itk_dir().join("h5_composite_slicer_inverse.h5");
    let text = std::fs::read_to_string(itk_dir().join("h5_composite_slicer_inverse.json")).expect("reference");
    let doc: Value = serde_json::from_str(&text).expect("JSON");
    let chain = itk_h5::read(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(chain.steps.len(), 3);
    let (xs, want) = (triples(&doc["x"]), triples(&doc["a_of_y"]));
    let ys = triples(&doc["y"]);
    let moved = xs.iter().zip(&ys).map(|(x, y)| max_diff(*x, *y)).fold(0.0, f64::max);
    assert!(moved > 0.5, "F(B(y)) moves y by at most {moved} mm");
    for (x, a) in xs.iter().zip(&want) {
        let got = chain.apply(*x);
        assert!(max_diff(got, *a) < 1e-5, "T({x:?}) = {got:?}, ITK's A(y) = {a:?}");
    }
    let e = itk_h5::read_affine(&path).expect_err("not linear").to_string();
    assert!(e.contains("InverseDisplacementFieldTransform_double_3_3") && e.contains("not only affine"), "{e}");
    // As a field (`--field`): the chain sampled on the grid of the field applied first, everywhere finite (at the
    // B-spline's edge, where ITK's spline jumps to the identity, the inverse is the nearest point found, as VTK's).
    let read = displacement::read_field_info(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((read.field.dims, read.direction), ([8, 7, 6], Some(FieldDirection::Pullback)));
    let g = read.field.lps_from_index;
    for (n, d) in read.field.displacements_lps.iter().enumerate().step_by(7) {
        let ijk = [n % 8, (n / 8) % 7, n / 56].map(|c| c as f64);
        let x = g.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let want = chain.apply(x);
        assert!((0..3).all(|a| (x[a] + f64::from(d[a]) - want[a]).abs() < 1e-5), "voxel {ijk:?}");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let again = dir.path().join("again.h5");
    let steps: Vec<itk_h5::H5Transform> = chain.steps.iter().map(itk_h5::H5Transform::from).collect();
    itk_h5::write(&again, &steps).expect("write");
    let back = itk_h5::read(&again).expect("read back");
    for x in &xs {
        assert!(max_diff(back.apply(*x), chain.apply(*x)) < 1e-9, "at {x:?}");
    }
}
