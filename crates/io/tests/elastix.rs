//! elastix transform parameter files: the linear ones elastix wrote (`tests/data/elastix/`, made by
//! `data-scripts/elastix_transforms.py` with itk-elastix 0.25.4) read to transforms that map points where transformix
//! mapped them; bad files are refused naming the file and the problem.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::elastix::{self, ElastixGrid};
use warpbench_io::geometry::Transform;
use warpbench_io::itk_tfm::{ItkAffine, ItkTransform};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/elastix")
}

fn reference() -> Value {
    let path = data_dir().join("transformix_reference.json");
    serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("JSON")
}

fn points(v: &Value) -> Vec<[f64; 3]> {
    v.as_array().expect("list").iter().map(|p| std::array::from_fn(|a| p[a].as_f64().expect("number"))).collect()
}

/// Every file elastix wrote (Euler both ways round, similarity, translation, and an affine over the rigid through
/// InitialTransformParameterFileName) maps the recorded points where transformix did. transformix prints its points
/// to 1e-6 mm, so the bound is 1e-5 mm; a wrong rotation order, versor, centre or composition order is off by
/// millimetres (the points move up to 8 mm).
#[test]
fn every_linear_file_elastix_wrote_maps_points_where_transformix_did() {
    let r = reference();
    let inputs = points(&r["elastix_points_lps"]);
    let files = r["elastix_files"].as_array().expect("files");
    assert_eq!(files.len(), 5);
    let mut read = Vec::new();
    for f in files {
        let file = f["file"].as_str().expect("file");
        let affine = elastix::read_affine(&data_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        let want = points(&f["transformix_lps"]);
        for (n, (x, w)) in inputs.iter().zip(&want).enumerate() {
            let got = affine.apply(*x);
            let err = (0..3).map(|a| (got[a] - w[a]).abs()).fold(0.0, f64::max);
            assert!(err < 1e-5, "{file}: point {}: {got:?}, transformix {w:?}", n + 1);
        }
        read.push((file, affine));
    }
    // The ZYX file differs from the rigid one only in the order of the angles (transformix: up to 0.031 mm apart,
    // 3000 times the bound); the chain differs from its rigid part.
    let far = |a: &ItkAffine, b: &ItkAffine| {
        inputs.iter().any(|x| (0..3).any(|k| (a.apply(*x)[k] - b.apply(*x)[k]).abs() > 1e-3))
    };
    assert!(far(&read[0].1, &read[1].1), "rigid.txt and rigid_zyx.txt are different rotations");
    assert!(far(&read[0].1, &read[3].1), "the affine chain is more than its rigid start");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write");
    p
}

#[test]
fn bad_parameter_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rigid = std::fs::read_to_string(data_dir().join("rigid.txt")).expect("rigid");
    let affine = std::fs::read_to_string(data_dir().join("affine.txt")).expect("affine");
    let refused = |p: &Path, needle: &str| {
        let e = elastix::read_affine(p).expect_err("refused").to_string();
        assert!(e.starts_with(&format!("{}: ", p.display())) && e.contains(needle), "{needle:?} in {e}");
    };
    let bspline = write(dir.path(), "bspline.txt", &rigid.replace("\"EulerTransform\"", "\"BSplineTransform\""));
    refused(&bspline, "BSplineTransform is not a linear transform");
    refused(&bspline, "transformix -def all");
    refused(
        &write(dir.path(), "few.txt", &rigid.replace("(NumberOfParameters 6)", "").replace(" 0.939309946573854)", ")")),
        "5 numbers, 6 expected",
    );
    refused(
        &write(dir.path(), "lost.txt", &affine.replace("\"rigid.txt\"", "\"gone.txt\"")),
        "\"gone.txt\" is neither beside it",
    );
    let looped = dir.path().join("loop.txt");
    std::fs::write(&looped, affine.replace("\"rigid.txt\"", "\"loop.txt\"")).expect("write");
    refused(&looped, "loops");
    std::fs::copy(data_dir().join("rigid.txt"), dir.path().join("rigid.txt")).expect("copy");
    refused(&write(dir.path(), "add.txt", &affine.replace("\"Compose\"", "\"Add\"")), "only \"Compose\" chains");
    refused(
        &write(dir.path(), "two_d.txt", &rigid.replace("(FixedImageDimension 3)", "(FixedImageDimension 2)")),
        "only 3-D",
    );
    refused(
        &write(dir.path(), "zyx.txt", &rigid.replace("(ComputeZYX \"false\")", "(ComputeZYX \"maybe\")")),
        "neither \"true\"",
    );
    refused(&write(dir.path(), "none.txt", "(Size 1 2 3)\n"), "no (Transform …)");
    refused(&write(dir.path(), "text.txt", "hello\n"), "not a (Name value …) line");
    // The chain's initial file is found beside the file that names it, from any working folder.
    assert!(elastix::read_affine(&dir.path().join("rigid.txt")).is_ok());
    let chained = write(dir.path(), "chained.txt", &affine);
    assert_eq!(
        elastix::read_affine(&chained).expect("the chain beside it"),
        elastix::read_affine(&data_dir().join("affine.txt")).expect("the fixture")
    );
}

/// What warpbench writes reads back (for the linear class) to the same map, names its grid as the fixed volume's,
/// and a transform that is not finite is refused without a file.
#[test]
fn a_written_affine_reads_back_and_names_the_grid() {
    let dir = tempfile::tempdir().expect("tempdir");
    let matrix = nalgebra::Matrix3::new(1.02, 0.05, -0.01, -0.04, 0.98, 0.02, 0.01, -0.03, 1.01);
    let affine = ItkAffine { matrix, translation: [3.0, -2.5, 1.25], center: [10.0, 20.0, -5.0] };
    let (s, c) = 0.4f64.sin_cos();
    let linear = nalgebra::Matrix3::new(c * 1.5, -s * 2.0, 0.0, s * 1.5, c * 2.0, 0.0, 0.0, 0.0, 2.5);
    let grid = ElastixGrid {
        dims: [7, 6, 5],
        lps_from_index: Transform::from_linear_translation(linear, [-30.0, 12.5, 7.25]),
    };
    let path = dir.path().join("TransformParameters.0.txt");
    elastix::write(&path, &ItkTransform::Affine(affine), &grid).expect("write");
    let back = elastix::read_affine(&path).expect("read back");
    for x in [[0.0, 0.0, 0.0], [50.0, -20.0, 33.0]] {
        let (a, b) = (affine.apply(x), back.apply(x));
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-12), "{a:?} vs {b:?}");
    }
    let text = std::fs::read_to_string(&path).expect("read");
    for line in [
        "(Size 7 6 5)",
        "(Spacing 1.5 2 2.5)",
        "(Origin -30 12.5 7.25)",
        "(Transform \"AffineTransform\")",
        "(CenterOfRotationPoint 10 20 -5)",
    ] {
        assert!(text.lines().any(|l| l == line), "{line} in\n{text}");
    }
    let direction = text.lines().find(|l| l.starts_with("(Direction ")).expect("Direction");
    let d: Vec<f64> = direction
        .trim_start_matches("(Direction ")
        .trim_end_matches(')')
        .split(' ')
        .map(|v| v.parse().expect("num"))
        .collect();
    // Column by column: the first column is index axis i's direction, (cos, sin, 0).
    assert!((d[0] - c).abs() < 1e-15 && (d[1] - s).abs() < 1e-15 && d[2] == 0.0, "{d:?}");
    let mut bad = affine;
    bad.translation[1] = f64::NAN;
    let nan = dir.path().join("nan.txt");
    assert!(elastix::write(&nan, &ItkTransform::Affine(bad), &grid).is_err());
    assert!(!nan.exists());
}
