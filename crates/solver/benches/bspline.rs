//! Hierarchical B-spline benchmarks (targets from the issue, release, 2 cores):
//! - fit N = 100 landmarks with 4 levels + sample the warp on 64³ points: ≤ 15 ms;
//! - invert a smooth 10 mm warp on a 64³ target grid: ≤ 500 ms.
//!
//! `RAYON_NUM_THREADS=2 cargo bench -p warpbench-solver --bench bspline -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::Parallelism;
use warpbench_solver::bspline::{BSplineParams, HierarchicalBSpline, RegularGrid};
use warpbench_solver::invert::{InvertParams, invert};
use warpbench_solver::{Aabb, Fixed, Moving, Warp};

fn landmarks(n: usize) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(2006);
    (0..n)
        .map(|_| {
            let p: [f64; 3] = std::array::from_fn(|_| rng.random_range(-95.0..95.0));
            let q: [f64; 3] = std::array::from_fn(|a| p[a] + rng.random_range(-10.0..10.0));
            (Point3::from_array(p), Point3::from_array(q))
        })
        .unzip()
}

/// d(x) = x + a sin(k · x + φ) per component: a smooth 10 mm warp, wavelength 150 mm.
#[derive(Debug)]
struct SineWarp;

impl Warp<Fixed, Moving> for SineWarp {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let k = std::f64::consts::TAU / 150.0;
        [
            x[0] + 10.0 * (k * x[1] + 0.3).sin(),
            x[1] + 8.0 * (k * (x[2] + x[0]) + 1.1).sin(),
            x[2] + 6.0 * (k * x[0] - 0.7).sin(),
        ]
    }
}

fn bench(c: &mut Criterion) {
    let bounds = Aabb::<Moving>::new(Point3::new(-100.0, -100.0, -100.0), Point3::new(100.0, 100.0, 100.0));
    let (src, dst) = landmarks(100);
    let params = BSplineParams { coarsest: [4, 4, 4], levels: 4, tolerance_mm: 0.01 };
    let grid = RegularGrid::spanning(bounds.min.coords(), bounds.max.coords(), [64, 64, 64]);
    let mut out = vec![[0.0; 3]; grid.len()];

    let w = HierarchicalBSpline::fit_forward(&src, &dst, bounds, &params).expect("fit");
    eprintln!("fit N=100: {:?}", w.fit_report());

    c.bench_function("bspline_fit_n100_l4", |b| {
        b.iter(|| HierarchicalBSpline::fit_forward(black_box(&src), black_box(&dst), bounds, &params).expect("fit"));
    });
    for (name, par) in [("seq", Parallelism::Sequential), ("rayon", Parallelism::Rayon)] {
        c.bench_function(&format!("bspline_sample_64cubed_{name}"), |b| {
            b.iter(|| w.sample_grid_into(&grid, black_box(&mut out), par).expect("sample"));
        });
        c.bench_function(&format!("bspline_fit_n100_l4_plus_sample_64cubed_{name}"), |b| {
            b.iter(|| {
                let w =
                    HierarchicalBSpline::fit_forward(black_box(&src), black_box(&dst), bounds, &params).expect("fit");
                w.sample_grid_into(&grid, &mut out, par).expect("sample");
            });
        });
    }
    c.bench_function("bspline_pointwise_64cubed_seq", |b| {
        b.iter(|| {
            for (i, o) in out.iter_mut().enumerate() {
                *o = w.apply_raw(grid.point(i));
            }
        });
    });

    let to = Aabb::<Fixed>::new(Point3::new(-100.0, -100.0, -100.0), Point3::new(100.0, 100.0, 100.0));
    let invert_params = InvertParams {
        source_samples: [16, 16, 16],
        target_samples: [64, 64, 64],
        bspline: BSplineParams { coarsest: [4, 4, 4], levels: 5, tolerance_mm: 1e-3 },
        iterations: 4,
        tolerance_mm: 0.0,
        check_samples: [32, 32, 32],
        par: Parallelism::Rayon,
    };
    let (_, report) = invert(&SineWarp, bounds, to, &invert_params).expect("invert");
    eprintln!("invert 64³: {report:?}");
    let mut group = c.benchmark_group("invert");
    group.sample_size(10);
    group.bench_function("invert_sine10mm_target64cubed", |b| {
        b.iter(|| invert(black_box(&SineWarp), bounds, to, &invert_params).expect("invert"));
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
