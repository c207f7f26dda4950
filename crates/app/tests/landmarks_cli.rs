//! `warpbench landmarks` end to end: conversions between BigWarp CSV, BigWarp JSON, Slicer pairs (`.mrk.json`,
//! `.fcsv`) and plain CSV, checked against independent readings of the files:
//!
//! - the fixtures written by BigWarp and by hand after Slicer's format (`tests/data/landmarks/`, whose README gives
//!   the points as Python's `csv`/`json` modules read them), read here by a few lines of test code, not through
//!   `warpbench_io`;
//! - the exported `.mrk.json` validated against Slicer's published markups schema (a copy in
//!   `tests/data/landmarks/schema/`, with its provenance in that folder's README), by a JSON Schema validator;
//! - a chain of conversions through every format that must give back the table it started from, exactly;
//! - and the refusals (exit 2, nothing written, the input unchanged).

mod common;

use std::path::{Path, PathBuf};

use common::{assert_ok, data, utf8, warpbench};
use serde_json::Value;

fn landmarks(name: &str) -> PathBuf {
    data(&format!("landmarks/{name}"))
}

/// Runs `warpbench landmarks ARGS --json` and returns the listing.
fn listing(args: &[&str]) -> Value {
    let mut all = vec!["landmarks"];
    all.extend_from_slice(args);
    all.push("--json");
    let out = warpbench(&all);
    assert_ok(&out);
    serde_json::from_slice(&out.stdout).expect("the listing is JSON")
}

/// The pairs of a listing, without the fields that name the files.
fn pairs_of(listing: &Value) -> Value {
    listing["pairs"].clone()
}

fn point(v: &Value) -> Option<[f64; 3]> {
    v.as_array().map(|a| std::array::from_fn(|k| a[k].as_f64().expect("a number")))
}

/// (name, active, moving, fixed) as the test reads a row.
type HandRow = (String, bool, Option<[f64; 3]>, Option<[f64; 3]>);

/// BigWarp's CSV as opencsv writes it, read with nothing but string splitting: (name, active, moving, fixed), where
/// `Infinity` ×3 is a missing half.
fn bigwarp_csv_by_hand(path: &Path) -> Vec<HandRow> {
    std::fs::read_to_string(path)
        .expect("read")
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|line| {
            let f: Vec<&str> = line.trim_matches('"').split("\",\"").collect();
            assert_eq!(f.len(), 8, "{line}");
            let half = |k: usize| -> Option<[f64; 3]> {
                (f[k] != "Infinity").then(|| std::array::from_fn(|c| f[k + c].parse().expect("a number")))
            };
            (f[0].to_string(), f[1] == "true", half(2), half(5))
        })
        .collect()
}

/// The `--json` listing of a BigWarp CSV holds what the file holds, in LPS, numbered from 1.
#[test]
fn the_listing_holds_what_a_bigwarp_file_holds() {
    for name in ["bigwarp_pairs.csv", "bigwarp_settings_landmarks.csv"] {
        let file = landmarks(name);
        let l = listing(&[utf8(&file)]);
        assert_eq!(l["schema"], "warpbench-landmarks/1");
        assert_eq!(l["format"], "bigwarp-csv");
        assert_eq!(l["coordinate_system"], "LPS");
        let expected = bigwarp_csv_by_hand(&file);
        let pairs = l["pairs"].as_array().expect("pairs");
        assert_eq!(pairs.len(), expected.len());
        assert_eq!(l["count"], expected.len());
        for (n, (p, (label, active, moving, fixed))) in pairs.iter().zip(&expected).enumerate() {
            assert_eq!(p["number"], n + 1);
            assert_eq!(p["name"], label.as_str());
            assert_eq!(p["active"], *active);
            assert_eq!(point(&p["moving"]), *moving, "{name} {label}");
            assert_eq!(point(&p["fixed"]), *fixed, "{name} {label}");
        }
        let usable = expected.iter().filter(|(_, a, m, f)| *a && m.is_some() && f.is_some()).count();
        assert_eq!(l["usable"], usable);
    }
    // BigWarp's own test says its CSV and its settings file hold the same landmarks.
    let csv = listing(&[utf8(&landmarks("bigwarp_settings_landmarks.csv"))]);
    let json = listing(&[utf8(&landmarks("bigwarp_settings.json"))]);
    assert_eq!(json["format"], "bigwarp-json");
    assert_eq!(pairs_of(&csv), pairs_of(&json));
}

/// A Slicer pair read from an RAS list and an LPS list: each side in LPS, the RAS one negated in x and y, as the
/// fixtures' README computes with Python's json module.
#[test]
fn a_slicer_pair_is_listed_in_lps_whatever_its_files_say() {
    let ras = landmarks("slicer5_ras.mrk.json");
    let lps = landmarks("slicer5_lps.mrk.json");
    let l = listing(&["--moving-points", utf8(&ras), "--fixed-points", utf8(&lps)]);
    assert_eq!(l["format"], "slicer-pair");
    let raw: Value = serde_json::from_str(&std::fs::read_to_string(&ras).expect("read")).expect("json");
    let cps = raw["markups"][0]["controlPoints"].as_array().expect("points");
    let pairs = l["pairs"].as_array().expect("pairs");
    assert_eq!(pairs.len(), cps.len());
    for (p, cp) in pairs.iter().zip(cps) {
        if cp["positionStatus"] == "defined" {
            let [x, y, z] = point(&cp["position"]).expect("a position");
            assert_eq!(point(&p["moving"]), Some([-x, -y, z]));
            assert_eq!(p["moving"], p["fixed"], "the two fixtures hold the same points");
        } else {
            assert!(p["moving"].is_null());
        }
    }
    // The README's LPS values.
    assert_eq!(point(&pairs[0]["fixed"]), Some([-53.5, -73.25, 10.0]));
    assert_eq!(pairs[1]["active"], false, "F-2 is not selected");
}

/// BigWarp CSV → BigWarp JSON → Slicer pair (.mrk.json) → plain CSV (LPS) → plain CSV (RAS) → BigWarp CSV in RAS →
/// (read with --ras) the same table, exactly: names, active flags, missing halves and every coordinate bit.
#[test]
fn every_conversion_gives_back_the_table_it_started_from() {
    let dir = tempfile::tempdir().expect("tempdir");
    let at = |name: &str| dir.path().join(name);
    let start = landmarks("bigwarp_pairs.csv");
    let original = pairs_of(&listing(&[utf8(&start)]));

    let steps: Vec<(Vec<String>, Vec<String>)> = vec![
        (vec![utf8(&start).into()], vec!["--out".into(), utf8(&at("a.json")).into()]),
        (
            vec![utf8(&at("a.json")).into()],
            vec![
                "--out-moving".into(),
                utf8(&at("b_moving.mrk.json")).into(),
                "--out-fixed".into(),
                utf8(&at("b_fixed.mrk.json")).into(),
            ],
        ),
        (
            vec![
                "--moving-points".into(),
                utf8(&at("b_moving.mrk.json")).into(),
                "--fixed-points".into(),
                utf8(&at("b_fixed.mrk.json")).into(),
            ],
            vec!["--out".into(), utf8(&at("c.csv")).into(), "--to".into(), "plain-csv".into()],
        ),
        (
            vec![utf8(&at("c.csv")).into()],
            vec!["--out".into(), utf8(&at("d.csv")).into(), "--to".into(), "plain-csv".into(), "--out-ras".into()],
        ),
        (vec![utf8(&at("d.csv")).into()], vec!["--out".into(), utf8(&at("e.csv")).into(), "--out-ras".into()]),
    ];
    for (input, output) in &steps {
        let mut args: Vec<&str> = vec!["landmarks"];
        args.extend(input.iter().map(String::as_str));
        args.extend(output.iter().map(String::as_str));
        let out = warpbench(&args);
        assert_ok(&out);
        let check: Vec<&str> = input.iter().map(String::as_str).collect();
        assert_eq!(pairs_of(&listing(&check)), original, "after reading {input:?}");
    }
    assert_eq!(listing(&[utf8(&at("c.csv"))])["format"], "plain-csv");
    assert!(std::fs::read_to_string(at("d.csv")).expect("read").starts_with("name,active,moving_r,moving_a,moving_s"));
    // The BigWarp CSV in RAS: x and y negated in the file, and read back with --ras.
    let e = bigwarp_csv_by_hand(&at("e.csv"));
    let [x, y, z] = point(&original[0]["moving"]).expect("Pt-0 moving");
    assert_eq!(e[0].2, Some([-x, -y, z]));
    assert_eq!(pairs_of(&listing(&[utf8(&at("e.csv")), "--ras"])), original);

    // Through .fcsv, which cannot store a missing point: BigWarp's own five complete pairs.
    let five = landmarks("bigwarp_settings_landmarks.csv");
    let (m, f) = (at("f_moving.fcsv"), at("f_fixed.fcsv"));
    assert_ok(&warpbench(&["landmarks", utf8(&five), "--out-moving", utf8(&m), "--out-fixed", utf8(&f)]));
    assert_eq!(
        pairs_of(&listing(&["--moving-points", utf8(&m), "--fixed-points", utf8(&f)])),
        pairs_of(&listing(&[utf8(&five)]))
    );
}

/// A pair's moving and fixed points as a listing gives them.
type PointPair = (Option<[f64; 3]>, Option<[f64; 3]>);

/// elastix's point sets (`--out-moving m.txt --out-fixed f.txt`) hold the pairs a warp uses, the active ones with
/// both points, in LPS mm, and read back (`--moving-points`, `--fixed-points`) to those points, in order.
#[test]
fn elastix_point_sets_hold_the_pairs_a_warp_uses() {
    let dir = tempfile::tempdir().expect("tempdir");
    for fixture in ["bigwarp_pairs.csv", "bigwarp_settings_landmarks.csv"] {
        let start = landmarks(fixture);
        let original = listing(&[utf8(&start)]);
        let (m, f) = (dir.path().join(format!("{fixture}_m.txt")), dir.path().join(format!("{fixture}_f.txt")));
        assert_ok(&warpbench(&["landmarks", utf8(&start), "--out-moving", utf8(&m), "--out-fixed", utf8(&f)]));
        assert!(std::fs::read_to_string(&m).expect("read").starts_with("point\n"));
        let back = listing(&["--moving-points", utf8(&m), "--fixed-points", utf8(&f)]);
        assert_eq!(back["format"], "elastix-pair");
        let used: Vec<PointPair> = original["pairs"]
            .as_array()
            .expect("pairs")
            .iter()
            .filter(|p| p["active"] == true && !p["moving"].is_null() && !p["fixed"].is_null())
            .map(|p| (point(&p["moving"]), point(&p["fixed"])))
            .collect();
        let got: Vec<PointPair> = back["pairs"]
            .as_array()
            .expect("pairs")
            .iter()
            .map(|p| (point(&p["moving"]), point(&p["fixed"])))
            .collect();
        assert_eq!(got, used, "{fixture}");
        assert_eq!(back["count"], original["usable"], "{fixture}");
    }
    // A file of one side given as a file of pairs names what it is.
    let one = dir.path().join("bigwarp_pairs.csv_m.txt");
    let out = warpbench(&["landmarks", utf8(&one), "--json"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("an elastix point file holds one side of the pairs"), "{stderr}");
}

/// The compiled markups schema (Slicer's `markups-schema-v1.0.3.json`, draft 7).
fn markups_schema() -> (boon::Schemas, boon::SchemaIndex) {
    let path = landmarks("schema/markups-schema-v1.0.3.json");
    let schema: Value = serde_json::from_str(&std::fs::read_to_string(&path).expect("read the schema")).expect("json");
    let (mut schemas, mut compiler) = (boon::Schemas::new(), boon::Compiler::new());
    compiler.add_resource("markups-schema-v1.0.3.json", schema).expect("add the schema");
    let index = compiler.compile("markups-schema-v1.0.3.json", &mut schemas).expect("compile the schema");
    (schemas, index)
}

/// The `.mrk.json` files `warpbench landmarks` writes validate against Slicer's published markups schema, and the
/// validator does refuse a file that breaks it (so the check can fail).
#[test]
fn exported_markups_validate_against_slicers_schema() {
    let (schemas, index) = markups_schema();
    let dir = tempfile::tempdir().expect("tempdir");
    for name in ["bigwarp_pairs.csv", "bigwarp_settings.json"] {
        let (m, f) =
            (dir.path().join(format!("{name}_moving.mrk.json")), dir.path().join(format!("{name}_fixed.mrk.json")));
        let input = landmarks(name);
        assert_ok(&warpbench(&["landmarks", utf8(&input), "--out-moving", utf8(&m), "--out-fixed", utf8(&f)]));
        for file in [&m, &f] {
            let doc: Value = serde_json::from_str(&std::fs::read_to_string(file).expect("read")).expect("json");
            if let Err(e) = schemas.validate(&doc, index) {
                panic!("{} does not validate: {e}", file.display());
            }
            let mut broken = doc.clone();
            broken["markups"][0]["controlPoints"][0]["position"] = serde_json::json!([1.0, 2.0]);
            assert!(schemas.validate(&broken, index).is_err(), "a two-coordinate position must not validate");
            let mut broken = doc.clone();
            broken["markups"][0]["coordinateSystem"] = "XYZ".into();
            assert!(schemas.validate(&broken, index).is_err(), "an unknown coordinate system must not validate");
        }
    }
    // Slicer's own style of file, as the fixtures imitate it, validates too.
    for name in ["slicer5_lps.mrk.json", "slicer5_ras.mrk.json"] {
        let doc: Value = serde_json::from_str(&std::fs::read_to_string(landmarks(name)).expect("read")).expect("json");
        assert!(schemas.validate(&doc, index).is_ok(), "{name}");
    }
}

/// The plain CSV read by a few lines of test code: header and values as documented.
#[test]
fn the_plain_csv_is_what_the_docs_say() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("plain.csv");
    let start = landmarks("bigwarp_pairs.csv");
    assert_ok(&warpbench(&["landmarks", utf8(&start), "--out", utf8(&out), "--to", "plain-csv", "--quiet"]));
    let text = std::fs::read_to_string(&out).expect("read");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("name,active,moving_l,moving_p,moving_s,fixed_l,fixed_p,fixed_s"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let expected = bigwarp_csv_by_hand(&start);
    assert_eq!(rows.len(), expected.len());
    for (row, (label, active, moving, fixed)) in rows.iter().zip(&expected) {
        assert_eq!(row[0], label);
        assert_eq!(row[1], if *active { "true" } else { "false" });
        for (k, half) in [moving, fixed].into_iter().enumerate() {
            let fields = &row[2 + 3 * k..5 + 3 * k];
            match half {
                Some(p) => {
                    let values: Vec<f64> = fields.iter().map(|f| f.parse().expect("a number")).collect();
                    assert_eq!(values, p.to_vec());
                }
                None => assert!(fields.iter().all(|f| f.is_empty()), "{row:?}"),
            }
        }
    }
}

/// Each refusal exits 2 with a message in the CLI's words, writes nothing and leaves existing files as they were.
#[test]
fn refusals_write_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let start = landmarks("bigwarp_pairs.csv");
    let existing = dir.path().join("existing.json");
    std::fs::write(&existing, "keep me").expect("write");
    let bad = dir.path().join("bad.csv");
    std::fs::write(
        &bad,
        "\"Pt-0\",\"true\",\"1\",\"2\",\"3\",\"4\",\"5\",\"6\"\n\"Pt-1\",\"yes\",\"1\",\"2\",\"3\",\"4\",\"5\",\"6\"\n",
    )
    .expect("write");
    let out = dir.path().join("out.csv");
    let one_side = landmarks("slicer5_lps.mrk.json");
    let (m, f) = (dir.path().join("m.fcsv"), dir.path().join("f.fcsv"));
    let f_txt = dir.path().join("f.txt");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec![utf8(&start), "--out", utf8(&existing)], "exists"),
        (vec![utf8(&start), "--out", utf8(&start), "--force"], "input"),
        (vec![utf8(&start), "--out", "x.txt"], "cannot tell the format"),
        (vec![utf8(&start), "--out", "x_moving.mrk.json"], "one side"),
        (vec![utf8(&one_side), "--json"], "one side"),
        (vec![utf8(&bad), "--out", utf8(&out)], "landmark 2"),
        (vec![utf8(&start), "--out-moving", utf8(&m), "--out-fixed", "f.png"], ".mrk.json"),
        (vec![utf8(&start), "--out-moving", utf8(&m), "--out-fixed", utf8(&f_txt)], "both as Slicer lists"),
        (vec![utf8(&start), "--out-moving", utf8(&m), "--out-fixed", utf8(&f)], "Pt-2"),
        (vec![utf8(&start), "--out-moving", "m.mrk.json", "--out-fixed", "f.mrk.json", "--out-ras"], "LPS"),
    ];
    for (args, needle) in cases {
        let mut all = vec!["landmarks"];
        all.extend(args.iter().copied());
        let run = warpbench(&all);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
        assert!(!out.exists() && !m.exists() && !f.exists() && !f_txt.exists(), "{args:?} wrote something");
        assert!(!Path::new("m.mrk.json").exists() && !Path::new("x.txt").exists());
    }
    assert_eq!(std::fs::read_to_string(&existing).expect("read"), "keep me");
    // A plain CSV states its coordinate system; --ras on it is refused rather than applied twice.
    let plain = dir.path().join("plain.csv");
    assert_ok(&warpbench(&["landmarks", utf8(&start), "--out", utf8(&plain), "--to", "plain-csv"]));
    let run = warpbench(&["landmarks", utf8(&plain), "--ras", "--json"]);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("header states its coordinate system"));
}

/// A thin-plate-spline transform file (`data-scripts/slicer_transforms.py`: ITK wrote it, with 3D Slicer's inverse class) is
/// listed as the pairs it holds: its source landmarks are Slicer's moving points, as the script's JSON says; it
/// converts to BigWarp like any file of pairs, and `--ras` is refused, since every ITK file is LPS.
#[test]
fn a_slicer_spline_file_lists_its_landmarks_as_pairs() {
    let file = data("itk/tps_slicer.h5");
    let text = std::fs::read_to_string(data("itk/slicer_tps_reference.json")).expect("reference");
    let reference: Value = serde_json::from_str(&text).expect("JSON");
    let listed = listing(&[utf8(&file)]);
    assert_eq!(listed["format"], "itk-tps");
    assert_eq!(listed["usable"], 10);
    for (i, pair) in listed["pairs"].as_array().expect("pairs").iter().enumerate() {
        assert_eq!(point(&pair["moving"]), point(&reference["moving"][i]), "pair {}", i + 1);
        assert_eq!(point(&pair["fixed"]), point(&reference["fixed"][i]), "pair {}", i + 1);
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("pairs.csv");
    assert_ok(&warpbench(&["landmarks", utf8(&file), "--out", utf8(&csv)]));
    assert_eq!(pairs_of(&listing(&[utf8(&csv)])), pairs_of(&listed));
    let run = warpbench(&["landmarks", utf8(&file), "--ras", "--json"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("tps_slicer.h5") && stderr.contains("LPS"), "{stderr}");
}
