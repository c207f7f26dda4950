//! Laws and oracles for the thin-plate spline (`warpbench_solver::tps`).
//!
//! Oracle: ITK 5.4.7 `ThinPlateSplineKernelTransform<double, 3>` outputs in `tests/data/itk/tps_reference.json`
//! (made by `data-scripts/itk_tps.py`). Laws: interpolation, affine reproduction, self-recovery, analytic
//! Jacobian, translation invariance, the two stiffness limits, and the degenerate-input decisions.

// A panic is how a test reports; exact float equality is the law where the same code path must give the same bits.
#![allow(clippy::unwrap_used, clippy::float_cmp)]

use nalgebra::{DMatrix, Matrix3};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, RngSeed};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_solver::tps::{Regularisation, Tps, fit_forward, fit_pullback, leave_one_out};
use warpbench_solver::{Fixed, Moving, SolverError, Warp};

type Src = Lps;
type Dst = Fixed;

/// The agreement with ITK, mm.
const ITK_TOL_MM: f64 = 1e-6;
/// Interpolation error allowed at a landmark: grows with N and the coordinate magnitude (mm).
fn hit_tol_mm(n: usize, max_abs: f64) -> f64 {
    1e-12 * n as f64 * (1.0 + max_abs)
}
/// Agreement of two fits of the same map on the same landmarks, mm.
const REFIT_TOL_MM: f64 = 1e-6;

fn seeded(cases: u32) -> Config {
    Config {
        cases,
        rng_algorithm: RngAlgorithm::ChaCha,
        rng_seed: RngSeed::Fixed(0x7a5_2026),
        failure_persistence: None,
        ..Config::default()
    }
}

fn pt<S: warpbench_io::geometry::Space>(v: [f64; 3]) -> Point3<S> {
    Point3::from_array(v)
}

fn random_points(rng: &mut ChaCha8Rng, n: usize, half_mm: f64) -> Vec<[f64; 3]> {
    (0..n).map(|_| std::array::from_fn(|_| rng.random_range(-half_mm..half_mm))).collect()
}

/// A smooth ~10 mm displacement of `p`.
fn smooth(p: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = p;
    [x + 10.0 * (y / 40.0).sin() + 2.0, y + 8.0 * (z / 50.0).cos(), z + 6.0 * (x / 60.0).sin() - 0.02 * y]
}

fn max_abs(v: &[[f64; 3]]) -> f64 {
    v.iter().flatten().fold(0.0_f64, |m, x| m.max(x.abs()))
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn fit(p: &[[f64; 3]], q: &[[f64; 3]], reg: Regularisation) -> Result<Tps<Dst, Src>, SolverError> {
    let src: Vec<Point3<Src>> = p.iter().copied().map(pt).collect();
    let dst: Vec<Point3<Dst>> = q.iter().copied().map(pt).collect();
    Tps::fit_regularised(&src, &dst, reg)
}

/// Least-squares affine fit (oracle for λ → ∞): minimises Σ‖A pᵢ + b − qᵢ‖².
fn affine_least_squares(p: &[[f64; 3]], q: &[[f64; 3]]) -> impl Fn([f64; 3]) -> [f64; 3] {
    let x = DMatrix::from_fn(p.len(), 4, |i, k| if k < 3 { p[i][k] } else { 1.0 });
    let y = DMatrix::from_fn(q.len(), 3, |i, k| q[i][k]);
    let beta = x.clone().svd(true, true).solve(&y, 1e-12).expect("svd solve");
    move |v: [f64; 3]| {
        std::array::from_fn(|k| v[0] * beta[(0, k)] + v[1] * beta[(1, k)] + v[2] * beta[(2, k)] + beta[(3, k)])
    }
}

// ---------------------------------------------------------------------------------------------------------
// ITK oracle

#[test]
fn itk_cross_check() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/itk/tps_reference.json");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).expect("read ITK reference")).expect("parse ITK reference");
    let points = |v: &serde_json::Value| -> Vec<[f64; 3]> {
        v.as_array().expect("array").iter().map(|p| std::array::from_fn(|k| p[k].as_f64().expect("number"))).collect()
    };
    let mut checked = 0;
    for case in doc["cases"].as_array().expect("cases") {
        let name = case["name"].as_str().expect("name");
        let (p, q, x) = (points(&case["source"]), points(&case["target"]), points(&case["queries"]));
        for result in case["results"].as_array().expect("results") {
            let stiffness = result["stiffness"].as_f64().expect("stiffness");
            let expected = points(&result["outputs"]);
            let src: Vec<Point3<Src>> = p.iter().copied().map(pt).collect();
            let dst: Vec<Point3<Dst>> = q.iter().copied().map(pt).collect();
            let tps = Tps::fit(&src, &dst, stiffness).expect("fit");
            let mut out = vec![[0.0; 3]; x.len()];
            tps.eval_into(&x, &mut out);
            for (k, (got, want)) in out.iter().zip(&expected).enumerate() {
                let err = dist(*got, *want);
                assert!(
                    err < ITK_TOL_MM,
                    "{name}, stiffness {stiffness}, query {k}: {got:?} vs ITK {want:?} ({err:e} mm)"
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 3 * 3 * 150, "the reference should hold 3 cases × 3 stiffnesses × 150 queries");
}

// ---------------------------------------------------------------------------------------------------------
// Laws

proptest! {
    #![proptest_config(seeded(24))]

    #[test]
    fn interpolates_every_landmark(n in 4_usize..60, seed in any::<u64>(), half in 1.0_f64..500.0) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = random_points(&mut rng, n, half);
        let q: Vec<[f64; 3]> = random_points(&mut rng, n, half);
        let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
        let tol = hit_tol_mm(n, max_abs(&p).max(max_abs(&q)));
        for (pi, qi) in p.iter().zip(&q) {
            let err = dist(tps.eval_point(*pi), *qi);
            prop_assert!(err <= tol, "miss {err:e} > {tol:e}");
        }
    }

    #[test]
    fn affine_landmarks_give_zero_weights_and_the_affine(n in 4_usize..40, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = random_points(&mut rng, n, 100.0);
        let a = Matrix3::from_fn(|r, c| f64::from(u8::from(r == c)) + rng.random_range(-0.3..0.3));
        let b: [f64; 3] = std::array::from_fn(|_| rng.random_range(-20.0..20.0));
        let q: Vec<[f64; 3]> =
            p.iter().map(|v| std::array::from_fn(|r| a[(r, 0)] * v[0] + a[(r, 1)] * v[1] + a[(r, 2)] * v[2] + b[r])).collect();
        for reg in [Regularisation::Interpolate, Regularisation::ItkStiffness(0.5), Regularisation::Smoothing(10.0)] {
            let tps = fit(&p, &q, reg).expect("fit");
            let w = max_abs(&tps.weights());
            prop_assert!(w < 1e-12, "{reg:?}: bending weights {w:e}");
            prop_assert!((tps.linear() - a).abs().max() < 1e-10);
            prop_assert!(dist(tps.translation(), b) < 1e-8);
        }
    }

    #[test]
    fn a_tps_is_recovered_by_fitting_its_own_samples(n in 5_usize..40, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = random_points(&mut rng, n, 100.0);
        // Random weights projected onto Pᵀw = 0 (the TPS side conditions).
        let pm = DMatrix::from_fn(n, 4, |i, k| if k < 3 { p[i][k] } else { 1.0 });
        let raw = DMatrix::from_fn(n, 3, |_, _| rng.random_range(-0.05..0.05));
        let pinv = pm.clone().pseudo_inverse(1e-12).expect("pinv");
        let w_mat = &raw - &pm * (pinv * &raw);
        let w: Vec<[f64; 3]> = (0..n).map(|i| [w_mat[(i, 0)], w_mat[(i, 1)], w_mat[(i, 2)]]).collect();
        let a = Matrix3::from_fn(|r, c| f64::from(u8::from(r == c)) + rng.random_range(-0.2..0.2));
        let centres: Vec<Point3<Src>> = p.iter().copied().map(pt).collect();
        let truth = Tps::<Dst, Src>::from_parts(&centres, &w, a, [1.0, -2.0, 3.0]).expect("from_parts");
        let q: Vec<[f64; 3]> = p.iter().map(|v| truth.eval_point(*v)).collect();
        let refit = fit(&p, &q, Regularisation::Interpolate).expect("fit");
        for x in random_points(&mut rng, 50, 200.0).iter().chain(&p) {
            let err = dist(refit.eval_point(*x), truth.eval_point(*x));
            prop_assert!(err < REFIT_TOL_MM, "refit differs by {err:e} mm at {x:?}");
        }
    }

    #[test]
    fn jacobian_matches_central_differences(n in 4_usize..30, seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = random_points(&mut rng, n, 100.0);
        let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
        let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
        let h = 1e-4;
        for x in random_points(&mut rng, 10, 150.0) {
            let j = Warp::<Dst, Src>::jacobian_raw(&tps, x);
            for c in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[c] += h;
                xm[c] -= h;
                let (fp, fm) = (tps.eval_point(xp), tps.eval_point(xm));
                for r in 0..3 {
                    let fd = (fp[r] - fm[r]) / (2.0 * h);
                    prop_assert!((j[(r, c)] - fd).abs() < 1e-6, "J[{r}][{c}] {} vs {fd}", j[(r, c)]);
                }
            }
        }
    }

    #[test]
    fn shifting_every_point_shifts_the_fit(n in 4_usize..40, seed in any::<u64>(), t in prop::array::uniform3(-300.0_f64..300.0), u in prop::array::uniform3(-300.0_f64..300.0)) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p = random_points(&mut rng, n, 100.0);
        let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
        let add = |v: [f64; 3], d: [f64; 3]| [v[0] + d[0], v[1] + d[1], v[2] + d[2]];
        let ps: Vec<[f64; 3]> = p.iter().map(|v| add(*v, t)).collect();
        let qs: Vec<[f64; 3]> = q.iter().map(|v| add(*v, u)).collect();
        let base = fit(&p, &q, Regularisation::ItkStiffness(0.5)).expect("fit");
        let shifted = fit(&ps, &qs, Regularisation::ItkStiffness(0.5)).expect("fit shifted");
        for x in random_points(&mut rng, 30, 150.0) {
            let err = dist(shifted.eval_point(add(x, t)), add(base.eval_point(x), u));
            prop_assert!(err < 1e-8, "translation changed the fit by {err:e} mm");
        }
    }
}

#[test]
fn analytic_jacobian_at_a_centre_is_finite_and_matches_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let p = random_points(&mut rng, 12, 80.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
    // At a centre the kernel term's derivative is taken as 0 = the central-difference limit.
    let j = Warp::<Dst, Src>::jacobian_raw(&tps, p[0]);
    assert!(j.iter().all(|v| v.is_finite()));
    let h = 1e-6;
    for c in 0..3 {
        let (mut xp, mut xm) = (p[0], p[0]);
        xp[c] += h;
        xm[c] -= h;
        let (fp, fm) = (tps.eval_point(xp), tps.eval_point(xm));
        for r in 0..3 {
            assert!((j[(r, c)] - (fp[r] - fm[r]) / (2.0 * h)).abs() < 1e-6);
        }
    }
}

#[test]
fn eval_into_equals_eval_point_and_apply() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let p = random_points(&mut rng, 37, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
    let x = random_points(&mut rng, 101, 150.0);
    let mut out = vec![[0.0; 3]; x.len()];
    tps.eval_into(&x, &mut out);
    for (xi, yi) in x.iter().zip(&out) {
        assert_eq!(*yi, tps.eval_point(*xi));
        assert_eq!(*yi, tps.apply(pt::<Src>(*xi)).coords());
    }
}

#[test]
fn forward_and_pullback_map_the_landmarks_in_their_directions() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let p = random_points(&mut rng, 20, 100.0);
    let moving: Vec<Point3<Moving>> = p.iter().copied().map(pt).collect();
    let fixed: Vec<Point3<Fixed>> = p.iter().map(|v| pt(smooth(*v))).collect();
    let fixed_from_moving = fit_forward(&moving, &fixed, 0.0).expect("forward");
    let moving_from_fixed = fit_pullback(&moving, &fixed, 0.0).expect("pullback");
    for (m, f) in moving.iter().zip(&fixed) {
        assert!(fixed_from_moving.apply(*m).distance(f) < 1e-9);
        assert!(moving_from_fixed.apply(*f).distance(m) < 1e-9);
    }
}

// ---------------------------------------------------------------------------------------------------------
// Stiffness

#[test]
fn itk_stiffness_residuals_are_nonzero_and_shrink_as_lambda_goes_to_zero() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let p = random_points(&mut rng, 30, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    for make in [Regularisation::ItkStiffness as fn(f64) -> Regularisation, Regularisation::Smoothing] {
        let mut previous = f64::INFINITY;
        for lambda in [1.0, 0.1, 0.01, 0.001] {
            let tps = fit(&p, &q, make(lambda)).expect("fit");
            let resid = p.iter().zip(&q).map(|(pi, qi)| dist(tps.eval_point(*pi), *qi)).fold(0.0, f64::max);
            assert!(resid > 0.0 && resid.is_finite(), "{:?}: residual {resid}", make(lambda));
            assert!(resid < previous, "{:?}: residual {resid} did not shrink (was {previous})", make(lambda));
            // The system says exactly qᵢ − f(pᵢ) = ±λ wᵢ.
            let w = tps.weights();
            for ((pi, qi), wi) in p.iter().zip(&q).zip(&w) {
                let f = tps.eval_point(*pi);
                let d = make(lambda).k_diagonal();
                assert!(dist([f[0] + d * wi[0], f[1] + d * wi[1], f[2] + d * wi[2]], *qi) < 1e-9);
            }
            previous = resid;
        }
    }
}

#[test]
fn very_large_lambda_approaches_the_least_squares_affine_fit() {
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let p = random_points(&mut rng, 25, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let ls = affine_least_squares(&p, &q);
    for reg in [Regularisation::ItkStiffness(1e10), Regularisation::Smoothing(1e10)] {
        let tps = fit(&p, &q, reg).expect("fit");
        for x in random_points(&mut rng, 30, 150.0) {
            let err = dist(tps.eval_point(x), ls(x));
            assert!(err < 1e-4, "{reg:?}: {err:e} mm from the least-squares affine");
        }
    }
}

#[test]
fn smoothing_bending_energy_decreases_with_lambda() {
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let p = random_points(&mut rng, 40, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let mut previous = f64::INFINITY;
    for lambda in [0.0, 1.0, 10.0, 100.0, 1e4] {
        let e = fit(&p, &q, Regularisation::Smoothing(lambda)).expect("fit").bending_energy();
        assert!(e >= 0.0 && e < previous, "λ = {lambda}: energy {e} (was {previous})");
        previous = e;
    }
}

#[test]
fn itk_stiffness_at_a_kernel_eigenvalue_is_an_error_not_nan() {
    // With U(r) = r, K + λI is singular on Pᵀw = 0 when λ = μⱼ, an eigenvalue of −Q₂ᵀKQ₂ (module docs).
    let mut rng = ChaCha8Rng::seed_from_u64(24);
    let p = random_points(&mut rng, 15, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let n = p.len();
    let k = DMatrix::from_fn(n, n, |i, j| dist(p[i], p[j]));
    let pm = DMatrix::from_fn(n, 4, |i, c| if c < 3 { p[i][c] } else { 1.0 });
    let q_full = pm.qr().q();
    // Orthonormal complement of P's columns: project the identity and orthonormalise.
    let proj = DMatrix::<f64>::identity(n, n) - &q_full * q_full.transpose();
    let eig = proj.symmetric_eigen();
    let keep: Vec<usize> = (0..n).filter(|&i| eig.eigenvalues[i] > 0.5).collect();
    assert_eq!(keep.len(), n - 4);
    let q2 = eig.eigenvectors.select_columns(&keep);
    let mu = (-(q2.transpose() * k * &q2)).symmetric_eigenvalues();
    for lambda in [mu.min(), mu.max(), mu[mu.len() / 2]] {
        match fit(&p, &q, Regularisation::ItkStiffness(lambda)) {
            Err(SolverError::Degenerate(msg)) => assert!(msg.contains("stiffness"), "{msg}"),
            other => panic!("λ = {lambda}: expected Degenerate, got {other:?}"),
        }
    }
}

// ---------------------------------------------------------------------------------------------------------
// Degenerate input

fn cube_corners() -> Vec<[f64; 3]> {
    (0..8).map(|i| [f64::from(i & 1) * 50.0, f64::from((i >> 1) & 1) * 50.0, f64::from((i >> 2) & 1) * 50.0]).collect()
}

#[test]
fn fewer_than_four_landmarks_is_too_few() {
    for n in 0..4 {
        let p = &cube_corners()[..n];
        assert_eq!(
            fit(p, p, Regularisation::Interpolate).unwrap_err(),
            SolverError::TooFew { method: "thin-plate spline", needed: 4, got: n }
        );
    }
}

#[test]
fn four_non_coplanar_landmarks_give_the_exact_affine() {
    let p = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]];
    let q = [[1.0, 2.0, 3.0], [12.0, 2.0, 3.0], [1.0, 11.0, 3.0], [1.0, 2.0, 15.0]];
    let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
    assert!(max_abs(&tps.weights()) == 0.0);
    for (pi, qi) in p.iter().zip(&q) {
        assert!(dist(tps.eval_point(*pi), *qi) < 1e-12);
    }
}

#[test]
fn same_source_with_different_targets_is_duplicate() {
    let mut p = cube_corners();
    let mut q = p.clone();
    p.push(p[2]);
    q.push([1.0, 2.0, 3.0]);
    // Pairs are numbered from 1 in messages and errors.
    assert!(matches!(
        fit(&p, &q, Regularisation::Interpolate).unwrap_err(),
        SolverError::Conflict { first: 3, second: 9, .. }
    ));
}

#[test]
fn a_repeated_pair_is_merged() {
    let p = cube_corners();
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let (mut p2, mut q2) = (p.clone(), q.clone());
    p2.insert(3, p[5]);
    q2.insert(3, q[5]);
    let once = fit(&p, &q, Regularisation::Interpolate).expect("fit");
    let twice = fit(&p2, &q2, Regularisation::Interpolate).expect("fit with a repeated pair");
    assert_eq!(twice.num_centres(), 8);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for x in random_points(&mut rng, 20, 100.0) {
        assert!(dist(once.eval_point(x), twice.eval_point(x)) < 1e-9);
    }
}

#[test]
fn repeated_pairs_leaving_fewer_than_four_are_too_few() {
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    assert_eq!(
        fit(&p, &p, Regularisation::Interpolate).unwrap_err(),
        SolverError::TooFew { method: "thin-plate spline", needed: 4, got: 3 }
    );
}

#[test]
fn coplanar_and_collinear_points_are_flat() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    // A tilted plane through random points, and a line.
    let plane: Vec<[f64; 3]> = (0..20)
        .map(|_| {
            let (s, t) = (rng.random_range(-100.0..100.0), rng.random_range(-100.0..100.0));
            [s + 0.3 * t + 7.0, 0.5 * s - t, 0.2 * s + 0.4 * t - 3.0]
        })
        .collect();
    let line: Vec<[f64; 3]> = (0..10).map(|i| [f64::from(i) * 3.0, f64::from(i) * -2.0 + 1.0, f64::from(i)]).collect();
    for (pts, word) in [(plane, "coplanar"), (line, "collinear")] {
        let q: Vec<[f64; 3]> = pts.iter().map(|v| smooth(*v)).collect();
        for reg in [Regularisation::Interpolate, Regularisation::ItkStiffness(1.0), Regularisation::Smoothing(1.0)] {
            match fit(&pts, &q, reg) {
                Err(e @ SolverError::Flat { shape, .. }) => {
                    assert_eq!(shape, word);
                    assert!(e.to_string().contains(word), "{e}");
                }
                other => panic!("{word} {reg:?}: expected Flat, got {other:?}"),
            }
        }
    }
}

#[test]
fn nearly_flat_but_valid_sources_still_fit_finitely() {
    let mut rng = ChaCha8Rng::seed_from_u64(32);
    // 0.01 mm thick over 200 mm: thin but well above FLAT_RTOL.
    let p: Vec<[f64; 3]> = (0..20)
        .map(|_| [rng.random_range(-100.0..100.0), rng.random_range(-100.0..100.0), rng.random_range(-0.01..0.01)])
        .collect();
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
    for (pi, qi) in p.iter().zip(&q) {
        assert!(dist(tps.eval_point(*pi), *qi) < 1e-6);
    }
}

#[test]
fn nearly_coincident_sources_with_different_targets_error_or_stay_finite() {
    for gap_mm in [1e-3, 1e-6, 1e-9, 1e-12] {
        let mut p = cube_corners();
        let mut q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
        p.push([p[3][0] + gap_mm, p[3][1], p[3][2]]);
        q.push([q[3][0] + 1.0, q[3][1], q[3][2]]);
        match fit(&p, &q, Regularisation::Interpolate) {
            Ok(tps) => {
                let mut out = vec![[0.0; 3]; p.len()];
                tps.eval_into(&p, &mut out);
                assert!(out.iter().flatten().all(|v| v.is_finite()), "gap {gap_mm}");
            }
            Err(SolverError::Degenerate(_) | SolverError::Conflict { .. }) => {}
            Err(other) => panic!("gap {gap_mm}: unexpected {other}"),
        }
    }
}

#[test]
fn non_finite_inputs_and_bad_stiffness_are_rejected() {
    let p = cube_corners();
    let mut q = p.clone();
    q[4][1] = f64::NAN;
    assert_eq!(fit(&p, &q, Regularisation::Interpolate).unwrap_err(), SolverError::NonFinite { pair: 5 });
    let mut p_inf = p.clone();
    p_inf[6][2] = f64::INFINITY;
    assert_eq!(fit(&p_inf, &p, Regularisation::Interpolate).unwrap_err(), SolverError::NonFinite { pair: 7 });
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(fit(&p, &p, Regularisation::ItkStiffness(bad)), Err(SolverError::InvalidParameter(_))));
        assert!(matches!(fit(&p, &p, Regularisation::Smoothing(bad)), Err(SolverError::InvalidParameter(_))));
    }
    assert_eq!(
        fit(&p, &p[..7], Regularisation::Interpolate).unwrap_err(),
        SolverError::LengthMismatch { from_space: "lps", from_len: 8, to_space: "fixed", to_len: 7 }
    );
}

#[test]
fn from_parts_validates_its_inputs() {
    let c: Vec<Point3<Src>> = cube_corners().into_iter().map(pt).collect();
    let w = vec![[0.0; 3]; 8];
    assert!(Tps::<Dst, Src>::from_parts(&c, &w[..7], Matrix3::identity(), [0.0; 3]).is_err());
    let mut w_nan = w.clone();
    w_nan[2][0] = f64::NAN;
    assert_eq!(
        Tps::<Dst, Src>::from_parts(&c, &w_nan, Matrix3::identity(), [0.0; 3]).unwrap_err(),
        SolverError::NonFinite { pair: 3 }
    );
    assert!(Tps::<Dst, Src>::from_parts(&c, &w, Matrix3::identity(), [f64::NAN, 0.0, 0.0]).is_err());
    let id = Tps::<Dst, Src>::from_parts(&c, &w, Matrix3::identity(), [0.0; 3]).expect("identity");
    assert_eq!(id.eval_point([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    assert_eq!(id.centres(), c);
}

// ---------------------------------------------------------------------------------------------------------
// Size

fn fits_and_interpolates(n: usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
    let p = random_points(&mut rng, n, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let tps = fit(&p, &q, Regularisation::Interpolate).expect("fit");
    let mut out = vec![[0.0; 3]; n];
    tps.eval_into(&p, &mut out);
    let tol = hit_tol_mm(n, max_abs(&q));
    for (o, qi) in out.iter().zip(&q) {
        assert!(dist(*o, *qi) < tol, "miss {:e} > {tol:e}", dist(*o, *qi));
    }
}

#[test]
fn n300_fits_and_interpolates() {
    fits_and_interpolates(300);
}

/// About 1 s in release, minutes in the unoptimised test profile: `cargo test --release -- --ignored`.
#[test]
#[ignore = "slow in the unoptimised test profile; run with --release --ignored"]
fn n2000_fits_and_interpolates() {
    fits_and_interpolates(2000);
}

// ---------------------------------------------------------------------------------------------------------
// Leave-one-out in closed form

/// The closed form against N refits with the same regularisation (what `diagnostics::leave_one_out` does); returns
/// how many pairs have an error.
fn assert_loo_matches_refits(p: &[[f64; 3]], q: &[[f64; 3]], reg: Regularisation) -> usize {
    let src: Vec<Point3<Src>> = p.iter().copied().map(pt).collect();
    let dst: Vec<Point3<Dst>> = q.iter().copied().map(pt).collect();
    let closed = leave_one_out(&src, &dst, reg).expect("closed form");
    let refits = warpbench_solver::diagnostics::leave_one_out(
        &src,
        &dst,
        |s: &[Point3<Src>], d: &[Point3<Dst>]| Tps::fit_regularised(s, d, reg),
        warpbench_solver::Parallelism::Sequential,
    );
    assert_eq!(closed.len(), refits.len());
    for (i, (c, r)) in closed.iter().zip(&refits).enumerate() {
        match (c, r) {
            (Some(c), Some(r)) => {
                // Both are O(N³) solves of the same systems; 1e-7 relative leaves room for their rounding.
                assert!((c - r).abs() <= 1e-7 * (1.0 + r), "{reg:?}, pair {i}: closed form {c} mm, refit {r} mm");
            }
            (None, None) => {}
            _ => panic!("{reg:?}, pair {i}: closed form {c:?}, refit {r:?}"),
        }
    }
    closed.iter().flatten().count()
}

#[test]
fn leave_one_out_in_closed_form_equals_refits() {
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    for n in [5, 6, 12, 40] {
        let p = random_points(&mut rng, n, 100.0);
        let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
        // ITK stiffness 10⁶ is above every eigenvalue of the reduced kernel: M is positive definite (the other factor).
        let regs = [
            Regularisation::Interpolate,
            Regularisation::Smoothing(3.0),
            Regularisation::ItkStiffness(0.01),
            Regularisation::ItkStiffness(1e6),
        ];
        for reg in regs {
            assert_eq!(assert_loo_matches_refits(&p, &q, reg), n, "{reg:?}: every refit of well spread points fits");
        }
    }
}

/// f for the pairs (`p`, `q`) and K̃ = K + dI, from nalgebra's LU of the whole augmented system [K̃ P; Pᵀ 0] in raw
/// coordinates: an oracle that shares no step with the solver (no QR, no reduction, no Cholesky).
fn lu_fit(p: &[[f64; 3]], q: &[[f64; 3]], d: f64) -> impl Fn([f64; 3]) -> [f64; 3] + use<> {
    let n = p.len();
    let l = DMatrix::from_fn(n + 4, n + 4, |i, j| match (i < n, j < n) {
        (true, true) => dist(p[i], p[j]) + if i == j { d } else { 0.0 },
        (true, false) => p[i].get(j - n).copied().unwrap_or(1.0),
        (false, true) => p[j].get(i - n).copied().unwrap_or(1.0),
        (false, false) => 0.0,
    });
    let b = DMatrix::from_fn(n + 4, 3, |i, k| if i < n { q[i][k] } else { 0.0 });
    let c = l.lu().solve(&b).expect("the augmented system is regular");
    let p = p.to_vec();
    move |x: [f64; 3]| {
        std::array::from_fn(|k| {
            let kernel: f64 = p.iter().enumerate().map(|(j, pj)| c[(j, k)] * dist(x, *pj)).sum();
            kernel + (0..3).map(|a| c[(n + a, k)] * x[a]).sum::<f64>() + c[(n + 3, k)]
        })
    }
}

/// The closed form at N = 300, where the reduced matrix spans several blocks of the blocked Cholesky and triangular
/// inverse (`dense::BLOCK`), against refits of some pairs by the LU oracle above; ITK stiffness 10⁶ makes M positive
/// definite (the other Cholesky).
#[test]
fn leave_one_out_in_closed_form_equals_lu_refits_at_n300() {
    let n = 300;
    assert!(n - 4 > 4 * warpbench_solver::dense::BLOCK, "the test must cross block boundaries");
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let p = random_points(&mut rng, n, 100.0);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    let src: Vec<Point3<Src>> = p.iter().copied().map(pt).collect();
    let dst: Vec<Point3<Dst>> = q.iter().copied().map(pt).collect();
    for reg in [Regularisation::Interpolate, Regularisation::Smoothing(3.0), Regularisation::ItkStiffness(1e6)] {
        let closed = leave_one_out(&src, &dst, reg).expect("closed form");
        for i in [0, 131, 299] {
            let keep = |v: &[[f64; 3]]| -> Vec<[f64; 3]> { [&v[..i], &v[i + 1..]].concat() };
            let refit = lu_fit(&keep(&p), &keep(&q), reg.k_diagonal());
            let oracle = dist(refit(p[i]), q[i]);
            let c = closed[i].expect("every refit of well spread points fits");
            assert!((c - oracle).abs() <= REFIT_TOL_MM, "{reg:?}, pair {i}: closed form {c} mm, LU refit {oracle} mm");
        }
    }
}

#[test]
fn leave_one_out_in_closed_form_handles_repeats_and_refits_that_go_flat() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    // Ten points on the plane z = 0 and two off it: leaving out either off-plane point keeps the set 3-D, but with
    // only one off-plane point, leaving it out makes the rest coplanar and the refit is refused.
    let mut p: Vec<[f64; 3]> =
        (0..10).map(|_| [rng.random_range(-80.0..80.0), rng.random_range(-80.0..80.0), 0.0]).collect();
    p.push([5.0, -3.0, 40.0]);
    let q: Vec<[f64; 3]> = p.iter().map(|v| smooth(*v)).collect();
    for reg in [Regularisation::Interpolate, Regularisation::Smoothing(2.0)] {
        assert_eq!(assert_loo_matches_refits(&p, &q, reg), 10);
        let src: Vec<Point3<Src>> = p.iter().copied().map(pt).collect();
        let dst: Vec<Point3<Dst>> = q.iter().copied().map(pt).collect();
        assert_eq!(leave_one_out(&src, &dst, reg).expect("closed form")[10], None);
    }
    // A repeated pair: its refit keeps the copy, so the error is the full fit's residual.
    let (mut p2, mut q2) = (p.clone(), q.clone());
    p2.push([5.0, -3.0, 40.0]);
    q2.push(q[10]);
    p2.push([-20.0, 30.0, -25.0]);
    q2.push(smooth([-20.0, 30.0, -25.0]));
    for reg in [Regularisation::Interpolate, Regularisation::Smoothing(2.0)] {
        assert_eq!(assert_loo_matches_refits(&p2, &q2, reg), 13, "{reg:?}");
    }
}
