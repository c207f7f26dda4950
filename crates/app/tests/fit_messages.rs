//! Degenerate landmark sets are refused the same way by every method, and a fit's errors speak the product's
//! language: the landmark file named, pairs numbered from 1 as in the file (inactive pairs count), moving/fixed
//! rather than source/target. The suspicious sets that still fit (a pair given twice, nearly flat points) give
//! warnings that name the file and the pairs.
//!
//! The binary runs `warpbench field` (the cheapest pair subcommand) on the MRI fixture as both volumes
//! (91×109×91, 2 mm; its box spans x −91..91, y −92..126, z −73..109 mm LPS).

mod common;

use std::path::Path;
use std::process::Output;

use common::{mri, utf8, warpbench};
use warpbench_app::fit;
use warpbench_app::inputs::{self, LandmarkSource};
use warpbench_io::landmarks::read_bigwarp_csv;
use warpbench_solver::method::Method;

const METHODS: [&str; 5] = ["tps", "hbspline", "affine", "similarity", "rigid"];

/// Six well spread fixed points inside the fixture.
const SPREAD: [[f64; 3]; 6] = [
    [0.0, 18.0, 18.0],
    [40.0, 18.0, 18.0],
    [-40.0, 10.0, 30.0],
    [0.0, 70.0, 10.0],
    [5.0, -40.0, 18.0],
    [0.0, 18.0, 60.0],
];

/// A BigWarp CSV of (moving, fixed, active) rows.
fn write_csv(path: &Path, rows: &[([f64; 3], [f64; 3], bool)]) {
    let lines: Vec<String> = rows
        .iter()
        .enumerate()
        .map(|(i, (p, q, active))| {
            let f: Vec<String> = p.iter().chain(q).map(|v| format!("\"{v}\"")).collect();
            format!("\"Pt-{i}\",\"{active}\",{}\n", f.join(","))
        })
        .collect();
    std::fs::write(path, lines.concat()).expect("write landmarks");
}

fn shifted(q: [f64; 3]) -> [f64; 3] {
    [q[0] + 3.0, q[1] - 2.0, q[2] + 1.5]
}

/// `warpbench field` with `method` on the pairs of `csv`.
fn field(dir: &Path, csv: &Path, method: &str) -> Output {
    let m = mri();
    let out = dir.join(format!("field_{method}.nii.gz"));
    warpbench(&[
        "field",
        "--fixed",
        utf8(&m),
        "--moving",
        utf8(&m),
        "--landmarks",
        utf8(csv),
        "--method",
        method,
        "--quiet",
        "--force",
        "--out",
        utf8(&out),
    ])
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Exit 2, the file named, the expected words, and none of the words the product does not use.
fn assert_refused(out: &Output, csv: &Path, method: &str, words: &[&str]) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(2), "{method}: expected a refusal, got: {err}");
    assert!(err.contains(utf8(csv)), "{method}: the message does not name the landmark file: {err}");
    for w in words {
        assert!(err.contains(w), "{method}: {w:?} missing from: {err}");
    }
    for w in ["source", "target"] {
        assert!(!err.contains(w), "{method}: the message says {w:?}: {err}");
    }
}

#[test]
fn all_fixed_points_at_one_place_are_refused_by_every_method() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("fixed_collapsed.csv");
    let rows: Vec<_> = SPREAD.iter().map(|q| (shifted(*q), [10.0, 20.0, 30.0], true)).collect();
    write_csv(&csv, &rows);
    for method in METHODS {
        // The hierarchical B-spline fitted this with exit 0 and a largest displacement of 3 895 mm.
        assert_refused(&field(dir.path(), &csv, method), &csv, method, &["all 6 fixed points are at one position"]);
    }
}

#[test]
fn all_moving_points_at_one_place_are_refused_by_every_method() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("moving_collapsed.csv");
    let rows: Vec<_> = SPREAD.iter().map(|q| ([1.0, 2.0, 3.0], *q, true)).collect();
    write_csv(&csv, &rows);
    for method in METHODS {
        assert_refused(&field(dir.path(), &csv, method), &csv, method, &["all 6 moving points are at one position"]);
    }
}

#[test]
fn three_pairs_are_too_few_for_the_methods_that_need_a_volume() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("three.csv");
    let rows: Vec<_> = SPREAD[..3].iter().map(|q| (shifted(*q), *q, true)).collect();
    write_csv(&csv, &rows);
    for method in ["tps", "hbspline", "affine"] {
        // The hierarchical B-spline fitted this with exit 0 and a largest displacement of 258 mm.
        assert_refused(&field(dir.path(), &csv, method), &csv, method, &["needs at least 4"]);
    }
    // Three points off one line fix a rotation.
    for method in ["rigid", "similarity"] {
        let out = field(dir.path(), &csv, method);
        assert_eq!(out.status.code(), Some(0), "{method}: {}", stderr(&out));
    }
}

#[test]
fn coplanar_points_are_refused_where_the_method_needs_a_volume() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("plane.csv");
    let rows: Vec<_> = SPREAD.iter().map(|q| [q[0], q[1], 18.0]).map(|q| (shifted(q), q, true)).collect();
    write_csv(&csv, &rows);
    for method in ["tps", "hbspline", "affine"] {
        assert_refused(&field(dir.path(), &csv, method), &csv, method, &["points are coplanar"]);
    }
}

#[test]
fn one_moving_point_with_two_fixed_partners_is_refused_naming_the_file_numbers() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("conflict.csv");
    // File pair 1 is inactive, so the fit sees file pairs 2..8 as its pairs 1..7: the message must say 3 and 8.
    let mut rows: Vec<_> = vec![([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], false)];
    rows.extend(SPREAD.iter().map(|q| (shifted(*q), *q, true)));
    rows.push((rows[2].0, [-30.0, -30.0, -30.0], true));
    write_csv(&csv, &rows);
    for method in METHODS {
        assert_refused(
            &field(dir.path(), &csv, method),
            &csv,
            method,
            &["landmarks 3 and 8 have the same moving point but different fixed points"],
        );
    }
}

#[test]
fn fit_errors_number_pairs_as_the_file_does() {
    // A conflict on the fixed side, behind two inactive pairs.
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("fixed_conflict.csv");
    let mut rows: Vec<_> = vec![([0.0; 3], [1.0; 3], false), ([0.0; 3], [2.0; 3], false)];
    rows.extend(SPREAD.iter().map(|q| (shifted(*q), *q, true)));
    rows.push(([-20.0, -20.0, -20.0], SPREAD[4], true));
    write_csv(&csv, &rows);
    let out = field(dir.path(), &csv, "tps");
    assert_refused(
        &out,
        &csv,
        "tps",
        &["fitting the tps warp", "landmarks 7 and 9 have the same fixed point but different moving points"],
    );
}

#[test]
fn a_repeated_pair_and_a_nearly_flat_set_give_warnings_naming_the_file_and_pairs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("repeated.csv");
    let mut rows: Vec<_> = vec![([0.0; 3], [1.0; 3], false)];
    rows.extend(SPREAD.iter().map(|q| (shifted(*q), *q, true)));
    rows.push(rows[4]);
    write_csv(&csv, &rows);
    let source = LandmarkSource::Pairs(csv.clone());
    let pairs = read_bigwarp_csv(&csv).expect("read");
    let volume = warpbench_io::open(mri()).expect("fixture");
    for method in METHODS {
        let method = Method::from_name(method).expect("method");
        let c = inputs::correspondences(&source, &pairs, &volume, &volume, inputs::min_pairs(&method)).expect("pairs");
        let warnings = fit::fit_warnings(&method, &c);
        assert_eq!(warnings.len(), 1, "{method}: {warnings:?}");
        assert!(warnings[0].starts_with(utf8(&csv)), "{method}: {warnings:?}");
        assert!(warnings[0].contains("landmarks 5 and 8 are the same pair"), "{method}: {warnings:?}");
        // It still fits, counting the pair once.
        assert!(
            fit::pullback_stack(
                &method,
                &c,
                inputs::volume_box(&volume),
                warpbench_app::project::stack::Layers::default()
            )
            .is_ok(),
            "{method}"
        );
    }

    // 0.2 mm thick over 80 mm: it fits, with a warning naming the side.
    let thin = dir.path().join("thin.csv");
    let rows: Vec<_> = SPREAD
        .iter()
        .enumerate()
        .map(|(i, q)| [q[0], q[1], 18.0 + if i % 2 == 0 { 0.1 } else { -0.1 }])
        .map(|q| (shifted(q), q, true))
        .collect();
    write_csv(&thin, &rows);
    let source = LandmarkSource::Pairs(thin.clone());
    let pairs = read_bigwarp_csv(&thin).expect("read");
    let method = Method::from_name("tps").expect("tps");
    let c = inputs::correspondences(&source, &pairs, &volume, &volume, 4).expect("pairs");
    let warnings = fit::fit_warnings(&method, &c);
    assert!(
        warnings.iter().any(|w| w.contains("the fixed points are nearly coplanar"))
            && warnings.iter().any(|w| w.contains("the moving points are nearly coplanar")),
        "{warnings:?}"
    );
}

#[test]
fn the_command_line_prints_the_fits_warnings_and_reports_them_in_json() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("repeated.csv");
    let mut rows: Vec<_> = SPREAD.iter().map(|q| (shifted(*q), *q, true)).collect();
    rows.push(rows[1]);
    write_csv(&csv, &rows);
    let m = mri();
    for sub in ["field", "warp"] {
        let out_path = dir.path().join(format!("{sub}.nii.gz"));
        let json = dir.path().join(format!("{sub}.json"));
        let mut args = vec![sub, "--fixed", utf8(&m), "--moving", utf8(&m), "--landmarks", utf8(&csv), "--force"];
        args.extend(["--out", utf8(&out_path)]);
        if sub == "warp" {
            args.extend(["--backend", "cpu"]);
        }
        args.push("--json");
        let out = warpbench(&args);
        assert!(out.status.success(), "{sub}: {}", stderr(&out));
        std::fs::write(&json, &out.stdout).expect("keep the report");
        let err = stderr(&out);
        assert!(err.contains(&format!("warning: {}: landmarks 2 and 7 are the same pair", utf8(&csv))), "{sub}: {err}");
        let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("the --json report");
        let warnings = report["warnings"].as_array().expect("warnings in --json");
        assert_eq!(warnings.len(), 1, "{sub}: {report}");
        assert!(warnings[0].as_str().is_some_and(|w| w.contains("same pair")), "{sub}: {report}");
    }
}
