//! ITK's linear classes besides the affine (translation, scale, Euler in both orders, versor, versor rigid,
//! similarity, scale versor, ITK 5's scale-skew versor) against SimpleITK: the `.tfm` it writes for each, and one `.h5` composite of all of them
//! (`data-scripts/itk_linear_sitk.py`), read as affines that map points where SimpleITK's `TransformPoint` maps them;
//! parameters a class cannot hold are refused naming the file.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::itk_h5;
use warpbench_io::itk_tfm::{self, ItkTransform};

fn itk_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk")
}

fn triples(v: &Value) -> Vec<[f64; 3]> {
    let number = |x: &Value| x.as_f64().expect("number");
    v.as_array().expect("array").iter().map(|p| std::array::from_fn(|i| number(&p[i]))).collect()
}

/// Both read the parameters as doubles, so the only difference is the order of the arithmetic: points up to
/// 120 mm from the origin, mapped through up to seven transforms, agree to far below this.
const BOUND_MM: f64 = 1e-9;

#[test]
fn every_class_maps_points_where_simpleitk_maps_them() {
    let text = std::fs::read_to_string(itk_dir().join("linear_reference.json")).expect("reference");
    let reference: Value = serde_json::from_str(&text).expect("JSON");
    let cases = reference["cases"].as_array().expect("cases");
    assert_eq!(cases.len(), 10);
    for case in cases {
        let file = case["file"].as_str().expect("file");
        let path = itk_dir().join(file);
        let affine = if itk_tfm::is_hdf5_name(&path) {
            itk_h5::read_affine(&path).unwrap_or_else(|e| panic!("{e}"))
        } else {
            let ItkTransform::Affine(a) = itk_tfm::read(&path).unwrap_or_else(|e| panic!("{e}")) else {
                panic!("{file}: not read as an affine");
            };
            assert_eq!(itk_tfm::read_affine(&path).ok(), Some(a), "{file}: read and read_affine");
            a
        };
        for (p, q) in triples(&case["points"]).iter().zip(triples(&case["transformed"])) {
            let y = affine.apply(*p);
            let err = (0..3).map(|i| (y[i] - q[i]).abs()).fold(0.0, f64::max);
            assert!(err < BOUND_MM, "{file}: T({p:?}) = {y:?}, SimpleITK {q:?}");
        }
    }
}

#[test]
fn parameters_a_class_cannot_hold_are_refused() {
    let cases = [
        ("Euler3DTransform_double_3_3", "0 0 0 1 2 3", "1 2 3 2", "ComputeZYX flag"),
        ("Euler3DTransform_double_3_3", "0 0 0 1 2 3", "1 2", "FixedParameters"),
        ("VersorRigid3DTransform_double_3_3", "0.8 0.8 0 1 2 3", "0 0 0", "longer than 1"),
        ("Similarity3DTransform_double_3_3", "0 0 0 1 2 3", "0 0 0", "6 numbers, expected 7"),
        ("TranslationTransform_double_3_3", "1 2 3", "4 5 6", "FixedParameters: 3 numbers, expected 0"),
        ("QuaternionRigidTransform_double_3_3", "0 0 0 1 1 2 3", "0 0 0", "Euler3DTransform"),
        ("ScaleSkewVersor3DTransform_double_3_3", "0 0 0 0 0 0 1 1 1 0 0 0", "0 0 0", "ITK 6"),
        ("ScaleVersor3DTransform_double_3_3", "0 0 0 0 0 0 1 1", "0 0 0", "8 numbers, expected 9"),
    ];
    for (kind, params, fixed, words) in cases {
        let text = format!(
            "#Insight Transform File V1.0\n#Transform 0\nTransform: {kind}\nParameters: {params}\nFixedParameters: \
             {fixed}\n"
        );
        let e = itk_tfm::parse(Path::new("start.tfm"), &text).expect_err(kind).to_string();
        assert!(e.contains("start.tfm") && e.contains(words), "{kind}: {e}");
    }
}
