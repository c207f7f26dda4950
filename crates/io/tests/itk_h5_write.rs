//! ITK's HDF5 transform files as warpbench writes them (`itk_h5::write`, `transform_file::write`): SimpleITK's own
//! files, read and written again, still map points where SimpleITK's `TransformPoint` maps them; the layout is ITK's
//! (group per transform, the class as a variable-length string, the parameters as numbers); a B-spline and a
//! thin-plate spline hold the numbers of their `.tfm`; what ITK could not read is refused and nothing is written.
//! SimpleITK reading what the CLI writes is `crates/python/tests/test_itk_h5_sitk.py`.

use std::path::{Path, PathBuf};

use hdf5_pure::File;
use nalgebra::Matrix3;
use serde_json::Value;
use warpbench_io::geometry::Transform;
use warpbench_io::itk_h5::{self, H5Transform, ItkStep};
use warpbench_io::itk_tfm::{self, ItkAffine, ItkBSpline, ItkThinPlateSpline, ItkTransform};
use warpbench_io::transform_file;

fn itk_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk")
}

fn triples(v: &Value) -> Vec<[f64; 3]> {
    v.as_array().expect("array").iter().map(|p| std::array::from_fn(|i| p[i].as_f64().expect("number"))).collect()
}

/// As in `itk_h5.rs`: a field's vectors are f32 in warpbench, affines are doubles.
const FIELD_MM: f64 = 1e-5;
const AFFINE_MM: f64 = 1e-9;

#[test]
fn simpleitks_files_written_again_map_points_where_simpleitk_maps_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(itk_dir().join("h5_reference.json")).expect("reference");
    let reference: Value = serde_json::from_str(&text).expect("JSON");
    for case in reference["cases"].as_array().expect("cases") {
        let file = case["file"].as_str().expect("file");
        let chain = itk_h5::read(&itk_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        let out = dir.path().join(file);
        let steps: Vec<H5Transform> = chain.steps.iter().map(H5Transform::from).collect();
        itk_h5::write(&out, &steps).unwrap_or_else(|e| panic!("{file}: {e}"));
        let again = itk_h5::read(&out).unwrap_or_else(|e| panic!("{file} written again: {e}"));
        assert_eq!(again.steps.len(), chain.steps.len(), "{file}");
        let field = chain.steps.iter().any(|s| matches!(s, ItkStep::Field(_)));
        let bound = if field { FIELD_MM } else { AFFINE_MM };
        for (p, q) in triples(&case["points"]).into_iter().zip(triples(&case["transformed"])) {
            let (before, after) = (chain.apply(p), again.apply(p));
            // The same numbers are written as they were read: the same map, bit for bit.
            assert_eq!(after.map(f64::to_bits), before.map(f64::to_bits), "{file}: T({p:?})");
            let off = (0..3).map(|i| (after[i] - q[i]).abs()).fold(0.0, f64::max);
            assert!(off < bound, "{file}: T({p:?}) = {after:?}, SimpleITK {q:?}");
        }
    }
}

/// A composite of an affine and a 3 × 2 × 2 field on an oblique grid, as ANTs lays out its `Composite.h5`.
fn composite_parts()
-> (ItkTransform, [usize; 3], Transform<warpbench_io::geometry::Lps, warpbench_io::geometry::Index>, Vec<[f32; 3]>) {
    let affine = ItkTransform::Affine(ItkAffine {
        matrix: Matrix3::new(1.02, 0.05, 0.0, -0.04, 0.98, 0.01, 0.0, 0.02, 1.01),
        translation: [2.0, -3.5, 1.25],
        center: [10.0, 20.0, -5.0],
    });
    let (c, s) = (0.6f64.cos(), 0.6f64.sin());
    let direction = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let spacing = Matrix3::from_diagonal(&nalgebra::Vector3::new(2.0, 1.5, 3.0));
    let grid = Transform::from_linear_translation(direction * spacing, [-12.0, 7.5, 30.0]);
    let vectors = (0..12).map(|v| [v as f32 * 0.25, -(v as f32) / 3.0, 1.0 + v as f32]).collect();
    (affine, [3, 2, 2], grid, vectors)
}

#[test]
fn the_layout_is_itks() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (affine, dims, grid, vectors) = composite_parts();
    let path = dir.path().join("Composite.h5");
    let field = H5Transform::Field { dims, lps_from_index: &grid, displacements_lps: &vectors };
    itk_h5::write(&path, &[H5Transform::Transform(&affine), field]).expect("write");
    assert!(itk_h5::looks_like_hdf5(&std::fs::read(&path).expect("read")));
    let file = File::open(&path).expect("HDF5");
    let mut groups = file.group("/TransformGroup").expect("group").groups().expect("groups");
    groups.sort();
    assert_eq!(groups, ["0", "1", "2"]);
    let class = |g: &str| {
        let d = file.dataset(&format!("/TransformGroup/{g}/TransformType")).expect("TransformType");
        // ITK reads the class into a variable-length ASCII string, and the HDF5 library converts neither a
        // fixed-length nor a UTF-8 string to that (SimpleITK failed to read the UTF-8 one).
        assert!(
            matches!(
                d.datatype().expect("type"),
                hdf5_pure::Datatype::VariableLength {
                    is_string: true,
                    charset: Some(hdf5_pure::CharacterSet::Ascii),
                    ..
                }
            ),
            "group {g}: {:?}",
            d.datatype()
        );
        assert_eq!(d.shape().expect("shape"), [1]);
        d.read_string().expect("string")
    };
    assert_eq!(class("0"), ["CompositeTransform_double_3_3"]);
    assert_eq!(class("1"), ["AffineTransform_double_3_3"]);
    assert_eq!(class("2"), ["DisplacementFieldTransform_float_3_3"]);
    assert!(file.dataset("/TransformGroup/0/TransformParameters").is_err(), "a composite has no parameters");
    let numbers = |at: &str| file.dataset(at).expect(at).read_f64().expect("numbers");
    let fixed = numbers("/TransformGroup/2/TransformFixedParameters");
    let (c, s) = (0.6f64.cos(), 0.6f64.sin());
    let want = [3.0, 2.0, 2.0, -12.0, 7.5, 30.0, 2.0, 1.5, 3.0, c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0];
    for (i, (a, b)) in fixed.iter().zip(want).enumerate() {
        assert!((a - b).abs() < 1e-15, "fixed parameter {}: {a} against {b}", i + 1);
    }
    assert_eq!(fixed.len(), 18);
    let params = file.dataset("/TransformGroup/2/TransformParameters").expect("parameters");
    assert_eq!(params.shape().expect("shape"), [36]);
    let flat: Vec<f64> = vectors.iter().flatten().map(|&v| f64::from(v)).collect();
    assert_eq!(params.read_f64().expect("numbers"), flat);
    let (tfm_params, tfm_fixed) = match itk_tfm::parse(Path::new("a.tfm"), &affine.to_text()).expect("tfm") {
        ItkTransform::Affine(a) => (a, a.center),
        other => panic!("{other:?}"),
    };
    assert_eq!(numbers("/TransformGroup/1/TransformFixedParameters"), tfm_fixed);
    let m = tfm_params.matrix;
    let row_major: Vec<f64> =
        (0..3).flat_map(|r| (0..3).map(move |c| m[(r, c)])).chain(tfm_params.translation).collect();
    assert_eq!(numbers("/TransformGroup/1/TransformParameters"), row_major);
}

fn bspline() -> ItkBSpline {
    let coefficients_mm =
        (0..5 * 4 * 6).map(|v| [(v % 7) as f64 * 0.3 - 1.0, (v % 5) as f64 * -0.2, (v % 3) as f64]).collect();
    ItkBSpline {
        grid_size: [5, 4, 6],
        grid_origin_lps: [-30.0, -25.0, -40.0],
        grid_spacing_mm: [20.0, 25.0, 16.0],
        grid_direction: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        coefficients_mm,
    }
}

#[test]
fn a_bspline_and_a_thin_plate_spline_hold_their_tfms_numbers() {
    let dir = tempfile::tempdir().expect("tempdir");
    let spline = ItkTransform::BSpline(bspline());
    let (h5, tfm) = (dir.path().join("b.h5"), dir.path().join("b.tfm"));
    for path in [&h5, &tfm] {
        transform_file::write(path, &spline).expect("write");
    }
    assert!(itk_h5::looks_like_hdf5(&std::fs::read(&h5).expect("h5")));
    assert!(std::fs::read_to_string(&tfm).expect("text").starts_with("#Insight Transform File V1.0"));
    let from_tfm = itk_tfm::read(&tfm).expect("tfm");
    let chain = itk_h5::read(&h5).expect("h5");
    match chain.steps.as_slice() {
        [ItkStep::Transform(t)] => assert_eq!(*t, from_tfm),
        other => panic!("{other:?}"),
    }
    for p in [[0.0, 0.0, 0.0], [12.5, -7.0, 20.0], [35.0, 30.0, -20.0], [500.0, 0.0, 0.0]] {
        assert_eq!(chain.apply(p).map(f64::to_bits), from_tfm_apply(&from_tfm, p).map(f64::to_bits), "T({p:?})");
    }
    let tps = ItkTransform::ThinPlateSpline(ItkThinPlateSpline {
        source_lps: vec![[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 12.0, 0.0], [0.0, 0.0, 9.0], [5.0, 5.0, 5.0]],
        target_lps: vec![[1.0, 0.0, 0.0], [11.0, 0.5, 0.0], [0.0, 12.0, -1.0], [0.5, 0.0, 9.0], [5.0, 6.0, 5.0]],
    });
    let tps_h5 = dir.path().join("tps.h5");
    transform_file::write(&tps_h5, &tps).expect("write");
    let file = File::open(&tps_h5).expect("HDF5");
    let read = |name: &str| file.dataset(&format!("/TransformGroup/0/{name}")).expect(name);
    assert_eq!(read("TransformType").read_string().expect("class"), ["ThinPlateSplineKernelTransform_double_3_3"]);
    let ItkTransform::ThinPlateSpline(t) = itk_tfm::parse(Path::new("t.tfm"), &tps.to_text()).expect("tfm") else {
        panic!("not a TPS");
    };
    let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
    assert_eq!(read("TransformParameters").read_f64().expect("numbers"), flat(&t.source_lps));
    assert_eq!(read("TransformFixedParameters").read_f64().expect("numbers"), flat(&t.target_lps));
    // ITK fits the spline again from its landmarks; warpbench does not, and says so when it meets one.
    let e = itk_h5::read(&tps_h5).expect_err("a TPS").to_string();
    assert!(e.contains("tps.h5") && e.contains("landmarks"), "{e}");
}

fn from_tfm_apply(t: &ItkTransform, p: [f64; 3]) -> [f64; 3] {
    match t {
        ItkTransform::BSpline(b) => b.apply(p),
        ItkTransform::Affine(a) => a.apply(p),
        ItkTransform::ThinPlateSpline(_) => unreachable!("a B-spline"),
    }
}

#[test]
fn what_itk_could_not_read_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (affine, dims, grid, vectors) = composite_parts();
    let refused = |name: &str, chain: &[H5Transform], words: &[&str]| {
        let path = dir.path().join(name);
        let e = itk_h5::write(&path, chain).expect_err(name).to_string();
        assert!(e.contains(name), "{e}");
        for w in words {
            assert!(e.contains(w), "{name}: {e:?} lacks {w:?}");
        }
        assert!(!path.exists(), "{name} was written");
        assert_eq!(std::fs::read_dir(dir.path()).expect("dir").count(), 0, "leftovers beside {name}");
    };
    refused("empty.h5", &[], &["no transform"]);
    refused(
        "short.h5",
        &[H5Transform::Field { dims, lps_from_index: &grid, displacements_lps: &vectors[..11] }],
        &["11 displacement vectors", "[3, 2, 2]"],
    );
    let mut bad = vectors.clone();
    bad[7][1] = f32::NAN;
    refused(
        "nan.h5",
        &[H5Transform::Field { dims, lps_from_index: &grid, displacements_lps: &bad }],
        &["voxel [1, 0, 1]", "not finite"],
    );
    let flat =
        Transform::from_linear_translation(Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 0.0, 1.0)), [0.0; 3]);
    refused(
        "singular.h5",
        &[H5Transform::Field { dims, lps_from_index: &flat, displacements_lps: &vectors }],
        &["singular"],
    );
    // Finite axes whose length overflows a double: no spacing ITK can hold (found by the fuzzer).
    let huge =
        Transform::from_linear_translation(Matrix3::new(1e308, 0.0, 0.0, 1e308, 1.0, 0.0, 0.0, 0.0, 1.0), [0.0; 3]);
    refused(
        "huge.h5",
        &[H5Transform::Field { dims, lps_from_index: &huge, displacements_lps: &vectors }],
        &["no finite ITK geometry"],
    );
    let ItkTransform::Affine(mut a) = affine else { unreachable!() };
    a.translation[2] = f64::INFINITY;
    let infinite = ItkTransform::Affine(a);
    refused("inf.h5", &[H5Transform::Transform(&infinite)], &["not finite"]);
    let mut small = bspline();
    small.grid_size = [3, 4, 6];
    small.coefficients_mm.truncate(3 * 4 * 6);
    refused("small.h5", &[H5Transform::Transform(&ItkTransform::BSpline(small))], &["[3, 4, 6]"]);
    // A text transform file is not written under an HDF5 name, which ITK would read as HDF5.
    let text = dir.path().join("text.h5");
    let e = itk_tfm::write(&text, &affine).expect_err("text as .h5").to_string();
    assert!(e.contains("text.h5") && e.contains("HDF5"), "{e}");
    assert!(!text.exists());
}
