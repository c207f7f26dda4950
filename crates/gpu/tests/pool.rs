//! [`warpbench_gpu::TexturePool`]: textures come back by descriptor, render targets drawn from a pool reuse them
//! after a drop (and still render correctly), and trimming frees what has been idle.

mod common;

use common::*;
use warpbench_gpu::{FeatureRequest, OrbitCamera, PoolStats, Projection, RenderSettings, RenderTarget, TexturePool};

#[test]
fn targets_reuse_pooled_textures_by_descriptor() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let pool = TexturePool::new(&ctx.device);
    let phantoms = Phantoms::new();
    let scene = Scene::new(&ctx, &phantoms, None, 16);
    let gpu = GpuScene::new(&ctx, &scene);
    let camera = OrbitCamera::fit(v3(-60.0, -60.0, -60.0), v3(60.0, 60.0, 60.0), Projection::Orthographic);
    let u = scene.uniforms(&camera, &RenderSettings::default(), (48, 40));
    let expected = gpu.render(&ctx, &scene, &u);

    let render_into = |target: &RenderTarget| {
        let f = warpbench_gpu::GpuLayer {
            volume: &gpu.fixed,
            control: None,
            prefiltered: None,
            style: scene.fixed_style,
            procedural: None,
            view: None,
        };
        let m = warpbench_gpu::GpuLayer {
            volume: &gpu.moving,
            control: None,
            prefiltered: None,
            style: scene.moving_style,
            procedural: None,
            view: None,
        };
        let frame = warpbench_gpu::GpuFrame { fixed: f, moving: m, tfs: &gpu.tfs };
        let data = warpbench_gpu::RaycastDrawData::with_uniforms(&ctx, &gpu.renderer, &frame, u);
        gpu.renderer.render(&ctx, &data, target).expect("render");
        target.read_back(&ctx).expect("read back")
    };
    {
        let first = RenderTarget::from_pool(&pool, 48, 40);
        assert_eq!(render_into(&first), expected);
    }
    assert_eq!(pool.stats(), PoolStats { created: 2, reused: 0, free: 2 }, "colour and hit depth go back");
    {
        // Same size: both textures are reused, and the frame is rendered afresh into them.
        let second = RenderTarget::from_pool(&pool, 48, 40);
        assert_eq!(pool.stats(), PoolStats { created: 2, reused: 2, free: 0 });
        assert_eq!(render_into(&second), expected);
        // Another size while the first pair is in use: new textures.
        let other = RenderTarget::from_pool(&pool, 64, 64);
        assert_eq!((other.width, pool.stats().created), (64, 4));
    }
    assert_eq!(pool.stats().free, 4);
    // Idle for more than one frame: trimmed.
    pool.begin_frame();
    assert_eq!(pool.trim(1), 0, "released this frame or the last one: kept");
    pool.begin_frame();
    pool.begin_frame();
    assert_eq!(pool.trim(1), 4);
    assert_eq!(pool.stats().free, 0);
    ctx.check_errors().expect("no wgpu errors");
}
