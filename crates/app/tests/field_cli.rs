//! `warpbench field` end to end: the binary on a real MRI fixture (`avg152T1_LR_nifti.nii`, 91×109×91, 2 mm, stored
//! left-right flipped) as both fixed and moving volume, checked three ways:
//!
//! - against our own math: the field read back with our reader equals u(x) − x at every voxel, u fitted here through
//!   `warpbench_solver`; the `.tfm` read back equals the solver's affine;
//! - against an independent reader: `tests/data/itk/field_*_reference.json` hold what SimpleITK 2.5.7 (ITK 5.4) maps
//!   at 441 voxel centres and at the landmarks when it reads a field (and a `.tfm`) this command wrote
//!   (`data-scripts/check_field_sitk.py`); the field written now must give the same points;
//! - and its refusals (exit 2, nothing written).
//!
//! The in-memory core the window calls, `field::displacement_field` with `field::write_field`, writes the very files
//! the command writes, and stops when its progress callback says so.

mod common;

use std::path::{Path, PathBuf};

use common::{assert_ok, deformed_pairs as write_pairs, mri as fixture, utf8, warpbench};

use warpbench_app::exit::Failure;
use warpbench_app::field;
use warpbench_app::inputs::Names;
use warpbench_app::project::stack::Layers;
use warpbench_io::displacement::{FieldDirection, FieldFormat};
use warpbench_io::geometry::{Index, Lps, Point3, Transform};
use warpbench_io::itk_tfm;
use warpbench_io::landmarks::read_bigwarp_csv;
use warpbench_io::nifti::{DisplacementField, read_displacement_field};
use warpbench_solver::linear::{self, LinearKind};
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::{Fixed, Moving, as_fixed, as_moving};
use warpbench_solver::warp::Warp;

/// The field is float32: a displacement of at most ~10 mm is rounded by less than 1e-6 mm; this leaves room for
/// the difference between our batch evaluation and the point evaluation used here.
const F32_TOLERANCE_MM: f64 = 1e-4;

fn itk_data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk").join(name)
}

/// The (moving, fixed) points of a BigWarp CSV, typed.
fn read_points(csv: &Path) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let pairs = read_bigwarp_csv(csv).expect("landmarks");
    let moving = pairs.iter().map(|p| as_moving(p.moving.expect("moving point"))).collect();
    let fixed = pairs.iter().map(|p| as_fixed(p.fixed.expect("fixed point"))).collect();
    (moving, fixed)
}

/// The pull-back u = moving_from_fixed fitted as the CLI fits it (over the fixed volume's box).
fn pullback(method: &Method, csv: &Path) -> FittedWarp<Moving, Fixed> {
    let (moving, fixed) = read_points(csv);
    let volume = warpbench_io::open(fixture()).expect("fixture");
    let fixed_box = warpbench_app::inputs::volume_box::<Fixed>(&volume);
    warpbench_app::fit::pullback(method, &fixed, &moving, fixed_box).expect("fit")
}

fn voxel_lps(lps_from_index: &Transform<Lps, Index>, ijk: [usize; 3]) -> [f64; 3] {
    lps_from_index.apply_point(Point3::from_array(ijk.map(|v| v as f64))).coords()
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}

/// The largest |D_file(x) − (u(x) − x)| over every voxel of `field`.
fn max_error_mm(field: &DisplacementField, u: &dyn Warp<Moving, Fixed>) -> f64 {
    let [nx, ny, nz] = field.dims;
    let mut worst = 0.0f64;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let x = voxel_lps(&field.lps_from_index, [i, j, k]);
                let u_x = u.apply_raw(x);
                let d = field.displacements_lps[i + nx * (j + ny * k)].map(f64::from);
                worst = worst.max(distance([x[0] + d[0], x[1] + d[1], x[2] + d[2]], u_x));
            }
        }
    }
    worst
}

#[test]
fn field_read_back_equals_the_pullback_and_maps_the_landmarks() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (f, pairs) = (fixture(), write_pairs(dir.path(), false));
    let out_gz = dir.path().join("field.nii.gz");
    let run = warpbench(&[
        "field",
        "--fixed",
        utf8(&f),
        "--moving",
        utf8(&f),
        "--landmarks",
        utf8(&pairs),
        "--json",
        "--quiet",
        "--out",
        utf8(&out_gz),
    ]);
    assert_ok(&run);
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!(json["schema"], "warpbench-field/1");
    assert_eq!(json["dims"], serde_json::json!([91, 109, 91]));
    assert_eq!(json["spacing_mm"], serde_json::json!([2.0, 2.0, 2.0]));
    assert_eq!(
        (json["grid"].as_str(), json["method"].as_str(), json["pairs"].as_u64()),
        (Some("fixed"), Some("tps"), Some(7))
    );
    assert_eq!(json["tfm"], serde_json::Value::Null);

    let field = read_displacement_field(&out_gz).expect("our reader reads the field");
    assert_eq!(field.dims, [91, 109, 91]);
    let fixed = warpbench_io::open(&f).expect("fixture");
    assert!(field.lps_from_index.max_abs_diff(&fixed.lps_from_index) < 1e-4);
    let u = pullback(&Method::Tps { stiffness: 0.0 }, &pairs);
    let worst = max_error_mm(&field, u.as_ref());
    assert!(worst < F32_TOLERANCE_MM, "the field differs from the pull-back by up to {worst} mm");
    let max_d =
        field.displacements_lps.iter().map(|d| d.map(f64::from)).map(|d| distance(d, [0.0; 3])).fold(0.0, f64::max);
    let reported = json["max_displacement_mm"].as_f64().expect("max_displacement_mm");
    assert!((max_d - reported).abs() < 1e-4 && reported > 4.0, "max |D| {max_d} vs reported {reported}");

    // The fixed landmarks lie on voxel centres: there the field maps qᵢ to pᵢ (TPS interpolates).
    let index_from_lps = field.lps_from_index.inverse().expect("invertible");
    let (moving_points, fixed_points) = read_points(&pairs);
    for (p, q) in moving_points.iter().zip(&fixed_points) {
        let idx = index_from_lps.apply_point(Point3::from_array(q.coords())).coords().map(|v| v.round() as usize);
        let d = field.displacements_lps[idx[0] + 91 * (idx[1] + 109 * idx[2])].map(f64::from);
        let q = q.coords();
        let mapped = [q[0] + d[0], q[1] + d[1], q[2] + d[2]];
        assert!(distance(mapped, p.coords()) < F32_TOLERANCE_MM, "q {q:?} maps to {mapped:?}, not {:?}", p.coords());
    }

    // Uncompressed, the header says what ITK needs: dim [5, X, Y, Z, 1, 3], intent 1006, float32.
    let out_nii = dir.path().join("field.nii");
    let args = ["field", "--fixed", utf8(&f), "--moving", utf8(&f), "--landmarks", utf8(&pairs), "--quiet", "--out"];
    assert_ok(&warpbench(&[&args[..], &[utf8(&out_nii)]].concat()));
    let raw = std::fs::read(&out_nii).expect("read the field");
    let i16_at = |o: usize| i16::from_le_bytes([raw[o], raw[o + 1]]);
    assert_eq!((0..8).map(|i| i16_at(40 + 2 * i)).collect::<Vec<_>>(), [5, 91, 109, 91, 1, 3, 1, 1]);
    assert_eq!((i16_at(68), i16_at(70)), (1006, 16), "intent_code and datatype");
    assert_eq!(raw.len(), 352 + 91 * 109 * 91 * 3 * 4);
    let same = read_displacement_field(&out_nii).expect("read .nii");
    assert_eq!(same.displacements_lps, field.displacements_lps, ".nii and .nii.gz hold the same field");
}

#[test]
fn reference_sets_the_grid() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (f, pairs) = (fixture(), write_pairs(dir.path(), false));
    let reference = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/big.nii.gz");
    let out = dir.path().join("field.nii.gz");
    let run = warpbench(&[
        "field",
        "--fixed",
        utf8(&f),
        "--moving",
        utf8(&f),
        "--landmarks",
        utf8(&pairs),
        "--reference",
        utf8(&reference),
        "--json",
        "--out",
        utf8(&out),
    ]);
    assert_ok(&run);
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!((json["grid"].as_str(), &json["dims"]), (Some("reference"), &serde_json::json!([64, 64, 21])));
    let field = read_displacement_field(&out).expect("read");
    let grid = warpbench_io::open(&reference).expect("reference volume");
    assert_eq!(field.dims, grid.dims);
    assert!(field.lps_from_index.max_abs_diff(&grid.lps_from_index) < 1e-4);
    // The same warp (fitted over the fixed box), evaluated on the reference's voxel centres.
    let worst = max_error_mm(&field, pullback(&Method::Tps { stiffness: 0.0 }, &pairs).as_ref());
    assert!(worst < F32_TOLERANCE_MM, "{worst} mm");
}

#[test]
fn tfm_round_trips_and_equals_the_solver_affine() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (f, pairs) = (fixture(), write_pairs(dir.path(), false));
    let (out, tfm) = (dir.path().join("affine.nii.gz"), dir.path().join("affine.tfm"));
    let run = warpbench(&[
        "field",
        "--fixed",
        utf8(&f),
        "--moving",
        utf8(&f),
        "--landmarks",
        utf8(&pairs),
        "--method",
        "affine",
        "--tfm",
        utf8(&tfm),
        "--json",
        "--out",
        utf8(&out),
    ]);
    assert_ok(&run);
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!(json["tfm"].as_str(), Some(utf8(&tfm)));
    let text = std::fs::read_to_string(&tfm).expect("tfm text");
    assert!(text.starts_with("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"));
    let read = itk_tfm::read_affine(&tfm).expect("our parser reads it");
    let (moving, fixed) = read_points(&pairs);
    let fit = linear::fit_pullback(LinearKind::Affine, &moving, &fixed).expect("fit");
    assert_eq!(read.matrix.map(f64::to_bits), fit.warp.linear().map(f64::to_bits), "A, bit for bit");
    assert_eq!(read.offset().map(f64::to_bits), fit.warp.translation().map(f64::to_bits), "b, bit for bit");
    // The field of the same run is that affine.
    let field = read_displacement_field(&out).expect("read");
    let worst = max_error_mm(&field, &fit.warp);
    assert!(worst < F32_TOLERANCE_MM, "field vs tfm: {worst} mm");
}

/// The ITK reference: what SimpleITK maps when it reads a field (and a `.tfm`) written by this command from
/// `tests/data/itk/field_pairs.csv` (`tests/data/itk/README.md`). The field written now must hold the same vectors
/// where ITK sampled it, and both must be the exact pull-back.
#[test]
fn itk_reads_our_field_as_our_pullback() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (f, pairs) = (fixture(), itk_data("field_pairs.csv"));
    for (method, reference) in [("tps", "field_tps_reference.json"), ("rigid", "field_rigid_reference.json")] {
        let text = std::fs::read_to_string(itk_data(reference)).expect("reference JSON");
        let itk: serde_json::Value = serde_json::from_str(&text).expect("parse reference");
        let out = dir.path().join(format!("{method}.nii.gz"));
        let tfm = dir.path().join(format!("{method}.tfm"));
        let mut args = vec!["field", "--fixed", utf8(&f), "--moving", utf8(&f), "--landmarks", utf8(&pairs)];
        args.extend(["--method", method, "--quiet", "--out", utf8(&out)]);
        if method == "rigid" {
            args.extend(["--tfm", utf8(&tfm)]);
        }
        assert_ok(&warpbench(&args));
        let field = read_displacement_field(&out).expect("read");
        let u = pullback(&Method::from_name(method).expect("method"), &pairs);

        let point = |v: &serde_json::Value| -> [f64; 3] {
            let a = v.as_array().expect("a point");
            std::array::from_fn(|i| a[i].as_f64().expect("a number"))
        };
        let grid = itk["field"]["grid"].as_array().expect("grid points");
        assert!(grid.len() > 300, "{} grid points", grid.len());
        for g in grid {
            let idx: [usize; 3] = point(&g["index"]).map(|v| v as usize);
            let (x_itk, mapped_itk) = (point(&g["x"]), point(&g["mapped"]));
            // ITK places the voxel where we do (so it read our sform/qform as we meant them) ...
            let x_lps = voxel_lps(&field.lps_from_index, idx);
            assert!(distance(x_itk, x_lps) < 1e-4, "voxel {idx:?}: ITK {x_itk:?}, ours {x_lps:?}");
            // ... reads there the vector we write now (so the RAS flip and the plane order are what ITK expects) ...
            let d = field.displacements_lps[idx[0] + 91 * (idx[1] + 109 * idx[2])].map(f64::from);
            let ours = [x_lps[0] + d[0], x_lps[1] + d[1], x_lps[2] + d[2]];
            assert!(
                distance(mapped_itk, ours) < F32_TOLERANCE_MM,
                "{method} {idx:?}: ITK {mapped_itk:?}, ours {ours:?}"
            );
            // ... and that is the pull-back.
            assert!(distance(mapped_itk, u.apply_raw(x_lps)) < F32_TOLERANCE_MM, "{method} {idx:?}");
        }
        // Off the grid ITK interpolates linearly: at the landmarks (not voxel centres) the TPS field maps qᵢ within
        // 0.1 mm of pᵢ (U(r) = r has a cusp at each landmark, which linear interpolation cuts).
        if method == "tps" {
            let worst = itk["field"]["landmark_max_error_mm"].as_f64().expect("landmark error");
            assert!(worst < 0.11, "ITK maps the landmarks {worst} mm from their targets");
        } else {
            let read = itk_tfm::read_affine(&tfm).expect("tfm");
            for l in itk["tfm"]["landmarks"].as_array().expect("tfm landmarks") {
                let (q, mapped_itk) = (point(&l["fixed"]), point(&l["mapped"]));
                assert!(distance(mapped_itk, read.apply(q)) < 1e-9, "tfm at {q:?}: ITK {mapped_itk:?}");
                assert!(distance(mapped_itk, u.apply_raw(q)) < 1e-9, "tfm vs the rigid pull-back at {q:?}");
            }
            let diff = itk["tfm"]["max_field_difference_mm"].as_f64().expect("field vs tfm");
            assert!(diff < F32_TOLERANCE_MM, "ITK: the rigid field and the tfm differ by {diff} mm");
        }
    }
}

#[test]
fn refuses_bad_landmarks_methods_and_unsafe_outputs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let f = fixture();
    let f = utf8(&f);
    let (good, outside) = (write_pairs(dir.path(), false), write_pairs(dir.path(), true));
    let out = dir.path().join("x.nii.gz");
    let o = utf8(&out);
    let expect_bad = |args: &[&str], needle: &str| {
        let run = warpbench(args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr:?} lacks {needle:?}");
    };
    let l = utf8(&good);
    let tfm = dir.path().join("x.tfm");
    expect_bad(
        &[
            "field",
            "--fixed",
            f,
            "--moving",
            f,
            "--landmarks",
            l,
            "--direction",
            "forward",
            "--tfm",
            utf8(&tfm),
            "--quiet",
            "--out",
            o,
        ],
        "x.tfm: an ITK transform file holds the pull-back",
    );
    expect_bad(
        &["field", "--fixed", f, "--moving", f, "--landmarks", l, "--format", "nrrd", "--quiet", "--out", o],
        "x.nii.gz: invalid: the nrrd field flavour is written to a .nrrd name",
    );
    // Learn2Reg's .npz holds the pull-back on the fixed voxels, in its one flavour.
    let npz = dir.path().join("disp.npz");
    let n = utf8(&npz);
    let field = ["field", "--fixed", f, "--moving", f, "--landmarks", l, "--quiet", "--out", n];
    for (extra, needle) in [
        (&["--direction", "forward"][..], "disp.npz: a name ending .npz is Learn2Reg's field, which maps fixed voxels"),
        (&["--reference", f][..], "which holds one vector per voxel of the fixed image: leave out --reference"),
        (&["--format", "metaimage"][..], "not the metaimage flavour"),
    ] {
        expect_bad(&[&field[..], extra].concat(), needle);
        assert!(!npz.exists());
    }
    // --format learn2reg: the NIfTI form under a NIfTI name, with the same rules.
    let form = dir.path().join("disp.nii.gz");
    let field = ["field", "--fixed", f, "--moving", f, "--landmarks", l, "--format", "learn2reg", "--quiet"];
    for (extra, needle) in [
        (&["--out", utf8(&form), "--direction", "forward"][..], "disp.nii.gz: --format learn2reg writes Learn2Reg's"),
        (&["--out", &format!("{o}.nrrd")][..], "as .npz (the challenge's form until 2021) or .nii.gz"),
    ] {
        expect_bad(&[&field[..], extra].concat(), needle);
        assert!(!form.exists());
    }
    expect_bad(
        &[
            "field",
            "--fixed",
            f,
            "--moving",
            f,
            "--landmarks",
            l,
            "--format",
            "ants",
            "--quiet",
            "--out",
            &format!("{o}.nrrd"),
        ],
        "x.nii.gz.nrrd: invalid: the ants field flavour is written to a .nii or .nii.gz name",
    );
    expect_bad(
        &["field", "--fixed", f, "--moving", f, "--landmarks", utf8(&outside), "--quiet", "--out", o],
        "landmark 3 (Pt-2) is outside the moving volume",
    );
    expect_bad(
        &["field", "--fixed", f, "--moving", f, "--quiet", "--out", o],
        "give the warp: --landmarks, --moving-points with --fixed-points, --session, or --field",
    );
    expect_bad(
        &["field", "--fixed", f, "--moving", f, "--landmarks", l, "--quiet", "--out", f],
        "refusing to overwrite an input",
    );
    expect_bad(
        &[
            "field",
            "--fixed",
            f,
            "--moving",
            f,
            "--landmarks",
            l,
            "--method",
            "rigid",
            "--tfm",
            o,
            "--quiet",
            "--out",
            o,
        ],
        "--tfm and --out are the same file",
    );
    assert!(!out.exists() && !tfm.exists(), "a refused run wrote a file");

    // An existing output needs --force, and is left as it was without it.
    std::fs::write(&out, b"keep me").expect("write");
    expect_bad(&["field", "--fixed", f, "--moving", f, "--landmarks", l, "--quiet", "--out", o], "exists; use --force");
    assert_eq!(std::fs::read(&out).expect("read"), b"keep me");
    std::fs::write(&tfm, b"keep me too").expect("write");
    expect_bad(
        &["field", "--fixed", f, "--moving", f, "--landmarks", l, "--method", "rigid", "--tfm", utf8(&tfm), "--quiet"]
            .into_iter()
            .chain(["--out", utf8(&dir.path().join("new.nii"))])
            .collect::<Vec<_>>(),
        "x.tfm: exists; use --force",
    );
    assert_eq!(std::fs::read(&tfm).expect("read"), b"keep me too");
    assert!(!dir.path().join("new.nii").exists());
    assert_ok(&warpbench(&["field", "--fixed", f, "--moving", f, "--landmarks", l, "--quiet", "--force", "--out", o]));
    assert!(read_displacement_field(&out).is_ok(), "--force replaced the file with a field");

    // A MetaImage field's .mhd writes a .raw beside it: an existing one is left as it was without --force, and a
    // NIfTI name is not a MetaImage one.
    let (mhd, raw) = (dir.path().join("deformationField.mhd"), dir.path().join("deformationField.raw"));
    std::fs::write(&raw, b"keep me three").expect("write");
    let metaimage = ["field", "--fixed", f, "--moving", f, "--landmarks", l, "--format", "metaimage", "--quiet"];
    let with = |more: &[&'static str], out: &Path| -> Vec<String> {
        metaimage.iter().chain(more).map(|a| (*a).to_string()).chain(["--out".into(), utf8(out).into()]).collect()
    };
    let args = with(&[], &mhd);
    expect_bad(&args.iter().map(String::as_str).collect::<Vec<_>>(), "deformationField.raw: exists; use --force");
    assert!(!mhd.exists() && std::fs::read(&raw).expect("read") == b"keep me three");
    let args = with(&[], &dir.path().join("field.nii.gz"));
    expect_bad(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "the metaimage field flavour is written to a .mha",
    );
    let args = with(&["--force"], &mhd);
    assert_ok(&warpbench(&args.iter().map(String::as_str).collect::<Vec<_>>()));
    assert!(std::fs::read(&raw).expect("read").len() == 12 * 91 * 109 * 91, "--force replaced the data file");
    assert!(warpbench_io::displacement::read_field(&mhd).is_ok());
}

fn names(moving: &Path, csv: &Path, out: &Path) -> Names {
    Names { moving: moving.display().to_string(), landmarks: csv.display().to_string(), out: out.to_path_buf() }
}

#[test]
fn the_in_memory_core_writes_the_files_the_command_writes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (f, csv) = (fixture(), write_pairs(dir.path(), false));
    let volume = warpbench_io::open(&f).expect("fixture");
    let pairs = read_bigwarp_csv(&csv).expect("landmarks");
    for (name, method) in [("tps", Method::Tps { stiffness: 0.0 }), ("affine", Method::Linear(LinearKind::Affine))] {
        let (cli_out, cli_tfm) =
            (dir.path().join(format!("cli_{name}.nii")), dir.path().join(format!("cli_{name}.tfm")));
        let mut args = vec!["field", "--fixed", utf8(&f), "--moving", utf8(&f), "--landmarks", utf8(&csv)];
        args.extend_from_slice(&["--method", name, "--json", "--quiet", "--out", utf8(&cli_out)]);
        let linear = matches!(method, Method::Linear(_));
        if linear {
            args.extend_from_slice(&["--tfm", utf8(&cli_tfm)]);
        }
        let run = warpbench(&args);
        assert_ok(&run);
        let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");

        let (core_out, core_tfm) =
            (dir.path().join(format!("core_{name}.nii")), dir.path().join(format!("core_{name}.tfm")));
        let mut last = (0, 0);
        let sampled = field::displacement_field(
            &volume,
            &volume,
            &volume,
            (&pairs, &Layers::default()),
            &names(&f, &csv, &core_out),
            &method,
            &mut |done, total| {
                assert!(done > last.0 && done <= total, "{done} of {total} after {last:?}");
                last = (done, total);
                true
            },
        )
        .expect("the field in memory");
        assert_eq!(last.1, 91, "progress counts the slices");
        field::write_field(&sampled, &core_out, FieldFormat::Itk, linear.then_some(core_tfm.as_path())).expect("write");
        let read = |p: &Path| std::fs::read(p).expect("read a written file");
        assert!(read(&cli_out) == read(&core_out), "{name}: the core's field differs from the command's");
        assert_eq!(linear, core_tfm.exists());
        if linear {
            assert_eq!(read(&cli_tfm), read(&core_tfm), "{name}: the core's .tfm differs from the command's");
        }
        assert_eq!(json["method"], sampled.method.as_str());
        assert_eq!(json["pairs"], sampled.pairs);
        // serde_json may parse a float one ulp off what it printed.
        let reported = json["max_displacement_mm"].as_f64().expect("max_displacement_mm");
        assert!(
            (reported - sampled.max_displacement_mm).abs() <= 1e-12 * reported,
            "{reported} vs {}",
            sampled.max_displacement_mm
        );
        assert_eq!(json["dims"], serde_json::json!(sampled.dims));
        assert_eq!(json["spacing_mm"], serde_json::json!(sampled.spacing_mm));
        assert_eq!(json["lps_from_index"], serde_json::json!(sampled.lps_from_index.rows()));
    }

    // A .tfm holds the pull-back: with a forward field it is refused before anything is written.
    let names = names(&f, &csv, Path::new("unused.nii"));
    let inputs = field::FieldInputs {
        fixed: &volume,
        moving: &volume,
        pairs: &pairs,
        names: &names,
        method: &Method::Tps { stiffness: 0.0 },
        layers: &Layers::default(),
    };
    let forward =
        field::sample_field(&volume, &inputs, FieldDirection::Forward, &mut |_, _| true).expect("the field in memory");
    assert!(forward.transform.is_none());
    let (out, tfm) = (dir.path().join("refused.nii"), dir.path().join("refused.tfm"));
    assert!(matches!(field::write_field(&forward, &out, FieldFormat::Itk, Some(&tfm)), Err(Failure::BadInput(_))));
    assert!(!out.exists() && !tfm.exists(), "a refused write wrote something");
}

#[test]
fn the_in_memory_core_stops_when_progress_says_so() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (f, csv) = (fixture(), write_pairs(dir.path(), false));
    let volume = warpbench_io::open(&f).expect("fixture");
    let pairs = read_bigwarp_csv(&csv).expect("landmarks");
    // Stop at the first report, and at the second.
    for stop_at in [1, 2] {
        let mut calls = 0;
        let result = field::displacement_field(
            &volume,
            &volume,
            &volume,
            (&pairs, &Layers::default()),
            &names(&f, &csv, &dir.path().join("never.nii")),
            &Method::Tps { stiffness: 0.0 },
            &mut |_, _| {
                calls += 1;
                calls < stop_at
            },
        );
        match result {
            Err(Failure::Cancelled(e)) => assert!(format!("{e:#}").contains("cancelled"), "{e:#}"),
            Err(other) => panic!("stop at {stop_at}: {:#}", other.error()),
            Ok(_) => panic!("stop at {stop_at}: a cancelled sampling returned a field"),
        }
        assert_eq!(calls, stop_at, "no progress call after the one that said stop");
    }
    assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 1, "only the pairs: nothing was written");
}
