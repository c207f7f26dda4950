//! [`RenderTarget`]: what the ray caster, its slices and the glyph pass draw into, the image and the first-hit
//! depth beside it, and how that depth is defined ([`HIT_OPACITY`], [`NO_HIT_DEPTH`]).

use crate::device::GpuContext;
use crate::error::Result;
use crate::pool::{TextureKey, TexturePool};

/// The ray caster's first-hit threshold: the hit depth is taken where the accumulated opacity first reaches it.
/// `HIT_OPACITY` in shaders/raycast.wgsl (checked by `tests/shaders.rs`).
pub const HIT_OPACITY: f32 = 0.5;
/// The hit depth of a ray that hits nothing (beyond the far plane's 1). `NO_HIT_DEPTH` in shaders/raycast.wgsl and
/// shaders/glyph.wgsl (checked by `tests/shaders.rs`).
pub const NO_HIT_DEPTH: f32 = 2.0;

/// An `Rgba8Unorm` image the ray caster writes (`STORAGE_BINDING`), the glyph pass draws over
/// (`RENDER_ATTACHMENT`), the app can show (`TEXTURE_BINDING`) and tests can read back (`COPY_SRC`), with
/// the ray caster's first-hit depth beside it (NDC depth as f32 bits in R32Uint, [`NO_HIT_DEPTH`] where nothing was
/// hit), which the glyph pass ([`crate::glyph`]) depth-tests against.
#[derive(Debug)]
pub struct RenderTarget {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub hit_depth: wgpu::Texture,
    pub hit_depth_view: wgpu::TextureView,
    pub width: u32,
    pub height: u32,
    /// Where the textures go back when the target is dropped ([`Self::from_pool`]).
    pool: Option<TexturePool>,
}

impl RenderTarget {
    /// The format of the image: premultiplied RGBA8.
    pub const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
    /// The format of the first-hit depth, the ray caster's second output ([`Self::hit_depth`]): the bits of an f32
    /// NDC depth, because R32Float is not colour-renderable on GLES (wgpu's GL backend), where the glyph pass reads
    /// it, and R32Uint is.
    pub const HIT_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
    /// The usages of both textures.
    pub const USAGE: wgpu::TextureUsages = wgpu::TextureUsages::RENDER_ATTACHMENT
        .union(wgpu::TextureUsages::STORAGE_BINDING)
        .union(wgpu::TextureUsages::TEXTURE_BINDING)
        .union(wgpu::TextureUsages::COPY_SRC);

    #[must_use]
    pub fn new(ctx: &GpuContext, width: u32, height: u32) -> Self {
        // A private pool: the textures are simply freed with the target.
        let mut target = Self::from_pool(&TexturePool::new(&ctx.device), width, height);
        target.pool = None;
        target
    }

    /// A target whose textures come from `pool` and return to it when the target is dropped: resizing a view or
    /// rendering a new slice each frame then reuses GPU memory instead of allocating it.
    #[must_use]
    pub fn from_pool(pool: &TexturePool, width: u32, height: u32) -> Self {
        let key = |format| TextureKey::d2(width.max(1), height.max(1), format, Self::USAGE);
        let texture = pool.acquire(key(Self::COLOUR_FORMAT), "raycast target");
        let hit_depth = pool.acquire(key(Self::HIT_DEPTH_FORMAT), "raycast hit depth");
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let hit_depth_view = hit_depth.create_view(&wgpu::TextureViewDescriptor::default());
        Self { texture, view, hit_depth, hit_depth_view, width, height, pool: Some(pool.clone()) }
    }

    /// Clears the image to transparent and the hit depth to [`NO_HIT_DEPTH`] (submitted at once).
    pub fn clear(&self, ctx: &GpuContext) {
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("clear target") });
        drop(encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("clear target"),
            color_attachments: &self.colour_attachments(),
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        }));
        ctx.queue.submit([encoder.finish()]);
    }

    /// The two textures as colour attachments, cleared to transparent and to [`NO_HIT_DEPTH`].
    #[must_use]
    fn colour_attachments(&self) -> [Option<wgpu::RenderPassColorAttachment<'_>>; 2] {
        let clear = |view, value| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(value), store: wgpu::StoreOp::Store },
            })
        };
        let no_hit = wgpu::Color { r: f64::from(NO_HIT_DEPTH.to_bits()), g: 0.0, b: 0.0, a: 0.0 };
        [clear(&self.view, wgpu::Color::TRANSPARENT), clear(&self.hit_depth_view, no_hit)]
    }

    /// The first-hit NDC depth per pixel of the last 3-D render, rows top to bottom ([`NO_HIT_DEPTH`] where the ray
    /// hit nothing; slice renders leave it as it was).
    pub fn read_hit_depth(&self, ctx: &GpuContext) -> Result<Vec<f32>> {
        let bytes = ctx.read_texture(&self.hit_depth, [self.width, self.height, 1], 4)?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    /// Premultiplied RGBA8, rows top to bottom, `4 · width` bytes per row (the copy's 256-byte row alignment removed).
    pub fn read_back(&self, ctx: &GpuContext) -> Result<Vec<u8>> {
        ctx.read_texture(&self.texture, [self.width, self.height, 1], 4)
    }
}

impl Drop for RenderTarget {
    fn drop(&mut self) {
        if let Some(pool) = self.pool.take() {
            pool.release(self.texture.clone());
            pool.release(self.hit_depth.clone());
        }
    }
}
