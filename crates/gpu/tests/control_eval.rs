//! GPU control-texture evaluation ([`ControlEvalPass`]) against its oracle, the solver's CPU sampling
//! (`warpbench_solver::control::ControlTexture`): real TPS and hierarchical B-spline pull-backs fitted by the solver to
//! landmarks with LPS offsets of a few hundred mm, evaluated into 33³ and 64³ grids and compared texel by texel and at
//! random points through the trilinear lookup; the displacement bounds reduced on the GPU against the read-back texels;
//! reuse of the target texture; bad input.

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_gpu::control_eval::{self, MAX_LATTICES, MAX_TPS_CENTRES};
use warpbench_gpu::{
    BSplineDesc, ControlEvalPass, ControlGridDesc, FeatureRequest, GpuContext, GpuControlTexture, GpuError,
    LatticeDesc, TpsDesc,
};
use warpbench_io::geometry::Point3;
use warpbench_solver::bspline::{BSplineParams, HierarchicalBSpline};
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::tps::{self, Tps};
use warpbench_solver::{Aabb, Fixed, Moving};

/// The voxel size the tolerance is stated for: 1 mm, the finest of the CT/MR volumes we register.
const VOXEL_MM: f64 = 1.0;
/// GPU (f32, local coordinates) vs solver (f64, rounded to f32): at most 1e-3 voxel. The f32 evaluation errs by
/// about N·2⁻²⁴·Σ|wᵢ|rᵢ ≈ 1e-5 mm here, so this leaves a wide margin yet catches any layout or convention error
/// (half a texel of a 3 mm pitch moves a 5–10 mm warp by ≫ 1e-3 mm). With `Rgba16Float` textures the measured f16
/// rounding error ([`warpbench_gpu::ControlInfo::quantisation_mm`]) is added.
const TOLERANCE_MM: f64 = 1e-3 * VOXEL_MM;
const CENTRE_LPS: [f64; 3] = [-20.0, 150.0, 400.0];
const HALF_BOX_MM: f64 = 100.0;
/// Random lookup points per comparison.
const PROBES: usize = 2000;

fn context(request: FeatureRequest) -> Option<(GpuContext, ControlEvalPass)> {
    let ctx = common::context(request)?;
    let pass = ControlEvalPass::new(&ctx).expect("control eval pass");
    Some((ctx, pass))
}

/// `n` landmark pairs: fixed points uniform in the box, moving = fixed + a smooth 5–10 mm field + 0.5 mm jitter.
fn landmarks(n: usize, seed: u64) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut moving, mut fixed) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n {
        let q: [f64; 3] = std::array::from_fn(|a| CENTRE_LPS[a] + rng.random_range(-HALF_BOX_MM..HALF_BOX_MM));
        let l: [f64; 3] = std::array::from_fn(|a| q[a] - CENTRE_LPS[a]);
        let d = [6.0 + 2.0 * (l[1] / 30.0).sin(), -5.0 + 3.0 * (l[2] / 40.0).cos(), 7.0 + 2.0 * (l[0] / 35.0).sin()];
        let p: [f64; 3] = std::array::from_fn(|a| q[a] + d[a] + rng.random_range(-0.5..0.5));
        fixed.push(Point3::from_array(q));
        moving.push(Point3::from_array(p));
    }
    (moving, fixed)
}

/// The landmark box, grown by 10 mm (the control grid's box).
fn domain() -> Aabb<Fixed> {
    let (lo, hi) = (CENTRE_LPS.map(|c| c - HALF_BOX_MM - 10.0), CENTRE_LPS.map(|c| c + HALF_BOX_MM + 10.0));
    Aabb::new(Point3::from_array(lo), Point3::from_array(hi))
}

fn grids(n: usize) -> (ControlGridDesc, ControlGrid) {
    let d = domain();
    let solver = ControlGrid::cube(n, d).expect("solver grid");
    (ControlGridDesc::cube(n, d.min.coords(), d.max.coords()), solver)
}

/// A fitted TPS pull-back and its plain-data form.
struct TpsData {
    tps: Tps<Moving, Fixed>,
    centres: Vec<[f64; 3]>,
    weights: Vec<[f64; 3]>,
}

impl TpsData {
    fn fit(n: usize, seed: u64) -> Self {
        let (moving, fixed) = landmarks(n, seed);
        let tps = tps::fit_pullback(&moving, &fixed, 0.0).expect("TPS fit");
        let centres = tps.centres().iter().map(Point3::coords).collect();
        let weights = tps.weights();
        Self { tps, centres, weights }
    }

    fn desc(&self) -> TpsDesc<'_> {
        let a = self.tps.linear();
        TpsDesc {
            centres_ref: &self.centres,
            weights: &self.weights,
            linear: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
            translation: self.tps.translation(),
        }
    }
}

fn fit_bspline(n: usize, seed: u64) -> HierarchicalBSpline<Moving, Fixed> {
    let (moving, fixed) = landmarks(n, seed);
    let d = domain();
    // The B-spline's domain is the landmark box without the margin, so the grid's outer texels exercise the clamping.
    let inner = Aabb::new(
        Point3::from_array(d.min.coords().map(|c| c + 10.0)),
        Point3::from_array(d.max.coords().map(|c| c - 10.0)),
    );
    HierarchicalBSpline::fit_pullback(&moving, &fixed, inner, &BSplineParams::default()).expect("B-spline fit")
}

fn lattice_desc(spline: &HierarchicalBSpline<Moving, Fixed>) -> LatticeDesc<'_> {
    let l = spline.lattice();
    LatticeDesc { cells: l.cells(), min_mm: l.min_mm(), max_mm: l.max_mm(), coefficients: l.coefficients() }
}

/// Largest per-component difference between the GPU texels and the oracle's, mm.
fn worst_texel_mm(gpu: &[[f32; 4]], oracle: &ControlTexture) -> f64 {
    assert_eq!(gpu.len(), oracle.texels.len());
    gpu.iter()
        .zip(&oracle.texels)
        .flat_map(|(g, o)| (0..4).map(move |c| (f64::from(g[c]) - f64::from(o[c])).abs()))
        .fold(0.0, f64::max)
}

/// Largest difference of the two textures' trilinear lookups (the solver's `lookup_raw`, the GPU sampler's math) at
/// random points of the box and a little beyond it (clamp-to-edge), mm.
fn worst_lookup_mm(gpu: &ControlTexture, oracle: &ControlTexture, seed: u64) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (lo, hi) = (oracle.grid.domain.min.coords(), oracle.grid.domain.max.coords());
    (0..PROBES)
        .map(|_| {
            let x: [f64; 3] = std::array::from_fn(|a| rng.random_range(lo[a] - 5.0..hi[a] + 5.0));
            let (g, o) = (gpu.lookup_raw(x), oracle.lookup_raw(x));
            (0..3).map(|c| (g[c] - o[c]).abs()).fold(0.0, f64::max)
        })
        .fold(0.0, f64::max)
}

/// Reads `control` back and checks it against `oracle`: texels, lookups, and the info (bounds, box, dims).
#[allow(clippy::float_cmp, reason = "the bounds are the stored texels' min and max exactly, and the box is copied")]
fn check_against_oracle(ctx: &GpuContext, control: &GpuControlTexture, oracle: &ControlTexture, what: &str) {
    let texels = control_eval::read_back_texels(ctx, control).expect("read back");
    let info = control.info;
    let tolerance = TOLERANCE_MM + f64::from(info.quantisation_mm);
    let texel = worst_texel_mm(&texels, oracle);
    let gpu = ControlTexture { grid: oracle.grid, texels: texels.clone() };
    let lookup = worst_lookup_mm(&gpu, oracle, 5);
    eprintln!(
        "{what}: {:?} {:?}, worst texel {texel:.2e} mm, worst lookup {lookup:.2e} mm, f16 rounding {:.2e} mm",
        info.dims,
        control.texture.format(),
        info.quantisation_mm
    );
    assert!(texel <= tolerance, "{what}: texels differ by {texel} mm (tolerance {tolerance})");
    assert!(lookup <= tolerance, "{what}: lookups differ by {lookup} mm (tolerance {tolerance})");
    // The warp is not trivial: a convention error would show.
    let spread = oracle.texels.iter().map(|t| f64::from(t[0].abs())).fold(0.0, f64::max);
    assert!(spread > 3.0, "{what}: the test warp is too small ({spread} mm)");
    // Bounds are exact: the componentwise min and max of the texels as stored.
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for t in &texels {
        for c in 0..3 {
            lo[c] = lo[c].min(t[c]);
            hi[c] = hi[c].max(t[c]);
        }
    }
    assert_eq!(info.disp_min_mm.to_array(), lo, "{what}: disp_min_mm");
    assert_eq!(info.disp_max_mm.to_array(), hi, "{what}: disp_max_mm");
    assert_eq!(info.dims, oracle.grid.dims.map(|d| d as u32));
    assert_eq!(info.box_min_ref.to_array(), oracle.grid.domain.min.coords());
    assert_eq!(info.box_max_ref.to_array(), oracle.grid.domain.max.coords());
    if control.texture.format() == wgpu::TextureFormat::Rgba32Float {
        assert!(info.quantisation_mm == 0.0, "f32 textures are not rounded");
    } else {
        // Half an f16 ulp of the largest displacement, 2⁻¹¹·max|d|, bounds correct rounding.
        let largest = lo.iter().chain(&hi).fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(info.quantisation_mm <= largest / 2048.0 + 1e-7, "{what}: f16 rounding {}", info.quantisation_mm);
    }
}

fn tps_matches_the_solver(request: FeatureRequest) {
    let Some((ctx, pass)) = context(request) else { return };
    let warp = TpsData::fit(30, 1);
    for n in [33, 64] {
        let (grid, solver_grid) = grids(n);
        let oracle = ControlTexture::sample(&warp.tps, solver_grid);
        let control = pass.evaluate_tps(&ctx, &warp.desc(), &grid, None).expect("evaluate TPS");
        check_against_oracle(&ctx, &control, &oracle, &format!("TPS N = 30, {n}³"));
    }
}

fn bspline_matches_the_solver(request: FeatureRequest) {
    let Some((ctx, pass)) = context(request) else { return };
    let spline = fit_bspline(60, 2);
    assert!(spline.fit_report().levels_used >= 2, "a hierarchy: {:?}", spline.fit_report());
    let lattice = lattice_desc(&spline);
    for n in [33, 64] {
        let (grid, solver_grid) = grids(n);
        let oracle = ControlTexture::sample(&spline, solver_grid);
        let control =
            pass.evaluate_bspline(&ctx, &BSplineDesc { lattices: &[lattice] }, &grid, None).expect("evaluate B-spline");
        check_against_oracle(&ctx, &control, &oracle, &format!("B-spline {:?} lattice, {n}³", lattice.cells));
    }
}

#[test]
fn tps_matches_the_solver_texel_by_texel_and_at_random_points() {
    tps_matches_the_solver(FeatureRequest::default());
}

#[test]
fn tps_matches_the_solver_in_the_f16_fallback() {
    tps_matches_the_solver(FeatureRequest { allow_float32_filterable: false, ..FeatureRequest::default() });
}

#[test]
fn hierarchical_bspline_matches_the_solver_texel_by_texel_and_at_random_points() {
    bspline_matches_the_solver(FeatureRequest::default());
}

#[test]
fn hierarchical_bspline_matches_the_solver_in_the_f16_fallback() {
    bspline_matches_the_solver(FeatureRequest { allow_float32_filterable: false, ..FeatureRequest::default() });
}

/// Several lattices (e.g. unrefined levels) are summed, each clamped to its own box: an arbitrary coarse lattice over
/// the grid's box plus the solver's fitted lattice over a smaller one, against the sum of the solver's evaluations.
#[test]
fn several_lattices_are_summed() {
    let Some((ctx, pass)) = context(FeatureRequest::default()) else { return };
    let spline = fit_bspline(40, 3);
    let fine = spline.lattice();
    let coarse_cells = [3, 2, 4];
    let d = domain();
    let mut coarse = warpbench_solver::bspline::ControlLattice::zeros(coarse_cells, d.min.coords(), d.max.coords())
        .expect("coarse lattice");
    for (i, c) in coarse.coefficients_mut().iter_mut().enumerate() {
        *c = 2.0 * ((i as f64) * 0.37).sin();
    }
    let lattices = [
        LatticeDesc {
            cells: coarse.cells(),
            min_mm: coarse.min_mm(),
            max_mm: coarse.max_mm(),
            coefficients: coarse.coefficients(),
        },
        lattice_desc(&spline),
    ];
    let desc = BSplineDesc { lattices: &lattices };
    let (grid, solver_grid) = grids(33);
    let control = pass.evaluate_bspline(&ctx, &desc, &grid, None).expect("evaluate");
    let texels = control_eval::read_back_texels(&ctx, &control).expect("read back");
    // Oracle: the sum of the two solver lattices, each clamped to its own box.
    let oracle: Vec<[f32; 4]> = (0..solver_grid.texel_count())
        .map(|i| {
            let [nx, ny, _] = solver_grid.dims;
            let x = solver_grid.texel_centre([i % nx, (i / nx) % ny, i / (nx * ny)]);
            let (a, b) = (coarse.eval(x), fine.eval(x));
            [(a[0] + b[0]) as f32, (a[1] + b[1]) as f32, (a[2] + b[2]) as f32, 0.0]
        })
        .collect();
    let worst = worst_texel_mm(&texels, &ControlTexture { grid: solver_grid, texels: oracle });
    let tolerance = TOLERANCE_MM + f64::from(control.info.quantisation_mm);
    assert!(worst <= tolerance, "two lattices: {worst} mm (tolerance {tolerance})");
    // And `BSplineDesc::eval` (the crate's f64 reference) is the same function.
    let x = [CENTRE_LPS[0] + 13.0, CENTRE_LPS[1] - 71.0, CENTRE_LPS[2] + 99.0];
    let (u, a, b) = (desc.eval(x), coarse.eval(x), fine.eval(x));
    assert!((0..3).all(|c| (u[c] - x[c] - a[c] - b[c]).abs() < 1e-9));
}

/// A second evaluation into the returned texture overwrites every texel and the bounds (no stale data), and keeps the
/// texture (no reallocation); a target of other dims is replaced.
#[test]
fn the_target_texture_is_reused_without_stale_data() {
    let Some((ctx, pass)) = context(FeatureRequest::default()) else { return };
    let (grid, solver_grid) = grids(33);
    let (first, second) = (TpsData::fit(30, 1), TpsData::fit(25, 9));
    let a = pass.evaluate_tps(&ctx, &first.desc(), &grid, None).expect("first");
    let a_texture = a.texture.clone();
    let a_info = a.info;
    let b = pass.evaluate_tps(&ctx, &second.desc(), &grid, Some(a)).expect("second");
    assert_eq!(b.texture, a_texture, "same dims and format: the texture is reused");
    assert_ne!(b.info.disp_min_mm, a_info.disp_min_mm, "the bounds are the new warp's");
    check_against_oracle(&ctx, &b, &ControlTexture::sample(&second.tps, solver_grid), "reused target");
    // A B-spline into the TPS's texture, and back: each evaluation owns every texel.
    let spline = fit_bspline(40, 4);
    let c = pass
        .evaluate_bspline(&ctx, &BSplineDesc { lattices: &[lattice_desc(&spline)] }, &grid, Some(b))
        .expect("B-spline into the TPS texture");
    assert_eq!(c.texture, a_texture);
    check_against_oracle(&ctx, &c, &ControlTexture::sample(&spline, solver_grid), "B-spline into reused target");
    // Other dims: a new texture.
    let (grid_64, _) = grids(64);
    let d = pass.evaluate_tps(&ctx, &first.desc(), &grid_64, Some(c)).expect("other dims");
    assert_ne!(d.texture, a_texture);
    assert_eq!(d.info.dims, [64; 3]);
}

/// Evaluations recorded into one encoder do not share per-call data: each sees its own weights and bounds.
#[test]
fn two_evaluations_in_one_submission_keep_their_own_data() {
    let Some((ctx, pass)) = context(FeatureRequest::default()) else { return };
    let (grid, solver_grid) = grids(17);
    let (first, second) = (TpsData::fit(30, 1), TpsData::fit(25, 9));
    let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
    let a = pass.encode_tps(&ctx, &mut encoder, &first.desc(), &grid, None).expect("first");
    let b = pass.encode_tps(&ctx, &mut encoder, &second.desc(), &grid, None).expect("second");
    ctx.queue.submit([encoder.finish()]);
    let (a, b) = (a.resolve(&ctx).expect("resolve first"), b.resolve(&ctx).expect("resolve second"));
    check_against_oracle(&ctx, &a, &ControlTexture::sample(&first.tps, solver_grid), "first of two");
    check_against_oracle(&ctx, &b, &ControlTexture::sample(&second.tps, solver_grid), "second of two");
}

/// A TPS of 10 000 centres (twice the solver's limit) evaluates; the result is checked against the crate's f64
/// reference at a few texels. More than [`MAX_TPS_CENTRES`] is refused before anything is allocated.
#[test]
fn large_tps_evaluates_and_absurd_sizes_are_refused() {
    let Some((ctx, pass)) = context(FeatureRequest::default()) else { return };
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let n = 10_000;
    let centres: Vec<[f64; 3]> =
        (0..n).map(|_| std::array::from_fn(|a| CENTRE_LPS[a] + rng.random_range(-HALF_BOX_MM..HALF_BOX_MM))).collect();
    let weights: Vec<[f64; 3]> = (0..n).map(|_| std::array::from_fn(|_| rng.random_range(-1e-4..1e-4))).collect();
    let desc = TpsDesc {
        centres_ref: &centres,
        weights: &weights,
        linear: [[1.01, 0.0, 0.02], [0.0, 0.99, 0.0], [-0.01, 0.0, 1.0]],
        translation: [2.0, -4.0, 1.0],
    };
    let (grid, solver_grid) = grids(8);
    let control = pass.evaluate_tps(&ctx, &desc, &grid, None).expect("10 000 centres");
    let texels = control_eval::read_back_texels(&ctx, &control).expect("read back");
    // 10⁴ f32 terms of up to 0.03 mm: ≈ 10⁴ · 2⁻²⁴ · 0.03 mm of rounding at worst, plus f16 rounding if stored so.
    let tolerance = 1e-4 + f64::from(control.info.quantisation_mm);
    for (i, t) in texels.iter().enumerate().step_by(37) {
        let [nx, ny, _] = solver_grid.dims;
        let x = solver_grid.texel_centre([i % nx, (i / nx) % ny, i / (nx * ny)]);
        let u = desc.eval(x);
        for c in 0..3 {
            assert!((f64::from(t[c]) - (u[c] - x[c])).abs() < tolerance, "texel {i}: {t:?} vs {u:?} − {x:?}");
        }
    }
    let many = vec![[0.0; 3]; MAX_TPS_CENTRES + 1];
    let err = pass
        .evaluate_tps(&ctx, &TpsDesc { centres_ref: &many, weights: &many, ..desc }, &grid, None)
        .expect_err("too many centres");
    assert!(matches!(err, GpuError::InvalidInput(_)) && err.to_string().contains("at most"), "{err}");
}

#[test]
fn bad_input_is_an_error() {
    let Some((ctx, pass)) = context(FeatureRequest::default()) else { return };
    let warp = TpsData::fit(30, 1);
    let (grid, _) = grids(9);
    let invalid = |r: warpbench_gpu::Result<GpuControlTexture>, what: &str, needle: &str| {
        let err = r.expect_err(what);
        assert!(matches!(err, GpuError::InvalidInput(_)), "{what}: {err}");
        assert!(err.to_string().contains(needle), "{what}: {err}");
    };
    // TPS: lengths, NaN, affine part, f32 overflow.
    let desc = warp.desc();
    invalid(
        pass.evaluate_tps(&ctx, &TpsDesc { weights: &warp.weights[1..], ..desc }, &grid, None),
        "short weights",
        "30 centres but 29 weights",
    );
    let mut nan = warp.centres.clone();
    nan[4][2] = f64::NAN;
    invalid(pass.evaluate_tps(&ctx, &TpsDesc { centres_ref: &nan, ..desc }, &grid, None), "NaN centre", "centre 4");
    invalid(
        pass.evaluate_tps(&ctx, &TpsDesc { translation: [0.0, f64::INFINITY, 0.0], ..desc }, &grid, None),
        "infinite translation",
        "affine",
    );
    let mut huge = warp.weights.clone();
    huge[0][0] = 1e300;
    invalid(pass.evaluate_tps(&ctx, &TpsDesc { weights: &huge, ..desc }, &grid, None), "f32 overflow", "f32");
    // Grids: zero, absurd, empty box, NaN box.
    for (dims, needle) in [([0, 9, 9], "dims"), ([9, 9, 100_000], "dims")] {
        invalid(pass.evaluate_tps(&ctx, &desc, &ControlGridDesc { dims, ..grid }, None), "bad dims", needle);
    }
    let flat = ControlGridDesc { box_max_ref: [grid.box_max_ref[0], grid.box_min_ref[1], grid.box_max_ref[2]], ..grid };
    invalid(pass.evaluate_tps(&ctx, &desc, &flat, None), "flat box", "box");
    let nan_box = ControlGridDesc { box_min_ref: [f64::NAN, 0.0, 0.0], ..grid };
    invalid(pass.evaluate_tps(&ctx, &desc, &nan_box, None), "NaN box", "box");
    // B-spline: coefficient count, NaN, too many lattices.
    let spline = fit_bspline(20, 5);
    let lattice = lattice_desc(&spline);
    let short = LatticeDesc { coefficients: &lattice.coefficients[..30], ..lattice };
    invalid(
        pass.evaluate_bspline(&ctx, &BSplineDesc { lattices: &[lattice, short] }, &grid, None),
        "short lattice",
        "lattice 1",
    );
    let mut nan = lattice.coefficients.to_vec();
    nan[10] = f64::NAN;
    invalid(
        pass.evaluate_bspline(
            &ctx,
            &BSplineDesc { lattices: &[LatticeDesc { coefficients: &nan, ..lattice }] },
            &grid,
            None,
        ),
        "NaN coefficient",
        "coefficient 10",
    );
    let many = [lattice; MAX_LATTICES + 1];
    invalid(
        pass.evaluate_bspline(&ctx, &BSplineDesc { lattices: &many }, &grid, None),
        "too many lattices",
        "lattices",
    );
    ctx.check_errors().expect("no wgpu errors");
}

/// Displacements beyond the f16 range cannot be stored as halves: the f16 fallback reports an error rather than
/// bounds or texels that are wrong; in f32 they evaluate.
#[test]
#[allow(clippy::float_cmp, reason = "a translation of 1e5 mm is exact in f32")]
fn displacements_beyond_f16_are_an_error_in_the_f16_fallback() {
    for allow_float32_filterable in [false, true] {
        let request = FeatureRequest { allow_float32_filterable, ..FeatureRequest::default() };
        let Some((ctx, pass)) = context(request) else { return };
        let desc = TpsDesc {
            centres_ref: &[],
            weights: &[],
            linear: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [1.0e5, 0.0, 0.0],
        };
        let (grid, _) = grids(4);
        let result = pass.evaluate_tps(&ctx, &desc, &grid, None);
        if ctx.capabilities.float32_filterable {
            let control = result.expect("f32 stores 1e5 mm");
            assert_eq!(control.info.disp_min_mm.x, 1.0e5);
            assert_eq!(control.info.disp_max_mm.x, 1.0e5);
        } else {
            let err = result.expect_err("f16 cannot store 1e5 mm");
            assert!(err.to_string().contains("f16"), "{err}");
        }
        ctx.check_errors().expect("no wgpu errors");
    }
}
