//! Landmark files: hand-written fixtures (tests/data/landmarks/README.md), round trips, bad rows.

use std::path::{Path, PathBuf};

use proptest::prelude::*;
use warpbench_io::ErrorKind;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::{
    self, BigWarpCsvOptions, LandmarkPair, SlicerPoint, complete_active_pairs, parse_bigwarp_csv, parse_fcsv,
    parse_mrk_json,
};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/landmarks").join(name)
}

fn p(x: f64, y: f64, z: f64) -> Point3<Lps> {
    Point3::new(x, y, z)
}

/// The LPS points that every Slicer fixture describes (README.md).
fn slicer_points_lps() -> [Point3<Lps>; 3] {
    [p(-53.5, -73.25, 10.0), p(49.875, -88.5, 0.0), p(-25.25, 59.25, -12.5)]
}

fn csv(text: &str) -> warpbench_io::Result<Vec<LandmarkPair>> {
    parse_bigwarp_csv(Path::new("pairs.csv"), text, BigWarpCsvOptions::default())
}

fn landmark_error(e: &warpbench_io::Error) -> (usize, String) {
    match &e.kind {
        ErrorKind::Landmark { index, problem } => (*index, problem.clone()),
        other => panic!("expected a landmark error, got {other}"),
    }
}

#[test]
fn bigwarp_csv_fixture_reads_moving_first() {
    let pairs = landmarks::read_bigwarp_csv(&fixture("bigwarp_pairs.csv")).expect("read");
    assert_eq!(pairs.len(), 4);
    assert_eq!(pairs[0], LandmarkPair::new("Pt-0", p(10.5, -20.25, 30.0), p(11.5, -19.25, 31.0)));
    assert!(!pairs[1].active, "Pt-1 is inactive");
    assert_eq!(pairs[1].fixed, Some(p(1.0, 2.0, 3.0)));
    assert_eq!(pairs[2].moving, Some(p(-5.125, 6.0, 7.75)));
    assert_eq!(pairs[2].fixed, None, "Infinity marks a missing half");
    assert_eq!(pairs[3].moving, Some(p(0.001, 250.0, -3.0)), "Java's 1.0E-3 spelling");
    // The solver sees the active, complete pairs only.
    let (moving, fixed) = complete_active_pairs(&pairs);
    assert_eq!(moving, vec![p(10.5, -20.25, 30.0), p(0.001, 250.0, -3.0)]);
    assert_eq!(fixed, vec![p(11.5, -19.25, 31.0), p(4.0, 5.0, 6.0)]);
}

#[test]
fn bigwarp_ras_option_negates_x_and_y() {
    let path = fixture("bigwarp_pairs.csv");
    let ras = landmarks::read_bigwarp_csv_with(&path, BigWarpCsvOptions { ras: true }).expect("read");
    assert_eq!(ras[0].moving, Some(p(-10.5, 20.25, 30.0)));
    assert_eq!(ras[2].fixed, None);
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("ras.csv");
    landmarks::write_bigwarp_csv_with(&out, &ras, BigWarpCsvOptions { ras: true }).expect("write");
    assert_eq!(landmarks::read_bigwarp_csv(&out).expect("read"), landmarks::read_bigwarp_csv(&path).expect("read"));
}

#[test]
fn bigwarp_unquoted_and_negative_infinity_are_read() {
    let pairs =
        csv("a,TRUE, 1,2,3 ,-Infinity,-Infinity,-Infinity\n\n\"b, with comma\",false,1,2,3,4,5,6\n").expect("read");
    assert_eq!(pairs.len(), 2);
    assert_eq!(pairs[0].fixed, None);
    assert_eq!(pairs[1].name, "b, with comma");
    // Empty and duplicate names are allowed.
    assert_eq!(csv("\"\",true,1,2,3,4,5,6\n\"\",true,1,2,3,4,5,6\n").expect("read").len(), 2);
}

#[test]
fn bigwarp_2d_files_are_refused() {
    let e = csv("\"Pt-0\",\"true\",\"1.0\",\"2.0\",\"3.0\",\"4.0\"\n").expect_err("2-D");
    assert!(e.to_string().contains("2-D landmarks are not supported"), "{e}");
    assert!(e.to_string().starts_with("pairs.csv: "), "{e}");
}

#[test]
fn bigwarp_malformed_rows_name_file_and_landmark() {
    let good = "\"Pt-0\",\"true\",\"1\",\"2\",\"3\",\"4\",\"5\",\"6\"\n";
    let cases = [
        ("\"Pt-1\",\"true\",\"1\",\"2\",\"3\",\"4\",\"5\"\n", "7 columns"),
        ("\"Pt-1\",\"yes\",\"1\",\"2\",\"3\",\"4\",\"5\",\"6\"\n", "active"),
        ("\"Pt-1\",\"true\",\"1\",\"two\",\"3\",\"4\",\"5\",\"6\"\n", "moving y"),
        ("\"Pt-1\",\"true\",\"1\",\"2\",\"3\",\"Infinity\",\"5\",\"6\"\n", "partly infinite"),
        ("\"Pt-1\",\"true\",\"1\",\"2\",\"3\",\"4\",\"NaN\",\"6\"\n", "fixed y is NaN"),
        ("\"Pt-1\",\"true\",\"nan\",\"2\",\"3\",\"4\",\"5\",\"6\"\n", "moving x is NaN"),
    ];
    for (row, want) in cases {
        let e = csv(&format!("{good}{row}")).expect_err(want);
        let (index, problem) = landmark_error(&e);
        assert_eq!(index, 2, "{e}");
        assert!(problem.contains(want) && problem.contains("Pt-1") && problem.contains("1-based"), "{e}");
        assert!(e.to_string().starts_with("pairs.csv: landmark 2: "), "{e}");
    }
}

#[test]
fn bigwarp_writer_quotes_like_opencsv_and_round_trips() {
    let pairs = vec![
        LandmarkPair::new("Pt-0", p(0.1, -2.0, 1e-7), p(1.0 / 3.0, 2.0, -0.0)),
        LandmarkPair { name: "say \"hi\"".into(), active: false, moving: None, fixed: Some(p(1.0, 2.0, 3.0)) },
    ];
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("pairs.csv");
    landmarks::write_bigwarp_csv(&out, &pairs).expect("write");
    let text = std::fs::read_to_string(&out).expect("text");
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "\"Pt-0\",\"true\",\"0.1\",\"-2.0\",\"1e-7\",\"0.3333333333333333\",\"2.0\",\"-0.0\"");
    assert_eq!(lines[1], "\"say \"\"hi\"\"\",\"false\",\"Infinity\",\"Infinity\",\"Infinity\",\"1.0\",\"2.0\",\"3.0\"");
    assert_eq!(landmarks::read_bigwarp_csv(&out).expect("read"), pairs);
    // NaN is refused on write, and nothing is written.
    let bad = dir.path().join("bad.csv");
    let nan = [LandmarkPair::new("x", p(f64::NAN, 0.0, 0.0), p(0.0, 0.0, 0.0))];
    assert!(landmarks::write_bigwarp_csv(&bad, &nan).is_err());
    assert!(!bad.exists());
}

#[test]
fn mrk_json_ras_and_lps_fixtures_describe_the_same_points() {
    let lps = landmarks::read_mrk_json(&fixture("slicer5_lps.mrk.json")).expect("lps");
    let ras = landmarks::read_mrk_json(&fixture("slicer5_ras.mrk.json")).expect("ras");
    assert_eq!(lps, ras);
    assert_eq!(lps.len(), 4);
    for (got, want) in lps.iter().zip(slicer_points_lps()) {
        assert_eq!(got.position, Some(want), "{got:?}");
    }
    assert_eq!(lps[0].label, "F-1");
    assert!(lps[0].selected && !lps[1].selected);
    assert_eq!(lps[3].position, None, "positionStatus undefined is a missing point");
}

#[test]
fn mrk_json_defaults_units_and_status() {
    let name = Path::new("m.mrk.json");
    let minimal = r#"{"markups":[{"type":"Fiducial","controlPoints":[{"label":"A","position":[1,2,3]}]}]}"#;
    let pts = parse_mrk_json(name, minimal).expect("minimal");
    assert_eq!(pts, vec![SlicerPoint { label: "A".into(), selected: true, position: Some(p(1.0, 2.0, 3.0)) }]);
    let um = r#"{"markups":[{"type":"Fiducial","coordinateSystem":"RAS","coordinateUnits":"um",
        "controlPoints":[{"position":[1000,-2500,500]},{"position":[1,1,1],"positionStatus":"preview"}]}]}"#;
    let pts = parse_mrk_json(name, um).expect("um");
    assert_eq!(pts[0].position, Some(p(-1.0, 2.5, 0.5)));
    assert_eq!(pts[1].position, None, "preview points are missing");
    // The first Fiducial list is read, after other markups.
    let mixed = r#"{"markups":[{"type":"Line","controlPoints":[]},{"type":"Fiducial","controlPoints":[]}]}"#;
    assert!(parse_mrk_json(name, mixed).expect("mixed").is_empty());
    for (text, want) in [
        (r#"{"markups":[{"type":"Curve"}]}"#, "no Fiducial"),
        (r#"{"markups":[]}"#, "no Fiducial"),
        (r"{}", "markups"),
        ("not json", "not JSON"),
        (r#"{"markups":[{"type":"Fiducial","coordinateSystem":"XYZ"}]}"#, "coordinateSystem"),
        (r#"{"markups":[{"type":"Fiducial","coordinateUnits":"cm"}]}"#, "coordinateUnits"),
        (r#"{"markups":[{"type":"Fiducial","controlPoints":[{"position":[1,2]}]}]}"#, "3 numbers"),
        (r#"{"markups":[{"type":"Fiducial","controlPoints":[{"position":[1,null,2]}]}]}"#, "3 numbers"),
        (r#"{"markups":[{"type":"Fiducial","controlPoints":[{"position":[1,NaN,2]}]}]}"#, "not JSON"),
    ] {
        let e = parse_mrk_json(name, text).expect_err(want);
        assert!(e.to_string().contains(want) && e.to_string().starts_with("m.mrk.json: "), "{want}: {e}");
    }
}

#[test]
fn mrk_json_writer_writes_a_complete_lps_file_and_round_trips() {
    let pts = vec![
        SlicerPoint { label: "F-1".into(), selected: true, position: Some(p(-53.5, 0.1, 1e-9)) },
        SlicerPoint { label: "gap".into(), selected: false, position: None },
    ];
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("pts.mrk.json");
    landmarks::write_mrk_json(&out, &pts).expect("write");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).expect("text")).expect("json");
    assert_eq!(doc["@schema"], landmarks::MARKUPS_SCHEMA);
    let m = &doc["markups"][0];
    assert_eq!(m["type"], "Fiducial");
    assert_eq!(m["coordinateSystem"], "LPS");
    assert_eq!(m["coordinateUnits"], "mm");
    for cp in m["controlPoints"].as_array().expect("points") {
        for key in [
            "id",
            "label",
            "description",
            "associatedNodeID",
            "position",
            "orientation",
            "selected",
            "locked",
            "visibility",
            "positionStatus",
        ] {
            assert!(cp.get(key).is_some(), "control point lacks {key}: {cp}");
        }
        assert_eq!(cp["orientation"].as_array().map(Vec::len), Some(9));
    }
    assert_eq!(m["controlPoints"][1]["positionStatus"], "undefined");
    assert_eq!(landmarks::read_mrk_json(&out).expect("read"), pts);
}

#[test]
fn fcsv_with_slicer5_extra_columns_and_legacy_ras_code() {
    let lps = landmarks::read_fcsv(&fixture("slicer5_extra_columns.fcsv")).expect("extra columns");
    let ras = landmarks::read_fcsv(&fixture("legacy_ras_code0.fcsv")).expect("code 0");
    assert_eq!(lps.len(), 3);
    for ((a, b), want) in lps.iter().zip(&ras).zip(slicer_points_lps()) {
        assert_eq!(a.position, Some(want));
        assert_eq!(b.position, Some(want));
        assert_eq!(a.label, b.label);
    }
    assert_eq!(lps.iter().map(|p| p.selected).collect::<Vec<_>>(), [true, false, true]);
    // The same points as the JSON fixtures.
    let json = landmarks::read_mrk_json(&fixture("slicer5_lps.mrk.json")).expect("json");
    assert_eq!(&json[..3], &lps[..]);
}

#[test]
fn fcsv_columns_line_and_default_order() {
    let name = Path::new("f.fcsv");
    let reordered = "# Markups fiducial file version = 5.6\n# CoordinateSystem = RAS\n\
                     # columns = label,sel,z,y,x\n\"A, B\",0,3,2,1\n";
    let pts = parse_fcsv(name, reordered).expect("reordered");
    assert_eq!(pts, vec![SlicerPoint { label: "A, B".into(), selected: false, position: Some(p(-1.0, -2.0, 3.0)) }]);
    let no_columns = "# Markups fiducial file version = 4.11\n# CoordinateSystem = 1\n\
                      id9,1.5,2.5,3.5,0,0,0,1,1,1,0,L,,\n";
    let pts = parse_fcsv(name, no_columns).expect("default order");
    assert_eq!(pts[0].position, Some(p(1.5, 2.5, 3.5)));
    assert_eq!(pts[0].label, "L");
    // Absent CoordinateSystem in a versioned file: refused (fcsv_coordinate_system_decision_table).
    let no_cs = "# Markups fiducial file version = 4.11\n1,1,2,3,0,0,0,1,1,1,0,L,,\n";
    assert!(parse_fcsv(name, no_cs).is_err());
}

#[test]
fn fcsv_bad_rows_are_refused() {
    let name = Path::new("f.fcsv");
    let head = "# Markups fiducial file version = 4.11\n# CoordinateSystem = LPS\n\
                # columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID\n\
                1,0,0,0,0,0,0,1,1,1,0,ok,,\n";
    for (row, want) in [
        ("2,1,nan,3,0,0,0,1,1,1,0,bad,,", "y is NaN"),
        ("2,1,2,,0,0,0,1,1,1,0,bad,,", "z is \"\""),
        ("2,1,2,inf,0,0,0,1,1,1,0,bad,,", "not finite"),
        ("2,1,2", "z is \"\""),
        ("2,1,2,3,0,0,0,1,1,maybe,0,bad,,", "sel"),
    ] {
        let e = parse_fcsv(name, &format!("{head}{row}\n")).expect_err(want);
        let (index, problem) = landmark_error(&e);
        assert_eq!(index, 2, "{e}");
        assert!(problem.contains(want) && problem.contains("line 5"), "{want}: {e}");
        assert!(e.to_string().starts_with("f.fcsv: landmark 2: "), "{e}");
    }
    let e = parse_fcsv(name, "# CoordinateSystem = XYZ\n").expect_err("cs");
    assert!(e.to_string().contains("CoordinateSystem"), "{e}");
    let e = parse_fcsv(name, "a,1,2,3\n").expect_err("unversioned");
    assert!(matches!(e.kind, ErrorKind::Unsupported(_)), "{e}");
    let e = parse_fcsv(name, "# columns = id,label\n1,a\n").expect_err("no xyz");
    assert!(e.to_string().contains("x, y and z"), "{e}");
}

#[test]
fn fcsv_round_trip_and_missing_points() {
    let pts = vec![
        SlicerPoint { label: "with, comma".into(), selected: false, position: Some(p(0.1, -1e-12, 12345.678)) },
        SlicerPoint { label: "F-2".into(), selected: true, position: Some(p(-0.0, 2.0, 3.0)) },
    ];
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("pts.fcsv");
    landmarks::write_fcsv(&out, &pts).expect("write");
    let text = std::fs::read_to_string(&out).expect("text");
    assert!(
        text.starts_with("# Markups fiducial file version = 4.11\n# CoordinateSystem = LPS\n# columns = id,x,y,z,")
    );
    assert_eq!(landmarks::read_fcsv(&out).expect("read"), pts);
    let missing = [SlicerPoint { label: "gap".into(), selected: true, position: None }];
    let e = landmarks::write_fcsv(&dir.path().join("gap.fcsv"), &missing).expect_err("missing");
    assert!(e.to_string().contains(".mrk.json"), "{e}");
}

#[test]
fn slicer_pair_reads_by_index() {
    let pairs =
        landmarks::read_slicer_pair(&fixture("slicer5_ras.mrk.json"), &fixture("slicer5_lps.mrk.json")).expect("pair");
    assert_eq!(pairs.len(), 4);
    assert_eq!(pairs[0], LandmarkPair::new("F-1", slicer_points_lps()[0], slicer_points_lps()[0]));
    assert!(!pairs[1].active, "F-2 is not selected");
    assert!(!pairs[3].is_complete());
    let (m, f) = complete_active_pairs(&pairs);
    assert_eq!(m.len(), 2);
    assert_eq!(m, f);
    // Mixed formats pair too, but only lists of equal length.
    let e = landmarks::read_slicer_pair(&fixture("slicer5_extra_columns.fcsv"), &fixture("slicer5_lps.mrk.json"))
        .expect_err("3 vs 4");
    let msg = e.to_string();
    assert!(msg.contains("slicer5_extra_columns.fcsv") && msg.contains("slicer5_lps.mrk.json"), "{msg}");
    assert!(msg.contains("has 3 points") && msg.contains("has 4"), "{msg}");
}

#[test]
fn slicer_pair_round_trips_through_both_formats() {
    let pairs = vec![
        LandmarkPair::new("A", p(1.0, 2.0, 3.0), p(-1.5, 2.25, 0.1)),
        LandmarkPair { name: "B".into(), active: false, moving: Some(p(0.0, 0.0, 1.0)), fixed: Some(p(4.0, 5.0, 6.0)) },
    ];
    let dir = tempfile::tempdir().expect("tempdir");
    for (m, f) in [("m.mrk.json", "f.mrk.json"), ("m.fcsv", "f.fcsv"), ("m.fcsv", "f.mrk.json")] {
        let (m, f) = (dir.path().join(m), dir.path().join(f));
        landmarks::write_slicer_pair(&m, &f, &pairs).expect("write");
        assert_eq!(landmarks::read_slicer_pair(&m, &f).expect("read"), pairs);
    }
    // A missing half fits JSON but not .fcsv; the refused write leaves neither file.
    let gap = vec![LandmarkPair { name: "G".into(), active: true, moving: Some(p(1.0, 1.0, 1.0)), fixed: None }];
    let (m, f) = (dir.path().join("gm.mrk.json"), dir.path().join("gf.mrk.json"));
    landmarks::write_slicer_pair(&m, &f, &gap).expect("json gap");
    assert_eq!(landmarks::read_slicer_pair(&m, &f).expect("read"), gap);
    let (m, f) = (dir.path().join("gm.fcsv"), dir.path().join("gf.fcsv"));
    assert!(landmarks::write_slicer_pair(&m, &f, &gap).is_err());
    assert!(!m.exists() && !f.exists());
}

fn coord() -> impl Strategy<Value = f64> {
    prop_oneof![-1e4f64..1e4, any::<f64>().prop_filter("finite", |x| x.is_finite()), Just(0.0), Just(-0.0)]
}

fn point() -> impl Strategy<Value = Option<Point3<Lps>>> {
    proptest::option::weighted(0.85, (coord(), coord(), coord()).prop_map(|(x, y, z)| p(x, y, z)))
}

fn pair() -> impl Strategy<Value = LandmarkPair> {
    ("[ -~]{0,12}", any::<bool>(), point(), point()).prop_map(|(name, active, moving, fixed)| LandmarkPair {
        name,
        active,
        moving,
        fixed,
    })
}

/// True when serde_json parses floats exactly (its `float_roundtrip` feature). Without it, its
/// parser may land one ULP off for long mantissas; then JSON round trips get that much slack.
fn json_floats_are_exact() -> bool {
    let hard = 4.501_766_808_677_364_3e61_f64;
    serde_json::from_str::<f64>(&format!("{hard:?}")).ok() == Some(hard)
}

fn same_point(a: Option<Point3<Lps>>, b: Option<Point3<Lps>>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) if !json_floats_are_exact() => a.coords().iter().zip(b.coords()).all(|(x, y)| {
            // Within 2 ULP (same sign), which also covers subnormals.
            x.is_sign_negative() == y.is_sign_negative() && x.to_bits().abs_diff(y.to_bits()) <= 2
        }),
        (a, b) => a == b,
    }
}

proptest! {
    /// Law: BigWarp CSV write then read is the identity (names, flags, missing halves, exact f64).
    #[test]
    fn random_pairs_round_trip_through_bigwarp_csv(pairs in proptest::collection::vec(pair(), 0..12), ras in any::<bool>()) {
        let name = Path::new("r.csv");
        let options = BigWarpCsvOptions { ras };
        let text = landmarks::to_bigwarp_csv(name, &pairs, options).expect("write");
        let back = parse_bigwarp_csv(name, &text, options).expect("read");
        prop_assert_eq!(back, pairs);
    }

    /// Law: a `.mrk.json` moving/fixed pair written and read back is the identity.
    #[test]
    fn random_pairs_round_trip_through_mrk_json(pairs in proptest::collection::vec(pair(), 0..12)) {
        let dir = tempfile::tempdir().expect("tempdir");
        let (m, f) = (dir.path().join("m.mrk.json"), dir.path().join("f.mrk.json"));
        landmarks::write_slicer_pair(&m, &f, &pairs).expect("write");
        let back = landmarks::read_slicer_pair(&m, &f).expect("read");
        prop_assert_eq!(back.len(), pairs.len());
        for (b, a) in back.iter().zip(&pairs) {
            // Pairing rule: an empty moving label falls back to the fixed one, which is the same name.
            prop_assert_eq!(&b.name, &a.name);
            prop_assert_eq!(b.active, a.active);
            prop_assert!(same_point(b.moving, a.moving), "{:?} vs {:?}", b.moving, a.moving);
            prop_assert!(same_point(b.fixed, a.fixed), "{:?} vs {:?}", b.fixed, a.fixed);
        }
    }

    /// Law: no text makes the parsers panic.
    #[test]
    fn arbitrary_text_never_panics(text in "(\\PC|\n|,|\"|#){0,200}") {
        let _ = parse_bigwarp_csv(Path::new("x.csv"), &text, BigWarpCsvOptions::default());
        let _ = parse_fcsv(Path::new("x.fcsv"), &text);
        let _ = parse_mrk_json(Path::new("x.mrk.json"), &text);
    }
}

// ---------------------------------------------------------------------------------------------
// Issue 13, items 8 and 9: the .fcsv coordinate-system decision table, and BOMs.

const BOM: &str = "\u{feff}";

/// Writes `text` to `dir/name` and returns the path.
fn write_file(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write");
    path
}

#[test]
fn slicer3_fcsv_from_slicers_test_data_is_read_as_ras() {
    // Slicer's own Slicer 3 test file (README.md): no version line, no CoordinateSystem line,
    // `# columns = label,x,y,z,sel,vis`. Slicer reads such positions as RAS.
    let pts = landmarks::read_fcsv(&fixture("slicer3.fcsv")).expect("slicer 3");
    assert_eq!(pts.len(), 56, "numPoints = 56");
    assert_eq!(pts[0], SlicerPoint { label: "midsag2".into(), selected: true, position: Some(p(-12.5, 93.5, 7.5)) });
    assert_eq!(pts[55].label, "midsag57");
    assert_eq!(pts[55].position, Some(p(11.5, -71.5, -26.5)), "RAS (-11.5, 71.5, -26.5) in LPS");
}

#[test]
fn fcsv_coordinate_system_decision_table() {
    let name = Path::new("f.fcsv");
    let row4 = "1,1,2,3,0,0,0,1,1,1,0,L,,\n";
    let at = |text: &str| parse_fcsv(name, text).map(|pts| pts[0].position);
    // Versioned files: the CoordinateSystem line decides.
    for (cs, want) in
        [("LPS", p(1.0, 2.0, 3.0)), ("1", p(1.0, 2.0, 3.0)), ("RAS", p(-1.0, -2.0, 3.0)), ("0", p(-1.0, -2.0, 3.0))]
    {
        let text = format!("# Markups fiducial file version = 4.11\n# CoordinateSystem = {cs}\n{row4}");
        assert_eq!(at(&text).expect(cs), Some(want), "{cs}");
    }
    // A versioned file without a CoordinateSystem line cannot be placed: every Slicer that writes the
    // version line writes it, and Slicer's default changed from RAS to LPS (2020). Refused, not guessed.
    let e = at(&format!("# Markups fiducial file version = 4.11\n{row4}")).expect_err("no cs");
    assert!(e.to_string().contains("no \"# CoordinateSystem\" line"), "{e}");
    // Unversioned (Slicer 3) files are RAS, with columns label,x,y,z,sel,vis unless a columns line says otherwise.
    let slicer3 = "# Fiducial List file /tmp/a.fcsv\n# name = a\n# numPoints = 1\nA,1,2,3,0,1\n";
    assert_eq!(
        parse_fcsv(name, slicer3).expect("slicer 3 without columns"),
        vec![SlicerPoint { label: "A".into(), selected: false, position: Some(p(-1.0, -2.0, 3.0)) }]
    );
    let slicer3_columns = "# columns = x,y,z,label\n1,2,3,B\n";
    assert_eq!(at(slicer3_columns).expect("slicer 3 columns"), Some(p(-1.0, -2.0, 3.0)));
    // An unversioned file with a CoordinateSystem line is neither Slicer 3 nor Slicer 4+: refused.
    let e = at("# CoordinateSystem = LPS\n# columns = label,x,y,z,sel,vis\nA,1,2,3,1,1\n").expect_err("mixed");
    assert!(e.to_string().contains("CoordinateSystem") && e.to_string().contains("version"), "{e}");
    // Neither a version line nor a Slicer 3 header: not a Slicer file.
    let e = at("A,1,2,3,1,1\n").expect_err("bare");
    assert!(matches!(e.kind, ErrorKind::Unsupported(_)), "{e}");
    // A version line without a version is not a version.
    let e =
        at(&format!("# Markups fiducial file version =\n# CoordinateSystem = LPS\n{row4}")).expect_err("empty version");
    assert!(e.to_string().contains("version"), "{e}");
}

#[test]
fn fcsv_position_status_column_marks_points_that_are_not_placed() {
    // Slicer 5 appends positionStatus (0 undefined, 1 preview, 2 defined, 3 missing) and autoCreated after the
    // 14 declared columns; a point whose status is not 2 has no position (its x, y, z are placeholders).
    let name = Path::new("f.fcsv");
    let head = "# Markups fiducial file version = 5.6\n# CoordinateSystem = LPS\n\
                # columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID\n";
    let rows = "1,1,2,3,0,0,0,1,1,1,0,A,,,2,0\n2,0,0,0,0,0,0,1,1,1,0,B,,,0,0\n3,0,0,0,0,0,0,1,1,1,0,C,,,1,0\n\
                4,0,0,0,0,0,0,1,1,1,0,D,,,3,0\n5,4,5,6,0,0,0,1,1,1,0,E,,\n";
    let pts = parse_fcsv(name, &format!("{head}{rows}")).expect("status");
    let positions: Vec<_> = pts.iter().map(|p| p.position).collect();
    assert_eq!(positions, [Some(p(1.0, 2.0, 3.0)), None, None, None, Some(p(4.0, 5.0, 6.0))]);
    let e = parse_fcsv(name, &format!("{head}1,1,2,3,0,0,0,1,1,1,0,A,,,x,0\n")).expect_err("bad status");
    let (index, problem) = landmark_error(&e);
    assert!(index == 1 && problem.contains("positionStatus"), "{e}");
}

#[test]
fn mrk_json_coded_units_are_read_not_defaulted() {
    // The schema allows coordinateUnits as a UCUM code triple; "um" must not be read as mm.
    let name = Path::new("m.mrk.json");
    let doc = |units: &str| {
        format!(
            r#"{{"markups":[{{"type":"Fiducial","coordinateUnits":{units},"controlPoints":[{{"position":[1000,2000,3000]}}]}}]}}"#
        )
    };
    let um = parse_mrk_json(name, &doc(r#"["um","UCUM","micrometer"]"#)).expect("um code");
    assert_eq!(um[0].position, Some(p(1.0, 2.0, 3.0)));
    let mm = parse_mrk_json(name, &doc(r#"["mm","UCUM","millimeter"]"#)).expect("mm code");
    assert_eq!(mm[0].position, Some(p(1000.0, 2000.0, 3000.0)));
    for bad in [r#"["mm","DCM","millimeter"]"#, r#"["cm","UCUM","centimeter"]"#, "7", r#"{"codeValue":"um"}"#] {
        let e = parse_mrk_json(name, &doc(bad)).expect_err(bad);
        assert!(e.to_string().contains("coordinateUnits"), "{bad}: {e}");
    }
}

#[test]
fn every_landmark_reader_strips_one_leading_bom() {
    let dir = tempfile::tempdir().expect("tempdir");
    for fixture_name in [
        "slicer5_lps.mrk.json",
        "slicer5_ras.mrk.json",
        "slicer5_extra_columns.fcsv",
        "legacy_ras_code0.fcsv",
        "slicer3.fcsv",
        "bigwarp_pairs.csv",
    ] {
        let text = std::fs::read_to_string(fixture(fixture_name)).expect("fixture");
        let with_bom = write_file(dir.path(), fixture_name, &format!("{BOM}{text}"));
        if Path::new(fixture_name).extension().is_some_and(|e| e == "csv") {
            let want = landmarks::read_bigwarp_csv(&fixture(fixture_name)).expect("plain");
            assert_eq!(landmarks::read_bigwarp_csv(&with_bom).expect("bom"), want, "{fixture_name}");
            assert_eq!(csv(&format!("{BOM}{text}")).expect("parse bom"), want, "{fixture_name}");
        } else {
            let want = landmarks::read_slicer_points(&fixture(fixture_name)).expect("plain");
            assert_eq!(landmarks::read_slicer_points(&with_bom).expect("bom"), want, "{fixture_name}");
        }
    }
    let fcsv = std::fs::read_to_string(fixture("slicer5_extra_columns.fcsv")).expect("fcsv");
    let json = std::fs::read_to_string(fixture("slicer5_lps.mrk.json")).expect("json");
    let name = Path::new("x");
    assert_eq!(parse_fcsv(name, &format!("{BOM}{fcsv}")).expect("fcsv"), parse_fcsv(name, &fcsv).expect("fcsv"));
    assert_eq!(
        parse_mrk_json(name, &format!("{BOM}{json}")).expect("json"),
        parse_mrk_json(name, &json).expect("json")
    );
    // One BOM only: a second one is content, and it is refused, not skipped.
    assert!(parse_mrk_json(name, &format!("{BOM}{BOM}{json}")).is_err());
}

// ---------------------------------------------------------------------------------------------
// Issue 13, item 10: BigWarp JSON landmarks, and reading one file of pairs by content.

/// BigWarp's `LandmarkTableModel.toJson()` for two pairs, the second without its moving half.
const BIGWARP_LANDMARKS: &str = r#"{"type": "BigWarpLandmarks", "numDimensions": 3,
    "movingPoints": [[1.5, -2.0, 3.0], [Infinity, Infinity, Infinity]],
    "fixedPoints": [[4.0, 5.0, 6.0], [7.0, 8.0, 9.0]],
    "active": [true, false], "names": ["A", "B, \"quoted\""]}"#;

fn bigwarp_json(text: &str) -> warpbench_io::Result<Vec<LandmarkPair>> {
    landmarks::parse_bigwarp_json(Path::new("pairs.json"), text, BigWarpCsvOptions::default())
}

#[test]
fn bigwarp_settings_json_reads_to_the_same_pairs_as_the_csv_bigwarp_made_it_from() {
    // BigWarp's own serialization test (README.md): it loads landmarks.csv and its settings file must equal
    // expected.json, so the two files hold the same landmarks by BigWarp's own account.
    let from_csv = landmarks::read_bigwarp_csv(&fixture("bigwarp_settings_landmarks.csv")).expect("csv");
    let from_json = landmarks::read_bigwarp_json(&fixture("bigwarp_settings.json")).expect("settings json");
    assert_eq!(from_json, from_csv);
    assert_eq!(from_json.len(), 5);
    assert_eq!(
        from_json[0],
        LandmarkPair::new(
            "Pt-0",
            p(193.152_710_280_373_7, 163.579_439_252_336_58, 130.000_000_000_000_03),
            p(216.017_975_084_172_32, 233.334_191_098_499_2, 126.862_635_798_327_89)
        )
    );
    // The same through the reader that picks the format by content.
    assert_eq!(landmarks::read_landmark_pairs(&fixture("bigwarp_settings.json")).expect("by content"), from_csv);
    // World coordinates as in the CSV reader: LPS by default, RAS when asked, for both formats.
    let ras = BigWarpCsvOptions { ras: true };
    assert_eq!(
        landmarks::read_bigwarp_json_with(&fixture("bigwarp_settings.json"), ras).expect("json ras"),
        landmarks::read_bigwarp_csv_with(&fixture("bigwarp_settings_landmarks.csv"), ras).expect("csv ras")
    );
}

#[test]
fn bigwarp_save_landmarks_json_with_a_pending_point_matches_the_csv() {
    // BigWarp's "Save landmarks" to .json (TransformWriterJson): {"type": <transform>, "landmarks": {...}},
    // a pending half as bare Infinity (Gson writes non-finite numbers that way).
    let json = landmarks::read_bigwarp_json(&fixture("bigwarp_pairs.json")).expect("json");
    assert_eq!(json, landmarks::read_bigwarp_csv(&fixture("bigwarp_pairs.csv")).expect("csv"));
    assert_eq!(json[2].fixed, None);
}

#[test]
fn bigwarp_json_is_read_alone_under_landmarks_and_under_transform() {
    let alone = bigwarp_json(BIGWARP_LANDMARKS).expect("alone");
    assert_eq!(
        alone,
        vec![
            LandmarkPair::new("A", p(1.5, -2.0, 3.0), p(4.0, 5.0, 6.0)),
            LandmarkPair { name: "B, \"quoted\"".into(), active: false, moving: None, fixed: Some(p(7.0, 8.0, 9.0)) },
        ]
    );
    let saved = format!(r#"{{"type": "Thin Plate Spline", "landmarks": {BIGWARP_LANDMARKS}}}"#);
    let settings =
        format!(r#"{{"Sources": {{}}, "Transform": {{"type": "Affine", "landmarks": {BIGWARP_LANDMARKS}}}}}"#);
    assert_eq!(bigwarp_json(&saved).expect("saved"), alone);
    assert_eq!(bigwarp_json(&settings).expect("settings"), alone);
    // Empty tables, as BigWarp writes them before the first point.
    let empty =
        r#"{"type":"BigWarpLandmarks","numDimensions":3,"movingPoints":[],"fixedPoints":[],"active":[],"names":[]}"#;
    assert!(bigwarp_json(empty).expect("empty").is_empty());
}

#[test]
fn bigwarp_json_bad_content_names_file_and_landmark() {
    let doc = |moving: &str, active: &str, names: &str| {
        format!(
            r#"{{"type":"BigWarpLandmarks","numDimensions":3,"movingPoints":[[1,2,3],{moving}],
            "fixedPoints":[[4,5,6],[7,8,9]],"active":{active},"names":{names}}}"#
        )
    };
    let (active, names) = ("[true,true]", r#"["P1","P2"]"#);
    for (text, want) in [
        (doc("[1,2]", active, names), "3 numbers"),
        (doc("[1,NaN,3]", active, names), "moving y is NaN"),
        (doc("[1,Infinity,3]", active, names), "partly infinite"),
        (doc("[1,\"two\",3]", active, names), "moving y"),
        (doc("[1,null,3]", active, names), "moving y"),
        (doc("[1,2,3]", "[true,\"yes\"]", names), "active"),
        (doc("[1,2,3]", active, r#"["P1",2]"#), "name"),
    ] {
        let e = bigwarp_json(&text).expect_err(want);
        let (index, problem) = landmark_error(&e);
        assert_eq!(index, 2, "{want}: {e}");
        assert!(problem.contains(want) && problem.contains("1-based"), "{want}: {e}");
        assert!(e.to_string().starts_with("pairs.json: landmark 2: "), "{e}");
    }
    for (text, want) in [
        (BIGWARP_LANDMARKS.replace("\"numDimensions\": 3", "\"numDimensions\": 2"), "2-D landmarks are not supported"),
        (BIGWARP_LANDMARKS.replace("\"numDimensions\": 3", "\"numDimensions\": 4"), "numDimensions"),
        (BIGWARP_LANDMARKS.replace("\"numDimensions\": 3,", ""), "numDimensions"),
        (BIGWARP_LANDMARKS.replace("[true, false]", "[true]"), "active has 1 entries but names has 2"),
        (BIGWARP_LANDMARKS.replace(", [7.0, 8.0, 9.0]", ""), "fixedPoints has 1 entries but names has 2"),
        (BIGWARP_LANDMARKS.replace("\"names\"", "\"labels\""), "names"),
        (format!(r#"{{"landmarks": {}}}"#, BIGWARP_LANDMARKS.replace("BigWarpLandmarks", "Other")), "BigWarpLandmarks"),
        ("{\"landmarks\": [1, 2]}".to_string(), "BigWarpLandmarks"),
        ("[1, 2]".to_string(), "BigWarpLandmarks"),
        ("{\"type\": \"BigWarpLandmarks\"".to_string(), "not JSON"),
    ] {
        let e = bigwarp_json(&text).expect_err(want);
        assert!(e.to_string().contains(want) && e.to_string().starts_with("pairs.json: "), "{want}: {e}");
    }
}

#[test]
fn bigwarp_json_writer_writes_what_bigwarp_reads_and_round_trips() {
    let pairs = vec![
        LandmarkPair::new("Pt-0", p(0.1, -2.0, 1e-7), p(1.0 / 3.0, 2.0, -0.0)),
        LandmarkPair { name: "say \"hi\"".into(), active: false, moving: None, fixed: Some(p(1.0, 2.0, 3.0)) },
    ];
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("pairs.json");
    landmarks::write_bigwarp_json(&out, &pairs).expect("write");
    let text = std::fs::read_to_string(&out).expect("text");
    // BigWarp's loadLandmarks(.json) reads {"landmarks": {...}} (TransformWriterJson.read); a pending half is
    // Infinity, as BigWarp writes it.
    assert!(text.starts_with("{\n  \"landmarks\": {\n    \"type\": \"BigWarpLandmarks\",\n"), "{text}");
    assert!(text.contains("\"numDimensions\": 3,"), "{text}");
    assert!(text.contains("[\n        Infinity,\n        Infinity,\n        Infinity\n      ]"), "{text}");
    assert!(text.contains("\"say \\\"hi\\\"\""), "{text}");
    assert_eq!(landmarks::read_bigwarp_json(&out).expect("read"), pairs);
    // Its structure (with the pending half made a string for a strict parser) is BigWarp's.
    let strict: serde_json::Value = serde_json::from_str(&text.replace("Infinity", "\"Infinity\"")).expect("json");
    let lm = &strict["landmarks"];
    for key in ["type", "numDimensions", "movingPoints", "fixedPoints", "active", "names"] {
        assert!(lm.get(key).is_some(), "no {key}: {text}");
    }
    assert_eq!(lm["active"], serde_json::json!([true, false]));
    // NaN is refused on write, and nothing is written.
    let bad = dir.path().join("bad.json");
    let nan = [LandmarkPair::new("x", p(f64::NAN, 0.0, 0.0), p(0.0, 0.0, 0.0))];
    assert!(landmarks::write_bigwarp_json(&bad, &nan).is_err());
    assert!(!bad.exists());
}

#[test]
fn one_file_of_pairs_is_read_by_content_and_written_by_extension() {
    use landmarks::LandmarkFileFormat as F;
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = landmarks::read_bigwarp_csv(&fixture("bigwarp_pairs.csv")).expect("csv");
    // Writers: .json is BigWarp JSON, anything else but a Slicer name is BigWarp CSV.
    let json = dir.path().join("pairs.json");
    let csv_path = dir.path().join("pairs.csv");
    landmarks::write_landmark_pairs(&json, &pairs).expect("json");
    landmarks::write_landmark_pairs(&csv_path, &pairs).expect("csv");
    assert!(std::fs::read_to_string(&json).expect("json").contains("BigWarpLandmarks"));
    assert_eq!(
        std::fs::read_to_string(&csv_path).expect("csv"),
        landmarks::to_bigwarp_csv(&csv_path, &pairs, BigWarpCsvOptions::default()).expect("csv")
    );
    for slicer in ["pairs.mrk.json", "pairs.fcsv"] {
        let path = dir.path().join(slicer);
        let e = landmarks::write_landmark_pairs(&path, &pairs).expect_err(slicer);
        assert!(e.to_string().contains("one side"), "{e}");
        assert!(!path.exists());
    }
    // Readers decide by content, whatever the name.
    let json_named_txt = write_file(dir.path(), "json.txt", &std::fs::read_to_string(&json).expect("json"));
    let csv_named_json = write_file(dir.path(), "csv.json", &std::fs::read_to_string(&csv_path).expect("csv"));
    for path in [&json, &csv_path, &json_named_txt, &csv_named_json] {
        assert_eq!(landmarks::read_landmark_pairs(path).expect("read"), pairs, "{}", path.display());
    }
    for (name, want) in [
        ("bigwarp_pairs.csv", F::BigWarpCsv),
        ("bigwarp_pairs.json", F::BigWarpJson),
        ("bigwarp_settings.json", F::BigWarpJson),
        ("slicer5_lps.mrk.json", F::SlicerMarkupsJson),
        ("slicer5_extra_columns.fcsv", F::SlicerFcsv),
        ("slicer3.fcsv", F::SlicerFcsv),
    ] {
        assert_eq!(landmarks::detect_landmark_file(&fixture(name)).expect(name), want, "{name}");
    }
    // A Slicer list holds one side: refused as a file of pairs, saying so.
    for name in ["slicer5_lps.mrk.json", "slicer3.fcsv"] {
        let e = landmarks::read_landmark_pairs(&fixture(name)).expect_err(name);
        assert!(matches!(e.kind, ErrorKind::Unsupported(_)) && e.to_string().contains("one side"), "{e}");
    }
    // An unknown JSON says what was expected, and what it found.
    let other = write_file(dir.path(), "other.json", r#"{"points": [[1, 2, 3]], "version": 2}"#);
    let e = landmarks::read_landmark_pairs(&other).expect_err("unknown json");
    let msg = e.to_string();
    assert!(msg.starts_with(&format!("{}: ", other.display())), "{msg}");
    for want in
        ["BigWarpLandmarks", "\"landmarks\"", "\"Transform\"", "Slicer", "\"markups\"", "\"points\", \"version\""]
    {
        assert!(msg.contains(want), "{want}: {msg}");
    }
    // A BigWarp file given as a Slicer point list says what it is.
    let e = landmarks::read_mrk_json(&fixture("bigwarp_pairs.json")).expect_err("bigwarp as slicer");
    assert!(e.to_string().contains("BigWarp landmarks file"), "{e}");
}

#[test]
fn bigwarp_json_strips_a_bom() {
    let text = std::fs::read_to_string(fixture("bigwarp_pairs.json")).expect("fixture");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = write_file(dir.path(), "bom.json", &format!("{BOM}{text}"));
    let want = landmarks::read_bigwarp_json(&fixture("bigwarp_pairs.json")).expect("plain");
    assert_eq!(landmarks::read_bigwarp_json(&path).expect("bom"), want);
    assert_eq!(landmarks::read_landmark_pairs(&path).expect("bom by content"), want);
}

proptest! {
    /// Law: BigWarp JSON write then read is the identity (names, flags, missing halves; exact f64 where
    /// serde_json parses exactly).
    #[test]
    fn random_pairs_round_trip_through_bigwarp_json(pairs in proptest::collection::vec(pair(), 0..12), ras in any::<bool>()) {
        let name = Path::new("r.json");
        let options = BigWarpCsvOptions { ras };
        let text = landmarks::to_bigwarp_json(name, &pairs, options).expect("write");
        let back = landmarks::parse_bigwarp_json(name, &text, options).expect("read");
        prop_assert_eq!(back.len(), pairs.len());
        for (b, a) in back.iter().zip(&pairs) {
            prop_assert_eq!(&b.name, &a.name);
            prop_assert_eq!(b.active, a.active);
            prop_assert!(same_point(b.moving, a.moving), "{:?} vs {:?}", b.moving, a.moving);
            prop_assert!(same_point(b.fixed, a.fixed), "{:?} vs {:?}", b.fixed, a.fixed);
        }
    }

    /// Law: no text makes the BigWarp JSON reader or the format detection panic.
    #[test]
    fn arbitrary_json_like_text_never_panics(text in "(\\PC|\n|\\[|\\]|\\{|\\}|,|\"|\\\\|Infinity|NaN|-){0,200}") {
        let _ = landmarks::parse_bigwarp_json(Path::new("x.json"), &text, BigWarpCsvOptions::default());
        let _ = landmarks::detect_landmark_format(Path::new("x"), &text);
    }
}

// ---------------------------------------------------------------------------------------------
// Landmark files are regular files of a bounded size (the readers' mechanism of issue 13, item 4).

#[cfg(unix)]
#[test]
fn a_named_pipe_given_as_landmarks_is_refused_without_blocking() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("pairs.csv");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(made.success());
    let (tx, rx) = std::sync::mpsc::channel();
    let path = fifo.clone();
    // Opening a FIFO blocks until a writer comes: run the read on its own thread and give it 10 s.
    std::thread::spawn(move || {
        let _ = tx.send((
            landmarks::read_bigwarp_csv(&path).map(|_| ()),
            landmarks::read_landmark_pairs(&path).map(|_| ()),
            landmarks::read_slicer_points(&path).map(|_| ()),
        ));
    });
    let results = rx.recv_timeout(std::time::Duration::from_secs(10)).expect("the reader blocked on a named pipe");
    for e in [results.0.expect_err("csv"), results.1.expect_err("pairs"), results.2.expect_err("slicer")] {
        assert!(e.to_string().contains("pairs.csv") && e.to_string().contains("named pipe"), "{e}");
    }
}

#[test]
fn an_oversized_landmark_file_is_refused_before_it_is_read() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("huge.csv");
    let file = std::fs::File::create(&path).expect("create");
    // Sparse: no disk is used.
    file.set_len(landmarks::MAX_LANDMARK_FILE_BYTES + 1).expect("set_len");
    let e = landmarks::read_landmark_pairs(&path).expect_err("huge");
    assert!(e.to_string().contains("huge.csv") && e.to_string().contains("bytes"), "{e}");
}

#[test]
fn a_long_name_is_cut_in_messages() {
    let long = "n".repeat(10_000);
    let e = csv(&format!("\"{long}\",\"true\",\"1\",\"x\",\"3\",\"4\",\"5\",\"6\"\n")).expect_err("bad y");
    let msg = e.to_string();
    assert!(msg.len() < 300 && msg.contains("…") && msg.contains("moving y"), "{} bytes: {}", msg.len(), &msg[..200]);
}

#[test]
fn a_slicer_point_list_is_read_by_content_and_a_bigwarp_file_is_named_as_such() {
    let dir = tempfile::tempdir().expect("tempdir");
    // An .fcsv saved under another name reads as .fcsv; a .mrk.json under another name as JSON.
    let fcsv = std::fs::read_to_string(fixture("slicer5_extra_columns.fcsv")).expect("fcsv");
    let json = std::fs::read_to_string(fixture("slicer5_lps.mrk.json")).expect("json");
    let fcsv_as_txt = write_file(dir.path(), "moving.txt", &fcsv);
    let json_as_txt = write_file(dir.path(), "fixed.txt", &json);
    assert_eq!(
        landmarks::read_slicer_points(&fcsv_as_txt).expect("fcsv by content"),
        landmarks::read_fcsv(&fixture("slicer5_extra_columns.fcsv")).expect("fcsv")
    );
    assert_eq!(
        landmarks::read_slicer_points(&json_as_txt).expect("json by content"),
        landmarks::read_mrk_json(&fixture("slicer5_lps.mrk.json")).expect("json")
    );
    // BigWarp files hold pairs: given as one side, they are refused, saying what they are.
    for name in ["bigwarp_pairs.csv", "bigwarp_pairs.json", "bigwarp_settings.json"] {
        let e = landmarks::read_slicer_points(&fixture(name)).expect_err(name);
        assert!(e.to_string().contains("BigWarp") && e.to_string().contains("not a Slicer point list"), "{e}");
    }
}

#[test]
fn text_that_is_no_landmark_file_is_not_called_bigwarp() {
    let dir = tempfile::tempdir().expect("tempdir");
    let junk = write_file(dir.path(), "notes.txt", "hello, world\n");
    let e = landmarks::read_slicer_points(&junk).expect_err("junk");
    assert!(!e.to_string().contains("BigWarp") && e.to_string().contains("not a Slicer point list"), "{e}");
}
