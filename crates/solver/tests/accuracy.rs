//! Accuracy on the geometry of the real fixture volumes: known synthetic warps are sampled at N
//! landmark pairs inside the volume, each method is fitted, and the target registration error (TRE)
//! is measured at 1 000 held-out points. The thresholds below were measured (see docs/accuracy.md,
//! which this test's table output produces) and set with about 30 % headroom, so a wrong kernel, a
//! transposed matrix or a sign error fails them.

#![allow(clippy::approx_constant, reason = "3.14 mm is a measured TRE bound, not π")]

use crate::common;

use common::volume_box;
use warpbench_io::geometry::Point3;
use warpbench_solver::Parallelism;
use warpbench_solver::bspline::BSplineParams;
use warpbench_solver::control::{ControlGrid, ControlTexture, texture_error_mm};
use warpbench_solver::diagnostics::{ErrorStats, jacobian_determinants};
use warpbench_solver::linear::LinearKind;
use warpbench_solver::synthetic::{SyntheticKind, SyntheticWarp, held_out_pairs, sample_pairs};
use warpbench_solver::tps::Tps;
use warpbench_solver::{Aabb, Fixed, Method, Moving, Warp};

const AMPLITUDE_MM: f64 = 10.0;
const HELD_OUT: usize = 1000;

fn methods() -> Vec<Method> {
    vec![
        Method::Tps { stiffness: 0.0 },
        Method::BSpline(BSplineParams { coarsest: [2, 2, 2], levels: 4, tolerance_mm: 0.01 }),
        Method::Linear(LinearKind::Affine),
        Method::Linear(LinearKind::Similarity),
        Method::Linear(LinearKind::Rigid),
    ]
}

/// Fits `method` to N pairs of `warp` and returns the TRE statistics at the held-out points.
fn tre(warp: &SyntheticWarp, domain: Aabb<Moving>, n: usize, method: Method, seed: u64) -> ErrorStats {
    let (p, q) = sample_pairs(warp, domain, n, seed);
    let fixed_from_moving = method.fit(&p, &q, domain).expect("fit");
    let (targets, truth) = held_out_pairs(warp, domain, HELD_OUT, seed);
    let errors: Vec<f64> = targets.iter().zip(&truth).map(|(x, y)| fixed_from_moving.apply(*x).distance(y)).collect();
    ErrorStats::of(&errors).expect("finite errors")
}

/// Upper bounds on the mean TRE (mm) per (warp, N, method), over both fixture volumes: 1.25 × the
/// measured worse of the two, plus 0.05 mm (measured 2026-11-22; the table is in docs/accuracy.md).
const MEAN_TRE_BOUND_MM: &[(&str, usize, &str, f64)] = &[
    ("sine", 20, "tps", 6.64),
    ("sine", 20, "hbspline(4 levels)", 7.06),
    ("sine", 20, "affine", 9.75),
    ("sine", 20, "similarity", 8.63),
    ("sine", 20, "rigid", 8.59),
    ("sine", 50, "tps", 3.03),
    ("sine", 50, "hbspline(4 levels)", 3.72),
    ("sine", 50, "affine", 8.52),
    ("sine", 50, "similarity", 8.48),
    ("sine", 50, "rigid", 8.47),
    ("sine", 200, "tps", 0.91),
    ("sine", 200, "hbspline(4 levels)", 0.99),
    ("sine", 200, "affine", 8.07),
    ("sine", 200, "similarity", 8.48),
    ("sine", 200, "rigid", 8.48),
    ("twist", 20, "tps", 1.86),
    ("twist", 20, "hbspline(4 levels)", 1.89),
    ("twist", 20, "affine", 3.19),
    ("twist", 20, "similarity", 2.96),
    ("twist", 20, "rigid", 2.96),
    ("twist", 50, "tps", 0.87),
    ("twist", 50, "hbspline(4 levels)", 1.08),
    ("twist", 50, "affine", 3.18),
    ("twist", 50, "similarity", 3.14),
    ("twist", 50, "rigid", 3.14),
    ("twist", 200, "tps", 0.26),
    ("twist", 200, "hbspline(4 levels)", 0.34),
    ("twist", 200, "affine", 2.87),
    ("twist", 200, "similarity", 2.87),
    ("twist", 200, "rigid", 2.87),
    ("bend", 20, "tps", 1.62),
    ("bend", 20, "hbspline(4 levels)", 1.72),
    ("bend", 20, "affine", 2.32),
    ("bend", 20, "similarity", 2.31),
    ("bend", 20, "rigid", 2.31),
    ("bend", 50, "tps", 0.62),
    ("bend", 50, "hbspline(4 levels)", 0.74),
    ("bend", 50, "affine", 2.10),
    ("bend", 50, "similarity", 2.08),
    ("bend", 50, "rigid", 2.08),
    ("bend", 200, "tps", 0.22),
    ("bend", 200, "hbspline(4 levels)", 0.29),
    ("bend", 200, "affine", 2.20),
    ("bend", 200, "similarity", 2.20),
    ("bend", 200, "rigid", 2.20),
    ("bump", 20, "tps", 0.76),
    ("bump", 20, "hbspline(4 levels)", 0.81),
    ("bump", 20, "affine", 1.29),
    ("bump", 20, "similarity", 1.64),
    ("bump", 20, "rigid", 1.70),
    ("bump", 50, "tps", 0.40),
    ("bump", 50, "hbspline(4 levels)", 0.51),
    ("bump", 50, "affine", 1.23),
    ("bump", 50, "similarity", 1.36),
    ("bump", 50, "rigid", 1.41),
    ("bump", 200, "tps", 0.23),
    ("bump", 200, "hbspline(4 levels)", 0.23),
    ("bump", 200, "affine", 1.01),
    ("bump", 200, "similarity", 1.15),
    ("bump", 200, "rigid", 1.16),
    ("tps-random", 20, "tps", 1.35),
    ("tps-random", 20, "hbspline(4 levels)", 1.64),
    ("tps-random", 20, "affine", 2.76),
    ("tps-random", 20, "similarity", 2.67),
    ("tps-random", 20, "rigid", 2.74),
    ("tps-random", 50, "tps", 0.76),
    ("tps-random", 50, "hbspline(4 levels)", 0.98),
    ("tps-random", 50, "affine", 2.89),
    ("tps-random", 50, "similarity", 2.85),
    ("tps-random", 50, "rigid", 2.82),
    ("tps-random", 200, "tps", 0.18),
    ("tps-random", 200, "hbspline(4 levels)", 0.27),
    ("tps-random", 200, "affine", 2.75),
    ("tps-random", 200, "similarity", 2.76),
    ("tps-random", 200, "rigid", 2.79),
    ("bspline-random", 20, "tps", 3.44),
    ("bspline-random", 20, "hbspline(4 levels)", 3.32),
    ("bspline-random", 20, "affine", 4.61),
    ("bspline-random", 20, "similarity", 4.81),
    ("bspline-random", 20, "rigid", 5.00),
    ("bspline-random", 50, "tps", 2.30),
    ("bspline-random", 50, "hbspline(4 levels)", 2.41),
    ("bspline-random", 50, "affine", 4.72),
    ("bspline-random", 50, "similarity", 4.72),
    ("bspline-random", 50, "rigid", 4.81),
    ("bspline-random", 200, "tps", 0.95),
    ("bspline-random", 200, "hbspline(4 levels)", 1.08),
    ("bspline-random", 200, "affine", 4.39),
    ("bspline-random", 200, "similarity", 4.60),
    ("bspline-random", 200, "rigid", 4.72),
];

#[test]
fn tre_on_fixture_geometry_meets_measured_bounds() {
    let volumes = [("MRI ch2", "nifti/ch2.nii.gz"), ("CT cranium", "nifti/cranium_ct.nii.gz")];
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    for (vname, rel) in volumes {
        let domain = volume_box(rel);
        for (k, kind) in SyntheticKind::ALL.into_iter().enumerate() {
            let warp = SyntheticWarp::new(kind, domain, AMPLITUDE_MM, 7 + k as u64).expect("synthetic warp");
            let mut tps_means = Vec::new();
            for n in [20, 50, 200] {
                let mut rigid_mean = f64::NAN;
                for method in methods() {
                    let s = tre(&warp, domain, n, method, 1000 + n as u64);
                    rows.push(format!(
                        "| {vname} | {kind} | {n} | {method} | {:.3} | {:.3} | {:.3} |",
                        s.mean, s.p95, s.max
                    ));
                    let name = method.to_string();
                    let bound = MEAN_TRE_BOUND_MM
                        .iter()
                        .find(|(k2, n2, m2, _)| *k2 == kind.name() && *n2 == n && *m2 == name)
                        .map(|t| t.3)
                        .expect("a bound for every row");
                    if s.mean > bound {
                        failures.push(format!("{vname} {kind} N={n} {name}: mean TRE {:.3} mm > {bound} mm", s.mean));
                    }
                    match method {
                        Method::Tps { .. } => tps_means.push(s.mean),
                        Method::Linear(LinearKind::Rigid) => rigid_mean = s.mean,
                        _ => {}
                    }
                }
                // Law: at N = 200 a deformable fit is at least 3× better than a rigid one on a non-rigid warp
                // (the local Gaussian bump is the closest call: 3.98×).
                let tps_mean = tps_means[tps_means.len() - 1];
                if n == 200 && tps_mean * 3.0 > rigid_mean {
                    failures.push(format!(
                        "{vname} {kind} N=200: TPS {tps_mean:.3} mm is not 3x better than rigid {rigid_mean:.3} mm"
                    ));
                }
            }
            // Law: more landmarks, smaller TPS error.
            if !(tps_means[0] > tps_means[1] && tps_means[1] > tps_means[2]) {
                failures.push(format!("{vname} {kind}: TPS mean TRE does not fall with N: {tps_means:?}"));
            }
        }
    }
    println!("| volume | warp | N | method | mean TRE mm | p95 mm | max mm |\n|---|---|---|---|---|---|---|");
    for r in rows {
        println!("{r}");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn control_texture_64_cubed_against_exact_tps() {
    let domain = volume_box("nifti/ch2.nii.gz");
    let warp = SyntheticWarp::new(SyntheticKind::TpsRandom, domain, AMPLITUDE_MM, 3).expect("warp");
    let (p, q) = sample_pairs(&warp, domain, 100, 5);
    let moving_from_fixed: Tps<Moving, Fixed> = Tps::fit(&q, &p, 0.0).expect("pull-back");
    let fixed_box: Aabb<Fixed> =
        Aabb::new(Point3::from_array(domain.min.coords()), Point3::from_array(domain.max.coords()));
    let grid = ControlGrid::cube(64, fixed_box).expect("grid");
    let texture = ControlTexture::sample(&moving_from_fixed, grid);
    let probes: Vec<Point3<Fixed>> =
        held_out_pairs(&warp, domain, 2000, 11).1.into_iter().filter(|y| fixed_box.contains(y)).collect();
    let (max, rms) = texture_error_mm(&texture, &moving_from_fixed, &probes);
    println!(
        "64³ control texture vs exact TPS pull-back: max {max:.4} mm, rms {rms:.4} mm, pitch {:?}",
        grid.pitch_mm()
    );
    // Measured: max 0.0445 mm, rms 0.0032 mm at a 2.8–3.4 mm texel pitch (trilinear error ~ h²|∇²u|/8).
    assert!(max < 0.06 && rms < 0.005, "control texture error max {max} mm, rms {rms} mm");
}

#[test]
fn stiffness_removes_folding() {
    // Two close landmarks pulled past each other fold an interpolating TPS.
    let p = [
        [0.0, 0.0, 0.0],
        [10.0, 0.0, 0.0],
        [-60.0, -60.0, -60.0],
        [60.0, -60.0, 60.0],
        [-60.0, 60.0, 60.0],
        [60.0, 60.0, -60.0],
    ]
    .map(Point3::<Moving>::from_array);
    let q = [
        [12.0, 0.0, 0.0],
        [-2.0, 0.0, 0.0],
        [-60.0, -60.0, -60.0],
        [60.0, -60.0, 60.0],
        [-60.0, 60.0, 60.0],
        [60.0, 60.0, -60.0],
    ]
    .map(Point3::<Fixed>::from_array);
    let domain = Aabb::new(Point3::new(-30.0, -30.0, -30.0), Point3::new(40.0, 30.0, 30.0));
    let report = |stiffness: f64| {
        let d = Tps::fit_smoothing(&p, &q, stiffness).expect("fit");
        let r = jacobian_determinants(&d, &domain, [24, 24, 24], Parallelism::Rayon);
        println!("λ = {stiffness}: min det J {:.4}, folded {:.3} %", r.min_det, 100.0 * r.fraction_folded);
        r
    };
    // Measured (smoothing spline, K − λI): λ = 0 folds 1.1 % of the box (min det −1.22); λ = 100 gives
    // min det 0.80, λ = 1000 0.97. The minimum determinant rises monotonically with λ.
    assert!(report(0.0).folds());
    let mut last = f64::NEG_INFINITY;
    for stiffness in [1.0, 10.0, 100.0, 1000.0] {
        let r = report(stiffness);
        assert!(r.min_det >= last, "min det J fell from {last} to {} at λ = {stiffness}", r.min_det);
        last = r.min_det;
        if stiffness < 100.0 {
            continue;
        }
        assert!(!r.folds() && r.min_det > 0.5, "λ = {stiffness} still folds: {r:?}");
    }
}
