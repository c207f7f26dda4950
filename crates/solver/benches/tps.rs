//! TPS benchmarks: fit at N = 100, 300 and 1000, single-threaded evaluation of a 64³ grid for N = 100, the
//! leave-one-out errors in closed form at N = 100, 300 and 1000 and by the N refits it replaces at N = 200, and one
//! landmark drag at N = 1000 with the window's 48³ control texture ([`warpbench_solver::tps_drag`]): one event of
//! a moving point, one of a fixed point (each with the texture on the CPU, and its coefficients alone, as on the
//! GPU route), the drag's start, and the full refit of both directions plus the texture
//! that an event cost before; and, for the profile of the leave-one-out, its two O(N³) kernels at N = 1000
//! ([`warpbench_solver::dense`]) on rayon's pool and on one thread, beside nalgebra's unblocked Cholesky.
//!
//! `cargo bench -p warpbench-solver --bench tps -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::DMatrix;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::diagnostics::leave_one_out as refit_leave_one_out;
use warpbench_solver::tps::{Regularisation, Tps, fit_forward, fit_pullback, leave_one_out};
use warpbench_solver::tps_drag::{DragTexture, DraggedEnd, PairDrag};
use warpbench_solver::{Aabb, Fixed, Moving, Parallelism, dense};

/// N landmark pairs in a 200 mm box with a smooth ~10 mm displacement.
fn landmarks(n: usize, seed: u64) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let moving: Vec<Point3<Moving>> = (0..n)
        .map(|_| {
            Point3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
            )
        })
        .collect();
    let fixed = moving
        .iter()
        .map(|p| {
            let [x, y, z] = p.coords();
            Point3::new(x + 10.0 * (y / 40.0).sin(), y + 10.0 * (z / 50.0).cos(), z + 8.0 * (x / 60.0).sin())
        })
        .collect();
    (moving, fixed)
}

fn bench_fit(c: &mut Criterion) {
    for n in [100, 300, 1000] {
        let (moving, fixed) = landmarks(n, 7);
        c.bench_function(&format!("tps_fit_n{n}"), |b| {
            b.iter(|| fit_pullback(black_box(&moving), black_box(&fixed), 0.0).expect("fit"));
        });
    }
}

fn bench_eval(c: &mut Criterion) {
    let (moving, fixed) = landmarks(100, 11);
    let tps: Tps<Moving, Fixed> = fit_pullback(&moving, &fixed, 0.0).expect("fit");
    let side = 64;
    let points: Vec<[f64; 3]> = (0..side * side * side)
        .map(|i| {
            let (x, y, z) = (i % side, (i / side) % side, i / (side * side));
            [x as f64 * 3.2 - 100.0, y as f64 * 3.2 - 100.0, z as f64 * 3.2 - 100.0]
        })
        .collect();
    let mut out = vec![[0.0; 3]; points.len()];
    c.bench_function("tps_eval_64cubed_n100_1thread", |b| {
        b.iter(|| tps.eval_into(black_box(&points), black_box(&mut out)));
    });
}

fn bench_leave_one_out(c: &mut Criterion) {
    let (moving, fixed) = landmarks(200, 13);
    let reg = Regularisation::Smoothing(0.0);
    c.bench_function("tps_leave_one_out_n200_closed_form", |b| {
        b.iter(|| leave_one_out(black_box(&fixed), black_box(&moving), reg).expect("leave-one-out"));
    });
    let mut group = c.benchmark_group("slow");
    group.sample_size(10);
    group.bench_function("tps_leave_one_out_n200_refits_1thread", |b| {
        b.iter(|| {
            let fit = |q: &[Point3<Fixed>], p: &[Point3<Moving>]| Tps::fit_regularised(q, p, reg);
            refit_leave_one_out(black_box(&fixed), black_box(&moving), fit, Parallelism::Sequential)
        });
    });
    group.finish();
    for n in [100, 300, 1000] {
        let (moving, fixed) = landmarks(n, 13);
        c.bench_function(&format!("tps_leave_one_out_n{n}_closed_form"), |b| {
            b.iter(|| leave_one_out(black_box(&fixed), black_box(&moving), reg).expect("leave-one-out"));
        });
    }
}

/// One drag event at N = 1000 with a 48³ texture over a 240 mm box: the fast paths and the full refit they replace.
fn bench_drag(c: &mut Criterion) {
    let (moving, fixed) = landmarks(1000, 17);
    let reg = Regularisation::Smoothing(0.0);
    let grid = ControlGrid::cube(48, Aabb::new(Point3::new(-120.0, -120.0, -120.0), Point3::new(120.0, 120.0, 120.0)))
        .expect("grid");
    let pair = 0;
    let mut texels = vec![[0.0f32; 4]; grid.texel_count()];
    for (end, name) in [(DraggedEnd::Moving, "moving"), (DraggedEnd::Fixed, "fixed")] {
        let drag = PairDrag::new(&fixed, &moving, pair, end, reg).expect("drag");
        let texture = DragTexture::new(&drag, grid);
        let start = if end == DraggedEnd::Moving { moving[pair].coords() } else { fixed[pair].coords() };
        let mut e = 0;
        c.bench_function(&format!("tps_drag_event_{name}_point_n1000_48cubed"), |b| {
            b.iter(|| {
                e += 1;
                let to = [start[0] + 0.5 * f64::from(e % 7), start[1], start[2]];
                let step = drag.step(black_box(to)).expect("step");
                texture.fill(&drag, &step, &mut texels);
                step
            });
        });
        // The coefficients alone: what an event leaves on the CPU when the GPU evaluates the texture.
        c.bench_function(&format!("tps_drag_coefficients_{name}_point_n1000"), |b| {
            b.iter(|| {
                e += 1;
                drag.step(black_box([start[0] + 0.5 * f64::from(e % 7), start[1], start[2]])).expect("step")
            });
        });
    }
    let mut group = c.benchmark_group("slow");
    group.sample_size(10);
    group.bench_function("tps_drag_start_n1000_48cubed", |b| {
        b.iter(|| {
            let drag = PairDrag::new(black_box(&fixed), &moving, pair, DraggedEnd::Fixed, reg).expect("drag");
            let texture = DragTexture::new(&drag, grid);
            (drag, texture)
        });
    });
    group.bench_function("tps_refit_both_and_texture_n1000_48cubed", |b| {
        b.iter(|| {
            let u = fit_pullback(black_box(&moving), black_box(&fixed), reg).expect("fit");
            let d = fit_forward(black_box(&moving), black_box(&fixed), reg).expect("fit");
            (ControlTexture::sample(&u, grid), d)
        });
    });
    group.finish();
}

/// The two O(N³) kernels under the closed-form leave-one-out at N = 1000 (the reduced matrix is (N − 4)²), for the
/// profile: the blocked Cholesky factorisation and the inverse of its factor, on rayon's pool and on one thread.
fn bench_dense(c: &mut Criterion) {
    let m = 996;
    let mut rng = ChaCha8Rng::seed_from_u64(19);
    let b = DMatrix::<f64>::from_fn(m, m, |_, _| rng.random_range(-1.0..1.0));
    let a = &b * b.transpose() + DMatrix::identity(m, m) * m as f64;
    let mut l = a.clone();
    dense::cholesky_in_place(&mut l, dense::BLOCK, Parallelism::Rayon).expect("SPD");
    for (parallelism, name) in [(Parallelism::Rayon, "rayon"), (Parallelism::Sequential, "1thread")] {
        c.bench_function(&format!("dense_cholesky_n{m}_{name}"), |bench| {
            bench.iter(|| {
                let mut f = black_box(&a).clone();
                dense::cholesky_in_place(&mut f, dense::BLOCK, parallelism).expect("SPD");
                f
            });
        });
        c.bench_function(&format!("dense_lower_triangular_inverse_n{m}_{name}"), |bench| {
            bench.iter(|| dense::lower_triangular_inverse(black_box(&l), dense::BLOCK, parallelism).expect("inverse"));
        });
    }
    c.bench_function(&format!("nalgebra_cholesky_n{m}"), |bench| {
        bench.iter(|| black_box(&a).clone().cholesky().expect("SPD"));
    });
}

criterion_group!(benches, bench_fit, bench_eval, bench_leave_one_out, bench_drag, bench_dense);
criterion_main!(benches);
