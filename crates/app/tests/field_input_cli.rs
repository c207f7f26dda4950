//! `warpbench warp --field` and `render --field` end to end: a displacement field as the warp, in each flavour.
//!
//! Oracle: `tests/data/itk/field_input_reference.json`, made by `data-scripts/field_input_sitk.py` (SimpleITK 2.5.7,
//! ITK 5.4): `Resample(moving, fixed, DisplacementFieldTransform(field), sitkLinear, 0.0, sitkFloat32)` at every voxel
//! of the fixed grid, through an oblique 9×8×7 DISPVECT field smaller than the fixed grid (so part of the output lies
//! outside the field, where ITK's displacement is zero). The same field written here as ANTs' VECTOR NIfTI and as
//! Slicer's NRRD must give the same output; a forward ("modeling") field, both or neither of --field and landmarks
//! are refused (exit 2).
//!
//! The render test needs a GPU adapter (lavapipe will do); without one it skips, unless REQUIRE_GPU_ADAPTER=1.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{assert_ok, data, utf8 as s, warpbench};
use warpbench_io::Volume;
use warpbench_io::displacement::{FieldDirection, FieldFormat, FieldSource, read_field, write_field, write_field_with};
use warpbench_io::geometry::{Index, Point3, Transform};
use warpbench_io::volume::{GeometrySource, VoxelData};
use warpbench_solver::field::SampledField;
use warpbench_solver::{Fixed, Moving, Warp};

/// The solver's tolerance against ITK's `TransformPoint` on this field (`crates/solver/tests/field_itk.rs`): ITK
/// evaluates in f64 from the same f32 vectors, the geometry goes through the file's f32 sform.
const ITK_TOL_MM: f64 = 1e-4;

fn fixture(name: &str) -> PathBuf {
    data(&format!("itk/field_input_{name}"))
}

fn reference() -> serde_json::Value {
    let text = std::fs::read_to_string(fixture("reference.json")).expect("the reference");
    serde_json::from_str(&text).expect("JSON")
}

fn f32_samples(path: &Path) -> (Vec<f32>, [usize; 3]) {
    let v = warpbench_io::open(path).expect("read the output");
    match v.data {
        VoxelData::F32(d) => (d, v.dims),
        other => panic!("{}: {:?} samples, not f32", path.display(), other.sample_type()),
    }
}

/// The value tolerance that [`ITK_TOL_MM`] of point error allows: the moving volume's trilinear interpolant changes
/// by at most Σₐ max |Δₐ v| / spacingₐ per mm of displacement, plus the f32 rounding of the output (4 ulp).
fn value_tolerance(expected: &[f64]) -> f64 {
    tolerance_for(&fixture("moving.nii.gz"), ITK_TOL_MM, expected)
}

/// What `point_mm` of point error allows in values resampled from the f32 volume at `moving` (see
/// [`value_tolerance`]).
fn tolerance_for(moving: &Path, point_mm: f64, expected: &[f64]) -> f64 {
    let moving = warpbench_io::open(moving).expect("moving");
    let VoxelData::F32(v) = &moving.data else { panic!("the moving fixture is f32") };
    let [nx, ny, nz] = moving.dims;
    let spacing = moving.spacing_mm();
    let mut slope = [0.0f64; 3];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let at = |i: usize, j: usize, k: usize| f64::from(v[i + nx * (j + ny * k)]);
                let here = at(i, j, k);
                let steps = [(i + 1 < nx, (i + 1, j, k)), (j + 1 < ny, (i, j + 1, k)), (k + 1 < nz, (i, j, k + 1))];
                for (a, (ok, (ii, jj, kk))) in steps.into_iter().enumerate() {
                    if ok {
                        slope[a] = slope[a].max((at(ii, jj, kk) - here).abs() / spacing[a]);
                    }
                }
            }
        }
    }
    let largest = expected.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    slope.iter().sum::<f64>() * point_mm + 4.0 * largest * f64::from(f32::EPSILON)
}

/// Runs `warp --field FIELD --exact` (plus `extra`) on the fixtures into `out`; the `--json` report.
fn warp_field(field: &Path, out: &Path, extra: &[&str]) -> (Output, Option<serde_json::Value>) {
    let (fixed, moving) = (fixture("fixed.nii.gz"), fixture("moving.nii.gz"));
    let mut args = vec!["warp", "--fixed", s(&fixed), "--moving", s(&moving), "--field", s(field)];
    args.extend(extra);
    args.extend(["--quiet", "--json", "--out", s(out)]);
    let run = warpbench(&args);
    let report = serde_json::from_slice(&run.stdout).ok();
    (run, report)
}

/// Compares `out` with SimpleITK's resampling voxel by voxel; the largest difference.
fn assert_matches_itk(out: &Path, what: &str) -> f64 {
    let reference = reference();
    let expected: Vec<f64> =
        reference["values"].as_array().expect("values").iter().map(|v| v.as_f64().expect("a number")).collect();
    let dims: Vec<usize> =
        reference["dims"].as_array().expect("dims").iter().map(|d| d.as_u64().expect("a size") as usize).collect();
    let (got, got_dims) = f32_samples(out);
    assert_eq!(got_dims.to_vec(), dims, "{what}: output grid");
    assert_eq!(got.len(), expected.len(), "{what}");
    let tolerance = value_tolerance(&expected);
    let mut worst = (0.0f64, 0usize);
    for (n, (g, e)) in got.iter().zip(&expected).enumerate() {
        let d = (f64::from(*g) - e).abs();
        if d > worst.0 {
            worst = (d, n);
        }
    }
    assert!(
        worst.0 <= tolerance,
        "{what}: voxel {} differs from SimpleITK by {} (tolerance {tolerance}): {} vs {}",
        worst.1,
        worst.0,
        got[worst.1],
        expected[worst.1]
    );
    worst.0
}

#[test]
fn exact_field_warp_matches_simpleitk_in_every_flavour() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The ITK flavour as committed (DISPVECT, RAS vectors), on the CPU.
    let itk_out = dir.path().join("itk.nii.gz");
    let (run, report) = warp_field(&fixture("field.nii.gz"), &itk_out, &["--exact", "--backend", "cpu"]);
    assert_ok(&run);
    let report = report.expect("the --json report");
    assert_eq!(report["schema"], "warpbench-warp/1");
    assert_eq!(report["method"], "field");
    assert_eq!(report["pairs"], 0);
    assert_eq!(report["pullback"], "exact");
    assert_eq!(report["field"], s(&fixture("field.nii.gz")));
    assert_matches_itk(&itk_out, "itk flavour");

    // The reference really reaches outside the field's grid: the output there is the moving volume unwarped, and
    // the field's trilinear interpolation inside. (Both count, or the comparison would test only one rule.)
    let inside = reference()["fixed_voxels_inside_field"].as_u64().expect("count");
    let total: u64 =
        reference()["dims"].as_array().expect("dims").iter().map(|d| d.as_u64().expect("a size")).product();
    assert!(inside > 100 && total - inside > 100, "{inside} of {total} voxels inside the field");

    // The same field as ANTs writes it (VECTOR, LPS), as Slicer's NRRD (resampling) and as transformix's MetaImage
    // (deformationField.mhd + .raw), written by warpbench.
    let (field, format) = read_field(&fixture("field.nii.gz")).expect("read the field");
    assert_eq!(format, FieldSource::Field(FieldFormat::Itk));
    let itk_values = f32_samples(&itk_out).0;
    for (format, name) in [
        (FieldFormat::Ants, "ants1Warp.nii.gz"),
        (FieldFormat::Nrrd, "field.nrrd"),
        (FieldFormat::MetaImage, "deformationField.mhd"),
    ] {
        let path = dir.path().join(name);
        write_field(&path, format, field.dims, &field.lps_from_index, &field.displacements_lps).expect("write");
        assert_eq!(read_field(&path).expect("read back").1, FieldSource::Field(format), "{name} reads as its flavour");
        let out = dir.path().join(format!("{format}.nii.gz"));
        let (run, _) = warp_field(&path, &out, &["--exact", "--backend", "cpu"]);
        assert_ok(&run);
        assert_matches_itk(&out, name);
        // The vectors and the grid are the same numbers in every flavour: so is the output, to the f32 geometry.
        let values = f32_samples(&out).0;
        let most = values.iter().zip(&itk_values).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(f64::from(most) <= value_tolerance(&[300.0]), "{name}: {most} from the ITK flavour's output");
    }

    // The GPU export evaluates the same per-voxel texture (where there is an adapter).
    let gpu_out = dir.path().join("gpu.nii.gz");
    let (run, _) = warp_field(&fixture("field.nii.gz"), &gpu_out, &["--exact", "--backend", "gpu"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    if run.status.code() == Some(1) && stderr.contains("no GPU adapter") {
        assert!(std::env::var_os("REQUIRE_GPU_ADAPTER").is_none(), "no GPU adapter: {stderr}");
    } else {
        assert_ok(&run);
        assert_matches_itk(&gpu_out, "gpu backend");
    }
}

/// `field --field` converts a field between the flavours, sampling it on the output grid: the field on the fixed
/// grid, written in each flavour (ITK, ANTs, Slicer's NRRD, MetaImage, ITK's `.h5`, Learn2Reg's NIfTI form), then
/// applied by `warp --exact`, resamples as SimpleITK does through the original field (the same oracle as above: at
/// fixed voxel centres the sampled field is the original one, trilinearly interpolated, and zero outside its grid).
/// `--direction forward` samples the field's inverse on the moving grid: the original field maps each of its points
/// back, F(y + D(y)) = y, where F is invertible near y. `--tfm` and landmarks are refused beside `--field`.
#[test]
fn field_converts_a_field_between_flavours_as_simpleitk_applies_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, original) = (fixture("fixed.nii.gz"), fixture("moving.nii.gz"), fixture("field.nii.gz"));
    let convert = |out: &Path, extra: &[&str]| {
        let mut args = vec!["field", "--fixed", s(&fixed), "--moving", s(&moving), "--field", s(&original)];
        args.extend(extra);
        args.extend(["--quiet", "--json", "--out", s(out)]);
        warpbench(&args)
    };
    let flavours: [(&str, &[&str]); 6] = [
        ("f.nii.gz", &[]),
        ("a.nii.gz", &["--format", "ants"]),
        ("f.nrrd", &["--format", "nrrd"]),
        ("f.mha", &["--format", "metaimage"]),
        ("f.h5", &[]),
        ("disp.nii.gz", &["--format", "learn2reg"]),
    ];
    for (name, extra) in flavours {
        let out = dir.path().join(name);
        let run = convert(&out, extra);
        assert_ok(&run);
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("field JSON");
        assert_eq!((report["pairs"].as_u64(), report["grid"].as_str()), (Some(0), Some("fixed")), "{name}");
        assert_eq!(report["method"], format!("field {}", s(&original)), "{name}");
        let warped = dir.path().join(format!("warped_{name}.nii.gz"));
        let l2r: &[&str] = if name.starts_with("disp") { &["--field-format", "learn2reg"] } else { &[] };
        let (run, _) = warp_field(&out, &warped, &[l2r, &["--exact", "--backend", "cpu"]].concat());
        assert_ok(&run);
        assert_matches_itk(&warped, name);
    }

    let forward = dir.path().join("forward.nrrd");
    assert_ok(&convert(&forward, &["--direction", "forward", "--format", "nrrd"]));
    let (inverse, _) = read_field(&forward).expect("the forward field");
    let (given, _) = read_field(&original).expect("the field");
    let f = SampledField::<Moving, Fixed>::from_displacement_field(given.clone()).expect("field");
    let grid = given.lps_from_index;
    let d = SampledField::<Fixed, Moving>::from_displacement_field(inverse).expect("its inverse");
    let mut moved = 0.0f64;
    for ijk in [[2.0, 2.0, 2.0], [4.5, 3.0, 3.5], [6.0, 5.0, 4.0], [3.0, 4.0, 2.5]] {
        // Points well inside the field's grid, where F is invertible.
        let y = grid.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let x = d.apply_raw(y);
        let back = f.apply_raw(x);
        moved = moved.max((0..3).map(|a| (x[a] - y[a]).abs()).fold(0.0, f64::max));
        // d is sampled at the moving grid's voxel centres and interpolated between them: its error is the
        // trilinear interpolation of the inverse over a voxel, not the inverse's own tolerance.
        assert!((0..3).all(|a| (back[a] - y[a]).abs() < 0.05), "F(d({y:?})) = {back:?}");
    }
    assert!(moved > 0.2, "the inverse moves the points (at most {moved} mm)");

    for (extra, says) in [
        (&["--tfm", "t.tfm"][..], "is a sampled field, which has none"),
        (&["--landmarks", "pairs.csv"][..], "'--field <FIELD>'"),
    ] {
        let run = convert(&dir.path().join("never.nii.gz"), extra);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(says), "{stderr}");
        assert!(!dir.path().join("never.nii.gz").exists());
    }
}

/// Trilinear interpolation of `v` at the continuous index `c` (every tap inside the grid).
fn trilinear(v: &[f32], dims: [usize; 3], c: [f64; 3]) -> f64 {
    let base: [usize; 3] = std::array::from_fn(|a| (c[a].floor() as usize).min(dims[a] - 2));
    let mut sum = 0.0;
    for corner in 0..8 {
        let mut w = 1.0;
        let mut ijk = [0; 3];
        for a in 0..3 {
            let f = c[a] - base[a] as f64;
            let up = corner >> a & 1 == 1;
            w *= if up { f } else { 1.0 - f };
            ijk[a] = base[a] + usize::from(up);
        }
        sum += w * f64::from(v[ijk[0] + dims[0] * (ijk[1] + dims[1] * ijk[2])]);
    }
    sum
}

#[test]
fn exact_field_warp_on_an_oblique_flipped_output_grid() {
    // `--exact` lays the texture texel on voxel in the output grid's own axes: an output grid that is oblique (the
    // field's own directions) and runs backwards along j checks that, against a brute-force oracle written here (the
    // field's pull-back at each voxel centre, then trilinear interpolation of the moving volume in f64).
    let dir = tempfile::tempdir().expect("tempdir");
    let (field, _) = read_field(&fixture("field.nii.gz")).expect("read the field");
    let field_index_from_index: Transform<Index, Index> =
        Transform::from_scale_translation([0.8, -0.8, 0.8], [1.0, 6.0, 1.0]);
    let lps_from_index = field.lps_from_index * field_index_from_index;
    let dims = [8, 7, 6];
    let reference = dir.path().join("oblique.nii.gz");
    let grid = Volume::new(
        &reference,
        dims,
        VoxelData::U8(vec![0; dims.iter().product()]),
        lps_from_index,
        GeometrySource::NiftiSform { code: 1 },
    )
    .expect("grid");
    warpbench_io::nifti::write(&reference, &grid).expect("write the grid");
    let grid = warpbench_io::open(&reference).expect("read the grid back");
    let out = dir.path().join("oblique_out.nii.gz");
    let (run, _) =
        warp_field(&fixture("field.nii.gz"), &out, &["--exact", "--backend", "cpu", "--reference", s(&reference)]);
    assert_ok(&run);
    let (got, got_dims) = f32_samples(&out);
    assert_eq!(got_dims, dims);

    let pullback = SampledField::<Moving, Fixed>::from_displacement_field(field).expect("field");
    let moving = warpbench_io::open(fixture("moving.nii.gz")).expect("moving");
    let VoxelData::F32(values) = &moving.data else { panic!("the moving fixture is f32") };
    let moving_index_from_lps = moving.lps_from_index.inverse().expect("invertible");
    let mut expected = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let x = grid.lps_from_index.apply_point(Point3::new(i as f64, j as f64, k as f64)).coords();
                assert!(pullback.displacement_raw(x).is_some(), "voxel ({i}, {j}, {k}) lies inside the field");
                let u = pullback.apply_raw(x);
                let c = moving_index_from_lps.apply_point(Point3::from_array(u)).coords();
                assert!((0..3).all(|a| c[a] >= 0.0 && c[a] <= (moving.dims[a] - 1) as f64), "inside the moving volume");
                expected.push(trilinear(values, moving.dims, c));
            }
        }
    }
    let tolerance = value_tolerance(&expected);
    for (n, (g, e)) in got.iter().zip(&expected).enumerate() {
        assert!((f64::from(*g) - e).abs() <= tolerance, "voxel {n}: warpbench {g}, oracle {e} (tolerance {tolerance})");
    }
}

#[test]
fn grid_field_warp_samples_the_field_into_the_control_texture() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("grid.nii.gz");
    let (run, report) = warp_field(&fixture("field.nii.gz"), &out, &["--grid", "64", "--backend", "cpu"]);
    assert_ok(&run);
    assert_eq!(report.expect("report")["pullback"], "grid 64");
    let expected: Vec<f64> =
        reference()["values"].as_array().expect("values").iter().map(|v| v.as_f64().expect("number")).collect();
    let got = f32_samples(&out).0;
    // The texture interpolates across the field's edge, where ITK's displacement jumps to zero, so voxels near the
    // edge differ; most voxels lie a texel or more from it and agree to the texture's interpolation error.
    let mut diffs: Vec<f64> = got.iter().zip(&expected).map(|(g, e)| (f64::from(*g) - e).abs()).collect();
    diffs.sort_by(f64::total_cmp);
    let median = diffs[diffs.len() / 2];
    assert!(median < 0.05, "median difference from SimpleITK {median}");
    let exact = dir.path().join("exact.nii.gz");
    assert_ok(&warp_field(&fixture("field.nii.gz"), &exact, &["--exact", "--backend", "cpu"]).0);
    assert_ne!(f32_samples(&exact).0, got, "--grid and --exact are different evaluations");
}

#[test]
fn render_refuses_a_forward_field_and_both_refuse_both_warps_and_none() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving) = (fixture("fixed.nii.gz"), fixture("moving.nii.gz"));
    let (field, _) = read_field(&fixture("field.nii.gz")).expect("read the field");
    let forward = dir.path().join("forward.nrrd");
    write_field_with(
        &forward,
        FieldFormat::Nrrd,
        FieldDirection::Forward,
        field.dims,
        &field.lps_from_index,
        &field.displacements_lps,
    )
    .expect("write");
    let csv = dir.path().join("pairs.csv");
    common::write_pairs_csv(&csv, &[([0.0; 3], [0.0; 3]); 4]);
    let out = dir.path().join("out.nii.gz");
    let itk_field = fixture("field.nii.gz");
    let base = ["--fixed", s(&fixed), "--moving", s(&moving), "--quiet", "--out", s(&out)];
    let expect_bad = |commands: &[&str], extra: &[&str], needles: &[&str]| {
        for command in commands {
            let mut args = vec![*command];
            args.extend(base);
            args.extend(extra);
            expect_refused(&args, &out, needles);
        }
    };
    let both = ["warp", "render"];
    // warp inverts a forward field (tests/field_input_cli.rs, `a_forward_field_is_inverted…`); render refuses it.
    expect_bad(
        &["render"],
        &["--field", s(&forward)],
        &["forward.nrrd", "forward displacement field", "give the pull-back"],
    );
    let landmarks_too = ["--field", s(&itk_field), "--landmarks", s(&csv)];
    expect_bad(&both, &landmarks_too, &["'--field <FIELD>'", "'--landmarks <LANDMARKS>'"]);
    expect_bad(&both, &["--field", s(&itk_field), "--method", "affine"], &["'--field <FIELD>'", "'--method <METHOD>'"]);
    // Without a warp, render draws the volumes as they are; warp refuses.
    expect_bad(&["warp"], &[], &["give the warp", "--landmarks", "--moving-points", "--field"]);
    let not_a_field = fixture("moving.nii.gz");
    expect_bad(&both, &["--field", s(&not_a_field)], &["field_input_moving.nii.gz"]);
    // Learn2Reg's NIfTI form (an (X, Y, Z, 3) array, nibabel's) is in voxels only when told; an ITK field in mm is not
    // read as one when told it is; --field-format needs --field.
    let form = common::data("learn2reg/disp_nibabel_f32.nii.gz");
    expect_bad(&both, &["--field", s(&form)], &["disp_nibabel_f32.nii.gz", "Learn2Reg", "--field-format learn2reg"]);
    let as_l2r = ["--field", s(&itk_field), "--field-format", "learn2reg"];
    expect_bad(&both, &as_l2r, &["field_input_field.nii.gz", "intent_code 1006", "in mm"]);
    expect_bad(&["render"], &["--field-format", "learn2reg"], &["--field <FIELD>"]);
}

#[test]
fn render_shows_the_moving_volume_through_the_field() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The moving volume as both, so that without a warp the two coincide: the field is what makes them differ.
    let moving = fixture("moving.nii.gz");
    let render = |out: &Path, extra: &[&str]| {
        let mut args = vec!["render", "--fixed", s(&moving), "--moving", s(&moving), "--blend", "moving-only"];
        args.extend(["--slice", "axial", "--quiet", "--out", s(out)]);
        args.extend(extra);
        warpbench(&args)
    };
    let plain = dir.path().join("plain.png");
    let run = render(&plain, &[]);
    if common::failed_for_want_of_a_gpu(&run) {
        return;
    }
    assert_ok(&run);
    let warped = dir.path().join("warped.png");
    assert_ok(&render(&warped, &["--field", s(&fixture("field.nii.gz"))]));
    let (a, b) = (image::open(&plain).expect("png").to_rgba8(), image::open(&warped).expect("png").to_rgba8());
    assert_eq!(a.dimensions(), (16, 16), "an axial slice of the 16³ grid");
    assert_eq!(a.dimensions(), b.dimensions());
    let differing = a.pixels().zip(b.pixels()).filter(|(p, q)| p != q).count();
    // The field covers the middle of the slice (its oblique 27 × 24 × 21 mm grid about (1, −1, 2) mm, in the moving
    // volume's 40 mm box) and leaves the border as it is.
    assert!(differing > 16 && differing < 16 * 16, "{differing} of 256 pixels differ with the field");
    let same_corner = a.get_pixel(0, 0) == b.get_pixel(0, 0);
    assert!(same_corner, "outside the field's grid the warp is the identity");

    // A Learn2Reg field (.npz, steps in voxels) is read against the two volumes: the frame is the one the same
    // pull-back gives written in millimetres as ITK's NIfTI (steps that float16 holds exactly, up to 2 voxels).
    let volume = warpbench_io::open(&moving).expect("the fixture");
    let [nx, ny, _] = volume.dims;
    let steps_vox = (0..volume.dims.iter().product::<usize>())
        .map(|n| [(2.0 * ((n / nx) % ny) as f32 / 15.0).round_ties_even() / 2.0 - 0.5, 0.25, -1.0])
        .collect();
    let steps = warpbench_io::learn2reg::VoxelField { dims: volume.dims, steps_vox };
    let npz = dir.path().join("disp.npz");
    warpbench_io::learn2reg::write_voxel_field(&npz, &steps).expect("npz written");
    let mm = warpbench_io::learn2reg::pullback_from_voxels(
        &npz,
        &steps,
        volume.dims,
        &volume.lps_from_index,
        &volume.lps_from_index,
    )
    .expect("in mm");
    let nifti = dir.path().join("disp.nii.gz");
    write_field(&nifti, FieldFormat::Itk, mm.dims, &mm.lps_from_index, &mm.displacements_lps).expect("written");
    // And in Learn2Reg's NIfTI form, read so when told.
    let form = dir.path().join("disp_0001_0001.nii.gz");
    warpbench_io::learn2reg::write_voxel_field_nifti(&form, &steps, &volume.lps_from_index).expect("written");
    let pngs = ["npz.png", "nifti.png", "form.png"].map(|name| dir.path().join(name));
    assert_ok(&render(&pngs[0], &["--field", s(&npz)]));
    assert_ok(&render(&pngs[1], &["--field", s(&nifti)]));
    assert_ok(&render(&pngs[2], &["--field", s(&form), "--field-format", "learn2reg"]));
    let [c, d, e] = pngs.map(|p| image::open(&p).expect("png").to_rgba8());
    assert!(c == d && e == d, "Learn2Reg's forms show as the same field in mm");
    assert!(c != a, "the field moves the volume");
}

/// A forward field (`field --direction forward`, NRRD `modeling`) is inverted by `warp` (scattered-data
/// interpolation, `solver::invert`) into the pull-back ũ it resamples with. Resampling the ramps v(x) = 500 + x_a
/// (one per axis a) is exact under trilinear interpolation, so the three outputs give ũ(x) itself at every voxel;
/// the forward map d (`points --from moving`, exact) must bring ũ(x) back to x within what the report's inverse
/// consistency ‖d(ũ(y)) − y‖ and the field's own interpolation of d (2 mm voxels) allow.
#[test]
fn a_forward_field_is_inverted_into_the_pullback_and_its_consistency_reported() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = common::mri();
    let pairs = common::data("itk/field_pairs.csv");
    let mri = warpbench_io::open(&fixed).expect("the MRI");
    let [nx, ny, nz] = mri.dims;
    let centre = |i: usize, j: usize, k: usize| {
        mri.lps_from_index.apply_point(warpbench_io::geometry::Point3::new(i as f64, j as f64, k as f64)).coords()
    };
    let ramp = |axis: usize| -> PathBuf {
        let mut samples = Vec::with_capacity(nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    samples.push((500.0 + centre(i, j, k)[axis]) as f32);
                }
            }
        }
        let path = dir.path().join(format!("ramp{axis}.nii"));
        let v = warpbench_io::Volume::new(
            &path,
            mri.dims,
            warpbench_io::VoxelData::F32(samples),
            mri.lps_from_index,
            warpbench_io::GeometrySource::NiftiSform { code: 1 },
        )
        .expect("volume");
        warpbench_io::nifti::write(&path, &v).expect("write the ramp");
        path
    };
    let ramps = [ramp(0), ramp(1), ramp(2)];

    let forward = dir.path().join("forward.nrrd");
    let run = warpbench(&[
        "field",
        "--fixed",
        s(&fixed),
        "--moving",
        s(&ramps[0]),
        "--landmarks",
        s(&pairs),
        "--direction",
        "forward",
        "--format",
        "nrrd",
        "--out",
        s(&forward),
        "--quiet",
    ]);
    assert_eq!(run.status.code(), Some(0), "{}", String::from_utf8_lossy(&run.stderr));
    let mut consistency_max = 0.0;
    let mut u_tilde: Vec<Vec<f32>> = Vec::new();
    for (axis, moving) in ramps.iter().enumerate() {
        let out = dir.path().join(format!("out{axis}.nii"));
        let args = [
            "warp",
            "--fixed",
            s(&fixed),
            "--moving",
            s(moving),
            "--field",
            s(&forward),
            "--exact",
            "--float",
            "--backend",
            "cpu",
            "--json",
            "--quiet",
            "--out",
            s(&out),
        ];
        let run = warpbench(&args);
        assert_eq!(run.status.code(), Some(0), "{}", String::from_utf8_lossy(&run.stderr));
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("the report");
        let c = &report["inverse_consistency_mm"];
        consistency_max = c["max_mm"].as_f64().expect("max_mm");
        assert!(c["rms_mm"].as_f64().expect("rms_mm") <= consistency_max && consistency_max < 0.05, "{c}");
        assert!(c["points"].as_u64().expect("points") > 1000);
        u_tilde.push(f32_samples(&out).0.into_iter().map(|v| v - 500.0).collect());
    }
    // ũ(x) at every 6th voxel of the inner region (20 mm from the box's faces), then d(ũ(x)) by `points`.
    let (mut xs, mut us) = (Vec::new(), Vec::new());
    for k in (10..nz - 10).step_by(6) {
        for j in (10..ny - 10).step_by(6) {
            for i in (10..nx - 10).step_by(6) {
                let v = i + nx * (j + ny * k);
                xs.push(centre(i, j, k));
                us.push([0, 1, 2].map(|a| f64::from(u_tilde[a][v])));
            }
        }
    }
    let list = dir.path().join("u.csv");
    let lines: Vec<String> = us.iter().map(|u| format!("{},{},{}", u[0], u[1], u[2])).collect();
    std::fs::write(&list, lines.join("\n") + "\n").expect("write");
    let back = dir.path().join("d_of_u.csv");
    let run = warpbench(&[
        "points",
        "--fixed",
        s(&fixed),
        "--moving",
        s(&ramps[0]),
        "--landmarks",
        s(&pairs),
        "--from",
        "moving",
        "--in",
        s(&list),
        "--out",
        s(&back),
        "--quiet",
    ]);
    assert_eq!(run.status.code(), Some(0), "{}", String::from_utf8_lossy(&run.stderr));
    let text = std::fs::read_to_string(&back).expect("read");
    let (mut worst, mut moved) = (0.0f64, 0.0f64);
    for ((line, x), u) in text.lines().zip(&xs).zip(&us) {
        let y: Vec<f64> = line.split(',').map(|v| v.parse().expect("a number")).collect();
        worst = worst.max((0..3).map(|a| (y[a] - x[a]).powi(2)).sum::<f64>().sqrt());
        moved = moved.max((0..3).map(|a| (u[a] - x[a]).powi(2)).sum::<f64>().sqrt());
    }
    assert_eq!(text.lines().count(), xs.len());
    assert!(moved > 3.0, "the inverse moves points ({moved} mm)");
    // The field holds d sampled on 2 mm voxels and interpolated linearly (3e-3 mm on these pairs,
    // data-scripts/field_formats_ref.py); f32 outputs of ~500 add 1e-4 mm.
    let bound = consistency_max + 0.01;
    assert!(worst <= bound, "d(ũ(x)) is {worst} mm from x (bound {bound} mm)");
}

/// An elastix transform parameter file is a field too: `warp --field` on elastix's B-spline over its affine and rigid
/// stages (`tests/data/elastix/bspline.txt`, made by `data-scripts/elastix_transforms.py` with itk-elastix 0.25.4)
/// resamples the moving blobs onto the fixed grid as transformix did with linear interpolation
/// (`transformix_bspline_result.nii.gz`). The field holds T(x) − x at the output's own voxel centres in f32, so the
/// point error is f32's rounding of displacements up to 11 mm (1e-6 mm; allowed 1e-5).
#[test]
fn warp_takes_an_elastix_transform_file_as_transformix_applies_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let blobs = data("elastix/moving_blobs.nii.gz");
    let transform = data("elastix/bspline.txt");
    let out = dir.path().join("out.nii.gz");
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&blobs),
        "--moving",
        s(&blobs),
        "--field",
        s(&transform),
        "--exact",
        "--quiet",
        "--json",
        "--out",
        s(&out),
    ]);
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert_eq!(report["method"], "field");
    assert_eq!(report["field"], s(&transform));
    let theirs = warpbench_io::open(data("elastix/transformix_bspline_result.nii.gz")).expect("transformix's");
    let VoxelData::F32(expected) = &theirs.data else { panic!("transformix wrote float") };
    let expected: Vec<f64> = expected.iter().map(|v| f64::from(*v)).collect();
    let (got, dims) = f32_samples(&out);
    assert_eq!(dims, theirs.dims);
    let tolerance = tolerance_for(&blobs, 1e-5, &expected);
    let worst = got.iter().zip(&expected).map(|(g, e)| (f64::from(*g) - e).abs()).fold(0.0, f64::max);
    assert!(worst <= tolerance, "{worst} from transformix's output (tolerance {tolerance})");
    // Not the identity: the chain moves the blobs by millimetres.
    let (unwarped, _) = f32_samples(&blobs);
    let moved = unwarped.iter().zip(&expected).map(|(u, e)| (f64::from(*u) - e).abs()).fold(0.0, f64::max);
    assert!(moved > 100.0 * tolerance, "the warp changes the image: {moved}");
}

/// 3D Slicer's grid transform saved in its modeling direction (`itk/h5_field_slicer_inverse.h5`: SimpleITK's
/// `h5_field.h5` under Slicer's `InverseDisplacementFieldTransform`, `data-scripts/slicer_transforms.py`) is a
/// forward field: `points --from moving --field` maps SimpleITK's 40 points in and around its grid as SimpleITK's
/// `TransformPoint` maps them through the plain file, which is Slicer's map from the moving space to the fixed one.
/// The bound is the f32 rounding of the vectors (under 10 mm: 1e-6 mm each, a few summed by the trilinear weights).
#[test]
fn slicers_inverse_field_maps_moving_points_as_itk_maps_them_through_the_field() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(data("itk/h5_reference.json")).expect("reference");
    let reference: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let case = reference["cases"].as_array().expect("cases").iter().find(|c| c["file"] == "h5_field.h5").expect("case");
    let xyz = |v: &serde_json::Value| -> Vec<[f64; 3]> {
        v.as_array()
            .expect("points")
            .iter()
            .map(|p| std::array::from_fn(|a| p[a].as_f64().expect("a number")))
            .collect()
    };
    let (points, want) = (xyz(&case["points"]), xyz(&case["transformed"]));
    let list = dir.path().join("points.csv");
    let lines: Vec<String> = points.iter().map(|p| format!("{:?},{:?},{:?}", p[0], p[1], p[2])).collect();
    std::fs::write(&list, lines.join("\n") + "\n").expect("write");
    let out = dir.path().join("mapped.csv");
    let volume = data("nifti/avg152T1_LR_nifti.nii");
    let field = data("itk/h5_field_slicer_inverse.h5");
    // The field under no landmarks: a window session holding it, as the window saves one.
    let session = dir.path().join("slicer.warpbench.json");
    let mut doc = common::session_json(&volume, &volume);
    doc["field"] = s(&field).into();
    std::fs::write(&session, doc.to_string()).expect("write the session");
    let run = warpbench(&[
        "points",
        "--fixed",
        s(&volume),
        "--moving",
        s(&volume),
        "--session",
        s(&session),
        "--from",
        "moving",
        "--in",
        s(&list),
        "--out",
        s(&out),
        "--quiet",
    ]);
    assert_ok(&run);
    let text = std::fs::read_to_string(&out).expect("read");
    let got: Vec<[f64; 3]> = text
        .lines()
        .map(|l| std::array::from_fn(|a| l.split(',').nth(a).expect("x,y,z").parse().expect("a number")))
        .collect();
    assert_eq!(got.len(), want.len());
    let mut moved = 0;
    for ((g, w), p) in got.iter().zip(&want).zip(&points) {
        let diff = (0..3).map(|a| (g[a] - w[a]).abs()).fold(0.0, f64::max);
        assert!(diff < 1e-5, "{p:?} went to {g:?}, SimpleITK {w:?}");
        moved += usize::from((0..3).any(|a| (w[a] - p[a]).abs() > 0.1));
    }
    assert!(moved > 10, "the field moves most points ({moved} of {})", points.len());
}

/// `info` describes a displacement field instead of refusing it as a volume: the ITK fixture's grid is where
/// SimpleITK puts its voxels (the reference's probes, continuous index to physical point), NumPy's Learn2Reg file
/// has NumPy's shape and largest step in voxels, and an `.h5` composite states its direction.
#[test]
fn info_describes_a_displacement_field_of_any_flavour() {
    let info = |path: &Path| -> serde_json::Value {
        let run = warpbench(&["info", "--json", "--quiet", s(path)]);
        assert_ok(&run);
        serde_json::from_slice(&run.stdout).expect("info JSON")
    };
    let itk = info(&fixture("field.nii.gz"));
    assert_eq!((itk["kind"].as_str(), itk["format"].as_str()), (Some("displacement_field"), Some("itk")), "{itk}");
    assert_eq!((itk["direction"].clone(), itk["units"].as_str()), (serde_json::Value::Null, Some("mm")));
    assert_eq!(itk["dims"], serde_json::json!([9, 8, 7]));
    let m: Vec<Vec<f64>> = serde_json::from_value(itk["lps_from_index"].clone()).expect("a matrix");
    let mut largest_probe = 0.0f64;
    for probe in reference()["probes"].as_array().expect("probes") {
        let ijk: Vec<f64> = serde_json::from_value(probe["index"].clone()).expect("index");
        let x: Vec<f64> = serde_json::from_value(probe["x"].clone()).expect("x");
        let tx: Vec<f64> = serde_json::from_value(probe["T(x)"].clone()).expect("T(x)");
        for r in 0..3 {
            let got = m[r][0] * ijk[0] + m[r][1] * ijk[1] + m[r][2] * ijk[2] + m[r][3];
            // The sform is stored in f32: its rounding at |x| < 20 mm.
            assert!((got - x[r]).abs() < 1e-5, "row {r} at {ijk:?}: {got} vs SimpleITK's {}", x[r]);
        }
        largest_probe = largest_probe.max((0..3).map(|a| (tx[a] - x[a]).powi(2)).sum::<f64>().sqrt());
    }
    let largest = itk["max_displacement"].as_f64().expect("a number");
    assert!(largest >= largest_probe - 1e-5 && largest < 10.0, "{largest} against the probes' {largest_probe}");

    let npz = info(&data("learn2reg/disp_f16.npz"));
    assert_eq!((npz["format"].as_str(), npz["units"].as_str()), (Some("learn2reg"), Some("voxels")), "{npz}");
    assert_eq!(
        (npz["dims"].clone(), npz["lps_from_index"].clone()),
        (serde_json::json!([5, 4, 2]), serde_json::Value::Null)
    );
    let numpy: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("learn2reg/reference.json")).expect("reference"))
            .expect("JSON");
    let steps: Vec<Vec<Vec<Vec<f64>>>> = serde_json::from_value(numpy["disp"].clone()).expect("disp");
    let numpy_largest =
        steps.iter().flatten().flatten().map(|d| d.iter().map(|c| c * c).sum::<f64>().sqrt()).fold(0.0, f64::max);
    assert!((npz["max_displacement"].as_f64().expect("a number") - numpy_largest).abs() < 1e-6, "{npz}");

    // Learn2Reg's NIfTI form says nothing of being a field: a volume of 3 frames, with where it is read as a field.
    let run = warpbench(&["info", "--quiet", s(&data("learn2reg/disp_nibabel_f32.nii.gz"))]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("3 frames") && stderr.contains("--field-format learn2reg"), "{stderr}");

    let h5 = info(&data("itk/h5_composite_slicer_inverse.h5"));
    assert_eq!((h5["format"].as_str(), h5["direction"].as_str()), (Some("itk_h5"), Some("pullback")), "{h5}");
    assert_eq!(h5["dims"], serde_json::json!([8, 7, 6]));
}

/// `--initial-field` puts a field under the landmark warp, as a session's field lies under it: with no pairs it alone
/// is the warp, and `warp --exact` resamples as SimpleITK does through it (the oracle above); with pairs whose moving
/// points lie up to 2.5 mm off the field's own map, the TPS (λ = 0) is fitted after the field has acted, so each
/// fixed landmark still maps onto its moving partner (which the field alone would miss).
#[test]
fn initial_field_lies_under_the_landmarks() {
    let (dir, none) = no_pairs();
    let (fixed, moving, field_path) = (fixture("fixed.nii.gz"), fixture("moving.nii.gz"), fixture("field.nii.gz"));
    let out = dir.path().join("alone.nii.gz");
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&fixed),
        "--moving",
        s(&moving),
        "--initial-field",
        s(&field_path),
        "--landmarks",
        s(&none),
        "--exact",
        "--backend",
        "cpu",
        "--quiet",
        "--json",
        "--out",
        s(&out),
    ]);
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert!(report["method"].as_str().expect("method").contains("field_input_field.nii.gz alone"), "{report}");
    assert_matches_itk(&out, "--initial-field with no pairs");

    // Pairs on top: fixed points inside the field, moving points off the field's map by a few mm.
    let (field, _) = read_field(&field_path).expect("read the field");
    let u: SampledField<Moving, Fixed> = SampledField::from_displacement_field(field).expect("field");
    let fixed_points = [[-6.0, 4.0, 3.0], [5.0, -3.0, -2.0], [2.0, 6.0, -5.0], [-4.0, -5.0, 4.0], [0.5, 0.5, 0.5]];
    let shifts = [[2.0, 0.0, 0.0], [0.0, -1.5, 0.5], [0.0, 0.0, 2.5], [-1.0, 1.0, 0.0], [0.0, 0.0, 0.0]];
    let pairs: Vec<([f64; 3], [f64; 3])> = fixed_points
        .iter()
        .zip(&shifts)
        .map(|(q, d)| {
            let p = u.apply_raw(*q);
            ([p[0] + d[0], p[1] + d[1], p[2] + d[2]], *q)
        })
        .collect();
    let csv = dir.path().join("pairs.csv");
    common::write_pairs_csv(&csv, &pairs);
    let targets = dir.path().join("targets.csv");
    let lines: Vec<String> = fixed_points.iter().map(|q| format!("{},{},{}", q[0], q[1], q[2])).collect();
    std::fs::write(&targets, lines.join("\n")).expect("write");
    let mapped = dir.path().join("mapped.csv");
    let run = warpbench(&[
        "points",
        "--fixed",
        s(&fixed),
        "--moving",
        s(&moving),
        "--initial-field",
        s(&field_path),
        "--landmarks",
        s(&csv),
        "--from",
        "fixed",
        "--in",
        s(&targets),
        "--out",
        s(&mapped),
        "--quiet",
    ]);
    assert_ok(&run);
    let text = std::fs::read_to_string(&mapped).expect("mapped points");
    for (line, (p, q)) in text.lines().zip(&pairs) {
        let got: Vec<f64> = line.split(',').take(3).map(|v| v.parse().expect("mm")).collect();
        let off = (0..3).map(|a| (got[a] - p[a]).powi(2)).sum::<f64>().sqrt();
        assert!(off < 1e-6, "u({q:?}) = {got:?}, not its partner {p:?} ({off} mm)");
    }
}

/// `--initial-field-format learn2reg` reads Learn2Reg's NIfTI form (an (X, Y, Z, 3) array of voxel steps) under the
/// landmarks as `--field-format learn2reg` reads it as the whole warp: `points` maps fixed points through it, with
/// pairs on top, as through the same steps in an `.npz` and as through the pull-back they state written in
/// millimetres as ITK's NIfTI (steps that float16 holds exactly, so all three hold the same field). Without the flag
/// the form is refused, exit 2, and the message names the flag.
#[test]
fn initial_field_format_reads_learn2regs_nifti_form_under_the_landmarks() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving) = (fixture("fixed.nii.gz"), fixture("moving.nii.gz"));
    let (f, m) = (warpbench_io::open(&fixed).expect("fixed"), warpbench_io::open(&moving).expect("moving"));
    let [nx, ny, _] = f.dims;
    let steps_vox = (0..f.dims.iter().product::<usize>())
        .map(|n| [0.25, (2.0 * ((n % nx) as f32) / 15.0).round_ties_even() / 2.0 - 0.5, ((n / nx) % ny) as f32 / 8.0])
        .collect();
    let steps = warpbench_io::learn2reg::VoxelField { dims: f.dims, steps_vox };
    let npz = dir.path().join("disp_0001_0002.npz");
    warpbench_io::learn2reg::write_voxel_field(&npz, &steps).expect("npz written");
    let form = dir.path().join("disp_0001_0002.nii.gz");
    warpbench_io::learn2reg::write_voxel_field_nifti(&form, &steps, &f.lps_from_index).expect("written");
    let mm = warpbench_io::learn2reg::pullback_from_voxels(&npz, &steps, f.dims, &f.lps_from_index, &m.lps_from_index)
        .expect("in mm");
    let itk = dir.path().join("disp_mm.nii.gz");
    write_field(&itk, FieldFormat::Itk, mm.dims, &mm.lps_from_index, &mm.displacements_lps).expect("written");
    // Two pairs on top, and points inside the fixed box.
    let csv = dir.path().join("pairs.csv");
    common::write_pairs_csv(&csv, &[([1.0, 2.0, -1.0], [0.0, 1.0, 0.0]), ([-3.0, 0.5, 2.0], [-4.0, 0.0, 3.0])]);
    let targets = dir.path().join("targets.csv");
    std::fs::write(&targets, "0,0,0\n-5,3,2\n4,-4,-3\n2.5,1.5,-6\n").expect("write");
    let mapped = |field: &Path, extra: &[&str], name: &str| {
        let out = dir.path().join(name);
        let mut args = vec!["points", "--fixed", s(&fixed), "--moving", s(&moving), "--initial-field", s(field)];
        args.extend(extra);
        args.extend(["--landmarks", s(&csv), "--from", "fixed", "--in", s(&targets), "--out", s(&out), "--quiet"]);
        assert_ok(&warpbench(&args));
        std::fs::read_to_string(&out).expect("mapped points")
    };
    let from_npz = mapped(&npz, &[], "npz.csv");
    let from_form = mapped(&form, &["--initial-field-format", "learn2reg"], "form.csv");
    let from_mm = mapped(&itk, &[], "mm.csv");
    assert_eq!(from_form, from_npz, "the NIfTI form and the .npz hold the same steps");
    for (a, b) in from_form.lines().zip(from_mm.lines()) {
        let parse = |l: &str| l.split(',').take(3).map(|v| v.parse::<f64>().expect("mm")).collect::<Vec<_>>();
        let (a, b) = (parse(a), parse(b));
        // The millimetre file's geometry goes through NIfTI's f32 sform.
        let off = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
        assert!(off < ITK_TOL_MM, "{a:?} against {b:?} through the field in mm ({off} mm)");
    }
    assert_ne!(from_form.lines().next(), Some("0,0,0"), "the field moves the points");
    let out = dir.path().join("refused.csv");
    let args = ["points", "--fixed", s(&fixed), "--moving", s(&moving), "--initial-field", s(&form), "--landmarks"];
    let mut args = args.to_vec();
    args.extend([s(&csv), "--from", "fixed", "--in", s(&targets), "--out", s(&out), "--quiet"]);
    expect_refused(&args, &out, &["disp_0001_0002.nii.gz", "Learn2Reg", "--initial-field-format learn2reg"]);
    // The flag means nothing without the field.
    let args = ["points", "--fixed", s(&fixed), "--moving", s(&moving), "--initial-field-format", "learn2reg"];
    let mut args = args.to_vec();
    args.extend(["--landmarks", s(&csv), "--from", "fixed", "--in", s(&targets), "--out", s(&out), "--quiet"]);
    expect_refused(&args, &out, &["--initial-field <FIELD>"]);
}

/// `--initial-field` is refused where it means nothing or cannot be read, exit 2, naming the file: beside `--field`
/// (which is the whole warp) or `--session` (which carries its own), in `render` without landmarks, and for a
/// Learn2Reg `.npz` whose shape is not the fixed volume's.
#[test]
fn initial_field_refusals() {
    let (dir, csv) = no_pairs();
    let (fixed, moving, field) = (fixture("fixed.nii.gz"), fixture("moving.nii.gz"), fixture("field.nii.gz"));
    let out = dir.path().join("out.nii.gz");
    let base = ["--fixed", s(&fixed), "--moving", s(&moving), "--quiet", "--out", s(&out)];
    // A Learn2Reg field is read against the volumes given: one of another shape is refused.
    let npz = dir.path().join("disp_0001_0002.npz");
    let steps = warpbench_io::learn2reg::VoxelField { dims: [4, 4, 4], steps_vox: vec![[0.5, 0.0, 0.0]; 64] };
    warpbench_io::learn2reg::write_voxel_field(&npz, &steps).expect("npz written");
    let cases: [(&str, Vec<&str>, &[&str]); 4] = [
        ("warp", vec!["--field", s(&field), "--initial-field", s(&field)], &["'--initial-field <FIELD>'"]),
        ("render", vec!["--initial-field", s(&field)], &["field_input_field.nii.gz", "give landmarks too"]),
        ("warp", vec!["--initial-field", s(&npz), "--landmarks", s(&csv)], &["disp_0001_0002.npz", "shape"]),
        ("field", vec!["--session", s(&csv), "--initial-field", s(&field)], &["'--initial-field <FIELD>'"]),
    ];
    for (command, extra, needles) in cases {
        let mut args = vec![command];
        args.extend(base);
        args.extend(extra);
        expect_refused(&args, &out, needles);
    }
}

/// A temporary folder holding a landmark file of no pairs, `none.csv`, beside which the `--initial-field` runs write.
fn no_pairs() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    let none = dir.path().join("none.csv");
    common::write_pairs_csv(&none, &[]);
    (dir, none)
}

/// Runs warpbench with `args`, which must exit 2 with each of `needles` on stderr and write nothing at `out`.
fn expect_refused(args: &[&str], out: &Path, needles: &[&str]) {
    let run = warpbench(args);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{args:?}: {stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{args:?}: {stderr:?} lacks {needle:?}");
    }
    assert!(!out.exists(), "a refused run wrote {}", out.display());
}

/// An FSL FNIRT warp, read against its reference (`--fixed`) and input (`--moving`), end to end: `field` writes the
/// pull-back that takes every reference voxel where fslpy 3.29.1 takes it (`tests/data/fnirt/reference.json`, made
/// by `data-scripts/fnirt_fixtures.py`) and says how it read a deformation field; `warp` resamples through it;
/// `info` tells what the file is; a fixed volume that is not the warp's reference is refused with exit 2, naming the
/// file.
#[test]
fn an_fnirt_warp_is_read_against_its_reference_and_input() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("fnirt/reference.json")).expect("reference")).expect("JSON");
    let src = data("fnirt/src.nii.gz");
    // `warpbench field` with FNIRT's reference as the fixed volume and `warp` under it.
    let field = |fixed: &Path, warp: &Path, out: &Path, extra: &[&str]| {
        let mut args = vec!["field", "--fixed", s(fixed), "--moving", s(&src), "--field", s(warp), "--out", s(out)];
        args.extend(extra);
        warpbench(&args)
    };
    for (name, inferred) in
        [("coef_neuro.nii.gz", None), ("coef_radio.nii.gz", None), ("field_abs.nii.gz", Some("absolute"))]
    {
        let case = &reference["warps"][name];
        let fixed = data(&format!("fnirt/{}.nii.gz", case["reference"].as_str().expect("a name")));
        let out = tmp.path().join("u.nii.gz");
        let run = field(&fixed, &data(&format!("fnirt/{name}")), &out, &["--force"]);
        assert_ok(&run);
        let stderr = String::from_utf8_lossy(&run.stderr);
        match inferred {
            Some(kind) => assert!(stderr.contains(&format!("read as {kind} positions")), "{name}: {stderr}"),
            None => assert!(!stderr.contains("warning"), "{name}: {stderr}"),
        }
        let (written, _) = read_field(&out).expect("read the output");
        let volume = warpbench_io::open(&fixed).expect("the reference");
        let mut worst = 0.0f64;
        for (v, want) in
            reference["voxels"].as_array().expect("voxels").iter().zip(case["moving_lps"].as_array().expect("points"))
        {
            let ijk: Vec<usize> =
                v.as_array().expect("a voxel").iter().map(|c| c.as_u64().expect("index") as usize).collect();
            let x = volume.voxel_lps(ijk[0], ijk[1], ijk[2]).coords();
            let d = written.displacements_lps[ijk[0] + written.dims[0] * (ijk[1] + written.dims[1] * ijk[2])];
            for c in 0..3 {
                worst = worst.max((x[c] + f64::from(d[c]) - want[c].as_f64().expect("a number")).abs());
            }
        }
        // The NIfTI output keeps float32 vectors of up to ~60 mm, in RAS: a few ULPs.
        assert!(worst < 1e-4, "{name}: {worst} mm from fslpy");
    }
    let warped = tmp.path().join("w.nii.gz");
    let (fixed, coef) = (data("fnirt/ref_neuro.nii.gz"), data("fnirt/coef_neuro.nii.gz"));
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&fixed),
        "--moving",
        s(&src),
        "--field",
        s(&coef),
        "--out",
        s(&warped),
        "--json",
    ]);
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("the report");
    assert_eq!(report["method"], "field", "{report}");
    assert_eq!(warpbench_io::open(&warped).expect("the output").dims, [20, 24, 18]);
    let info = warpbench(&["info", "--json", s(&coef)]);
    assert_ok(&info);
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).expect("JSON");
    assert_eq!((&info["kind"], &info["format"]), (&"displacement_field".into(), &"fnirt".into()), "{info}");
    // The input as the reference: not the grid the coefficients were made over.
    let run = field(&src, &coef, &tmp.path().join("x.nii.gz"), &[]);
    assert_eq!(run.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("coef_neuro.nii.gz") && stderr.contains("fnirt's --ref"), "{stderr}");
    assert!(!tmp.path().join("x.nii.gz").exists());

    // Written back as FNIRT's relative field (`--format fnirt`): the same warp, read against the same pair.
    let written = tmp.path().join("fnirt.nii.gz");
    let run = field(&fixed, &coef, &written, &["--format", "fnirt", "--json"]);
    assert_ok(&run);
    let summary: serde_json::Value = serde_json::from_slice(&run.stdout).expect("the summary");
    assert_eq!(summary["format"], "fnirt", "{summary}");
    let volume = |p: &Path| warpbench_io::open(p).expect("volume");
    let (f, m) = (volume(&fixed), volume(&src));
    let pullback = |w: &Path| {
        warpbench_io::fnirt::read_pullback(w, (f.dims, &f.lps_from_index), (m.dims, &m.lps_from_index))
            .unwrap_or_else(|e| panic!("{e}"))
            .field
            .displacements_lps
    };
    let worst = pullback(&written)
        .iter()
        .zip(pullback(&coef))
        .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0f32, f32::max))
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "{worst} mm");
    // FNIRT's field is a NIfTI pull-back: another name or the forward map exits 2 before any work.
    for (out, extra) in [("w.nrrd", &[][..]), ("fwd.nii.gz", &["--direction", "forward"][..])] {
        let out = tmp.path().join(out);
        let run = field(&fixed, &coef, &out, &[&["--format", "fnirt"][..], extra].concat());
        assert_eq!(run.status.code(), Some(2), "{extra:?}");
        assert!(String::from_utf8_lossy(&run.stderr).contains("--format fnirt"), "{extra:?}");
        assert!(!out.exists());
    }
}

#[test]
fn an_afni_warp_is_read_as_its_pullback_and_described() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("afni_made/reference.json")).expect("reference"))
            .expect("JSON");
    for (stem, case) in reference["warps"].as_object().expect("warps") {
        // A volume on the warp's own grid as the fixed one, so the output's voxels are the warp's.
        let warp = data(&format!("afni_made/{stem}.HEAD"));
        let read = warpbench_io::displacement::read_field_info(&warp).expect("the warp");
        let n = read.field.displacements_lps.len();
        let grid = Volume::new(
            &warp,
            read.field.dims,
            VoxelData::U8(vec![0; n]),
            read.field.lps_from_index,
            GeometrySource::Afni,
        )
        .expect("a grid");
        let fixed = tmp.path().join("fixed.nii.gz");
        warpbench_io::write_volume(&fixed, &grid).expect("write");
        // `field` on the warp's own grid, in a flavour.
        let convert = |format: &str, out: &Path| {
            let run = warpbench(&[
                "field",
                "--fixed",
                s(&fixed),
                "--moving",
                s(&fixed),
                "--field",
                s(&warp),
                "--format",
                format,
                "--out",
                s(out),
            ]);
            assert_ok(&run);
        };
        let out = tmp.path().join(format!("{stem}_ants.nii.gz"));
        convert("ants", &out);
        let (written, _) = read_field(&out).expect("read the output");
        let mut worst = 0.0f64;
        let voxels = case["voxels"].as_array().expect("voxels");
        let points = case["nitransforms_lps"].as_array().expect("points");
        for (v, want) in voxels.iter().zip(points) {
            let ijk: Vec<usize> =
                v.as_array().expect("a voxel").iter().map(|c| c.as_u64().expect("index") as usize).collect();
            let x = grid.voxel_lps(ijk[0], ijk[1], ijk[2]).coords();
            let d = written.displacements_lps[ijk[0] + written.dims[0] * (ijk[1] + written.dims[1] * ijk[2])];
            for c in 0..3 {
                worst = worst.max((x[c] + f64::from(d[c]) - want[c].as_f64().expect("a number")).abs());
            }
        }
        // The NIfTI grid is stored in float32: a few ULPs of the coordinates.
        assert!(worst < 1e-4, "{stem}: {worst} mm from nitransforms");
        // Written back for AFNI: the same vectors, in AFNI's NIfTI form (as the fixture made by nibabel is).
        let afni = tmp.path().join(format!("{stem}_WARP.nii.gz"));
        convert("afni", &afni);
        let again = warpbench_io::displacement::read_field_info(&afni).expect("the AFNI field");
        assert_eq!(again.source.name(), "afni");
        assert_eq!(again.field.displacements_lps, read.field.displacements_lps, "{stem}");
        let info = warpbench(&["info", "--json", s(&warp)]);
        assert_ok(&info);
        let info: serde_json::Value = serde_json::from_slice(&info.stdout).expect("JSON");
        assert_eq!((&info["kind"], &info["format"]), (&"displacement_field".into(), &"afni".into()), "{info}");
    }
    // AFNI's other datasets are volumes: one sub-brick chosen with --frame.
    let dataset = data("afni/example4d+orig.HEAD");
    let info = warpbench(&["info", "--json", "--frame", "2", s(&dataset)]);
    assert_ok(&info);
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).expect("JSON");
    assert_eq!(
        (&info["kind"], &info["format"], &info["description"]),
        (&"volume".into(), &"afni".into(), &"#2".into()),
        "{info}"
    );
    // AFNI's own names: a bare dataset name with a sub-brick selector as --fixed, a warp by its bare name as --field.
    let warped = tmp.path().join("w.nii.gz");
    let fixed = data("afni/example4d+orig[0]");
    let bare_warp = data("afni_made/warp_rai+tlrc");
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&fixed),
        "--moving",
        s(&fixed),
        "--field",
        s(&bare_warp),
        "--out",
        s(&warped),
    ]);
    assert_ok(&run);
    assert_eq!(warpbench_io::open(&warped).expect("the output").dims, [33, 41, 25]);
    // Without --frame, the choice is asked for in AFNI's words (no Learn2Reg hint for its 3 sub-bricks).
    let info = warpbench(&["info", s(&dataset)]);
    assert_eq!(info.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&info.stderr);
    assert!(
        stderr.contains("an AFNI dataset of 3 sub-bricks: choose one with --frame N") && !stderr.contains("Learn2Reg"),
        "{stderr}"
    );
    // ...and refused as a field, naming the file and its labels.
    let out = tmp.path().join("x.nii.gz");
    let fixed = data("afni/scaled+tlrc.HEAD");
    let run =
        warpbench(&["field", "--fixed", s(&fixed), "--moving", s(&fixed), "--field", s(&dataset), "--out", s(&out)]);
    assert_eq!(run.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("example4d+orig.HEAD") && stderr.contains("not a 3dQwarp warp"), "{stderr}");
    assert!(!out.exists());
}
