//! Laws of the seeded synthetic warps: round trips, amplitudes, determinism and fold-freeness.

use nalgebra::Matrix3;
use warpbench_io::geometry::Point3;
use warpbench_solver::synthetic::{
    INVERSE_TOLERANCE_MM, SyntheticKind, SyntheticWarp, grid_max_displacement_mm, held_out_pairs, held_out_points,
    sample_pairs,
};
use warpbench_solver::{Aabb, Fixed, Moving, SolverError, Warp};

/// Round-trip tolerance, mm.
const ROUND_TRIP_MM: f64 = 1e-6;
/// The amplitude the docs call fold-free for every kind over this box (10 mm over ~200 mm).
const FOLD_FREE_MM: f64 = 10.0;

/// A 200 × 180 × 160 mm box, off the origin, so that axes and edges differ.
fn domain() -> Aabb<Moving> {
    Aabb::new(Point3::new(-90.0, -110.0, -70.0), Point3::new(110.0, 70.0, 90.0))
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn warp(kind: SyntheticKind, amplitude_mm: f64, seed: u64) -> SyntheticWarp {
    SyntheticWarp::new(kind, domain(), amplitude_mm, seed).expect("valid parameters")
}

/// Amplitudes to exercise per kind: the fold-free 10 mm, and a larger one inside each kind's
/// documented guarantee (sine < 0.276 L_min, bump < 0.206 L_min; twist/bend always).
fn amplitudes(kind: SyntheticKind) -> &'static [f64] {
    match kind {
        SyntheticKind::Sine | SyntheticKind::Twist | SyntheticKind::Bend => &[FOLD_FREE_MM, 30.0],
        SyntheticKind::Bump => &[FOLD_FREE_MM, 25.0],
        SyntheticKind::TpsRandom | SyntheticKind::BSplineRandom => &[FOLD_FREE_MM],
    }
}

#[test]
fn forward_after_pullback_is_identity() {
    for kind in SyntheticKind::ALL {
        for &amplitude in amplitudes(kind) {
            for seed in 0..3 {
                let d = warp(kind, amplitude, seed);
                let u = d.pullback();
                let mut worst_fu: f64 = 0.0;
                let mut worst_uf: f64 = 0.0;
                for x in held_out_points(domain(), 200, seed) {
                    // u ∘ d = id on the moving box, d ∘ u = id on its image.
                    let y = d.apply(x);
                    worst_uf = worst_uf.max(dist(u.apply(y).coords(), x.coords()));
                    let y_fixed = Point3::<Fixed>::from_array(x.coords());
                    worst_fu = worst_fu.max(dist(d.apply(u.apply(y_fixed)).coords(), y_fixed.coords()));
                }
                assert!(worst_uf < ROUND_TRIP_MM, "{kind} A={amplitude} seed {seed}: u∘d off by {worst_uf:e} mm");
                assert!(worst_fu < ROUND_TRIP_MM, "{kind} A={amplitude} seed {seed}: d∘u off by {worst_fu:e} mm");
                assert_eq!(u.non_converged_count(), 0, "{kind} A={amplitude} seed {seed}");
            }
        }
    }
}

#[test]
fn invert_point_reports_convergence() {
    for kind in SyntheticKind::ALL {
        let u = warp(kind, FOLD_FREE_MM, 7).pullback();
        let e = u.invert_point(Point3::new(3.0, -4.0, 5.0));
        assert!(e.converged && e.residual_mm <= INVERSE_TOLERANCE_MM, "{kind}: {e:?}");
        assert_eq!(kind.has_analytic_inverse(), e.iterations == 0, "{kind}: {e:?}");
        let bad = u.invert_point(Point3::new(f64::NAN, 0.0, 0.0));
        assert!(!bad.converged);
    }
}

#[test]
fn measured_amplitude_matches_request() {
    for kind in SyntheticKind::ALL {
        for &amplitude in amplitudes(kind) {
            for seed in 0..3 {
                let d = warp(kind, amplitude, seed);
                let measured = d.max_displacement_mm();
                eprintln!("{kind} A={amplitude} seed {seed}: measured max displacement {measured:.6} mm");
                match kind {
                    // Exact by construction (attained at a corner, or normalised on the same grid).
                    SyntheticKind::Twist
                    | SyntheticKind::Bend
                    | SyntheticKind::TpsRandom
                    | SyntheticKind::BSplineRandom => {
                        assert!((measured - amplitude).abs() < 1e-9 * amplitude, "{kind}: {measured} vs {amplitude}");
                    }
                    // The analytic peak is A; the grid sees at most that and at least 95 % of it.
                    SyntheticKind::Sine | SyntheticKind::Bump => {
                        assert!(
                            measured <= amplitude * (1.0 + 1e-12) && measured >= 0.95 * amplitude,
                            "{kind}: {measured}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn zero_amplitude_is_the_identity() {
    for kind in SyntheticKind::ALL {
        let d = warp(kind, 0.0, 3);
        for x in held_out_points(domain(), 20, 1) {
            assert!(dist(d.apply(x).coords(), x.coords()) < 1e-12, "{kind}");
        }
        assert!(d.max_displacement_mm() < 1e-12);
    }
}

#[test]
fn seeds_are_deterministic_and_distinct() {
    for kind in SyntheticKind::ALL {
        let (a, b, c) = (warp(kind, FOLD_FREE_MM, 11), warp(kind, FOLD_FREE_MM, 11), warp(kind, FOLD_FREE_MM, 12));
        let mut differ: f64 = 0.0;
        for x in held_out_points(domain(), 50, 0) {
            let same = a.apply(x).coords().iter().zip(b.apply(x).coords()).all(|(u, v)| u.to_bits() == v.to_bits());
            assert!(same, "{kind}: the same seed must give the same warp, bit for bit");
            differ = differ.max(dist(a.apply(x).coords(), c.apply(x).coords()));
        }
        assert!(differ > 0.1, "{kind}: seeds 11 and 12 give nearly the same warp ({differ} mm)");
    }
}

#[test]
fn jacobian_determinant_is_positive_at_fold_free_amplitudes() {
    let n = 15;
    let (lo, size) = (domain().min.coords(), domain().size());
    for kind in SyntheticKind::ALL {
        for &amplitude in amplitudes(kind) {
            for seed in 0..3 {
                let d = warp(kind, amplitude, seed);
                let mut min_det = f64::INFINITY;
                for k in 0..n {
                    for j in 0..n {
                        for i in 0..n {
                            let t = [i, j, k].map(|v| v as f64 / (n - 1) as f64);
                            let x = [lo[0] + size[0] * t[0], lo[1] + size[1] * t[1], lo[2] + size[2] * t[2]];
                            min_det = min_det.min(d.jacobian_raw(x).determinant());
                        }
                    }
                }
                if seed == 0 {
                    eprintln!(
                        "{kind} A={amplitude}: min det J {min_det:.4}, Lipschitz bound {:?}",
                        d.displacement_lipschitz_bound()
                    );
                }
                assert!(min_det > 0.0, "{kind} A={amplitude} seed {seed}: det J = {min_det}");
                if let (Some(l), SyntheticKind::Sine | SyntheticKind::Bump) = (d.displacement_lipschitz_bound(), kind) {
                    assert!(l < 1.0, "{kind}: bound {l}");
                }
            }
        }
    }
}

#[test]
fn analytic_jacobian_matches_central_differences() {
    let h = 1e-4;
    for kind in SyntheticKind::ALL {
        let d = warp(kind, 2.0 * FOLD_FREE_MM, 5);
        for x in held_out_points(domain(), 20, 9) {
            let x = x.coords();
            let numeric = Matrix3::from_fn(|r, c| {
                let (mut xp, mut xm) = (x, x);
                xp[c] += h;
                xm[c] -= h;
                (d.apply_raw(xp)[r] - d.apply_raw(xm)[r]) / (2.0 * h)
            });
            let err = (d.jacobian_raw(x) - numeric).amax();
            assert!(err < 1e-6, "{kind} at {x:?}: analytic vs numeric Jacobian differ by {err:e}");
        }
    }
}

#[test]
fn names_round_trip() {
    let names: Vec<String> = SyntheticKind::ALL.iter().map(ToString::to_string).collect();
    assert_eq!(names, ["sine", "twist", "bend", "bump", "tps-random", "bspline-random"]);
    for kind in SyntheticKind::ALL {
        assert_eq!(kind.to_string().parse::<SyntheticKind>(), Ok(kind));
    }
    assert!(matches!("wobble".parse::<SyntheticKind>(), Err(SolverError::InvalidParameter(_))));
}

#[test]
fn invalid_parameters_are_errors() {
    let flat = Aabb::new(Point3::new(0.0, 0.0, 0.0), Point3::new(100.0, 100.0, 0.0));
    let nan = Aabb::new(Point3::new(f64::NAN, 0.0, 0.0), Point3::new(100.0, 100.0, 100.0));
    for kind in SyntheticKind::ALL {
        for bad_box in [flat, nan] {
            assert!(matches!(SyntheticWarp::new(kind, bad_box, 5.0, 0), Err(SolverError::InvalidParameter(_))));
        }
        for bad in [-1.0, f64::NAN, f64::INFINITY, 1e6] {
            assert!(
                matches!(SyntheticWarp::new(kind, domain(), bad, 0), Err(SolverError::InvalidParameter(_))),
                "{kind} with amplitude {bad}"
            );
        }
    }
    // The sine limit is √3·L_min/(2π) = 44.1 mm for L_min = 160 mm.
    assert!(SyntheticWarp::new(SyntheticKind::Sine, domain(), 44.0, 0).is_ok());
    assert!(SyntheticWarp::new(SyntheticKind::Sine, domain(), 44.2, 0).is_err());
}

#[test]
fn sampled_pairs_follow_the_warp() {
    let d = warp(SyntheticKind::Bump, FOLD_FREE_MM, 4);
    let (moving, fixed) = sample_pairs(&d, domain(), 30, 8);
    let (again, _) = sample_pairs(&d, domain(), 30, 8);
    assert_eq!(moving, again);
    assert_eq!(moving.len(), 30);
    for (p, q) in moving.iter().zip(&fixed) {
        assert!(domain().contains(p));
        assert_eq!(d.apply(*p), *q);
    }
    let (held, held_fixed) = held_out_pairs(&d, domain(), 30, 8);
    assert!(held.iter().zip(&moving).all(|(a, b)| a != b), "held-out points must not be the landmarks");
    assert_eq!(held_fixed[0], d.apply(held[0]));
    // Works for any forward warp, e.g. a boxed one.
    let boxed: Box<dyn Warp<Fixed, Moving>> = Box::new(d.clone());
    assert_eq!(sample_pairs(boxed.as_ref(), domain(), 5, 8).1, fixed[..5].to_vec());
    assert!((grid_max_displacement_mm(&d, domain(), 41) - d.max_displacement_mm()).abs() < 1e-15);
}

/// Beyond the fold-free range the numerical inverse may fail; it says so and never returns NaN.
#[test]
fn folding_warps_never_give_nan() {
    for kind in [SyntheticKind::TpsRandom, SyntheticKind::BSplineRandom] {
        let d = warp(kind, 150.0, 1);
        let u = d.pullback();
        let mut failed = 0;
        for y in held_out_points(domain(), 100, 2) {
            let e = u.invert_point(Point3::from_array(y.coords()));
            assert!(e.point.iter().all(|v| v.is_finite()) && e.residual_mm.is_finite(), "{kind}: {e:?}");
            assert_eq!(e.converged, e.residual_mm <= INVERSE_TOLERANCE_MM);
            failed += usize::from(!e.converged);
            assert!(u.apply(Point3::<Fixed>::from_array(y.coords())).is_finite());
        }
        assert_eq!(u.non_converged_count(), failed, "{kind}");
        eprintln!("{kind} at 150 mm: {failed} of 100 points did not invert");
    }
}
