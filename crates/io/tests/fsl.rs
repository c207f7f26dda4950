//! FSL's FLIRT matrix against nitransforms 25.1.0 (`data-scripts/fsl_flirt_nitransforms.py`): the matrices it wrote
//! between volumes of either handedness, oblique ones among them, read with the same volumes to the pull-back
//! nitransforms reads; written again, to the file's numbers; and text that is not a FLIRT matrix refused, naming the
//! file and what is wrong.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use warpbench_io::fsl;

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/fsl")
}

fn matrix(v: &serde_json::Value) -> Matrix4<f64> {
    Matrix4::from_fn(|r, c| v[r][c].as_f64().expect("a number"))
}

/// RAS ↔ LPS.
fn flip() -> Matrix4<f64> {
    Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0))
}

#[test]
fn a_flirt_matrix_reads_as_nitransforms_reads_it() {
    let text = std::fs::read_to_string(dir().join("reference.json")).expect("the reference");
    let reference: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    for name in ["oblique_from_las", "lps_from_oblique_las"] {
        let case = &reference[name];
        let path = dir().join(format!("{name}.mat"));
        let head = std::fs::read(&path).expect("the matrix");
        assert!(fsl::looks_like_flirt_matrix(&head), "{name}");
        let flirt = fsl::read(&path).expect("read");
        let open = |key: &str| warpbench_io::open(dir().join(case[key].as_str().expect("a name"))).expect("volume");
        let (fixed, moving) = (open("fixed"), open("moving"));
        let (f, m) = ((fixed.dims, &fixed.lps_from_index), (moving.dims, &moving.lps_from_index));
        let u = fsl::moving_from_fixed(&path, &flirt, f, m).expect("the pull-back");
        let want = flip() * matrix(&case["ras"]) * flip();
        // The same doubles through the same products, in another order.
        assert!((u - want).abs().max() < 1e-12, "{name}: {u} against nitransforms' {want}");
        // The file's eight decimals hold the known transform to about 1e-6 of its numbers.
        let known = flip() * matrix(&reference["known_ras"]) * flip();
        assert!((u - known).abs().max() < 1e-5, "{name}: {u} against the transform written {known}");
        // Written again: the file's numbers, and the text reads back to them.
        let again = fsl::flirt_from(&path, &u, f, m).expect("the matrix");
        assert!((again - flirt).abs().max() < 1e-12, "{name}: {again} against the file's {flirt}");
        let parsed = fsl::parse(&path, &fsl::to_text(&again)).expect("parse");
        assert!((parsed - again).abs().max() < 1e-12);
    }
}

#[test]
fn fsl_coordinates_reverse_the_first_axis_of_a_neurological_grid() {
    // LAS (det < 0): FSL's coordinates are the indices scaled. LPS's determinant is positive: i runs the other way.
    let las = warpbench_io::geometry::Transform::from_scale_translation([1.5, -1.0, 1.1], [0.0; 3]);
    let s = fsl::fsl_from_index(([4, 5, 3], &las));
    assert_eq!(s, Matrix4::from_diagonal(&nalgebra::Vector4::new(1.5, 1.0, 1.1, 1.0)));
    let lps = warpbench_io::geometry::Transform::from_scale_translation([2.0, 2.0, 2.5], [0.0; 3]);
    let s = fsl::fsl_from_index(([4, 5, 3], &lps));
    // Voxel 0 is at x = 3 · 2 mm, voxel 3 at 0.
    assert_eq!(s * nalgebra::Vector4::new(0.0, 1.0, 1.0, 1.0), nalgebra::Vector4::new(6.0, 2.0, 2.5, 1.0));
    assert_eq!(s * nalgebra::Vector4::new(3.0, 0.0, 0.0, 1.0), nalgebra::Vector4::new(0.0, 0.0, 0.0, 1.0));
}

#[test]
fn text_that_is_not_a_flirt_matrix_is_refused_by_name() {
    let name = Path::new("start.mat");
    let cases: [(&str, &[&str]); 5] = [
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", &["3 lines", "4"]),
        ("1 0 0 0 5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", &["line 1", "5 numbers"]),
        ("1 0 0 0\n0 nan 0 0\n0 0 1 0\n0 0 0 1\n", &["line 2", "\"nan\""]),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 2 1\n", &["0 0 0 1"]),
        ("1 0 0 x\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", &["line 1", "\"x\""]),
    ];
    for (text, needles) in cases {
        let e = fsl::parse(name, text).expect_err(text).to_string();
        assert!(e.contains("start.mat"), "{e}");
        for needle in needles {
            assert!(e.contains(needle), "{text:?}: {e:?} lacks {needle:?}");
        }
    }
    // FLIRT's own spacing, blank lines and exponents are fine.
    let m = fsl::parse(name, "  1.0  0  0  1e1  \n\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").expect("a FLIRT matrix");
    assert!((m[(0, 3)] - 10.0).abs() < 1e-15, "{m}");
    // Other transform files are not taken for one: ITK's text, ANTs' binary .mat.
    let itk = std::fs::read(dir().join("../itk/tfm_composite.tfm")).expect("a .tfm");
    assert!(!fsl::looks_like_flirt_matrix(&itk));
    let ants = std::fs::read(dir().join("../itk/affine_sitk.mat")).expect("an ANTs .mat");
    assert!(!fsl::looks_like_flirt_matrix(&ants));
    // A singular grid or matrix is refused, naming the file.
    let singular = Matrix4::zeros();
    let grid = warpbench_io::geometry::Transform::identity();
    let e = fsl::moving_from_fixed(name, &singular, ([2, 2, 2], &grid), ([2, 2, 2], &grid)).expect_err("singular");
    assert!(e.to_string().contains("start.mat") && e.to_string().contains("cannot be inverted"), "{e}");
}
