//! MNI tag point files (`.tag`) and MNI transform files (`.xfm`) against VTK 9.7.1's `vtkMNITagPointReader` and
//! `vtkMNITransformReader` (and SimpleITK 2.5.7's MINC transform reader): the fixtures of `tests/data/mni/`, written by
//! VTK's writers and by hand in MNI's `register` layout (`data-scripts/mni_vtk.py`), read to what VTK reads; what we
//! write reads back; bad files are refused naming the file, the landmark (1-based) or the line.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Vector4};
use serde_json::Value;
use warpbench_io::ErrorKind;
use warpbench_io::geometry::Point3;
use warpbench_io::landmarks::{self, LandmarkFileFormat, LandmarkPair};
use warpbench_io::mni_xfm::{self, XfmStep};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/mni")
}

fn reference() -> Value {
    let path = data_dir().join("reference.json");
    serde_json::from_str(&std::fs::read_to_string(&path).expect("reference")).expect("JSON")
}

fn triple(v: &Value) -> [f64; 3] {
    let a = v.as_array().expect("triple");
    std::array::from_fn(|k| a[k].as_f64().expect("number"))
}

fn ras(p: Point3<warpbench_io::geometry::Lps>) -> [f64; 3] {
    let [x, y, z] = p.coords();
    [-x, -y, z]
}

#[test]
fn tag_files_read_as_vtk_reads_them_volume_1_fixed() {
    let r = reference();
    let tags = r["tags"].as_array().expect("tags");
    let mut read = 0;
    for t in tags {
        let file = t["file"].as_str().expect("file");
        let path = data_dir().join(file);
        assert_eq!(landmarks::detect_landmark_file(&path).expect("detect"), LandmarkFileFormat::MniTag, "{file}");
        if t["volumes"] == 1 {
            let e = landmarks::read_landmark_pairs(&path).expect_err("one volume");
            assert!(e.to_string().contains("one volume"), "{e}");
            continue;
        }
        let pairs = landmarks::read_landmark_pairs(&path).unwrap_or_else(|e| panic!("{e}"));
        let points = t["points"].as_array().expect("points");
        let (fixed, moving) = (points[0].as_array().expect("1"), points[1].as_array().expect("2"));
        assert_eq!(pairs.len(), fixed.len(), "{file}");
        // VTK keeps points in float32: ours, parsed in double, round to VTK's.
        for (i, p) in pairs.iter().enumerate() {
            assert!(p.active && p.is_complete(), "{file} {i}");
            let (f, m) = (ras(p.fixed.expect("fixed")), ras(p.moving.expect("moving")));
            let (vf, vm) = (triple(&fixed[i]), triple(&moving[i]));
            for k in 0..3 {
                assert_eq!((f[k] as f32).to_bits(), (vf[k] as f32).to_bits(), "{file} pair {i} fixed {k}");
                assert_eq!((m[k] as f32).to_bits(), (vm[k] as f32).to_bits(), "{file} pair {i} moving {k}");
            }
        }
        let names: Vec<&str> = pairs.iter().map(|p| p.name.as_str()).collect();
        match t["labels"].as_array() {
            Some(labels) => {
                let want: Vec<&str> = labels.iter().map(|l| l.as_str().unwrap_or("")).collect();
                assert_eq!(names, want, "{file}");
            }
            None => assert!(names.iter().all(|n| n.is_empty()), "{file}: {names:?}"),
        }
        read += 1;
    }
    assert!(read >= 4, "{read} files of pairs");
}

#[test]
fn a_tag_file_we_write_reads_back_and_keeps_register_s_order() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = landmarks::read_landmark_pairs(&data_dir().join("pairs_ids.tag")).expect("read");
    let out = dir.path().join("out.tag");
    landmarks::write_landmark_pairs(&out, &pairs).expect("write");
    let text = std::fs::read_to_string(&out).expect("text");
    assert!(text.starts_with("MNI Tag Point File\nVolumes = 2;\n"), "{text}");
    assert_eq!(landmarks::read_landmark_pairs(&out).expect("back"), pairs);
    // Volume 1's numbers, the fixed point in RAS, come first on each line.
    let first = text.lines().find(|l| l.starts_with(' ')).expect("a point line");
    let numbers: Vec<f64> = first.split_whitespace().take(3).map(|w| w.parse().expect("number")).collect();
    assert_eq!(numbers, ras(pairs[0].fixed.expect("fixed")));
    // Half-placed, inactive or oddly named pairs have no place in a tag file: refused, naming the landmark.
    let p = |x: f64| Point3::new(x, 2.0, 3.0);
    let cases = [
        (LandmarkPair { moving: None, ..LandmarkPair::new("a", p(1.0), p(2.0)) }, "misses a half"),
        (LandmarkPair { active: false, ..LandmarkPair::new("b", p(1.0), p(2.0)) }, "inactive"),
        (LandmarkPair::new("say \"c\"", p(1.0), p(2.0)), "double quote"),
    ];
    for (bad, says) in cases {
        let e = landmarks::to_mni_tag(&out, &[pairs[0].clone(), bad]).expect_err(says);
        assert!(matches!(e.kind, ErrorKind::Landmark { index: 2, .. }), "{e}");
        assert!(e.to_string().contains(says), "{e}");
    }
}

#[test]
fn bad_tag_files_are_refused_naming_the_file_and_the_landmark() {
    let name = Path::new("bad.tag");
    let head = "MNI Tag Point File\nVolumes = 2;\nPoints =\n";
    let cases = [
        ("MNI Tag Point File\nVolumes = 3;\nPoints = ;", "Volumes = 3"),
        ("MNI Tag Point File\nVolumes = 2;\n", "expected Points ="),
        (&*format!("{head} 1 2 3 4 5 6 \"a\"\n 1 2 3 4 x 6;"), "(1-based"),
        (&*format!("{head} 1 2 3 4 5 6 \"a\"\n 1 2 3 4 5 nan;"), "coordinate 6 is NaN"),
        (&*format!("{head} 1 2 3 4 5 6 \"open"), "no closing quote"),
        (&*format!("{head} 1 2 3 4 5 6"), "without the closing ;"),
        (&*format!("{head} 1 2 3 4 5 6 1.5 2 \"a\";"), "patient id"),
    ];
    for (text, says) in cases {
        let e = landmarks::parse_mni_tag(name, text).expect_err(says);
        let msg = e.to_string();
        assert!(msg.starts_with("bad.tag"), "{msg}");
        assert!(msg.contains(says), "{says}: {msg}");
    }
    let e = landmarks::parse_mni_tag(name, &format!("{head} 1 2 3 4 5 6 \"a\"\n 7 8 9 1 2 x;")).expect_err("x");
    assert!(matches!(e.kind, ErrorKind::Landmark { index: 2, .. }), "{e}");
    assert!(e.to_string().contains("line 5"), "{e}");
}

/// The map of a transform reference: VTK's points at the test points.
fn vtk_points(t: &Value, key: &str) -> Option<Vec<[f64; 3]>> {
    t["vtk"][key].as_array().map(|a| a.iter().map(triple).collect())
}

fn apply(m: &Matrix4<f64>, p: [f64; 3]) -> [f64; 3] {
    let v = m * Vector4::new(p[0], p[1], p[2], 1.0);
    [v[0], v[1], v[2]]
}

#[test]
fn linear_transform_files_map_as_vtk_maps_them() {
    let r = reference();
    let test_points: Vec<[f64; 3]> = r["test_points"].as_array().expect("points").iter().map(triple).collect();
    let mut linear = 0;
    for t in r["transforms"].as_array().expect("transforms") {
        let file = t["file"].as_str().expect("file");
        let path = data_dir().join(file);
        let classes: Vec<&str> =
            t["vtk"]["classes"].as_array().expect("classes").iter().map(|c| c.as_str().expect("class")).collect();
        if classes.iter().any(|c| *c != "vtkTransform") {
            // A grid or thin-plate-spline transform: refused, naming it.
            let e = mni_xfm::read_map(&path).expect_err(file);
            assert!(e.to_string().contains("Grid_Transform") || e.to_string().contains("Thin_Plate_Spline"), "{e}");
            assert!(
                warpbench_io::mni_xfm::read(&path).expect("parses").iter().all(|s| !matches!(s, XfmStep::Linear(_)))
            );
            continue;
        }
        let map = mni_xfm::read_map(&path).unwrap_or_else(|e| panic!("{e}"));
        let want = vtk_points(t, "points").expect("VTK's points");
        for (p, w) in test_points.iter().zip(&want) {
            let got = apply(&map, *p);
            for k in 0..3 {
                assert!((got[k] - w[k]).abs() < 1e-9, "{file}: {got:?} vs VTK {w:?} at {p:?}");
            }
        }
        // SimpleITK reads the numbers as they are (no RAS/LPS flip): the same map.
        if let Some(sitk) = t["sitk"]["points"].as_array() {
            for (p, w) in test_points.iter().zip(sitk.iter().map(triple)) {
                let got = apply(&map, *p);
                assert!((0..3).all(|k| (got[k] - w[k]).abs() < 1e-9), "{file}: {got:?} vs SimpleITK {w:?}");
            }
        }
        // The starting transform is the pull-back: the inverse map, in LPS.
        let u = mni_xfm::read_affine(&path).expect("affine");
        for p in &test_points {
            let q = apply(&map, *p);
            let back = u.apply([-q[0], -q[1], q[2]]);
            assert!((0..3).all(|k| (back[k] - [-p[0], -p[1], p[2]][k]).abs() < 1e-9), "{file}");
        }
        linear += 1;
    }
    assert!(linear >= 3, "{linear} linear files");
}

#[test]
fn what_we_write_reads_back_and_bad_files_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let u = Matrix4::new(0.9, 0.1, -0.05, 12.5, -0.08, 1.1, 0.02, -3.0, 0.04, -0.01, 0.95, 7.25, 0.0, 0.0, 0.0, 1.0);
    let out = dir.path().join("out.xfm");
    mni_xfm::write(&out, &u).expect("write");
    let back = mni_xfm::read_affine(&out).expect("read");
    for r in 0..3 {
        for c in 0..3 {
            assert!((back.matrix[(r, c)] - u[(r, c)]).abs() < 1e-12);
        }
        assert!((back.offset()[r] - u[(r, 3)]).abs() < 1e-12);
    }
    // ITK's writers refuse the name: ITK would read an .xfm as MINC's.
    let e = warpbench_io::transform_file::write(
        &dir.path().join("x.xfm"),
        &warpbench_io::itk_tfm::ItkTransform::Affine(back),
    )
    .expect_err("itk to .xfm");
    assert!(e.to_string().contains("MNI"), "{e}");
    let name = Path::new("bad.xfm");
    let cases = [
        ("Transform_Type = Linear;", "does not start with"),
        ("MNI Transform File\n% nothing\n", "no transform"),
        ("MNI Transform File\nTransform_Type = Linear;\nLinear_Transform = 1 0 0 0 0 1 0 0 0 0 1;", "11 numbers"),
        ("MNI Transform File\nTransform_Type = Linear;\n", "has no Linear_Transform"),
        (
            "MNI Transform File\nTransform_Type = Linear;\nLinear_Transform =\n 1 0 0 0\n 0 1 0 0\n 0 0 1 0",
            "no closing ;",
        ),
        ("MNI Transform File\nLinear_Transform = 1 0 0 0 0 1 0 0 0 0 1 0;", "outside a Transform_Type"),
        ("MNI Transform File\nTransform_Type = Linear;\nInvert_Flag = Maybe;", "not True or False"),
        (
            "MNI Transform File\nTransform_Type = Linear;\nInvert_Flag = True;\nLinear_Transform = 1 0 0 0 0 1 0 0 0 0 0 0;",
            "singular",
        ),
    ];
    for (text, says) in cases {
        let e = mni_xfm::parse(name, text).expect_err(says);
        assert!(e.to_string().starts_with("bad.xfm") && e.to_string().contains(says), "{says}: {e}");
    }
    let e = mni_xfm::parse(name, "MNI Transform File\n\nTransform_Type = Linear;\nLinear_Transform = 1 0 x;")
        .expect_err("x");
    assert!(e.to_string().contains("line 4"), "{e}");
}

/// The reference's grid volume: its values (RAS, the file's C order: z, y, x, component) at voxel (i, j, k).
fn grid_value(g: &Value, [i, j, k]: [usize; 3], c: usize) -> f64 {
    let shape: Vec<usize> =
        g["shape"].as_array().expect("shape").iter().map(|x| x.as_u64().expect("n") as usize).collect();
    let values = g["values"].as_array().expect("values");
    values[((k * shape[1] + j) * shape[2] + i) * 3 + c].as_f64().expect("value")
}

#[test]
fn grid_transforms_read_as_displacement_fields_on_their_grids() {
    use warpbench_io::displacement::{FieldDirection, FieldFormat, FieldSource, read_field_info};
    use warpbench_io::elastix::{FieldInterpolation, FieldStep};
    let r = reference();
    let test_points: Vec<[f64; 3]> = r["test_points"].as_array().expect("points").iter().map(triple).collect();
    for (file, direction) in [
        ("grid.xfm", FieldDirection::Forward),
        ("grid_inverted.xfm", FieldDirection::Pullback),
        ("grid_itk.xfm", FieldDirection::Forward),
    ] {
        let t = r["transforms"].as_array().expect("transforms").iter().find(|t| t["file"] == file).expect(file);
        let g = &t["grid_volume"];
        let path = data_dir().join(file);
        let read = read_field_info(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((read.source, read.direction), (FieldSource::Field(FieldFormat::Minc), Some(direction)), "{file}");
        let field = &read.field;
        assert_eq!(field.dims, [6, 5, 4], "{file}");
        // 10 mm voxels from (-25, -20, -15) RAS, axis-aligned: in LPS, x and y flipped.
        let want = [[-10.0, 0.0, 0.0, 25.0], [0.0, -10.0, 0.0, 20.0], [0.0, 0.0, 10.0, -15.0], [0.0, 0.0, 0.0, 1.0]];
        assert_eq!(field.lps_from_index.rows(), want, "{file}");
        for k in 0..4 {
            for j in 0..5 {
                for i in 0..6 {
                    let d = field.displacements_lps[(k * 5 + j) * 6 + i];
                    for (c, &x) in d.iter().enumerate() {
                        let ras = if c < 2 { -x } else { x };
                        let want = grid_value(g, [i, j, k], c) as f32;
                        assert_eq!(ras.to_bits(), want.to_bits(), "{file} voxel {i} {j} {k} {c}");
                    }
                }
            }
        }
        // x ↦ x + D(x) read trilinearly (ITK's DisplacementFieldTransform, FieldStep): SimpleITK's map at every point
        // where it reads the file; VTK's (tricubic) where the two agree, at the grid's nodes (the first two test points
        // past the 14 inside).
        let step = FieldStep::new(&path, path.clone(), read.field.clone(), FieldInterpolation::Linear).expect("step");
        let ours = |p: [f64; 3]| {
            let q = step.apply([-p[0], -p[1], p[2]]);
            [-q[0], -q[1], q[2]]
        };
        if let Some(sitk) = t["sitk"]["points"].as_array() {
            for (p, w) in test_points.iter().zip(sitk.iter().map(triple)) {
                let got = ours(*p);
                assert!((0..3).all(|k| (got[k] - w[k]).abs() < 1e-5), "{file}: {got:?} vs SimpleITK {w:?} at {p:?}");
            }
        }
        if direction == FieldDirection::Forward
            && let Some(vtk) = vtk_points(t, "points")
        {
            for n in [14, 15] {
                let got = ours(test_points[n]);
                assert!((0..3).all(|k| (got[k] - vtk[n][k]).abs() < 1e-5), "{file}: node {n}: {got:?} vs VTK");
            }
        }
    }
    // A file of a linear and a grid transform, and a grid file that is not a grid, are refused, naming them.
    let dir = tempfile::tempdir().expect("tempdir");
    let chain = dir.path().join("chain.xfm");
    let linear = std::fs::read_to_string(data_dir().join("linear.xfm")).expect("linear");
    std::fs::write(&chain, format!("{linear}\nTransform_Type = Grid_Transform;\nDisplacement_Volume = none.mnc;\n"))
        .expect("write");
    let e = read_field_info(&chain).expect_err("chain");
    assert!(e.to_string().contains("holds Linear, Grid_Transform"), "{e}");
    let not_grid = dir.path().join("volume.xfm");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/minc/oblique_i16.mnc"),
        dir.path().join("v.mnc"),
    )
    .expect("copy");
    std::fs::write(&not_grid, "MNI Transform File\nTransform_Type = Grid_Transform;\nDisplacement_Volume = v.mnc;\n")
        .expect("write");
    let e = read_field_info(&not_grid).expect_err("a volume");
    assert!(e.to_string().contains("v.mnc cannot be read") && e.to_string().contains("vector_dimension"), "{e}");
}

#[test]
fn a_field_written_as_a_grid_transform_reads_back() {
    use warpbench_io::displacement::{FieldDirection, FieldFormat, FieldSource, read_field_info, write_field_with};
    let dir = tempfile::tempdir().expect("tempdir");
    let grid = crate::support::oblique_grid(-1.0);
    let dims = [4, 3, 2];
    let vectors: Vec<[f32; 3]> =
        (0..24).map(|i| [i as f32 * 0.25 - 3.0, 1.0 - i as f32 * 0.125, (i * i) as f32 * 0.01]).collect();
    for direction in [FieldDirection::Pullback, FieldDirection::Forward] {
        let out = dir.path().join(format!("u_{}.XFM", direction.name()));
        write_field_with(&out, FieldFormat::Minc, direction, dims, &grid, &vectors).expect("write");
        let grid_file = dir.path().join(format!("u_{}_grid_0.mnc", direction.name()));
        assert!(grid_file.is_file(), "the grid beside it");
        let text = std::fs::read_to_string(&out).expect("text");
        assert_eq!(text.contains("Invert_Flag = True;"), direction == FieldDirection::Pullback, "{text}");
        let read = read_field_info(&out).expect("read");
        assert_eq!((read.source, read.direction), (FieldSource::Field(FieldFormat::Minc), Some(direction)));
        assert_eq!(read.field.dims, dims);
        assert_eq!(read.field.displacements_lps, vectors, "float32 vectors, exactly");
        let (got, want) = (read.field.lps_from_index.rows(), grid.rows());
        for r in 0..4 {
            for c in 0..4 {
                assert!((got[r][c] - want[r][c]).abs() < 1e-12, "{got:?} vs {want:?}");
            }
        }
    }
    // Only an .xfm name holds it; a non-finite vector is refused, naming the voxel, and nothing is written.
    let e = write_field_with(
        &dir.path().join("u.nii.gz"),
        FieldFormat::Minc,
        FieldDirection::Pullback,
        dims,
        &grid,
        &vectors,
    )
    .expect_err("name");
    assert!(e.to_string().contains(".xfm"), "{e}");
    let mut bad = vectors.clone();
    bad[5][1] = f32::NAN;
    let out = dir.path().join("nan.xfm");
    let e = write_field_with(&out, FieldFormat::Minc, FieldDirection::Pullback, dims, &grid, &bad).expect_err("NaN");
    assert!(e.to_string().contains("[1, 1, 0]"), "{e}");
    assert!(!out.exists() && !dir.path().join("nan_grid_0.mnc").exists());
}

#[test]
fn a_tag_file_of_one_volume_is_one_side_of_the_pairs() {
    let r = reference();
    let t = r["tags"].as_array().expect("tags").iter().find(|t| t["file"] == "one_volume.tag").expect("one volume");
    let path = data_dir().join("one_volume.tag");
    let points = landmarks::read_slicer_points(&path).unwrap_or_else(|e| panic!("{e}"));
    let vtk = t["points"][0].as_array().expect("points");
    assert_eq!(points.len(), vtk.len());
    for (p, v) in points.iter().zip(vtk.iter().map(triple)) {
        let got = ras(p.position.expect("placed"));
        assert!(p.selected && (0..3).all(|k| (got[k] as f32).to_bits() == (v[k] as f32).to_bits()), "{got:?} vs {v:?}");
    }
    // Two such lists pair by order, as Slicer's and elastix's do; a tag file of pairs is not a list.
    let pairs = landmarks::read_slicer_pair(&path, &path).expect("pair");
    assert!(pairs.iter().all(|p| p.is_complete() && p.moving == p.fixed));
    let e = landmarks::read_slicer_points(&data_dir().join("pairs.tag")).expect_err("pairs");
    assert!(e.to_string().contains("holds pairs"), "{e}");
}
