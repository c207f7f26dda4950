//! The gradient prefilter (Brunet, Nowak & Gleicher 2006 §3.4): a separable 3-D Gaussian
//! G_σ ∗ v, σ in source voxels, run as three compute dispatches (x, y, z) that each may halve their axis, so the
//! result can be stored at half resolution (the filtered volume is band-limited). A fourth dispatch takes its
//! gradient per texel, which the ray caster reads through the warp for shading ([`crate::settings::ShadingMode`]):
//! ∇(v∘u)(x) = J_u(x)ᵀ ∇v(u(x)), one hardware-filtered lookup of the gradient ([`GpuPrefiltered`]).
//!
//! Output texel j along an axis lies at source index c_j = (j + ½)·n_src/n_dst − ½ (both textures cover the same
//! \[0,1\]³ box of voxel edges, so the ray caster samples them with the same `tex_from_lps`) and holds
//! Σᵢ wᵢ·v[clamp(i)] / Σᵢ wᵢ with wᵢ = exp(−(i − c_j)²/(2σ²)), i ∈ [⌊c_j⌋ − r, ⌈c_j⌉ + r], r = ⌈2.5σ⌉
//! ([`PrefilterSettings::radius_vox`]), clamp-to-edge. Values are the volume's normalised texels (the affine value
//! mapping commutes with a filter whose weights sum to 1).
//!
//! **Format.** Every pass writes an `R32Float` write-only storage texture, a 2-D *array* with one layer per z
//! (wgpu's GL backend binds a 3-D storage texture as a single layer: wgpu-hal 30 `ImageBinding` has layered = false
//! for `D3`, so writes to z > 0 are lost; an array view is bound layered on every backend): `R32Float` is storage-capable in the WebGPU
//! core format table and reported so (`get_texture_format_features`, `STORAGE_BINDING`) by lavapipe and by GL, where
//! `R16Float` and `R8Unorm` are not (research/stack.md §2). [`GpuContext::headless_requesting`] records the adapter's answer
//! in [`GpuContext::r32float_storage`] and [`PrefilterPass::new`] checks it. `R32Float` is not filterable on GL, so the
//! ray caster filters the prefiltered copy by hand (8 `textureLoad`s), on every device alike.
//!
//! **Gradient.** `cs_gradient` takes central differences of the filtered copy, clamp-to-edge, in normalised texel
//! units per unit of texture coordinate: g_a\[i\] = (v\[min(i + e_a, n − 1)\] − v\[max(i − e_a, 0)\])·n_a/2. It
//! writes them as `Rgba16Float` texels (x, y, z, 0) into a storage buffer in the copy layout of a z-slab, copied
//! into a 3-D texture ([`GRADIENT_FORMAT`], filterable on every device, 8 bytes a texel: twice the `R32Float` copy,
//! which is dropped once the gradient is made). The ray caster samples it with the hardware filter: one lookup where
//! central differences of the copy through the warp took six lookups of eight loads each.
//!
//! Types: [`PrefilterPass`] (long-lived pipeline), [`GpuPrefiltered`] (the gradient texture), [`cpu_prefilter`] and
//! [`PrefilteredTexels::gradients`] (the CPU reference, the oracle of `tests/prefilter.rs`).

use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;

use crate::compute::{self, binding, uniform};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, layout};
use crate::volume::{GpuVolume, PreparedVolume};

/// `shaders/prefilter.wgsl`: `cs_gaussian_from_volume` (x) and `cs_gaussian_from_layers` (y, z), one axis of the
/// separable Gaussian each, and `cs_gradient`.
pub const SHADER: ShaderSource = ShaderSource {
    name: "prefilter",
    path: "shaders/prefilter.wgsl",
    // Followed by the f16 conversions it shares with another pass (appended: line numbers stay those of the file).
    source: concat!(include_str!("../../../shaders/prefilter.wgsl"), include_str!("../../../shaders/f16.wgsl")),
    entry_points: &[(FROM_VOLUME, Stage::Compute), (FROM_LAYERS, Stage::Compute), (GRADIENT, Stage::Compute)],
};
/// The entry point of the x pass, which reads the volume's 3-D texture.
const FROM_VOLUME: &str = "cs_gaussian_from_volume";
/// The entry point of the y and z passes, which read the previous pass's 2-D array.
const FROM_LAYERS: &str = "cs_gaussian_from_layers";
/// The entry point of the gradient pass.
const GRADIENT: &str = "cs_gradient";

pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "p");
/// The x pass's source: the volume.
pub const SLOT_SOURCE_VOLUME: BindSlot = BindSlot::new(0, 1, "src_volume");
pub const SLOT_OUTPUT: BindSlot = BindSlot::new(0, 2, "dst");
/// The y and z passes' source: the previous pass's output.
pub const SLOT_SOURCE_LAYERS: BindSlot = BindSlot::new(0, 3, "src_layers");
/// The gradient pass's uniforms, source (the z pass's output) and output buffer.
pub const SLOT_GRADIENT_UNIFORMS: BindSlot = BindSlot::new(0, 4, "g");
pub const SLOT_FILTERED: BindSlot = BindSlot::new(0, 5, "filtered");
pub const SLOT_GRADIENT_OUT: BindSlot = BindSlot::new(0, 6, "gradient_out");

pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "prefilter",
    shader: SHADER,
    uniform_structs: &[
        layout!(PrefilterUniforms { axis, radius_vox, sigma_vox, dst_dims }),
        layout!(GradientUniforms { dims, first_z, row_words, slab_depth }),
    ],
    slots: &[
        SLOT_UNIFORMS,
        SLOT_SOURCE_VOLUME,
        SLOT_OUTPUT,
        SLOT_SOURCE_LAYERS,
        SLOT_GRADIENT_UNIFORMS,
        SLOT_FILTERED,
        SLOT_GRADIENT_OUT,
    ],
    constants: &[],
};

/// The prefilter's output format (see the module docs).
pub const PREFILTER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// The gradient texture's format (see the module docs).
pub const GRADIENT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Bytes of one gradient texel.
const GRADIENT_TEXEL_BYTES: u32 = 8;
/// The most bytes one gradient slab's buffer holds (within the device's storage-binding and buffer limits).
const GRADIENT_SLAB_BYTES: u64 = 64 << 20;
/// `@workgroup_size` of the prefilter's entry points.
const WORKGROUP: u32 = 4;

/// One axis pass's uniforms: `PrefilterUniforms` in shaders/prefilter.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PrefilterUniforms {
    pub axis: u32,
    pub radius_vox: u32,
    pub sigma_vox: f32,
    _pad0: u32,
    /// The output texture's dims (`textureDimensions` of a 3-D storage texture reads 0 on wgpu's GL backend).
    pub dst_dims: [u32; 3],
    _pad1: u32,
}
const _: () = assert!(std::mem::size_of::<PrefilterUniforms>() == 32);

/// One slab of the gradient pass: `GradientUniforms` in shaders/prefilter.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct GradientUniforms {
    /// The filtered copy's dims.
    pub dims: [u32; 3],
    pub first_z: u32,
    /// u32 words per row of the copy layout.
    pub row_words: u32,
    pub slab_depth: u32,
    _pad0: u32,
    _pad1: u32,
}
const _: () = assert!(std::mem::size_of::<GradientUniforms>() == 32);

/// Gaussian width and output resolution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrefilterSettings {
    /// Standard deviation in source voxels (clamped to ≥ 0.25).
    pub sigma_vox: f32,
    /// Halve each axis (rounding up): an eighth of the texels. Use σ ≥ 1 then, so the result is band-limited.
    pub half_resolution: bool,
}

impl Default for PrefilterSettings {
    fn default() -> Self {
        Self { sigma_vox: 1.0, half_resolution: false }
    }
}

impl PrefilterSettings {
    #[must_use]
    pub fn sigma(self) -> f32 {
        self.sigma_vox.max(0.25)
    }

    /// Taps on each side beyond the two nearest source voxels: ⌈2.5σ⌉.
    #[must_use]
    pub fn radius_vox(self) -> u32 {
        (2.5 * self.sigma()).ceil() as u32
    }

    /// The output dims for source dims `dims`.
    #[must_use]
    pub fn output_dims(self, dims: [u32; 3]) -> [u32; 3] {
        if self.half_resolution { dims.map(|d| d.div_ceil(2)) } else { dims }
    }

    fn uniforms(self, axis: u32, dst_dims: [u32; 3]) -> PrefilterUniforms {
        PrefilterUniforms { axis, radius_vox: self.radius_vox(), sigma_vox: self.sigma(), _pad0: 0, dst_dims, _pad1: 0 }
    }
}

/// A prefiltered volume on the CPU: normalised texels, x fastest, and their gradient as the GPU stores it.
#[derive(Clone, Debug, PartialEq)]
pub struct PrefilteredTexels {
    pub dims: [u32; 3],
    pub texels: Vec<f32>,
    /// [`Self::gradients`] of the texels, made once: what the ray caster's gradient texture holds.
    pub gradients: Vec<[f32; 4]>,
}

impl PrefilteredTexels {
    /// Filtered texels `texels` (x fastest) of a `dims` grid, and their gradients.
    #[must_use]
    pub fn new(dims: [u32; 3], texels: Vec<f32>) -> Self {
        let gradients = Self::gradients(dims, &texels);
        Self { dims, texels, gradients }
    }

    /// [`cpu_prefilter`] of `volume`'s normalised texels.
    #[must_use]
    pub fn from_volume(volume: &PreparedVolume, settings: PrefilterSettings) -> Self {
        cpu_prefilter(volume.info.dims, |i| volume.texels.normalised(i), settings)
    }

    /// The gradient pass of the shader (module docs): per texel (g_x, g_y, g_z, 0) by central differences,
    /// clamp-to-edge, in normalised texel units per unit of texture coordinate, each rounded to f16 as the texture
    /// stores it. On rayon's pool, one z-plane a task.
    #[must_use]
    pub fn gradients(dims: [u32; 3], texels: &[f32]) -> Vec<[f32; 4]> {
        let [nx, ny, nz] = dims.map(|d| d as usize);
        let at = |x: usize, y: usize, z: usize| texels[x + nx * (y + ny * z)];
        let f16 = |v: f32| half::f16::from_f32(v).to_f32();
        let mut out = vec![[0.0f32; 4]; nx * ny * nz];
        out.par_chunks_mut((nx * ny).max(1)).enumerate().for_each(|(z, plane)| {
            for y in 0..ny {
                for x in 0..nx {
                    let i = [x, y, z];
                    let n = [nx, ny, nz];
                    let mut g = [0.0f32; 4];
                    for a in 0..3 {
                        let (mut hi, mut lo) = (i, i);
                        hi[a] = (i[a] + 1).min(n[a] - 1);
                        lo[a] = i[a].saturating_sub(1);
                        g[a] = f16((at(hi[0], hi[1], hi[2]) - at(lo[0], lo[1], lo[2])) * (0.5 * n[a] as f32));
                    }
                    plane[x + nx * y] = g;
                }
            }
        });
        out
    }
}

/// One axis pass of the shader, in f32: `src` has dims `src_dims`, the result `dst_dims` (differing only on `axis`).
fn cpu_axis(src: &[f32], src_dims: [u32; 3], axis: usize, dst_dims: [u32; 3], s: PrefilterSettings) -> Vec<f32> {
    let (n_src, n_dst) = (src_dims[axis], dst_dims[axis]);
    let radius = s.radius_vox() as i32;
    let inv_two_var = 0.5 / (s.sigma() * s.sigma());
    let last = n_src as i32 - 1;
    // The weights depend only on the output index along the axis: (first source index, weights) per j.
    let taps: Vec<(i32, Vec<f32>)> = (0..n_dst)
        .map(|j| {
            let c = (j as f32 + 0.5) * n_src as f32 / n_dst as f32 - 0.5;
            let (lo, hi) = (c.floor() as i32 - radius, c.ceil() as i32 + radius);
            (lo, (lo..=hi).map(|i| (-(i as f32 - c) * (i as f32 - c) * inv_two_var).exp()).collect())
        })
        .collect();
    let (sx, sy) = (src_dims[0] as usize, src_dims[1] as usize);
    let plane = dst_dims[0] as usize * dst_dims[1] as usize;
    let mut out = vec![0.0f32; plane * dst_dims[2] as usize];
    // One output z-plane per task; each voxel's sum is the same sequence of operations as on one thread.
    out.par_chunks_mut(plane.max(1)).enumerate().for_each(|(z, out_plane)| {
        for y in 0..dst_dims[1] {
            for x in 0..dst_dims[0] {
                let mut q = [x as i32, y as i32, z as i32];
                let (lo, weights) = &taps[q[axis] as usize];
                let (mut sum, mut weight_sum) = (0.0f32, 0.0f32);
                for (k, &w) in weights.iter().enumerate() {
                    q[axis] = (lo + k as i32).clamp(0, last);
                    sum += w * src[q[0] as usize + sx * (q[1] as usize + sy * q[2] as usize)];
                    weight_sum += w;
                }
                out_plane[x as usize + dst_dims[0] as usize * y as usize] = sum / weight_sum;
            }
        }
    });
    out
}

/// The CPU reference of [`PrefilterPass::run`]: the x, y and z passes of the shader, in f32, in the same order, on
/// rayon's pool. Also what a CPU driver's window uses instead of the pass (faster there than the shader).
#[must_use]
pub fn cpu_prefilter(dims: [u32; 3], texel: impl Fn(usize) -> f32, settings: PrefilterSettings) -> PrefilteredTexels {
    let count: usize = dims.iter().map(|&d| d as usize).product();
    let mut data: Vec<f32> = (0..count).map(texel).collect();
    let out_dims = settings.output_dims(dims);
    let mut cur = dims;
    for axis in 0..3 {
        let mut next = cur;
        next[axis] = out_dims[axis];
        data = cpu_axis(&data, cur, axis, next, settings);
        cur = next;
    }
    PrefilteredTexels::new(out_dims, data)
}

/// The gradient of a volume's prefiltered copy on the GPU: a [`GRADIENT_FORMAT`] 3-D texture the ray caster samples
/// with the hardware filter (module docs).
#[derive(Debug)]
pub struct GpuPrefiltered {
    pub dims: [u32; 3],
    pub settings: PrefilterSettings,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
}

/// An `R32Float` 2-D array texture of `dims[2]` layers, and its `D2Array` view.
fn r32_layers(
    ctx: &GpuContext,
    label: &str,
    dims: [u32; 3],
    usage: wgpu::TextureUsages,
) -> (wgpu::Texture, wgpu::TextureView) {
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: dims[2] },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: PREFILTER_FORMAT,
        usage,
        view_formats: &[],
    });
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    (texture, view)
}

/// A [`GRADIENT_FORMAT`] 3-D texture of `dims`, and its view.
fn gradient_texture(ctx: &GpuContext, label: &str, dims: [u32; 3]) -> (wgpu::Texture, wgpu::TextureView) {
    let usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::COPY_SRC;
    let texture = ctx.texture_3d(label, dims, GRADIENT_FORMAT, usage);
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    (texture, view)
}

/// The bytes of one row of `width` gradient texels in a copy layout (padded to the copy alignment).
fn gradient_row_bytes(width: u32) -> u32 {
    (GRADIENT_TEXEL_BYTES * width).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
}

impl GpuPrefiltered {
    /// Uploads the gradient of prefiltered texels computed elsewhere (the CPU reference, which a CPU driver's window
    /// uses, or a resampled copy in tests); `settings` only records how they were made.
    pub fn upload(ctx: &GpuContext, texels: &PrefilteredTexels, settings: PrefilterSettings) -> Result<Self> {
        let dims = texels.dims;
        let count: usize = dims.iter().map(|&d| d as usize).product();
        if dims.contains(&0) || texels.gradients.len() != count {
            return Err(GpuError::InvalidInput(format!(
                "prefiltered gradients: dims {dims:?} need {count} texels, got {}",
                texels.gradients.len()
            )));
        }
        if dims.iter().any(|&d| d > ctx.limits.max_texture_dimension_3d) {
            return Err(GpuError::Unsupported(format!(
                "a {dims:?} gradient texture; the device allows {} texels a side",
                ctx.limits.max_texture_dimension_3d
            )));
        }
        let (texture, view) = gradient_texture(ctx, "prefiltered gradient (uploaded)", dims);
        let bytes: Vec<u8> = texels
            .gradients
            .iter()
            .flat_map(|g| g.map(|c| half::f16::from_f32(c).to_bits().to_le_bytes()))
            .flatten()
            .collect();
        ctx.queue.write_texture(
            texture.as_image_copy(),
            &bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(GRADIENT_TEXEL_BYTES * dims[0]),
                rows_per_image: Some(dims[1]),
            },
            wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: dims[2] },
        );
        Ok(Self { dims, settings, texture, view })
    }

    /// A 1×1×1 zero texture, bound where a volume has no prefiltered copy (a uniform flag skips it).
    #[must_use]
    pub(crate) fn placeholder(ctx: &GpuContext) -> wgpu::TextureView {
        let (texture, view) = gradient_texture(ctx, "prefiltered gradient placeholder", [1, 1, 1]);
        ctx.queue.write_texture(
            texture.as_image_copy(),
            &[0u8; GRADIENT_TEXEL_BYTES as usize],
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(GRADIENT_TEXEL_BYTES),
                rows_per_image: Some(1),
            },
            wgpu::Extent3d { width: 1, height: 1, depth_or_array_layers: 1 },
        );
        view
    }

    /// The gradient texels (x, y, z, 0), x fastest (for tests).
    pub fn read_back(&self, ctx: &GpuContext) -> Result<Vec<[f32; 4]>> {
        let bytes = ctx.read_texture(&self.texture, self.dims, GRADIENT_TEXEL_BYTES)?;
        Ok(bytes
            .chunks_exact(8)
            .map(|t| std::array::from_fn(|c| half::f16::from_le_bytes([t[2 * c], t[2 * c + 1]]).to_f32()))
            .collect())
    }
}

/// The long-lived part of the prefilter: the compute pipeline and its bind group layout.
#[derive(Debug)]
pub struct PrefilterPass {
    /// x pass (reads the volume's 3-D texture) and y/z passes (read the previous 2-D array).
    from_volume: (wgpu::ComputePipeline, wgpu::BindGroupLayout),
    from_layers: (wgpu::ComputePipeline, wgpu::BindGroupLayout),
    /// The gradient pass (reads the z pass's 2-D array, writes a buffer).
    gradient: (wgpu::ComputePipeline, wgpu::BindGroupLayout),
}

impl PrefilterPass {
    /// Storage textures per compute stage and invocations per workgroup the pass needs.
    pub const STORAGE_TEXTURES: u32 = 1;
    pub const INVOCATIONS: u32 = WORKGROUP * WORKGROUP * WORKGROUP;

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        if !ctx.r32float_storage
            || l.max_texture_array_layers < 2
            || l.max_storage_textures_per_shader_stage < Self::STORAGE_TEXTURES
            || l.max_compute_invocations_per_workgroup < Self::INVOCATIONS
            || l.max_compute_workgroup_size_z < WORKGROUP
        {
            return Err(GpuError::Unsupported(format!(
                "the prefilter needs compute with {} R32Float storage texture(s) and {} invocations per workgroup \
                 (R32Float storage: {}; limits: {} storage textures, {} invocations)",
                Self::STORAGE_TEXTURES,
                Self::INVOCATIONS,
                ctx.r32float_storage,
                l.max_storage_textures_per_shader_stage,
                l.max_compute_invocations_per_workgroup
            )));
        }
        let device = &ctx.device;
        let module = SHADER.create_module(device);
        let make = |entry_point: &str, source: wgpu::TextureViewDimension, source_slot: BindSlot| {
            let output = wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format: PREFILTER_FORMAT,
                view_dimension: wgpu::TextureViewDimension::D2Array,
            };
            let layout = compute::layout(
                device,
                entry_point,
                &[
                    binding(SLOT_UNIFORMS, uniform::<PrefilterUniforms>()),
                    binding(source_slot, compute::texture(source)),
                    binding(SLOT_OUTPUT, output),
                ],
            );
            (compute::pipeline(device, entry_point, &module, Some(entry_point), &[&layout]), layout)
        };
        let from_volume = make(FROM_VOLUME, wgpu::TextureViewDimension::D3, SLOT_SOURCE_VOLUME);
        let from_layers = make(FROM_LAYERS, wgpu::TextureViewDimension::D2Array, SLOT_SOURCE_LAYERS);
        let gradient_layout = compute::layout(
            device,
            GRADIENT,
            &[
                binding(SLOT_GRADIENT_UNIFORMS, uniform::<GradientUniforms>()),
                binding(SLOT_FILTERED, compute::texture(wgpu::TextureViewDimension::D2Array)),
                binding(SLOT_GRADIENT_OUT, compute::storage(false, None)),
            ],
        );
        let gradient =
            (compute::pipeline(device, GRADIENT, &module, Some(GRADIENT), &[&gradient_layout]), gradient_layout);
        ctx.check_errors()?;
        Ok(Self { from_volume, from_layers, gradient })
    }

    /// Records the three axis passes that filter `volume` and the gradient pass into a new gradient texture, which
    /// is returned; the caller submits `encoder`. Fails when the volume has more slices than the device allows array
    /// layers. Intermediate textures and buffers are dropped once the commands have run.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        volume: &GpuVolume,
        settings: PrefilterSettings,
    ) -> Result<GpuPrefiltered> {
        let src_dims = volume.info.dims;
        if src_dims[2] > ctx.limits.max_texture_array_layers {
            return Err(GpuError::Unsupported(format!(
                "the prefilter stores z as array layers: {} slices, the device allows {}",
                src_dims[2], ctx.limits.max_texture_array_layers
            )));
        }
        let out_dims = settings.output_dims(src_dims);
        let storage = wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING;
        let mut cur_dims = src_dims;
        let mut cur_view = volume.view.clone();
        for axis in 0..3u32 {
            let mut next_dims = cur_dims;
            next_dims[axis as usize] = out_dims[axis as usize];
            let (_texture, view) = r32_layers(ctx, "prefilter pass", next_dims, storage);
            let buffer = ctx.uniform_buffer("prefilter uniforms", &settings.uniforms(axis, next_dims));
            let ((pipeline, layout), source_slot) = if axis == 0 {
                (&self.from_volume, SLOT_SOURCE_VOLUME)
            } else {
                (&self.from_layers, SLOT_SOURCE_LAYERS)
            };
            let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("prefilter"),
                layout,
                entries: &[
                    SLOT_UNIFORMS.entry(buffer.as_entire_binding()),
                    source_slot.entry(wgpu::BindingResource::TextureView(&cur_view)),
                    SLOT_OUTPUT.entry(wgpu::BindingResource::TextureView(&view)),
                ],
            });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("prefilter"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.dispatch_workgroups(
                    next_dims[0].div_ceil(WORKGROUP),
                    next_dims[1].div_ceil(WORKGROUP),
                    next_dims[2].div_ceil(WORKGROUP),
                );
            }
            cur_dims = next_dims;
            cur_view = view;
        }
        let (texture, view) = self.encode_gradient(ctx, encoder, &cur_view, out_dims)?;
        Ok(GpuPrefiltered { dims: out_dims, settings, texture, view })
    }

    /// Records the gradient pass over the filtered copy `filtered` (`dims`), slab by slab into one buffer, each slab
    /// copied into the returned gradient texture.
    fn encode_gradient(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        filtered: &wgpu::TextureView,
        dims: [u32; 3],
    ) -> Result<(wgpu::Texture, wgpu::TextureView)> {
        if dims.iter().any(|&d| d > ctx.limits.max_texture_dimension_3d) {
            return Err(GpuError::Unsupported(format!(
                "a {dims:?} gradient texture; the device allows {} texels a side",
                ctx.limits.max_texture_dimension_3d
            )));
        }
        let row_bytes = gradient_row_bytes(dims[0]);
        let plane_bytes = u64::from(row_bytes) * u64::from(dims[1]);
        let budget =
            GRADIENT_SLAB_BYTES.min(ctx.limits.max_storage_buffer_binding_size).min(ctx.limits.max_buffer_size);
        if plane_bytes > budget {
            return Err(GpuError::Unsupported(format!(
                "one {}×{} plane of the gradient takes {plane_bytes} bytes; the device binds at most {budget}",
                dims[0], dims[1]
            )));
        }
        let slab_depth = u32::try_from(budget / plane_bytes).unwrap_or(u32::MAX).min(dims[2]).max(1);
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let buffer = ctx.buffer("prefilter gradient slab", plane_bytes * u64::from(slab_depth), usage);
        let (texture, view) = gradient_texture(ctx, "prefiltered gradient", dims);
        let (pipeline, layout) = &self.gradient;
        let mut first_z = 0;
        while first_z < dims[2] {
            let depth = slab_depth.min(dims[2] - first_z);
            let uniforms =
                GradientUniforms { dims, first_z, row_words: row_bytes / 4, slab_depth: depth, _pad0: 0, _pad1: 0 };
            let uniform_buffer = ctx.uniform_buffer("prefilter gradient uniforms", &uniforms);
            let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("prefilter gradient"),
                layout,
                entries: &[
                    SLOT_GRADIENT_UNIFORMS.entry(uniform_buffer.as_entire_binding()),
                    SLOT_FILTERED.entry(wgpu::BindingResource::TextureView(filtered)),
                    SLOT_GRADIENT_OUT.entry(buffer.as_entire_binding()),
                ],
            });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("prefilter gradient"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.dispatch_workgroups(
                    dims[0].div_ceil(WORKGROUP),
                    dims[1].div_ceil(WORKGROUP),
                    depth.div_ceil(WORKGROUP),
                );
            }
            encoder.copy_buffer_to_texture(
                wgpu::TexelCopyBufferInfo {
                    buffer: &buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row_bytes),
                        rows_per_image: Some(dims[1]),
                    },
                },
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z: first_z },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: depth },
            );
            first_z += depth;
        }
        Ok((texture, view))
    }

    /// Filters `volume` and submits.
    pub fn run(&self, ctx: &GpuContext, volume: &GpuVolume, settings: PrefilterSettings) -> Result<GpuPrefiltered> {
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("prefilter") });
        let out = self.encode(ctx, &mut encoder, volume, settings)?;
        ctx.queue.submit([encoder.finish()]);
        ctx.check_errors()?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constants_and_linear_ramps_are_preserved_in_the_interior() {
        let dims = [9, 8, 7];
        let ramp = |i: usize| (i % 9) as f32 * 0.1 + 0.2;
        for half in [false, true] {
            let s = PrefilterSettings { sigma_vox: 1.0, half_resolution: half };
            let c = cpu_prefilter(dims, |_| 0.5, s);
            assert_eq!(c.dims, s.output_dims(dims));
            assert!(c.texels.iter().all(|v| (v - 0.5).abs() < 1e-6));
            // A ramp along x is reproduced where the taps do not reach the edges: value at c_j.
            let r = cpu_prefilter(dims, ramp, s);
            let n = r.dims[0] as usize;
            let j = n / 2;
            let c_j = (j as f32 + 0.5) * 9.0 / n as f32 - 0.5;
            assert!((r.texels[j] - (c_j * 0.1 + 0.2)).abs() < 1e-5, "half {half}: {} at c {c_j}", r.texels[j]);
        }
    }
}
