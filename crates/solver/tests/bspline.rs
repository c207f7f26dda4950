//! Laws of the hierarchical B-spline warp (Lee, Wolberg & Shin 1997): partition of unity, exact
//! refinement, convergence to the landmarks, reproduction of constant and linear displacements, the
//! analytic Jacobian against finite differences, the pull-back at reversed landmarks, the separable grid
//! kernels against point-wise evaluation, and degenerate input.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::bspline::{
    BSplineParams, ControlLattice, HierarchicalBSpline, RegularGrid, basis, basis_derivative,
};
use warpbench_solver::{Aabb, Fixed, Moving, Parallelism, SolverError, Warp};

/// Round-off allowance for values of `scale_mm` after a few hundred multiply-adds.
fn eps_mm(scale_mm: f64) -> f64 {
    1e-12 * scale_mm.max(1.0) * 64.0
}

fn domain<S: warpbench_io::geometry::Space>() -> Aabb<S> {
    Aabb::new(Point3::new(-100.0, -80.0, -60.0), Point3::new(100.0, 120.0, 140.0))
}

fn random_point(rng: &mut ChaCha8Rng, lo: [f64; 3], hi: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|a| rng.random_range(lo[a]..hi[a]))
}

fn random_landmarks(seed: u64, n: usize, amplitude_mm: f64) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d: Aabb<Moving> = domain();
    let (lo, hi) = (d.min.coords(), d.max.coords());
    let mut src = Vec::with_capacity(n);
    let mut dst = Vec::with_capacity(n);
    for _ in 0..n {
        let p = random_point(&mut rng, lo, hi);
        let q: [f64; 3] = std::array::from_fn(|a| p[a] + rng.random_range(-amplitude_mm..amplitude_mm));
        src.push(Point3::from_array(p));
        dst.push(Point3::from_array(q));
    }
    (src, dst)
}

/// The smallest ∞-norm distance between two points (how many cells a lattice needs to tell them apart).
fn min_separation_mm<S: warpbench_io::geometry::Space>(points: &[Point3<S>]) -> f64 {
    let mut best = f64::INFINITY;
    for (i, p) in points.iter().enumerate() {
        for q in &points[i + 1..] {
            let (a, b) = (p.coords(), q.coords());
            best = best.min((0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max));
        }
    }
    best
}

fn max_diff(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max)
}

/// The smallest eigenvalue of the points' scatter matrix over its largest: 0 for coplanar points, 1 for isotropic ones.
fn spread(points: &[[f64; 3]]) -> f64 {
    let n = points.len() as f64;
    let mean: [f64; 3] = std::array::from_fn(|a| points.iter().map(|p| p[a]).sum::<f64>() / n);
    let scatter =
        nalgebra::Matrix3::from_fn(|r, c| points.iter().map(|p| (p[r] - mean[r]) * (p[c] - mean[c])).sum::<f64>());
    let eigenvalues = nalgebra::SymmetricEigen::new(scatter).eigenvalues;
    let (lo, hi) = eigenvalues.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), &l| (lo.min(l), hi.max(l)));
    if hi > 0.0 { lo / hi } else { 0.0 }
}

fn norm(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn basis_is_a_nonnegative_partition_of_unity(t in 0.0..=1.0f64) {
        let b = basis(t);
        prop_assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        prop_assert!(b.iter().all(|&v| v >= 0.0));
        let d = basis_derivative(t);
        prop_assert!(d.iter().sum::<f64>().abs() < 1e-15);
        // The derivative agrees with a central difference of the basis.
        let h = 1e-6;
        let (bp, bm) = (basis(t + h), basis(t - h));
        for a in 0..4 {
            prop_assert!(((bp[a] - bm[a]) / (2.0 * h) - d[a]).abs() < 1e-8);
        }
    }

    #[test]
    fn refinement_leaves_the_field_unchanged(
        seed in any::<u64>(),
        cells in prop::array::uniform3(1usize..5),
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (lo, hi) = ([-100.0, -80.0, -60.0], [100.0, 120.0, 140.0]);
        let mut coarse = ControlLattice::zeros(cells, lo, hi).expect("small lattice");
        for c in coarse.coefficients_mut() {
            *c = rng.random_range(-10.0..10.0);
        }
        let fine = coarse.refine().expect("refine");
        prop_assert_eq!(fine.cells(), [cells[0] * 2, cells[1] * 2, cells[2] * 2]);
        let twice = coarse.refined(2).expect("refine twice");
        let mut worst = 0.0_f64;
        for _ in 0..200 {
            // Inside and a little outside the box (clamped).
            let x = random_point(&mut rng, [-120.0, -100.0, -80.0], [120.0, 140.0, 160.0]);
            let f = coarse.eval(x);
            worst = worst.max(max_diff(f, fine.eval(x))).max(max_diff(f, twice.eval(x)));
        }
        prop_assert!(worst < 1e-9, "refined field differs by {worst} mm");
    }

    #[test]
    fn enough_levels_approach_the_landmarks(seed in any::<u64>(), n in 4usize..40) {
        let (src, dst) = random_landmarks(seed, n, 10.0);
        // "Enough levels" is relative to the closest pair: the finest cell (6.25 mm here) must separate them.
        prop_assume!(min_separation_mm(&src) > 6.25);
        let params = BSplineParams { coarsest: [2, 2, 2], levels: 5, tolerance_mm: 0.05 };
        let w = HierarchicalBSpline::fit_forward(&src, &dst, domain(), &params).expect("fit");
        let worst = src.iter().zip(&dst).map(|(p, q)| w.apply(*p).distance(q)).fold(0.0, f64::max);
        prop_assert!(worst < params.tolerance_mm, "landmark error {worst} mm ({:?})", w.fit_report());
        prop_assert!((w.fit_report().max_residual_mm - worst).abs() < 1e-9);
    }

    #[test]
    fn constant_displacement_is_reproduced_everywhere(
        seed in any::<u64>(),
        n in 4usize..20,
        shift in prop::array::uniform3(-20.0..20.0f64),
        levels in 1usize..4,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d: Aabb<Moving> = domain();
        let src: Vec<Point3<Moving>> =
            (0..n).map(|_| Point3::from_array(random_point(&mut rng, d.min.coords(), d.max.coords()))).collect();
        let dst: Vec<Point3<Fixed>> = src
            .iter()
            .map(|p| Point3::from_array(std::array::from_fn(|a| p.coords()[a] + shift[a])))
            .collect();
        let params = BSplineParams { coarsest: [2, 3, 2], levels, tolerance_mm: 0.0 };
        let w = HierarchicalBSpline::fit_forward(&src, &dst, d, &params).expect("fit");
        for _ in 0..100 {
            let x = random_point(&mut rng, [-300.0; 3], [300.0; 3]);
            prop_assert!(max_diff(w.displacement_raw(x), shift) < eps_mm(20.0));
        }
    }

    #[test]
    fn linear_displacement_is_reproduced_by_a_single_level(
        seed in any::<u64>(),
        n in 4usize..30,
        a in prop::array::uniform9(-0.1..0.1f64),
        b in prop::array::uniform3(-10.0..10.0f64),
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d: Aabb<Moving> = domain();
        let (lo, hi) = (d.min.coords(), d.max.coords());
        let field = |p: [f64; 3]| -> [f64; 3] {
            std::array::from_fn(|r| b[r] + a[3 * r] * p[0] + a[3 * r + 1] * p[1] + a[3 * r + 2] * p[2])
        };
        let points: Vec<[f64; 3]> = (0..n).map(|_| random_point(&mut rng, lo, hi)).collect();
        // The initial affine fit is a pseudo-inverse solution that drops the directions of the points' scatter below
        // 1e-6 of its largest (module docs): a nearly flat draw of a few points gives an in-plane map only.
        prop_assume!(spread(&points) > 1e-4, "nearly coplanar points");
        let values: Vec<[f64; 3]> = points.iter().map(|&p| field(p)).collect();
        let params = BSplineParams { coarsest: [3, 3, 3], levels: 1, tolerance_mm: 1e-9 };
        let w = HierarchicalBSpline::<Fixed, Moving>::fit_displacements_raw(&points, &values, d, &params)
            .expect("fit");
        prop_assert_eq!(w.lattice().cells(), [3, 3, 3]);
        for _ in 0..100 {
            let x = random_point(&mut rng, lo, hi);
            prop_assert!(max_diff(w.displacement_raw(x), field(x)) < 1e-9, "at {x:?}");
        }
    }

    #[test]
    fn analytic_jacobian_matches_finite_differences(seed in any::<u64>(), n in 4usize..30) {
        let (src, dst) = random_landmarks(seed, n, 10.0);
        let params = BSplineParams { coarsest: [2, 2, 2], levels: 4, tolerance_mm: 0.0 };
        let w = HierarchicalBSpline::fit_forward(&src, &dst, domain(), &params).expect("fit");
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
        for _ in 0..20 {
            // Strictly inside, so the central difference does not cross the clamped boundary.
            let x = random_point(&mut rng, [-99.0, -79.0, -59.0], [99.0, 119.0, 139.0]);
            let analytic = w.jacobian_raw(x);
            let h = 1e-4;
            for c in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[c] += h;
                xm[c] -= h;
                let (fp, fm) = (w.apply_raw(xp), w.apply_raw(xm));
                for r in 0..3 {
                    let fd = (fp[r] - fm[r]) / (2.0 * h);
                    prop_assert!((fd - analytic[(r, c)]).abs() < 1e-6, "J[{r},{c}] {fd} vs {}", analytic[(r, c)]);
                }
            }
        }
    }

    #[test]
    fn pullback_hits_the_reversed_landmarks(seed in any::<u64>(), n in 4usize..30) {
        let (moving, fixed) = random_landmarks(seed, n, 10.0);
        prop_assume!(min_separation_mm(&fixed) > 6.25);
        let params = BSplineParams { coarsest: [2, 2, 2], levels: 5, tolerance_mm: 0.05 };
        let u = HierarchicalBSpline::fit_pullback(&moving, &fixed, domain(), &params).expect("fit");
        for (p, q) in moving.iter().zip(&fixed) {
            let e = u.apply(*q).distance(p);
            prop_assert!(e < params.tolerance_mm, "u(q) misses p by {e} mm");
        }
    }

    #[test]
    fn grid_kernels_match_pointwise_evaluation(seed in any::<u64>(), dims in prop::array::uniform3(1usize..7)) {
        let (src, dst) = random_landmarks(seed, 12, 10.0);
        let params = BSplineParams { coarsest: [2, 3, 2], levels: 3, tolerance_mm: 0.0 };
        let w = HierarchicalBSpline::fit_forward(&src, &dst, domain(), &params).expect("fit");
        // The grid pokes out of the domain on every side, to exercise the clamping.
        let grid = RegularGrid::spanning([-130.0, -90.0, -70.0], [110.0, 150.0, 160.0], dims);
        for par in [Parallelism::Sequential, Parallelism::Rayon] {
            let mut out = vec![[0.0; 3]; grid.len()];
            w.sample_grid_into(&grid, &mut out, par).expect("sample");
            let mut jac = vec![[[0.0; 3]; 3]; grid.len()];
            w.lattice().sample_jacobian_grid_into(&grid, &mut jac, par).expect("jacobian grid");
            for (idx, (o, j)) in out.iter().zip(&jac).enumerate() {
                let x = grid.point(idx);
                prop_assert!(max_diff(*o, w.apply_raw(x)) < eps_mm(200.0));
                let mut jp = [[0.0; 3]; 3];
                w.lattice().jacobian_into(x, &mut jp);
                for r in 0..3 {
                    prop_assert!(max_diff(j[r], jp[r]) < 1e-12);
                }
            }
        }
    }

    #[test]
    fn grid_fit_equals_scattered_fit_at_the_grid_points(seed in any::<u64>(), dims in prop::array::uniform3(2usize..6)) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d: Aabb<Moving> = domain();
        let grid = RegularGrid::spanning([-110.0, -80.0, -60.0], [100.0, 130.0, 140.0], dims);
        let values: Vec<[f64; 3]> =
            (0..grid.len()).map(|_| random_point(&mut rng, [-5.0; 3], [5.0; 3])).collect();
        let points: Vec<[f64; 3]> = (0..grid.len()).map(|i| grid.point(i)).collect();
        let params = BSplineParams { coarsest: [2, 2, 3], levels: 3, tolerance_mm: 0.0 };
        let a = HierarchicalBSpline::<Fixed, Moving>::fit_grid_raw(&grid, &values, d, &params, Parallelism::Rayon).expect("grid fit");
        let b = HierarchicalBSpline::<Fixed, Moving>::fit_displacements_raw(&points, &values, d, &params)
            .expect("scattered fit");
        prop_assert_eq!(a.lattice().cells(), b.lattice().cells());
        let worst = a
            .lattice()
            .coefficients()
            .iter()
            .zip(b.lattice().coefficients())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        prop_assert!(worst < 1e-9, "coefficients differ by {worst}");
    }
}

#[test]
fn no_landmarks_is_the_identity() {
    let params = BSplineParams::default();
    let w = HierarchicalBSpline::<Fixed, Moving>::identity(domain(), &params).expect("identity");
    for x in [[0.0, 0.0, 0.0], [1e3, -1e3, 5.0], [-100.0, -80.0, -60.0]] {
        assert!(max_diff(w.apply_raw(x), x) == 0.0, "identity moved {x:?}");
    }
    assert_eq!(w.fit_report().levels_used, 0);
    // Landmark pairs are checked as for every method: none are too few.
    assert_eq!(
        HierarchicalBSpline::fit_forward(&[], &[], domain(), &params).err(),
        Some(SolverError::TooFew { method: "hierarchical B-spline", needed: 4, got: 0 })
    );
}

#[test]
fn degenerate_input_is_an_error_not_a_nan() {
    let (mut src, dst) = random_landmarks(7, 5, 10.0);
    let params = BSplineParams::default();
    src[3] = Point3::new(f64::NAN, 0.0, 0.0);
    assert_eq!(
        HierarchicalBSpline::fit_forward(&src, &dst, domain(), &params).err(),
        Some(SolverError::NonFinite { pair: 4 })
    );
    let (src, dst) = random_landmarks(7, 5, 10.0);
    assert!(matches!(
        HierarchicalBSpline::fit_forward(&src, &dst[..4], domain(), &params),
        Err(SolverError::LengthMismatch { from_len: 5, to_len: 4, .. })
    ));
    let flat = Aabb::new(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 1.0));
    assert!(matches!(
        HierarchicalBSpline::fit_forward(&src, &dst, flat, &params),
        Err(SolverError::InvalidParameter(_))
    ));
    let nan_box = Aabb::new(Point3::new(f64::NAN, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
    assert!(matches!(
        HierarchicalBSpline::fit_forward(&src, &dst, nan_box, &params),
        Err(SolverError::InvalidParameter(_))
    ));
    for bad in [
        BSplineParams { coarsest: [0, 2, 2], ..params },
        BSplineParams { levels: 0, ..params },
        BSplineParams { tolerance_mm: f64::NAN, ..params },
        BSplineParams { tolerance_mm: -1.0, ..params },
        BSplineParams { levels: 40, ..params },
        BSplineParams { coarsest: [usize::MAX, 2, 2], ..params },
    ] {
        assert!(
            matches!(
                HierarchicalBSpline::fit_forward(&src, &dst, domain(), &bad),
                Err(SolverError::InvalidParameter(_))
            ),
            "{bad:?} accepted"
        );
    }
}

#[test]
fn coincident_and_coplanar_samples_stay_finite() {
    // Two samples at one point with different displacements, and all samples on one plane: the lower tier
    // approximates them (landmark pairs like these are refused by `fit`, as for every method).
    let points = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, 50.0, 0.0]];
    let displacements = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, -2.0, 0.0]];
    let params = BSplineParams { coarsest: [2, 2, 2], levels: 5, tolerance_mm: 0.0 };
    let w = HierarchicalBSpline::<Fixed, Moving>::fit_displacements_raw(&points, &displacements, domain(), &params)
        .expect("fit");
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..200 {
        let x = random_point(&mut rng, [-300.0; 3], [300.0; 3]);
        assert!(w.apply_raw(x).iter().all(|v| v.is_finite()));
    }
    // The conflicting pair is approximated by its mean.
    assert!(norm(w.apply_raw([0.0; 3]), [0.0; 3]) < 0.05);
    let src: Vec<Point3<Moving>> = points.iter().map(|p| Point3::from_array(*p)).collect();
    let dst: Vec<Point3<Fixed>> =
        points.iter().zip(&displacements).map(|(p, d)| Point3::new(p[0] + d[0], p[1] + d[1], p[2] + d[2])).collect();
    assert!(matches!(
        HierarchicalBSpline::fit_forward(&src, &dst, domain(), &params),
        Err(SolverError::Conflict { space: "moving", first: 1, second: 2, .. })
    ));
}

#[test]
fn lattice_sum_refines_the_coarser_term() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (lo, hi) = ([-100.0, -80.0, -60.0], [100.0, 120.0, 140.0]);
    let mut a = ControlLattice::zeros([2, 3, 2], lo, hi).expect("lattice");
    let mut b = ControlLattice::zeros([8, 12, 8], lo, hi).expect("lattice");
    for c in a.coefficients_mut().iter_mut().chain(b.coefficients_mut()) {
        *c = rng.random_range(-5.0..5.0);
    }
    let sum = a.add(&b).expect("sum");
    assert_eq!(sum.cells(), [8, 12, 8]);
    for _ in 0..100 {
        let x = random_point(&mut rng, lo, hi);
        let (fa, fb, fs) = (a.eval(x), b.eval(x), sum.eval(x));
        assert!(max_diff(fs, [fa[0] + fb[0], fa[1] + fb[1], fa[2] + fb[2]]) < 1e-9);
    }
    let c = ControlLattice::zeros([3, 3, 3], lo, hi).expect("lattice");
    assert!(a.add(&c).is_err());
}
