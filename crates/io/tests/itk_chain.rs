//! ITK's text transform files of several transforms, and 3D Slicer's inverse B-spline in one, against SimpleITK
//! (`data-scripts/itk_tfm_chain.py`, SimpleITK 2.5.7): the composite of an affine and a B-spline maps points where
//! SimpleITK's `TransformPoint` maps them, inside the B-spline's domain and outside it; the file with the B-spline
//! renamed to Slicer's `InverseBSplineTransform` maps B(y) to A(y), the law of T = A ∘ B⁻¹; read as a field on a grid,
//! each voxel holds T(x) − x; bad files are refused naming the file and the problem.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::displacement::{self, FieldDirection, FieldSource, SampleGrid};
use warpbench_io::geometry::{Point3, Transform};
use warpbench_io::itk_chain::{InverseStep, ItkStep};
use warpbench_io::itk_tfm::ItkTransform;
use warpbench_io::transform_file::read_chain;
use warpbench_io::volume::GeometrySource;

fn itk(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk").join(name)
}

fn reference() -> Value {
    let text = std::fs::read_to_string(itk("tfm_chain_reference.json")).expect("reference");
    serde_json::from_str(&text).expect("JSON")
}

fn triple(v: &Value) -> [f64; 3] {
    let n: Vec<f64> = v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect();
    n.try_into().expect("three numbers")
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// SimpleITK and warpbench evaluate the same cubic B-spline and affine in doubles from the same decimal numbers
/// (ITK writes them with 17 significant digits); they differ only in the order of the sums: 1e-9 mm.
const SAME_MATH_MM: f64 = 1e-9;

#[test]
fn a_composite_maps_points_as_simpleitk_does() {
    let composite = read_chain(&itk("tfm_composite.tfm")).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(
        composite.steps.as_slice(),
        [ItkStep::Transform(ItkTransform::Affine(_)), ItkStep::Transform(ItkTransform::BSpline(_))]
    ));
    let alone = read_chain(&itk("tfm_bspline.tfm")).unwrap_or_else(|e| panic!("{e}"));
    let mut inside = 0;
    for case in reference()["forward"].as_array().expect("points") {
        let x = triple(&case["x"]);
        let (want, want_b) = (triple(&case["composite"]), triple(&case["bspline"]));
        assert!(distance(composite.apply(x), want) < SAME_MATH_MM, "T({x:?}) = {:?}, ITK {want:?}", composite.apply(x));
        assert!(distance(alone.apply(x), want_b) < SAME_MATH_MM, "B({x:?}) = {:?}, ITK {want_b:?}", alone.apply(x));
        inside += usize::from(distance(want_b, x) > 0.01);
    }
    assert!(inside >= 20, "only {inside} points inside the B-spline's domain");
}

#[test]
fn slicers_inverse_bspline_in_a_text_file_is_the_inverse() {
    let chain = read_chain(&itk("tfm_slicer_inverse.tfm")).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(chain.steps.as_slice(), [_, ItkStep::Inverse(InverseStep::BSpline(_))]));
    for case in reference()["inverse"].as_array().expect("points") {
        let (y, b_of_y, a_of_y) = (triple(&case["y"]), triple(&case["b_of_y"]), triple(&case["a_of_y"]));
        // B⁻¹ is found to 1e-6 mm of residual; the affine after it stretches that by at most its largest gain (1.1).
        let got = chain.apply(b_of_y);
        assert!(distance(got, a_of_y) < 2e-6, "T(B({y:?})) = {got:?}, A(y) = {a_of_y:?}");
    }
}

#[test]
fn a_bspline_chain_is_a_field_on_the_grid_given() {
    let path = itk("tfm_composite.tfm");
    let chain = read_chain(&path).expect("chain");
    // Without a grid it is refused, naming the file and where a grid comes from.
    let e = displacement::read_field_info(&path).expect_err("no grid").to_string();
    assert!(e.contains("tfm_composite.tfm") && e.contains("no grid") && e.contains("--fixed"), "{e}");
    let lps_from_index = Transform::from_scale_translation([3.0, 3.5, 4.0], [-30.0, -25.0, -18.0]);
    let grid =
        SampleGrid { dims: [20, 15, 10], lps_from_index, geometry_source: GeometrySource::NiftiSform { code: 1 } };
    let read = displacement::read_field_on(&path, Some(&grid)).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((read.source, read.direction), (FieldSource::ItkTransform, Some(FieldDirection::Pullback)));
    assert_eq!((read.field.dims, read.field.lps_from_index), (grid.dims, lps_from_index));
    let [nx, ny, _] = grid.dims;
    for (v, d) in read.field.displacements_lps.iter().enumerate() {
        let ijk = Point3::new((v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64);
        let x = lps_from_index.apply_point(ijk).coords();
        let y = chain.apply(x);
        // f32 vectors of at most ~40 mm: 2⁻²⁴ × 40 mm.
        assert!((0..3).all(|a| (f64::from(d[a]) - (y[a] - x[a])).abs() < 3e-6), "voxel {v}: {d:?}");
    }
}

#[test]
fn bad_chains_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let good = std::fs::read_to_string(itk("tfm_composite.tfm")).expect("text");
    let affine_only = {
        let start = good.find("#Transform 2").expect("the B-spline's block");
        good[..start].to_owned()
    };
    let cases: [(&str, String, &str); 5] = [
        ("gap.tfm", good.replace("#Transform 2", "#Transform 3"), "numbered 0, 1, … in order"),
        (
            "nested.tfm",
            good.replace("AffineTransform_double_3_3", "CompositeTransform_double_3_3"),
            "a composite inside",
        ),
        (
            "empty.tfm",
            "#Insight Transform File V1.0\n#Transform 0\nTransform: CompositeTransform_double_3_3\n".into(),
            "holds no transforms",
        ),
        ("short.tfm", good.replace("FixedParameters: 4 -3 2", "FixedParameters: 4 -3"), "FixedParameters"),
        ("linear.tfm", affine_only, "starting transform"),
    ];
    for (name, text, says) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, text).expect("write");
        let grid = SampleGrid {
            dims: [2, 2, 2],
            lps_from_index: Transform::from_scale_translation([1.0; 3], [0.0; 3]),
            geometry_source: GeometrySource::NiftiSform { code: 1 },
        };
        let e = displacement::read_field_on(&path, Some(&grid)).expect_err(name).to_string();
        assert!(e.starts_with(&path.display().to_string()) && e.contains(says), "{name}: {e}");
    }
    // A one-transform reader still refuses a composite, saying what it holds.
    let e = warpbench_io::itk_tfm::read(&itk("tfm_composite.tfm")).expect_err("composite").to_string();
    assert!(e.contains("3 transforms") && e.contains("a single transform"), "{e}");
}

/// One reading of a file tells a field from a chain: SimpleITK's `.h5` of an affine and a field (as ANTs' composite)
/// is the field `read_field_info` gives, its `.h5` of an affine and its `.tfm` composite are chains, and a NIfTI field
/// is a field.
#[test]
fn a_field_or_a_chain_from_one_reading() {
    use warpbench_io::itk_chain::FieldOrChain;
    let h5 = itk("h5_composite.h5");
    match displacement::read_field_or_chain(&h5).expect("h5") {
        FieldOrChain::Field(read) => assert_eq!(read, displacement::read_field_info(&h5).expect("the field")),
        FieldOrChain::Chain(_) => panic!("a composite with a field is a field"),
    }
    for name in ["h5_affine.h5", "tfm_composite.tfm"] {
        let read = displacement::read_field_or_chain(&itk(name)).expect(name);
        assert!(matches!(read, FieldOrChain::Chain(_)), "{name}");
    }
    let nifti = itk("field_input_field.nii.gz");
    assert!(matches!(displacement::read_field_or_chain(&nifti).expect("nifti"), FieldOrChain::Field(_)));
}
