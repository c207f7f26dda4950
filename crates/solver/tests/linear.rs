//! Laws of the linear fits (Umeyama 1991) and the predicted TRE (Fitzpatrick, West & Maurer 1998).

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::linear::{
    AffineWarp, LinearKind, TrePredictor, fit, fit_affine, fit_forward, fit_pullback, fit_rigid, fit_similarity,
    fle_from_fre, predicted_tre, predicted_tre_for,
};
use warpbench_solver::{Fixed, Moving, SolverError, Warp};

/// Exact recovery tolerance, mm, for coordinates of a few hundred mm.
const EXACT_MM: f64 = 1e-9;
/// Orthonormality tolerance for fitted rotations.
const ORTHO_TOL: f64 = 1e-12;

fn coord() -> impl Strategy<Value = f64> {
    -100.0..100.0f64
}

fn points(min: usize, max: usize) -> impl Strategy<Value = Vec<[f64; 3]>> {
    prop::collection::vec([coord(), coord(), coord()], min..=max)
}

fn rotation() -> impl Strategy<Value = Matrix3<f64>> {
    [-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64].prop_filter_map("zero quaternion", |[w, x, y, z]| {
        let q = Quaternion::new(w, x, y, z);
        (q.norm() > 0.1).then(|| *UnitQuaternion::from_quaternion(q).to_rotation_matrix().matrix())
    })
}

fn moving(p: &[[f64; 3]]) -> Vec<Point3<Moving>> {
    p.iter().map(|c| Point3::from_array(*c)).collect()
}

fn fixed(p: &[[f64; 3]]) -> Vec<Point3<Fixed>> {
    p.iter().map(|c| Point3::from_array(*c)).collect()
}

fn map(linear: &Matrix3<f64>, t: [f64; 3], p: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let w: AffineWarp<Fixed, Moving> = AffineWarp::new(*linear, t);
    p.iter().map(|x| w.apply_raw(*x)).collect()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Smallest spread ratio (√(λ_min/λ_max)) of a configuration, to skip near-degenerate random draws.
fn flatness(p: &[[f64; 3]]) -> f64 {
    let n = p.len() as f64;
    let m = p.iter().fold(Vector3::zeros(), |acc, x| acc + Vector3::from(*x)) / n;
    let cov = p.iter().fold(Matrix3::zeros(), |acc, x| {
        let d = Vector3::from(*x) - m;
        acc + d * d.transpose()
    }) / n;
    let e = cov.symmetric_eigenvalues();
    (e.min().max(0.0) / e.max()).sqrt()
}

/// Standard normal samples (Box–Muller), from a seeded RNG.
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn assert_proper_rotation(r: &Matrix3<f64>) {
    let err = (r.transpose() * r - Matrix3::identity()).norm();
    assert!(err < ORTHO_TOL, "‖RᵀR − I‖ = {err:e}");
    assert!((r.determinant() - 1.0).abs() < ORTHO_TOL, "det R = {}", r.determinant());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, failure_persistence: None, ..ProptestConfig::default() })]

    /// Rigid fits return proper rotations whatever the input: noisy, reflected or unrelated targets.
    #[test]
    fn rigid_rotation_is_proper_orthonormal(
        src in points(3, 12),
        rot in rotation(),
        t in [coord(), coord(), coord()],
        noise in prop::collection::vec([-5.0..5.0f64, -5.0..5.0, -5.0..5.0], 12),
        reflect in any::<bool>(),
        unrelated in points(12, 12),
        mode in 0..3u8,
    ) {
        prop_assume!(flatness(&src) > 1e-3 || src.len() == 3);
        let mut dst = map(&rot, t, &src);
        for (i, q) in dst.iter_mut().enumerate() {
            match mode {
                0 => for a in 0..3 { q[a] += noise[i][a]; },
                1 => *q = unrelated[i],
                _ => {}
            }
            if reflect { q[0] = -q[0]; }
        }
        match fit_rigid(&moving(&src), &fixed(&dst)) {
            Ok(f) => {
                assert_proper_rotation(&f.warp.linear());
                prop_assert!(f.fre_rms_mm.is_finite());
            }
            // Unrelated or 3-point targets may be collinear by chance only; never NaN.
            Err(e) => prop_assert!(matches!(e, SolverError::Degenerate(_)), "{e}"),
        }
    }

    /// A rigid transform is recovered exactly from exact pairs.
    #[test]
    fn rigid_exact_recovery(src in points(3, 10), rot in rotation(), t in [coord(), coord(), coord()],
                            probe in points(5, 5)) {
        prop_assume!(flatness(&src) > 1e-2 || (src.len() == 3 && triangle_ok(&src)));
        let dst = map(&rot, t, &src);
        let f = fit_rigid(&moving(&src), &fixed(&dst)).expect("well-posed");
        prop_assert!(f.fre_rms_mm < EXACT_MM);
        for (x, y) in probe.iter().zip(map(&rot, t, &probe)) {
            let e = dist(f.warp.apply_raw(*x), y);
            prop_assert!(e < EXACT_MM, "error {e:e} mm, flatness {}, n {}", flatness(&src), src.len());
        }
    }

    /// A similarity transform (rotation, scale 0.2–5) is recovered exactly from exact pairs.
    #[test]
    fn similarity_exact_recovery(src in points(3, 10), rot in rotation(), scale in 0.2..5.0f64,
                                 t in [coord(), coord(), coord()], probe in points(5, 5)) {
        prop_assume!(flatness(&src) > 1e-2 || (src.len() == 3 && triangle_ok(&src)));
        let linear = rot * scale;
        let dst = map(&linear, t, &src);
        let f = fit_similarity(&moving(&src), &fixed(&dst)).expect("well-posed");
        prop_assert!((f.scale - scale).abs() < 1e-12 * scale.max(1.0));
        for (x, y) in probe.iter().zip(map(&linear, t, &probe)) {
            prop_assert!(dist(f.warp.apply_raw(*x), y) < EXACT_MM);
        }
    }

    /// A general affine transform (singular values 0.5–2, possibly reflecting) is recovered exactly.
    #[test]
    fn affine_exact_recovery(src in points(4, 12), r1 in rotation(), r2 in rotation(),
                             s in [0.5..2.0f64, 0.5..2.0, 0.5..2.0], flip in any::<bool>(),
                             t in [coord(), coord(), coord()], probe in points(5, 5)) {
        prop_assume!(flatness(&src) > 1e-2);
        let sign = if flip { -1.0 } else { 1.0 };
        let linear = r1 * Matrix3::from_diagonal(&Vector3::new(s[0], s[1], sign * s[2])) * r2;
        let dst = map(&linear, t, &src);
        let f = fit_affine(&moving(&src), &fixed(&dst)).expect("well-posed");
        prop_assert!(f.fre_rms_mm < EXACT_MM);
        for (x, y) in probe.iter().zip(map(&linear, t, &probe)) {
            let e = dist(f.warp.apply_raw(*x), y);
            prop_assert!(e < EXACT_MM, "error {e:e} mm, flatness {}", flatness(&src));
        }
    }

    /// pull-back ∘ forward = identity: exactly for rigid fits even with noisy pairs, and for every
    /// kind on exact pairs. The exact inverse of a fit composes to the identity too.
    #[test]
    fn pullback_after_forward_is_identity(src in points(4, 10), rot in rotation(), scale in 0.5..2.0f64,
                                          t in [coord(), coord(), coord()],
                                          noise in prop::collection::vec([-3.0..3.0f64, -3.0..3.0, -3.0..3.0], 10),
                                          probe in points(5, 5)) {
        prop_assume!(flatness(&src) > 1e-2);
        let (m, exact) = (moving(&src), map(&(rot * scale), t, &src));
        let noisy: Vec<[f64; 3]> = exact.iter().zip(&noise).map(|(q, e)| [q[0] + e[0], q[1] + e[1], q[2] + e[2]]).collect();
        let check = |kind: LinearKind, dst: &[[f64; 3]]| -> Result<(), TestCaseError> {
            let fixed_from_moving = fit_forward(kind, &m, &fixed(dst)).expect("forward").warp;
            let moving_from_fixed = fit_pullback(kind, &m, &fixed(dst)).expect("pull-back").warp;
            let round = moving_from_fixed * fixed_from_moving;
            let exact_inverse = fixed_from_moving.inverse().expect("invertible");
            for x in &probe {
                prop_assert!(dist(round.apply_raw(*x), *x) < EXACT_MM, "{kind}: {:?}", round);
                prop_assert!(dist(exact_inverse.apply_raw(fixed_from_moving.apply_raw(*x)), *x) < EXACT_MM);
            }
            Ok(())
        };
        check(LinearKind::Rigid, &map(&rot, t, &src))?;
        check(LinearKind::Rigid, &noisy)?;
        check(LinearKind::Similarity, &exact)?;
        check(LinearKind::Affine, &exact)?;
    }

    /// Collinear sets never give a rotation, coplanar sets never an affine map, and nothing is NaN.
    #[test]
    fn degenerate_configurations_are_errors(a in [coord(), coord(), coord()], d in [coord(), coord(), coord()],
                                            e in [coord(), coord(), coord()],
                                            ts in prop::collection::vec(-3.0..3.0f64, 3..10),
                                            us in prop::collection::vec(-3.0..3.0f64, 10)) {
        let line: Vec<[f64; 3]> = ts.iter().map(|t| [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]]).collect();
        let plane: Vec<[f64; 3]> = ts.iter().zip(&us)
            .map(|(t, u)| [a[0] + t * d[0] + u * e[0], a[1] + t * d[1] + u * e[1], a[2] + t * d[2] + u * e[2]])
            .collect();
        for kind in [LinearKind::Rigid, LinearKind::Similarity, LinearKind::Affine] {
            let r = fit(kind, &moving(&line), &fixed(&line));
            prop_assert!(
                matches!(
                    r,
                    Err(SolverError::Flat { shape: "collinear", .. } | SolverError::Coincident { .. } | SolverError::TooFew { .. })
                ),
                "{kind} on a line: {r:?}"
            );
            prop_assert!(predicted_tre_for(kind, &moving(&line), 1.0, Point3::new(1.0, 2.0, 3.0)).is_err());
        }
        prop_assert!(predicted_tre(&moving(&line), 1.0, Point3::new(1.0, 2.0, 3.0)).is_infinite());
        if plane.len() >= 4 {
            let r = fit_affine(&moving(&plane), &fixed(&plane));
            prop_assert!(
                matches!(r, Err(SolverError::Flat { .. } | SolverError::Coincident { .. })),
                "affine on a plane: {r:?}"
            );
        }
    }
}

/// A triangle whose smallest height is at least 10 % of its longest side.
fn triangle_ok(p: &[[f64; 3]]) -> bool {
    let (a, b, c) = (Vector3::from(p[0]), Vector3::from(p[1]), Vector3::from(p[2]));
    let area2 = (b - a).cross(&(c - a)).norm();
    let longest = (b - a).norm().max((c - a).norm()).max((c - b).norm());
    longest > 1.0 && area2 / longest > 0.1 * longest
}

#[test]
fn too_few_and_invalid_inputs_are_errors() {
    let p = moving(&[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]]);
    let q = fixed(&[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]]);
    for kind in LinearKind::ALL {
        for n in 0..kind.min_points() {
            assert_eq!(
                fit(kind, &p[..n], &q[..n]).err(),
                Some(SolverError::TooFew { method: kind.name(), needed: kind.min_points(), got: n })
            );
        }
        assert!(matches!(fit(kind, &p, &q[..3]), Err(SolverError::LengthMismatch { from_len: 4, to_len: 3, .. })));
        let mut bad = q.clone();
        bad[2] = Point3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(fit(kind, &p, &bad).err(), Some(SolverError::NonFinite { pair: 3 }));
        // Every source point at one place.
        let same = vec![Point3::<Moving>::new(1.0, 2.0, 3.0); 5];
        assert!(matches!(
            fit(kind, &same, &q[..1].repeat(5)),
            Err(SolverError::Coincident { space: "moving", count: 5, .. })
        ));
    }
    // Targets collapsed to one point: the rotation is undetermined.
    let collapsed = vec![Point3::<Fixed>::new(5.0, 5.0, 5.0); 4];
    assert!(matches!(fit_rigid(&p, &collapsed), Err(SolverError::Coincident { space: "fixed", .. })));
    assert!(matches!(fit_similarity(&p, &collapsed), Err(SolverError::Coincident { space: "fixed", .. })));
    // A coplanar set is fine for rigid and similarity fits (three or more non-collinear points).
    let f = fit_rigid(&p[..3], &q[..3]).expect("a triangle fixes the rotation");
    assert_proper_rotation(&f.warp.linear());
    // predicted_tre never returns NaN.
    assert!(predicted_tre(&p[..2], 1.0, Point3::new(0.0, 0.0, 0.0)).is_infinite());
    assert!(predicted_tre(&p, -1.0, Point3::new(0.0, 0.0, 0.0)).is_infinite());
    assert!(predicted_tre(&p, 1.0, Point3::new(f64::NAN, 0.0, 0.0)).is_infinite());
    assert_eq!(fle_from_fre(LinearKind::Rigid, 1.0, 2), None);
    assert_eq!(fle_from_fre(LinearKind::Affine, 1.0, 4), None);
}

#[test]
fn transform_round_trip_and_names() {
    let w: AffineWarp<Fixed, Moving> =
        AffineWarp::new(Matrix3::new(1.0, 0.2, 0.0, 0.0, 2.0, 0.1, 0.3, 0.0, 0.5), [1.0, -2.0, 3.0]);
    let t = w.to_transform();
    assert_eq!(AffineWarp::from_transform(&t), w);
    let x = Point3::<Moving>::new(4.0, 5.0, 6.0);
    assert!(dist(t.apply_point(x).coords(), w.apply(x).coords()) < 1e-12);
    assert_eq!(w.jacobian_raw([9.0, 9.0, 9.0]), w.linear());
    let singular: AffineWarp<Fixed, Moving> = AffineWarp::new(Matrix3::zeros(), [0.0; 3]);
    assert!(matches!(singular.inverse(), Err(SolverError::Degenerate(_))));
    for kind in LinearKind::ALL {
        assert_eq!(kind.to_string().parse::<LinearKind>(), Ok(kind));
    }
    assert!("shear".parse::<LinearKind>().is_err());
}

/// Monte-Carlo check of the predicted TRE: perturb the target points with isotropic Gaussian FLE,
/// refit, and compare the mean squared TRE at a few targets with the prediction. Returns the worst
/// relative error of the RMS TRE and of the FLE estimated from FRE.
fn monte_carlo(kind: LinearKind, n: usize, trials: usize, seed: u64) -> (f64, f64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let fle_rms_mm = 1.0;
    let sigma = fle_rms_mm / 3.0_f64.sqrt();
    // Fiducials spread anisotropically (a flat-ish head): 80 × 60 × 30 mm half-extents.
    let src: Vec<[f64; 3]> = (0..n)
        .map(|_| [rng.random_range(-80.0..80.0), rng.random_range(-60.0..60.0), rng.random_range(-30.0..30.0)])
        .collect();
    let linear = *UnitQuaternion::from_euler_angles(0.3, -0.2, 0.7).to_rotation_matrix().matrix() * 1.1;
    let linear = if kind == LinearKind::Rigid { linear / 1.1 } else { linear };
    let t = [10.0, -20.0, 5.0];
    let dst = map(&linear, t, &src);
    let targets = [[0.0, 0.0, 0.0], [90.0, 40.0, -60.0], [-30.0, 100.0, 20.0], [20.0, -10.0, 80.0]];
    let truth = map(&linear, t, &targets);
    let mut tre_sq = [0.0; 4];
    let mut fle_sq_est = 0.0;
    for _ in 0..trials {
        let noisy: Vec<[f64; 3]> = dst
            .iter()
            .map(|q| [q[0] + sigma * gauss(&mut rng), q[1] + sigma * gauss(&mut rng), q[2] + sigma * gauss(&mut rng)])
            .collect();
        let f = fit(kind, &moving(&src), &fixed(&noisy)).expect("well-posed");
        for (k, r) in targets.iter().enumerate() {
            tre_sq[k] += dist(f.warp.apply_raw(*r), truth[k]).powi(2);
        }
        fle_sq_est += f.estimated_fle_rms_mm().expect("N large enough").powi(2);
    }
    let predictor = TrePredictor::new(kind, &moving(&src), fle_rms_mm).expect("well-posed");
    let mut worst: f64 = 0.0;
    for (k, r) in targets.iter().enumerate() {
        let simulated = (tre_sq[k] / trials as f64).sqrt();
        let predicted = predictor.rms_tre_mm(Point3::from_array(*r));
        eprintln!("{kind} N={n} target {r:?}: simulated RMS TRE {simulated:.4} mm, predicted {predicted:.4} mm");
        worst = worst.max((simulated / predicted - 1.0).abs());
    }
    let fle_est = (fle_sq_est / trials as f64).sqrt();
    eprintln!("{kind} N={n}: FLE {fle_rms_mm} mm, mean estimate from FRE {fle_est:.4} mm");
    (worst, (fle_est / fle_rms_mm - 1.0).abs())
}

/// Fitzpatrick, West & Maurer (1998) for the rigid fit, within 10 % of 2 000 seeded trials.
#[test]
fn rigid_tre_prediction_matches_monte_carlo() {
    for (n, seed) in [(6, 1), (12, 2)] {
        let (tre_err, fle_err) = monte_carlo(LinearKind::Rigid, n, 2000, seed);
        assert!(tre_err < 0.10, "rigid N={n}: TRE prediction off by {:.1} %", 100.0 * tre_err);
        assert!(fle_err < 0.05, "rigid N={n}: FLE estimate off by {:.1} %", 100.0 * fle_err);
    }
}

/// The similarity and affine predictions (our first-order extensions), within 10 %.
#[test]
fn similarity_and_affine_tre_prediction_matches_monte_carlo() {
    for kind in [LinearKind::Similarity, LinearKind::Affine] {
        let (tre_err, fle_err) = monte_carlo(kind, 8, 2000, 3);
        assert!(tre_err < 0.10, "{kind}: TRE prediction off by {:.1} %", 100.0 * tre_err);
        assert!(fle_err < 0.05, "{kind}: FLE estimate off by {:.1} %", 100.0 * fle_err);
    }
}

#[test]
fn predicted_tre_is_smallest_at_the_centroid() {
    let p = moving(&[[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 80.0, 0.0], [0.0, 0.0, 60.0], [50.0, 50.0, 50.0]]);
    let centroid = Point3::new(30.0, 26.0, 22.0);
    let at_centre = predicted_tre(&p, 2.0, centroid);
    assert!((at_centre - 2.0 / 5.0_f64.sqrt()).abs() < 1e-12, "{at_centre}");
    let far = predicted_tre(&p, 2.0, Point3::new(300.0, 26.0, 22.0));
    assert!(far > at_centre);
    for kind in LinearKind::ALL {
        let v = predicted_tre_for(kind, &p, 2.0, centroid).expect("well-posed");
        assert!((v - at_centre).abs() < 1e-12, "{kind}: {v}");
    }
}
