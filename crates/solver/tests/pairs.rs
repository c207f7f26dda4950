//! Laws of the one validation every fit runs ([`warpbench_solver::pairs`]): every method, in both directions,
//! refuses the same degenerate pair sets with the same typed error (pairs numbered from 1, sides named moving and
//! fixed), and accepts the suspicious ones with the same warnings.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::bspline::{BSplineParams, HierarchicalBSpline};
use warpbench_solver::method::Method;
use warpbench_solver::pairs::{self, PairWarning};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::tps::Tps;
use warpbench_solver::{SolverError, Warp};

const METHODS: [&str; 5] = ["tps", "hbspline", "affine", "similarity", "rigid"];

fn methods() -> impl Iterator<Item = Method> {
    METHODS.into_iter().map(|m| Method::from_name(m).expect("method"))
}

fn moving_box() -> Aabb<Moving> {
    Aabb::new(Point3::new(-150.0, -150.0, -150.0), Point3::new(150.0, 150.0, 150.0))
}

fn fixed_box() -> Aabb<Fixed> {
    Aabb::new(Point3::new(-150.0, -150.0, -150.0), Point3::new(150.0, 150.0, 150.0))
}

/// `n` pairs spread through a 200 mm cube, the fixed points a smooth deformation of the moving ones.
fn spread(seed: u64, n: usize) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let p: Vec<[f64; 3]> = (0..n).map(|_| std::array::from_fn(|_| rng.random_range(-100.0..100.0))).collect();
    let q = p.iter().map(|v| Point3::new(v[0] + 3.0 + 0.02 * v[1], v[1] - 2.0, v[2] + 0.01 * v[0] * v[2] / 10.0));
    (p.iter().map(|v| Point3::from_array(*v)).collect(), q.collect())
}

/// Fits `method` both ways (forward on (p, q), pull-back on (q, p)), returning both errors.
fn both_ways(method: &Method, p: &[Point3<Moving>], q: &[Point3<Fixed>]) -> (Option<SolverError>, Option<SolverError>) {
    (method.fit(p, q, moving_box()).err(), method.fit(q, p, fixed_box()).err())
}

/// Every method refuses in both directions with an error `accept`s, and `check` says the same.
fn refused_by_all(p: &[Point3<Moving>], q: &[Point3<Fixed>], accept: impl Fn(&Method, &SolverError) -> bool) {
    for method in methods() {
        let (forward, pullback) = both_ways(&method, p, q);
        for (dir, e) in [("forward", forward), ("pull-back", pullback)] {
            let e = e.unwrap_or_else(|| panic!("{method} {dir}: accepted"));
            assert!(accept(&method, &e), "{method} {dir}: {e:?}");
            let text = e.to_string();
            assert!(!text.contains("source") && !text.contains("target"), "{method} {dir}: {text}");
        }
        assert!(method.check(p, q).is_err() && method.check(q, p).is_err(), "{method}: check accepted");
    }
}

#[test]
fn all_fixed_points_at_one_place_are_refused_by_every_method_both_ways() {
    let (p, _) = spread(1, 12);
    let q = vec![Point3::<Fixed>::new(10.0, 20.0, 30.0); p.len()];
    refused_by_all(&p, &q, |_, e| matches!(e, SolverError::Coincident { space: "fixed", count: 12, .. }));
}

#[test]
fn all_moving_points_at_one_place_are_refused_by_every_method_both_ways() {
    let (_, q) = spread(2, 12);
    let p = vec![Point3::<Moving>::new(-5.0, 0.0, 7.0); q.len()];
    refused_by_all(&p, &q, |_, e| matches!(e, SolverError::Coincident { space: "moving", .. }));
    assert!(
        SolverError::Coincident { space: "moving", count: 12, at_mm: [-5.0, 0.0, 7.0] }
            .to_string()
            .contains("all 12 moving points are at one position (-5.00, 0.00, 7.00) mm")
    );
}

#[test]
fn too_few_pairs_are_refused_by_the_methods_minimum() {
    let (p, q) = spread(3, 4);
    for (name, needed) in [("tps", 4), ("hbspline", 4), ("affine", 4), ("similarity", 3), ("rigid", 3)] {
        let method = Method::from_name(name).expect("method");
        assert_eq!(method.needs().min_pairs, needed, "{method}");
        for n in 0..needed {
            let (forward, pullback) = both_ways(&method, &p[..n], &q[..n]);
            for e in [forward, pullback] {
                assert!(
                    matches!(e, Some(SolverError::TooFew { needed: m, got, .. }) if m == needed && got == n),
                    "{method}, {n} pairs: {e:?}"
                );
            }
        }
        let (forward, pullback) = both_ways(&method, &p[..needed], &q[..needed]);
        assert!(forward.is_none() && pullback.is_none(), "{method}: {forward:?} {pullback:?}");
    }
}

#[test]
fn a_flat_side_is_refused_where_the_method_needs_its_extent() {
    let (p, q) = spread(4, 10);
    // Fixed points on a tilted plane, then on a line; the moving points stay spread.
    let plane: Vec<Point3<Fixed>> =
        q.iter().map(Point3::coords).map(|v| Point3::new(v[0], v[1], 0.3 * v[0] - 0.2 * v[1] + 5.0)).collect();
    let line: Vec<Point3<Fixed>> = q.iter().map(|v| v.coords()[0]).map(|t| Point3::new(t, 2.0 * t - 1.0, -t)).collect();
    for method in methods() {
        let needs_volume = method.needs().spread == pairs::Spread::NotCoplanar;
        let (forward, pullback) = both_ways(&method, &p, &plane);
        for e in [forward, pullback] {
            if needs_volume {
                assert!(
                    matches!(e, Some(SolverError::Flat { space: "fixed", shape: "coplanar", count: 10, .. })),
                    "{method}: {e:?}"
                );
            } else {
                assert!(e.is_none(), "{method} on a plane: {e:?}");
            }
        }
        let (forward, pullback) = both_ways(&method, &p, &line);
        for e in [forward, pullback] {
            assert!(matches!(e, Some(SolverError::Flat { space: "fixed", shape: "collinear", .. })), "{method}: {e:?}");
        }
    }
}

#[test]
fn one_point_with_two_partners_is_refused_on_either_side_naming_both_pairs() {
    let (mut p, mut q) = spread(5, 9);
    // Pair 10 repeats pair 4's moving point with another fixed point.
    p.push(p[3]);
    q.push(Point3::new(-60.0, 40.0, 10.0));
    refused_by_all(&p, &q, |_, e| {
        *e == SolverError::Conflict { space: "moving", other: "fixed", first: 4, second: 10 }
    });
    let text = SolverError::Conflict { space: "moving", other: "fixed", first: 4, second: 10 }.to_string();
    assert!(text.contains("landmarks 4 and 10 have the same moving point but different fixed points"), "{text}");
    // And on the fixed side: pair 10 repeats pair 2's fixed point with another moving point.
    let (mut p, mut q) = spread(6, 9);
    q.push(q[1]);
    p.push(Point3::new(12.0, -70.0, 33.0));
    refused_by_all(&p, &q, |_, e| {
        *e == SolverError::Conflict { space: "fixed", other: "moving", first: 2, second: 10 }
    });
}

#[test]
fn a_repeated_pair_warns_and_counts_once_in_every_method() {
    let (p, q) = spread(7, 12);
    let (mut p2, mut q2) = (p.clone(), q.clone());
    p2.push(p[4]);
    q2.push(q[4]);
    let repeated = PairWarning::Repeated { first: 5, second: 13 };
    assert!(repeated.to_string().contains("landmarks 5 and 13 are the same pair"), "{repeated}");
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let probes: Vec<Point3<Fixed>> =
        (0..30).map(|_| Point3::from_array(std::array::from_fn(|_| rng.random_range(-90.0..90.0)))).collect();
    for method in methods() {
        assert_eq!(method.check(&p2, &q2), Ok(vec![repeated.clone()]), "{method} forward");
        assert_eq!(method.check(&q2, &p2), Ok(vec![repeated.clone()]), "{method} pull-back");
        let once = method.fit(&q, &p, fixed_box()).expect("fit");
        let twice = method.fit(&q2, &p2, fixed_box()).expect("fit with a repeated pair");
        for x in &probes {
            let d = once.apply(*x).distance(&twice.apply(*x));
            assert!(d < 1e-9, "{method}: the repeated pair changed the warp by {d} mm at {x:?}");
        }
    }
    // The families keep their warnings.
    let tps = Tps::fit(&q2, &p2, 0.0).expect("tps");
    assert_eq!(tps.warnings(), std::slice::from_ref(&repeated));
    let spline = HierarchicalBSpline::fit(&q2, &p2, fixed_box(), &BSplineParams::default()).expect("b-spline");
    assert_eq!(spline.warnings(), [repeated]);
    assert!(Tps::fit(&q, &p, 0.0).expect("tps").warnings().is_empty());
}

#[test]
fn a_nearly_flat_side_fits_with_a_warning() {
    let (p, q) = spread(9, 12);
    // 0.2 mm thick across ~100 mm: above the refusal, below the warning's 1 %.
    let thin: Vec<Point3<Fixed>> = q
        .iter()
        .enumerate()
        .map(|(i, v)| Point3::new(v.coords()[0], v.coords()[1], if i % 2 == 0 { 0.2 } else { -0.2 }))
        .collect();
    for method in methods() {
        let warnings = method.check(&p, &thin).expect("fits");
        let coplanar_matters = method.needs().spread == pairs::Spread::NotCoplanar;
        assert_eq!(
            warnings.iter().any(|w| matches!(w, PairWarning::NearlyFlat { space: "fixed", shape: "coplanar", .. })),
            coplanar_matters,
            "{method}: {warnings:?}"
        );
        assert!(method.fit(&thin, &p, fixed_box()).is_ok(), "{method}");
    }
}

#[test]
fn pair_numbers_are_one_based_and_renumber() {
    let (mut p, q) = spread(10, 8);
    p[5] = Point3::new(f64::NAN, 0.0, 0.0);
    for method in methods() {
        let (forward, pullback) = both_ways(&method, &p, &q);
        assert_eq!(forward, Some(SolverError::NonFinite { pair: 6 }), "{method}");
        assert_eq!(pullback, Some(SolverError::NonFinite { pair: 6 }), "{method}");
    }
    let e = SolverError::Conflict { space: "fixed", other: "moving", first: 2, second: 5 };
    assert_eq!(
        e.renumber(|n| n + 10),
        SolverError::Conflict { space: "fixed", other: "moving", first: 12, second: 15 }
    );
    assert_eq!(
        PairWarning::Repeated { first: 1, second: 3 }.renumber(|n| 2 * n),
        PairWarning::Repeated { first: 2, second: 6 }
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Refusal and warnings do not depend on the direction of the fit or on the order of the pairs (up to
    /// which copy of a repeated pair comes first).
    #[test]
    fn the_verdict_is_the_same_both_ways(seed in 0u64..1000, n in 0usize..12, collapse in 0usize..4) {
        let (mut p, mut q) = spread(seed, n);
        match collapse {
            1 => q.iter_mut().for_each(|v| *v = Point3::new(1.0, 1.0, 1.0)),
            2 if n > 4 => { p[n - 1] = p[0]; q[n - 1] = q[0]; }
            3 if n > 4 => { p[n - 1] = p[1]; }
            _ => {}
        }
        for method in methods() {
            let forward = method.check(&p, &q);
            let pullback = method.check(&q, &p);
            prop_assert_eq!(forward.is_ok(), pullback.is_ok(), "{}: {:?} vs {:?}", method, forward, pullback);
            if let (Ok(f), Ok(b)) = (&forward, &pullback) {
                prop_assert_eq!(f.len(), b.len());
            }
            // A fit that passes the check does not fail on a degenerate configuration.
            if forward.is_ok() {
                let fit = method.fit(&p, &q, moving_box());
                prop_assert!(fit.is_ok(), "{}: checked, then {:?}", method, fit.err());
            }
        }
    }
}
