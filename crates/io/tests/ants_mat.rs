//! The ANTs / ITK affine `.mat` (MATLAB v4) against SimpleITK: its files (and hand-made big-endian and float ones,
//! `data-scripts/ants_mat_sitk.py`) read to the parameters SimpleITK reads and the `.tfm` of the same transform holds;
//! ours are SimpleITK's bytes and read back bit for bit; bad files are refused naming the file and the problem.

use std::path::{Path, PathBuf};

use nalgebra::Matrix3;
use serde_json::Value;
use warpbench_io::itk_tfm::{self, ItkAffine, ItkThinPlateSpline, ItkTransform};

use crate::support::numbers;

fn itk_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk")
}

fn reference() -> Value {
    let text = std::fs::read_to_string(itk_dir().join("ants_mat_reference.json")).expect("reference");
    serde_json::from_str(&text).expect("JSON")
}

fn parameters(a: &ItkAffine) -> Vec<f64> {
    (0..3).flat_map(|r| (0..3).map(move |c| a.matrix[(r, c)])).chain(a.translation).collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn simpleitk_files_read_to_simpleitks_parameters_and_the_tfms() {
    let r = reference();
    let tfm = itk_tfm::read_affine(&itk_dir().join(r["tfm"].as_str().expect("tfm"))).expect("the .tfm");
    for case in r["cases"].as_array().expect("cases") {
        let file = case["file"].as_str().expect("file");
        let path = itk_dir().join(file);
        let a = itk_tfm::read_affine(&path).unwrap_or_else(|e| panic!("{e}"));
        let ItkTransform::Affine(b) = itk_tfm::read(&path).expect("read") else { panic!("{file}: not an affine") };
        assert_eq!(a, b);
        assert_eq!(bits(&parameters(&a)), bits(&numbers(&case["parameters"])), "{file}: parameters");
        assert_eq!(bits(&a.center), bits(&numbers(&case["fixed_parameters"])), "{file}: centre");
        // The double files hold the .tfm's numbers; the float one those numbers rounded to f32.
        let from_tfm: Vec<f64> = parameters(&tfm).into_iter().chain(tfm.center).collect();
        let ours: Vec<f64> = parameters(&a).into_iter().chain(a.center).collect();
        let want: Vec<f64> =
            if file.contains("float") { from_tfm.iter().map(|&x| f64::from(x as f32)).collect() } else { from_tfm };
        assert_eq!(bits(&ours), bits(&want), "{file} against the .tfm");
        for (p, q) in case["points"].as_array().expect("points").iter().zip(case["transformed"].as_array().expect("q"))
        {
            let (p, q) = (numbers(p), numbers(q));
            let y = a.apply([p[0], p[1], p[2]]);
            let err = (0..3).map(|i| (y[i] - q[i]).abs()).fold(0.0, f64::max);
            assert!(err < 1e-12, "{file}: T({p:?}) = {y:?}, SimpleITK {q:?}");
        }
    }
}

#[test]
fn we_write_simpleitks_bytes_and_read_them_back_bit_for_bit() {
    let tfm = itk_tfm::read_affine(&itk_dir().join("affine_sitk.tfm")).expect("tfm");
    let theirs = std::fs::read(itk_dir().join("affine_sitk.mat")).expect("mat");
    assert_eq!(itk_tfm::to_mat_bytes(&tfm), theirs, "the same transform, the same bytes");

    let dir = tempfile::tempdir().expect("tempdir");
    let affine = ItkAffine {
        matrix: Matrix3::new(1.02, -0.05, 0.001, 0.04, 0.98, -0.3, 1e-7, 0.31, 1.1),
        translation: [3.25, -2.0 / 3.0, 1e-300],
        center: [f64::MIN_POSITIVE, -0.0, 7.0 / 3.0],
    };
    for name in ["a.mat", "B.MAT"] {
        let path = dir.path().join(name);
        itk_tfm::write_affine(&path, &affine).expect("write");
        let back = itk_tfm::read_affine(&path).expect("read");
        assert_eq!(bits(&parameters(&back)), bits(&parameters(&affine)));
        assert_eq!(bits(&back.center), bits(&affine.center));
    }
    // Told by content too: a .mat renamed.
    let renamed = dir.path().join("start.transform");
    std::fs::copy(dir.path().join("a.mat"), &renamed).expect("copy");
    assert_eq!(itk_tfm::read_affine(&renamed).expect("by content"), affine);

    // A .mat holds an affine only.
    let tps = ItkTransform::ThinPlateSpline(ItkThinPlateSpline {
        source_lps: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        target_lps: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    });
    let out = dir.path().join("tps.mat");
    let e = itk_tfm::write(&out, &tps).expect_err("a TPS in a .mat");
    assert!(e.to_string().contains("holds an affine transform only; write the"), "{e}");
    assert!(!out.exists());
}

/// One little-endian MATLAB v4 variable of doubles, `rows` × 1, with an explicit type code.
fn variable(code: i32, name: &str, values: &[f64]) -> Vec<u8> {
    let mut out = Vec::new();
    for w in [code, values.len() as i32, 1, 0, name.len() as i32 + 1] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(name.as_bytes());
    out.push(0);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

#[test]
fn bad_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let good = std::fs::read(itk_dir().join("affine_sitk.mat")).expect("mat");
    let p12: Vec<f64> = (0..12).map(f64::from).collect();
    let c3 = [1.0, 2.0, 3.0];
    let fixed = variable(0, "fixed", &c3);
    let cat = |a: Vec<u8>, b: &[u8]| [a, b.to_vec()].concat();
    let mut imaginary = good.clone();
    imaginary[12] = 1;
    let mut nan = variable(0, "AffineTransform_double_3_3", &p12);
    let at = nan.len() - 8;
    nan[at..].copy_from_slice(&f64::NAN.to_le_bytes());
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty.mat", Vec::new(), "fewer than a MATLAB v4 variable header"),
        ("text.mat", b"#Insight Transform File V1.0\n".to_vec(), "an ITK text transform file: name it .tfm"),
        ("random.mat", vec![0xAB; 64], "not a MATLAB v4 variable header"),
        ("cut_values.mat", good[..100].to_vec(), "the file ends within variable 1 (the 12 values"),
        ("cut_name.mat", good[..30].to_vec(), "the file ends within variable 1 (its name)"),
        ("cut_fixed.mat", good[..good.len() - 4].to_vec(), "the file ends within variable 2"),
        ("no_fixed.mat", variable(0, "AffineTransform_double_3_3", &p12), "no \"fixed\" variable"),
        ("no_params.mat", fixed.clone(), "no parameters variable"),
        ("other_name.mat", cat(variable(0, "parameters", &p12), &fixed), "is named \"parameters\""),
        ("euler.mat", cat(variable(0, "Euler3DTransform_double_3_3", &[0.0; 6]), &fixed), "only an affine"),
        ("eleven.mat", cat(variable(0, "AffineTransform_double_3_3", &p12[..11]), &fixed), "must hold 12 values"),
        (
            "four_fixed.mat",
            cat(variable(0, "AffineTransform_double_3_3", &p12), &variable(0, "fixed", &[0.0; 4])),
            "must hold 3 values",
        ),
        ("int32.mat", cat(variable(20, "AffineTransform_double_3_3", &p12), &fixed), "type code 20"),
        // A type code whose big-endian reading is i32::MIN, from which the big-endian base (1000) cannot be taken in
        // i32 (found by fuzzing).
        ("min_code.mat", cat(variable(0x80, "AffineTransform_double_3_3", &p12), &fixed), "-2147483648 big-endian"),
        (
            "mixed_order.mat",
            cat(variable(0, "AffineTransform_double_3_3", &p12), &variable(1000, "fixed", &c3)),
            "variable 2: type code",
        ),
        ("imaginary.mat", imaginary, "complex values"),
        ("twice.mat", cat(cat(variable(0, "AffineTransform_double_3_3", &p12), &fixed), &fixed), "given twice"),
        ("nan.mat", cat(nan, &fixed), "value 12 is not finite"),
    ];
    for (name, bytes, needle) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).expect("write");
        let e = itk_tfm::read(&path).expect_err(name);
        let msg = e.to_string();
        assert!(msg.starts_with(&path.display().to_string()), "{name}: {msg}");
        assert!(msg.contains(needle), "{name}: {msg:?} lacks {needle:?}");
    }
}
