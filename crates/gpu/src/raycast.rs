//! The ray caster: one compute pass, an invocation per pixel, that samples the fixed and the (deformed) moving volume at the same points
//! of ref space (Brunet et al. 2006 §4.3: both volumes share one proxy geometry), classifies each with its transfer
//! function, combines them by a [`BlendMode`] and composites front to back. It writes the image and the first-hit
//! depth into the [`RenderTarget`]'s storage textures (`cs_raycast`, slices `cs_slice`), 8×8 pixels a workgroup. A
//! compute shader, not a fragment shader: data-centre GPUs run fragment shaders on a few of their processors only
//! (`docs/benchmarks.md`, Real GPU), while desktop GPUs and CPU drivers run both alike.
//!
//! Per pixel: a ray from the near to the far plane (`ref_from_clip`), clipped to the proxy box (the ref-space box
//! where either volume can appear after its warp, [`LayerParams::box_ref`]); samples at t_k = t_enter + (k + j)·step with j = 0, or a fixed
//! per-pixel hash when jitter is on; at each x_ref, for each visible volume, u(x) = x + disp(ctrl_tex_from_ref · x)
//! (or x), `tex_from_lps · u(x)`, trilinear sample (transparent outside \[0, 1\]³), value → TF; opacity correction
//! α' = 1 − (1 − α)^(step/ref_step) with ref_step one voxel of the finest visible spacing; blend; "over"
//! compositing of premultiplied colour, stopping at α > 0.99. The output is premultiplied RGBA8.
//!
//! **Pre-integrated classification** ([`Classification::PreIntegrated`], DVR only; Engel, Kraus & Ertl 2001): the same
//! sample lattice, but each sample k ≥ 1 closes the segment from sample k − 1, classified by looking up the layer's
//! [`crate::transfer::PreIntegrationTable`] at (TF coordinate of sample k − 1, of sample k): the exact segment
//! integral of colour and opacity for a value going linearly between them (opacity correction included); a segment
//! with an end outside the volume's box is transparent. DVR lights the segment's straight colour C/α with the
//! gradient at the segment's midpoint. The tables (256×256 `Rgba32Float`, one per layer) are built on the CPU for the
//! layer's TF row, opacity scale and the frame's step, and cached by the [`RaycastRenderer`] (the last few), so a
//! frame pays for them only when its look or sample rate changes. Empty-space skipping jumps over the segments that
//! lie inside an empty brick and re-samples the front of the next one, so the image is the same as without it.
//!
//! **Shading** ([`Shading`], [`ShadingMode`]; Brunet et al. 2006 §3.4, Westermann & Rezk-Salama 2001 §3.3): the
//! gradient at a ref-space sample x is the gradient of the *deformed* prefiltered copy v_pf ([`crate::prefilter`]) by
//! the chain rule through Φ = p∘u∘w (view deformation, pull-back, procedural deformation), ∇(v_pf∘Φ)(x) =
//! J_Φ(x)ᵀ ∇v_pf(Φ(x)): ∇v_pf is one hardware-filtered lookup of the copy's gradient texture, and J_Φ the identity
//! for an undeformed volume, else central differences of Φ with step h, column i = \[Φ(x + h·eᵢ) − Φ(x − h·eᵢ)\]/2h,
//! so the lighting follows the deformation. Without a copy, central differences of the volume itself through the
//! warp, gᵢ(x) = \[v(Φ(x + h·eᵢ)) − v(Φ(x − h·eᵢ))\]/2h. h defaults to one voxel of the finest visible spacing. DVR lights every sample
//! with opacity > 0; iso mode takes, per layer, the first sample with value ≥ [`LayerStyle::iso_value`], refines it
//! by bisection, lights it opaque, and blends the two layers' hits once by the [`BlendMode`] (the checkerboard cell
//! is chosen at the nearer hit). Each shading mode (and each set of deformations computed in the shader,
//! [`RaycastUniforms::deformations`], and what the two volumes' flags have in common: a volume filtered by hand, both
//! prefiltered) has its own pipeline (WGSL overrides `SHADING`, `DEFORMATIONS`, `ANY_MANUAL_FILTER`,
//! `ALL_PREFILTERED`), created on first use, so the unlit pass compiles none of the lighting code and pays nothing for
//! it, and a CPU driver, which runs both sides of a branch it cannot prove uniform, none of the branches no volume
//! takes.
//!
//! Types: [`RaycastRenderer`] (long-lived: pipeline, layout, samplers) and [`RaycastDrawData`] (one frame: bind
//! group and uniforms over the volumes, control textures and transfer functions). [`RaycastUniforms`] is built by
//! [`RaycastUniforms::new`] from the plain settings of [`crate::settings`], which the CPU reference
//! ([`crate::cpu_reference`]) consumes too. It draws into a [`RenderTarget`].

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Mat4};

use crate::camera::{OrbitCamera, Projection};
use crate::control::{GpuControlTexture, PreparedControl};
use crate::device::GpuContext;
use crate::empty_space::{
    BrickLattice, DEFAULT_REF_BRICK_VOXELS, EmptySpaceGrid, EmptySpaceKey, GpuEmptySpace, OCCUPIED_FIXED,
    OCCUPIED_MOVING, OccupancyLayer,
};
use crate::error::{GpuError, Result};
use crate::prefilter::GpuPrefiltered;
use crate::procedural::{
    PROCEDURAL_BEND, PROCEDURAL_BUMP, PROCEDURAL_NONE, PROCEDURAL_SHIFT, PROCEDURAL_SINE, PROCEDURAL_TWIST, Procedural,
    ProceduralUniforms,
};
use crate::settings::{
    BlendMode, Classification, LayerParams, LayerStyle, RenderSettings, Shading, ShadingMode, proxy_box_ref,
};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, WgslConstant, layout};
use crate::slice::SlicePlane;
use crate::target::{HIT_OPACITY, NO_HIT_DEPTH, RenderTarget};
use crate::transfer::{GpuPreIntegration, GpuTransferFunctions, OpacityTable, PreIntegrationKey};
use crate::view_deformation::{
    VIEW_EMPTY, VIEW_FISH_EYE, VIEW_LEAFER, VIEW_NONE, ViewDeformation, ViewDeformationUniforms,
};
use crate::volume::GpuVolume;

/// `VolumeUniforms.flags`, the WGSL constants of the same names ([`INTERFACE`]).
pub const VOLUME_VISIBLE: u32 = 1;
pub const VOLUME_HAS_WARP: u32 = 2;
pub const VOLUME_MANUAL_FILTER: u32 = 4;
/// A prefiltered copy is bound for this volume (gradients come from it; otherwise from the volume itself).
pub const VOLUME_HAS_PREFILTER: u32 = 8;
/// `RaycastUniforms.flags`.
pub const RAYCAST_JITTER: u32 = 1;
/// DVR composites pre-integrated segments ([`Classification::PreIntegrated`]) from the layers' tables
/// ([`SLOT_FIXED_PREINTEGRATION`], [`SLOT_MOVING_PREINTEGRATION`]).
pub const RAYCAST_PREINTEGRATED: u32 = 2;
/// [`RaycastUniforms::deformations`] bits, the WGSL constants `DEFORM_*`: a layer has a procedural deformation, a layer
/// has a view deformation. The pipelines are specialised on them (WGSL override `DEFORMATIONS`).
pub const DEFORM_PROCEDURAL: u32 = 1;
pub const DEFORM_VIEW: u32 = 2;

/// What a frame's two volumes' flags have in common, which the raycast and slice pipelines are specialised on (WGSL
/// overrides `ANY_MANUAL_FILTER`, `ALL_PREFILTERED`): a branch on a volume's flag that the variant settles is compiled
/// out. The image is the same either way; the cost is not on a CPU driver, which runs both sides of a branch it cannot
/// prove uniform (masked): on lavapipe the hand filter and the gradients without a prefiltered copy cost every sample
/// even where no volume takes them (the demo pair's shaded frame took twice as long, `docs/benchmarks.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct LayerVariant {
    /// A volume is filtered by hand ([`VOLUME_MANUAL_FILTER`]).
    any_manual_filter: bool,
    /// Both volumes have a prefiltered copy ([`VOLUME_HAS_PREFILTER`]).
    all_prefiltered: bool,
}

impl LayerVariant {
    /// Every branch kept (what the picks compile).
    const ALL: Self = Self { any_manual_filter: true, all_prefiltered: false };

    fn of(u: &RaycastUniforms) -> Self {
        let flags = [u.fixed.flags, u.moving.flags];
        Self {
            any_manual_filter: flags.iter().any(|f| f & VOLUME_MANUAL_FILTER != 0),
            all_prefiltered: flags.iter().all(|f| f & VOLUME_HAS_PREFILTER != 0),
        }
    }

    /// The WGSL overrides that select it.
    fn constants(self) -> [(&'static str, f64); 2] {
        [
            ("ANY_MANUAL_FILTER", f64::from(u8::from(self.any_manual_filter))),
            ("ALL_PREFILTERED", f64::from(u8::from(self.all_prefiltered))),
        ]
    }
}

/// Which of the module's entry points a pipeline runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Entry {
    Raycast,
    Slice,
}

/// What a pipeline is specialised on: its entry point, the shading mode's code (`SHADING`; raycast only), the
/// deformations computed in the shader (`DEFORMATIONS`) and the volumes' flags ([`LayerVariant`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct PipelineKey {
    entry: Entry,
    shading: u32,
    deformations: u32,
    variant: LayerVariant,
}

/// Pre-integration tables a renderer keeps for reuse ([`RaycastRenderer`]): two layers at the full and the interactive
/// rate.
const PREINTEGRATION_CACHE: usize = 4;
/// Early ray termination threshold.
pub const EARLY_EXIT_ALPHA: f32 = 0.99;

/// One volume's uniforms: `VolumeUniforms` in shaders/raycast.wgsl ([`INTERFACE`]).
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
    /// The deformation of the layer's data the shader computes after the pull-back ([`crate::procedural`]).
    pub procedural: ProceduralUniforms,
    /// The deformation of the view the layer is drawn through, before the pull-back ([`crate::view_deformation`]).
    pub view: ViewDeformationUniforms,
}
const _: () = assert!(std::mem::size_of::<VolumeUniforms>() == 288);

/// The empty-space grid a frame skips by ([`crate::empty_space`]): `EmptySpaceUniforms` in shaders/raycast.wgsl
/// ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct EmptySpaceUniforms {
    /// The ref-space corner of brick (0, 0, 0).
    pub min_ref: [f32; 3],
    /// 1: skip the bricks the grid marks empty; 0: skip nothing (the grid bound is a placeholder).
    pub enabled: u32,
    pub dims: [u32; 3],
    /// Brick edge, ref mm.
    pub brick_mm: f32,
}
const _: () = assert!(std::mem::size_of::<EmptySpaceUniforms>() == 32);

impl EmptySpaceUniforms {
    /// Skipping by a grid on `lattice`.
    #[must_use]
    pub fn on(lattice: &BrickLattice) -> Self {
        Self { min_ref: lattice.min_ref.to_array(), enabled: 1, dims: lattice.dims, brick_mm: lattice.brick_mm }
    }
}

/// The frame's uniforms: `RaycastUniforms` in shaders/raycast.wgsl ([`INTERFACE`]).
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
    /// Empty-space skipping: off unless the frame binds a grid ([`RaycastDrawData::with_empty_space`]).
    pub empty_space: EmptySpaceUniforms,
}
const _: () = assert!(std::mem::size_of::<RaycastUniforms>() == 832);

impl VolumeUniforms {
    /// The uniforms of `layer`, whose transfer function is a row of a texture of `tf_rows` rows.
    #[must_use]
    pub fn new(layer: &LayerParams, tf_rows: u32) -> Self {
        let mut flags = 0;
        if layer.has_prefilter {
            flags |= VOLUME_HAS_PREFILTER;
        }
        if layer.style.visible {
            flags |= VOLUME_VISIBLE;
        }
        if layer.control.is_some() {
            flags |= VOLUME_HAS_WARP;
        }
        if layer.volume.manual_filter {
            flags |= VOLUME_MANUAL_FILTER;
        }
        Self {
            tex_from_lps: layer.volume.tex_from_lps.to_cols_array_2d(),
            ctrl_tex_from_ref: layer.control.map_or(Mat4::IDENTITY, |c| c.ctrl_tex_from_ref).to_cols_array_2d(),
            value_offset: layer.volume.value_offset,
            value_scale: layer.volume.value_scale,
            window_low: layer.style.window.low(),
            window_width: layer.style.window.width,
            tf_row: layer.style.tf_row.min(tf_rows.max(1) - 1),
            opacity_scale: layer.style.opacity_scale,
            flags,
            iso_value: layer.style.iso_value,
            procedural: ProceduralUniforms::of(layer.procedural.as_ref()),
            view: ViewDeformationUniforms::of(layer.view.as_ref()),
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
        let (box_min, box_max) = settings.box_override_ref.unwrap_or_else(|| proxy_box_ref(fixed, moving));
        let visible: Vec<&LayerParams> = match settings.blend {
            BlendMode::FixedOnly => vec![fixed],
            BlendMode::MovingOnly => vec![moving],
            _ => vec![fixed, moving],
        };
        let finest_mm =
            visible.iter().filter(|l| l.style.visible).flat_map(|l| l.volume.spacing_mm).fold(f64::INFINITY, f64::min);
        let finest_mm = if finest_mm.is_finite() { finest_mm as f32 } else { 1.0 };
        let mut flags = if settings.jitter_seed.is_some() { RAYCAST_JITTER } else { 0 };
        if settings.classification == Classification::PreIntegrated && settings.shading.mode != ShadingMode::Iso {
            flags |= RAYCAST_PREINTEGRATED;
        }
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
            flags,
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
            fixed: VolumeUniforms::new(fixed, tf_rows),
            moving: VolumeUniforms::new(moving, tf_rows),
            ref_from_frag_px: Mat4::IDENTITY.to_cols_array_2d(),
            empty_space: EmptySpaceUniforms::default(),
        }
    }

    /// The deformations computed in the shader that this frame uses ([`DEFORM_PROCEDURAL`], [`DEFORM_VIEW`]): the
    /// pipeline it runs carries only their code.
    #[must_use]
    pub fn deformations(&self) -> u32 {
        let mut bits = 0;
        for v in [&self.fixed, &self.moving] {
            if v.procedural.kind != PROCEDURAL_NONE {
                bits |= DEFORM_PROCEDURAL;
            }
            if v.view.kind != VIEW_NONE {
                bits |= DEFORM_VIEW;
            }
        }
        bits
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
        let settings = RenderSettings {
            shading: Shading::default(),
            jitter_seed: None,
            classification: Classification::PerSample,
            ..*settings
        };
        Self {
            ref_from_frag_px: plane.ref_from_frag_px().to_cols_array_2d(),
            ..Self::new(&camera, &settings, (w, h), fixed, moving, tf_rows)
        }
    }
}

/// `shaders/raycast.wgsl`: `cs_raycast` (the 3-D view), `cs_slice` ([`crate::slice`]) and `cs_pick`
/// ([`crate::pick`]).
pub const SHADER: ShaderSource = ShaderSource {
    name: "raycast",
    path: "shaders/raycast.wgsl",
    source: include_str!("../../../shaders/raycast.wgsl"),
    entry_points: &[
        (RaycastRenderer::ENTRY_POINT, Stage::Compute),
        (RaycastRenderer::SLICE_ENTRY_POINT, Stage::Compute),
        (PICK_ENTRY_POINT, Stage::Compute),
    ],
};

/// The picking pass's entry point ([`crate::pick`]), in this pass's shader.
pub const PICK_ENTRY_POINT: &str = "cs_pick";

/// The frame's bind group ([`RaycastDrawData::bind_group`]), group 0 of the ray caster and of the picking pass.
pub const FRAME_GROUP: u32 = 0;
/// [`RaycastUniforms`].
pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(FRAME_GROUP, 0, "u");
pub const SLOT_FIXED_VOLUME: BindSlot = BindSlot::new(FRAME_GROUP, 1, "fixed_tex");
pub const SLOT_MOVING_VOLUME: BindSlot = BindSlot::new(FRAME_GROUP, 2, "moving_tex");
/// The fixed volume's control texture (a placeholder without a warp).
pub const SLOT_FIXED_CONTROL: BindSlot = BindSlot::new(FRAME_GROUP, 3, "fixed_ctrl_tex");
pub const SLOT_MOVING_CONTROL: BindSlot = BindSlot::new(FRAME_GROUP, 4, "moving_ctrl_tex");
/// The transfer functions, one row each.
pub const SLOT_TRANSFER_FUNCTIONS: BindSlot = BindSlot::new(FRAME_GROUP, 5, "tf_tex");
/// Filtering or not, as the volumes' formats allow.
pub const SLOT_VOLUME_SAMPLER: BindSlot = BindSlot::new(FRAME_GROUP, 6, "volume_sampler");
/// Always filtering: control textures and transfer functions.
pub const SLOT_LINEAR_SAMPLER: BindSlot = BindSlot::new(FRAME_GROUP, 7, "linear_sampler");
/// The fixed volume's prefiltered copy (a placeholder without one).
pub const SLOT_FIXED_GRADIENT: BindSlot = BindSlot::new(FRAME_GROUP, 8, "fixed_grad_tex");
pub const SLOT_MOVING_GRADIENT: BindSlot = BindSlot::new(FRAME_GROUP, 9, "moving_grad_tex");
/// The empty-space grid ([`crate::empty_space`]; a placeholder marking everything occupied without one).
pub const SLOT_EMPTY_SPACE: BindSlot = BindSlot::new(FRAME_GROUP, 10, "empty_space_tex");
/// The fixed layer's pre-integration table ([`crate::transfer::PreIntegrationTable`]; a placeholder unless the frame
/// pre-integrates).
pub const SLOT_FIXED_PREINTEGRATION: BindSlot = BindSlot::new(FRAME_GROUP, 11, "fixed_preint_tex");
pub const SLOT_MOVING_PREINTEGRATION: BindSlot = BindSlot::new(FRAME_GROUP, 12, "moving_preint_tex");

/// The ray caster's own bind group: the band of rows and the images it writes ([`RaycastRenderer::render_rows`]).
/// The picking pass's group has the same number, with bindings 0–2 ([`crate::pick`]); the two never share a
/// pipeline.
pub const OUTPUT_GROUP: u32 = 1;
/// [`BandUniforms`].
pub const SLOT_BAND: BindSlot = BindSlot::new(OUTPUT_GROUP, 3, "band");
/// The image, [`RenderTarget::COLOUR_FORMAT`], written as a storage texture.
pub const SLOT_OUT_COLOUR: BindSlot = BindSlot::new(OUTPUT_GROUP, 4, "out_colour");
/// The first-hit depth, [`RenderTarget::HIT_DEPTH_FORMAT`] (3-D frames only; slices leave it as it was).
pub const SLOT_OUT_HIT_DEPTH: BindSlot = BindSlot::new(OUTPUT_GROUP, 5, "out_hit_depth");
/// Pixels per workgroup along x and y: `WORKGROUP_EDGE` in shaders/raycast.wgsl.
pub const WORKGROUP_EDGE: u32 = 8;
const _: () = assert!(FRAME_GROUP == 0 && OUTPUT_GROUP == 1, "RaycastRenderer::new lists the layouts in group order");

/// The rows one dispatch covers: `BandUniforms` in shaders/raycast.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct BandUniforms {
    /// The band's first row, from the top.
    pub first_row: u32,
    /// The row after the band's last.
    pub end_row: u32,
    _pad0: u32,
    _pad1: u32,
}
const _: () = assert!(std::mem::size_of::<BandUniforms>() == 16);

impl BandUniforms {
    /// The rows `rows`.
    #[must_use]
    pub fn new(rows: std::ops::Range<u32>) -> Self {
        Self { first_row: rows.start, end_row: rows.end, _pad0: 0, _pad1: 0 }
    }
}

/// The ray caster's part of `shaders/raycast.wgsl` (the picking pass declares its own, [`crate::pick::INTERFACE`]).
pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "raycast",
    shader: SHADER,
    uniform_structs: &[
        layout!(VolumeUniforms {
            tex_from_lps,
            ctrl_tex_from_ref,
            value_offset,
            value_scale,
            window_low,
            window_width,
            tf_row,
            opacity_scale,
            flags,
            iso_value,
            procedural,
            view
        }),
        layout!(ViewDeformationUniforms { centre_ref, kind, front, radius_mm, normal, amplitude }),
        layout!(ProceduralUniforms {
            centre_mm,
            kind,
            vector_mm,
            amplitude_mm,
            wavenumber_per_mm,
            rate_per_mm,
            phase_rad,
            sigma_mm,
            axis,
            normal_axis,
            normal_sign
        }),
        layout!(EmptySpaceUniforms { min_ref, enabled, dims, brick_mm }),
        layout!(BandUniforms { first_row, end_row }),
        layout!(RaycastUniforms {
            ref_from_clip,
            box_min_ref,
            step_mm,
            box_max_ref,
            ref_step_mm,
            viewport_px,
            blend_mode,
            flags,
            blend_weight,
            checker_cell_mm,
            max_steps,
            jitter_seed,
            shading_mode,
            bisection_steps,
            gradient_step_mm,
            ambient,
            diffuse,
            specular,
            shininess,
            fixed,
            moving,
            ref_from_frag_px,
            empty_space
        }),
    ],
    slots: &[
        SLOT_UNIFORMS,
        SLOT_FIXED_VOLUME,
        SLOT_MOVING_VOLUME,
        SLOT_FIXED_CONTROL,
        SLOT_MOVING_CONTROL,
        SLOT_TRANSFER_FUNCTIONS,
        SLOT_VOLUME_SAMPLER,
        SLOT_LINEAR_SAMPLER,
        SLOT_FIXED_GRADIENT,
        SLOT_MOVING_GRADIENT,
        SLOT_EMPTY_SPACE,
        SLOT_FIXED_PREINTEGRATION,
        SLOT_MOVING_PREINTEGRATION,
        SLOT_BAND,
        SLOT_OUT_COLOUR,
        SLOT_OUT_HIT_DEPTH,
    ],
    constants: &[
        WgslConstant::u32("WORKGROUP_EDGE", WORKGROUP_EDGE),
        WgslConstant::u32("VOLUME_VISIBLE", VOLUME_VISIBLE),
        WgslConstant::u32("VOLUME_HAS_WARP", VOLUME_HAS_WARP),
        WgslConstant::u32("VOLUME_MANUAL_FILTER", VOLUME_MANUAL_FILTER),
        WgslConstant::u32("VOLUME_HAS_PREFILTER", VOLUME_HAS_PREFILTER),
        WgslConstant::u32("RAYCAST_JITTER", RAYCAST_JITTER),
        WgslConstant::u32("DEFORM_PROCEDURAL", DEFORM_PROCEDURAL),
        WgslConstant::u32("DEFORM_VIEW", DEFORM_VIEW),
        WgslConstant::u32("VIEW_NONE", VIEW_NONE),
        WgslConstant::u32("VIEW_FISH_EYE", VIEW_FISH_EYE),
        WgslConstant::u32("VIEW_LEAFER", VIEW_LEAFER),
        WgslConstant::f32("VIEW_EMPTY", VIEW_EMPTY),
        WgslConstant::u32("PROCEDURAL_NONE", PROCEDURAL_NONE),
        WgslConstant::u32("PROCEDURAL_SHIFT", PROCEDURAL_SHIFT),
        WgslConstant::u32("PROCEDURAL_SINE", PROCEDURAL_SINE),
        WgslConstant::u32("PROCEDURAL_TWIST", PROCEDURAL_TWIST),
        WgslConstant::u32("PROCEDURAL_BEND", PROCEDURAL_BEND),
        WgslConstant::u32("PROCEDURAL_BUMP", PROCEDURAL_BUMP),
        WgslConstant::u32("RAYCAST_PREINTEGRATED", RAYCAST_PREINTEGRATED),
        WgslConstant::u32("OCCUPIED_FIXED", OCCUPIED_FIXED),
        WgslConstant::u32("OCCUPIED_MOVING", OCCUPIED_MOVING),
        WgslConstant::f32("EARLY_EXIT_ALPHA", EARLY_EXIT_ALPHA),
        WgslConstant::f32("HIT_OPACITY", HIT_OPACITY),
        WgslConstant::f32("NO_HIT_DEPTH", NO_HIT_DEPTH),
    ],
};

/// The stages that see the frame's bind group: the ray caster and the picking pass ([`crate::pick`]), which marches
/// the same samples, are both compute shaders.
const FRAME_STAGES: wgpu::ShaderStages = wgpu::ShaderStages::COMPUTE;

/// The long-lived part of the ray caster: pipeline, bind group layout, samplers and the placeholder control texture.
#[derive(Debug)]
pub struct RaycastRenderer {
    device: wgpu::Device,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    /// The raycast and slice pipelines, one per [`PipelineKey`], created on first use ([`Self::pipeline`]).
    pipelines: std::sync::Mutex<std::collections::HashMap<PipelineKey, wgpu::ComputePipeline>>,
    /// The frame's bind group (group [`FRAME_GROUP`]), shared with the picking pass.
    layout: wgpu::BindGroupLayout,
    /// The output's bind group (group [`OUTPUT_GROUP`]).
    output_layout: wgpu::BindGroupLayout,
    volume_sampler: wgpu::Sampler,
    linear_sampler: wgpu::Sampler,
    placeholder_control: wgpu::TextureView,
    placeholder_prefiltered: wgpu::TextureView,
    placeholder_empty_space: wgpu::TextureView,
    placeholder_preintegration: wgpu::TextureView,
    /// The pre-integration tables of recent frames, most recently used last ([`Self::preintegration`]).
    preintegration: std::sync::Mutex<Vec<std::sync::Arc<GpuPreIntegration>>>,
    volumes_filterable: bool,
}

impl RaycastRenderer {
    /// Requested when the adapter has them; without them the pass falls back (see [`crate::volume`] and
    /// [`crate::control`]).
    pub const OPTIONAL_FEATURES: wgpu::Features =
        wgpu::Features::TEXTURE_FORMAT_16BIT_NORM.union(wgpu::Features::FLOAT32_FILTERABLE);
    /// Sampled textures, samplers and storage textures per compute stage this pass binds.
    pub const SAMPLED_TEXTURES: u32 = 10;
    pub const SAMPLERS: u32 = 2;
    pub const STORAGE_TEXTURES: u32 = 2;
    /// The 3-D view's entry point in `shaders/raycast.wgsl`.
    pub const ENTRY_POINT: &'static str = "cs_raycast";
    /// The slice entry point in `shaders/raycast.wgsl`.
    pub const SLICE_ENTRY_POINT: &'static str = "cs_slice";

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        if l.max_sampled_textures_per_shader_stage < Self::SAMPLED_TEXTURES
            || l.max_samplers_per_shader_stage < Self::SAMPLERS
            || l.max_storage_textures_per_shader_stage < Self::STORAGE_TEXTURES
        {
            return Err(GpuError::Unsupported(format!(
                "the ray caster binds {} textures, {} samplers and {} storage textures per stage; the device allows \
                 {}, {} and {}",
                Self::SAMPLED_TEXTURES,
                Self::SAMPLERS,
                Self::STORAGE_TEXTURES,
                l.max_sampled_textures_per_shader_stage,
                l.max_samplers_per_shader_stage,
                l.max_storage_textures_per_shader_stage
            )));
        }
        let device = &ctx.device;
        let volumes_filterable = ctx.capabilities.volumes_filterable();
        let texture = |view_dimension, filterable| wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension,
            multisampled: false,
        };
        let tex3d = |slot: BindSlot, filterable| {
            slot.layout_entry(FRAME_STAGES, texture(wgpu::TextureViewDimension::D3, filterable))
        };
        let sampler = |slot: BindSlot, kind| slot.layout_entry(FRAME_STAGES, wgpu::BindingType::Sampler(kind));
        let volume_sampling = if volumes_filterable {
            wgpu::SamplerBindingType::Filtering
        } else {
            wgpu::SamplerBindingType::NonFiltering
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("raycast"),
            entries: &[
                SLOT_UNIFORMS.layout_entry(
                    FRAME_STAGES,
                    wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<RaycastUniforms>() as u64),
                    },
                ),
                tex3d(SLOT_FIXED_VOLUME, volumes_filterable),
                tex3d(SLOT_MOVING_VOLUME, volumes_filterable),
                tex3d(SLOT_FIXED_CONTROL, true),
                tex3d(SLOT_MOVING_CONTROL, true),
                SLOT_TRANSFER_FUNCTIONS.layout_entry(FRAME_STAGES, texture(wgpu::TextureViewDimension::D2, true)),
                sampler(SLOT_VOLUME_SAMPLER, volume_sampling),
                sampler(SLOT_LINEAR_SAMPLER, wgpu::SamplerBindingType::Filtering),
                // The prefiltered copies' gradients: Rgba16Float, filterable everywhere.
                tex3d(SLOT_FIXED_GRADIENT, true),
                tex3d(SLOT_MOVING_GRADIENT, true),
                SLOT_EMPTY_SPACE.layout_entry(
                    FRAME_STAGES,
                    wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D3,
                        multisampled: false,
                    },
                ),
                // Rgba32Float, read with textureLoad.
                SLOT_FIXED_PREINTEGRATION.layout_entry(FRAME_STAGES, texture(wgpu::TextureViewDimension::D2, false)),
                SLOT_MOVING_PREINTEGRATION.layout_entry(FRAME_STAGES, texture(wgpu::TextureViewDimension::D2, false)),
            ],
        });
        let storage = |slot: BindSlot, format| {
            slot.layout_entry(
                FRAME_STAGES,
                wgpu::BindingType::StorageTexture {
                    access: wgpu::StorageTextureAccess::WriteOnly,
                    format,
                    view_dimension: wgpu::TextureViewDimension::D2,
                },
            )
        };
        let output_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("raycast output"),
            entries: &[
                SLOT_BAND.layout_entry(
                    FRAME_STAGES,
                    wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<BandUniforms>() as u64),
                    },
                ),
                storage(SLOT_OUT_COLOUR, RenderTarget::COLOUR_FORMAT),
                storage(SLOT_OUT_HIT_DEPTH, RenderTarget::HIT_DEPTH_FORMAT),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("raycast"),
            bind_group_layouts: &[Some(&layout), Some(&output_layout)],
            immediate_size: 0,
        });
        let module = SHADER.create_module(device);
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
        let placeholder_empty_space = GpuEmptySpace::placeholder(ctx);
        let placeholder_preintegration = GpuPreIntegration::placeholder(ctx);
        ctx.check_errors()?;
        let renderer = Self {
            device: device.clone(),
            module,
            pipeline_layout,
            pipelines: std::sync::Mutex::default(),
            layout,
            output_layout,
            volume_sampler,
            linear_sampler,
            placeholder_control,
            placeholder_prefiltered,
            placeholder_empty_space,
            placeholder_preintegration,
            preintegration: std::sync::Mutex::new(Vec::new()),
            volumes_filterable,
        };
        // The unlit pipeline now, so that shader errors surface here; the others on first use.
        renderer.pipeline(PipelineKey {
            entry: Entry::Raycast,
            shading: ShadingMode::None.code(),
            deformations: 0,
            variant: LayerVariant::ALL,
        });
        ctx.check_errors()?;
        Ok(renderer)
    }

    /// The pipeline for `key`, created on first use: each compiles only its own code, so the unlit pass carries none
    /// of the lighting, a frame without deformations computed in the shader none of theirs, and a volume none of the
    /// branches its flags do not take.
    fn pipeline(&self, key: PipelineKey) -> wgpu::ComputePipeline {
        let mut pipelines = self.pipelines.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        pipelines
            .entry(key)
            .or_insert_with(|| {
                let [manual, prefiltered] = key.variant.constants();
                let deformations = ("DEFORMATIONS", f64::from(key.deformations));
                match key.entry {
                    Entry::Raycast => {
                        let shading = ("SHADING", f64::from(key.shading));
                        let constants = [shading, deformations, manual, prefiltered];
                        self.create_pipeline("raycast", Self::ENTRY_POINT, &constants)
                    }
                    Entry::Slice => {
                        self.create_pipeline("slice", Self::SLICE_ENTRY_POINT, &[deformations, manual, prefiltered])
                    }
                }
            })
            .clone()
    }

    /// The pipeline of `entry` for `uniforms`' shading mode, deformations and volumes.
    fn pipeline_for(&self, entry: Entry, uniforms: &RaycastUniforms) -> wgpu::ComputePipeline {
        self.pipeline(PipelineKey {
            entry,
            shading: match entry {
                Entry::Raycast => uniforms.shading_mode.min(ShadingMode::Iso.code()),
                Entry::Slice => 0,
            },
            deformations: uniforms.deformations() & (DEFORM_PROCEDURAL | DEFORM_VIEW),
            variant: LayerVariant::of(uniforms),
        })
    }

    /// The pre-integration table of `tf` for `key`: from the renderer's cache of the last [`PREINTEGRATION_CACHE`]
    /// tables, or built ([`GpuPreIntegration::build`], tens of ms of CPU) and cached.
    fn preintegration(
        &self,
        ctx: &GpuContext,
        tf: &crate::transfer::TransferFunction,
        key: PreIntegrationKey,
    ) -> std::sync::Arc<GpuPreIntegration> {
        let mut cache = self.preintegration.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(i) = cache.iter().position(|t| t.key == key) {
            let table = cache.remove(i);
            cache.push(table.clone());
            return table;
        }
        let table = std::sync::Arc::new(GpuPreIntegration::build(ctx, tf, key));
        if cache.len() >= PREINTEGRATION_CACHE {
            cache.remove(0);
        }
        cache.push(table.clone());
        table
    }

    fn create_pipeline(&self, label: &str, entry_point: &str, constants: &[(&str, f64)]) -> wgpu::ComputePipeline {
        self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: Some(&self.pipeline_layout),
            module: &self.module,
            entry_point: Some(entry_point),
            compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
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

    /// Renders the slice `data` ([`RaycastUniforms::for_slice`]) into `target` (the plane's size; every pixel is
    /// written, the hit depth is left as it was) and submits.
    pub fn render_slice(&self, ctx: &GpuContext, data: &RaycastDrawData, target: &RenderTarget) -> Result<()> {
        let pipeline = self.pipeline_for(Entry::Slice, &data.uniforms);
        self.dispatch(ctx, &pipeline, data, target, 0..target.height, "slice")
    }

    /// Renders `data` into `target` (every pixel is written) and submits.
    pub fn render(&self, ctx: &GpuContext, data: &RaycastDrawData, target: &RenderTarget) -> Result<()> {
        let pipeline = self.pipeline_for(Entry::Raycast, &data.uniforms);
        self.dispatch(ctx, &pipeline, data, target, 0..target.height, "raycast")
    }

    /// Renders the rows `rows` of `data`'s frame (a band across the whole width, rows counted from the top) into
    /// `target` and submits, so that a frame too slow for one UI frame (on a CPU driver) is rendered over several.
    /// A band from row 0 clears the whole target first (transparent, no hit); a later band keeps what earlier bands
    /// drew. Every pixel's ray depends only on the pixel, so bands covering all rows give exactly the image of
    /// [`Self::render`].
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
        if rows.start == 0 && rows.end < target.height {
            target.clear(ctx);
        }
        let pipeline = self.pipeline_for(Entry::Raycast, &data.uniforms);
        self.dispatch(ctx, &pipeline, data, target, rows, "raycast")
    }

    /// Runs `pipeline` over the rows `rows` of `target` (one invocation per pixel) and submits.
    fn dispatch(
        &self,
        ctx: &GpuContext,
        pipeline: &wgpu::ComputePipeline,
        data: &RaycastDrawData,
        target: &RenderTarget,
        rows: std::ops::Range<u32>,
        label: &str,
    ) -> Result<()> {
        let band_buffer = ctx.uniform_buffer("raycast band", &BandUniforms::new(rows.clone()));
        let output = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("raycast output"),
            layout: &self.output_layout,
            entries: &[
                SLOT_BAND.entry(band_buffer.as_entire_binding()),
                SLOT_OUT_COLOUR.entry(wgpu::BindingResource::TextureView(&target.view)),
                SLOT_OUT_HIT_DEPTH.entry(wgpu::BindingResource::TextureView(&target.hit_depth_view)),
            ],
        });
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        {
            let mut pass =
                encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(label), timestamp_writes: None });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(FRAME_GROUP, &data.bind_group, &[]);
            pass.set_bind_group(OUTPUT_GROUP, &output, &[]);
            pass.dispatch_workgroups(
                target.width.div_ceil(WORKGROUP_EDGE),
                (rows.end - rows.start).div_ceil(WORKGROUP_EDGE),
                1,
            );
        }
        ctx.queue.submit([encoder.finish()]);
        ctx.check_errors()
    }
}

/// One volume with its optional control texture and prefiltered copy, as bound for a frame.
#[derive(Clone, Copy, Debug)]
pub struct GpuLayer<'a> {
    pub volume: &'a GpuVolume,
    pub control: Option<&'a GpuControlTexture>,
    /// The [`crate::PrefilterPass`] output of `volume`, for shading gradients; without it they come from `volume`.
    pub prefiltered: Option<&'a GpuPrefiltered>,
    pub style: LayerStyle,
    /// A deformation of the layer's data computed in the shader ([`LayerParams::procedural`]).
    pub procedural: Option<Procedural>,
    /// A deformation of the view the layer is drawn through ([`LayerParams::view`]).
    pub view: Option<ViewDeformation>,
}

impl GpuLayer<'_> {
    #[must_use]
    pub fn params(&self) -> LayerParams {
        LayerParams {
            volume: self.volume.info,
            control: self.control.map(|c| c.info),
            style: self.style,
            has_prefilter: self.prefiltered.is_some(),
            procedural: self.procedural,
            view: self.view,
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

impl GpuFrame<'_> {
    /// The key of an empty-space grid on `lattice` for this frame's layers.
    #[must_use]
    pub fn empty_space_key(&self, lattice: BrickLattice) -> EmptySpaceKey {
        let (f, m) = (self.fixed.params(), self.moving.params());
        EmptySpaceKey::new(&f, &m, [self.opacity(&f), self.opacity(&m)], lattice)
    }

    /// The automatic proxy box of this frame ([`proxy_box_ref`]).
    #[must_use]
    pub fn proxy_box_ref(&self) -> (glam::Vec3, glam::Vec3) {
        proxy_box_ref(&self.fixed.params(), &self.moving.params())
    }

    fn opacity(&self, layer: &LayerParams) -> &OpacityTable {
        let row = layer.style.tf_row.min(self.tfs.rows.max(1) - 1) as usize;
        &self.tfs.opacity[row]
    }

    /// Classifies the bricks of `box_ref` (bricks of [`DEFAULT_REF_BRICK_VOXELS`] voxels of the finer volume) for
    /// this frame's layers and uploads the grid. `control_texels`: the (fixed, moving) control textures' texels when
    /// the CPU has them, for per-brick displacement bounds; without them the textures' global bounds are used.
    #[must_use]
    pub fn empty_space(
        &self,
        ctx: &GpuContext,
        box_ref: (glam::Vec3, glam::Vec3),
        control_texels: [Option<&PreparedControl>; 2],
    ) -> GpuEmptySpace {
        self.empty_space_on(ctx, self.default_lattice(box_ref), control_texels)
    }

    /// The bricks [`Self::empty_space`] classifies: [`DEFAULT_REF_BRICK_VOXELS`] voxels of the finer volume (at
    /// most [`crate::empty_space::MAX_REF_BRICKS_PER_AXIS`] per axis) over `box_ref`.
    #[must_use]
    pub fn default_lattice(&self, box_ref: (glam::Vec3, glam::Vec3)) -> BrickLattice {
        let (f, m) = (self.fixed.params(), self.moving.params());
        let finest = [f, m].iter().flat_map(|l| l.volume.spacing_mm).fold(f64::INFINITY, f64::min);
        let finest = if finest.is_finite() { finest as f32 } else { 1.0 };
        BrickLattice::covering(box_ref, DEFAULT_REF_BRICK_VOXELS * finest)
    }

    /// As [`Self::empty_space`] on the bricks of `lattice`.
    #[must_use]
    pub fn empty_space_on(
        &self,
        ctx: &GpuContext,
        lattice: BrickLattice,
        control_texels: [Option<&PreparedControl>; 2],
    ) -> GpuEmptySpace {
        let (f, m) = (self.fixed.params(), self.moving.params());
        let fixed = OccupancyLayer {
            params: f,
            bricks: &self.fixed.volume.bricks,
            control_texels: control_texels[0],
            opacity: self.opacity(&f),
        };
        let moving = OccupancyLayer {
            params: m,
            bricks: &self.moving.volume.bricks,
            control_texels: control_texels[1],
            opacity: self.opacity(&m),
        };
        let grid = EmptySpaceGrid::build(&fixed, &moving, lattice);
        GpuEmptySpace::upload(ctx, &grid)
    }
}

/// One frame's resources: the uniform buffer and the bind group over both layers and the transfer functions.
#[derive(Debug)]
pub struct RaycastDrawData {
    pub uniforms: RaycastUniforms,
    /// The buffer of [`Self::uniforms`], held as long as the bind group that binds it.
    _uniform_buffer: wgpu::Buffer,
    /// The (fixed, moving) pre-integration tables the bind group binds, when the frame pre-integrates.
    _preintegration: Option<[std::sync::Arc<GpuPreIntegration>; 2]>,
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

    /// As [`Self::new`], skipping the bricks `empty_space` marks empty (see [`Self::with_empty_space`]).
    #[must_use]
    pub fn new_with_empty_space(
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        frame: &GpuFrame<'_>,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        size_px: (u32, u32),
        empty_space: Option<&GpuEmptySpace>,
    ) -> Self {
        let (fixed, moving) = (frame.fixed.params(), frame.moving.params());
        let uniforms = RaycastUniforms::new(camera, settings, size_px, &fixed, &moving, frame.tfs.rows);
        Self::with_empty_space(ctx, renderer, frame, uniforms, empty_space)
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
        Self::with_empty_space(ctx, renderer, frame, uniforms, None)
    }

    /// As [`Self::with_uniforms`], skipping the bricks `empty_space` marks empty ([`crate::empty_space`]) when it
    /// was built for this frame's layers ([`GpuEmptySpace::key`] equals [`GpuFrame::empty_space_key`]); otherwise
    /// (or with `None`) skipping nothing. The image is the same either way.
    #[must_use]
    pub fn with_empty_space(
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        frame: &GpuFrame<'_>,
        mut uniforms: RaycastUniforms,
        empty_space: Option<&GpuEmptySpace>,
    ) -> Self {
        let empty_space = empty_space.filter(|e| e.key == frame.empty_space_key(e.lattice));
        uniforms.empty_space =
            empty_space.map_or_else(EmptySpaceUniforms::default, |e| EmptySpaceUniforms::on(&e.lattice));
        let empty_space_view = empty_space.map_or(&renderer.placeholder_empty_space, |e| &e.view);
        let GpuFrame { fixed, moving, tfs } = frame;
        let buffer = ctx.uniform_buffer("raycast uniforms", &uniforms);
        let fixed_ctrl = fixed.control.map_or(&renderer.placeholder_control, |c| &c.view);
        let moving_ctrl = moving.control.map_or(&renderer.placeholder_control, |c| &c.view);
        let fixed_pf = fixed.prefiltered.map_or(&renderer.placeholder_prefiltered, |p| &p.view);
        let moving_pf = moving.prefiltered.map_or(&renderer.placeholder_prefiltered, |p| &p.view);
        debug_assert!(renderer.volumes_filterable != fixed.volume.info.manual_filter);
        let preintegration = (uniforms.flags & RAYCAST_PREINTEGRATED != 0).then(|| {
            let step_ratio = uniforms.step_mm / uniforms.ref_step_mm;
            [&uniforms.fixed, &uniforms.moving].map(|v| {
                let tf = &tfs.functions[(v.tf_row as usize).min(tfs.functions.len() - 1)];
                renderer.preintegration(ctx, tf, PreIntegrationKey::new(tf, v.opacity_scale, step_ratio))
            })
        });
        let [fixed_preint, moving_preint] = match &preintegration {
            Some([f, m]) => [&f.view, &m.view],
            None => [&renderer.placeholder_preintegration; 2],
        };
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("raycast"),
            layout: &renderer.layout,
            entries: &[
                SLOT_UNIFORMS.entry(buffer.as_entire_binding()),
                SLOT_FIXED_VOLUME.entry(wgpu::BindingResource::TextureView(&fixed.volume.view)),
                SLOT_MOVING_VOLUME.entry(wgpu::BindingResource::TextureView(&moving.volume.view)),
                SLOT_FIXED_CONTROL.entry(wgpu::BindingResource::TextureView(fixed_ctrl)),
                SLOT_MOVING_CONTROL.entry(wgpu::BindingResource::TextureView(moving_ctrl)),
                SLOT_TRANSFER_FUNCTIONS.entry(wgpu::BindingResource::TextureView(&tfs.view)),
                SLOT_VOLUME_SAMPLER.entry(wgpu::BindingResource::Sampler(&renderer.volume_sampler)),
                SLOT_LINEAR_SAMPLER.entry(wgpu::BindingResource::Sampler(&renderer.linear_sampler)),
                SLOT_FIXED_GRADIENT.entry(wgpu::BindingResource::TextureView(fixed_pf)),
                SLOT_MOVING_GRADIENT.entry(wgpu::BindingResource::TextureView(moving_pf)),
                SLOT_EMPTY_SPACE.entry(wgpu::BindingResource::TextureView(empty_space_view)),
                SLOT_FIXED_PREINTEGRATION.entry(wgpu::BindingResource::TextureView(fixed_preint)),
                SLOT_MOVING_PREINTEGRATION.entry(wgpu::BindingResource::TextureView(moving_preint)),
            ],
        });
        Self { uniforms, _uniform_buffer: buffer, _preintegration: preintegration, bind_group }
    }

    /// The frame's bind group (group 0 of the ray caster and of the picking pass).
    #[must_use]
    pub fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A variant compiles out a branch only where no volume takes it: the hand filter when no volume has it, the
    /// gradients without a copy when both volumes have one.
    #[test]
    fn a_variant_keeps_every_branch_some_volume_takes() {
        let variant = |fixed: u32, moving: u32| {
            let mut u = RaycastUniforms::zeroed();
            (u.fixed.flags, u.moving.flags) = (fixed | VOLUME_VISIBLE, moving | VOLUME_HAS_WARP);
            LayerVariant::of(&u)
        };
        let both = VOLUME_HAS_PREFILTER;
        assert_eq!(variant(both, both), LayerVariant { any_manual_filter: false, all_prefiltered: true });
        assert_eq!(variant(both, 0), LayerVariant { any_manual_filter: false, all_prefiltered: false });
        assert_eq!(
            variant(0, both | VOLUME_MANUAL_FILTER),
            LayerVariant { any_manual_filter: true, all_prefiltered: false }
        );
        assert_eq!(
            variant(VOLUME_MANUAL_FILTER | both, both),
            LayerVariant { any_manual_filter: true, all_prefiltered: true }
        );
        // The variant that keeps every branch is what a pipeline without these overrides compiles (WGSL defaults).
        let source = include_str!("../../../shaders/raycast.wgsl");
        assert!(source.contains("override ANY_MANUAL_FILTER: bool = true;"));
        assert!(source.contains("override ALL_PREFILTERED: bool = false;"));
        assert_eq!(LayerVariant::ALL.constants(), [("ANY_MANUAL_FILTER", 1.0), ("ALL_PREFILTERED", 0.0)]);
    }
}
