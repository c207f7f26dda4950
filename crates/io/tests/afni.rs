//! AFNI's matrix file (`.aff12.1D`): the two-row example of AFNI's documentation ("-1Dmatrix_save and
//! -1Dmatrix_apply", R. W. Cox, 2007) is refused as two matrices and each of its rows reads to its twelve numbers,
//! row by row; what is written reads back to the same doubles; obliquity is told as nitransforms tells it (the
//! oblique grid of `tests/data/fsl/` is oblique, the LAS and LPS ones are not); bad text is refused by name.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use warpbench_io::afni;

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/fsl")
}

const DOC_ROWS: [&str; 2] = [
    " 1 0.000906864 -0.000222938 -0.0564219 -0.000908728 0.999963 -0.00850925 -0.660097 0.000215214 0.00850945 \
     0.999964 0.579968",
    " 1 0.000346147 -0.000353107 -0.0735129 -0.00034904 0.999966 -0.00822638 -0.435146 0.000350247 0.0082265 \
     0.999966 0.0866295",
];

#[test]
fn the_documentations_matrices_read_row_by_row() {
    let name = Path::new("volreg.aff12.1D");
    let header = "# 3dvolreg matrices (DICOM-to-DICOM, row-by-row):";
    let both = format!("{header}\n{}\n{}\n", DOC_ROWS[0], DOC_ROWS[1]);
    assert!(afni::looks_like_afni_matrix(both.as_bytes()));
    let e = afni::parse(name, &both).expect_err("two matrices").to_string();
    assert!(e.contains("volreg.aff12.1D") && e.contains("2 matrices"), "{e}");
    // A long run's file is told by its first 4 KiB, whose last row is cut.
    let long = format!("{header}\n{}", format!("{}\n", DOC_ROWS[0]).repeat(60));
    assert!(long.len() > 4096 && afni::looks_like_afni_matrix(&long.as_bytes()[..4096]));
    let e = afni::parse(name, &long).expect_err("60 matrices").to_string();
    assert!(e.contains("60 matrices"), "{e}");
    for row in DOC_ROWS {
        let m = afni::parse(name, &format!("{header}\n{row}\n")).expect("one matrix");
        let numbers: Vec<f64> = row.split_whitespace().map(|v| v.parse().expect("a number")).collect();
        for (n, want) in numbers.iter().enumerate() {
            assert_eq!(m[(n / 4, n % 4)].to_bits(), want.to_bits(), "number {}", n + 1);
        }
        assert_eq!(m.row(3).iter().copied().collect::<Vec<_>>(), [0.0, 0.0, 0.0, 1.0]);
        let again = afni::parse(name, &afni::to_text(&m)).expect("what is written");
        assert!(again.iter().zip(m.iter()).all(|(a, b)| a.to_bits() == b.to_bits()), "{again} against {m}");
    }
}

#[test]
fn obliquity_is_told_by_the_axes_angle_to_the_patient_axes() {
    let open = |n: &str| warpbench_io::open(dir().join(format!("{n}.nii.gz"))).expect("volume").lps_from_index;
    // The oblique grid is rotated by (0.1, -0.2, 0.3) rad about the axes: far beyond 0.01°.
    assert!(afni::obliquity_degrees(&open("oblique")) > 5.0);
    for n in ["las", "lps"] {
        assert!(afni::obliquity_degrees(&open(n)) < 1e-9, "{n}");
        afni::check_cardinal(Path::new("m.aff12.1D"), "fixed", &open(n)).expect("not oblique");
    }
    let e = afni::check_cardinal(Path::new("m.aff12.1D"), "moving", &open("oblique_las")).expect_err("oblique");
    assert!(e.to_string().contains("m.aff12.1D") && e.to_string().contains("moving volume is oblique"), "{e}");
}

#[test]
fn text_that_is_not_one_afni_matrix_is_refused_by_name() {
    let name = Path::new("start.aff12.1D");
    let cases: [(&str, &str); 4] = [
        ("# only a comment\n", "no matrix"),
        ("1 0 0 0 0 1 0 0 0 0 1\n", "11 numbers"),
        ("1 0 0 0 0 1 0 0 0 0 1 inf\n", "number 12"),
        ("1 0 0 0 0 1 0 0 0 0 1 0 7\n", "13 numbers"),
    ];
    for (text, needle) in cases {
        let e = afni::parse(name, text).expect_err(text).to_string();
        assert!(e.contains("start.aff12.1D") && e.contains(needle), "{text:?}: {e}");
    }
    // FSL's matrix (four rows of four) and ITK's text are not AFNI's.
    let flirt = std::fs::read(dir().join("oblique_from_las.mat")).expect("a FLIRT matrix");
    assert!(!afni::looks_like_afni_matrix(&flirt));
    let itk = std::fs::read(dir().join("../itk/tfm_composite.tfm")).expect("a .tfm");
    assert!(!afni::looks_like_afni_matrix(&itk));
    assert!(afni::write(Path::new("/nonexistent-dir/x.aff12.1D"), &Matrix4::identity()).is_err());
}
