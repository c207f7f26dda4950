//! elastix point files and transformix's `outputpoints.txt`: round trips, the count check, `index` files through a
//! volume's geometry (and refused without one), pairs from elastix's two point sets and from transformix's result.

use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Vector3};
use warpbench_io::geometry::{Index, Lps, Point3, Transform};
use warpbench_io::landmarks::{
    self, ElastixPointKind, ElastixPoints, LandmarkFileFormat, LandmarkPair, PointFile, PointFileFormat,
    PointFileOptions,
};

fn name() -> &'static Path {
    Path::new("pts.txt")
}

fn parse(text: &str) -> warpbench_io::Result<ElastixPoints> {
    landmarks::parse_elastix_points(name(), text)
}

fn message(text: &str) -> String {
    let e = parse(text).expect_err(text).to_string();
    assert!(e.starts_with("pts.txt: "), "{e}");
    e
}

#[test]
fn point_and_index_files_round_trip_exactly() {
    let rows = vec![[102.8, -33.4, 57.0], [1e-300, -0.0, 2.0 / 3.0], [-7.25, 1e22, 0.1]];
    let dir = tempfile::tempdir().expect("tempdir");
    for kind in [ElastixPointKind::Point, ElastixPointKind::Index] {
        let file = ElastixPoints { kind, rows: rows.clone(), lines: Vec::new() };
        let path = dir.path().join(format!("{}.txt", kind.word()));
        landmarks::write_elastix_points(&path, &file).expect("write");
        let text = std::fs::read_to_string(&path).expect("text");
        assert!(text.starts_with(&format!("{}\n3\n", kind.word())), "{text}");
        let back = landmarks::read_elastix_points(&path).expect("read");
        assert_eq!(back.kind, kind);
        let bits = |r: &[[f64; 3]]| r.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back.rows), bits(&rows));
        assert_eq!(back.lines, [3, 4, 5]);
    }
}

#[test]
fn the_header_is_read_as_elastix_reads_it() {
    let a = parse("point\n2\n1 2 3\n4 5 6\n").expect("two lines");
    let b = parse("point 2\n\n1\t2 3\r\n  4 5 6  \n\n").expect("count on the first line, blank lines");
    assert_eq!(a.rows, b.rows);
    assert_eq!(a.kind, ElastixPointKind::Point);
    // elastix before 3.503: no word, the count first, indices.
    let legacy = parse("2\n1 2 3\n4 5 6\n").expect("legacy");
    assert_eq!(legacy.kind, ElastixPointKind::Index);
    assert_eq!(legacy.rows, a.rows);
    assert!(landmarks::looks_like_elastix_points("index\n1\n0 0 0\n"));
    assert!(!landmarks::looks_like_elastix_points("1,2,3\n"));
    assert!(!landmarks::looks_like_elastix_points("x,y,z\n1,2,3\n"));
}

#[test]
fn a_count_that_disagrees_with_the_rows_and_bad_rows_are_refused_with_their_line() {
    let cases = [
        ("point\n3\n1 2 3\n4 5 6\n", "line 2 says 3 points, but the file has 2 (lines 3 to 4)"),
        ("point\n1\n1 2 3\n\n4 5 6\n", "line 2 says 1 points, but the file has 2 (lines 3 to 5)"),
        ("index 2\n1 2 3\n", "line 1 says 2 points, but the file has 1 (lines 2 to 2)"),
        ("point\n0\n", ""),
        ("point\n", "line 1: \"point\" is not followed by the number of points"),
        ("point\nmany\n1 2 3\n", "line 2: the number of points is \"many\""),
        ("points\n1\n1 2 3\n", "line 1: \"points\" is neither \"point\" nor \"index\""),
        ("point\n2\n1 2\n3 4\n", "landmark 1: (1-based, \"\", line 3) 2 values; a point line holds x y z"),
        ("point\n1\n1 2 3 4\n", "line 3) 4 values"),
        ("point\n1\n1 nan 3\n", "line 3) y is \"nan\", not a finite number"),
        ("point\n1\n1 2 three\n", "z is \"three\""),
        ("", "the file is empty"),
    ];
    for (text, needle) in cases {
        if needle.is_empty() {
            assert!(parse(text).expect(text).rows.is_empty());
            continue;
        }
        let e = message(text);
        assert!(e.contains(needle), "{text:?}: {e:?} lacks {needle:?}");
    }
}

fn oblique() -> Transform<Lps, Index> {
    let r = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.3).into_inner();
    let linear: Matrix3<f64> = r * Matrix3::from_diagonal(&Vector3::new(0.7, 1.3, 2.5));
    Transform::from_linear_translation(linear, [-10.5, 20.25, 3.0])
}

#[test]
fn index_files_go_through_the_volume_and_are_refused_without_one() {
    let mut file = parse("index\n2\n0 0 0\n1 2 3.5\n").expect("index");
    let lps = file.to_lps(name(), Some(&oblique())).expect("through the volume");
    assert_eq!(lps[0], Point3::new(-10.5, 20.25, 3.0), "index 0 is the offset, exactly");
    let want = oblique().apply_point(Point3::new(1.0, 2.0, 3.5));
    assert_eq!(lps[1], want);
    let e = file.to_lps(name(), None).expect_err("no volume").to_string();
    assert!(e.starts_with("pts.txt: ") && e.contains("\"index\" file holds voxel indices"), "{e}");

    let index_from_lps = oblique().inverse().expect("invertible");
    file.set_lps(name(), &lps, Some(&index_from_lps)).expect("back to indices");
    for (got, want) in file.rows.iter().zip([[0.0, 0.0, 0.0], [1.0, 2.0, 3.5]]) {
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-12), "{got:?}");
    }
    assert!(file.set_lps(name(), &lps, None).is_err());
    // A `point` file needs no volume, and ignores one.
    let points = parse("point\n1\n1 2 3\n").expect("point");
    assert_eq!(points.to_lps(name(), None).expect("lps"), points.to_lps(name(), Some(&oblique())).expect("lps"));
}

#[test]
fn elastix_files_are_point_files_and_one_side_of_a_pair() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = "point\n2\n1 2 3\n4 5 6\n";
    assert_eq!(landmarks::detect_point_format(name(), text).expect("detect"), PointFileFormat::ElastixPoints);
    assert_eq!(landmarks::detect_landmark_format(name(), text).expect("detect"), LandmarkFileFormat::ElastixPoints);
    assert_eq!(PointFileFormat::named_by(Path::new("a.TXT")), Some(&[PointFileFormat::ElastixPoints][..]));
    let PointFile::Elastix(e) = landmarks::parse_point_file(name(), text, PointFileOptions::default()).expect("read")
    else {
        panic!("an elastix file")
    };
    assert_eq!(e.rows.len(), 2);
    let ras = landmarks::parse_point_file(name(), text, PointFileOptions { ras: true }).expect_err("ras");
    assert!(ras.to_string().contains("ITK's physical space"), "{ras}");

    // One side: refused as a file of pairs, paired by order with another side (elastix or Slicer).
    let (moving, fixed) = (dir.path().join("moving.txt"), dir.path().join("fixed.txt"));
    std::fs::write(&moving, "point\n2\n1 2 3\n4 5 6\n").expect("write");
    std::fs::write(&fixed, "point\n2\n1.5 2 3\n4 5.5 6\n").expect("write");
    let e = landmarks::read_landmark_pairs(&moving).expect_err("one side").to_string();
    assert!(e.contains("holds the points of one image"), "{e}");
    let pairs = landmarks::read_slicer_pair(&moving, &fixed).expect("pairs");
    assert_eq!(pairs.len(), 2);
    assert_eq!(pairs[1].moving, Some(Point3::new(4.0, 5.0, 6.0)));
    assert_eq!(pairs[1].fixed, Some(Point3::new(4.0, 5.5, 6.0)));
    assert!(pairs.iter().all(|p| p.active));
    let index = dir.path().join("index.txt");
    std::fs::write(&index, "index\n2\n1 2 3\n4 5 6\n").expect("write");
    let e = landmarks::read_slicer_pair(&moving, &index).expect_err("index").to_string();
    assert!(e.contains("index.txt") && e.contains("voxel indices"), "{e}");
    let one = dir.path().join("one.txt");
    std::fs::write(&one, "point\n1\n1 2 3\n").expect("write");
    let e = landmarks::read_slicer_pair(&moving, &one).expect_err("counts").to_string();
    assert!(e.contains("moving.txt") && e.contains("one.txt") && e.contains("paired by index"), "{e}");

    // Written as elastix point sets: the active pairs with both points, both files .txt.
    let mut all = pairs.clone();
    all.push(LandmarkPair { name: "off".into(), active: false, ..all[0].clone() });
    all.push(LandmarkPair { name: "half".into(), active: true, moving: None, ..all[0].clone() });
    let (mo, fo) = (dir.path().join("m_out.txt"), dir.path().join("f_out.txt"));
    landmarks::write_slicer_pair(&mo, &fo, &all).expect("write");
    assert_eq!(std::fs::read_to_string(&mo).expect("m"), "point\n2\n1.0 2.0 3.0\n4.0 5.0 6.0\n");
    assert_eq!(landmarks::read_slicer_pair(&mo, &fo).expect("back"), pairs);
    let e = landmarks::write_slicer_pair(&mo, &dir.path().join("f.mrk.json"), &all).expect_err("mixed");
    assert!(e.to_string().contains("both as Slicer lists"), "{e}");
}

#[test]
fn transformix_output_is_a_file_of_pairs() {
    // As transformix writes it (std::fixed, tabs), with OutputIndexMoving when it had the moving image.
    let text = "Point\t0\t; InputIndex = [ 10 20 30 ]\t; InputPoint = [ 10.000000 20.000000 30.000000 ]\t; \
                OutputIndexFixed = [ 9 19 31 ]\t; OutputPoint = [ 9.500000 19.200000 31.100000 ]\t; \
                Deformation = [ -0.500000 -0.800000 1.100000 ]\n\
                Point\t1\t; InputIndex = [ 1 2 3 ]\t; InputPoint = [ -1.500000 2.000000 3.000000 ]\t; \
                OutputIndexFixed = [ 1 2 3 ]\t; OutputPoint = [ -1.000000 2.500000 3.250000 ]\t; \
                Deformation = [ 0.500000 0.500000 0.250000 ]\t; OutputIndexMoving = [ 1 2 3 ]\n";
    let out = Path::new("outputpoints.txt");
    assert_eq!(landmarks::detect_landmark_format(out, text).expect("detect"), LandmarkFileFormat::TransformixOutput);
    assert!(LandmarkFileFormat::TransformixOutput.holds_pairs());
    let pairs = landmarks::transformix_pairs(out, text).expect("pairs");
    assert_eq!(pairs.len(), 2);
    assert_eq!(pairs[0].name, "Point 0");
    assert_eq!(pairs[0].fixed, Some(Point3::new(10.0, 20.0, 30.0)), "InputPoint is on the fixed image");
    assert_eq!(pairs[0].moving, Some(Point3::new(9.5, 19.2, 31.1)), "OutputPoint = T(InputPoint) on the moving one");
    assert_eq!(pairs[1].moving, Some(Point3::new(-1.0, 2.5, 3.25)));
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("outputpoints.txt");
    std::fs::write(&path, text).expect("write");
    assert_eq!(landmarks::read_landmark_pairs(&path).expect("as pairs"), pairs);
    let e = landmarks::parse_point_file(out, text, PointFileOptions::default()).expect_err("not a point file");
    assert!(e.to_string().contains("read it as landmark pairs"), "{e}");

    let bad = [
        ("Point\t0\t; InputPoint = [ 1 2 3 ]\n", "lacks an InputPoint or an OutputPoint"),
        ("Point\t0\t; InputPoint = [ 1 2 ]\t; OutputPoint = [ 1 2 ]\n", "InputPoint has 2 values"),
        ("Point\t0\t; InputPoint = 1 2 3\t; OutputPoint = [ 1 2 3 ]\n", "not [ x y z ]"),
        (
            "Point\t0\t; InputPoint = [ 1 2 3 ]\t; OutputPoint = [ 1 2 3 ]\nPunkt 1\n",
            "landmark 2: (1-based, \"\", line 2) starts \"Punkt 1\"",
        ),
        ("Point\t0\t; InputPoint = [ 1 x 3 ]\t; OutputPoint = [ 1 2 3 ]\n", "not a list of finite numbers"),
    ];
    for (text, needle) in bad {
        let e = landmarks::parse_transformix_output(out, text).expect_err(text).to_string();
        assert!(e.starts_with("outputpoints.txt: ") && e.contains(needle), "{e:?} lacks {needle:?}");
    }
}
