//! `invert`: the inverse composed with the forward warp is the identity to a fraction of a voxel, and the
//! report agrees with an independent brute-force measurement.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::Parallelism;
use warpbench_solver::bspline::BSplineParams;
use warpbench_solver::invert::{InvertParams, invert};
use warpbench_solver::{Aabb, Fixed, Moving, SolverError, Warp};

/// A smooth synthetic forward warp d(x) = x + Σ_m a_m sin(k_m · x + φ_m), with |a_m| ≤ 10 mm in total
/// per component and wavelengths ≥ 120 mm, so ‖∂D‖ < 1 and d is invertible.
#[derive(Debug)]
struct SineWarp {
    terms: Vec<([f64; 3], [f64; 3], f64)>,
}

impl SineWarp {
    fn seeded(seed: u64, amplitude_mm: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let terms = (0..2)
            .map(|_| {
                let amp: [f64; 3] = std::array::from_fn(|_| rng.random_range(-0.5..0.5) * amplitude_mm);
                let wavelength_mm = rng.random_range(120.0..250.0);
                let dir: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
                let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-3);
                let k = dir.map(|v| v / norm * std::f64::consts::TAU / wavelength_mm);
                (amp, k, rng.random_range(0.0..std::f64::consts::TAU))
            })
            .collect();
        Self { terms }
    }
}

impl Warp<Fixed, Moving> for SineWarp {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let mut out = x;
        for (amp, k, phase) in &self.terms {
            let s = (k[0] * x[0] + k[1] * x[1] + k[2] * x[2] + phase).sin();
            for r in 0..3 {
                out[r] += amp[r] * s;
            }
        }
        out
    }
}

fn boxes() -> (Aabb<Moving>, Aabb<Fixed>) {
    (
        Aabb::new(Point3::new(-100.0, -100.0, -100.0), Point3::new(100.0, 100.0, 100.0)),
        Aabb::new(Point3::new(-100.0, -100.0, -100.0), Point3::new(100.0, 100.0, 100.0)),
    )
}

/// Small enough for debug-mode tests: a 16³ source grid, a 24³ target grid, a 16-cell lattice.
fn small_params() -> InvertParams {
    InvertParams {
        source_samples: [12, 12, 12],
        target_samples: [24, 24, 24],
        bspline: BSplineParams { coarsest: [2, 2, 2], levels: 4, tolerance_mm: 1e-4 },
        iterations: 4,
        tolerance_mm: 0.0,
        check_samples: [10, 10, 10],
        par: Parallelism::Rayon,
    }
}

/// Inverse consistency bounds for 10 mm warps over a 200 mm box, with 1 mm voxels: RMS < 0.1 voxel (the
/// issue's requirement) and max < 0.5 voxel with the small debug-mode grids above. The max occurs at the
/// box corners, which the forward samples barely reach; a seed found in CI reached 0.28 mm (RMS 0.04 mm),
/// and 40 random seeds stay under 0.5 mm. The default parameters (64³ targets, 5 levels) reach a max of
/// 0.007 mm on the benchmark warp.
const RMS_BOUND_MM: f64 = 0.1;
const MAX_BOUND_MM: f64 = 0.5;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    #[test]
    fn inverse_after_forward_is_the_identity(seed in any::<u64>(), amplitude_mm in 2.0..=10.0f64) {
        let forward = SineWarp::seeded(seed, amplitude_mm);
        let (from, to) = boxes();
        let (inverse, report) = invert(&forward, from, to, &small_params()).expect("invert");
        prop_assert!(report.rms_mm < RMS_BOUND_MM, "{report:?}");
        prop_assert!(report.max_mm < MAX_BOUND_MM, "{report:?}");
        // The iteration improves on the initial scattered fit.
        prop_assert!(report.rms_mm <= report.rms_history_mm[0], "{report:?}");

        // Brute force, independently of the report's grid: random targets in the box, and u ∘ d on
        // random sources whose image stays in the box.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xface);
        let mut sum = 0.0;
        let mut worst = 0.0_f64;
        let n = 2000;
        for _ in 0..n {
            let y: [f64; 3] = std::array::from_fn(|_| rng.random_range(-95.0..95.0));
            let e = dist(forward.apply_raw(inverse.apply_raw(y)), y);
            sum += e * e;
            worst = worst.max(e);
            let x: [f64; 3] = std::array::from_fn(|_| rng.random_range(-85.0..85.0));
            prop_assert!(dist(inverse.apply_raw(forward.apply_raw(x)), x) < 2.0 * MAX_BOUND_MM);
        }
        let rms = (sum / f64::from(n)).sqrt();
        prop_assert!(rms < RMS_BOUND_MM && worst < MAX_BOUND_MM, "random-point rms {rms}, max {worst}");
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn report_matches_a_brute_force_measurement() {
    let forward = SineWarp::seeded(42, 10.0);
    let (from, to) = boxes();
    let params = small_params();
    let (inverse, report) = invert(&forward, from, to, &params).expect("invert");
    // The report's grid: the centres of a check_samples partition of the target box.
    let [nx, ny, nz] = params.check_samples;
    let (lo, hi) = (to.min.coords(), to.max.coords());
    let mut sum = 0.0;
    let mut worst = 0.0_f64;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = [i, j, k];
                let n = [nx, ny, nz];
                let y: [f64; 3] = std::array::from_fn(|a| lo[a] + (c[a] as f64 + 0.5) * (hi[a] - lo[a]) / n[a] as f64);
                let e = dist(forward.apply(inverse.apply(Point3::from_array(y))).coords(), y);
                sum += e * e;
                worst = worst.max(e);
            }
        }
    }
    let count = nx * ny * nz;
    let rms = (sum / count as f64).sqrt();
    assert_eq!(report.check_points, count);
    assert!((rms - report.rms_mm).abs() < 1e-9, "{rms} vs {report:?}");
    assert!((worst - report.max_mm).abs() < 1e-9, "{worst} vs {report:?}");
    assert_eq!(report.rms_history_mm.len(), report.iterations + 1);
    assert!(report.initial_samples > 0);
    // Sequential and parallel runs agree.
    let (_, seq) =
        invert(&forward, from, to, &InvertParams { par: Parallelism::Sequential, ..params }).expect("invert");
    assert!((seq.rms_mm - report.rms_mm).abs() < 1e-12);
    eprintln!("inverse consistency: {report:?}");
}

#[test]
fn identity_inverts_to_identity_at_once() {
    struct Identity;
    impl Warp<Fixed, Moving> for Identity {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            x
        }
    }
    let (from, to) = boxes();
    let params = InvertParams { tolerance_mm: 1e-9, ..small_params() };
    let (inverse, report) = invert(&Identity, from, to, &params).expect("invert");
    assert_eq!(report.iterations, 0);
    assert!(report.max_mm < 1e-9);
    assert!(dist(inverse.apply_raw([3.0, -7.0, 50.0]), [3.0, -7.0, 50.0]) < 1e-9);
}

#[test]
fn bad_input_is_an_error() {
    struct Nan;
    impl Warp<Fixed, Moving> for Nan {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            if x[0] > 50.0 { [f64::NAN; 3] } else { x }
        }
    }
    let (from, to) = boxes();
    let params = small_params();
    assert!(matches!(invert(&Nan, from, to, &params), Err(SolverError::Degenerate(_))));
    let forward = SineWarp::seeded(1, 5.0);
    let flat = Aabb::new(Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 1.0, 1.0));
    assert!(matches!(invert(&forward, from, flat, &params), Err(SolverError::InvalidParameter(_))));
    for bad in [
        InvertParams { target_samples: [0, 4, 4], ..params },
        InvertParams { check_samples: [usize::MAX, 2, 2], ..params },
        InvertParams { tolerance_mm: f64::NAN, ..params },
        InvertParams { bspline: BSplineParams { levels: 0, ..params.bspline }, ..params },
    ] {
        assert!(matches!(invert(&forward, from, to, &bad), Err(SolverError::InvalidParameter(_))), "{bad:?}");
    }
}
