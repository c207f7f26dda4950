//! `warpbench transform` end to end, against ITK's own reading of the files it writes.
//!
//! `tests/data/itk/tfm_reference.json` (made by `data-scripts/itk_tfm_ref.py`, provenance in that folder's README)
//! holds, for an affine, two thin-plate splines (λ = 0 and λ = 2) and a hierarchical B-spline fitted on
//! `field_pairs.csv`, what ITK 5.4.7 / SimpleITK 2.5.7 map 300 points of the fixed box to through the `.tfm`
//! (`ReadTransform` + `TransformPoint`; the TPS through `ThinPlateSplineKernelTransform` given the file's parameters).
//! The script checked 10 000 points against `warpbench points --from fixed`. Here, for each case:
//!
//! - warpbench's pull-back (`points --from fixed`) at the recorded points equals ITK's outputs within 1e-4 mm;
//! - the file written now says the same: evaluated by ITK's rules (the affine's matrix and offset, the B-spline's
//!   `TransformPoint` rule, an interpolating U = r spline through the TPS file's landmarks) it gives ITK's outputs;
//! - and the refusals exit 2, name the file and write nothing.
//!
//! elastix: `tests/data/elastix/transformix_reference.json` (made by `data-scripts/elastix_transforms.py` with
//! itk-elastix 0.25.4) holds where transformix maps points through the files `transform --format elastix` writes,
//! and through linear files elastix itself wrote, which `--initial` reads.

mod common;

use std::path::{Path, PathBuf};

use common::{assert_ok, data, mri, utf8, warpbench};
use serde_json::Value;
use warpbench_io::geometry::Point3;
use warpbench_io::itk_tfm::{self, ItkTransform};
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::tps::Tps;
use warpbench_solver::warp::Warp;

const TOLERANCE_MM: f64 = 1e-4;

fn reference() -> Value {
    let text = std::fs::read_to_string(data("itk/tfm_reference.json")).expect("read the reference");
    serde_json::from_str(&text).expect("the reference is JSON")
}

fn points_of(v: &Value) -> Vec<[f64; 3]> {
    v.as_array()
        .expect("a list of points")
        .iter()
        .map(|p| std::array::from_fn(|k| p[k].as_f64().expect("a number")))
        .collect()
}

fn strings(v: &Value) -> Vec<String> {
    v.as_array().expect("a list").iter().map(|s| s.as_str().expect("a string").to_string()).collect()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// The common arguments of the reference: the MRI as fixed and moving, the field pairs.
fn pair_args() -> Vec<String> {
    let (f, l) = (mri(), data("itk/field_pairs.csv"));
    ["--fixed", utf8(&f), "--moving", utf8(&f), "--landmarks", utf8(&l)].map(str::to_string).to_vec()
}

/// The file evaluated by ITK's rule for its class.
fn itk_rule(t: &ItkTransform, x: [f64; 3]) -> [f64; 3] {
    match t {
        ItkTransform::Affine(a) => a.apply(x),
        ItkTransform::BSpline(b) => b.apply(x),
        ItkTransform::ThinPlateSpline(s) => {
            let src: Vec<Point3<Fixed>> = s.source_lps.iter().map(|&p| Point3::from_array(p)).collect();
            let dst: Vec<Point3<Moving>> = s.target_lps.iter().map(|&p| Point3::from_array(p)).collect();
            Tps::fit(&src, &dst, 0.0).expect("an interpolating spline through the file's landmarks").apply_raw(x)
        }
    }
}

#[test]
fn itk_reads_every_method_as_warpbench_s_pullback() {
    let reference = reference();
    let recorded_points = points_of(&reference["points_lps"]);
    let dir = tempfile::tempdir().expect("tempdir");
    let points_csv = dir.path().join("points.csv");
    let lines: Vec<String> = recorded_points.iter().map(|p| format!("{},{},{}", p[0], p[1], p[2])).collect();
    let text = lines.join("\n") + "\n";
    std::fs::write(&points_csv, text).expect("write points");

    let cases = reference["cases"].as_array().expect("cases");
    assert_eq!(cases.len(), 4);
    for case in cases {
        let name = case["name"].as_str().expect("a name");
        let flags = strings(&case["flags"]);
        let itk_outputs = points_of(&case["itk_outputs_lps"]);
        assert_eq!(itk_outputs.len(), recorded_points.len());

        // The file, written now.
        let tfm = dir.path().join(format!("{name}.tfm"));
        let mut args: Vec<String> = vec!["transform".into()];
        args.extend(pair_args());
        args.extend(flags.iter().cloned());
        args.extend(["--out".into(), utf8(&tfm).into(), "--json".into(), "--quiet".into()]);
        let out = warpbench(&args);
        assert_ok(&out);
        let summary: Value = serde_json::from_slice(&out.stdout).expect("the summary is JSON");
        assert_eq!(summary["schema"], "warpbench-transform/1");
        assert_eq!(summary["itk_class"], case["itk_class"], "{name}");
        assert_eq!(summary["map"], "moving_from_fixed");
        assert_eq!(summary["pairs"], 8);
        let first_line = std::fs::read_to_string(&tfm).expect("read the file");
        assert!(first_line.starts_with("#Insight Transform File V1.0\n"), "{name}");
        let t = itk_tfm::read(&tfm).expect("the file reads back");
        assert_eq!(t.type_name(), case["itk_class"].as_str().expect("a class"));
        for (k, (&x, &want)) in recorded_points.iter().zip(&itk_outputs).enumerate() {
            let got = itk_rule(&t, x);
            assert!(dist(got, want) <= TOLERANCE_MM, "{name}: point {}: the file gives {got:?}, ITK {want:?}", k + 1);
        }

        // warpbench's pull-back at the same points.
        let mapped = dir.path().join(format!("{name}_u.csv"));
        let mut args: Vec<String> = vec!["points".into()];
        args.extend(pair_args());
        args.extend(flags.iter().cloned());
        args.extend(
            ["--from", "fixed", "--in", utf8(&points_csv), "--out", utf8(&mapped), "--quiet"].map(String::from),
        );
        assert_ok(&warpbench(&args));
        let ours: Vec<[f64; 3]> = std::fs::read_to_string(&mapped)
            .expect("read")
            .lines()
            .map(|l| {
                let f: Vec<f64> = l.split(',').map(|v| v.parse().expect("a number")).collect();
                [f[0], f[1], f[2]]
            })
            .collect();
        assert_eq!(ours.len(), itk_outputs.len());
        let mut moved = 0.0f64;
        for (k, ((&u, &want), &x)) in ours.iter().zip(&itk_outputs).zip(&recorded_points).enumerate() {
            assert!(dist(u, want) <= TOLERANCE_MM, "{name}: point {}: u = {u:?}, ITK {want:?}", k + 1);
            moved = moved.max(dist(u, x));
        }
        assert!(moved > 1.0, "{name}: the warp moves points ({moved} mm), so agreement means something");
    }
}

#[test]
fn the_stiff_spline_is_the_same_transform_as_the_interpolating_one_through_its_values() {
    // λ > 0: the file holds the centres and u(centres), not λ; the interpolating spline through them is u (module
    // docs of warpbench_app::transform). Its targets are not the moving landmarks, so λ did change the file.
    let dir = tempfile::tempdir().expect("tempdir");
    let read = |stiffness: &str| -> Vec<[f64; 3]> {
        let tfm = dir.path().join(format!("tps_{stiffness}.tfm"));
        let mut args: Vec<String> = vec!["transform".into()];
        args.extend(pair_args());
        args.extend(["--stiffness", stiffness, "--out", utf8(&tfm), "--quiet"].map(String::from));
        assert_ok(&warpbench(&args));
        match itk_tfm::read(&tfm).expect("read") {
            ItkTransform::ThinPlateSpline(s) => s.target_lps,
            other => panic!("a thin-plate spline, not {}", other.type_name()),
        }
    };
    let (exact, stiff) = (read("0"), read("2"));
    let moving: Vec<[f64; 3]> = std::fs::read_to_string(data("itk/field_pairs.csv"))
        .expect("read")
        .lines()
        .map(|l| {
            let f: Vec<f64> =
                l.trim_matches('"').split("\",\"").skip(2).take(3).map(|v| v.parse().expect("num")).collect();
            [f[0], f[1], f[2]]
        })
        .collect();
    for (k, (e, m)) in exact.iter().zip(&moving).enumerate() {
        assert!(dist(*e, *m) < 1e-9, "λ = 0: target {} is the moving landmark: {e:?} vs {m:?}", k + 1);
    }
    let shift = exact.iter().zip(&stiff).map(|(a, b)| dist(*a, *b)).fold(0.0, f64::max);
    assert!(shift > 0.01, "λ = 2 smooths: the targets move by {shift} mm");
}

#[test]
fn refusals_exit_2_naming_the_file_and_write_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = |extra: &[&str]| {
        let mut args: Vec<String> = vec!["transform".into()];
        args.extend(pair_args());
        args.extend(extra.iter().map(ToString::to_string));
        warpbench(&args)
    };
    let stderr = |o: &std::process::Output| String::from_utf8_lossy(&o.stderr).into_owned();

    let taken: PathBuf = dir.path().join("taken.tfm");
    std::fs::write(&taken, "keep me").expect("write");
    let o = run(&["--out", utf8(&taken)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("taken.tfm") && stderr(&o).contains("--force"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&taken).expect("read"), "keep me");

    let pairs = data("itk/field_pairs.csv");
    let before = std::fs::read(&pairs).expect("read");
    let o = run(&["--out", utf8(&pairs), "--force"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("field_pairs.csv"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&pairs).expect("read"), before, "the input is unchanged");

    let out = dir.path().join("negative.tfm");
    let o = run(&["--stiffness=-1", "--out", utf8(&out)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("stiffness"), "{}", stderr(&o));
    assert!(!out.exists());

    let three = dir.path().join("three.csv");
    let lines: Vec<&str> = std::str::from_utf8(&before).expect("utf8").lines().take(3).collect();
    std::fs::write(&three, lines.join("\n") + "\n").expect("write");
    let out = dir.path().join("three.tfm");
    let f = mri();
    let o = warpbench(&[
        "transform",
        "--fixed",
        utf8(&f),
        "--moving",
        utf8(&f),
        "--landmarks",
        utf8(&three),
        "--out",
        utf8(&out),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("three.csv"), "{}", stderr(&o));
    assert!(!out.exists());
    assert!(!Path::new(&out).with_extension("tfm.tmp").exists());
}

#[test]
fn field_tfm_writes_the_file_transform_writes() {
    let dir = tempfile::tempdir().expect("tempdir");
    for method in ["tps", "hbspline"] {
        let (a, b, field) = (dir.path().join("a.tfm"), dir.path().join("b.tfm"), dir.path().join("f.nii.gz"));
        let mut args: Vec<String> = vec!["transform".into()];
        args.extend(pair_args());
        args.extend(["--method", method, "--levels", "2", "--out", utf8(&a), "--quiet", "--force"].map(String::from));
        assert_ok(&warpbench(&args));
        let mut args: Vec<String> = vec!["field".into()];
        args.extend(pair_args());
        args.extend(
            ["--method", method, "--levels", "2", "--tfm", utf8(&b), "--out", utf8(&field), "--json", "--force"]
                .map(String::from),
        );
        let out = warpbench(&args);
        assert_ok(&out);
        let summary: Value = serde_json::from_slice(&out.stdout).expect("JSON");
        let class =
            if method == "tps" { "ThinPlateSplineKernelTransform_double_3_3" } else { "BSplineTransform_double_3_3" };
        assert_eq!(summary["tfm_class"], class);
        assert_eq!(std::fs::read(&a).expect("read"), std::fs::read(&b).expect("read"), "{method}");
    }
}

/// `warpbench align` finds a known rigid transform of the MRI fixture (the moving file is the same voxels with the
/// transform put into its header, so m(T(x)) = f(x) exactly), writes it as an ITK affine that the reader gives back,
/// reports it in `--json`, and refuses to overwrite its output or to read a file that is not a volume.
#[test]
fn align_writes_the_known_rigid_transform_as_an_itk_affine() {
    use nalgebra::{Rotation3, Unit, Vector3};
    use warpbench_io::geometry::Transform;

    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = mri();
    let mut moving = warpbench_io::open(&fixed).expect("read the fixture");
    let rotation =
        Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(0.3, -0.5, 1.0)), 12f64.to_radians()).into_inner();
    let truth: Transform<warpbench_io::geometry::Lps, warpbench_io::geometry::Lps> =
        Transform::from_linear_translation(rotation, [14.0, -9.0, 6.0]);
    moving.lps_from_index = truth * moving.lps_from_index;
    let moving_path = dir.path().join("moved.nii");
    warpbench_io::nifti::write(&moving_path, &moving).expect("write the moved fixture");
    let out = dir.path().join("align.tfm");
    let args = ["align", "--fixed", utf8(&fixed), "--moving", utf8(&moving_path), "--out-tfm", utf8(&out), "--json"];
    let run = warpbench(&args);
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!(report["schema"], "warpbench-align/1");
    assert_eq!(report["kind"], "rigid");
    assert!((report["rotation_deg"].as_f64().expect("rotation") - 12.0).abs() < 0.2, "{report}");
    let Ok(ItkTransform::Affine(affine)) = itk_tfm::read(&out) else { panic!("an affine in {}", out.display()) };
    // Over the fixed volume's box, the file maps like the truth within half a millimetre.
    let volume = warpbench_io::open(&fixed).expect("fixture");
    let mut worst: f64 = 0.0;
    for c in 0..8 {
        let ijk = [0, 1, 2].map(|a| if c >> a & 1 == 1 { (volume.dims[a] - 1) as f64 } else { 0.0 });
        let x = volume.lps_from_index.apply_point(Point3::from_array(ijk)).coords();
        let got = affine.apply(x);
        let want = truth.apply_point(Point3::from_array(x)).coords();
        worst = worst.max((0..3).map(|a| (got[a] - want[a]).powi(2)).sum::<f64>().sqrt());
    }
    assert!(worst < 0.5, "{worst} mm at a corner of the fixed box");
    // The moving_from_fixed rows in the report are the file's map.
    let rows = &report["moving_from_fixed"];
    let x = [10.0, -20.0, 30.0];
    let from_rows: Vec<f64> = (0..3)
        .map(|r| {
            (0..3).map(|c| rows[r][c].as_f64().expect("entry") * x[c]).sum::<f64>() + rows[r][3].as_f64().expect("t")
        })
        .collect();
    let from_file = affine.apply(x);
    assert!((0..3).all(|a| (from_rows[a] - from_file[a]).abs() < 1e-9));

    // Refusals: an existing output without --force, and a moving file that is not a volume.
    let again = warpbench(&args);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("align.tfm"), "{}", String::from_utf8_lossy(&again.stderr));
    let not_a_volume = data("nifti/not-nifti.nii");
    let out2 = dir.path().join("never.tfm");
    let bad = warpbench(&["align", "--fixed", utf8(&fixed), "--moving", utf8(&not_a_volume), "--out-tfm", utf8(&out2)]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not-nifti.nii"), "{}", String::from_utf8_lossy(&bad.stderr));
    assert!(!out2.exists());
}

/// `--initial` puts `warpbench align`'s result under the landmark warp: with fewer pairs than the method needs it
/// alone is the warp (`points` maps by its affine exactly; `warp` gives back the fixed volume from a moving volume
/// moved by a known rigid transform), with enough pairs the landmark warp refines it (the TPS hits its pairs and
/// `transform` writes it as one TPS), and a file that is not an affine is refused by name.
#[test]
fn initial_puts_the_alignment_under_the_landmark_warp() {
    use nalgebra::{Rotation3, Unit, Vector3};
    use warpbench_io::geometry::{Lps, Transform};

    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = mri();
    let fixed_volume = warpbench_io::open(&fixed).expect("read the fixture");
    let mut moving = fixed_volume.clone();
    let rotation =
        Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(-0.4, 0.2, 1.0)), 9f64.to_radians()).into_inner();
    let truth: Transform<Lps, Lps> = Transform::from_linear_translation(rotation, [-8.0, 11.0, 4.0]);
    moving.lps_from_index = truth * moving.lps_from_index;
    let moving_path = dir.path().join("moved.nii");
    warpbench_io::nifti::write(&moving_path, &moving).expect("write the moved fixture");
    let tfm = dir.path().join("start.tfm");
    assert_ok(&warpbench(&[
        "align",
        "--fixed",
        utf8(&fixed),
        "--moving",
        utf8(&moving_path),
        "--out-tfm",
        utf8(&tfm),
        "--quiet",
    ]));
    let Ok(ItkTransform::Affine(start)) = itk_tfm::read(&tfm) else { panic!("an affine") };

    // Two pairs (too few for a TPS): the start alone.
    let fixed_points = [
        [10.0, -20.0, 15.0],
        [-30.0, 5.0, 0.0],
        [25.0, 30.0, -10.0],
        [0.0, -40.0, 30.0],
        [-15.0, 10.0, -25.0],
        [5.0, 5.0, 5.0],
    ];
    let bump = |q: [f64; 3], i: usize| {
        let p = start.apply(q);
        [p[0] + if i == 5 { 2.0 } else { 0.0 }, p[1], p[2]]
    };
    let pairs: Vec<([f64; 3], [f64; 3])> = fixed_points.iter().enumerate().map(|(i, q)| (bump(*q, i), *q)).collect();
    let two = dir.path().join("two.csv");
    common::write_pairs_csv(&two, &pairs[..2]);
    let six = dir.path().join("six.csv");
    common::write_pairs_csv(&six, &pairs);
    let targets = dir.path().join("targets.csv");
    std::fs::write(&targets, "12,-7,20,a\n-35,22,-14,b\n").expect("write points");
    let mapped = dir.path().join("mapped.csv");
    let base = ["--fixed", utf8(&fixed), "--moving", utf8(&moving_path), "--initial", utf8(&tfm)];
    let run = warpbench(
        &[
            &["points"][..],
            &base,
            &["--landmarks", utf8(&two), "--from", "fixed", "--in", utf8(&targets), "--out", utf8(&mapped), "--json"],
        ]
        .concat(),
    );
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert!(report["method"].as_str().expect("method").contains("alone (2 pairs; tps needs 4)"), "{report}");
    let text = std::fs::read_to_string(&mapped).expect("read the mapped points");
    for (line, x) in
        text.lines().filter(|l| !l.starts_with('#') && !l.is_empty()).zip([[12.0, -7.0, 20.0], [-35.0, 22.0, -14.0]])
    {
        let got: Vec<f64> = line.split(',').take(3).map(|v| v.trim().parse().expect("number")).collect();
        let want = start.apply(x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-6), "{got:?} vs {want:?}");
    }

    // warp through the start alone gives back the fixed volume (the moving one is the fixed one, moved).
    let warped = dir.path().join("warped.nii");
    assert_ok(&warpbench(
        &[&["warp"][..], &base, &["--landmarks", utf8(&two), "--exact", "--float", "--out", utf8(&warped), "--quiet"]]
            .concat(),
    ));
    let out = warpbench_io::open(&warped).expect("read the output");
    let (mut sum_sq, mut count) = (0.0, 0usize);
    let (mut diff_sq, mut range) = (0.0, 0.0f64);
    for k in 4..fixed_volume.dims[2] - 4 {
        for j in 4..fixed_volume.dims[1] - 4 {
            for i in 4..fixed_volume.dims[0] - 4 {
                let o = fixed_volume.offset(i, j, k);
                let (a, b) = (fixed_volume.data.get_f64(o), out.data.get_f64(o));
                diff_sq += (a - b).powi(2);
                sum_sq += a * a;
                range = range.max(a.abs());
                count += 1;
            }
        }
    }
    let rms = (diff_sq / count as f64).sqrt();
    assert!(
        rms < 0.02 * range,
        "RMS difference {rms} against a range of {range} (signal RMS {})",
        (sum_sq / count as f64).sqrt()
    );

    // Six pairs: a TPS on top of the start hits every pair, and `transform` writes one TPS.
    let out_tfm = dir.path().join("tps.tfm");
    let run = warpbench(
        &[&["transform"][..], &base, &["--landmarks", utf8(&six), "--out", utf8(&out_tfm), "--json"]].concat(),
    );
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert!(report["method"].as_str().expect("method").starts_with("tps on "), "{report}");
    let Ok(ItkTransform::ThinPlateSpline(spline)) = itk_tfm::read(&out_tfm) else { panic!("a TPS file") };
    let source: Vec<Point3<Fixed>> = spline.source_lps.iter().map(|p| Point3::from_array(*p)).collect();
    let target: Vec<Point3<Moving>> = spline.target_lps.iter().map(|p| Point3::from_array(*p)).collect();
    let tps = Tps::fit(&source, &target, 0.0).expect("ITK's interpolating spline");
    for (p, q) in &pairs {
        let got = tps.apply(Point3::<Fixed>::from_array(*q)).coords();
        assert!((0..3).all(|a| (got[a] - p[a]).abs() < 1e-6), "{got:?} vs {p:?}");
    }

    // A file that is not an affine.
    let run = warpbench(
        &[
            &["points"][..],
            &["--fixed", utf8(&fixed), "--moving", utf8(&moving_path), "--initial", utf8(&out_tfm)],
            &[
                "--landmarks",
                utf8(&six),
                "--from",
                "fixed",
                "--in",
                utf8(&targets),
                "--out",
                utf8(&dir.path().join("never.csv")),
            ],
        ]
        .concat(),
    );
    assert_eq!(run.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("tps.tfm") && stderr.contains("affine"), "{stderr}");
}

/// ANTs' `.mat` wherever a `.tfm` goes: `align` and `transform` write the same affine to either name (the same
/// numbers, bit for bit), `--initial` reads either to the same warp, and a `.mat` is refused for a TPS.
#[test]
fn the_ants_mat_is_the_tfms_affine_in_and_out() {
    use nalgebra::{Rotation3, Unit, Vector3};
    use warpbench_io::geometry::{Lps, Transform};

    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = mri();
    let mut moving = warpbench_io::open(&fixed).expect("read the fixture");
    let rotation =
        Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(0.2, 0.5, 1.0)), 7f64.to_radians()).into_inner();
    let truth: Transform<Lps, Lps> = Transform::from_linear_translation(rotation, [6.0, -4.0, 3.0]);
    moving.lps_from_index = truth * moving.lps_from_index;
    let moving_path = dir.path().join("moved.nii");
    warpbench_io::nifti::write(&moving_path, &moving).expect("write the moved fixture");
    let pair = ["--fixed", utf8(&fixed), "--moving", utf8(&moving_path)];
    let affine_of = |path: &Path| match itk_tfm::read(path) {
        Ok(ItkTransform::Affine(a)) => a,
        other => panic!("{}: {other:?}", path.display()),
    };
    let bits = |a: &itk_tfm::ItkAffine| {
        a.matrix.iter().chain(&a.translation).chain(&a.center).map(|v| v.to_bits()).collect::<Vec<_>>()
    };

    let (tfm, mat) = (dir.path().join("start.tfm"), dir.path().join("start.mat"));
    for out in [&tfm, &mat] {
        let args = [&["align"][..], &pair, &["--shrink", "4,2", "--out-tfm", utf8(out), "--quiet"]].concat();
        assert_ok(&warpbench(&args));
    }
    assert_eq!(bits(&affine_of(&mat)), bits(&affine_of(&tfm)), "align: the same affine in both files");
    assert_eq!(itk_tfm::to_mat_bytes(&affine_of(&tfm)), std::fs::read(&mat).expect("mat"));

    let pairs = dir.path().join("pairs.csv");
    let q = [[10.0, -20.0, 15.0], [-30.0, 5.0, 0.0], [25.0, 30.0, -10.0], [0.0, -40.0, 30.0], [-15.0, 10.0, -25.0]];
    let p: Vec<([f64; 3], [f64; 3])> = q.iter().map(|q| ([q[0] + 1.0, q[1] - 2.0, q[2] + 0.5], *q)).collect();
    common::write_pairs_csv(&pairs, &p);
    let (lin_tfm, lin_mat) = (dir.path().join("affine.tfm"), dir.path().join("affine.mat"));
    for out in [&lin_tfm, &lin_mat] {
        let args =
            [&["transform"][..], &pair, &["--landmarks", utf8(&pairs), "--method", "affine", "--out", utf8(out)]]
                .concat();
        assert_ok(&warpbench(&args));
    }
    assert_eq!(bits(&affine_of(&lin_mat)), bits(&affine_of(&lin_tfm)), "transform: the same affine");

    // --initial: the same mapped points from either file.
    let targets = dir.path().join("targets.csv");
    std::fs::write(&targets, "12,-7,20,a\n-35,22,-14,b\n").expect("write points");
    let mapped = |initial: &Path, name: &str| {
        let out = dir.path().join(name);
        let args = [
            &["points"][..],
            &pair,
            &["--initial", utf8(initial), "--landmarks", utf8(&pairs), "--from", "fixed"],
            &["--in", utf8(&targets), "--out", utf8(&out), "--quiet"],
        ]
        .concat();
        assert_ok(&warpbench(&args));
        std::fs::read_to_string(&out).expect("mapped points")
    };
    assert_eq!(mapped(&mat, "via_mat.csv"), mapped(&tfm, "via_tfm.csv"));

    // A TPS has no .mat: refused, nothing written.
    let tps_mat = dir.path().join("tps.mat");
    let run = warpbench(&[&["transform"][..], &pair, &["--landmarks", utf8(&pairs), "--out", utf8(&tps_mat)]].concat());
    assert_eq!(run.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("tps.mat") && stderr.contains("holds an affine transform only"), "{stderr}");
    assert!(!tps_mat.exists());
}

fn elastix_reference() -> Value {
    let text = std::fs::read_to_string(data("elastix/transformix_reference.json")).expect("read the reference");
    serde_json::from_str(&text).expect("the reference is JSON")
}

/// `points --from fixed` on the MRI with `flags` (the landmark flags included) at `at`: warpbench's pull-back.
fn pullback_at(dir: &Path, flags: &[&str], at: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let (input, output) = (dir.join("in.csv"), dir.join("out.csv"));
    let lines: Vec<String> = at.iter().map(|p| format!("{:?},{:?},{:?}", p[0], p[1], p[2])).collect();
    std::fs::write(&input, lines.join("\n") + "\n").expect("write");
    let m = mri();
    let mut args = vec!["points", "--fixed", utf8(&m), "--moving", utf8(&m), "--from", "fixed", "--quiet", "--force"];
    args.extend_from_slice(flags);
    args.extend(["--in", utf8(&input), "--out", utf8(&output)]);
    assert_ok(&warpbench(&args));
    let text = std::fs::read_to_string(&output).expect("read");
    text.lines()
        .map(|l| std::array::from_fn(|k| l.split(',').nth(k).expect("x,y,z").parse().expect("a number")))
        .collect()
}

/// `transform --format elastix` writes, for each method, the very file `data-scripts/elastix_transforms.py` gave
/// transformix (itk-elastix 0.25.4; same sha256), and warpbench's pull-back maps the recorded points where transformix
/// mapped them through it: a SplineKernelTransform (interpolating, and λ = 5 through u's values at the centres), a
/// cubic BSplineTransform on the hierarchy's finest lattice, an AffineTransform. transformix prints 6 decimals, so
/// the bound is 1e-5 mm (the script measured 5e-7); the points move up to 6.7 mm.
#[test]
fn transformix_maps_points_through_our_elastix_file_as_warpbench_does() {
    use sha2::Digest;
    let r = elastix_reference();
    let at = points_of(&r["warpbench_points_lps"]);
    let dir = tempfile::tempdir().expect("tempdir");
    let (m, l) = (mri(), data("itk/field_pairs.csv"));
    for case in r["warpbench_files"].as_array().expect("cases") {
        let name = case["name"].as_str().expect("name");
        let flags = strings(&case["flags"]);
        let path = dir.path().join(format!("{name}.txt"));
        let mut args = vec!["transform", "--fixed", utf8(&m), "--moving", utf8(&m), "--landmarks", utf8(&l)];
        args.extend(flags.iter().map(String::as_str));
        args.extend(["--format", "elastix", "--quiet", "--json", "--out", utf8(&path)]);
        let run = warpbench(&args);
        assert_ok(&run);
        let summary: Value = serde_json::from_slice(&run.stdout).expect("JSON");
        assert_eq!(summary["format"], "elastix");
        let text = std::fs::read_to_string(&path).expect("read");
        let class = summary["elastix_transform"].as_str().expect("a class");
        assert!(text.lines().any(|line| line == format!("(Transform \"{class}\")")), "{name}: {class}");
        let sha = format!("{:x}", sha2::Sha256::digest(text.as_bytes()));
        assert_eq!(sha, case["sha256"].as_str().expect("sha256"), "{name}: the file transformix read");
        let mut landmark_flags = vec!["--landmarks", utf8(&l)];
        landmark_flags.extend(flags.iter().map(String::as_str));
        let ours = pullback_at(dir.path(), &landmark_flags, &at);
        for (n, (got, want)) in ours.iter().zip(points_of(&case["transformix_lps"])).enumerate() {
            assert!(dist(*got, want) < 1e-5, "{name}: point {}: warpbench {got:?}, transformix {want:?}", n + 1);
        }
        // warpbench reads the file back as transformix applies it: the thin-plate spline solved from its
        // landmarks as ITK solves it, the B-spline and the affine from their parameters.
        let back = warpbench_io::elastix::read_transform(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        for (n, (x, want)) in at.iter().zip(points_of(&case["transformix_lps"])).enumerate() {
            let got = back.apply(*x);
            assert!(dist(got, want) < 1e-5, "{name} read back: point {}: {got:?}, transformix {want:?}", n + 1);
        }
    }
}

/// `--initial` takes elastix's own linear files, a chain of them included (an affine over a rigid, as `elastix -p
/// rigid -p affine` writes it): with too few pairs to refine it, the pull-back is the file's transform, which maps
/// the recorded points where transformix did. A deformable elastix file, and `--format elastix` to a `.mat`, exit 2.
#[test]
fn initial_reads_elastix_linear_files_and_their_chain() {
    let r = elastix_reference();
    let at = points_of(&r["elastix_points_lps"]);
    let dir = tempfile::tempdir().expect("tempdir");
    let three = dir.path().join("three.csv");
    let pairs = std::fs::read_to_string(data("itk/field_pairs.csv")).expect("pairs");
    std::fs::write(&three, pairs.lines().take(3).collect::<Vec<_>>().join("\n") + "\n").expect("write");
    for f in r["elastix_files"].as_array().expect("files").iter().filter(|f| f["linear"] == true) {
        let file = data(&format!("elastix/{}", f["file"].as_str().expect("file")));
        let ours = pullback_at(dir.path(), &["--landmarks", utf8(&three), "--initial", utf8(&file)], &at);
        for (n, (got, want)) in ours.iter().zip(points_of(&f["transformix_lps"])).enumerate() {
            assert!(dist(*got, want) < 1e-5, "{}: point {}: {got:?} vs {want:?}", file.display(), n + 1);
        }
    }
    let m = mri();
    let bspline = dir.path().join("bspline.txt");
    let made = ["transform", "--fixed", utf8(&m), "--moving", utf8(&m), "--landmarks"];
    let field_pairs = data("itk/field_pairs.csv");
    let mut args = made.to_vec();
    args.extend([
        utf8(&field_pairs),
        "--method",
        "hbspline",
        "--format",
        "elastix",
        "--quiet",
        "--out",
        utf8(&bspline),
    ]);
    assert_ok(&warpbench(&args));
    let (input, output) = (dir.path().join("p.csv"), dir.path().join("o.csv"));
    std::fs::write(&input, "1,2,3\n").expect("write");
    let run = warpbench(&[
        "points",
        "--fixed",
        utf8(&m),
        "--moving",
        utf8(&m),
        "--landmarks",
        utf8(&three),
        "--initial",
        utf8(&bspline),
        "--from",
        "fixed",
        "--in",
        utf8(&input),
        "--out",
        utf8(&output),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("bspline.txt") && stderr.contains("BSplineTransform is not a linear transform"),
        "{stderr}"
    );
    assert!(!output.exists());
    let mat = dir.path().join("t.mat");
    let mut args = made.to_vec();
    args.extend([utf8(&field_pairs), "--method", "affine", "--format", "elastix", "--quiet", "--out", utf8(&mat)]);
    let run = warpbench(&args);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("not a .mat"));
    assert!(!mat.exists());
}

/// `info` describes an ITK transform file that holds no displacement field by what it holds and how warpbench takes
/// it: SimpleITK's composite of an affine and a B-spline (a 3-cell mesh per axis: 6 control points,
/// `data-scripts/itk_tfm_chain.py`) is a field, its affine `.mat` and `.h5` a starting transform, ITK's thin-plate
/// spline through 10 landmarks (`data-scripts/slicer_transforms.py`) landmark pairs; 3D Slicer's inverse B-spline is
/// named as such. An `.h5` holding a field is still described as the field. FSL's FLIRT matrix is a starting
/// transform read against the two volumes.
#[test]
fn info_describes_a_transform_file_by_what_it_holds() {
    let info = |name: &str| {
        let run = warpbench(&["info", utf8(&data(&format!("itk/{name}"))), "--json"]);
        assert_ok(&run);
        serde_json::from_slice::<Value>(&run.stdout).expect("JSON")
    };
    let kinds = |v: &Value| -> Vec<String> {
        v["transforms"]
            .as_array()
            .expect("transforms")
            .iter()
            .map(|t| t["kind"].as_str().expect("kind").into())
            .collect()
    };
    let composite = info("tfm_composite.tfm");
    assert_eq!((composite["kind"].as_str(), composite["format"].as_str()), (Some("transform"), Some("itk_tfm")));
    assert_eq!(kinds(&composite), ["affine", "bspline"]);
    assert_eq!(composite["transforms"][1]["size"], serde_json::json!([6, 6, 6]));
    assert_eq!(composite["read_as"], "displacement_field");
    assert_eq!(kinds(&info("tfm_slicer_inverse.tfm")), ["affine", "inverse_bspline"]);
    for (name, format) in [("affine_sitk.mat", "ants_mat"), ("h5_affine.h5", "itk_h5")] {
        let linear = info(name);
        assert_eq!((linear["format"].as_str(), linear["read_as"].as_str()), (Some(format), Some("starting_transform")));
    }
    let tps = info("tps_itk.tfm");
    assert_eq!((kinds(&tps), tps["transforms"][0]["landmarks"].as_u64()), (vec!["thin_plate_spline".into()], Some(10)));
    assert_eq!(tps["read_as"], "landmarks");
    assert_eq!(info("h5_composite.h5")["kind"], "displacement_field");
    let text = warpbench(&["info", utf8(&data("itk/tfm_composite.tfm"))]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("2 transforms, the last applied first") && text.contains("6 × 6 × 6 control points"),
        "{text}"
    );
    // FSL's FLIRT matrix (nitransforms', `data-scripts/fsl_flirt_nitransforms.py`): an affine that needs its images.
    let flirt = data("fsl/oblique_from_las.mat");
    let run = warpbench(&["info", utf8(&flirt), "--json"]);
    assert_ok(&run);
    let v: Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert_eq!((v["format"].as_str(), v["read_as"].as_str()), (Some("fsl"), Some("starting_transform")));
    assert_eq!(kinds(&v), ["affine"]);
    let text = warpbench(&["info", utf8(&flirt)]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("FSL FLIRT matrix") && text.contains("--fixed as FLIRT's -ref"), "{text}");
    // AFNI's matrix file: the same, its base and source the two volumes.
    let dir = tempfile::tempdir().expect("tempdir");
    let afni = dir.path().join("mr_to_ct.aff12.1D");
    std::fs::write(&afni, "# 3dAllineate matrices (DICOM-to-DICOM, row-by-row):\n1 0 0 2 0 1 0 -1 0 0 1 0.5\n")
        .expect("write");
    let run = warpbench(&["info", utf8(&afni), "--json"]);
    assert_ok(&run);
    let v: Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert_eq!((v["format"].as_str(), v["read_as"].as_str()), (Some("afni"), Some("starting_transform")));
}
