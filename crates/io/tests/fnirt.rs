//! FSL FNIRT's warps against fslpy 3.29.1 (`data-scripts/fnirt_fixtures.py`): coefficient fields over references of
//! either handedness, with and without a starting affine, and the same warp as relative and absolute deformation
//! fields, each read as the pull-back that takes each reference voxel to the source point fslpy maps it to; the
//! deformation type fslpy detects; and what is not such a warp, or not against its reference, refused naming the file.

use std::path::{Path, PathBuf};

use warpbench_io::Volume;
use warpbench_io::fnirt;

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/fnirt")
}

fn open(name: &str) -> Volume {
    warpbench_io::open(dir().join(name)).unwrap_or_else(|e| panic!("{e}"))
}

fn reference() -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir().join("reference.json")).expect("the reference")).expect("JSON")
}

#[test]
fn each_warp_takes_the_reference_voxels_where_fslpy_takes_them() {
    let reference = reference();
    let voxels = reference["voxels"].as_array().expect("voxels");
    let src = open("src.nii.gz");
    for (name, case) in reference["warps"].as_object().expect("warps") {
        let fixed = open(&format!("{}.nii.gz", case["reference"].as_str().expect("a name")));
        let path = dir().join(name);
        assert_eq!(
            warpbench_io::nifti::fsl_intent(&path).expect("read"),
            Some(if name.starts_with("coef") { 2007 } else { 2006 })
        );
        let read = fnirt::read_pullback(&path, (fixed.dims, &fixed.lps_from_index), (src.dims, &src.lps_from_index))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(read.field.dims, fixed.dims);
        assert_eq!(read.field.lps_from_index, fixed.lps_from_index);
        if let Some(detected) = case.get("detected") {
            let detected = detected.as_str().expect("a type");
            assert_eq!(detected, case["written_as"].as_str().expect("a type"), "{name}: fslpy's own test");
            assert!(
                read.warnings.iter().any(|w| w.starts_with(&format!("read as {detected}"))),
                "{name}: {:?}",
                read.warnings
            );
        } else {
            assert!(read.warnings.is_empty(), "{name}: {:?}", read.warnings);
        }
        let mut worst = 0.0f64;
        for (v, want) in voxels.iter().zip(case["moving_lps"].as_array().expect("points")) {
            let ijk: Vec<usize> =
                v.as_array().expect("a voxel").iter().map(|c| c.as_u64().expect("an index") as usize).collect();
            let n = ijk[0] + fixed.dims[0] * (ijk[1] + fixed.dims[1] * ijk[2]);
            let x = fixed.voxel_lps(ijk[0], ijk[1], ijk[2]).coords();
            let d = read.field.displacements_lps[n];
            for c in 0..3 {
                let got = x[c] + f64::from(d[c]);
                worst = worst.max((got - want[c].as_f64().expect("a number")).abs());
            }
        }
        // fslpy evaluates in float64 from the same float32 numbers; the field keeps float32 vectors of up to ~60 mm.
        assert!(worst < 1e-4, "{name}: {worst} mm from fslpy");
    }
}

#[test]
fn the_relative_and_absolute_fields_and_the_coefficients_are_one_warp() {
    let fixed = open("ref_neuro.nii.gz");
    let src = open("src.nii.gz");
    let read = |name: &str| {
        fnirt::read_pullback(&dir().join(name), (fixed.dims, &fixed.lps_from_index), (src.dims, &src.lps_from_index))
            .unwrap_or_else(|e| panic!("{e}"))
            .field
            .displacements_lps
    };
    let coef = read("coef_neuro.nii.gz");
    for name in ["field_rel.nii.gz", "field_abs.nii.gz"] {
        let worst = coef
            .iter()
            .zip(read(name))
            .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0f32, f32::max))
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{name}: {worst} mm from the coefficients");
    }
}

#[test]
fn what_is_not_an_fnirt_warp_against_its_reference_is_refused_naming_the_file() {
    let neuro = open("ref_neuro.nii.gz");
    let radio = open("ref_radio.nii.gz");
    let src = open("src.nii.gz");
    let refused = |name: &str, fixed: &Volume, want: &str| {
        let path = dir().join(name);
        let e = fnirt::read_pullback(&path, (fixed.dims, &fixed.lps_from_index), (src.dims, &src.lps_from_index))
            .expect_err(name)
            .to_string();
        assert!(e.contains(name) && e.contains(want), "{name}: {e}");
    };
    refused("coef_quadratic.nii.gz", &radio, "quadratic B-spline coefficients are not read");
    refused("topup_field.nii.gz", &radio, "TOPUP off-resonance field");
    // The right shape, the wrong place: the radiological reference lies elsewhere.
    refused("field_rel.nii.gz", &radio, "mm from the fixed volume's");
    // Another grid altogether.
    refused("field_rel.nii.gz", &src, "give that image (fnirt's --ref) as the fixed volume");
    refused("coef_neuro.nii.gz", &src, "made with a reference image of [20, 24, 18] voxels");
    // Not FSL's: an ordinary image, and a file that is no NIfTI at all.
    assert_eq!(warpbench_io::nifti::fsl_intent(&dir().join("src.nii.gz")).expect("read"), None);
    assert_eq!(warpbench_io::nifti::fsl_intent(&dir().join("reference.json")).expect("read"), None);
    refused("src.nii.gz", &neuro, "not an FSL FNIRT warp");
}

/// What `write_pullback` writes is FNIRT's relative deformation field (intent 2006, float32, the reference's sform)
/// and reads back, as such, to the pull-back it was given: here the coefficients' own, on the reference grid of each
/// handedness. (`crates/python/tests/test_fnirt.py` has nibabel read the header.)
#[test]
fn a_pullback_written_as_an_fnirt_field_reads_back_to_itself() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let src = open("src.nii.gz");
    for (coef, reference) in [("coef_neuro.nii.gz", "ref_neuro.nii.gz"), ("coef_radio.nii.gz", "ref_radio.nii.gz")] {
        let fixed = open(reference);
        let (f, m) = ((fixed.dims, &fixed.lps_from_index), (src.dims, &src.lps_from_index));
        let read = fnirt::read_pullback(&dir().join(coef), f, m).unwrap_or_else(|e| panic!("{e}"));
        let out = tmp.path().join("w.nii.gz");
        fnirt::write_pullback(&out, f, m, &read.field.displacements_lps).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(warpbench_io::nifti::fsl_intent(&out).expect("read"), Some(2006));
        let again = fnirt::read_pullback(&out, f, m).unwrap_or_else(|e| panic!("{e}"));
        assert!(again.warnings.iter().any(|w| w.starts_with("read as relative")), "{:?}", again.warnings);
        let worst = again
            .field
            .displacements_lps
            .iter()
            .zip(&read.field.displacements_lps)
            .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0f32, f32::max))
            .fold(0.0f32, f32::max);
        // Two float32 roundings of vectors up to ~60 mm.
        assert!(worst < 2e-5, "{coef}: {worst} mm");
    }
}
