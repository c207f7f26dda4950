//! Empty-space skipping ([`warpbench_gpu::empty_space`]): the image with skipping is the image without, bit for bit
//! (colour and first-hit depth), through a warp, for every shading mode, blend modes and jitter; both match the CPU
//! reference within the tolerance a conformant device's filter allows ([`Allowance`], as `gpu_vs_cpu.rs`); every brick the grid marks empty is transparent at densely sampled
//! points (the CPU reference's classification, through the warp); a one-voxel-thin feature on a brick boundary is
//! kept; and picking through the same grid returns the same hits.
//!
//! Bit-exactness is the law here, not a tolerance: the marcher takes exactly the samples it takes without skipping
//! (it jumps along the same lattice t_k) and a skipped sample would have added premultiplied zero.

mod common;

use common::*;
use glam::{DVec3, Vec3};
use warpbench_gpu::cpu_reference::{self, CpuLayer};
use warpbench_gpu::empty_space::{BrickLattice, OCCUPIED_FIXED, OCCUPIED_MOVING};
use warpbench_gpu::{
    BlendMode, Classification, FeatureRequest, GpuContext, GpuEmptySpace, GpuFrame, GpuLayer, LayerStyle, OrbitCamera,
    PickPass, PickRay, PickRequest, PickTarget, PrefilterSettings, Probe, Projection, RaycastDrawData, RaycastUniforms,
    RenderSettings, RenderTarget, Shading, ShadingMode, TransferFunction, VolumeDesc, VolumeSamples, Window,
};

const SIZE: (u32, u32) = (64, 64);

fn camera(azimuth_rad: f32, zoom: f32) -> OrbitCamera {
    let cam =
        OrbitCamera::fit(v3(-70.0, -70.0, -70.0), v3(70.0, 70.0, 70.0), Projection::Perspective { fov_y_rad: 0.6 });
    OrbitCamera { azimuth_rad, elevation_rad: 0.3, zoom, ..cam }
}

fn frame<'a>(gpu: &'a GpuScene, s: &Scene) -> GpuFrame<'a> {
    GpuFrame {
        fixed: GpuLayer {
            volume: &gpu.fixed,
            control: None,
            prefiltered: gpu.fixed_pf.as_ref(),
            style: s.fixed_style,
            procedural: None,
            view: s.views[0],
        },
        moving: GpuLayer {
            volume: &gpu.moving,
            control: gpu.control.as_ref(),
            prefiltered: gpu.moving_pf.as_ref(),
            style: s.moving_style,
            procedural: s.moving_procedural,
            view: s.views[1],
        },
        tfs: &gpu.tfs,
    }
}

/// The grid of the scene's automatic proxy box, with the control texture's texels.
fn grid(ctx: &GpuContext, gpu: &GpuScene, s: &Scene) -> GpuEmptySpace {
    let f = frame(gpu, s);
    f.empty_space(ctx, f.proxy_box_ref(), [None, s.control.as_ref()])
}

/// Colour and first-hit depth bits of the frame `u`, skipping by `empty_space` or not.
fn render(
    ctx: &GpuContext,
    gpu: &GpuScene,
    s: &Scene,
    u: &RaycastUniforms,
    empty_space: Option<&GpuEmptySpace>,
) -> (Vec<u8>, Vec<u32>) {
    let data = RaycastDrawData::with_empty_space(ctx, &gpu.renderer, &frame(gpu, s), *u, empty_space);
    assert_eq!(data.uniforms.empty_space.enabled, u32::from(empty_space.is_some()), "the grid fits the frame");
    let target = RenderTarget::new(ctx, SIZE.0, SIZE.1);
    gpu.renderer.render(ctx, &data, &target).expect("render");
    let depth = target.read_hit_depth(ctx).expect("hit depth").iter().map(|d| d.to_bits()).collect();
    (target.read_back(ctx).expect("read back"), depth)
}

/// Checks, at 4³ points per brick (and its corners), that every volume the grid marks empty there classifies to
/// zero on the CPU (through its warp). Returns the number of (brick, volume) pairs marked empty.
fn check_empty_bricks_are_transparent(s: &Scene, gpu: &GpuScene, grid: &GpuEmptySpace, u: &RaycastUniforms) -> usize {
    let cells = grid_cells(s, gpu, grid);
    let lattice = grid.lattice;
    let f = CpuLayer::new(&s.fixed, None, None);
    let m = CpuLayer::new(&s.moving, s.control.as_ref(), None);
    let mut empty = 0;
    let [nx, ny, nz] = lattice.dims;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let cell = u32::from(cells[(i + nx * (j + ny * k)) as usize]);
                let (lo, hi) = lattice.brick_box([i, j, k]);
                for (bit, layer, v) in [(OCCUPIED_FIXED, &f, &u.fixed), (OCCUPIED_MOVING, &m, &u.moving)] {
                    if cell & bit != 0 {
                        continue;
                    }
                    empty += 1;
                    for p in 0..5usize.pow(3) {
                        let w = DVec3::new((p % 5) as f64, ((p / 5) % 5) as f64, (p / 25) as f64) / 4.0;
                        let x = (lo + w * (hi - lo)).as_vec3();
                        let c = cpu_reference::classify(layer, u, v, &s.tfs, x, Vec3::Z);
                        assert!(c.w <= 0.0, "brick {i},{j},{k} (bit {bit}) is marked empty but α = {} at {x}", c.w);
                    }
                }
            }
        }
    }
    empty
}

/// The CPU grid behind `grid` (rebuilt the same way: the GPU texture is not read back).
fn grid_cells(s: &Scene, gpu: &GpuScene, grid: &GpuEmptySpace) -> Vec<u8> {
    use warpbench_gpu::OccupancyLayer;
    let (fp, mp) = s.params();
    let fixed = OccupancyLayer {
        params: fp,
        bricks: &gpu.fixed.bricks,
        control_texels: None,
        opacity: &gpu.tfs.opacity[fp.style.tf_row as usize],
    };
    let moving = OccupancyLayer {
        params: mp,
        bricks: &gpu.moving.bricks,
        control_texels: s.control.as_ref(),
        opacity: &gpu.tfs.opacity[mp.style.tf_row as usize],
    };
    let cpu = warpbench_gpu::EmptySpaceGrid::build(&fixed, &moving, grid.lattice);
    assert_eq!(cpu.key, grid.key);
    cpu.cells
}

#[test]
fn skipping_keeps_the_image_bit_exact_through_a_warp() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let scene = Scene::new(&ctx, &phantoms, Some(&warp), 16).with_prefilter(PrefilterSettings::default());
    let gpu = GpuScene::new(&ctx, &scene);
    let grid = grid(&ctx, &gpu, &scene);
    eprintln!(
        "grid {:?} bricks of {} mm, {:.0} % empty",
        grid.lattice.dims,
        grid.lattice.brick_mm,
        100.0 * grid.empty_fraction
    );
    assert!(grid.empty_fraction > 0.2, "the scene has empty space to skip: {}", grid.empty_fraction);
    let mix = BlendMode::Mix { moving_weight: 0.5 };
    let (per_sample, preintegrated) = (Classification::PerSample, Classification::PreIntegrated);
    let cases = [
        ("mix, unlit", mix, ShadingMode::None, None, 0.5, per_sample),
        ("mix, DVR, jitter", mix, ShadingMode::Dvr, Some(7), 1.1, per_sample),
        ("moving only, DVR", BlendMode::MovingOnly, ShadingMode::Dvr, None, -2.0, per_sample),
        ("fixed only, unlit", BlendMode::FixedOnly, ShadingMode::None, Some(3), 2.5, per_sample),
        ("checkerboard", BlendMode::Checkerboard { cell_mm: 12.0 }, ShadingMode::None, None, 1.9, per_sample),
        ("difference", BlendMode::Difference, ShadingMode::None, None, 0.2, per_sample),
        ("pre-integrated, mix, unlit", mix, ShadingMode::None, None, 0.5, preintegrated),
        ("pre-integrated, mix, DVR, jitter", mix, ShadingMode::Dvr, Some(7), 1.1, preintegrated),
        ("pre-integrated, moving only, DVR", BlendMode::MovingOnly, ShadingMode::Dvr, None, -2.0, preintegrated),
        ("pre-integrated, fixed only, unlit", BlendMode::FixedOnly, ShadingMode::None, Some(3), 2.5, preintegrated),
        ("pre-integrated, red-cyan", BlendMode::RedCyan, ShadingMode::None, None, 1.9, preintegrated),
    ];
    for (label, blend, mode, jitter_seed, azimuth, classification) in cases {
        let shading = Shading::with_mode(mode);
        let settings = RenderSettings { blend, jitter_seed, shading, classification, ..Default::default() };
        let u = scene.uniforms(&camera(azimuth, 1.0), &settings, SIZE);
        let (plain, plain_depth) = render(&ctx, &gpu, &scene, &u, None);
        let (skipped, skipped_depth) = render(&ctx, &gpu, &scene, &u, Some(&grid));
        assert!(coverage(&plain) > 0.2, "{label}: something to see");
        assert!(plain == skipped, "{label}: skipping changed {} channels", max_diff(&plain, &skipped, 0).1);
        assert!(plain_depth == skipped_depth, "{label}: skipping changed the first-hit depth");
        if jitter_seed.is_none() && mode == ShadingMode::None {
            let (ok, verdict) = scene.allowance(&u, filter).judge(&skipped, Look::Smooth);
            assert!(ok, "{label}: from the CPU reference {verdict}");
        }
    }
    let u = scene.uniforms(&camera(0.5, 1.0), &RenderSettings::default(), SIZE);
    let empty = check_empty_bricks_are_transparent(&scene, &gpu, &grid, &u);
    assert!(empty > 0);
}

/// Through a procedural deformation of the moving layer's data ([`warpbench_gpu::procedural`]), on top of the warp,
/// through the fish-eye lens on both layers and the leafer on one: the bricks are classified through the deformations' image bounds,
/// and skipping still changes nothing.
#[test]
fn skipping_keeps_the_image_bit_exact_through_procedural_deformations() {
    use warpbench_gpu::{Axis, Procedural};
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut scene = Scene::new(&ctx, &phantoms, Some(&warp), 16);
    let gpu = GpuScene::new(&ctx, &scene);
    let c = v3(4.0, -3.0, 2.0);
    for p in [
        Procedural::Twist { centre_mm: c, axis: Axis::Y, rate_rad_per_mm: 0.004 },
        Procedural::bend(c, Axis::Z, Axis::X, false, 0.003),
        Procedural::Bump { centre_mm: c, sigma_mm: 25.0, vector_mm: v3(12.0, -6.0, 4.0) },
    ] {
        scene.moving_procedural = Some(p);
        // The bump under the fish-eye lens too (a view deformation of both layers on top), the bend with the moving
        // layer opened by a leafer.
        scene.views = match p {
            Procedural::Bump { .. } => {
                [Some(warpbench_gpu::ViewDeformation::FishEye {
                    centre_ref: v3(30.0, -65.0, 20.0),
                    radius_mm: 35.0,
                    amplitude: 0.7,
                }); 2]
            }
            Procedural::Bend { .. } => [
                None,
                warpbench_gpu::ViewDeformation::leafer(
                    v3(4.0, -3.0, 2.0),
                    v3(0.6, -1.0, 0.3),
                    v3(0.0, 0.0, 1.0),
                    80.0,
                    0.5,
                ),
            ],
            _ => [None; 2],
        };
        let grid = grid(&ctx, &gpu, &scene);
        for (blend, mode) in [(BlendMode::MovingOnly, ShadingMode::None), (BlendMode::Difference, ShadingMode::Dvr)] {
            let settings = RenderSettings { blend, shading: Shading::with_mode(mode), ..Default::default() };
            let u = scene.uniforms(&camera(0.7, 1.0), &settings, SIZE);
            let (plain, plain_depth) = render(&ctx, &gpu, &scene, &u, None);
            let (skipped, skipped_depth) = render(&ctx, &gpu, &scene, &u, Some(&grid));
            let label = format!("{} {} {}", p.name(), blend.name(), mode.name());
            assert!(coverage(&plain) > 0.2, "{label}: something to see");
            assert!(plain == skipped, "{label}: skipping changed {} channels", max_diff(&plain, &skipped, 0).1);
            assert!(plain_depth == skipped_depth, "{label}: skipping changed the first-hit depth");
        }
        let u = scene.uniforms(&camera(0.7, 1.0), &RenderSettings::default(), SIZE);
        let empty = check_empty_bricks_are_transparent(&scene, &gpu, &grid, &u);
        eprintln!("{}: {:.0} % of bricks empty, {empty} (brick, volume) pairs", p.name(), 100.0 * grid.empty_fraction);
        assert!(grid.empty_fraction > 0.1, "{}: nothing to skip", p.name());
    }
}

/// A grid built for other looks is not used: the frame skips nothing rather than skipping wrongly.
#[test]
fn a_grid_for_another_look_is_ignored() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let mut scene = Scene::new(&ctx, &phantoms, None, 16);
    let gpu = GpuScene::new(&ctx, &scene);
    let grid = grid(&ctx, &gpu, &scene);
    scene.moving_style.window = Window::from_range(-200.0, 20.0);
    let u = scene.uniforms(&camera(0.5, 1.0), &RenderSettings::default(), SIZE);
    let data = RaycastDrawData::with_empty_space(&ctx, &gpu.renderer, &frame(&gpu, &scene), u, Some(&grid));
    assert_eq!(data.uniforms.empty_space.enabled, 0);
}

/// A volume that is zero except for one-voxel-thin slabs of `value` at x = `slab_x` (voxel indices): brick
/// boundaries of the volume's 8-voxel bricks and of the ref grid.
fn slab_scene(ctx: &GpuContext, slab_x: &[usize]) -> Scene {
    const SLAB_N: usize = 40;
    let mut values = vec![0.0f32; SLAB_N.pow(3)];
    for (i, v) in values.iter_mut().enumerate() {
        let (x, y, z) = (i % SLAB_N, (i / SLAB_N) % SLAB_N, i / SLAB_N / SLAB_N);
        if slab_x.contains(&x) && (12..28).contains(&y) && (12..28).contains(&z) {
            *v = 100.0;
        }
    }
    let s = 2.0;
    let h = (SLAB_N as f64 - 1.0) / 2.0 * s;
    let lps_from_index = [[s, 0.0, 0.0, -h], [0.0, s, 0.0, -h], [0.0, 0.0, s, -h], [0.0, 0.0, 0.0, 1.0]];
    let desc = VolumeDesc { dims: [SLAB_N; 3], samples: VolumeSamples::F32(&values), lps_from_index };
    let vol = warpbench_gpu::PreparedVolume::prepare(
        &desc,
        ctx.capabilities,
        warpbench_gpu::VolumeBudget::for_device(&ctx.limits),
    )
    .expect("slab");
    // Transparent only where a lookup sees (almost) no slab: any point within a voxel of a slab is visible, so a
    // brick that misses a slab voxel its lookups read shows as a difference.
    let (clear, solid) = ([1.0, 0.8, 0.6, 0.0], [1.0, 0.8, 0.6, 1.0]);
    let tf = TransferFunction::from_points("slab", &[(0.0, clear), (0.05, clear), (0.06, solid), (1.0, solid)]);
    let style = |visible| LayerStyle {
        window: Window::from_range(0.0, 100.0),
        tf_row: 0,
        opacity_scale: 1.0,
        visible,
        iso_value: 50.0,
    };
    Scene {
        fixed: vol.clone(),
        moving: vol,
        control: None,
        tfs: vec![tf],
        fixed_style: style(true),
        moving_style: style(false),
        prefilter: None,
        fixed_pf: None,
        moving_pf: None,
        moving_procedural: None,
        views: [None; 2],
    }
}

#[test]
fn thin_features_at_brick_boundaries_are_never_skipped() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let filter = DeviceFilter::measure(&ctx);
    // Voxels 7 | 8 and 23 | 24 straddle volume-brick boundaries; 31 is a brick's last voxel.
    let scene = slab_scene(&ctx, &[8, 23, 31]);
    let gpu = GpuScene::new(&ctx, &scene);
    let f = frame(&gpu, &scene);
    // Bricks of 8 mm on the 2 mm grid: the slabs' x lie on ref-brick boundaries too (box min −40 mm).
    let lattice = BrickLattice::covering(f.proxy_box_ref(), 8.0);
    assert!((lattice.brick_mm - 8.0).abs() < 1e-6, "{}", lattice.brick_mm);
    let grid = f.empty_space_on(&ctx, lattice, [None, None]);
    assert!(grid.empty_fraction > 0.4, "mostly empty: {}", grid.empty_fraction);
    for (azimuth, zoom) in [(0.7, 1.6), (1.4, 2.0), (std::f32::consts::FRAC_PI_2, 1.5), (2.3, 1.6)] {
        let settings = RenderSettings { samples_per_voxel: 0.7, ..Default::default() };
        let u = scene.uniforms(&camera(azimuth, zoom), &settings, SIZE);
        let (plain, plain_depth) = render(&ctx, &gpu, &scene, &u, None);
        let (skipped, skipped_depth) = render(&ctx, &gpu, &scene, &u, Some(&grid));
        eprintln!("azimuth {azimuth}: coverage {}", coverage(&plain));
        assert!(coverage(&plain) > 0.02, "azimuth {azimuth}: the slabs are seen ({})", coverage(&plain));
        assert!(plain == skipped && plain_depth == skipped_depth, "azimuth {azimuth}: skipping changed the image");
        let (ok, verdict) = scene.allowance(&u, filter).judge(&skipped, Look::Smooth);
        eprintln!("azimuth {azimuth}: from the CPU reference {verdict}");
        assert!(ok, "azimuth {azimuth}: from the CPU reference {verdict}");
    }
    let u = scene.uniforms(&camera(0.0, 1.0), &RenderSettings::default(), SIZE);
    assert!(check_empty_bricks_are_transparent(&scene, &gpu, &grid, &u) > 0);
}

#[test]
fn picking_through_the_grid_returns_the_same_hits() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let scene = Scene::new(&ctx, &phantoms, Some(&warp), 16);
    let gpu = GpuScene::new(&ctx, &scene);
    let grid = grid(&ctx, &gpu, &scene);
    let pass = PickPass::new(&ctx, &gpu.renderer).expect("pick pass");
    for classification in Classification::ALL {
        let settings = RenderSettings { classification, ..Default::default() };
        let u = scene.uniforms(&camera(0.7, 1.0), &settings, SIZE);
        let rays: Vec<PickRay> = (0..16 * 16)
            .map(|i| {
                let p = [(i % 16) as f32 * 4.0 + 2.0, (i / 16) as f32 * 4.0 + 2.0];
                PickRay::from_pixel(&u, p).expect("ray")
            })
            .collect();
        let plain = RaycastDrawData::with_empty_space(&ctx, &gpu.renderer, &frame(&gpu, &scene), u, None);
        let skipping = RaycastDrawData::with_empty_space(&ctx, &gpu.renderer, &frame(&gpu, &scene), u, Some(&grid));
        assert_eq!(skipping.uniforms.empty_space.enabled, 1);
        for target in [PickTarget::Fixed, PickTarget::Moving] {
            for probe in [Probe::Opacity { threshold: 0.05 }, Probe::DEFAULT, Probe::Gradient { threshold: 5.0 }] {
                let request = PickRequest::new(target, probe);
                let a = pass.pick(&ctx, &plain, &request, &rays).expect("pick");
                let b = pass.pick(&ctx, &skipping, &request, &rays).expect("pick");
                let hits = a.iter().filter(|h| h.found().is_some()).count();
                assert!(hits > 10, "{classification:?} {target:?} {probe:?}: {hits} hits");
                assert_eq!(a, b, "{classification:?} {target:?} {probe:?}: skipping changed a hit");
            }
        }
    }
}
