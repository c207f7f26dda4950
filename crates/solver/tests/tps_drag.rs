//! The drag fast path of `tps_drag` against the slow path it replaces: both warps refitted in full with the dragged
//! point moved (their values, and their coefficients within the bound the conditioning of the moved system gives),
//! and the control texture sampled again from the refitted pull-back.

use nalgebra::{DMatrix, SymmetricEigen};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::tps::{Regularisation, Tps};
use warpbench_solver::tps_drag::{DragTexture, DraggedEnd, FactoredTps, PairDrag};
use warpbench_solver::{Aabb, Fixed, Moving, Warp};

/// Largest accepted difference between a fast-path warp and the full refit, mm (the bound).
const WARP_TOL_MM: f64 = 1e-6;

/// N pairs in a 200 mm box, the moving points a smooth ~10 mm displacement of the fixed ones.
fn pairs(n: usize, seed: u64) -> (Vec<Point3<Fixed>>, Vec<Point3<Moving>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let fixed: Vec<Point3<Fixed>> = (0..n)
        .map(|_| {
            Point3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
            )
        })
        .collect();
    let moving = fixed
        .iter()
        .map(|q| {
            let [x, y, z] = q.coords();
            Point3::new(x + 10.0 * (y / 40.0).sin(), y + 10.0 * (z / 50.0).cos(), z + 8.0 * (x / 60.0).sin())
        })
        .collect();
    (fixed, moving)
}

fn grid() -> ControlGrid {
    ControlGrid::cube(24, Aabb::new(Point3::new(-120.0, -110.0, -115.0), Point3::new(118.0, 112.0, 109.0)))
        .expect("grid")
}

fn probes(count: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count).map(|_| std::array::from_fn(|_| rng.random_range(-130.0..130.0))).collect()
}

fn worst<To: warpbench_io::geometry::Space, From: warpbench_io::geometry::Space>(
    a: &Tps<To, From>,
    b: &Tps<To, From>,
    at: &[[f64; 3]],
) -> f64 {
    at.iter()
        .map(|x| {
            let (u, v) = (a.apply_raw(*x), b.apply_raw(*x));
            (0..3).map(|k| (u[k] - v[k]).abs()).fold(0.0, f64::max)
        })
        .fold(0.0, f64::max)
}

/// The constant of the coefficient bound ([`coefficients_within_conditioning`]): the backward error of each solve
/// is at most `SOLVE_BACKWARD_ERROR` · (N + 4) · ε relative to ‖L‖ (Householder QR and Cholesky: a small multiple of
/// N ε; Higham, *Accuracy and Stability of Numerical Algorithms*, Theorems 10.3 and 19.4). The fast path chains
/// three solves with the kept factorisation (c, gₖ and h) and the 2 × 2 system S, the refit one, hence four.
const SOLVE_BACKWARD_ERROR: f64 = 4.0;

/// A TPS's coefficients ĉ = [W/α; Â] (N + 4 rows, 3 columns) in the basis of the system L̂_α that [`system`]
/// assembles: the raw weights W over α, and the affine part x ↦ A x + b written over p̂(x) = ((x − c)/s, 1).
fn coefficients<To: warpbench_io::geometry::Space, From: warpbench_io::geometry::Space>(
    tps: &Tps<To, From>,
    (c, s): ([f64; 3], f64),
    alpha: f64,
) -> DMatrix<f64> {
    let (w, a, b) = (tps.weights(), tps.linear(), tps.translation());
    let n = w.len();
    DMatrix::from_fn(n + 4, 3, |i, col| match i.checked_sub(n) {
        None => w[i][col] / alpha,
        Some(k @ 0..3) => a[(col, k)] * s,
        Some(_) => b[col] + (0..3).map(|k| a[(col, k)] * c[k]).sum::<f64>(),
    })
}

/// The centroid c and RMS radius s of `centres` (how the solver scales the affine block).
fn centre_and_scale(centres: &[[f64; 3]]) -> ([f64; 3], f64) {
    let n = centres.len() as f64;
    let c: [f64; 3] = std::array::from_fn(|k| centres.iter().map(|p| p[k]).sum::<f64>() / n);
    let s = (centres.iter().map(|p| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f64>()).sum::<f64>() / n).sqrt();
    (c, s)
}

/// L̂_α = D L̂ D = [α²(K + dI), α P̂; α P̂ᵀ, 0] for D = diag(α I_N, I₄), L̂ being the system of `centres` with P̂ rows
/// ((x − c)/s, 1).
fn system(centres: &[[f64; 3]], k_diagonal: f64, (c, s): ([f64; 3], f64), alpha: f64) -> DMatrix<f64> {
    let n = centres.len();
    DMatrix::from_fn(n + 4, n + 4, |i, j| match (i < n, j < n) {
        (true, true) if i == j => alpha * alpha * k_diagonal,
        (true, true) => alpha * alpha * (0..3).map(|k| (centres[i][k] - centres[j][k]).powi(2)).sum::<f64>().sqrt(),
        (true, false) if j - n < 3 => alpha * (centres[i][j - n] - c[j - n]) / s,
        (false, true) if i - n < 3 => alpha * (centres[j][i - n] - c[i - n]) / s,
        (true, false) | (false, true) => alpha,
        (false, false) => 0.0,
    })
}

/// The 2-norm condition number of a symmetric matrix.
fn condition(l: &DMatrix<f64>) -> f64 {
    let eig = SymmetricEigen::new(l.clone()).eigenvalues;
    let (lo, hi) = eig.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), e| (lo.min(e.abs()), hi.max(e.abs())));
    hi / lo
}

/// The fast path's coefficients of one direction against the refit's, both solutions of the moved system L̂′ ĉ = b̂:
/// two backward-stable solves (backward error η = [`SOLVE_BACKWARD_ERROR`] · (N + 4) · ε) differ by at most
/// ‖ĉ_fast − ĉ_full‖_F ≤ 2 κ₂(L̂′) η ‖ĉ_full‖_F to first order (Higham, Theorem 7.2). Returns the difference over
/// that bound.
///
/// The bound is taken in the scaled system D L̂′ D, D = diag(α I_N, I₄), with coefficients D⁻¹ĉ = [W/α; Â]: for α a
/// power of two both solvers commute with that scaling to the last bit (every product and reflector scales exactly),
/// so the same analysis holds there, and the scaling that balances the two blocks (α the power of two nearest
/// ‖W‖/‖Â‖) gives a bound some 10⁴ times tighter than α = 1, where ‖Â‖ (hundreds of mm) and κ (≈ 10⁶) meet.
fn coefficients_within_conditioning<To: warpbench_io::geometry::Space, From: warpbench_io::geometry::Space>(
    fast: &Tps<To, From>,
    full: &Tps<To, From>,
    regularisation: Regularisation,
) -> f64 {
    let centres: Vec<[f64; 3]> = full.centres().iter().map(Point3::coords).collect();
    let fast_centres: Vec<[f64; 3]> = fast.centres().iter().map(Point3::coords).collect();
    assert_eq!(fast_centres, centres, "the fast path moves the same centre to the same place");
    let n = centres.len();
    let basis = centre_and_scale(&centres);
    let unscaled = coefficients(full, basis, 1.0);
    let alpha = 2f64.powi((unscaled.rows(0, n).norm() / unscaled.rows(n, 4).norm()).log2().round() as i32);
    let (c_fast, c_full) = (coefficients(fast, basis, alpha), coefficients(full, basis, alpha));
    let l = system(&centres, regularisation.k_diagonal(), basis, alpha);
    let eta = SOLVE_BACKWARD_ERROR * (n + 4) as f64 * f64::EPSILON;
    let bound = 2.0 * condition(&l) * eta * c_full.norm();
    (c_fast - c_full).norm() / bound
}

/// A base under the landmarks, as the drag sees it: B⁻¹, which moves the pull-back layer's data (the moving
/// points), and B, which moves the forward layer's (the fixed points). Smooth and far from affine, a field's stand-in.
#[derive(Clone, Copy, PartialEq)]
enum Base {
    None,
    Bent,
}

impl Base {
    fn inverse(self, p: [f64; 3]) -> [f64; 3] {
        match self {
            Self::None => p,
            Self::Bent => [p[0] - 4.0 * (p[1] / 30.0).sin(), p[1] + 3.0 * (p[2] / 45.0).cos(), p[2] - 2.5],
        }
    }

    fn forward(self, q: [f64; 3]) -> [f64; 3] {
        match self {
            Self::None => q,
            Self::Bent => [q[0] + 5.0 * (q[2] / 35.0).cos(), q[1] - 2.0, q[2] + 3.0 * (q[0] / 50.0).sin()],
        }
    }

    /// The pull-back layer's data B⁻¹(pᵢ) and the forward layer's B(qᵢ), typed as the plain drag types them.
    fn data(self, fixed: &[Point3<Fixed>], moving: &[Point3<Moving>]) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
        let u = moving.iter().map(|p| Point3::from_array(self.inverse(p.coords()))).collect();
        let d = fixed.iter().map(|q| Point3::from_array(self.forward(q.coords()))).collect();
        (u, d)
    }
}

/// Drags pair `pair`'s `end` through `steps` and compares every event with the full refits, on `base`
/// ([`PairDrag::on_base`]; without one, [`PairDrag::new`]).
fn check_drag(n: usize, seed: u64, end: DraggedEnd, regularisation: Regularisation, base: Base) {
    let (mut fixed, mut moving) = pairs(n, seed);
    let pair = n / 3;
    let g = grid();
    let drag = if base == Base::None {
        PairDrag::new(&fixed, &moving, pair, end, regularisation)
    } else {
        let (u_data, d_data) = base.data(&fixed, &moving);
        PairDrag::on_base((&fixed, &u_data), (&moving, &d_data), (pair, end), regularisation)
    }
    .expect("drag state");
    let texture = DragTexture::new(&drag, g);
    let at = probes(400, seed + 1);
    let mut texels = vec![[0.0f32; 4]; g.texel_count()];
    let (start_q, start_p) = (fixed[pair].coords(), moving[pair].coords());
    for (e, step) in [[0.5, 0.0, 0.0], [3.0, -2.0, 1.0], [-8.0, 5.5, 12.0], [0.01, 0.02, -0.03]].iter().enumerate() {
        let start = if end == DraggedEnd::Moving { start_p } else { start_q };
        let to = [start[0] + step[0], start[1] + step[1], start[2] + step[2]];
        match end {
            DraggedEnd::Moving => moving[pair] = Point3::new(to[0], to[1], to[2]),
            DraggedEnd::Fixed => fixed[pair] = Point3::new(to[0], to[1], to[2]),
        }
        let fast = match (base, end) {
            (Base::None, _) => drag.step(to),
            (_, DraggedEnd::Moving) => drag.step_on_base(base.inverse(to), to),
            (_, DraggedEnd::Fixed) => drag.step_on_base(to, base.forward(to)),
        }
        .expect("fast step");
        texture.fill(&drag, &fast, &mut texels);
        let (u_data, d_data) = base.data(&fixed, &moving);
        let pullback = Tps::<Moving, Fixed>::fit_regularised(&fixed, &u_data, regularisation).expect("refit u");
        let forward = Tps::<Fixed, Moving>::fit_regularised(&moving, &d_data, regularisation).expect("refit d");
        let (du, dd) = (worst(&fast.pullback, &pullback, &at), worst(&fast.forward, &forward, &at));
        assert!(du <= WARP_TOL_MM, "N = {n}, {end:?} event {e}: pull-back differs by {du:e} mm");
        assert!(dd <= WARP_TOL_MM, "N = {n}, {end:?} event {e}: forward warp differs by {dd:e} mm");
        // The coefficients themselves (what the GPU evaluates into the texture), against the conditioning bound.
        let ru = coefficients_within_conditioning(&fast.pullback, &pullback, regularisation);
        let rd = coefficients_within_conditioning(&fast.forward, &forward, regularisation);
        assert!(ru <= 1.0, "N = {n}, {end:?} event {e}: pull-back coefficients differ by {ru} times the bound");
        assert!(rd <= 1.0, "N = {n}, {end:?} event {e}: forward coefficients differ by {rd} times the bound");
        // The texture against a full re-sample of the refitted pull-back: f32 texels, so within a few f32 steps of
        // the displacements' size.
        let full = ControlTexture::sample(&pullback, g);
        let (mut diff, mut size) = (0.0f32, 0.0f32);
        for (a, b) in texels.iter().zip(&full.texels) {
            for k in 0..4 {
                diff = diff.max((a[k] - b[k]).abs());
                size = size.max(b[k].abs());
            }
        }
        let tol = 8.0 * f32::EPSILON * size;
        assert!(diff <= tol, "N = {n}, {end:?} event {e}: texture differs by {diff:e} mm (tolerance {tol:e})");
    }
}

#[test]
fn moving_point_drags_match_full_refits() {
    check_drag(50, 3, DraggedEnd::Moving, Regularisation::Smoothing(0.0), Base::None);
    check_drag(300, 4, DraggedEnd::Moving, Regularisation::Smoothing(0.0), Base::None);
}

#[test]
fn fixed_point_drags_match_full_refits() {
    check_drag(50, 5, DraggedEnd::Fixed, Regularisation::Smoothing(0.0), Base::None);
    check_drag(300, 6, DraggedEnd::Fixed, Regularisation::Smoothing(0.0), Base::None);
}

/// On a base (a field under the landmarks, the window's Refine by intensities): the layers' data are the points the
/// base moved, and each end's drag moves one datum and one centre as without it.
#[test]
fn drags_on_a_base_match_full_refits_of_the_layers() {
    check_drag(60, 12, DraggedEnd::Moving, Regularisation::Smoothing(0.0), Base::Bent);
    check_drag(60, 13, DraggedEnd::Fixed, Regularisation::Smoothing(0.0), Base::Bent);
    check_drag(40, 14, DraggedEnd::Fixed, Regularisation::Smoothing(2.0), Base::Bent);
}

#[test]
fn smoothing_drags_match_full_refits() {
    check_drag(50, 7, DraggedEnd::Moving, Regularisation::Smoothing(2.0), Base::None);
    check_drag(50, 8, DraggedEnd::Fixed, Regularisation::Smoothing(2.0), Base::None);
}

/// L x = b for the explicitly assembled L = [K + dI, P; Pᵀ, 0] (raw coordinates: P̂ spans the same columns, so the
/// weights agree and the kernel rows of the residual must vanish).
#[test]
fn solve_inverts_the_assembled_system() {
    let (fixed, moving) = pairs(40, 9);
    let reg = Regularisation::Smoothing(0.5);
    let sys = FactoredTps::<Moving, Fixed>::fit(&fixed, &moving, reg).expect("fit");
    let n = fixed.len();
    let q: Vec<[f64; 3]> = fixed.iter().map(Point3::coords).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    let mut rhs = DMatrix::<f64>::from_fn(n + 4, 2, |i, _| if i < n { rng.random_range(-1.0..1.0) } else { 0.0 });
    let b = rhs.clone();
    assert!(sys.solve_in_place(&mut rhs));
    // Kernel rows: Σⱼ (K + dI)ᵢⱼ wⱼ + affine(qᵢ) = bᵢ; constraint rows: Σ wⱼ = 0, Σ wⱼ qⱼ = 0.
    // Kernel rows: (K + dI) W + P̂ Â = B, and P̂ spans the columns of P = [qᵢᵀ 1], so B − (K + dI) W must lie in
    // that span; constraint rows: Pᵀ W = 0.
    let k = DMatrix::from_fn(n, n, |i, j| {
        if i == j { reg.k_diagonal() } else { (0..3).map(|a| (q[i][a] - q[j][a]).powi(2)).sum::<f64>().sqrt() }
    });
    let p = DMatrix::from_fn(n, 4, |i, a| if a < 3 { q[i][a] } else { 1.0 });
    let w = rhs.rows(0, n).clone_owned();
    let target = b.rows(0, n) - &k * &w;
    let coef = (p.transpose() * &p).lu().solve(&(p.transpose() * &target)).expect("normal equations");
    let off_span = (target - &p * coef).amax();
    let constraint = (p.transpose() * &w).amax();
    assert!(off_span < 1e-9, "kernel rows: residual {off_span:e}");
    assert!(constraint < 1e-9, "constraint rows: residual {constraint:e}");
}

#[test]
fn a_point_dragged_onto_another_is_refused() {
    let (fixed, moving) = pairs(30, 11);
    let g = grid();
    let mut texels = vec![[0.0f32; 4]; g.texel_count()];
    let drag = PairDrag::new(&fixed, &moving, 2, DraggedEnd::Fixed, Regularisation::Interpolate).expect("drag");
    let onto = drag.step(fixed[5].coords()).expect_err("onto another point").to_string();
    assert!(onto.contains("point 3 lands on point 6"), "{onto}");
    let nan = drag.step([f64::NAN, 0.0, 0.0]).expect_err("not finite").to_string();
    assert!(nan.contains("landmark 3 "), "{nan}");
    let drag = PairDrag::new(&fixed, &moving, 2, DraggedEnd::Moving, Regularisation::Interpolate).expect("drag");
    assert!(drag.step(moving[7].coords()).is_err());
    let unmoved = drag.step(moving[2].coords()).expect("no move at all is fine");
    DragTexture::new(&drag, g).fill(&drag, &unmoved, &mut texels);
    // Pairs given twice cannot be dragged apart by the fast path.
    let (mut f2, mut m2) = (fixed.clone(), moving.clone());
    f2.push(fixed[0]);
    m2.push(moving[0]);
    assert!(PairDrag::new(&f2, &m2, 0, DraggedEnd::Fixed, Regularisation::Interpolate).is_err());
}
