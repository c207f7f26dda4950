//! elastix transform parameter files: the ones elastix wrote (`tests/data/elastix/`, made by
//! `data-scripts/elastix_transforms.py` and `elastix_field.py` with itk-elastix 0.25.4), linear and B-spline, read to
//! transforms that map points where transformix mapped them, and to the displacement field transformix writes; bad
//! files are refused naming the file and the problem.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::elastix::{self, ElastixGrid};
use warpbench_io::geometry::Transform;
use warpbench_io::itk_tfm::{ItkAffine, ItkTransform};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/elastix")
}

fn reference() -> Value {
    let path = data_dir().join("transformix_reference.json");
    serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("JSON")
}

fn points(v: &Value) -> Vec<[f64; 3]> {
    v.as_array().expect("list").iter().map(|p| std::array::from_fn(|a| p[a].as_f64().expect("number"))).collect()
}

fn worst(got: &[[f64; 3]], want: &[[f64; 3]]) -> f64 {
    assert_eq!(got.len(), want.len());
    got.iter().zip(want).flat_map(|(g, w)| (0..3).map(move |a| (g[a] - w[a]).abs())).fold(0.0, f64::max)
}

/// Reads the parameter file `file` of the fixtures (with its chain) and maps `inputs` through it; they must land
/// where transformix put them (`want`), within its printing of 1e-6 mm. Returns where they land.
fn maps_as_transformix_did(file: &str, inputs: &[[f64; 3]], want: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let chain = elastix::read_transform(&data_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
    let got: Vec<_> = inputs.iter().map(|x| chain.apply(*x)).collect();
    assert!(worst(&got, want) < 1e-5, "{file}: {} mm from transformix", worst(&got, want));
    got
}

/// Every file elastix wrote (Euler both ways round, similarity, translation, an affine over the rigid through
/// InitialTransformParameterFileName, a B-spline over that affine, a B-spline on an oblique grid) maps the recorded
/// points where transformix did, and the linear ones read as one affine that does too. transformix prints its points
/// to 1e-6 mm, so the bound is 1e-5 mm; a wrong rotation order, versor, centre or composition order is off by
/// millimetres (the points move up to 8 mm).
#[test]
fn every_file_elastix_wrote_maps_points_where_transformix_did() {
    let r = reference();
    let inputs = points(&r["elastix_points_lps"]);
    let files = r["elastix_files"].as_array().expect("files");
    assert_eq!(files.len(), 7);
    let mut read = Vec::new();
    for f in files {
        let file = f["file"].as_str().expect("file");
        let want = points(&f["transformix_lps"]);
        maps_as_transformix_did(file, &inputs, &want);
        if f["linear"] == true {
            let affine = elastix::read_affine(&data_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
            let got: Vec<_> = inputs.iter().map(|x| affine.apply(*x)).collect();
            assert!(worst(&got, &want) < 1e-5, "{file} as one affine: {} mm", worst(&got, &want));
            read.push((file, affine));
        } else {
            let e = elastix::read_affine(&data_dir().join(file)).expect_err("not linear").to_string();
            assert!(e.contains("BSplineTransform is not a linear transform") && e.contains("--field"), "{e}");
        }
    }
    // The ZYX file differs from the rigid one only in the order of the angles (transformix: up to 0.031 mm apart,
    // 3000 times the bound); the chain differs from its rigid part.
    let far = |a: &ItkAffine, b: &ItkAffine| {
        inputs.iter().any(|x| (0..3).any(|k| (a.apply(*x)[k] - b.apply(*x)[k]).abs() > 1e-3))
    };
    assert!(far(&read[0].1, &read[1].1), "rigid.txt and rigid_zyx.txt are different rotations");
    assert!(far(&read[0].1, &read[3].1), "the affine chain is more than its rigid start");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write");
    p
}

#[test]
fn bad_parameter_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rigid = std::fs::read_to_string(data_dir().join("rigid.txt")).expect("rigid");
    let affine = std::fs::read_to_string(data_dir().join("affine.txt")).expect("affine");
    let refused = |p: &Path, needle: &str| {
        let e = elastix::read_affine(p).expect_err("refused").to_string();
        assert!(e.starts_with(&format!("{}: ", p.display())) && e.contains(needle), "{needle:?} in {e}");
    };
    let other =
        write(dir.path(), "other.txt", &rigid.replace("\"EulerTransform\"", "\"WeightedCombinationTransform\""));
    refused(&other, "WeightedCombinationTransform is not read");
    refused(&other, "transformix -def all");
    refused(
        &write(dir.path(), "few.txt", &rigid.replace("(NumberOfParameters 6)", "").replace(" 0.939309946573854)", ")")),
        "5 numbers, 6 expected",
    );
    refused(
        &write(dir.path(), "lost.txt", &affine.replace("\"rigid.txt\"", "\"gone.txt\"")),
        "\"gone.txt\" is neither beside it",
    );
    let looped = dir.path().join("loop.txt");
    std::fs::write(&looped, affine.replace("\"rigid.txt\"", "\"loop.txt\"")).expect("write");
    refused(&looped, "loops");
    std::fs::copy(data_dir().join("rigid.txt"), dir.path().join("rigid.txt")).expect("copy");
    refused(&write(dir.path(), "add.txt", &affine.replace("\"Compose\"", "\"Add\"")), "only \"Compose\" chains");
    refused(
        &write(dir.path(), "two_d.txt", &rigid.replace("(FixedImageDimension 3)", "(FixedImageDimension 2)")),
        "only 3-D",
    );
    refused(
        &write(dir.path(), "zyx.txt", &rigid.replace("(ComputeZYX \"false\")", "(ComputeZYX \"maybe\")")),
        "neither \"true\"",
    );
    refused(&write(dir.path(), "none.txt", "(Size 1 2 3)\n"), "no (Transform …)");
    refused(&write(dir.path(), "text.txt", "hello\n"), "not a (Name value …) line");
    // The chain's initial file is found beside the file that names it, from any working folder.
    assert!(elastix::read_affine(&dir.path().join("rigid.txt")).is_ok());
    let chained = write(dir.path(), "chained.txt", &affine);
    assert_eq!(
        elastix::read_affine(&chained).expect("the chain beside it"),
        elastix::read_affine(&data_dir().join("affine.txt")).expect("the fixture")
    );
}

/// What warpbench writes reads back (for the linear class) to the same map, names its grid as the fixed volume's,
/// and a transform that is not finite is refused without a file.
#[test]
fn a_written_affine_reads_back_and_names_the_grid() {
    let dir = tempfile::tempdir().expect("tempdir");
    let matrix = nalgebra::Matrix3::new(1.02, 0.05, -0.01, -0.04, 0.98, 0.02, 0.01, -0.03, 1.01);
    let affine = ItkAffine { matrix, translation: [3.0, -2.5, 1.25], center: [10.0, 20.0, -5.0] };
    let (s, c) = 0.4f64.sin_cos();
    let linear = nalgebra::Matrix3::new(c * 1.5, -s * 2.0, 0.0, s * 1.5, c * 2.0, 0.0, 0.0, 0.0, 2.5);
    let grid = ElastixGrid {
        dims: [7, 6, 5],
        lps_from_index: Transform::from_linear_translation(linear, [-30.0, 12.5, 7.25]),
    };
    let path = dir.path().join("TransformParameters.0.txt");
    elastix::write(&path, &ItkTransform::Affine(affine), &grid).expect("write");
    let back = elastix::read_affine(&path).expect("read back");
    for x in [[0.0, 0.0, 0.0], [50.0, -20.0, 33.0]] {
        let (a, b) = (affine.apply(x), back.apply(x));
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-12), "{a:?} vs {b:?}");
    }
    let text = std::fs::read_to_string(&path).expect("read");
    for line in [
        "(Size 7 6 5)",
        "(Spacing 1.5 2 2.5)",
        "(Origin -30 12.5 7.25)",
        "(Transform \"AffineTransform\")",
        "(CenterOfRotationPoint 10 20 -5)",
    ] {
        assert!(text.lines().any(|l| l == line), "{line} in\n{text}");
    }
    let direction = text.lines().find(|l| l.starts_with("(Direction ")).expect("Direction");
    let d: Vec<f64> = direction
        .trim_start_matches("(Direction ")
        .trim_end_matches(')')
        .split(' ')
        .map(|v| v.parse().expect("num"))
        .collect();
    // Column by column: the first column is index axis i's direction, (cos, sin, 0).
    assert!((d[0] - c).abs() < 1e-15 && (d[1] - s).abs() < 1e-15 && d[2] == 0.0, "{d:?}");
    let mut bad = affine;
    bad.translation[1] = f64::NAN;
    let nan = dir.path().join("nan.txt");
    assert!(elastix::write(&nan, &ItkTransform::Affine(bad), &grid).is_err());
    assert!(!nan.exists());
}

/// A B-spline elastix fitted over its affine and rigid stages (`bspline.txt`, 9³ control points, its coefficients
/// with a seeded bump added) maps where transformix maps: outside the fixed box, where the B-spline ends and the
/// chain is affine, and at voxel centres, where the field it reads as holds T(x) − x in f32 (the bound adds f32's
/// rounding of a displacement of up to 11 mm, 1e-6 mm, to transformix's printed 1e-6).
#[test]
fn a_bspline_over_its_affine_chain_maps_and_samples_where_transformix_does() {
    let r = reference();
    let case = &r["bspline_chain"];
    let path = data_dir().join(case["file"].as_str().expect("file"));
    let chain = elastix::read_transform(&path).expect("read");
    let kinds: Vec<_> = chain.links.iter().map(|l| l.file.file_name().expect("name").to_string_lossy()).collect();
    assert_eq!(kinds, ["rigid.txt", "affine.txt", "bspline.txt"], "the initial transform first");
    let outside = points(&case["outside_lps"]);
    let got: Vec<_> = outside.iter().map(|x| chain.apply(*x)).collect();
    assert!(worst(&got, &points(&case["transformix_outside_lps"])) < 1e-5, "outside the fixed box");

    let field = elastix::read_field(&path).expect("the field");
    assert_eq!(field.dims, [28, 28, 28]);
    let (d, g) = (&field.displacements_lps, &field.lps_from_index);
    let indices = case["indices"].as_array().expect("indices");
    let centres = points(&case["centres_lps"]);
    let mut got = Vec::new();
    for (ijk, x) in indices.iter().zip(&centres) {
        let [i, j, k] = std::array::from_fn(|a| ijk[a].as_u64().expect("index") as usize);
        let at = g.apply_point(warpbench_io::geometry::Point3::new(i as f64, j as f64, k as f64)).coords();
        assert!((0..3).all(|a| (at[a] - x[a]).abs() < 1e-9), "voxel {ijk} is at {x:?}");
        let v = d[(k * 28 + j) * 28 + i];
        got.push([x[0] + f64::from(v[0]), x[1] + f64::from(v[1]), x[2] + f64::from(v[2])]);
    }
    let want = points(&case["transformix_centres_lps"]);
    assert!(worst(&got, &want) < 1e-5, "the field: {} mm from transformix", worst(&got, &want));
    let moved = centres.iter().zip(&want).map(|(x, y)| (0..3).map(|a| (y[a] - x[a]).abs()).fold(0.0, f64::max));
    assert!(moved.fold(0.0, f64::max) > 5.0, "the chain moves the centres by millimetres");
    let read = warpbench_io::displacement::read_field_info(&path).expect("read as any field");
    assert_eq!(read.source, warpbench_io::displacement::FieldSource::ElastixTransform);
    assert_eq!(read.field, field);
}

/// The B-spline over an oblique, anisotropic grid that `data-scripts/elastix_field.py` gave transformix reads as the
/// very field transformix wrote for it (`tests/data/metaimage/transformix_field.mhd`): the same grid, and every
/// vector within f32 rounding of both sides (|D| ≤ 1.6 mm, so 2e-7 mm each; bound 1e-6) — but on the image's first
/// voxel along each axis. The control grid starts exactly one spacing before that voxel, so its centre lies on the
/// edge of the region where the B-spline is defined, and transformix puts it on either side by rounding (D = 0 at
/// some, the spline at others; warpbench takes the edge as inside, as exact arithmetic does): those 168 of 504
/// voxels are a tie, not a test.
#[test]
fn an_oblique_bspline_reads_as_the_field_transformix_wrote_for_it() {
    let ours = elastix::read_field(&data_dir().join("bspline_oblique.txt")).expect("read");
    let (theirs, _) = warpbench_io::displacement::read_field(&data_dir().join("../metaimage/transformix_field.mhd"))
        .expect("transformix's field");
    assert_eq!(ours.dims, theirs.dims);
    let (a, b) = (ours.lps_from_index.linear(), theirs.lps_from_index.linear());
    assert!((a - b).abs().max() < 1e-12, "{a} vs {b}");
    let (a, b) = (ours.lps_from_index.translation(), theirs.lps_from_index.translation());
    assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-12), "{a:?} vs {b:?}");
    let [nx, ny, _] = ours.dims;
    let mut compared = 0;
    let mut err = 0.0f64;
    for (n, (p, q)) in ours.displacements_lps.iter().zip(&theirs.displacements_lps).enumerate() {
        let [i, j, k] = [n % nx, (n / nx) % ny, n / (nx * ny)];
        if i == 0 || j == 0 || k == 0 {
            continue;
        }
        compared += 1;
        err = (0..3).map(|c| f64::from((p[c] - q[c]).abs())).fold(err, f64::max);
    }
    assert_eq!(compared, 336);
    assert!(err < 1e-6, "{err} mm from transformix's field");
    let largest = theirs.displacements_lps.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(largest > 0.5, "the field is not nearly zero: {largest}");
}

/// Deformable files that cannot be read as elastix would apply them are refused, naming the file and the problem;
/// a file without a fixed grid reads as a transform but not as a field.
#[test]
fn bad_deformable_files_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(data_dir().join("bspline_oblique.txt")).expect("read");
    let refused = |name: &str, text: &str, needle: &str| {
        let p = write(dir.path(), name, text);
        let e = elastix::read_field(&p).expect_err(needle).to_string();
        assert!(e.starts_with(&format!("{}: ", p.display())) && e.contains(needle), "{needle:?} in {e}");
    };
    let quadratic = text.replace("(BSplineTransformSplineOrder 3)", "(BSplineTransformSplineOrder 2)");
    refused("quadratic.txt", &quadratic, "only cubic (3) B-splines");
    refused("cyclic.txt", &text.replace("(UseCyclicTransform \"false\")", "(UseCyclicTransform \"true\")"), "cyclic");
    refused("index.txt", &text.replace("(GridIndex 0 0 0)", "(GridIndex 1 0 0)"), "GridIndex");
    refused("small.txt", &text.replace("(GridSize 7 7 7)", "(GridSize 7 3 7)"), "whole numbers ≥ 4");
    refused("count.txt", &text.replace("(GridSize 7 7 7)", "(GridSize 7 7 6)"), "1029 numbers, 882 expected");
    refused("flat.txt", &text.replace("(GridSpacing 6.0 6.0 6.0)", "(GridSpacing 6.0 0 6.0)"), "not positive");
    refused("size.txt", &text.replace("(Size 9 8 7)", "(Size 9 8 0.5)"), "positive whole numbers");
    let no_grid = text.lines().filter(|l| !l.starts_with("(Size ")).collect::<Vec<_>>().join("\n") + "\n";
    refused("no_grid.txt", &no_grid, "no fixed grid");
    assert!(elastix::read_transform(&write(dir.path(), "grid.txt", &no_grid)).is_ok(), "a transform all the same");
    let kernel = "(Transform \"SplineKernelTransform\")\n(SplineKernelType \"ElasticBodySpline\")\n\
                  (FixedImageLandmarks 0 0 0 1 0 0 0 1 0 0 0 1)\n(TransformParameters 0 0 0 1 0 0 0 1 0 0 0 1)\n";
    let p = write(dir.path(), "kernel.txt", kernel);
    let e = elastix::read_transform(&p).expect_err("kernel").to_string();
    assert!(e.contains("only the ThinPlateSpline kernel"), "{e}");
    let p = write(dir.path(), "odd.txt", &kernel.replace("ElasticBodySpline", "ThinPlateSpline").replace(" 1)", ")"));
    let e = elastix::read_transform(&p).expect_err("odd").to_string();
    assert!(e.contains("not a multiple of 3"), "{e}");
    // Four landmarks off one plane interpolate: each maps to its target.
    let four = kernel
        .replace("ElasticBodySpline", "ThinPlateSpline")
        .replace("(TransformParameters 0 0 0 1 0 0 0 1 0 0 0 1)", "(TransformParameters 1 2 3 2 2 3 1 3 3 1 2 4)");
    let t = elastix::read_transform(&write(dir.path(), "four.txt", &four)).expect("four landmarks");
    // From bytes (the fuzzing entry) a file reads as from disk, but a chain cannot be followed.
    let rigid = data_dir().join("rigid.txt");
    let bytes = std::fs::read(&rigid).expect("read");
    assert_eq!(
        elastix::parse_transform(&rigid, &bytes).expect("parse"),
        elastix::read_transform(&rigid).expect("read")
    );
    let affine = data_dir().join("affine.txt");
    let e = elastix::parse_transform(&affine, &std::fs::read(&affine).expect("read")).expect_err("a chain").to_string();
    assert!(e.contains("names the initial transform \"rigid.txt\""), "{e}");
    let e = elastix::parse_transform(&affine, &[0xff, 0xfe, b'(']).expect_err("not UTF-8").to_string();
    assert!(e.contains("not UTF-8"), "{e}");
    let y = t.apply([0.5, 0.25, 0.125]);
    assert!((0..3).all(|a| (y[a] - [1.5, 2.25, 3.125][a]).abs() < 1e-12), "a translation by (1, 2, 3): {y:?}");
}

/// elastix's `DeformationFieldTransform` (`field_nearest.txt`, `field_linear.txt`, made by
/// `data-scripts/elastix_field_transform.py`) over transformix's own field of an oblique 9×8×7 grid maps 120 points
/// where transformix mapped them: points drawn one voxel past the field's grid on every side, so that about half lie
/// outside it (transformix leaves them where they are) and some in the half voxel past the outermost centres (the
/// outermost vectors, held). The bound is transformix's printing, 1e-5 mm; reading a vector off by one voxel, or
/// the wrong interpolation, moves points by tenths of a millimetre (the vectors reach 1.4 mm). At the field's own
/// centres both read back its vectors, and a chain with the file sampled on its grid gives the field.
#[test]
fn deformation_field_transforms_map_points_where_transformix_did() {
    let path = data_dir().join("transformix_field_transform.json");
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("JSON");
    let inputs = points(&r["points_lps"]);
    let files = r["files"].as_array().expect("files");
    let mut outcomes = Vec::new();
    for f in files {
        let file = f["file"].as_str().expect("file");
        let got = maps_as_transformix_did(file, &inputs, &points(&f["transformix_lps"]));
        let still = got.iter().zip(&inputs).filter(|(g, x)| worst(&[**g], &[**x]) == 0.0).count();
        assert!((30..=90).contains(&still), "{file}: {still} of 120 points outside the field, by design about half");
        let e = elastix::read_affine(&data_dir().join(file)).expect_err("not linear").to_string();
        assert!(e.contains("DeformationFieldTransform is not a linear transform"), "{e}");
        let sampled = elastix::read_field(&data_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        outcomes.push((got, sampled));
    }
    let (nearest, linear) = (&outcomes[0], &outcomes[1]);
    assert!(worst(&nearest.0, &linear.0) > 0.05, "the two interpolations differ between centres");
    let field =
        warpbench_io::metaimage::read_displacement_field(&data_dir().join("../metaimage/transformix_field.mhd"))
            .expect("the field");
    for (_, sampled) in [nearest, linear] {
        assert_eq!(sampled.dims, field.dims);
        let off = sampled
            .displacements_lps
            .iter()
            .zip(&field.displacements_lps)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
            .fold(0.0_f32, f32::max);
        assert!(off < 1e-5, "at its own centres the transform is the field's vectors: {off} mm");
    }
}

#[test]
fn bad_deformation_field_transforms_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(data_dir().join("field_linear.txt")).expect("read");
    let field = data_dir().join("../metaimage/transformix_field.mhd");
    let text = text.replace("../metaimage/transformix_field.mhd", &field.display().to_string());
    let refused = |name: &str, text: &str, needle: &str| {
        let p = write(dir.path(), name, text);
        let e = elastix::read_transform(&p).expect_err(needle).to_string();
        assert!(e.starts_with(&format!("{}: ", p.display())) && e.contains(needle), "{needle:?} in {e}");
    };
    assert!(elastix::read_transform(&write(dir.path(), "absolute.txt", &text)).is_ok(), "a field named by its path");
    let order = text.replace("(DeformationFieldInterpolationOrder 1)", "(DeformationFieldInterpolationOrder 3)");
    refused("order.txt", &order, "DeformationFieldInterpolationOrder [3.0] is neither 0 nor 1");
    let unnamed = text.lines().filter(|l| !l.starts_with("(DeformationFieldFileName")).collect::<Vec<_>>().join("\n");
    refused("unnamed.txt", &unnamed, "has no (DeformationFieldFileName …)");
    refused(
        "missing.txt",
        &text.replace("transformix_field.mhd", "nowhere.mhd"),
        "neither beside it nor where it says",
    );
    refused(
        "cosines.txt",
        &text.replace("(UseDirectionCosines \"true\")", "(UseDirectionCosines \"false\")"),
        "UseDirectionCosines \"false\"",
    );
    // A parameter file is not a field, even its own name (which would loop).
    refused("itself.txt", &text.replace(&field.display().to_string(), "itself.txt"), "not a field");
    // A field that is not one: the reader's own message names the field's file.
    let p = write(dir.path(), "volume.txt", &text.replace(&field.display().to_string(), "volume.mha"));
    let volume = data_dir().join("../metaimage/oblique_f32.mha");
    std::fs::copy(&volume, dir.path().join("volume.mha")).expect("copy");
    let e = elastix::read_transform(&p).expect_err("a volume").to_string();
    assert!(e.contains("volume.mha"), "{e}");
    // From bytes there is no file beside to read the field from.
    let e = elastix::parse_transform(&p, text.as_bytes()).expect_err("from bytes").to_string();
    assert!(e.contains("DeformationFieldTransform"), "{e}");
}
