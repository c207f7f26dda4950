//! `warpbench warp` end to end, on real fixtures: identity landmarks give back the input; a rigid landmark set on
//! the CT reproduces the rigidly resampled CT (against a brute-force f64 trilinear resampling written here); the GPU
//! and the CPU backends write the same file; `--out-dicom` writes a series our reader reads back; refusals. And the
//! in-memory core the window calls, `warp::resample`, makes the very file the command writes, and stops when asked.

mod common;

use std::path::{Path, PathBuf};

use common::{assert_ok, data, utf8 as s, warpbench, write_pairs_csv as write_pairs};

use warpbench_app::exit::Failure;
use warpbench_app::inputs::Names;
use warpbench_app::project::field_file::FieldFile;
use warpbench_app::project::stack::Layers;
use warpbench_app::warp::{self, Backend, PullBackMode, WarpSettings};
use warpbench_gpu::export::{Interpolation, Progress};
use warpbench_io::landmarks::read_bigwarp_csv;
use warpbench_io::volume::VoxelData;
use warpbench_solver::method::Method;

#[test]
fn identity_landmarks_give_back_the_input_on_both_backends() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let points = [[0.0, 18.0, 18.0], [40.0, 18.0, 18.0], [-40.0, 30.0, 0.0], [0.0, 70.0, 40.0], [10.0, -40.0, 18.0]];
    let pairs: Vec<_> = points.iter().map(|q| (*q, *q)).collect();
    let csv = dir.path().join("identity.csv");
    write_pairs(&csv, &pairs);
    let input = warpbench_io::open(&mri).expect("read the fixture");
    for backend in ["cpu", "gpu"] {
        let out = dir.path().join(format!("same_{backend}.nii.gz"));
        let run = warpbench(&[
            "warp",
            "--fixed",
            s(&mri),
            "--moving",
            s(&mri),
            "--landmarks",
            s(&csv),
            "--backend",
            backend,
            "--quiet",
            "--json",
            "--out",
            s(&out),
        ]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        if backend == "gpu" && run.status.code() == Some(1) && stderr.contains("no GPU adapter") {
            assert!(std::env::var_os("REQUIRE_GPU_ADAPTER").is_none(), "no GPU adapter: {stderr}");
            continue;
        }
        assert_ok(&run);
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("the --json report");
        assert_eq!(report["schema"], "warpbench-warp/1");
        assert!(report["backend"].as_str().is_some_and(|b| b.starts_with(backend)), "{report}");
        // The stages' seconds are measured and add up to at most the total.
        let stage = |k: &str| report["seconds"][k].as_f64().unwrap_or(f64::NAN);
        let stages: f64 = ["load", "fit", "resample", "write"].iter().map(|k| stage(k)).sum();
        assert!(stage("resample") > 0.0 && stage("load") > 0.0 && stages <= stage("total") + 1e-6, "{report}");
        let output = warpbench_io::open(&out).expect("read the output");
        assert_eq!(output.dims, input.dims);
        assert!(output.lps_from_index.max_abs_diff(&input.lps_from_index) < 1e-6, "geometry changed");
        assert_eq!(output.data, input.data, "{backend}: identity landmarks changed the voxels");
    }
}

/// Brute-force trilinear sample of `v` (f64) at continuous index `s`, clamp-to-edge, or None outside
/// −½ ≤ s ≤ n − ½.
fn trilinear(v: &warpbench_io::Volume, s: [f64; 3]) -> Option<f64> {
    if (0..3).any(|a| s[a] < -0.5 || s[a] > v.dims[a] as f64 - 0.5) {
        return None;
    }
    let c: Vec<f64> = (0..3).map(|a| s[a].clamp(0.0, v.dims[a] as f64 - 1.0)).collect();
    let i0: Vec<usize> = c.iter().map(|x| x.floor() as usize).collect();
    let f: Vec<f64> = c.iter().zip(&i0).map(|(x, i)| x - *i as f64).collect();
    let mut acc = 0.0;
    for corner in 0..8 {
        let mut w = 1.0;
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let hi = corner >> a & 1 == 1;
            idx[a] = if hi { (i0[a] + 1).min(v.dims[a] - 1) } else { i0[a] };
            w *= if hi { f[a] } else { 1.0 - f[a] };
        }
        acc += w * v.data.get_f64(v.offset(idx[0], idx[1], idx[2]));
    }
    Some(acc)
}

#[test]
fn a_rigid_landmark_set_reproduces_the_rigidly_resampled_ct() {
    let dir = tempfile::tempdir().expect("tempdir");
    let ct_path = data("nifti/cranium_ct.nii.gz");
    let ct = warpbench_io::open(&ct_path).expect("read the CT");
    // u(x) = R (x − c) + c + t: 8° about S through the CT's centre c, then t = (5, −3, 2) mm.
    let c = [0.0, 0.0, 0.0];
    let (sin, cos) = 8f64.to_radians().sin_cos();
    let t = [5.0, -3.0, 2.0];
    let u = |x: [f64; 3]| {
        let d = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
        [cos * d[0] - sin * d[1] + c[0] + t[0], sin * d[0] + cos * d[1] + c[1] + t[1], d[2] + c[2] + t[2]]
    };
    let fixed_points = [
        [-60.0, -60.0, -40.0],
        [60.0, -50.0, -30.0],
        [50.0, 60.0, -20.0],
        [-50.0, 50.0, 10.0],
        [0.0, 0.0, 40.0],
        [30.0, -20.0, 50.0],
        [-20.0, 30.0, -50.0],
        [10.0, 10.0, 0.0],
    ];
    let pairs: Vec<_> = fixed_points.iter().map(|q| (u(*q), *q)).collect();
    let csv = dir.path().join("rigid.csv");
    write_pairs(&csv, &pairs);
    let out = dir.path().join("rigid.nii.gz");
    assert_ok(&warpbench(&[
        "warp",
        "--fixed",
        s(&ct_path),
        "--moving",
        s(&ct_path),
        "--landmarks",
        s(&csv),
        "--method",
        "rigid",
        "--exact",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        s(&out),
    ]));
    let warped = warpbench_io::open(&out).expect("read the output");
    assert!(matches!(warped.data, VoxelData::I16(_)), "the CT's sample type is kept");
    let index_from_lps = ct.lps_from_index.inverse().expect("invertible");
    let (mut compared, mut worst, mut off) = (0usize, 0.0f64, 0usize);
    for k in (0..ct.dims[2]).step_by(3) {
        for j in (0..ct.dims[1]).step_by(5) {
            for i in (0..ct.dims[0]).step_by(5) {
                let x = ct.voxel_lps(i, j, k).coords();
                let s_idx = index_from_lps.apply_point(warpbench_io::geometry::Point3::from_array(u(x))).coords();
                // Skip voxels within 1e-3 voxel of the inside boundary (where f32 rounding may decide either way).
                let near_edge = (0..3)
                    .any(|a| (s_idx[a] + 0.5).abs() < 1e-3 || (s_idx[a] - (ct.dims[a] as f64 - 0.5)).abs() < 1e-3);
                if near_edge {
                    continue;
                }
                let expected = trilinear(&ct, s_idx).unwrap_or(-1024.0).round_ties_even().clamp(-32768.0, 32767.0);
                let got = warped.data.get_f64(warped.offset(i, j, k));
                let d = (got - expected).abs();
                worst = worst.max(d);
                off += usize::from(d > 1.0);
                compared += 1;
            }
        }
    }
    eprintln!("{compared} voxels compared: worst |warp − reference| = {worst} HU, {off} differ by more than 1 HU");
    assert!(compared > 50_000, "too few voxels compared: {compared}");
    // The rigid fit is exact on noise-free pairs up to ~1e-10 mm, and the export evaluates in f32 (~1e-5 voxel):
    // only rounding ties (x.5 HU) can differ, by 1.
    assert!(worst <= 1.0, "the warp differs from the rigid resampling by {worst} HU");
}

/// Five pairs of a shift by (2, −1, 3) mm inside the MRI fixture, written as `shift.csv` in `dir`.
fn shift_pairs(dir: &Path) -> PathBuf {
    let q = [[0.0, 18.0, 18.0], [40.0, 18.0, 18.0], [-40.0, 30.0, 0.0], [0.0, 70.0, 40.0], [10.0, -40.0, 18.0]];
    let pairs: Vec<_> = q.iter().map(|q| ([q[0] + 2.0, q[1] - 1.0, q[2] + 3.0], *q)).collect();
    let csv = dir.join("shift.csv");
    write_pairs(&csv, &pairs);
    csv
}

#[test]
fn writes_a_dicom_series_and_refuses_bad_requests() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let csv = shift_pairs(dir.path());
    let out = dir.path().join("shift.nii");
    let dcm = dir.path().join("series");
    assert_ok(&warpbench(&[
        "warp",
        "--fixed",
        s(&mri),
        "--moving",
        s(&mri),
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
    let nii = warpbench_io::open(&out).expect("read the NIfTI");
    let series = warpbench_io::open(&dcm).expect("read the DICOM series");
    // The series may order its axes differently (slices along the normal of the image plane), so compare the same
    // LPS points: every voxel centre of the series is a voxel centre of the NIfTI with the same value.
    assert_eq!(series.dims.iter().product::<usize>(), nii.dims.iter().product::<usize>());
    let nii_index_from_lps = nii.lps_from_index.inverse().expect("invertible");
    for k in 0..series.dims[2] {
        for j in (0..series.dims[1]).step_by(3) {
            for i in (0..series.dims[0]).step_by(3) {
                let idx = nii_index_from_lps.apply_point(series.voxel_lps(i, j, k)).coords();
                let r = idx.map(f64::round);
                assert!(idx.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-3), "({i}, {j}, {k}) is not a voxel centre");
                let (a, b, c) = (r[0] as usize, r[1] as usize, r[2] as usize);
                let (want, got) = (nii.data.get_f64(nii.offset(a, b, c)), series.data.get_f64(series.offset(i, j, k)));
                assert!((want - got).abs() < 1e-9, "voxel ({i}, {j}, {k}): DICOM {got}, NIfTI {want}");
            }
        }
    }

    let expect_bad = |args: &[&str], needle: &str| {
        let run = warpbench(args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr:?} lacks {needle:?}");
    };
    let m = s(&mri);
    let l = s(&csv);
    let fresh = dir.path().join("fresh.nii.gz");
    let f = s(&fresh);
    expect_bad(
        &["warp", "--fixed", m, "--moving", m, "--landmarks", l, "--method", "hbspline", "--exact", "-q", "--out", f],
        "--exact",
    );
    expect_bad(
        &["warp", "--fixed", m, "--moving", m, "--landmarks", l, "-q", "--out", s(&dir.path().join("x.png"))],
        "--out must end in .nii, .nii.gz, .nrrd, .mha, .mhd, .mgh, .mgz, .mnc or .ome.zarr",
    );
    expect_bad(&["warp", "--fixed", m, "--moving", m, "--landmarks", l, "-q", "--out", s(&out)], "exists; use --force");
    expect_bad(
        &["warp", "--fixed", m, "--moving", m, "--landmarks", l, "-q", "--out", m],
        "refusing to overwrite an input",
    );
    expect_bad(&["warp", "--fixed", m, "--moving", m, "-q", "--out", f], "--landmarks");
    expect_bad(
        &["warp", "--fixed", m, "--moving", m, "--landmarks", l, "-q", "--out", f, "--out-dicom", s(&dcm)],
        "new or empty folder",
    );
    assert!(!fresh.exists(), "a refused run wrote its output");
}

#[test]
fn writes_the_volume_in_the_format_its_name_says() {
    // The same warp written as NIfTI, NRRD and MetaImage (.mha with its samples compressed, .mhd with a .raw) reads
    // back to the same voxels and geometry; and a MetaImage input is read like any other.
    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let csv = shift_pairs(dir.path());
    let warp_to = |moving: &Path, out: &Path| {
        assert_ok(&warpbench(&[
            "warp",
            "--fixed",
            s(&mri),
            "--moving",
            s(moving),
            "--landmarks",
            s(&csv),
            "--method",
            "affine",
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            s(out),
        ]));
        warpbench_io::open(out).expect("read the output")
    };
    let reference = warp_to(&mri, &dir.path().join("out.nii.gz"));
    for name in ["out.mha", "out.mhd", "out.nrrd", "OUT.MHA"] {
        let out = dir.path().join(name);
        let v = warp_to(&mri, &out);
        assert_eq!(v.data, reference.data, "{name}");
        assert!(v.lps_from_index.max_abs_diff(&reference.lps_from_index) < 1e-4, "{name}: geometry");
    }
    assert!(dir.path().join("out.raw").is_file(), "the .mhd's data file");
    // A .mhd whose data file exists is refused without --force, like the header itself.
    std::fs::write(dir.path().join("taken.raw"), "keep me").expect("write");
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&mri),
        "--moving",
        s(&mri),
        "--landmarks",
        s(&csv),
        "--method",
        "affine",
        "--quiet",
        "--out",
        s(&dir.path().join("taken.mhd")),
    ]);
    assert_eq!(run.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("taken.raw: exists; use --force") && stderr.contains("the data file of"), "{stderr}");
    assert_eq!(std::fs::read_to_string(dir.path().join("taken.raw")).expect("read"), "keep me");
    assert!(!dir.path().join("taken.mhd").exists());
    let header = std::fs::read_to_string(dir.path().join("out.mhd")).expect("header");
    assert!(header.ends_with("ElementDataFile = out.raw\n"), "{header}");

    // The warped volume as the moving one, read from MetaImage: the same as from NIfTI.
    let from_mha = warp_to(&dir.path().join("out.mha"), &dir.path().join("again.nii.gz"));
    let from_nii = warp_to(&dir.path().join("out.nii.gz"), &dir.path().join("again2.nii.gz"));
    assert_eq!(from_mha.data, from_nii.data);

    // OME-Zarr: the samples stored along +L, +P, +S, each voxel where the NIfTI has it; read as the moving volume, it
    // warps as the NIfTI does; an existing store is replaced only with --force.
    let zarr = dir.path().join("out.ome.zarr");
    let v = warp_to(&mri, &zarr);
    assert_same_voxels_in_space(&reference, &v);
    let from_zarr = warp_to(&zarr, &dir.path().join("again3.nii.gz"));
    assert_eq!(from_zarr.data, from_nii.data);
    // The warped volume warped again (so shifted twice) replaces the store.
    let shifted = dir.path().join("out.nii.gz");
    let warp_shifted = |out: &Path, force: bool| {
        let mut args = vec!["warp", "--fixed", s(&mri), "--moving", s(&shifted), "--landmarks", s(&csv)];
        args.extend(["--method", "affine", "--backend", "cpu", "--quiet", "--out", s(out)]);
        args.extend(force.then_some("--force"));
        warpbench(&args)
    };
    let run = warp_shifted(&zarr, false);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("out.ome.zarr: exists; use --force"));
    assert_ok(&warp_shifted(&zarr, true));
    assert_ne!(from_nii.data, reference.data);
    // A folder of anything else is refused up front, with --force too, and kept.
    let notes = dir.path().join("notes.ome.zarr");
    std::fs::create_dir(&notes).expect("mkdir");
    std::fs::write(notes.join("mine.txt"), "keep").expect("write");
    let run = warp_shifted(&notes, true);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("a folder that warpbench does not replace"));
    assert_eq!(std::fs::read_to_string(notes.join("mine.txt")).expect("kept"), "keep");
    assert_same_voxels_in_space(&from_nii, &warpbench_io::open(&zarr).expect("read"));
}

/// Asserts that every voxel centre of `a` is a voxel centre of `b` (to 1e-6 of a voxel) holding the same value.
fn assert_same_voxels_in_space(a: &warpbench_io::Volume, b: &warpbench_io::Volume) {
    let b_index_from_lps = b.lps_from_index.inverse().expect("invertible");
    let [ni, nj, nk] = a.dims;
    for (i, j, k) in (0..nk).flat_map(|k| (0..nj).flat_map(move |j| (0..ni).map(move |i| (i, j, k)))) {
        let at = b_index_from_lps.apply_point(a.voxel_lps(i, j, k)).coords();
        let index = at.map(f64::round);
        assert!(at.iter().zip(&index).all(|(x, r)| (x - r).abs() < 1e-6), "({i}, {j}, {k}) lands at {at:?}");
        let [x, y, z] = index.map(|v| v as usize);
        assert!(x < b.dims[0] && y < b.dims[1] && z < b.dims[2], "({i}, {j}, {k}) lands outside");
        let (got, want) = (b.data.get_f64(b.offset(x, y, z)), a.data.get_f64(a.offset(i, j, k)));
        assert!(got.to_bits() == want.to_bits(), "({i}, {j}, {k}): {got} != {want}");
    }
}

/// Pairs on the MRI fixture: fixed points inside the brain, moving points shifted by (2, −1, 3) mm plus a few mm of
/// local deformation, so the TPS is not affine.
fn deformed_pairs(dir: &Path) -> PathBuf {
    let q = [
        [0.0, 18.0, 18.0],
        [40.0, 18.0, 18.0],
        [-40.0, 30.0, 0.0],
        [0.0, 70.0, 40.0],
        [10.0, -40.0, 18.0],
        [0.0, 18.0, -20.0],
    ];
    let local = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-1.5, 0.0, 1.0], [0.0, 0.0, -2.0], [1.0, 1.0, 0.0], [0.0; 3]];
    let pairs: Vec<_> =
        q.iter().zip(local).map(|(q, l)| ([q[0] + 2.0 + l[0], q[1] - 1.0 + l[1], q[2] + 3.0 + l[2]], *q)).collect();
    let csv = dir.join("deformed.csv");
    write_pairs(&csv, &pairs);
    csv
}

fn names(moving: &Path, csv: &Path, out: &Path) -> Names {
    Names { moving: moving.display().to_string(), landmarks: csv.display().to_string(), out: out.to_path_buf() }
}

#[test]
fn the_in_memory_core_makes_the_file_the_command_writes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let csv = deformed_pairs(dir.path());
    let volume = warpbench_io::open(&mri).expect("read the fixture");
    let pairs = read_bigwarp_csv(&csv).expect("read the pairs");
    // A control texture with linear interpolation (the defaults), and the exact TPS with cubic interpolation to f32.
    let cases: [(&[&str], WarpSettings); 2] = [
        (
            &["--grid", "24"],
            WarpSettings {
                method: Method::Tps { stiffness: 0.0 },
                pullback: PullBackMode::Grid(24),
                interpolation: Interpolation::Trilinear,
                float: false,
                backend: Backend::Cpu,
                outside_value: None,
            },
        ),
        (
            &["--exact", "--interp", "cubic", "--float", "--outside", "-7.5"],
            WarpSettings {
                method: Method::Tps { stiffness: 0.0 },
                pullback: PullBackMode::Exact,
                interpolation: Interpolation::CatmullRom,
                float: true,
                backend: Backend::Cpu,
                outside_value: Some(-7.5),
            },
        ),
    ];
    for (n, (extra, settings)) in cases.iter().enumerate() {
        let from_cli = dir.path().join(format!("cli_{n}.nii"));
        let mut args = vec!["warp", "--fixed", s(&mri), "--moving", s(&mri), "--landmarks", s(&csv), "--method", "tps"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--backend", "cpu", "--quiet", "--json", "--out", s(&from_cli)]);
        let run = warpbench(&args);
        assert_ok(&run);
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("the --json report");

        let from_core = dir.path().join(format!("core_{n}.nii"));
        let mut calls = 0usize;
        let resampled = warp::resample(
            &volume,
            &volume,
            &volume,
            (&pairs, &Layers::default()),
            &names(&mri, &csv, &from_core),
            settings,
            &mut |p: Progress| {
                calls += 1;
                assert!(p.slices_done <= p.slices_total && p.slices_total == volume.dims[2], "{p:?}");
                true
            },
        )
        .expect("resample in memory");
        assert!(calls > 1, "progress is reported per slab: {calls} calls");
        let description = warp::series_description(&resampled.method, &mri);
        warp::write_outputs(&resampled.volume, &from_core, None, &description, None).expect("write");
        let (cli_bytes, core_bytes) =
            (std::fs::read(&from_cli).expect("CLI file"), std::fs::read(&from_core).expect("core file"));
        assert!(cli_bytes == core_bytes, "case {n}: the core's file differs from the command's");

        // What the report says is what the core says.
        assert_eq!(report["method"], resampled.method.as_str());
        assert_eq!(report["pairs"], resampled.pairs);
        assert_eq!(report["pullback"], resampled.pullback.as_str());
        assert_eq!(report["interpolation"], resampled.interpolation);
        assert_eq!(report["backend"], resampled.backend.as_str());
        assert_eq!(report["outside_value"], resampled.outside_value);
        assert_eq!(report["dtype"], resampled.volume.sample_type().name());
        assert_eq!(resampled.volume.modality, volume.modality);
        assert_eq!(resampled.volume.lps_from_index, volume.lps_from_index);
        // The warp moves voxels: the comparison is not between two copies of the input.
        assert!(resampled.volume.data != volume.data || settings.float, "case {n}: nothing moved");
    }
}

#[test]
fn the_in_memory_core_stops_when_progress_says_so() {
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let volume = warpbench_io::open(&mri).expect("read the fixture");
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = deformed_pairs(dir.path());
    let pairs = read_bigwarp_csv(&csv).expect("read the pairs");
    let settings = WarpSettings {
        method: Method::Tps { stiffness: 0.0 },
        pullback: PullBackMode::Grid(16),
        interpolation: Interpolation::Trilinear,
        float: false,
        backend: Backend::Cpu,
        outside_value: None,
    };
    // Stop at the first report, and at the second (after a slab was done).
    for stop_at in [1, 2] {
        let mut calls = 0usize;
        let result = warp::resample(
            &volume,
            &volume,
            &volume,
            (&pairs, &Layers::default()),
            &names(&mri, &csv, &dir.path().join("never.nii")),
            &settings,
            &mut |_: Progress| {
                calls += 1;
                calls < stop_at
            },
        );
        match result {
            Err(Failure::Cancelled(e)) => {
                assert!(format!("{e:#}").contains("cancelled"), "{e:#}");
            }
            Err(other) => panic!("stop at {stop_at}: {:#}", other.error()),
            Ok(_) => panic!("stop at {stop_at}: a cancelled resampling returned a volume"),
        }
        assert_eq!(calls, stop_at, "no progress call after the one that said stop");
    }
    assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 1, "only the pairs: nothing was written");
}

/// `warp` with identity pairs at five voxel centres of `grid` (the fixed volume as read: not coplanar, inside both
/// boxes when both sides are the same file), `extra` choosing the parts. Returns the run and the output's path.
fn warp_identity(
    dir: &Path,
    name: &str,
    grid: &warpbench_io::Volume,
    [fixed, moving]: [&Path; 2],
    extra: &[&str],
) -> (std::process::Output, PathBuf) {
    let out = dir.join(format!("{name}.nii.gz"));
    let mut args = vec!["warp", "--fixed", s(fixed), "--moving", s(moving)];
    args.extend_from_slice(extra);
    let csv = dir.join(format!("{name}.csv"));
    args.extend_from_slice(&["--landmarks", s(&csv), "--quiet", "--out", s(&out)]);
    let [ni, nj, nk] = grid.dims.map(|n| n - 1);
    let corners = [[0, 0, 0], [ni, 0, 0], [0, nj, 0], [0, 0, nk], [ni / 2, nj / 2, nk / 2]];
    let pairs: Vec<_> = corners
        .iter()
        .map(|&[i, j, k]| {
            let x = grid.voxel_lps(i, j, k).coords();
            (x, x)
        })
        .collect();
    write_pairs(&csv, &pairs);
    (warpbench(&args), out)
}

#[test]
fn a_4d_input_is_read_by_the_frame_chosen_for_its_side() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bold = data("nifti/functional.nii");
    let frame = |t: usize| warpbench_io::LoadOptions::new().frame(t).open(&bold).expect("the fixture's frame");
    // Without a choice: refused with the option that chooses, for the side at fault.
    let (result, out) = warp_identity(dir.path(), "none", &frame(0), [&bold, &bold], &[]);
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(
        err.contains(
            "functional.nii: 4-D file with 20 frames: this command reads one 3-D volume; choose one with \
                      --fixed-frame N (N from 0 to 19)"
        ),
        "{err}"
    );
    assert!(!out.exists());
    let (result, _) = warp_identity(dir.path(), "moving", &frame(0), [&bold, &bold], &["--fixed-frame", "3"]);
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("choose one with --moving-frame N (N from 0 to 19)"), "{err}");
    // Chosen: identity pairs give the chosen frame back, voxel for voxel.
    let (result, out) =
        warp_identity(dir.path(), "three", &frame(0), [&bold, &bold], &["--fixed-frame", "3", "--moving-frame", "3"]);
    assert_ok(&result);
    let warped = warpbench_io::open(&out).expect("the output");
    assert_eq!(warped.data, frame(3).data);
    assert_ne!(frame(3).data, frame(4).data, "the fixture's frames differ");
    // A frame past the last, a series of a file, and a frame of a one-volume format are refused, naming the file.
    for (extra, words) in [
        (["--fixed-frame", "3", "--moving-frame", "20"], "frame 20 is out of range: the file has 20 frame(s)"),
        (["--fixed-frame", "3", "--moving-series", "1.2.3"], "a DICOM series was chosen, but this is not DICOM"),
    ] {
        let (result, out) = warp_identity(dir.path(), "bad", &frame(0), [&bold, &bold], &extra);
        assert_eq!(result.status.code(), Some(2), "{extra:?}");
        let err = String::from_utf8_lossy(&result.stderr);
        assert!(err.contains("functional.nii") && err.contains(words), "{extra:?}: {err}");
        assert!(!out.exists());
    }
    let nrrd = data("nrrd/").read_dir().expect("the NRRD fixtures").map(|e| e.expect("entry").path());
    let nrrd = nrrd.filter(|p| p.extension().is_some_and(|e| e == "nrrd")).find(|p| warpbench_io::open(p).is_ok());
    let nrrd = nrrd.expect("a NRRD volume");
    let (result, _) = warp_identity(
        dir.path(),
        "nrrd",
        &warpbench_io::open(&nrrd).expect("NRRD"),
        [&nrrd, &nrrd],
        &["--moving-frame", "1"],
    );
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("frame 1 is out of range: the file has 1 frame"), "{err}");
    // Both options for one side are a usage error.
    let (result, _) = warp_identity(
        dir.path(),
        "both",
        &frame(0),
        [&bold, &bold],
        &["--fixed-frame", "3", "--fixed-series", "1.2.3"],
    );
    assert_eq!(result.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&result.stderr).contains("cannot be used with"));
}

#[test]
fn a_session_gives_the_volumes_and_the_frames_the_window_read() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bold = data("nifti/functional.nii");
    let frame = |t: usize| warpbench_io::LoadOptions::new().frame(t).open(&bold).expect("the fixture's frame");
    let grid = frame(0);
    let [ni, nj, nk] = grid.dims.map(|n| n - 1);
    let landmarks: Vec<_> = [[0, 0, 0], [ni, 0, 0], [0, nj, 0], [0, 0, nk], [ni / 2, nj / 2, nk / 2]]
        .iter()
        .enumerate()
        .map(|(n, &[i, j, k])| {
            let x = grid.voxel_lps(i, j, k).coords();
            serde_json::json!({"name": format!("Pt-{n}"), "active": true, "moving_lps": x, "fixed_lps": x})
        })
        .collect();
    // A session as the window saves one after "Choose a frame": the file, and frame 3 of it on both sides.
    let session = dir.path().join("bold.warpbench.json");
    let mut doc = common::session_json(&bold, &bold);
    doc["fixed_part"] = serde_json::json!({"frame": 3});
    doc["moving_part"] = serde_json::json!({"frame": 3});
    doc["landmarks"] = landmarks.into();
    std::fs::write(&session, doc.to_string()).expect("write the session");
    let warp = |name: &str, volumes: &[&str]| {
        let out = dir.path().join(format!("{name}.nii.gz"));
        let mut args = vec!["warp", "--session", s(&session)];
        args.extend_from_slice(volumes);
        args.extend_from_slice(&["--out", s(&out)]);
        (warpbench(&args), out)
    };
    // The session's frame on both sides, said on stderr.
    let (result, out) = warp("session", &["--fixed", s(&bold), "--moving", s(&bold)]);
    assert_ok(&result);
    assert_eq!(warpbench_io::open(&out).expect("the output").data, frame(3).data);
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(
        err.contains(
            "functional.nii: reading frame 3, as the session did (--moving-frame or --moving-series chooses another)"
        ),
        "{err}"
    );
    assert!(err.contains("--fixed-frame or --fixed-series chooses another"), "{err}");
    // The command line's choice wins, side by side: frame 4 of the moving file on frame 3's grid.
    let (result, out) = warp("four", &["--fixed", s(&bold), "--moving", s(&bold), "--moving-frame", "4", "--quiet"]);
    assert_ok(&result);
    assert!(result.stderr.is_empty(), "{}", String::from_utf8_lossy(&result.stderr));
    assert_eq!(warpbench_io::open(&out).expect("the output").data, frame(4).data);
    assert_ne!(frame(3).data, frame(4).data, "the fixture's frames differ");
    // Another file than the session's takes nothing from it: the same file by another name is still the session's.
    let copy = dir.path().join("copy.nii");
    std::fs::copy(&bold, &copy).expect("copy");
    let (result, out) = warp("other", &["--fixed", s(&copy), "--moving", s(&bold), "--quiet"]);
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("copy.nii: 4-D file with 20 frames") && err.contains("--fixed-frame N"), "{err}");
    assert!(!out.exists());
    let relative = bold.parent().expect("folder").join("../nifti/functional.nii");
    let (result, out) = warp("relative", &["--fixed", s(&relative), "--moving", s(&bold), "--quiet"]);
    assert_ok(&result);
    assert_eq!(warpbench_io::open(&out).expect("the output").data, frame(3).data);
    // Without --fixed and --moving the session's volumes are read, each with its frame, and stderr says which.
    let (result, out) = warp("both", &[]);
    assert_ok(&result);
    assert_eq!(warpbench_io::open(&out).expect("the output").data, frame(3).data);
    let err = String::from_utf8_lossy(&result.stderr);
    for side in ["fixed", "moving"] {
        let said =
            format!("bold.warpbench.json: the {side} volume is {}, frame 3, as the session read it", bold.display());
        assert!(err.contains(&said), "{err}");
    }
    // One side given, the other the session's: the copy's frame 4 as the grid, the session's frame 3 resampled.
    let (result, out) = warp("one", &["--fixed", s(&copy), "--fixed-frame", "4", "--quiet"]);
    assert_ok(&result);
    assert_eq!(warpbench_io::open(&out).expect("the output").data, frame(3).data);
    // A session of the demo pair names no files.
    let demo = dir.path().join("demo.warpbench.json");
    doc["fixed"] = serde_json::Value::Null;
    doc["moving"] = serde_json::Value::Null;
    std::fs::write(&demo, doc.to_string()).expect("write the session");
    let out = dir.path().join("demo.nii.gz");
    let result = warpbench(&["warp", "--session", s(&demo), "--moving", s(&bold), "--out", s(&out)]);
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("demo.warpbench.json: the session shows the demo pair, which has no files"), "{err}");
    assert!(!out.exists());
    // Without a session both are required, as before.
    let result = warpbench(&["warp", "--moving", s(&bold), "--landmarks", s(&session), "--out", s(&out)]);
    assert_eq!(result.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&result.stderr).contains("--fixed <FIXED>"));
    // A frame chosen for a volume no option or session names.
    let png = dir.path().join("frame.png");
    let result =
        warpbench(&["render", "--fixed", s(&bold), "--fixed-frame", "0", "--moving-frame", "1", "--out", s(&png)]);
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("--moving-frame and --moving-series choose a volume of --moving: give --moving"), "{err}");
    assert!(!png.exists());
}

#[test]
fn a_dicom_folder_of_several_series_is_read_by_the_series_chosen() {
    let dir = tempfile::tempdir().expect("tempdir");
    let folder = data("dicom/mixed_ct5n_mr_small");
    let Err(e) = warpbench_io::open(&folder) else { panic!("the folder holds two series") };
    let warpbench_io::ErrorKind::MultipleSeries(list) = e.kind else { panic!("{e}") };
    // The CT series: five slices, so that the pairs are not coplanar.
    let ct = list.iter().find(|s| s.modality == "CT").expect("a CT series").series_instance_uid.clone();
    let series = warpbench_io::LoadOptions::new().series(ct.clone()).open(&folder).expect("the CT series");
    assert_eq!(series.modality, warpbench_io::Modality::Ct);
    let (result, out) = warp_identity(dir.path(), "none", &series, [&folder, &folder], &["--fixed-series", &ct]);
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("the folder holds 2 DICOM series") && err.contains(&ct), "{err}");
    assert!(err.contains("choose one with --moving-series UID"), "{err}");
    assert!(!out.exists());
    let chosen = ["--fixed-series", &ct, "--moving-series", &ct];
    let (result, out) = warp_identity(dir.path(), "ct", &series, [&folder, &folder], &chosen);
    assert_ok(&result);
    assert_eq!(warpbench_io::open(&out).expect("the output").data.to_f32(), series.data.to_f32());
    let unknown = ["--fixed-series", "1.2.3", "--moving-series", &ct];
    let (result, _) = warp_identity(dir.path(), "unknown", &series, [&folder, &folder], &unknown);
    assert_eq!(result.status.code(), Some(2));
    let err = String::from_utf8_lossy(&result.stderr);
    assert!(err.contains("mixed_ct5n_mr_small") && err.contains("1.2.3"), "{err}");
}

/// Runs `points` on `xs` with the pair and `source` (`--landmarks L` or `--session S`), from `side`; the mapped points.
fn map_points(dir: &Path, source: [&str; 2], side: &str, xs: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let (run, _) = run_points(dir, source, side, xs);
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("points JSON");
    report["points"]
        .as_array()
        .expect("points")
        .iter()
        .map(|p| std::array::from_fn(|a| p["output_lps"][a].as_f64().expect("a coordinate")))
        .collect()
}

/// Runs `points --json` on `xs` with the MRI as both volumes and `source`, from `side`, in `dir`: the run and its
/// output's path.
fn run_points(dir: &Path, source: [&str; 2], side: &str, xs: &[[f64; 3]]) -> (std::process::Output, PathBuf) {
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let input = dir.join(format!("in_{side}_{}.csv", source[0].trim_start_matches('-')));
    let lines: Vec<String> = xs.iter().enumerate().map(|(i, x)| format!("{},{},{},p{i}\n", x[0], x[1], x[2])).collect();
    std::fs::write(&input, lines.concat()).expect("write points");
    let out = dir.join(format!("out_{side}_{}.csv", source[0].trim_start_matches('-')));
    let run = warpbench(&[
        "points",
        "--fixed",
        s(&mri),
        "--moving",
        s(&mri),
        source[0],
        source[1],
        "--from",
        side,
        "--in",
        s(&input),
        "--out",
        s(&out),
        "--json",
        "--force",
        "--quiet",
    ]);
    (run, out)
}

/// A window session's brush (issue 17, item 4) acts on top of the landmark warp wherever `--session` is taken:
/// `points` maps fixed points through u ∘ b⁻¹ and moving points through b ∘ d (checked against the solver's exact
/// pointwise inverse of the same strokes and its forward map, around the landmark-only mapping); `warp` resamples
/// through u ∘ b⁻¹ (the brushed volume at x is the landmark-only one at b⁻¹(x)) and its `--json` reports how well the
/// fitted inverse undoes the brush; `transform` refuses a brush it cannot write.
#[test]
fn a_sessions_brush_acts_on_top_of_the_landmarks() {
    use warpbench_app::project::document::Document;
    use warpbench_app::project::session::{self, SessionFile, View};
    use warpbench_solver::brush::{Brush, BrushStroke};
    use warpbench_solver::warp::Warp;

    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let csv = deformed_pairs(dir.path());
    let volume = warpbench_io::open(&mri).expect("fixture");
    let pairs = read_bigwarp_csv(&csv).expect("pairs");
    let stroke = BrushStroke { centre_mm: [10.0, 0.0, 30.0], displacement_mm: [0.0, 8.0, 0.0], radius_mm: 30.0 };
    let mut document = Document::new([Some(mri.clone()), Some(mri.clone())], [&volume, &volume], pairs);
    document.brush = vec![stroke];
    let session_path = dir.path().join("brushed.warpbench.json");
    session::save(&session_path, &SessionFile::new(document, View::default(), true)).expect("save the session");
    let brush = Brush::new(vec![stroke]).expect("brush");
    let (landmarks, session) = (["--landmarks", s(&csv)], ["--session", s(&session_path)]);

    // From the fixed side: u(b⁻¹(x)) against the landmark-only u at the exact b⁻¹(x).
    let xs = [[10.0, 8.0, 30.0], [20.0, 0.0, 25.0], [-5.0, 15.0, 40.0], [60.0, -60.0, -30.0]];
    let exact: Vec<[f64; 3]> = xs.iter().map(|&x| brush.invert_point(x)).collect();
    let (brushed, plain) =
        (map_points(dir.path(), session, "fixed", &xs), map_points(dir.path(), landmarks, "fixed", &exact));
    let worst = brushed
        .iter()
        .zip(&plain)
        .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    eprintln!("u(b⁻¹(x)) within {worst:.4} mm of u at the exact inverse");
    assert!(worst < 0.05, "{brushed:?} against {plain:?}");
    // From the moving side: b(d(p)).
    let ps = [[13.0, -2.0, 31.5], [0.0, 0.0, 0.0], [40.0, 30.0, 10.0]];
    let (brushed, plain) =
        (map_points(dir.path(), session, "moving", &ps), map_points(dir.path(), landmarks, "moving", &ps));
    for (b, p) in brushed.iter().zip(&plain) {
        let expected = brush.apply_raw(*p);
        assert!((0..3).all(|k| (b[k] - expected[k]).abs() < 1e-6), "b(d(p)) = {b:?}, expected {expected:?}");
    }

    // warp: the brushed volume at x is the landmark-only one at b⁻¹(x), around the stroke.
    let (out_plain, out_brushed) = (dir.path().join("plain.nii"), dir.path().join("brushed.nii"));
    let base = ["warp", "--fixed", s(&mri), "--moving", s(&mri), "--grid", "48", "--backend", "cpu", "--quiet"];
    assert_ok(&warpbench(&[&base[..], &landmarks[..], &["--out", s(&out_plain)]].concat()));
    let run = warpbench(&[&base[..], &session[..], &["--out", s(&out_brushed), "--json"]].concat());
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("warp JSON");
    let max_mm = report["inverse_consistency_mm"]["max_mm"].as_f64().expect("the inverse's consistency");
    assert!(max_mm < 0.05, "{report}");
    assert!(report["method"].as_str().is_some_and(|m| m.contains("tps + brush (1 stroke)")), "{report}");
    let (plain, brushed) =
        (warpbench_io::open(&out_plain).expect("plain"), warpbench_io::open(&out_brushed).expect("brushed"));
    let index_from_lps = plain.lps_from_index.inverse().expect("invertible");
    let at = |v: &warpbench_io::Volume, x: [f64; 3]| {
        trilinear(v, index_from_lps.apply_point(warpbench_io::geometry::Point3::from_array(x)).coords())
    };
    let (mut shown, mut expected, mut unmoved) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..brushed.dims[2] {
        for j in 0..brushed.dims[1] {
            for i in 0..brushed.dims[0] {
                let x = brushed.voxel_lps(i, j, k).coords();
                if (0..3).map(|a| (x[a] - [10.0, 8.0, 30.0][a]).powi(2)).sum::<f64>().sqrt() > 20.0 {
                    continue;
                }
                let (Some(e), Some(u)) = (at(&plain, brush.invert_point(x)), at(&plain, x)) else { continue };
                shown.push(brushed.data.get_f64(brushed.offset(i, j, k)));
                expected.push(e);
                unmoved.push(u);
            }
        }
    }
    let ncc = |a: &[f64], b: &[f64]| {
        let (ma, mb) = (a.iter().sum::<f64>() / a.len() as f64, b.iter().sum::<f64>() / b.len() as f64);
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let (va, vb): (f64, f64) = (a.iter().map(|x| (x - ma).powi(2)).sum(), b.iter().map(|y| (y - mb).powi(2)).sum());
        cov / (va * vb).sqrt()
    };
    let rms =
        |a: &[f64], b: &[f64]| (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
    let (with_brush, without) = (rms(&shown, &expected), rms(&shown, &unmoved));
    eprintln!(
        "{} voxels by the stroke: RMS difference from the plain volume at b⁻¹(x) {with_brush:.2}, at x {without:.2} \
         (NCC {:.4})",
        shown.len(),
        ncc(&shown, &expected)
    );
    assert!(shown.len() > 1000 && with_brush < 0.25 * without, "{with_brush} / {without}");

    // render: the GPU draws the moving volume through the same brushed pull-back (its control texture): an axial
    // slice through the stroke, moving layer alone on a grey ramp, correlates with the CPU-resampled volume's voxels.
    let slice_png = dir.path().join("slice.png");
    let run = warpbench(
        &[
            &["render", "--fixed", s(&mri), "--moving", s(&mri), "--slice", "axial:30", "--blend", "moving-only"][..],
            &["--moving-preset", "grey-ramp", "--no-glyphs", "--quiet", "--out", s(&slice_png)],
            &session[..],
        ]
        .concat(),
    );
    if !common::failed_for_want_of_a_gpu(&run) {
        assert_ok(&run);
        let img = image::open(&slice_png).expect("the slice").to_luma8();
        let k = (0..brushed.dims[2])
            .find(|&k| (brushed.voxel_lps(0, 0, k).coords()[2] - 30.0).abs() < 1e-6)
            .expect("a voxel plane at S = 30 mm");
        assert_eq!(img.dimensions(), (brushed.dims[0] as u32, brushed.dims[1] as u32));
        let (mut grey, mut cpu_brushed, mut cpu_plain) = (Vec::new(), Vec::new(), Vec::new());
        for j in 0..brushed.dims[1] {
            for i in 0..brushed.dims[0] {
                let x = brushed.voxel_lps(i, j, k).coords();
                if (x[0] - 10.0).hypot(x[1] - 8.0) > 30.0 {
                    continue;
                }
                grey.push(f64::from(img.get_pixel(i as u32, j as u32)[0]));
                cpu_brushed.push(brushed.data.get_f64(brushed.offset(i, j, k)));
                cpu_plain.push(plain.data.get_f64(plain.offset(i, j, k)));
            }
        }
        let (with_brush, without) = (ncc(&grey, &cpu_brushed), ncc(&grey, &cpu_plain));
        eprintln!(
            "render --session against warp --session around the stroke: NCC {with_brush:.4} (plain {without:.4})"
        );
        // What the correlation leaves unexplained, 1 − NCC, is ten times smaller with the brush than without.
        assert!(with_brush > 0.99 && 1.0 - with_brush < 0.1 * (1.0 - without), "NCC {with_brush} vs {without}");
    }

    // field: the same brushed pull-back, with the inverse's consistency in its report.
    let field_out = dir.path().join("field.nii.gz");
    let run = warpbench(
        &[
            &["field", "--fixed", s(&mri), "--moving", s(&mri), "--quiet", "--json"][..],
            &session[..],
            &["--out", s(&field_out)],
        ]
        .concat(),
    );
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("field JSON");
    assert!(report["inverse_consistency_mm"]["max_mm"].as_f64().is_some_and(|m| m < 0.05), "{report}");
    assert!(report["method"].as_str().is_some_and(|m| m.contains("+ brush (1 stroke)")), "{report}");

    let run = warpbench(
        &[
            &["transform", "--fixed", s(&mri), "--moving", s(&mri)][..],
            &session[..],
            &["--out", s(&dir.path().join("t.tfm"))],
        ]
        .concat(),
    );
    assert_eq!(run.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("brush strokes have no exact ITK transform") && stderr.contains(".h5"), "{stderr}");
    // ITK's HDF5 file holds it as a DisplacementFieldTransform of the brushed pull-back on the fixed grid.
    let h5 = dir.path().join("brushed.h5");
    let run = warpbench(
        &[&["transform", "--fixed", s(&mri), "--moving", s(&mri), "--quiet"][..], &session[..], &["--out", s(&h5)]]
            .concat(),
    );
    assert_ok(&run);
    let chain = warpbench_io::itk_h5::read(&h5).unwrap_or_else(|e| panic!("{e}"));
    let x = plain.voxel_lps(50, 58, 51).coords();
    let (got, want) = (chain.apply(x), common::map_through_session(dir.path(), [&mri, &mri, &session_path], x));
    assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "at {x:?}: the .h5 maps to {got:?}, u = {want:?}");
    assert!((0..3).any(|a| (got[a] - x[a]).abs() > 0.5), "the brush moves {x:?}");
    // For elastix the brushed pull-back is a DeformationFieldTransform over its field, which is u at voxel centres.
    let out = dir.path().join("brushed.txt");
    let run = warpbench(
        &[
            &["transform", "--fixed", s(&mri), "--moving", s(&mri), "--format", "elastix", "--quiet"][..],
            &session[..],
            &["--out", s(&out)],
        ]
        .concat(),
    );
    assert_ok(&run);
    let chain = warpbench_io::elastix::read_transform(&out).unwrap_or_else(|e| panic!("{e}"));
    let x = plain.voxel_lps(50, 58, 51).coords();
    let (got, want) = (chain.apply(x), common::map_through_session(dir.path(), [&mri, &mri, &session_path], x));
    assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "at {x:?}: the file maps to {got:?}, u = {want:?}");
}

/// `--stiffness auto`: the λ the pairs make most likely, the same as the solver's
/// `choose_stiffness` on the file's pairs (fixed → moving, the pull-back), named in the report's method; refused with
/// another method or a stiffness that is not a number ≥ 0.
#[test]
fn stiffness_auto_is_the_solvers_choice() {
    use warpbench_io::geometry::Point3;
    use warpbench_solver::spaces::{Fixed, Moving};

    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let noisy = common::noisy_mri_pairs();
    let csv = dir.path().join("noisy.csv");
    write_pairs(&csv, &noisy);
    let pairs = read_bigwarp_csv(&csv).expect("pairs");
    let fixed: Vec<Point3<Fixed>> = pairs.iter().map(|p| Point3::from_array(p.fixed.expect("q").coords())).collect();
    let moving: Vec<Point3<Moving>> = pairs.iter().map(|p| Point3::from_array(p.moving.expect("p").coords())).collect();
    let expected = warpbench_solver::stiffness::choose_stiffness(&fixed, &moving).expect("a choice");
    assert!(expected.lambda > 0.0, "{expected:?}");

    let out = dir.path().join("auto.nii");
    let base = ["warp", "--fixed", s(&mri), "--moving", s(&mri), "--landmarks", s(&csv), "--quiet"];
    let run =
        warpbench(&[&base[..], &["--stiffness", "auto", "--backend", "cpu", "--json", "--out", s(&out)]].concat());
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("warp JSON");
    assert_eq!(report["method"].as_str(), Some(format!("tps(λ={})", expected.lambda).as_str()), "{report}");

    let never = dir.path().join("never.nii");
    let refused = warpbench(&[&base[..], &["--stiffness", "auto", "--method", "affine", "--out", s(&never)]].concat());
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--stiffness auto chooses the TPS's λ"));
    for bad in ["--stiffness=-1", "--stiffness=soft"] {
        let refused = warpbench(&[&base[..], &[bad, "--out", s(&never)]].concat());
        assert_eq!(refused.status.code(), Some(2), "{bad}");
        assert!(String::from_utf8_lossy(&refused.stderr).contains("not a stiffness"), "{bad}");
    }
}

/// A session's displacement field (one chosen in the window, or Refine by intensities') is a base under the landmark
/// fit for the command line as for the window: with fewer pairs than the method needs, the field alone is the warp, so
/// `points --session` maps a fixed point x to F(x) instead of refusing the pairs.
#[test]
fn a_sessions_field_alone_is_the_warp_below_the_methods_pairs() {
    use warpbench_app::project::document::Document;
    use warpbench_app::project::session::{self, SessionFile, View};
    use warpbench_app::project::stack::FieldLayer;
    use warpbench_io::displacement::{FieldFormat, write_field};
    use warpbench_io::geometry::{Index, Lps, Transform};

    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let volume = warpbench_io::open(&mri).expect("fixture");
    // A smooth field of up to 3 mm on a 10³ grid over the fixed volume's box.
    let (lo, step) = ([-90.0, -126.0, -72.0], [20.0, 24.0, 18.0]);
    let grid = Transform::<Lps, Index>::from_scale_translation(step, lo);
    let vectors: Vec<[f32; 3]> = (0..1000)
        .map(|n| {
            let x = [lo[0] + step[0] * (n % 10) as f64, lo[1] + step[1] * ((n / 10) % 10) as f64];
            [(3.0 * (x[1] / 40.0).sin()) as f32, (2.0 * (x[0] / 30.0).cos()) as f32, 1.0]
        })
        .collect();
    let field_path = dir.path().join("field.nii.gz");
    write_field(&field_path, FieldFormat::Itk, [10; 3], &grid, &vectors).expect("field written");
    let pairs = read_bigwarp_csv(&deformed_pairs(dir.path())).expect("pairs");
    let mut document = Document::new([Some(mri.clone()), Some(mri.clone())], [&volume, &volume], pairs[..2].to_vec());
    document.field = Some(FieldFile::new(field_path.clone()));
    let session_path = dir.path().join("field.warpbench.json");
    session::save(&session_path, &SessionFile::new(document, View::default(), true)).expect("save the session");

    let xs = [[10.0, 8.0, 30.0], [-20.0, 40.0, -10.0]];
    let mapped = map_points(dir.path(), ["--session", s(&session_path)], "fixed", &xs);
    let layer = FieldLayer::read(&field_path).expect("read the field");
    for (x, got) in xs.iter().zip(&mapped) {
        let want = layer.moving_from_fixed_raw(*x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "F({x:?}) = {want:?}, mapped {got:?}");
        assert!((0..3).any(|a| (got[a] - x[a]).abs() > 0.5), "the field moves {x:?}");
    }

    // No transform file holds the field exactly: `transform` refuses the ITK format, and with `--format elastix`
    // writes a DeformationFieldTransform over the pull-back sampled on the fixed grid, the field beside it. Read
    // back, it maps the grid's voxel centres as `points --session` does, within the field's f32 rounding.
    let transform = |format: &str, out: &Path| {
        let volumes = ["transform", "--fixed", s(&mri), "--moving", s(&mri), "--session", s(&session_path)];
        warpbench(&[&volumes[..], &["--format", format, "--json", "--quiet", "--out", s(out)]].concat())
    };
    let refused = transform("itk", &dir.path().join("t.tfm"));
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("NAME.h5"));
    // An elastix parameter file is text: not under an HDF5 name, which ITK would read as HDF5.
    let refused = transform("elastix", &dir.path().join("t.h5"));
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(!dir.path().join("t.h5").exists());
    // ITK's HDF5 file holds it: a DisplacementFieldTransform over the pull-back sampled on the fixed grid.
    let h5 = dir.path().join("with_field.h5");
    let run = transform("itk", &h5);
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("transform JSON");
    assert_eq!(report["itk_class"], "DisplacementFieldTransform_float_3_3", "{report}");
    assert_eq!(report["field"], serde_json::Value::Null, "{report}");
    let h5_chain = warpbench_io::itk_h5::read(&h5).unwrap_or_else(|e| panic!("{e}"));
    // A name elastix's parser cannot quote is refused before anything is written, the field included.
    let quoted = dir.path().join("a\"b.txt");
    let refused = transform("elastix", &quoted);
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("holds a quote"));
    assert!(!quoted.exists() && !dir.path().join("a\"b.field.mha").exists(), "nothing written");
    let out = dir.path().join("TransformParameters.0.txt");
    let run = transform("elastix", &out);
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("transform JSON");
    let field_file = dir.path().join("TransformParameters.0.field.mha");
    assert_eq!(report["elastix_transform"], "DeformationFieldTransform", "{report}");
    assert_eq!(report["field"], s(&field_file), "{report}");
    let chain = warpbench_io::elastix::read_transform(&out).unwrap_or_else(|e| panic!("{e}"));
    let centres: Vec<[f64; 3]> = [[0, 0, 0], [45, 54, 45], [12, 80, 33], [90, 108, 90]]
        .map(|[i, j, k]| volume.voxel_lps(i, j, k).coords())
        .into();
    let mapped = map_points(dir.path(), ["--session", s(&session_path)], "fixed", &centres);
    for (x, want) in centres.iter().zip(&mapped) {
        for got in [chain.apply(*x), h5_chain.apply(*x)] {
            assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "at {x:?}: a file maps to {got:?}, u = {want:?}");
        }
    }
}

/// A session's Learn2Reg field (`.npz`, steps in voxels) is read against the grids the session recorded when it was
/// chosen, whatever volumes the command is given: `points --session` maps the fixed voxel centre i to the moving
/// grid's point at i + d\[i\] (the challenge's own definition, computed here from the grids). A session that names an
/// `.npz` without its grids, or with a fixed grid of another shape, is refused naming the file.
#[test]
fn a_sessions_learn2reg_field_is_read_against_its_recorded_grids() {
    use warpbench_app::project::document::Document;
    use warpbench_app::project::field_file::{FieldFile, VoxelGrid, VoxelGrids};
    use warpbench_app::project::session::{self, SessionFile, View};
    use warpbench_io::geometry::{Index, Lps, Point3, Transform};
    use warpbench_io::learn2reg::{VoxelField, write_voxel_field};

    let dir = tempfile::tempdir().expect("tempdir");
    let mri = data("nifti/avg152T1_LR_nifti.nii");
    let fixed = warpbench_io::open(&mri).expect("fixture");
    // The moving image on another grid (2.5 mm voxels, shifted), so that a step in voxels is not one in mm and the
    // command's volumes (the MRI twice) are not the recorded ones.
    let mut moving = fixed.clone();
    moving.lps_from_index = Transform::<Lps, Index>::from_scale_translation([2.5; 3], [-100.0, -140.0, -80.0]);
    let moving_path = dir.path().join("moving.nii");
    warpbench_io::write_volume(&moving_path, &moving).expect("moving written");
    // Steps of up to 2 voxels, multiples of 1/64, which float16 holds exactly.
    let [nx, ny, _] = fixed.dims;
    let step_at = |n: usize| -> [f32; 3] {
        let (j, k) = ((n / nx) % ny, n / (nx * ny));
        [2.0 * (j as f32 / 9.0).sin(), -1.5 * (k as f32 / 11.0).cos(), 0.75].map(|v| (v * 64.0).round() / 64.0)
    };
    let field = VoxelField { dims: fixed.dims, steps_vox: (0..fixed.dims.iter().product()).map(step_at).collect() };
    let npz = dir.path().join("disp_0001_0001.npz");
    write_voxel_field(&npz, &field).expect("npz written");

    let pairs = read_bigwarp_csv(&deformed_pairs(dir.path())).expect("pairs");
    let grids = VoxelGrids { fixed: VoxelGrid::of(&fixed), moving: VoxelGrid::of(&moving) };
    let save = |name: &str, file: FieldFile| {
        let mut document =
            Document::new([Some(mri.clone()), Some(moving_path.clone())], [&fixed, &moving], pairs[..2].to_vec());
        document.field = Some(file);
        let path = dir.path().join(name);
        session::save(&path, &SessionFile::new(document, View::default(), true)).expect("save the session");
        path
    };
    let session_path = save("l2r.warpbench.json", FieldFile { path: npz.clone(), voxel_grids: Some(Box::new(grids)) });
    let reopened = session::load(&session_path).expect("the session reopens");
    assert_eq!(reopened.document.field.and_then(|f| f.voxel_grids).as_deref(), Some(&grids), "the grids are kept");

    let voxels = [[0, 0, 0], [45, 54, 45], [12, 80, 33], [90, 108, 90]];
    let xs: Vec<[f64; 3]> = voxels.iter().map(|&[i, j, k]| fixed.voxel_lps(i, j, k).coords()).collect();
    let mapped = map_points(dir.path(), ["--session", s(&session_path)], "fixed", &xs);
    for (&[i, j, k], got) in voxels.iter().zip(&mapped) {
        let d = step_at(i + nx * (j + ny * k));
        let ijk = [i as f64 + f64::from(d[0]), j as f64 + f64::from(d[1]), k as f64 + f64::from(d[2])];
        let want = moving.lps_from_index.apply_point(Point3::from_array(ijk)).coords();
        // The field keeps millimetres in f32: its rounding at |x| < 200 mm.
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-4), "voxel {:?}: {got:?}, not {want:?}", [i, j, k]);
    }

    let refusals = dir.path().join("refused");
    std::fs::create_dir(&refusals).expect("a folder");
    let refused = |session_path: &Path, says: &str| {
        let (run, out) = run_points(&refusals, ["--session", s(session_path)], "fixed", &[[0.0; 3]]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains("disp_0001_0001.npz") && stderr.contains(says), "{stderr}");
        assert!(!out.exists());
    };
    refused(&save("bare.warpbench.json", FieldFile::new(npz.clone())), "nothing here records which");
    let small = VoxelGrids { fixed: VoxelGrid { dims: [10, 10, 10], ..grids.fixed }, ..grids };
    refused(
        &save("small.warpbench.json", FieldFile { path: npz.clone(), voxel_grids: Some(Box::new(small)) }),
        "shape",
    );

    // `--initial-field` reads it against the command's own volumes, as the window reads one chosen with them open:
    // given the recorded pair, the same map.
    let (input, out, none) =
        (dir.path().join("l2r_in.csv"), dir.path().join("l2r_out.csv"), dir.path().join("none.csv"));
    let lines: Vec<String> = xs.iter().map(|x| format!("{},{},{}\n", x[0], x[1], x[2])).collect();
    std::fs::write(&input, lines.concat()).expect("write points");
    common::write_pairs_csv(&none, &[]);
    let run = warpbench(&[
        "points",
        "--fixed",
        s(&mri),
        "--moving",
        s(&moving_path),
        "--initial-field",
        s(&npz),
        "--landmarks",
        s(&none),
        "--from",
        "fixed",
        "--in",
        s(&input),
        "--out",
        s(&out),
        "--quiet",
    ]);
    assert_ok(&run);
    let text = std::fs::read_to_string(&out).expect("mapped");
    for (line, want) in text.lines().zip(&mapped) {
        let got: Vec<f64> = line.split(',').take(3).map(|v| v.parse().expect("mm")).collect();
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-9), "{got:?}, through the session {want:?}");
    }
}

#[test]
fn an_oblique_grid_is_refused_as_ome_zarr_before_the_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    let oblique = data("minc/oblique_i16.mnc");
    let csv = dir.path().join("pairs.csv");
    write_pairs(&csv, &[([0.0; 3], [0.0; 3]), ([5.0, 0.0, 0.0], [5.0, 0.0, 0.0]), ([0.0, 5.0, 0.0], [0.0, 5.0, 0.0])]);
    let out = dir.path().join("o.ome.zarr");
    let run = warpbench(&[
        "warp",
        "--fixed",
        s(&oblique),
        "--moving",
        s(&oblique),
        "--landmarks",
        s(&csv),
        "--method",
        "rigid",
        "--quiet",
        "--out",
        s(&out),
    ]);
    assert_eq!(run.status.code(), Some(2), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("o.ome.zarr") && stderr.contains("oblique grid") && stderr.contains("NIfTI"), "{stderr}");
    assert_eq!(std::fs::read_dir(dir.path()).expect("dir").count(), 1, "only the pairs: nothing written");
}
