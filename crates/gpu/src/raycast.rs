//! The ray caster: one full-screen pass that samples the fixed and the (deformed) moving volume at the same points
//! of ref space (Brunet et al. 2006 §4.3: both volumes share one proxy geometry), classifies each with its transfer
//! function, combines them by a [`BlendMode`] and composites front to back.
//!
//! Per pixel: a ray from the near to the far plane (`ref_from_clip`), clipped to the proxy box (the ref-space box
//! where either volume can appear after its warp, [`LayerParams::box_ref`]); samples at t_k = t_enter + (k + j)·step with j = 0, or a fixed
//! per-pixel hash when jitter is on; at each x_ref, for each visible volume, u(x) = x + disp(ctrl_tex_from_ref · x)
//! (or x), `tex_from_lps · u(x)`, trilinear sample (transparent outside \[0, 1\]³), value → TF; opacity correction
//! α' = 1 − (1 − α)^(step/ref_step) with ref_step one voxel of the finest visible spacing; blend; "over"
//! compositing of premultiplied colour, stopping at α > 0.99. The output is premultiplied RGBA8.
//!
//! **Shading** ([`Shading`], [`ShadingMode`]; Brunet et al. 2006 §3.4, Westermann & Rezk-Salama 2001 §3.3): the
//! gradient at a ref-space sample x is taken by central differences in ref space *through the warp*,
//! gᵢ(x) = \[v_pf(tex(u(x + h·eᵢ))) − v_pf(tex(u(x − h·eᵢ)))\] / 2h, of the layer's prefiltered copy v_pf
//! ([`crate::prefilter`]; the volume itself without one), so it is the gradient of the *deformed* volume and the
//! lighting follows the deformation. h defaults to one voxel of the finest visible spacing. DVR lights every sample
//! with opacity > 0; iso mode takes, per layer, the first sample with value ≥ [`LayerStyle::iso_value`], refines it
//! by bisection, lights it opaque, and blends the two layers' hits once by the [`BlendMode`] (the checkerboard cell
//! is chosen at the nearer hit). Each shading mode has its own pipeline (WGSL override `SHADING`), created on first
//! use, so the unlit pass costs what it did before shading existed.
//!
//! Types: [`RaycastRenderer`] (long-lived: pipeline, layout, samplers) and [`RaycastDrawData`] (one frame: bind
//! group and uniforms over the volumes, control textures and transfer functions). [`RaycastUniforms`] is built by
//! [`RaycastUniforms::new`] from plain [`LayerParams`], which the CPU reference ([`crate::cpu_reference`]) consumes too.

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Mat4};

use crate::camera::{OrbitCamera, Projection};
use crate::control::{ControlInfo, GpuControlTexture};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::pool::{TextureKey, TexturePool};
use crate::prefilter::GpuPrefiltered;
use crate::shaders::{RAYCAST, Stage};
use crate::slice::SlicePlane;
use crate::transfer::{GpuTransferFunctions, Window};
use crate::volume::{GpuVolume, VolumeInfo};

/// `VolumeUniforms.flags`
pub const VOLUME_VISIBLE: u32 = 1;
pub const VOLUME_HAS_WARP: u32 = 2;
pub const VOLUME_MANUAL_FILTER: u32 = 4;
/// A prefiltered copy is bound for this volume (gradients come from it; otherwise from the volume itself).
pub const VOLUME_HAS_PREFILTER: u32 = 8;
/// `RaycastUniforms.flags`
pub const RAYCAST_JITTER: u32 = 1;
/// Early ray termination threshold.
pub const EARLY_EXIT_ALPHA: f32 = 0.99;

/// One volume's uniforms. Keep in sync with `VolumeUniforms` in shaders/raycast.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct VolumeUniforms {
    /// Column-major, as glam and WGSL store matrices.
    pub tex_from_lps: [[f32; 4]; 4],
    pub ctrl_tex_from_ref: [[f32; 4]; 4],
    pub value_offset: f32,
    pub value_scale: f32,
    pub window_low: f32,
    pub window_width: f32,
    pub tf_row: u32,
    pub opacity_scale: f32,
    pub flags: u32,
    /// Iso-surface threshold, value units.
    pub iso_value: f32,
}
const _: () = assert!(std::mem::size_of::<VolumeUniforms>() == 160);

/// The frame's uniforms. Keep in sync with `RaycastUniforms` in shaders/raycast.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RaycastUniforms {
    pub ref_from_clip: [[f32; 4]; 4],
    pub box_min_ref: [f32; 3],
    pub step_mm: f32,
    pub box_max_ref: [f32; 3],
    pub ref_step_mm: f32,
    pub viewport_px: [f32; 2],
    pub blend_mode: u32,
    pub flags: u32,
    pub blend_weight: f32,
    pub checker_cell_mm: f32,
    pub max_steps: u32,
    pub jitter_seed: u32,
    /// [`ShadingMode::code`]. Selects the pipeline, which is specialised on it (WGSL override `SHADING`).
    pub shading_mode: u32,
    /// Iso mode: bisection steps refining the first hit between the last two samples.
    pub bisection_steps: u32,
    /// Central-difference step h (ref mm).
    pub gradient_step_mm: f32,
    pub ambient: f32,
    pub diffuse: f32,
    pub specular: f32,
    pub shininess: f32,
    _pad0: u32,
    pub fixed: VolumeUniforms,
    pub moving: VolumeUniforms,
    /// Slices only (`fs_slice`): ref from framebuffer coordinates, x_ref = ref_from_frag_px · (x, y, 0, 1) with pixel
    /// centres at (px + ½, py + ½) ([`crate::SlicePlane::ref_from_frag_px`]); the identity for 3-D frames.
    pub ref_from_frag_px: [[f32; 4]; 4],
}
const _: () = assert!(std::mem::size_of::<RaycastUniforms>() == 544);

/// How the two classified samples combine (`RaycastUniforms.blend_mode`, `BLEND_*` in the shader).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BlendMode {
    /// (1 − w)·fixed + w·moving.
    Mix {
        moving_weight: f32,
    },
    /// fixed + moving, clamped.
    Additive,
    /// |fixed − moving| in colour, max of the opacities: aligned structures go dark.
    Difference,
    /// A 3-D checkerboard of `cell_mm` cells in ref space; cells with an even index sum show fixed.
    Checkerboard {
        cell_mm: f32,
    },
    /// Fixed luminance in red, moving luminance in green and blue.
    RedCyan,
    FixedOnly,
    MovingOnly,
}

impl BlendMode {
    /// One of each, for tests and menus.
    pub const ALL: [Self; 7] = [
        Self::Mix { moving_weight: 0.5 },
        Self::Additive,
        Self::Difference,
        Self::Checkerboard { cell_mm: 12.0 },
        Self::RedCyan,
        Self::FixedOnly,
        Self::MovingOnly,
    ];

    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::Mix { .. } => 0,
            Self::Additive => 1,
            Self::Difference => 2,
            Self::Checkerboard { .. } => 3,
            Self::RedCyan => 4,
            Self::FixedOnly => 5,
            Self::MovingOnly => 6,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Mix { .. } => "mix",
            Self::Additive => "additive",
            Self::Difference => "difference",
            Self::Checkerboard { .. } => "checkerboard",
            Self::RedCyan => "red-cyan",
            Self::FixedOnly => "fixed-only",
            Self::MovingOnly => "moving-only",
        }
    }
}

/// How samples are lit (`RaycastUniforms.shading_mode`, `SHADING_*` in the shader).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadingMode {
    /// Unlit direct volume rendering: the transfer function's colour as it is.
    None,
    /// Direct volume rendering, each sample with opacity > 0 lit by its gradient.
    Dvr,
    /// Per volume, the first sample whose value ≥ [`LayerStyle::iso_value`], refined by bisection, lit and opaque;
    /// the two volumes' hits are then blended once by the [`BlendMode`].
    Iso,
}

impl ShadingMode {
    pub const ALL: [Self; 3] = [Self::None, Self::Dvr, Self::Iso];

    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Dvr => 1,
            Self::Iso => 2,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Dvr => "dvr",
            Self::Iso => "iso",
        }
    }
}

/// Lighting: a headlight (light = view direction), two-sided.
///
/// For a sample with gradient g and n = g/|g|, l = −ray direction:
/// colour' = clamp(colour·(ambient + diffuse·|n·l|) + specular·|n·l|^shininess, 0, 1) (straight colour; with a
/// headlight the Blinn-Phong half vector is l). The gradient is taken through the warp (see [`crate::raycast`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shading {
    pub mode: ShadingMode,
    pub ambient: f32,
    pub diffuse: f32,
    /// 0 turns specular off.
    pub specular: f32,
    pub shininess: f32,
    /// Central-difference step in ref mm; `None` is one voxel of the finest visible spacing.
    pub gradient_step_mm: Option<f32>,
    /// Iso mode: bisection steps between the last sample below and the first at or above the threshold.
    pub bisection_steps: u32,
}

impl Default for Shading {
    fn default() -> Self {
        Self {
            mode: ShadingMode::None,
            ambient: 0.3,
            diffuse: 0.7,
            specular: 0.2,
            shininess: 24.0,
            gradient_step_mm: None,
            bisection_steps: 6,
        }
    }
}

impl Shading {
    /// The default lighting with `mode`.
    #[must_use]
    pub fn with_mode(mode: ShadingMode) -> Self {
        Self { mode, ..Self::default() }
    }
}

/// Which sample rate a frame uses: the full one when the view is still, a lower one while the user drags (Brunet,
/// Nowak & Gleicher 2006 §6.2: their implementation "adjusts sampling rates to provide faster performance at the
/// expense of image quality"). Opacity is corrected to the step, so the picture keeps its brightness and only gets
/// coarser.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Quality {
    #[default]
    Full,
    Interactive,
}

/// Frame-wide settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub blend: BlendMode,
    /// Samples per voxel of the finest visible spacing (step = spacing / samples_per_voxel).
    pub samples_per_voxel: f32,
    /// The samples per voxel of [`Quality::Interactive`] frames ([`Self::at`]).
    pub interaction_samples_per_voxel: f32,
    /// `Some(seed)`: jitter ray starts by a fixed per-pixel hash of (pixel, seed). `None` for tests and goldens.
    pub jitter_seed: Option<u32>,
    /// Upper bound on samples per ray.
    pub max_steps: u32,
    /// Replaces the automatic proxy box (the union of both layers' [`LayerParams::box_ref`]: where each volume can
    /// appear after its warp).
    pub box_override_ref: Option<(glam::Vec3, glam::Vec3)>,
    pub shading: Shading,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            blend: BlendMode::Mix { moving_weight: 0.5 },
            samples_per_voxel: 1.0,
            interaction_samples_per_voxel: 0.5,
            jitter_seed: None,
            max_steps: 4096,
            box_override_ref: None,
            shading: Shading::default(),
        }
    }
}

impl RenderSettings {
    /// These settings at `quality`: [`Quality::Interactive`] samples at [`Self::interaction_samples_per_voxel`]
    /// (never more finely than the full rate).
    #[must_use]
    pub fn at(&self, quality: Quality) -> Self {
        match quality {
            Quality::Full => *self,
            Quality::Interactive => {
                Self { samples_per_voxel: self.interaction_samples_per_voxel.min(self.samples_per_voxel), ..*self }
            }
        }
    }
}

/// How one volume is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerStyle {
    pub window: Window,
    /// Row in the transfer-function texture.
    pub tf_row: u32,
    /// Multiplies the TF opacity.
    pub opacity_scale: f32,
    pub visible: bool,
    /// Iso-surface threshold in this volume's value units (HU for CT), for [`ShadingMode::Iso`].
    pub iso_value: f32,
}

/// Everything about one volume that goes into the uniforms, without GPU resources.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerParams {
    pub volume: VolumeInfo,
    /// The pull-back into this volume's LPS space; `None` is the identity fast path.
    pub control: Option<ControlInfo>,
    pub style: LayerStyle,
    /// A prefiltered copy is bound: gradients for shading come from it.
    pub has_prefilter: bool,
}

impl LayerParams {
    fn uniforms(&self, tf_rows: u32) -> VolumeUniforms {
        let mut flags = 0;
        if self.has_prefilter {
            flags |= VOLUME_HAS_PREFILTER;
        }
        if self.style.visible {
            flags |= VOLUME_VISIBLE;
        }
        if self.control.is_some() {
            flags |= VOLUME_HAS_WARP;
        }
        if self.volume.manual_filter {
            flags |= VOLUME_MANUAL_FILTER;
        }
        VolumeUniforms {
            tex_from_lps: self.volume.tex_from_lps.to_cols_array_2d(),
            ctrl_tex_from_ref: self.control.map_or(Mat4::IDENTITY, |c| c.ctrl_tex_from_ref).to_cols_array_2d(),
            value_offset: self.volume.value_offset,
            value_scale: self.volume.value_scale,
            window_low: self.style.window.low(),
            window_width: self.style.window.width,
            tf_row: self.style.tf_row.min(tf_rows.max(1) - 1),
            opacity_scale: self.style.opacity_scale,
            flags,
            iso_value: self.style.iso_value,
        }
    }

    /// A ref-space box that contains every point where this layer can have content: the volume is non-transparent
    /// only where u(x) = x + d(x) lies in its LPS box [lo, hi], and d(x) lies componentwise in
    /// [`ControlInfo::disp_min_mm`, `ControlInfo::disp_max_mm`] everywhere (trilinear, clamp-to-edge), so
    /// x ∈ [lo − d_max, hi − d_min]. Exact for the identity and for a constant displacement; conservative otherwise.
    #[must_use]
    pub fn box_ref(&self) -> (DVec3, DVec3) {
        let (lo, hi) = (self.volume.box_min_lps, self.volume.box_max_lps);
        match self.control {
            Some(c) => (lo - c.disp_max_mm.as_dvec3(), hi - c.disp_min_mm.as_dvec3()),
            None => (lo, hi),
        }
    }
}

impl RaycastUniforms {
    /// The uniforms of one frame `size_px` = (width, height) big.
    #[must_use]
    pub fn new(
        camera: &OrbitCamera,
        settings: &RenderSettings,
        size_px: (u32, u32),
        fixed: &LayerParams,
        moving: &LayerParams,
        tf_rows: u32,
    ) -> Self {
        let (w, h) = (size_px.0.max(1), size_px.1.max(1));
        let (box_min, box_max) = settings.box_override_ref.unwrap_or_else(|| {
            let (a, b) = (fixed.box_ref(), moving.box_ref());
            (a.0.min(b.0).as_vec3(), a.1.max(b.1).as_vec3())
        });
        let visible: Vec<&LayerParams> = match settings.blend {
            BlendMode::FixedOnly => vec![fixed],
            BlendMode::MovingOnly => vec![moving],
            _ => vec![fixed, moving],
        };
        let finest_mm =
            visible.iter().filter(|l| l.style.visible).flat_map(|l| l.volume.spacing_mm).fold(f64::INFINITY, f64::min);
        let finest_mm = if finest_mm.is_finite() { finest_mm as f32 } else { 1.0 };
        let (blend_weight, checker_cell_mm) = match settings.blend {
            BlendMode::Mix { moving_weight } => (moving_weight, 1.0),
            BlendMode::Checkerboard { cell_mm } => (0.5, cell_mm.max(1e-3)),
            _ => (0.5, 1.0),
        };
        Self {
            ref_from_clip: camera.ref_from_clip(w as f32 / h as f32).to_cols_array_2d(),
            box_min_ref: box_min.to_array(),
            step_mm: finest_mm / settings.samples_per_voxel.max(1e-3),
            box_max_ref: box_max.to_array(),
            ref_step_mm: finest_mm,
            viewport_px: [w as f32, h as f32],
            blend_mode: settings.blend.code(),
            flags: if settings.jitter_seed.is_some() { RAYCAST_JITTER } else { 0 },
            blend_weight,
            checker_cell_mm,
            max_steps: settings.max_steps,
            jitter_seed: settings.jitter_seed.unwrap_or(0),
            shading_mode: settings.shading.mode.code(),
            bisection_steps: settings.shading.bisection_steps,
            gradient_step_mm: settings.shading.gradient_step_mm.unwrap_or(finest_mm).max(1e-4),
            ambient: settings.shading.ambient,
            diffuse: settings.shading.diffuse,
            specular: settings.shading.specular,
            shininess: settings.shading.shininess.max(0.0),
            _pad0: 0,
            fixed: fixed.uniforms(tf_rows),
            moving: moving.uniforms(tf_rows),
            ref_from_frag_px: Mat4::IDENTITY.to_cols_array_2d(),
        }
    }

    /// The uniforms of a slice ([`crate::slice`]) through `plane`, drawn with [`RaycastRenderer::render_slice`]:
    /// the viewport is `plane.size`; of `settings` only the blend mode matters (slices are unlit, one sample per
    /// pixel).
    #[must_use]
    pub fn for_slice(
        plane: &SlicePlane,
        settings: &RenderSettings,
        fixed: &LayerParams,
        moving: &LayerParams,
        tf_rows: u32,
    ) -> Self {
        let (w, h) = plane.size;
        let centre = DVec3::from_array(plane.ref_from_pixel(f64::from(w) / 2.0, f64::from(h) / 2.0)).as_vec3();
        let camera = OrbitCamera::fit(centre - glam::Vec3::ONE, centre + glam::Vec3::ONE, Projection::Orthographic);
        let settings = RenderSettings { shading: Shading::default(), jitter_seed: None, ..*settings };
        Self {
            ref_from_frag_px: plane.ref_from_frag_px().to_cols_array_2d(),
            ..Self::new(&camera, &settings, (w, h), fixed, moving, tf_rows)
        }
    }
}

/// The stages that see the frame's bind group: the ray caster's fragment stage and the picking pass
/// ([`crate::pick`]), which marches the same samples in a compute shader.
const FRAME_STAGES: wgpu::ShaderStages = wgpu::ShaderStages::FRAGMENT.union(wgpu::ShaderStages::COMPUTE);

/// The long-lived part of the ray caster: pipeline, bind group layout, samplers and the placeholder control texture.
#[derive(Debug)]
pub struct RaycastRenderer {
    device: wgpu::Device,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    /// One per [`ShadingMode`], created on first use ([`Self::pipeline`]).
    pipelines: [std::sync::OnceLock<wgpu::RenderPipeline>; 3],
    /// The slice pipeline (`fs_slice`), created on first use.
    slice_pipeline: std::sync::OnceLock<wgpu::RenderPipeline>,
    layout: wgpu::BindGroupLayout,
    volume_sampler: wgpu::Sampler,
    linear_sampler: wgpu::Sampler,
    placeholder_control: wgpu::TextureView,
    placeholder_prefiltered: wgpu::TextureView,
    volumes_filterable: bool,
}

impl RaycastRenderer {
    /// The output format.
    pub const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
    /// The format of the first-hit depth, the ray caster's second output ([`RenderTarget::hit_depth`]): the bits of
    /// an f32 NDC depth, because R32Float is not colour-renderable on GLES (wgpu's GL backend) and R32Uint is.
    pub const HIT_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
    /// Requested when the adapter has them; without them the pass falls back (see [`crate::volume`] and
    /// [`crate::control`]).
    pub const OPTIONAL_FEATURES: wgpu::Features =
        wgpu::Features::TEXTURE_FORMAT_16BIT_NORM.union(wgpu::Features::FLOAT32_FILTERABLE);
    /// Sampled textures and samplers per fragment stage this pass binds.
    pub const SAMPLED_TEXTURES: u32 = 7;
    pub const SAMPLERS: u32 = 2;
    /// The slice fragment entry point in `shaders/raycast.wgsl`.
    pub const SLICE_ENTRY_POINT: &'static str = "fs_slice";

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        if l.max_sampled_textures_per_shader_stage < Self::SAMPLED_TEXTURES
            || l.max_samplers_per_shader_stage < Self::SAMPLERS
        {
            return Err(GpuError::Unsupported(format!(
                "the ray caster binds {} textures and {} samplers per stage; the device allows {} and {}",
                Self::SAMPLED_TEXTURES,
                Self::SAMPLERS,
                l.max_sampled_textures_per_shader_stage,
                l.max_samplers_per_shader_stage
            )));
        }
        let device = &ctx.device;
        let volumes_filterable = ctx.capabilities.volumes_filterable();
        let tex3d = |binding, filterable| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: FRAME_STAGES,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable },
                view_dimension: wgpu::TextureViewDimension::D3,
                multisampled: false,
            },
            count: None,
        };
        // Prefiltered copies: R32Float 2-D arrays (layer = z), read with textureLoad.
        let layers = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: FRAME_STAGES,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        };
        let sampler = |binding, kind| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: FRAME_STAGES,
            ty: wgpu::BindingType::Sampler(kind),
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("raycast"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: FRAME_STAGES,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<RaycastUniforms>() as u64),
                    },
                    count: None,
                },
                tex3d(1, volumes_filterable),
                tex3d(2, volumes_filterable),
                tex3d(3, true),
                tex3d(4, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: FRAME_STAGES,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                sampler(
                    6,
                    if volumes_filterable {
                        wgpu::SamplerBindingType::Filtering
                    } else {
                        wgpu::SamplerBindingType::NonFiltering
                    },
                ),
                sampler(7, wgpu::SamplerBindingType::Filtering),
                layers(8),
                layers(9),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("raycast"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = RAYCAST.create_module(device);
        let filter = if volumes_filterable { wgpu::FilterMode::Linear } else { wgpu::FilterMode::Nearest };
        let clamp = wgpu::AddressMode::ClampToEdge;
        let volume_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("volume"),
            address_mode_u: clamp,
            address_mode_v: clamp,
            address_mode_w: clamp,
            mag_filter: filter,
            min_filter: filter,
            ..Default::default()
        });
        let linear_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("linear"),
            address_mode_u: clamp,
            address_mode_v: clamp,
            address_mode_w: clamp,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let placeholder_control = GpuControlTexture::placeholder(ctx);
        let placeholder_prefiltered = GpuPrefiltered::placeholder(ctx);
        ctx.check_errors()?;
        let renderer = Self {
            device: device.clone(),
            module,
            pipeline_layout,
            pipelines: Default::default(),
            slice_pipeline: std::sync::OnceLock::new(),
            layout,
            volume_sampler,
            linear_sampler,
            placeholder_control,
            placeholder_prefiltered,
            volumes_filterable,
        };
        // The unlit pipeline now, so that shader errors surface here; the lit ones on first use.
        renderer.pipeline(ShadingMode::None.code());
        ctx.check_errors()?;
        Ok(renderer)
    }

    /// The pipeline specialised for shading mode `code` (the WGSL override `SHADING`), created on first use: each
    /// mode compiles only its own code, which keeps the unlit pass as small and fast as before shading existed.
    fn pipeline(&self, code: u32) -> &wgpu::RenderPipeline {
        let code = code.min(ShadingMode::Iso.code());
        self.pipelines[code as usize].get_or_init(|| {
            let fragment = RAYCAST.entry_point(Stage::Fragment);
            self.create_pipeline("raycast", fragment, &[("SHADING", f64::from(code))], true)
        })
    }

    /// The slice pipeline: the same module, layout and vertex stage, fragment entry point [`Self::SLICE_ENTRY_POINT`].
    fn slice_pipeline(&self) -> &wgpu::RenderPipeline {
        self.slice_pipeline.get_or_init(|| self.create_pipeline("slice", Some(Self::SLICE_ENTRY_POINT), &[], false))
    }

    /// `with_hit_depth`: the fragment stage also writes the first-hit depth (`fs_raycast`; slices do not).
    fn create_pipeline(
        &self,
        label: &str,
        fragment: Option<&str>,
        constants: &[(&str, f64)],
        with_hit_depth: bool,
    ) -> wgpu::RenderPipeline {
        let colour = Some(wgpu::ColorTargetState {
            format: Self::TARGET_FORMAT,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        });
        let hit_depth = Some(wgpu::ColorTargetState {
            format: Self::HIT_DEPTH_FORMAT,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        });
        let targets = [colour, hit_depth];
        let targets = if with_hit_depth { &targets[..] } else { &targets[..1] };
        self.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: Some(&self.pipeline_layout),
            vertex: wgpu::VertexState {
                module: &self.module,
                entry_point: RAYCAST.entry_point(Stage::Vertex),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &self.module,
                entry_point: fragment,
                compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
                targets,
            }),
            multiview_mask: None,
            cache: None,
        })
    }

    /// The layout of a frame's bind group (group 0), shared with the picking pass.
    #[must_use]
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// The `shaders/raycast.wgsl` module, whose `cs_pick` entry point the picking pass uses.
    #[must_use]
    pub fn module(&self) -> &wgpu::ShaderModule {
        &self.module
    }

    /// Creates the pipeline for `mode` now (it is otherwise created by the first draw that needs it).
    pub fn prepare_pipeline(&self, ctx: &GpuContext, mode: ShadingMode) -> Result<()> {
        self.pipeline(mode.code());
        ctx.check_errors()
    }

    /// Records the pass's draw into `pass`, whose colour attachments must be [`Self::TARGET_FORMAT`] and
    /// [`Self::HIT_DEPTH_FORMAT`] ([`RenderTarget::colour_attachments`]).
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, data: &RaycastDrawData) {
        pass.set_pipeline(self.pipeline(data.uniforms.shading_mode));
        pass.set_bind_group(0, &data.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }

    /// Records a slice draw ([`crate::slice`]; `data` built from [`RaycastUniforms::for_slice`]) into `pass`, whose
    /// one colour attachment is [`Self::TARGET_FORMAT`].
    pub fn draw_slice(&self, pass: &mut wgpu::RenderPass<'_>, data: &RaycastDrawData) {
        pass.set_pipeline(self.slice_pipeline());
        pass.set_bind_group(0, &data.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }

    /// Renders the slice `data` ([`RaycastUniforms::for_slice`]) into `target` (the plane's size, cleared to
    /// transparent) and submits.
    pub fn render_slice(&self, ctx: &GpuContext, data: &RaycastDrawData, target: &RenderTarget) -> Result<()> {
        Self::render_with(ctx, target, false, LoadOp::Clear, |pass| self.draw_slice(pass, data))
    }

    /// Renders `data` into `target` (cleared to transparent) and submits.
    pub fn render(&self, ctx: &GpuContext, data: &RaycastDrawData, target: &RenderTarget) -> Result<()> {
        Self::render_with(ctx, target, true, LoadOp::Clear, |pass| self.draw(pass, data))
    }

    /// Renders the rows `rows` of `data`'s frame (a band across the whole width, rows counted from the top) into
    /// `target` and submits, so that a frame too slow for one UI frame (on a CPU driver) is rendered over several.
    /// A band from row 0 clears the whole target first; a later band keeps what earlier bands drew. Every pixel's ray
    /// depends only on the pixel, so bands covering all rows give exactly the image of [`Self::render`].
    pub fn render_rows(
        &self,
        ctx: &GpuContext,
        data: &RaycastDrawData,
        target: &RenderTarget,
        rows: std::ops::Range<u32>,
    ) -> Result<()> {
        let rows = rows.start.min(target.height)..rows.end.min(target.height);
        if rows.is_empty() {
            return Ok(());
        }
        let load = if rows.start == 0 { LoadOp::Clear } else { LoadOp::Keep };
        Self::render_with(ctx, target, true, load, |pass| {
            pass.set_scissor_rect(0, rows.start, target.width, rows.end - rows.start);
            self.draw(pass, data);
        })
    }

    fn render_with(
        ctx: &GpuContext,
        target: &RenderTarget,
        with_hit_depth: bool,
        load: LoadOp,
        record: impl FnOnce(&mut wgpu::RenderPass<'_>),
    ) -> Result<()> {
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("raycast") });
        {
            let mut attachments = target.colour_attachments();
            if load == LoadOp::Keep {
                for a in attachments.iter_mut().flatten() {
                    a.ops.load = wgpu::LoadOp::Load;
                }
            }
            let attachments = if with_hit_depth { &attachments[..] } else { &attachments[..1] };
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("raycast"),
                color_attachments: attachments,
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            record(&mut pass);
        }
        ctx.queue.submit([encoder.finish()]);
        ctx.check_errors()
    }
}

/// What a ray-casting pass does with the target's contents before drawing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LoadOp {
    /// Clear to transparent and no hit.
    Clear,
    /// Keep them (a later band of [`RaycastRenderer::render_rows`]).
    Keep,
}

/// One volume with its optional control texture and prefiltered copy, as bound for a frame.
#[derive(Clone, Copy, Debug)]
pub struct GpuLayer<'a> {
    pub volume: &'a GpuVolume,
    pub control: Option<&'a GpuControlTexture>,
    /// The [`crate::PrefilterPass`] output of `volume`, for shading gradients; without it they come from `volume`.
    pub prefiltered: Option<&'a GpuPrefiltered>,
    pub style: LayerStyle,
}

impl GpuLayer<'_> {
    #[must_use]
    pub fn params(&self) -> LayerParams {
        LayerParams {
            volume: self.volume.info,
            control: self.control.map(|c| c.info),
            style: self.style,
            has_prefilter: self.prefiltered.is_some(),
        }
    }
}

/// What a frame binds: both layers and the transfer-function texture their styles index.
#[derive(Clone, Copy, Debug)]
pub struct GpuFrame<'a> {
    pub fixed: GpuLayer<'a>,
    pub moving: GpuLayer<'a>,
    pub tfs: &'a GpuTransferFunctions,
}

/// One frame's resources: the uniform buffer and the bind group over both layers and the transfer functions.
#[derive(Debug)]
pub struct RaycastDrawData {
    pub uniforms: RaycastUniforms,
    buffer: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl RaycastDrawData {
    /// Uniforms for `camera`/`settings` at `size_px`, bound with the layers' textures.
    #[must_use]
    pub fn new(
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        frame: &GpuFrame<'_>,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        size_px: (u32, u32),
    ) -> Self {
        let (fixed, moving) = (frame.fixed.params(), frame.moving.params());
        let uniforms = RaycastUniforms::new(camera, settings, size_px, &fixed, &moving, frame.tfs.rows);
        Self::with_uniforms(ctx, renderer, frame, uniforms)
    }

    /// A slice through `plane` ([`crate::slice`]), drawn with [`RaycastRenderer::render_slice`] into a target of
    /// `plane.size`.
    #[must_use]
    pub fn for_slice(
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        frame: &GpuFrame<'_>,
        plane: &SlicePlane,
        settings: &RenderSettings,
    ) -> Self {
        let (fixed, moving) = (frame.fixed.params(), frame.moving.params());
        let uniforms = RaycastUniforms::for_slice(plane, settings, &fixed, &moving, frame.tfs.rows);
        Self::with_uniforms(ctx, renderer, frame, uniforms)
    }

    /// As [`Self::new`] with uniforms built by the caller (the tests share them with the CPU reference).
    #[must_use]
    pub fn with_uniforms(
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        frame: &GpuFrame<'_>,
        uniforms: RaycastUniforms,
    ) -> Self {
        let GpuFrame { fixed, moving, tfs } = frame;
        let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("raycast uniforms"),
            size: std::mem::size_of::<RaycastUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue.write_buffer(&buffer, 0, bytemuck::bytes_of(&uniforms));
        let fixed_ctrl = fixed.control.map_or(&renderer.placeholder_control, |c| &c.view);
        let moving_ctrl = moving.control.map_or(&renderer.placeholder_control, |c| &c.view);
        let fixed_pf = fixed.prefiltered.map_or(&renderer.placeholder_prefiltered, |p| &p.view);
        let moving_pf = moving.prefiltered.map_or(&renderer.placeholder_prefiltered, |p| &p.view);
        debug_assert!(renderer.volumes_filterable != fixed.volume.info.manual_filter);
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("raycast"),
            layout: &renderer.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&fixed.volume.view) },
                wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::TextureView(&moving.volume.view) },
                wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(fixed_ctrl) },
                wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::TextureView(moving_ctrl) },
                wgpu::BindGroupEntry { binding: 5, resource: wgpu::BindingResource::TextureView(&tfs.view) },
                wgpu::BindGroupEntry { binding: 6, resource: wgpu::BindingResource::Sampler(&renderer.volume_sampler) },
                wgpu::BindGroupEntry { binding: 7, resource: wgpu::BindingResource::Sampler(&renderer.linear_sampler) },
                wgpu::BindGroupEntry { binding: 8, resource: wgpu::BindingResource::TextureView(fixed_pf) },
                wgpu::BindGroupEntry { binding: 9, resource: wgpu::BindingResource::TextureView(moving_pf) },
            ],
        });
        Self { uniforms, buffer, bind_group }
    }

    /// The frame's bind group (group 0 of the ray caster and of the picking pass).
    #[must_use]
    pub fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    /// New camera, settings or styles for the same textures.
    pub fn update_uniforms(&mut self, ctx: &GpuContext, uniforms: RaycastUniforms) {
        self.uniforms = uniforms;
        ctx.queue.write_buffer(&self.buffer, 0, bytemuck::bytes_of(&uniforms));
    }
}

/// The ray caster's first-hit threshold: the hit depth is taken where the accumulated opacity first reaches it.
/// Keep in sync with `HIT_OPACITY` in shaders/raycast.wgsl.
pub const HIT_OPACITY: f32 = 0.5;
/// The hit depth of a ray that hits nothing (beyond the far plane's 1). Keep in sync with shaders/raycast.wgsl.
pub const NO_HIT_DEPTH: f32 = 2.0;

/// An `Rgba8Unorm` render target the app can show (`TEXTURE_BINDING`) and tests can read back (`COPY_SRC`), with
/// the ray caster's first-hit depth beside it (NDC depth as f32 bits in R32Uint, [`NO_HIT_DEPTH`] where nothing was hit), which the
/// glyph pass ([`crate::glyph`]) depth-tests against.
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
    /// The usages of both textures.
    pub const USAGE: wgpu::TextureUsages = wgpu::TextureUsages::RENDER_ATTACHMENT
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
        let texture = pool.acquire(key(RaycastRenderer::TARGET_FORMAT), "raycast target");
        let hit_depth = pool.acquire(key(RaycastRenderer::HIT_DEPTH_FORMAT), "raycast hit depth");
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let hit_depth_view = hit_depth.create_view(&wgpu::TextureViewDescriptor::default());
        Self { texture, view, hit_depth, hit_depth_view, width, height, pool: Some(pool.clone()) }
    }

    /// The two attachments of a ray-casting pass, cleared to transparent and to [`NO_HIT_DEPTH`].
    #[must_use]
    pub fn colour_attachments(&self) -> [Option<wgpu::RenderPassColorAttachment<'_>>; 2] {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::{ControlDesc, PreparedControl};
    use crate::device::Capabilities;
    use crate::volume::{PreparedVolume, VolumeBudget, VolumeDesc, VolumeSamples};

    #[test]
    fn proxy_box_covers_the_warped_extent() {
        let samples = vec![0u8; 8];
        let lps_from_index = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims: [2, 2, 2], samples: VolumeSamples::U8(&samples), lps_from_index };
        let caps = Capabilities { norm16: true, float32_filterable: true };
        let budget = VolumeBudget { max_dimension: 64, max_bytes: 1 << 20 };
        let vol = PreparedVolume::prepare(&desc, caps, budget).expect("volume");
        // Voxel-edge box [−0.5, 1.5]³; displacements x ∈ [−10, 2], y = 3, z = 0.
        let texels: Vec<f32> = [[-10.0, 3.0, 0.0, 0.0], [2.0, 3.0, 0.0, 0.0]].concat().repeat(4);
        let cdesc = ControlDesc { dims: [2, 2, 2], texels: &texels, box_min_ref: [0.0; 3], box_max_ref: [1.0; 3] };
        let ctrl = PreparedControl::prepare(&cdesc, true).expect("control");
        let style = LayerStyle {
            window: Window::from_range(0.0, 1.0),
            tf_row: 0,
            opacity_scale: 1.0,
            visible: true,
            iso_value: 0.5,
        };
        let plain = LayerParams { volume: vol.info, control: None, style, has_prefilter: false };
        let warped = LayerParams { control: Some(ctrl.info), ..plain };
        assert_eq!(plain.box_ref(), (DVec3::splat(-0.5), DVec3::splat(1.5)));
        let (lo, hi) = warped.box_ref();
        assert_eq!((lo, hi), (DVec3::new(-2.5, -3.5, -0.5), DVec3::new(11.5, -1.5, 1.5)));
    }
}
