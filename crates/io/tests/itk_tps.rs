//! Thin-plate-spline transform files read as landmark pairs, against files ITK wrote (`data-scripts/slicer_transforms.py`):
//! ITK's own class, whose source landmarks are the fixed points, and 3D Slicer's `Inverse…` class, whose source
//! landmarks are the moving points, each as `.tfm` text and as `.h5`. The script's JSON holds the points it gave ITK.
//! Other transforms are refused naming the file and what it holds.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::landmarks::{self, LandmarkFileFormat, LandmarkPair};
use warpbench_io::{itk_h5, itk_tfm};

fn itk_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk")
}

fn reference() -> Value {
    let text = std::fs::read_to_string(itk_dir().join("slicer_tps_reference.json")).expect("reference");
    serde_json::from_str(&text).expect("JSON")
}

fn triples(v: &Value) -> Vec<[f64; 3]> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|p| {
            let p = p.as_array().expect("point");
            [0, 1, 2].map(|i| p[i].as_f64().expect("number"))
        })
        .collect()
}

fn sides(pairs: &[LandmarkPair]) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    pairs.iter().map(|p| (p.moving.expect("moving").coords(), p.fixed.expect("fixed").coords())).unzip()
}

/// ITK writes a `.tfm`'s numbers with 17 significant digits and an `.h5`'s as doubles, so both read back to the
/// script's doubles exactly; the bound only absorbs a last-digit rounding of a decimal text.
fn assert_points(got: &[[f64; 3]], want: &[[f64; 3]], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        for a in 0..3 {
            assert!((g[a] - w[a]).abs() <= 1e-12 * w[a].abs().max(1.0), "{what} point {}: {g:?} vs {w:?}", i + 1);
        }
    }
}

#[test]
fn itk_and_slicer_spline_files_read_to_the_pairs_given_to_itk() {
    let r = reference();
    let (moving, fixed) = (triples(&r["moving"]), triples(&r["fixed"]));
    for name in ["tps_itk.tfm", "tps_itk.h5", "tps_slicer.tfm", "tps_slicer.h5"] {
        let path = itk_dir().join(name);
        assert_eq!(landmarks::detect_landmark_file(&path).expect(name), LandmarkFileFormat::ItkThinPlateSpline);
        assert!(LandmarkFileFormat::ItkThinPlateSpline.holds_pairs());
        let pairs = landmarks::read_landmark_pairs(&path).expect(name);
        // ITK's class holds the fixed points as its source; Slicer's inverse class the moving ones. Reading either
        // the wrong way round swaps the two sides, which these comparisons catch.
        let (got_moving, got_fixed) = sides(&pairs);
        assert_points(&got_moving, &moving, &format!("{name} moving"));
        assert_points(&got_fixed, &fixed, &format!("{name} fixed"));
        assert!(pairs.iter().all(|p| p.active), "{name}: all active");
        assert_eq!(pairs[0].name, "Pt-0", "{name}");
        assert_eq!(pairs[9].name, "Pt-9", "{name}");
    }
}

#[test]
fn the_class_decides_which_landmarks_are_fixed() {
    // The same landmarks under the two classes: the sides swap, and nothing else changes.
    let text = std::fs::read_to_string(itk_dir().join("tps_slicer.tfm")).expect("tfm");
    assert!(text.contains("Transform: InverseThinPlateSplineKernelTransform_double_3_3"));
    let plain = text.replace("InverseThinPlateSplineKernelTransform", "ThinPlateSplineKernelTransform");
    let float = text.replace("_double_3_3", "_float_3_3");
    let dir = tempfile_dir("class");
    let (a, b, c) = (dir.join("inverse.tfm"), dir.join("plain.tfm"), dir.join("float.tfm"));
    std::fs::write(&a, &text).expect("write");
    std::fs::write(&b, plain).expect("write");
    std::fs::write(&c, float).expect("write");
    let inverse = landmarks::read_landmark_pairs(&a).expect("inverse");
    let forward = landmarks::read_landmark_pairs(&b).expect("plain");
    assert_eq!(landmarks::read_landmark_pairs(&c).expect("float"), inverse, "the _float_3_3 class reads the same");
    for (i, f) in inverse.iter().zip(&forward) {
        assert_eq!((i.moving, i.fixed), (f.fixed, f.moving));
    }
    assert_eq!(
        landmarks::SplineFileClass::of("InverseThinPlateSplineKernelTransform_float_3_3"),
        Some(landmarks::SplineFileClass::SlicerInverse)
    );
    assert_eq!(
        landmarks::SplineFileClass::of("ThinPlateSplineKernelTransform_double_3_3"),
        Some(landmarks::SplineFileClass::Itk)
    );
    assert_eq!(landmarks::SplineFileClass::of("ThinPlateSplineKernelTransform_double_2_2"), None);
    std::fs::remove_dir_all(dir).ok();
}

fn tempfile_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("warpbench-itk-tps-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    dir
}

#[test]
fn other_transform_files_are_refused_as_pairs_naming_what_they_hold() {
    let cases = [
        ("affine_sitk.tfm", "AffineTransform_double_3_3, not a thin-plate spline"),
        ("h5_affine.h5", "AffineTransform_double_3_3, not a thin-plate spline"),
        ("h5_composite.h5", "2 transforms (AffineTransform_double_3_3, DisplacementFieldTransform"),
    ];
    for (name, want) in cases {
        let path = itk_dir().join(name);
        let e = landmarks::read_landmark_pairs(&path).expect_err(name).to_string();
        assert!(e.contains(name) && e.contains(want), "{name}: {e}");
    }
    // A .tfm given as one side of a Slicer pair says it holds pairs.
    let e = landmarks::read_slicer_points(&itk_dir().join("tps_slicer.tfm")).expect_err("one side").to_string();
    assert!(e.contains("tps_slicer.tfm") && e.contains("read it as a file of pairs"), "{e}");
    // A spline whose landmark counts differ is refused by the same checks as a transform.
    let text = std::fs::read_to_string(itk_dir().join("tps_itk.tfm")).expect("tfm");
    let short: String = text
        .lines()
        .map(|l| match l.strip_prefix("FixedParameters:") {
            Some(rest) => format!("FixedParameters:{}", rest.rsplitn(4, ' ').nth(3).expect("numbers")),
            None => l.to_owned(),
        })
        .collect::<Vec<_>>()
        .join("\n");
    let dir = tempfile_dir("short");
    let path = dir.join("short.tfm");
    std::fs::write(&path, short).expect("write");
    let e = landmarks::read_landmark_pairs(&path).expect_err("short").to_string();
    assert!(e.contains("short.tfm") && e.contains("FixedParameters: 27 numbers, expected 30"), "{e}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn as_transforms_the_spline_files_point_to_their_landmarks() {
    // Read as a transform, Slicer's class says what it is and where its landmarks are read.
    let e = itk_tfm::read(&itk_dir().join("tps_slicer.tfm")).expect_err("slicer tfm").to_string();
    assert!(e.contains("tps_slicer.tfm") && e.contains("modeling direction") && e.contains("--landmarks"), "{e}");
    let e = itk_h5::read(&itk_dir().join("tps_slicer.h5")).expect_err("slicer h5").to_string();
    assert!(e.contains("tps_slicer.h5") && e.contains("modeling direction") && e.contains("--landmarks"), "{e}");
    let e = itk_h5::read(&itk_dir().join("tps_itk.h5")).expect_err("itk h5").to_string();
    assert!(e.contains("tps_itk.h5") && e.contains("--landmarks"), "{e}");
}
