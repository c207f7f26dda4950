//! Control-texture sampling and leave-one-out (issue 3 targets, 2-core machine):
//! - 64³ control texture from a TPS pull-back with N = 100: ≤ 40 ms;
//! - leave-one-out for all N = 100 landmarks (TPS): ≤ 100 ms.
//!
//! `cargo bench -p warpbench-solver --bench sampling -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use warpbench_io::geometry::Point3;
use warpbench_solver::Parallelism;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::diagnostics::leave_one_out;
use warpbench_solver::synthetic::{SyntheticKind, SyntheticWarp, sample_pairs};
use warpbench_solver::tps::Tps;
use warpbench_solver::{Aabb, Fixed, Moving};

fn setup() -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>, Aabb<Fixed>) {
    // The MRI fixture's extent (181 × 217 × 181 mm) with a 10 mm random TPS warp.
    let moving_box = Aabb::new(Point3::new(-90.0, -126.0, -72.0), Point3::new(90.0, 90.0, 108.0));
    let warp = SyntheticWarp::new(SyntheticKind::TpsRandom, moving_box, 10.0, 1).expect("warp");
    let (p, q) = sample_pairs(&warp, moving_box, 100, 2);
    let fixed_box = Aabb::new(Point3::new(-90.0, -126.0, -72.0), Point3::new(90.0, 90.0, 108.0));
    (p, q, fixed_box)
}

fn benches(c: &mut Criterion) {
    let (p, q, fixed_box) = setup();
    let moving_from_fixed: Tps<Moving, Fixed> = Tps::fit(&q, &p, 0.0).expect("pull-back");
    let grid = ControlGrid::cube(64, fixed_box).expect("grid");
    c.bench_function("control texture 64³ from TPS N=100 (rayon)", |b| {
        b.iter(|| black_box(ControlTexture::sample(&moving_from_fixed, grid)));
    });
    c.bench_function("TPS fit N=100 + control texture 64³", |b| {
        b.iter(|| {
            let u: Tps<Moving, Fixed> = Tps::fit(&q, &p, 0.0).expect("fit");
            black_box(ControlTexture::sample(&u, grid))
        });
    });
    c.bench_function("leave-one-out TPS N=100 (rayon)", |b| {
        b.iter(|| {
            black_box(leave_one_out(
                &p,
                &q,
                |s: &[Point3<Moving>], d: &[Point3<Fixed>]| Tps::fit(s, d, 0.0),
                Parallelism::Rayon,
            ))
        });
    });
}

criterion_group!(sampling, benches);
criterion_main!(sampling);
