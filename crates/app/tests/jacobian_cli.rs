//! `warpbench jacobian` end to end: the det ∇u map equals central differences of the pull-back that `points --from
//! fixed` evaluates (a brute-force oracle of the same derivative), and det ∇d with `--direction forward` those of
//! the forward map `points --from moving` evaluates; the magnitude map is the length of `field`'s vectors (of
//! `field --direction forward`'s with `--direction forward`), a crossing pair of landmarks is reported as folding where it folds, and bad outputs are refused.

mod common;

use std::path::Path;

use common::{assert_ok, data, mri, utf8 as s, warpbench, write_pairs_csv};
use serde_json::Value;
use warpbench_io::geometry::{Index, Lps, Point3, Transform};
use warpbench_io::volume::VoxelData;

/// A map as written: its values, dims and `lps_from_index`.
fn map(path: &Path) -> (Vec<f32>, [usize; 3], Transform<Lps, Index>) {
    let v = warpbench_io::open(path).expect("read the map");
    let VoxelData::F32(values) = v.data else { panic!("{}: not float32", path.display()) };
    (values, v.dims, v.lps_from_index)
}

/// `warpbench <command>` on the MRI with itself and `pairs`, then `rest`.
fn on_mri(command: &str, pairs: &Path, rest: &[&str]) -> std::process::Output {
    let m = mri();
    let mut args = vec![command, "--fixed", s(&m), "--moving", s(&m), "--landmarks", s(pairs)];
    args.extend_from_slice(rest);
    warpbench(&args)
}

/// `jacobian` on the MRI with `pairs` (and `extra`) into `out`: its `--json` report.
fn jacobian(pairs: &Path, out: &Path, extra: &[&str]) -> Value {
    let mut rest = extra.to_vec();
    rest.extend(["--quiet", "--json", "--out", s(out)]);
    let run = on_mri("jacobian", pairs, &rest);
    assert_ok(&run);
    serde_json::from_slice(&run.stdout).expect("JSON")
}

/// det ∇u at 60 voxel centres spread over the head equals the determinant of central differences (h = 1e-3 mm) of
/// u as `points --from fixed` prints it (shortest round-trip f64). The difference quotient is off by h²/6 · |∂³u|
/// (under 1e-9 for this TPS) and by the rounding of u over h (1e-13 · 100 mm / 1e-3 mm = 1e-8); the map holds f32
/// (6e-8 at det ≈ 1). Bound: 1e-6.
#[test]
fn the_det_map_is_the_derivative_of_the_pullback_that_points_evaluates() {
    det_map_is_the_derivative_of_the_map_points_evaluates("pullback");
}

/// The same law for `--direction forward`: det ∇d on the moving grid against central differences of `points --from
/// moving`.
#[test]
fn the_forward_det_map_is_the_derivative_of_the_forward_map_that_points_evaluates() {
    det_map_is_the_derivative_of_the_map_points_evaluates("forward");
}

fn det_map_is_the_derivative_of_the_map_points_evaluates(direction: &str) {
    let (from, grid) = if direction == "forward" { ("moving", "moving") } else { ("fixed", "fixed") };
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = data("itk/field_pairs.csv");
    let out = dir.path().join("det.nii.gz");
    let report = jacobian(&pairs, &out, &["--direction", direction]);
    assert_eq!(report["schema"], "warpbench-jacobian/1");
    assert_eq!(report["quantity"], "det");
    assert_eq!(report["grid"], grid);
    assert_eq!(report["direction"], direction);
    let (values, dims, lps) = map(&out);
    assert_eq!(dims, [91, 109, 91]);
    let centre = |v: usize| {
        let ijk = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
        lps.apply_point(Point3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64)).coords()
    };
    let n = values.len();
    let chosen: Vec<usize> = (0..60).map(|k| (k * 7919 * 97 + n / 3) % n).collect();
    let h = 1e-3;
    let mut lines = Vec::new();
    for &v in &chosen {
        let x = centre(v);
        for a in 0..3 {
            for sign in [1.0, -1.0] {
                let mut p = x;
                p[a] += sign * h;
                lines.push(format!("{:?},{:?},{:?}", p[0], p[1], p[2]));
            }
        }
    }
    let (input, output) = (dir.path().join("in.csv"), dir.path().join("out.csv"));
    std::fs::write(&input, lines.join("\n") + "\n").expect("write");
    assert_ok(&on_mri("points", &pairs, &["--from", from, "--quiet", "--in", s(&input), "--out", s(&output)]));
    let text = std::fs::read_to_string(&output).expect("read");
    let u: Vec<[f64; 3]> = text
        .lines()
        .map(|l| std::array::from_fn(|k| l.split(',').nth(k).expect("x,y,z").parse().expect("a number")))
        .collect();
    let mut worst = 0.0f64;
    let mut spread = (f64::INFINITY, f64::NEG_INFINITY);
    for (k, &v) in chosen.iter().enumerate() {
        let j = nalgebra::Matrix3::from_fn(|r, a| (u[6 * k + 2 * a][r] - u[6 * k + 2 * a + 1][r]) / (2.0 * h));
        let det = j.determinant();
        worst = worst.max((f64::from(values[v]) - det).abs());
        spread = (spread.0.min(det), spread.1.max(det));
    }
    assert!(worst < 1e-6, "{worst} from the central differences");
    assert!(spread.1 - spread.0 > 0.01, "the warp's det varies over the points: {spread:?}");
    // The report's extremes are the map's.
    let (lo, hi) = values.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    assert_eq!(report["min"].as_f64(), Some(f64::from(lo)));
    assert_eq!(report["max"].as_f64(), Some(f64::from(hi)));
    assert_eq!(report["fraction_folded"].as_f64(), Some(0.0));
    let at: Vec<f64> = report["min_at_lps"].as_array().expect("at").iter().map(|v| v.as_f64().expect("mm")).collect();
    let first = values.iter().position(|v| v.to_bits() == lo.to_bits()).expect("the minimum");
    assert_eq!(at, centre(first).to_vec());
}

/// The magnitude map is the length of the vector `field` writes at each voxel (both f32 of f64 values under 10 mm:
/// 1e-6 apart at most), in either direction.
#[test]
fn the_magnitude_map_is_the_length_of_the_fields_vectors() {
    for direction in ["pullback", "forward"] {
        magnitude_is_the_length_of_the_fields_vectors(direction);
    }
}

fn magnitude_is_the_length_of_the_fields_vectors(direction: &str) {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = data("itk/field_pairs.csv");
    let out = dir.path().join("moved.nrrd");
    let report = jacobian(&pairs, &out, &["--quantity", "magnitude", "--direction", direction]);
    assert_eq!(report["quantity"], "magnitude");
    assert!(report["fraction_folded"].is_null());
    let field = dir.path().join("field.nii.gz");
    assert_ok(&on_mri("field", &pairs, &["--quiet", "--direction", direction, "--out", s(&field)]));
    let (vectors, _) = warpbench_io::displacement::read_field(&field).expect("field");
    let (values, dims, _) = map(&out);
    assert_eq!(dims, vectors.dims);
    let worst = values
        .iter()
        .zip(&vectors.displacements_lps)
        .map(|(m, d)| (f64::from(*m) - d.iter().map(|c| f64::from(*c).powi(2)).sum::<f64>().sqrt()).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-5, "{worst} from |D|");
    assert!(report["max"].as_f64().expect("max") > 1.0, "the warp moves points by millimetres");
}

/// Two pairs whose moving points cross over (fixed 20 mm apart along x, moving swapped) fold the TPS between them:
/// the map is ≤ 0 there, the report counts it and places its minimum between the two.
#[test]
fn crossing_pairs_are_reported_as_folding_where_they_fold() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = dir.path().join("crossed.csv");
    let mut list = vec![([10.0, 0.0, 0.0], [-10.0, 0.0, 0.0]), ([-10.0, 0.0, 0.0], [10.0, 0.0, 0.0])];
    for p in [[60.0, 60.0, 40.0], [-60.0, 60.0, -40.0], [60.0, -80.0, -40.0], [-60.0, -80.0, 40.0], [0.0, 0.0, 60.0]] {
        list.push((p, p));
    }
    write_pairs_csv(&pairs, &list);
    let out = dir.path().join("det.mha");
    let report = jacobian(&pairs, &out, &[]);
    let folded = report["fraction_folded"].as_f64().expect("a fraction");
    assert!(folded > 0.0 && report["min"].as_f64().expect("min") <= 0.0, "{report}");
    let at: Vec<f64> = report["min_at_lps"].as_array().expect("at").iter().map(|v| v.as_f64().expect("mm")).collect();
    assert!(at[0].abs() < 15.0 && at[1].abs() < 20.0 && at[2].abs() < 20.0, "folds between the pairs: {at:?}");
    let (values, _, _) = map(&out);
    let share = values.iter().filter(|&&v| v <= 0.0).count() as f64 / values.len() as f64;
    assert!((share - folded).abs() < 1e-12, "{share} vs {folded}");
}

/// An output name that is no volume format, or an existing file without --force, exits 2 naming it, and nothing is
/// written or changed.
#[test]
fn bad_outputs_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = data("itk/field_pairs.csv");
    let txt = dir.path().join("det.txt");
    let run = on_mri("jacobian", &pairs, &["--out", s(&txt)]);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("det.txt"), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(!txt.exists());
    let existing = dir.path().join("det.nii");
    std::fs::write(&existing, b"mine").expect("write");
    let run = on_mri("jacobian", &pairs, &["--out", s(&existing)]);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("--force"));
    assert_eq!(std::fs::read(&existing).expect("read"), b"mine");
    let run = on_mri("jacobian", &pairs, &["--quantity", "volume", "--out", s(&existing)]);
    assert_eq!(run.status.code(), Some(2), "an unknown quantity");
}
