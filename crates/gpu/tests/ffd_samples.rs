//! The registration's per-sample GPU work ([`FfdSamplesPass`]) against an f64 oracle built from the solver: the
//! displacement from `ControlLattice::eval`, the value and gradient from `Image::sample_with_gradient`, on an oblique,
//! anisotropic 40 × 36 × 32 image with a block without values (NaN), under a random 7 × 8 × 6 lattice of up to 3 mm.
//!
//! The tolerances are the rounding of each f32 step, derived below; the samples whose displaced position lies
//! within 10⁻³ voxel of a cell face or the image's edge are left out, because there f32 may choose the neighbouring
//! cell, whose gradient differs (the trilinear gradient jumps across faces).

mod common;

use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_gpu::ffd_samples::{FfdImage, FfdLevel, FfdSamplePoint, FfdSamplesPass};
use warpbench_gpu::{FeatureRequest, GpuError};
use warpbench_io::geometry::{Index, Transform};
use warpbench_solver::Fixed;
use warpbench_solver::bspline::{ControlLattice, basis};
use warpbench_solver::image::Image;

const DIMS: [usize; 3] = [40, 36, 32];
/// f32's unit roundoff.
const EPS: f64 = f32::EPSILON as f64 / 2.0;
/// Samples closer than this (voxels) to a cell face or the edge are left out (module docs).
const AMBIGUOUS_VOX: f64 = 1e-3;

struct Case {
    image: Image<Fixed>,
    lattice: ControlLattice,
    /// ∂index/∂mm.
    a: Matrix3<f64>,
    samples: Vec<FfdSamplePoint>,
    /// The samples' positions, mm.
    points: Vec<[f64; 3]>,
}

/// The oblique image: smooth blobs (values up to about 900), NaN in the block [0, 6)³.
fn image() -> Image<Fixed> {
    let rotation = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, 0.5)), 0.4);
    let linear = rotation.matrix() * Matrix3::from_diagonal(&Vector3::new(1.2, 0.9, 1.5));
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::new(-30.0, 110.0, 240.0));
    let blobs = [[12.0, 10.0, 9.0, 600.0], [28.0, 22.0, 18.0, 900.0], [20.0, 30.0, 25.0, -400.0]];
    let values = (0..DIMS.iter().product::<usize>())
        .map(|o| {
            let ijk = [o % DIMS[0], (o / DIMS[0]) % DIMS[1], o / (DIMS[0] * DIMS[1])];
            if ijk.iter().all(|&i| i < 6) {
                return f32::NAN;
            }
            let x = ijk.map(|i| i as f64);
            blobs
                .iter()
                .map(|b| b[3] * (-((x[0] - b[0]).powi(2) + (x[1] - b[1]).powi(2) + (x[2] - b[2]).powi(2)) / 60.0).exp())
                .sum::<f64>() as f32
        })
        .collect();
    Image::new(DIMS, values, Transform::<Fixed, Index>::from_matrix(m)).expect("test image")
}

/// The footprint of `x` in `lattice`, the solver's convention (x clamped to the box; cell i = ⌊u⌋ at most cells − 1),
/// checked against the lattice's own evaluation.
fn footprint(lattice: &ControlLattice, x: [f64; 3]) -> ([usize; 3], [[f64; 4]; 3]) {
    let (lo, hi, cells) = (lattice.min_mm(), lattice.max_mm(), lattice.cells());
    let mut first = [0; 3];
    let mut weights = [[0.0; 4]; 3];
    for a in 0..3 {
        let u = (x[a].clamp(lo[a], hi[a]) - lo[a]) / (hi[a] - lo[a]) * cells[a] as f64;
        let i = (u.floor() as usize).min(cells[a] - 1);
        first[a] = i;
        weights[a] = basis(u - i as f64);
    }
    let dims = lattice.dims();
    let phi = lattice.coefficients();
    let mut d = [0.0; 3];
    for c in 0..4 {
        for b in 0..4 {
            for a in 0..4 {
                let w = weights[0][a] * weights[1][b] * weights[2][c];
                let k = ((first[2] + c) * dims[1] + first[1] + b) * dims[0] + first[0] + a;
                (0..3).for_each(|r| d[r] += w * phi[3 * k + r]);
            }
        }
    }
    let want = lattice.eval(x);
    assert!((0..3).all(|r| (d[r] - want[r]).abs() < 1e-9), "footprint convention: {d:?} vs {want:?}");
    (first, weights)
}

fn case(samples: usize, seed: u64) -> Case {
    let image = image();
    let corners: Vec<[f64; 3]> = (0..8)
        .map(|c| {
            image.voxel_point(
                if c & 1 == 0 { 0 } else { DIMS[0] - 1 },
                if c & 2 == 0 { 0 } else { DIMS[1] - 1 },
                if c & 4 == 0 { 0 } else { DIMS[2] - 1 },
            )
        })
        .collect();
    let lo: [f64; 3] = std::array::from_fn(|a| corners.iter().map(|c| c[a]).fold(f64::INFINITY, f64::min));
    let hi: [f64; 3] = std::array::from_fn(|a| corners.iter().map(|c| c[a]).fold(f64::NEG_INFINITY, f64::max));
    let mut lattice = ControlLattice::zeros([4, 5, 3], lo, hi).expect("lattice");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for c in lattice.coefficients_mut() {
        *c = rng.random_range(-3.0..3.0);
    }
    let origin = image.voxel_point(0, 0, 0);
    let a = {
        let e = |i, j, k| image.voxel_point(i, j, k);
        let cols = [e(1, 0, 0), e(0, 1, 0), e(0, 0, 1)].map(|p| Vector3::from(p) - Vector3::from(origin));
        Matrix3::from_columns(&cols).try_inverse().expect("index map")
    };
    let mut points = Vec::with_capacity(samples);
    let mut out = Vec::with_capacity(samples);
    while out.len() < samples {
        // Inside the image's index box and a voxel beyond it, so that some displaced samples leave it.
        let xi: [f64; 3] = std::array::from_fn(|r| rng.random_range(-1.0..DIMS[r] as f64));
        let x: [f64; 3] = (Vector3::from(origin) + a.try_inverse().expect("inverse") * Vector3::from(xi)).into();
        let (first, weights) = footprint(&lattice, x);
        let eta = displaced_index(&image, &lattice, x);
        let ambiguous = (0..3).any(|r| {
            let top = (DIMS[r] - 1) as f64;
            let frac = eta[r] - eta[r].floor();
            frac.min(1.0 - frac) < AMBIGUOUS_VOX || (eta[r] + AMBIGUOUS_VOX > top && eta[r] - AMBIGUOUS_VOX < top)
        });
        if ambiguous {
            continue;
        }
        points.push(x);
        out.push(FfdSamplePoint { index: image.index_of(x), first, weights });
    }
    Case { image, lattice, a, samples: out, points }
}

fn displaced_index(image: &Image<Fixed>, lattice: &ControlLattice, x: [f64; 3]) -> [f64; 3] {
    let d = lattice.eval(x);
    image.index_of([x[0] + d[0], x[1] + d[1], x[2] + d[2]])
}

/// The f64 oracle of one sample: value, gradient (mm⁻¹), and its f32 error bounds.
struct Expected {
    value: f64,
    gradient: [f64; 3],
    value_bound: f64,
    gradient_bound: f64,
}

fn expected(case: &Case, x: [f64; 3]) -> Option<Expected> {
    let d = case.lattice.eval(x);
    let y = [x[0] + d[0], x[1] + d[1], x[2] + d[2]];
    let (value, gradient) = case.image.sample_with_gradient(y)?;
    if !value.is_finite() {
        return None;
    }
    let xi = case.image.index_of(x);
    let eta = case.image.index_of(y);
    // The cell's corners (the solver's cell rule; for a finite value all 8 are finite).
    let base: [usize; 3] =
        std::array::from_fn(|r| (eta[r].clamp(0.0, (DIMS[r] - 1) as f64).floor() as usize).min(DIMS[r] - 2));
    let corners: Vec<f64> = (0..8)
        .map(|c| f64::from(case.image.at(base[0] + (c & 1), base[1] + ((c >> 1) & 1), base[2] + ((c >> 2) & 1))))
        .collect();
    let m = corners.iter().fold(0.0f64, |acc, v| acc.max(v.abs())).max(value.abs());
    let spread = corners.iter().fold(f64::NEG_INFINITY, |acc, &v| acc.max(v))
        - corners.iter().fold(f64::INFINITY, |acc, &v| acc.min(v));
    let a_norm = (0..3).map(|r| (0..3).map(|c| case.a[(r, c)].abs()).sum::<f64>()).fold(0.0, f64::max);
    let at_norm = (0..3).map(|c| (0..3).map(|r| case.a[(r, c)].abs()).sum::<f64>()).fold(0.0, f64::max);
    let phi_max = case.lattice.coefficients().iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
    let xi_max = xi.iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
    // η = ξ + A·D in f32. ξ, A, the weights and φ are rounded once each (ε relative); D is a sum of 64 products
    // (≤ 67 ε Σ|B||φ| ≤ 67 ε max|φ|, the weights summing to 1); A·D and the sum with ξ add a few ε each:
    let delta_eta = 8.0 * EPS * xi_max + 80.0 * EPS * a_norm * phi_max;
    // Trilinear interpolation in f32 at a position off by δη: the value moves by at most 3 · spread · δη (the
    // interpolant's slope per index unit is at most the spread along each axis), and its 7 lerps round at most
    // 16 ε max|corner|. The gradient's blended differences move by at most 2 · spread · δη per axis and round by
    // 32 ε max|corner|, and Aᵀ multiplies them by ‖Aᵀ‖∞.
    let value_bound = 3.0 * spread * delta_eta + 16.0 * EPS * m;
    let gradient_bound = at_norm * (6.0 * spread * delta_eta + 32.0 * EPS * m);
    Some(Expected { value, gradient, value_bound, gradient_bound })
}

#[test]
fn values_and_gathered_gradients_match_the_solver_within_f32_rounding() {
    let Some(ctx) = common::context(FeatureRequest::default()) else { return };
    let case = case(6000, 7);
    let pass = FfdSamplesPass::new(&ctx).expect("pass");
    let a = case.a;
    let level = FfdLevel {
        image: FfdImage {
            dims: DIMS,
            values: case.image.values(),
            index_from_mm: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
        },
        lattice_dims: case.lattice.dims(),
        samples: &case.samples,
    };
    let prepared = pass.prepare(&ctx, &level).expect("prepare");
    let mut values = vec![0.0; case.samples.len()];
    prepared.values(&ctx, case.lattice.coefficients(), &mut values).expect("values");

    let expected: Vec<Option<Expected>> = case.points.iter().map(|&x| expected(&case, x)).collect();
    let (mut inside, mut outside) = (0, 0);
    let mut worst = 0.0f64;
    for (n, (got, want)) in values.iter().zip(&expected).enumerate() {
        match want {
            None => {
                assert!(got.is_nan(), "sample {n}: {got} where the image has no value");
                outside += 1;
            }
            Some(e) => {
                assert!(
                    (got - e.value).abs() <= e.value_bound,
                    "sample {n}: {got} vs {} (bound {:e})",
                    e.value,
                    e.value_bound
                );
                inside += 1;
                worst = worst.max((got - e.value).abs() / e.value_bound);
            }
        }
    }
    eprintln!("values: the largest error is {worst:.3} of its bound");
    // Both kinds are exercised.
    assert!(inside > 4000 && outside > 100, "{inside} inside, {outside} outside");

    // Weights: random, 0 where the sample has no value (as the registration gives them).
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let weights: Vec<f64> =
        expected.iter().map(|e| if e.is_some() { rng.random_range(-1.0..1.0) } else { 0.0 }).collect();
    let coefficients = case.lattice.coefficients().len();
    let mut got = vec![0.0; coefficients];
    prepared.weighted_gradient(&ctx, &weights, &mut got).expect("gradient");

    let mut want = vec![0.0; coefficients];
    let mut bound = vec![0.0; coefficients];
    let mut magnitude = vec![0.0; coefficients];
    let mut terms = vec![0usize; coefficients / 3];
    let dims = case.lattice.dims();
    for ((s, e), &w) in case.samples.iter().zip(&expected).zip(&weights) {
        let Some(e) = e else { continue };
        for c in 0..4 {
            for b in 0..4 {
                for a in 0..4 {
                    let basis = s.weights[0][a] * s.weights[1][b] * s.weights[2][c];
                    let k = ((s.first[2] + c) * dims[1] + s.first[1] + b) * dims[0] + s.first[0] + a;
                    terms[k] += 1;
                    for r in 0..3 {
                        want[3 * k + r] += w * basis * e.gradient[r];
                        // The gradient's own error, and the rounding of w, the basis product and the product (8 ε).
                        bound[3 * k + r] += (w * basis).abs() * (e.gradient_bound + 8.0 * EPS * e.gradient[r].abs());
                        magnitude[3 * k + r] += (w * basis * e.gradient[r]).abs();
                    }
                }
            }
        }
    }
    let mut worst = 0.0f64;
    for i in 0..coefficients {
        // A sum of n terms in f32 rounds by at most n ε Σ|terms|.
        let tolerance = bound[i] + terms[i / 3] as f64 * EPS * magnitude[i];
        worst = worst.max((got[i] - want[i]).abs() / tolerance.max(f64::MIN_POSITIVE));
        assert!(
            (got[i] - want[i]).abs() <= tolerance,
            "coefficient {i}: {} vs {} (bound {tolerance:e})",
            got[i],
            want[i]
        );
    }
    eprintln!("gradients: the largest error is {worst:.3} of its bound");
    assert!(want.iter().any(|v| v.abs() > 1.0), "the gathered gradient is not trivially small");

    // The same inputs give the same bits.
    let mut again = vec![0.0; case.samples.len()];
    prepared.values(&ctx, case.lattice.coefficients(), &mut again).expect("values");
    assert!(values.iter().zip(&again).all(|(x, y)| x.to_bits() == y.to_bits()), "values differ between runs");
    let mut gradient_again = vec![0.0; coefficients];
    prepared.weighted_gradient(&ctx, &weights, &mut gradient_again).expect("gradient");
    assert!(got.iter().zip(&gradient_again).all(|(x, y)| x.to_bits() == y.to_bits()), "gradients differ between runs");
}

#[test]
fn a_footprint_outside_the_lattice_is_refused_naming_the_sample() {
    let Some(ctx) = common::context(FeatureRequest::default()) else { return };
    let mut case = case(10, 1);
    case.samples[3].first = [5, 0, 0];
    let pass = FfdSamplesPass::new(&ctx).expect("pass");
    let level = FfdLevel {
        image: FfdImage {
            dims: DIMS,
            values: case.image.values(),
            index_from_mm: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        },
        lattice_dims: case.lattice.dims(),
        samples: &case.samples,
    };
    match pass.prepare(&ctx, &level) {
        Err(GpuError::InvalidInput(message)) => assert!(message.starts_with("sample 4:"), "{message}"),
        other => panic!("expected a refusal, got {:?}", other.map(|p| p.samples())),
    }
}
