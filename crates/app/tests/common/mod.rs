//! Helpers shared by the app's end-to-end tests: fixture paths, running the binary, and writing landmark files.
#![allow(dead_code, reason = "each test binary uses a subset")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A committed fixture under `tests/data`.
pub fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data").join(rel)
}

/// The MRI fixture the tests warp (`avg152T1_LR_nifti.nii`, 91×109×91, 2 mm).
pub fn mri() -> PathBuf {
    data("nifti/avg152T1_LR_nifti.nii")
}

/// Runs the `warpbench` binary.
pub fn warpbench<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_warpbench")).args(args).output().expect("run warpbench")
}

pub fn assert_ok(out: &Output) {
    assert_eq!(out.status.code(), Some(0), "stderr: {}", String::from_utf8_lossy(&out.stderr));
}

pub fn utf8(p: &Path) -> &str {
    p.to_str().expect("utf8 path")
}

/// A BigWarp CSV of (moving p, fixed q) pairs (LPS mm), named `Pt-0`, `Pt-1`, …
pub fn write_pairs_csv(path: &Path, pairs: &[([f64; 3], [f64; 3])]) {
    let lines: Vec<String> = pairs
        .iter()
        .enumerate()
        .map(|(i, (p, q))| {
            let f: Vec<String> = p.iter().chain(q).map(|v| format!("\"{v}\"")).collect();
            format!("\"Pt-{i}\",\"true\",{}\n", f.join(","))
        })
        .collect();
    std::fs::write(path, lines.concat()).expect("write landmarks");
}

/// Seven pairs on the MRI fixture: fixed points inside the brain, moving points shifted by (3, −2, 1.5) mm plus a
/// few mm of local deformation, so the warp is not rigid. `outside_third` moves pair 2's moving point out of the
/// volume. Written as `pairs.csv` (or `outside.csv`) in `dir`.
pub fn deformed_pairs(dir: &Path, outside_third: bool) -> PathBuf {
    let fixed = [
        [0.0, 18.0, 18.0],
        [40.0, 18.0, 18.0],
        [-40.0, 18.0, 18.0],
        [0.0, 70.0, 18.0],
        [0.0, -40.0, 18.0],
        [0.0, 18.0, 60.0],
        [0.0, 18.0, -20.0],
    ];
    let local = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-1.5, 0.0, 1.0], [0.0, 0.0, -2.0], [1.0, 1.0, 0.0]];
    let pairs: Vec<([f64; 3], [f64; 3])> = fixed
        .iter()
        .enumerate()
        .map(|(i, q)| {
            let l = local[i % local.len()];
            let mut p = [q[0] + 3.0 + l[0], q[1] - 2.0 + l[1], q[2] + 1.5 + l[2]];
            if outside_third && i == 2 {
                p[0] = -300.0;
            }
            (p, *q)
        })
        .collect();
    let path = dir.join(if outside_third { "outside.csv" } else { "pairs.csv" });
    write_pairs_csv(&path, &pairs);
    path
}

/// Whether a run of the binary failed only for want of a GPU adapter (then the test is skipped, outside CI, where
/// `REQUIRE_GPU_ADAPTER` makes it a failure).
pub fn failed_for_want_of_a_gpu(out: &Output) -> bool {
    let stderr = String::from_utf8_lossy(&out.stderr);
    if out.status.code() == Some(1) && stderr.contains("no GPU adapter") {
        assert!(std::env::var_os("REQUIRE_GPU_ADAPTER").is_none(), "no GPU adapter: {stderr}");
        eprintln!("skipped: {stderr}");
        return true;
    }
    false
}

/// Twenty (moving, fixed) pairs on the MRI fixture: a smooth deformation of a few mm plus about 1.5 mm of
/// deterministic "localisation noise", for choosing a stiffness.
pub fn noisy_mri_pairs() -> Vec<([f64; 3], [f64; 3])> {
    (0..20)
        .map(|i| {
            let f = f64::from(i);
            let q =
                [f64::from((i * 37) % 120) - 60.0, f64::from((i * 53) % 150) - 90.0, f64::from((i * 71) % 120) - 50.0];
            let p = [
                q[0] + 3.0 * (q[1] / 40.0).sin() + 1.5 * (1.7 * f).sin(),
                q[1] + 2.0 * (q[0] / 50.0).cos() + 1.5 * (2.3 * f).cos(),
                q[2] + 1.5 + 1.5 * (3.1 * f).sin(),
            ];
            (p, q)
        })
        .collect()
}

/// `count` voxel centres (LPS mm) of `v` with the largest central-difference gradient magnitude, at least 7 voxels from
/// every face and more than `apart_mm` from each other, strongest first: points on strong edges, where a similarity
/// search has something to find.
pub fn edge_points(v: &warpbench_io::Volume, count: usize, apart_mm: f64) -> Vec<[f64; 3]> {
    let [nx, ny, nz] = v.dims;
    let at = |i: usize, j: usize, k: usize| v.data.get_f64(v.offset(i, j, k));
    let mut edges: Vec<(f64, [usize; 3])> = Vec::new();
    for k in 7..nz - 7 {
        for j in 7..ny - 7 {
            for i in 7..nx - 7 {
                let g = [
                    at(i + 1, j, k) - at(i - 1, j, k),
                    at(i, j + 1, k) - at(i, j - 1, k),
                    at(i, j, k + 1) - at(i, j, k - 1),
                ];
                edges.push((g.iter().map(|x| x * x).sum(), [i, j, k]));
            }
        }
    }
    edges.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut chosen: Vec<[f64; 3]> = Vec::new();
    for (_, [i, j, k]) in edges {
        let x = v.voxel_lps(i, j, k).coords();
        if chosen.iter().all(|y| (0..3).map(|a| (x[a] - y[a]).powi(2)).sum::<f64>() > apart_mm * apart_mm) {
            chosen.push(x);
        }
        if chosen.len() == count {
            break;
        }
    }
    chosen
}

/// The moving point `warpbench points --from fixed --session session` maps the fixed point `x` to (the pair given as
/// `fixed` and `moving`), through files in `dir`.
pub fn map_through_session(dir: &Path, [fixed, moving, session]: [&Path; 3], x: [f64; 3]) -> [f64; 3] {
    let targets = dir.join("targets.csv");
    std::fs::write(&targets, format!("{},{},{},a\n", x[0], x[1], x[2])).expect("write a point");
    let mapped = dir.join("mapped.csv");
    let out = warpbench(&[
        "points",
        "--fixed",
        utf8(fixed),
        "--moving",
        utf8(moving),
        "--session",
        utf8(session),
        "--from",
        "fixed",
        "--in",
        utf8(&targets),
        "--out",
        utf8(&mapped),
        "--force",
    ]);
    assert_ok(&out);
    let text = std::fs::read_to_string(&mapped).expect("mapped");
    let got: Vec<f64> = text
        .lines()
        .find(|l| !l.starts_with('#'))
        .expect("a line")
        .split(',')
        .take(3)
        .map(|v| v.trim().parse().expect("number"))
        .collect();
    [got[0], got[1], got[2]]
}

/// A window session as the window saves one (schema `warpbench-session/1`), of the volumes `fixed` and `moving`, with
/// no landmarks and the window's usual settings; a test sets what it needs (`landmarks`, `fixed_part`, `field`).
pub fn session_json(fixed: &Path, moving: &Path) -> serde_json::Value {
    serde_json::json!({
        "schema": "warpbench-session/1", "fixed": utf8(fixed), "moving": utf8(moving), "landmarks": [],
        "settings": {"blend": "red-cyan", "mix_weight": 0.5, "checker_mm": 16.0, "shading": "iso",
                     "samples_per_voxel": 1.0, "method": "tps", "stiffness": 0.0, "bspline_levels": 4,
                     "control_texels": 64, "show_landmarks": true},
        "layers": [{"preset": "mr-t1", "window_low": 0.0, "window_high": 100.0, "visible": true},
                   {"preset": "mr-t1", "window_low": 0.0, "window_high": 100.0, "visible": true}],
        "camera": {"azimuth_deg": 30.0, "elevation_deg": 10.0, "zoom": 100.0, "target_lps": [0.0, 0.0, 0.0]},
        "slice_mm": [0.0, 0.0, 0.0], "clean_exit": true,
    })
}
