//! `warpbench points` end to end, against laws that do not go through the points code:
//!
//! - **The warped volume shows the point where `points --from moving` puts it.** Bright dots on a moving volume,
//!   resampled by `warpbench warp` (v'(x) = v(u(x))), are found again in the output by their intensity centroid,
//!   within half a voxel of where `points` maps their centres.
//! - **`--from fixed` undoes `--from moving`** to within the inverse consistency of the warp: ‖u(d(p)) − p‖ is at most
//!   the largest ‖u(d(y)) − y‖ measured on a grid over the moving box by the solver itself.
//! - **Landmarks are interpolated**: with TPS λ = 0 a moving landmark maps exactly onto its fixed partner, so a
//!   BigWarp file moved `--from moving` gets its own fixed column back.
//! - Each format comes back in its own format and coordinate convention (a Slicer RAS file stays RAS, `--ras` CSV
//!   stays RAS, names and unplaced points are kept), read back here by string splitting or `serde_json`.
//! - Refusals exit 2, naming the file, and write nothing.

mod common;

use std::path::{Path, PathBuf};

use common::{assert_ok, data, utf8, warpbench, write_pairs_csv};
use serde_json::Value;
use warpbench_io::geometry::{Lps, Point3, Transform};
use warpbench_io::{GeometrySource, Volume, VoxelData, nifti};
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

/// Voxels per axis and spacing of the test volumes: 48³ at 2 mm, centred on the origin (voxel centres −47…47 mm).
const N: usize = 48;
const SPACING_MM: f64 = 2.0;
const ORIGIN_MM: f64 = -47.0;

/// The bright dots on the moving volume (LPS mm) and their Gaussian width.
const DOTS: [[f64; 3]; 3] = [[-10.0, 6.0, 4.0], [14.0, -12.0, -8.0], [2.0, 16.0, -14.0]];
const DOT_SIGMA_MM: f64 = 2.0;

fn lps_from_index() -> Transform<Lps, warpbench_io::geometry::Index> {
    Transform::from_scale_translation([SPACING_MM; 3], [ORIGIN_MM; 3])
}

fn centre(i: usize) -> f64 {
    ORIGIN_MM + SPACING_MM * i as f64
}

/// A 48³ float volume whose samples are `f` at the voxel centres (LPS mm), written as NIfTI.
fn write_volume(path: &Path, f: impl Fn([f64; 3]) -> f64) {
    let mut samples = Vec::with_capacity(N * N * N);
    for k in 0..N {
        for j in 0..N {
            for i in 0..N {
                samples.push(f([centre(i), centre(j), centre(k)]) as f32);
            }
        }
    }
    let v =
        Volume::new(path, [N; 3], VoxelData::F32(samples), lps_from_index(), GeometrySource::NiftiSform { code: 1 })
            .expect("volume");
    nifti::write(path, &v).expect("write volume");
}

/// Eight pairs: fixed points on a cube of ±28 mm and its centre, moving points shifted by (3, −2, 1.5) mm plus up
/// to 2 mm of local deformation (a smooth, non-affine warp that folds nowhere).
fn pairs() -> Vec<([f64; 3], [f64; 3])> {
    let fixed: [[f64; 3]; 9] = [
        [-28.0, -28.0, -28.0],
        [28.0, -28.0, -28.0],
        [-28.0, 28.0, -28.0],
        [28.0, 28.0, -28.0],
        [-28.0, -28.0, 28.0],
        [28.0, -28.0, 28.0],
        [-28.0, 28.0, 28.0],
        [28.0, 28.0, 28.0],
        [0.0, 0.0, 0.0],
    ];
    let local = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-1.5, 0.0, 1.0], [0.0, 0.0, -2.0], [1.0, 1.0, 0.0]];
    fixed
        .iter()
        .enumerate()
        .map(|(n, q)| {
            let l = local[n % local.len()];
            ([q[0] + 3.0 + l[0], q[1] - 2.0 + l[1], q[2] + 1.5 + l[2]], *q)
        })
        .collect()
}

/// The pair of volumes (a flat fixed one, the dotted moving one) and the landmark CSV, in `dir`.
struct Scene {
    fixed: PathBuf,
    moving: PathBuf,
    landmarks: PathBuf,
}

fn scene(dir: &Path) -> Scene {
    let (fixed, moving, landmarks) = (dir.join("fixed.nii"), dir.join("moving.nii"), dir.join("pairs.csv"));
    write_volume(&fixed, |_| 100.0);
    write_volume(&moving, |x| {
        DOTS.iter()
            .map(|d| {
                let r2: f64 = (0..3).map(|a| (x[a] - d[a]).powi(2)).sum();
                1000.0 * (-r2 / (2.0 * DOT_SIGMA_MM * DOT_SIGMA_MM)).exp()
            })
            .sum()
    });
    write_pairs_csv(&landmarks, &pairs());
    Scene { fixed, moving, landmarks }
}

/// Runs `warpbench points` on the scene with `args` after the common ones, `--json`, and returns the report.
fn points(s: &Scene, args: &[&str]) -> Value {
    let mut all = vec!["points", "--fixed", utf8(&s.fixed), "--moving", utf8(&s.moving), "--landmarks"];
    all.push(utf8(&s.landmarks));
    all.extend_from_slice(args);
    all.extend(["--json", "--quiet"]);
    let out = warpbench(&all);
    assert_ok(&out);
    serde_json::from_slice(&out.stdout).expect("the report is JSON")
}

fn xyz(v: &Value) -> [f64; 3] {
    let a = v.as_array().expect("a point");
    std::array::from_fn(|k| a[k].as_f64().expect("a number"))
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// Points `x,y,z,name` (LPS), no header.
fn write_point_csv(path: &Path, points: &[[f64; 3]]) {
    let lines: Vec<String> =
        points.iter().enumerate().map(|(n, p)| format!("{},{},{},dot-{}", p[0], p[1], p[2], n + 1)).collect();
    let text = lines.join("\n") + "\n";
    std::fs::write(path, text).expect("write points");
}

/// Reads a CSV point list `x,y,z,name` by string splitting.
fn read_point_csv(path: &Path) -> Vec<([f64; 3], String)> {
    std::fs::read_to_string(path)
        .expect("read points")
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (std::array::from_fn(|k| f[k].trim().parse().expect("a number")), f[3].to_string())
        })
        .collect()
}

/// The intensity centroid (LPS mm) of the samples above a tenth of the peak within 8 mm of `near`.
fn centroid_near(v: &Volume, near: [f64; 3]) -> [f64; 3] {
    let mut in_reach = Vec::new();
    for k in 0..N {
        for j in 0..N {
            for i in 0..N {
                let x = [centre(i), centre(j), centre(k)];
                if dist(x, near) <= 8.0 {
                    in_reach.push((x, v.data.get_f64(i + N * (j + N * k))));
                }
            }
        }
    }
    let peak = in_reach.iter().map(|&(_, s)| s).fold(f64::MIN, f64::max);
    assert!(peak > 300.0, "a dot near {near:?}: peak {peak}");
    let (mut sum, mut weight) = ([0.0; 3], 0.0);
    for (x, s) in in_reach.into_iter().filter(|&(_, s)| s > 0.1 * peak) {
        for a in 0..3 {
            sum[a] += s * x[a];
        }
        weight += s;
    }
    sum.map(|c| c / weight)
}

#[test]
fn a_point_moved_from_moving_lands_where_the_warped_volume_shows_it_and_comes_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = scene(dir.path());
    let warped = dir.path().join("warped.nii");
    let out = warpbench(&[
        "warp",
        "--fixed",
        utf8(&s.fixed),
        "--moving",
        utf8(&s.moving),
        "--landmarks",
        utf8(&s.landmarks),
        "--method",
        "tps",
        "--exact",
        "--float",
        "--backend",
        "cpu",
        "--out",
        utf8(&warped),
        "--quiet",
    ]);
    assert_ok(&out);
    let warped = warpbench_io::open(&warped).expect("read the warped volume");

    let dots = dir.path().join("dots.csv");
    write_point_csv(&dots, &DOTS);
    let to_fixed = dir.path().join("dots_fixed.csv");
    let report = points(&s, &["--from", "moving", "--in", utf8(&dots), "--out", utf8(&to_fixed)]);
    assert_eq!(report["schema"], "warpbench-points/1");
    assert_eq!(report["map"], "fixed_from_moving");
    assert_eq!((report["from"].as_str(), report["to"].as_str()), (Some("moving"), Some("fixed")));
    assert_eq!(report["format"], "point-list");
    let moved = read_point_csv(&to_fixed);
    assert_eq!(moved.len(), DOTS.len());
    for (n, ((y, name), dot)) in moved.iter().zip(&DOTS).enumerate() {
        assert_eq!(name, &format!("dot-{}", n + 1), "names are kept");
        assert!(dist(*y, *dot) > 2.0, "the warp moves dot {}: {y:?} from {dot:?}", n + 1);
        let seen = centroid_near(&warped, *y);
        let err = dist(seen, *y);
        assert!(err <= 0.5 * SPACING_MM, "dot {}: points says {y:?}, the warped volume shows it at {seen:?}", n + 1);
        // The JSON report holds the same numbers as the file.
        let p = &report["points"][n];
        assert!(dist(xyz(&p["output_lps"]), *y) == 0.0 && dist(xyz(&p["input_lps"]), *dot) == 0.0, "{p}");
        assert_eq!(p["outside"], false);
    }

    // Back with the pull-back u: within the inverse consistency of u and d, which the solver measures here on a
    // grid over the moving box (the same fits as the CLI's: TPS λ = 0 over the volumes' boxes).
    let back = dir.path().join("dots_back.csv");
    let report = points(&s, &["--from", "fixed", "--in", utf8(&to_fixed), "--out", utf8(&back)]);
    assert_eq!(report["map"], "moving_from_fixed");
    let consistency_mm = inverse_consistency_mm();
    assert!(consistency_mm < 0.5, "a mild warp is nearly inverse-consistent: {consistency_mm} mm");
    for (n, ((p, _), dot)) in read_point_csv(&back).iter().zip(&DOTS).enumerate() {
        let err = dist(*p, *dot);
        assert!(err <= consistency_mm + 1e-9, "dot {}: back at {p:?}, {err} mm from {dot:?} > {consistency_mm}", n + 1);
    }
}

/// The largest ‖u(d(y)) − y‖ over a 13³ grid of the moving box, for TPS λ = 0 fitted both ways on [`pairs`].
fn inverse_consistency_mm() -> f64 {
    let (moving, fixed): (Vec<_>, Vec<_>) =
        pairs().into_iter().map(|(p, q)| (Point3::<Moving>::from_array(p), Point3::<Fixed>::from_array(q))).unzip();
    let lo = centre(0);
    let hi = centre(N - 1);
    let bbox_fixed =
        warpbench_solver::spaces::Aabb::<Fixed>::new(Point3::from_array([lo; 3]), Point3::from_array([hi; 3]));
    let bbox_moving =
        warpbench_solver::spaces::Aabb::<Moving>::new(Point3::from_array([lo; 3]), Point3::from_array([hi; 3]));
    let method = Method::from_name("tps").expect("tps");
    let d = warpbench_app::fit::forward(&method, &fixed, &moving, bbox_moving).expect("d");
    let u = warpbench_app::fit::pullback(&method, &fixed, &moving, bbox_fixed).expect("u");
    let mut worst = 0.0f64;
    for k in 0..13 {
        for j in 0..13 {
            for i in 0..13 {
                let y = [i, j, k].map(|n| lo + (hi - lo) * f64::from(n) / 12.0);
                let back = u.apply_raw(d.apply_raw(y));
                worst = worst.max(dist(back, y));
            }
        }
    }
    worst
}

#[test]
fn a_bigwarp_file_moved_from_moving_gets_its_own_fixed_points_back() {
    // TPS with λ = 0 interpolates: d(pᵢ) = qᵢ. The landmark file itself, moved --from moving, must come back with the
    // fixed column it had (to rounding), names and active flags kept.
    let dir = tempfile::tempdir().expect("tempdir");
    let s = scene(dir.path());
    let out = dir.path().join("moved.csv");
    let report = points(&s, &["--from", "moving", "--in", utf8(&s.landmarks), "--out", utf8(&out)]);
    assert_eq!(report["format"], "bigwarp-csv");
    let rows = |p: &Path| -> Vec<Vec<String>> {
        std::fs::read_to_string(p)
            .expect("read")
            .lines()
            .map(|l| l.trim_matches('"').split("\",\"").map(str::to_string).collect())
            .collect()
    };
    let (before, after) = (rows(&s.landmarks), rows(&out));
    assert_eq!(before.len(), after.len());
    for (b, a) in before.iter().zip(&after) {
        assert_eq!(a[..2], b[..2], "name and active flag are kept");
        let num = |row: &[String], c: usize| -> f64 { row[c].parse().expect("a number") };
        for c in 2..5 {
            assert!((num(a, c) - num(b, c)).abs() == 0.0, "{}: the moving point is kept (column {c})", b[0]);
        }
        for c in 5..8 {
            let (want, got): (f64, f64) = (b[c].parse().expect("number"), a[c].parse().expect("number"));
            assert!((want - got).abs() < 1e-6, "{}: column {c}: {got} vs {want}", b[0]);
        }
    }
}

#[test]
fn slicer_and_ras_files_come_back_in_their_own_convention() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = scene(dir.path());

    // The LPS CSV's result, negated in x and y, is the --ras CSV's result.
    let lps = dir.path().join("dots.csv");
    write_point_csv(&lps, &DOTS);
    let ras = dir.path().join("dots_ras.csv");
    write_point_csv(&ras, &DOTS.map(|[x, y, z]| [-x, -y, z]));
    let (lps_out, ras_out) = (dir.path().join("lps_out.csv"), dir.path().join("ras_out.csv"));
    points(&s, &["--from", "fixed", "--in", utf8(&lps), "--out", utf8(&lps_out)]);
    let report = points(&s, &["--from", "fixed", "--in", utf8(&ras), "--out", utf8(&ras_out), "--ras"]);
    assert_eq!(report["file_coordinates"], "RAS");
    for ((l, _), (r, _)) in read_point_csv(&lps_out).iter().zip(&read_point_csv(&ras_out)) {
        assert!(dist(*l, [-r[0], -r[1], r[2]]) < 1e-9, "{l:?} vs RAS {r:?}");
    }

    // A Slicer RAS .mrk.json: written back in RAS with its labels, the unplaced point still unplaced, and each placed
    // point where the LPS CSV of the same points goes.
    let mrk = data("landmarks/slicer5_ras.mrk.json");
    let mrk_out = dir.path().join("moved.mrk.json");
    let report = points(&s, &["--from", "fixed", "--in", utf8(&mrk), "--out", utf8(&mrk_out)]);
    assert_eq!(report["format"], "slicer-mrk-json");
    assert_eq!(report["file_coordinates"], "RAS");
    let read = |p: &Path| -> Value { serde_json::from_str(&std::fs::read_to_string(p).expect("read")).expect("json") };
    let (before, after) = (read(&mrk), read(&mrk_out));
    let markup = &after["markups"][0];
    assert_eq!(markup["coordinateSystem"], "RAS");
    let before_points = before["markups"][0]["controlPoints"].as_array().expect("points");
    let after_points = markup["controlPoints"].as_array().expect("points");
    assert_eq!(before_points.len(), after_points.len());
    let placed: Vec<[f64; 3]> = before_points
        .iter()
        .filter(|p| p["positionStatus"] != "undefined")
        .map(|p| {
            let [x, y, z] = xyz(&p["position"]);
            [-x, -y, z]
        })
        .collect();
    let placed_csv = dir.path().join("placed.csv");
    write_point_csv(&placed_csv, &placed);
    let placed_out = dir.path().join("placed_out.csv");
    points(&s, &["--from", "fixed", "--in", utf8(&placed_csv), "--out", utf8(&placed_out)]);
    let mut expected = read_point_csv(&placed_out).into_iter();
    for (b, a) in before_points.iter().zip(after_points) {
        assert_eq!(a["label"], b["label"]);
        assert_eq!(a["positionStatus"], b["positionStatus"]);
        if b["positionStatus"] == "undefined" {
            assert_eq!(a["position"], b["position"], "an unplaced point is not moved");
            continue;
        }
        let (want_lps, _) = expected.next().expect("a placed point");
        let [x, y, z] = xyz(&a["position"]);
        assert!(dist([-x, -y, z], want_lps) < 1e-9, "{}: {:?} vs {want_lps:?}", b["label"], [x, y, z]);
    }
}

#[test]
fn refusals_exit_2_naming_the_file_and_write_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = scene(dir.path());
    let dots = dir.path().join("dots.csv");
    write_point_csv(&dots, &DOTS);
    let before = std::fs::read(&dots).expect("read");
    let run = |extra: &[&str]| {
        let mut all = vec!["points", "--fixed", utf8(&s.fixed), "--moving", utf8(&s.moving), "--landmarks"];
        all.push(utf8(&s.landmarks));
        all.extend_from_slice(extra);
        warpbench(&all)
    };
    let stderr = |o: &std::process::Output| String::from_utf8_lossy(&o.stderr).into_owned();

    // The output is the input.
    let o = run(&["--from", "moving", "--in", utf8(&dots), "--out", utf8(&dots)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("dots.csv"), "{}", stderr(&o));

    // An existing output without --force.
    let taken = dir.path().join("taken.csv");
    std::fs::write(&taken, "keep me").expect("write");
    let o = run(&["--from", "moving", "--in", utf8(&dots), "--out", utf8(&taken)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("taken.csv"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&taken).expect("read"), "keep me");

    // An output name that says another format.
    let wrong = dir.path().join("moved.mrk.json");
    let o = run(&["--from", "moving", "--in", utf8(&dots), "--out", utf8(&wrong)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("moved.mrk.json"), "{}", stderr(&o));
    assert!(!wrong.exists());

    // A point line that is not one, named by its line.
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "1,2,3,a\n4,five,6,b\n").expect("write");
    let o = run(&["--from", "moving", "--in", utf8(&bad), "--out", utf8(&dir.path().join("bad_out.csv"))]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("bad.csv") && stderr(&o).contains('2'), "{}", stderr(&o));
    assert!(!dir.path().join("bad_out.csv").exists());

    // No --from: clap's usage error, also exit 2.
    let o = run(&["--in", utf8(&dots), "--out", utf8(&dir.path().join("x.csv"))]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--from"), "{}", stderr(&o));

    assert_eq!(std::fs::read(&dots).expect("read"), before, "the input is unchanged");
}

/// An elastix point file's rows, after its word and count.
fn read_elastix(path: &Path) -> (String, Vec<[f64; 3]>) {
    let text = std::fs::read_to_string(path).expect("read the elastix file");
    let mut lines = text.lines();
    let word = lines.next().expect("the word").to_owned();
    let count: usize = lines.next().expect("the count").parse().expect("a count");
    let rows: Vec<[f64; 3]> = lines
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().expect("a number")).collect();
            [v[0], v[1], v[2]]
        })
        .collect();
    assert_eq!(rows.len(), count, "{text}");
    (word, rows)
}

/// elastix point files in and out of `warpbench points`: a `point` file maps like a CSV list (LPS mm, bit for bit);
/// an `index` file is read as voxel indices of the --from volume and written as voxel indices of the other one (here
/// oblique, so a wrong volume or a transposed matrix shows); a count that disagrees with the rows, and --ras, are
/// refused. And elastix's two point sets, or transformix's outputpoints.txt, give the pairs `--landmarks` gives.
#[test]
fn elastix_point_files_map_like_a_csv_list_and_index_files_through_their_volumes() {
    use nalgebra::{Matrix3, Rotation3, Vector3};
    let dir = tempfile::tempdir().expect("tempdir");
    let s = scene(dir.path());
    // The moving volume on an oblique grid: 2.1 mm, turned 12° about S, centred on the origin.
    let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), 12f64.to_radians()).into_inner();
    let linear: Matrix3<f64> = turn * 2.1;
    let half = Vector3::from_element((N as f64 - 1.0) / 2.0);
    let origin = -(linear * half);
    let moving_lps_from_index = Transform::from_linear_translation(linear, [origin[0], origin[1], origin[2]]);
    let moving = dir.path().join("moving_oblique.nii");
    let v = Volume::new(
        &moving,
        [N; 3],
        VoxelData::F32(vec![0.0; N * N * N]),
        moving_lps_from_index,
        GeometrySource::NiftiSform { code: 1 },
    )
    .expect("volume");
    nifti::write(&moving, &v).expect("write");
    let moving_lps_from_index = warpbench_io::open(&moving).expect("read").lps_from_index;

    let targets = [[5.0, -3.0, 7.0], [-12.0, 10.0, 2.0], [20.5, 0.25, -9.0]];
    let run = |landmarks: &[&str], input: &Path, out: &Path| -> Value {
        let mut all = vec!["points", "--fixed", utf8(&s.fixed), "--moving", utf8(&moving)];
        all.extend_from_slice(landmarks);
        all.extend(["--from", "fixed", "--in", utf8(input), "--out", utf8(out), "--json", "--quiet"]);
        let o = warpbench(&all);
        assert_ok(&o);
        serde_json::from_slice(&o.stdout).expect("JSON")
    };
    let given = ["--landmarks", utf8(&s.landmarks)];
    let csv = dir.path().join("targets.csv");
    write_point_csv(&csv, &targets);
    run(&given, &csv, &dir.path().join("mapped.csv"));
    let want: Vec<[f64; 3]> = read_point_csv(&dir.path().join("mapped.csv")).into_iter().map(|(p, _)| p).collect();

    // `point`: LPS mm in and out, the same numbers as the CSV list.
    let pts = dir.path().join("targets.txt");
    let body: Vec<String> = targets.iter().map(|p| format!("{} {} {}", p[0], p[1], p[2])).collect();
    std::fs::write(&pts, format!("point\n3\n{}\n", body.join("\n"))).expect("write");
    let report = run(&given, &pts, &dir.path().join("mapped_pts.txt"));
    assert_eq!(report["format"], "elastix-points");
    assert_eq!(report["file_coordinates"], "LPS");
    let (word, rows) = read_elastix(&dir.path().join("mapped_pts.txt"));
    assert_eq!(word, "point");
    assert_eq!(rows, want);

    // `index`: voxel indices of the fixed volume in, of the (oblique) moving volume out.
    let fixed_index_from_lps = lps_from_index().inverse().expect("invertible");
    let idx: Vec<[f64; 3]> =
        targets.iter().map(|&p| fixed_index_from_lps.apply_point(Point3::<Lps>::from_array(p)).coords()).collect();
    let ind = dir.path().join("targets_index.txt");
    let body: Vec<String> = idx.iter().map(|p| format!("{:?} {:?} {:?}", p[0], p[1], p[2])).collect();
    std::fs::write(&ind, format!("index\n3\n{}\n", body.join("\n"))).expect("write");
    let report = run(&given, &ind, &dir.path().join("mapped_index.txt"));
    assert_eq!(report["file_coordinates"], "index");
    let (word, rows) = read_elastix(&dir.path().join("mapped_index.txt"));
    assert_eq!(word, "index");
    for (r, w) in rows.iter().zip(&want) {
        let lps = moving_lps_from_index.apply_point(Point3::from_array(*r)).coords();
        assert!(dist(lps, *w) < 1e-9, "index {r:?} is {lps:?} mm, the CSV route {w:?}");
        assert!((0..3).all(|a| r[a] > -1.0 && r[a] < N as f64), "{r:?} are indices of the moving volume");
    }

    // elastix's two point sets as the pairs, and transformix's outputpoints.txt: the same mapping.
    let (m, f): (Vec<[f64; 3]>, Vec<[f64; 3]>) = pairs().into_iter().unzip();
    let side = |name: &str, v: &[[f64; 3]]| {
        let path = dir.path().join(name);
        let rows: Vec<String> = v.iter().map(|p| format!("{} {} {}", p[0], p[1], p[2])).collect();
        std::fs::write(&path, format!("point\n{}\n{}\n", v.len(), rows.join("\n"))).expect("write");
        path
    };
    let (mp, fp) = (side("moving_points.txt", &m), side("fixed_points.txt", &f));
    run(&["--moving-points", utf8(&mp), "--fixed-points", utf8(&fp)], &csv, &dir.path().join("via_sets.csv"));
    let outputpoints = dir.path().join("outputpoints.txt");
    let lines: Vec<String> = f
        .iter()
        .zip(&m)
        .enumerate()
        .map(|(n, (q, p))| {
            format!(
                "Point\t{n}\t; InputIndex = [ 0 0 0 ]\t; InputPoint = [ {} {} {} ]\t; OutputIndexFixed = [ 0 0 0 ]\t; \
                 OutputPoint = [ {} {} {} ]\t; Deformation = [ 0 0 0 ]",
                q[0], q[1], q[2], p[0], p[1], p[2]
            )
        })
        .collect();
    std::fs::write(&outputpoints, lines.join("\n") + "\n").expect("write");
    run(&["--landmarks", utf8(&outputpoints)], &csv, &dir.path().join("via_transformix.csv"));
    for name in ["via_sets.csv", "via_transformix.csv"] {
        let got: Vec<[f64; 3]> = read_point_csv(&dir.path().join(name)).into_iter().map(|(p, _)| p).collect();
        assert_eq!(got, want, "{name}");
    }

    // Refusals: a count that disagrees with the rows (named by its line and the file), --ras.
    let short = dir.path().join("short.txt");
    std::fs::write(&short, "point\n3\n1 2 3\n4 5 6\n").expect("write");
    let mut all = vec!["points", "--fixed", utf8(&s.fixed), "--moving", utf8(&moving), "--landmarks"];
    all.extend([utf8(&s.landmarks), "--from", "fixed", "--in", utf8(&short), "--out"]);
    let out = dir.path().join("never.txt");
    let o = warpbench(&[&all[..], &[utf8(&out)]].concat());
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("short.txt") && stderr.contains("line 2 says 3 points, but the file has 2"), "{stderr}");
    let o = warpbench(&[&all[..10], &[utf8(&pts), "--out", utf8(&out), "--ras"]].concat());
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("targets.txt") && stderr.contains("ITK's physical space"), "{stderr}");
    assert!(!out.exists());
}

/// `warpbench suggest` (issue 18 item 2): the moving MRI is the fixed one moved by a known rigid T (in its header, so
/// the true fixed point of a moving point p is T⁻¹(p)); from a starting transform 2.5 mm off, the suggestions for
/// points on strong edges land near the truth (the prediction's error cut), the output pairs them in BigWarp CSV
/// (low-confidence ones inactive), and a point whose patch leaves the volume is reported, not guessed.
#[test]
fn suggest_finds_the_targets_of_a_known_rigid_transform() {
    use warpbench_io::itk_tfm::{self, ItkAffine};
    use warpbench_io::landmarks::read_bigwarp_csv;

    let dir = tempfile::tempdir().expect("tempdir");
    let fixed_path = common::mri();
    let fixed = warpbench_io::open(&fixed_path).expect("the fixture");
    let (c, s) = (8f64.to_radians().cos(), 8f64.to_radians().sin());
    let rotation = nalgebra::Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let truth: Transform<Lps, Lps> = Transform::from_linear_translation(rotation, [5.0, -7.0, 3.0]);
    let mut moving = fixed.clone();
    moving.lps_from_index = truth * moving.lps_from_index;
    let moving_path = dir.path().join("moved.nii");
    nifti::write(&moving_path, &moving).expect("write the moved fixture");
    // The starting transform (fixed → moving), 2.5 mm off the truth.
    let t = truth.translation();
    let start = ItkAffine::from_offset(rotation, [t[0] + 2.0, t[1] - 1.5, t[2]]);
    let tfm = dir.path().join("start.tfm");
    itk_tfm::write_affine(&tfm, &start).expect("write the start");

    // Fixed points on strong edges, at least 7 voxels (14 mm) inside the volume, 15 mm apart; their moving points T(x).
    let chosen = common::edge_points(&fixed, 12, 15.0);
    let moving_points: Vec<[f64; 3]> =
        chosen.iter().map(|x| truth.apply_point(Point3::from_array(*x)).coords()).collect();
    let mut lines: Vec<String> =
        moving_points.iter().enumerate().map(|(n, p)| format!("{},{},{},edge{n}", p[0], p[1], p[2])).collect();
    lines.push("500,500,500,outside".into());
    let list = lines.join("\n") + "\n";
    let points = dir.path().join("moving_points.csv");
    std::fs::write(&points, list).expect("write the points");
    let out = dir.path().join("suggested.csv");
    let run = warpbench(&[
        "suggest",
        "--fixed",
        utf8(&fixed_path),
        "--moving",
        utf8(&moving_path),
        "--initial",
        utf8(&tfm),
        "--points",
        utf8(&points),
        "--out",
        utf8(&out),
        "--json",
    ]);
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert_eq!(report["schema"], "warpbench-suggest/1");
    assert_eq!(report["failed"], 1, "{report}");
    let rows = report["points"].as_array().expect("points");
    assert_eq!(rows.len(), 13);
    assert!(rows[12]["problem"].as_str().expect("a reason").contains("point 13"), "{}", rows[12]);
    let inverse = truth.inverse().expect("invertible");
    let mut errors: Vec<f64> = Vec::new();
    for (row, p) in rows.iter().zip(&moving_points) {
        let got: Vec<f64> =
            row["fixed_lps"].as_array().expect("a suggestion").iter().map(|v| v.as_f64().expect("mm")).collect();
        let want = inverse.apply_point(Point3::from_array(*p)).coords();
        errors.push((0..3).map(|a| (got[a] - want[a]).powi(2)).sum::<f64>().sqrt());
    }
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    eprintln!("suggest on a 2 mm MRI from a start 2.5 mm off: errors {errors:.2?} mm");
    assert!(median < 1.0, "median {median} mm (the prediction is 2.5 mm off)");
    // The file pairs each moving point with its suggestion; low confidence is inactive.
    let pairs = read_bigwarp_csv(&out).expect("BigWarp CSV");
    assert_eq!(pairs.len(), 13);
    for (pair, row) in pairs.iter().zip(rows) {
        assert_eq!(pair.active, !row["low_confidence"].as_bool().expect("flag"));
    }
    assert!(pairs[12].fixed.is_none() && !pairs[12].active);
}

/// ITK's and 3D Slicer's thin-plate-spline files (`data-scripts/slicer_transforms.py`) given as `--landmarks` map points as
/// ITK's `TransformPoint` maps them: ITK's class (fixed → moving) `--from fixed`, and the spline of Slicer's inverse
/// class (moving → fixed, the transform Slicer resamples with being its inverse) `--from moving`. Both are the
/// interpolating spline with kernel r that warpbench fits with TPS λ = 0; ITK solves it with an SVD and warpbench
/// with an LU, each in doubles, so the two agree to rounding amplified by the system's condition (2e-14 mm here).
#[test]
fn itk_and_slicer_spline_files_map_points_as_itk_does() {
    let dir = tempfile::tempdir().expect("tempdir");
    let base = scene(dir.path());
    let itk = data("itk");
    let text = std::fs::read_to_string(itk.join("slicer_tps_reference.json")).expect("reference");
    let reference: Value = serde_json::from_str(&text).expect("JSON");
    let queries: Vec<[f64; 3]> = reference["queries"].as_array().expect("queries").iter().map(xyz).collect();
    let input = dir.path().join("queries.csv");
    write_point_csv(&input, &queries);
    let cases = [
        ("tps_itk.h5", "fixed", "moving_from_fixed"),
        ("tps_itk.tfm", "fixed", "moving_from_fixed"),
        ("tps_slicer.h5", "moving", "fixed_from_moving"),
        ("tps_slicer.tfm", "moving", "fixed_from_moving"),
    ];
    for (name, from, map) in cases {
        let s = Scene { fixed: base.fixed.clone(), moving: base.moving.clone(), landmarks: itk.join(name) };
        let out = dir.path().join(format!("{name}.csv"));
        let report = points(&s, &["--from", from, "--in", utf8(&input), "--out", utf8(&out), "--force"]);
        assert_eq!(report["map"], map, "{name}");
        assert_eq!(report["pairs"], 10, "{name}");
        let want = reference[map].as_array().expect("outputs");
        let got = report["points"].as_array().expect("points");
        assert_eq!(got.len(), want.len(), "{name}");
        let worst = got.iter().zip(want).map(|(g, w)| dist(xyz(&g["output_lps"]), xyz(w))).fold(0.0, f64::max);
        assert!(worst < 1e-9, "{name}: {worst} mm from ITK");
    }
    // Slicer resamples with the exact inverse of its spline; warpbench's pull-back through the same pairs is a spline
    // of its own, which agrees at the landmarks and differs between them by the warp's inverse consistency. Taking
    // Slicer's images of the random queries back `--from fixed` measures it: 0.0196 mm at most on this fixture (its
    // 10 landmarks are displaced by up to 2 mm), the figure docs/formats.md quotes.
    let s = Scene { fixed: base.fixed.clone(), moving: base.moving.clone(), landmarks: itk.join("tps_slicer.h5") };
    let images: Vec<[f64; 3]> = reference["fixed_from_moving"].as_array().expect("outputs").iter().map(xyz).collect();
    let back_in = dir.path().join("images.csv");
    write_point_csv(&back_in, &images[20..]);
    let back_out = dir.path().join("back.csv");
    let report = points(&s, &["--from", "fixed", "--in", utf8(&back_in), "--out", utf8(&back_out), "--force"]);
    let back = report["points"].as_array().expect("points");
    let gaps: Vec<f64> = back.iter().zip(&queries[20..]).map(|(b, q)| dist(xyz(&b["output_lps"]), *q)).collect();
    let worst = gaps.iter().copied().fold(0.0, f64::max);
    assert!(worst > 1e-3 && worst < 0.03, "Slicer's inverse and the pull-back differ by {worst} mm");
}
