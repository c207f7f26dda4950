//! Control textures evaluated on the GPU (Brunet, Nowak & Gleicher 2006 §3.3): the displacement of a pull-back,
//!
//! disp(x_abc) = u(x_abc) − x_abc,   x_abc = min + ((a, b, c) + ½)·pitch,   pitch = (max − min)/n,
//!
//! at the centre of every texel (a, b, c) of an n₀ × n₁ × n₂ grid over a box [min, max] of ref space (the solver's
//! `ControlGrid` convention; [`ControlGridDesc`]), written straight into the 3-D control texture the ray caster
//! samples ([`GpuControlTexture`]). Dragging a landmark then costs one small CPU solve, an upload of the weights and
//! one dispatch: no CPU sampling of the grid and no texture upload.
//!
//! - **TPS** ([`ControlEvalPass::evaluate_tps`], input [`TpsDesc`]): u(x) = A x + b + Σᵢ wᵢ ‖x − pᵢ‖ (Davis 1997,
//!   U(r) = r), evaluated in f32 in the local form about the box centre o ([`TpsDesc::local`]),
//!   disp(o + x′) = (A − I) x′ + (A o + b − o) + Σᵢ wᵢ ‖x′ − (pᵢ − o)‖, so that LPS offsets of a few hundred mm cost
//!   no digits. One invocation per texel loops over the N centres (a storage buffer, at most [`MAX_TPS_CENTRES`]).
//! - **Hierarchical B-spline** ([`ControlEvalPass::evaluate_bspline`], input [`BSplineDesc`]): disp(x) =
//!   Σ_ℓ D_ℓ(clamp(x, Ω_ℓ)), D_ℓ the cubic tensor-product B-spline of lattice ℓ (Lee, Wolberg & Shin 1997 eq. 1), 64
//!   taps per lattice, in cell units u = (x − Ω.min)/h of each lattice (computed as first + (a, b, c)·step from f64
//!   constants, so again no large f32 coordinates). This is the solver's `HierarchicalBSpline` exactly: it refines
//!   every level onto one lattice and clamps x to the domain.
//!
//! # Output
//!
//! The format is the one [`crate::control`] chooses: `Rgba32Float` when the device can filter it, else `Rgba16Float`
//! (the shader rounds to f16 and measures the rounding error, [`ControlInfo::quantisation_mm`]). The shader writes a
//! storage *buffer* laid out as `copy_buffer_to_texture` wants it (rows padded to 256 bytes), and the buffer is then
//! copied into the 3-D texture in the same command encoder. A write-only storage texture would save that copy
//! (≈ 4 MiB at 64³ in f32: microseconds on a real GPU), but wgpu's GL backend binds a 3-D storage texture as one
//! layer (see [`crate::prefilter`]), so slices z > 0 would be lost there, and the ray caster needs a filterable 3-D
//! texture. One buffer path works on every backend and for both formats. The staging buffer is kept by the pass and
//! reused (grown when a larger grid comes); the target texture is reused when its dims and format match, so a drag
//! allocates only a few small buffers.
//!
//! # Displacement bounds
//!
//! The ray caster sizes its proxy box with [`ControlInfo::disp_min_mm`] / [`ControlInfo::disp_max_mm`]. They are
//! reduced on the GPU in the same dispatch: each workgroup (8 × 8 × 1 texels) reduces the values *as stored* in
//! workgroup memory and merges its min and max into a 32-byte buffer with one `atomicMin`/`atomicMax` per component,
//! floats mapped to u32 by the order-preserving map (negative: all bits flipped; positive: sign bit set). The same
//! buffer carries the largest f16 rounding error and a non-finite flag. [`ControlEvalPass::encode_tps`] records the
//! work and a copy of those 32 bytes into a mappable buffer and returns a [`PendingControl`];
//! [`PendingControl::resolve`] waits for the GPU, maps them and fills the [`ControlInfo`], so a [`GpuControlTexture`]
//! never carries unknown bounds. [`ControlEvalPass::evaluate_tps`] does all of it. The readback is a CPU–GPU sync of
//! a few bytes; `benches/control_eval.rs` measures the update with and without it.
//!
//! The f64 references of the two functions are [`TpsDesc::eval`] and [`BSplineDesc::eval`]; `tests/control_eval.rs`
//! compares the GPU result with the solver's CPU sampling (`warpbench_solver::control`).

use std::sync::{Mutex, PoisonError};

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Mat4, Vec3};
use half::f16;
use wgpu::util::DeviceExt;

use crate::compute::{self, binding, storage, uniform};
use crate::control::{ControlInfo, GpuControlTexture};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::pullback::{BSplineDesc, TpsDesc};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, layout};

/// `shaders/control_eval.wgsl`: `cs_tps` and `cs_bspline`, a pull-back's displacement at every texel centre into a
/// staging buffer, with its bounds reduced.
pub const SHADER: ShaderSource = ShaderSource {
    name: "control_eval",
    path: "shaders/control_eval.wgsl",
    // Followed by the f16 conversions it shares with another pass (appended: line numbers stay those of the file).
    source: concat!(include_str!("../../../shaders/control_eval.wgsl"), include_str!("../../../shaders/f16.wgsl")),
    entry_points: &[(TPS_ENTRY_POINT, Stage::Compute), (BSPLINE_ENTRY_POINT, Stage::Compute)],
};
const TPS_ENTRY_POINT: &str = "cs_tps";
const BSPLINE_ENTRY_POINT: &str = "cs_bspline";

/// Both entry points: [`ControlEvalUniforms`].
pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "p");
/// Both: the staging buffer, rows padded for `copy_buffer_to_texture`.
pub const SLOT_OUTPUT: BindSlot = BindSlot::new(0, 1, "out_words");
/// Both: the bounds words (module docs).
pub const SLOT_BOUNDS: BindSlot = BindSlot::new(0, 2, "bounds");
/// TPS: the centres and weights, 8 f32 each.
pub const SLOT_TPS_CENTRES: BindSlot = BindSlot::new(0, 3, "centres");
/// B-spline: [`BSplineUniforms`].
pub const SLOT_LATTICES: BindSlot = BindSlot::new(0, 4, "bs");
/// B-spline: the coefficients of every lattice.
pub const SLOT_COEFFICIENTS: BindSlot = BindSlot::new(0, 5, "coefficients");

pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "control_eval",
    shader: SHADER,
    uniform_structs: &[
        layout!(ControlEvalUniforms {
            dims,
            row_stride_texels,
            first_local,
            store_f16,
            pitch_mm,
            count,
            offset_mm,
            linear_minus_identity
        }),
        layout!(LatticeUniforms { first_cell, coef_offset, cell_step, cells }),
        layout!(BSplineUniforms { lattices }),
    ],
    slots: &[SLOT_UNIFORMS, SLOT_OUTPUT, SLOT_BOUNDS, SLOT_TPS_CENTRES, SLOT_LATTICES, SLOT_COEFFICIENTS],
    constants: &[],
};

/// Largest control grid per axis (the solver's `control::MAX_TEXELS`).
pub const MAX_CONTROL_TEXELS: usize = 256;
/// Largest TPS accepted. The solver fits at most 5 000 landmarks; this leaves room for merged or synthetic warps while
/// one 64³ dispatch stays below 10¹⁰ kernel evaluations (minutes on lavapipe, milliseconds on a desktop GPU).
pub const MAX_TPS_CENTRES: usize = 1 << 15;
/// Most lattices of one [`BSplineDesc`] (a uniform array in the shader; the solver passes one).
pub const MAX_LATTICES: usize = 8;
/// `@workgroup_size` of both entry points.
const WORKGROUP: [u32; 3] = [8, 8, 1];
/// u32 words of the bounds buffer: min xyz, max xyz (ordered), f16 rounding error (f32 bits), non-finite flag.
const BOUNDS_WORDS: usize = 8;
const BOUNDS_BYTES: u64 = (BOUNDS_WORDS * 4) as u64;

/// Uniforms of both entry points: `ControlEvalUniforms` in shaders/control_eval.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ControlEvalUniforms {
    pub dims: [u32; 3],
    /// Texels per row of the staging buffer (rows padded to 256 bytes).
    pub row_stride_texels: u32,
    /// TPS: centre of texel (0, 0, 0) minus the origin o, mm.
    pub first_local: [f32; 3],
    /// 1: store f16 halves (`Rgba16Float`), 0: f32.
    pub store_f16: u32,
    pub pitch_mm: [f32; 3],
    /// TPS: centres; B-spline: lattices.
    pub count: u32,
    /// TPS: A o + b − o, mm.
    pub offset_mm: [f32; 3],
    _pad0: u32,
    /// TPS: A − I, column-major as WGSL's `mat3x3<f32>` (each column padded to 4 floats).
    pub linear_minus_identity: [[f32; 4]; 3],
}
const _: () = assert!(std::mem::size_of::<ControlEvalUniforms>() == 112);

/// One lattice of [`BSplineUniforms`]: `LatticeUniforms` in shaders/control_eval.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct LatticeUniforms {
    /// Cell units u = (x − Ω.min)/h at the centre of texel (0, 0, 0).
    pub first_cell: [f32; 3],
    /// Index of the lattice's first coefficient in the coefficient buffer.
    pub coef_offset: u32,
    /// u per texel: pitch / h.
    pub cell_step: [f32; 3],
    _pad0: u32,
    pub cells: [u32; 3],
    _pad1: u32,
}
const _: () = assert!(std::mem::size_of::<LatticeUniforms>() == 48);

/// The lattices of a B-spline evaluation: `BSplineUniforms` in shaders/control_eval.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct BSplineUniforms {
    pub lattices: [LatticeUniforms; MAX_LATTICES],
}
const _: () = assert!(std::mem::size_of::<BSplineUniforms>() == 48 * MAX_LATTICES);

/// The control grid to evaluate: `dims` texels over the box [min, max] of ref space, texel (a, b, c) centred at
/// min + ((a, b, c) + ½)·(max − min)/dims (the solver's `ControlGrid`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlGridDesc {
    pub dims: [usize; 3],
    pub box_min_ref: [f64; 3],
    pub box_max_ref: [f64; 3],
}

impl ControlGridDesc {
    /// An n³ grid over [min, max].
    #[must_use]
    pub fn cube(n: usize, box_min_ref: [f64; 3], box_max_ref: [f64; 3]) -> Self {
        Self { dims: [n; 3], box_min_ref, box_max_ref }
    }

    /// Texel pitch per axis, mm.
    #[must_use]
    pub fn pitch_mm(&self) -> DVec3 {
        (DVec3::from_array(self.box_max_ref) - DVec3::from_array(self.box_min_ref))
            / DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64)
    }

    /// The ref position of texel (a, b, c)'s centre.
    #[must_use]
    pub fn texel_centre(&self, abc: [usize; 3]) -> DVec3 {
        let f = DVec3::new(abc[0] as f64, abc[1] as f64, abc[2] as f64) + DVec3::splat(0.5);
        DVec3::from_array(self.box_min_ref) + f * self.pitch_mm()
    }

    /// Checks dims (1..=[`MAX_CONTROL_TEXELS`] and the device's 3-D texture limit) and the box.
    pub fn validate(&self, limits: &wgpu::Limits) -> Result<()> {
        let most = MAX_CONTROL_TEXELS.min(limits.max_texture_dimension_3d as usize);
        if self.dims.iter().any(|&n| n == 0 || n > most) {
            return Err(GpuError::InvalidInput(format!(
                "control grid dims {:?}: each axis needs 1 to {most} texels",
                self.dims
            )));
        }
        let (min, max) = (DVec3::from_array(self.box_min_ref), DVec3::from_array(self.box_max_ref));
        if !min.is_finite() || !max.is_finite() || (max - min).min_element() <= 0.0 {
            return Err(GpuError::InvalidInput(format!("control grid box {min} .. {max} is empty or not finite")));
        }
        Ok(())
    }

    /// Ref mm → \[0, 1\]³ control-texture coordinates (as [`crate::PreparedControl::prepare`] computes it).
    fn ctrl_tex_from_ref(&self) -> Mat4 {
        let min = DVec3::from_array(self.box_min_ref);
        let scale = (DVec3::from_array(self.box_max_ref) - min).recip();
        Mat4::from_scale_rotation_translation(scale.as_vec3(), glam::Quat::IDENTITY, (-min * scale).as_vec3())
    }

    fn info(&self, disp_min_mm: Vec3, disp_max_mm: Vec3, quantisation_mm: f32) -> ControlInfo {
        ControlInfo {
            dims: self.dims.map(|d| d as u32),
            ctrl_tex_from_ref: self.ctrl_tex_from_ref(),
            box_min_ref: DVec3::from_array(self.box_min_ref),
            box_max_ref: DVec3::from_array(self.box_max_ref),
            quantisation_mm,
            disp_min_mm,
            disp_max_mm,
        }
    }
}

/// A control texture whose commands are recorded (and, once the caller submits them, running) but whose
/// displacement bounds are not read back yet. [`Self::resolve`] gives the [`GpuControlTexture`].
#[derive(Debug)]
pub struct PendingControl {
    grid: ControlGridDesc,
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    /// 32 bytes, `MAP_READ`: the bounds words (see the module docs).
    bounds: wgpu::Buffer,
}

impl PendingControl {
    /// The texture being written (its values are valid once the recorded commands have run).
    #[must_use]
    pub fn texture(&self) -> &wgpu::Texture {
        &self.texture
    }

    /// The texture and its view without bounds, for callers that bound the displacement otherwise (the benchmark
    /// re-evaluates one warp, whose bounds it already knows). The texture is a valid `target` for the next evaluation.
    #[must_use]
    pub fn into_texture(self) -> (wgpu::Texture, wgpu::TextureView) {
        (self.texture, self.view)
    }

    /// Waits for the GPU, reads the bounds back (32 bytes) and returns the texture with its complete
    /// [`ControlInfo`]. Call it after submitting the encoder the work was recorded into. Fails when a displacement was
    /// not finite (or beyond the f16 range when storing halves).
    pub fn resolve(self, ctx: &GpuContext) -> Result<GpuControlTexture> {
        let words: Vec<u32> = ctx.map_read(&self.bounds, self.bounds.size(), bytemuck::pod_collect_to_vec)?;
        if words[7] != 0 {
            return Err(GpuError::InvalidInput(
                "the pull-back's displacement is not finite (or beyond the f16 range of the control texture) at some \
                 texel"
                    .into(),
            ));
        }
        let disp_min_mm = Vec3::new(from_ordered(words[0]), from_ordered(words[1]), from_ordered(words[2]));
        let disp_max_mm = Vec3::new(from_ordered(words[3]), from_ordered(words[4]), from_ordered(words[5]));
        let quantisation_mm = f32::from_bits(words[6]);
        let info = self.grid.info(disp_min_mm, disp_max_mm, quantisation_mm);
        Ok(GpuControlTexture { info, texture: self.texture, view: self.view })
    }
}

/// The inverse of the shader's `ordered` map.
fn from_ordered(u: u32) -> f32 {
    if u & 0x8000_0000 == 0 { f32::from_bits(!u) } else { f32::from_bits(u & 0x7fff_ffff) }
}

/// The texels of a control texture as `[dx, dy, dz, 0]` f32, x fastest (f16 texels widened). Waits for the GPU.
pub fn read_back_texels(ctx: &GpuContext, control: &GpuControlTexture) -> Result<Vec<[f32; 4]>> {
    let dims = control.info.dims;
    match control.texture.format() {
        wgpu::TextureFormat::Rgba32Float => {
            Ok(bytemuck::pod_collect_to_vec(&ctx.read_texture(&control.texture, dims, 16)?))
        }
        wgpu::TextureFormat::Rgba16Float => {
            let halves: Vec<u16> = bytemuck::pod_collect_to_vec(&ctx.read_texture(&control.texture, dims, 8)?);
            Ok(halves.chunks_exact(4).map(|h| std::array::from_fn(|i| f16::from_bits(h[i]).to_f32())).collect())
        }
        other => Err(GpuError::InvalidInput(format!("{other:?} is not a control texture format"))),
    }
}

/// The whole of `buffer` in `slot`.
fn bind(slot: BindSlot, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    slot.entry(buffer.as_entire_binding())
}

/// Which entry point, and the buffers of its own slots.
enum Kind<'a> {
    /// [`SLOT_TPS_CENTRES`].
    Tps(&'a wgpu::Buffer),
    /// [`SLOT_LATTICES`] and [`SLOT_COEFFICIENTS`].
    BSpline(&'a wgpu::Buffer, &'a wgpu::Buffer),
}

/// The long-lived part of GPU control-texture evaluation: the two compute pipelines, their bind group layouts and a
/// reusable staging buffer.
#[derive(Debug)]
pub struct ControlEvalPass {
    tps: (wgpu::ComputePipeline, wgpu::BindGroupLayout),
    bspline: (wgpu::ComputePipeline, wgpu::BindGroupLayout),
    /// The output staging buffer (`STORAGE | COPY_SRC`), grown on demand. Commands that use it are ordered within a
    /// queue, so one buffer serves every evaluation.
    staging: Mutex<Option<wgpu::Buffer>>,
}

impl ControlEvalPass {
    /// Storage buffers per compute stage and invocations per workgroup the pass needs.
    pub const STORAGE_BUFFERS: u32 = 3;
    pub const INVOCATIONS: u32 = WORKGROUP[0] * WORKGROUP[1] * WORKGROUP[2];

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        let workgroup_bytes = 2 * Self::INVOCATIONS * 16;
        if l.max_storage_buffers_per_shader_stage < Self::STORAGE_BUFFERS
            || l.max_compute_invocations_per_workgroup < Self::INVOCATIONS
            || l.max_compute_workgroup_size_x < WORKGROUP[0]
            || l.max_compute_workgroup_size_y < WORKGROUP[1]
            || l.max_compute_workgroup_storage_size < workgroup_bytes
        {
            return Err(GpuError::Unsupported(format!(
                "control-texture evaluation needs compute with {} storage buffers, {} invocations per workgroup and \
                 {workgroup_bytes} bytes of workgroup memory (limits: {} storage buffers, {} invocations, {} bytes)",
                Self::STORAGE_BUFFERS,
                Self::INVOCATIONS,
                l.max_storage_buffers_per_shader_stage,
                l.max_compute_invocations_per_workgroup,
                l.max_compute_workgroup_storage_size
            )));
        }
        let device = &ctx.device;
        let module = SHADER.create_module(device);
        let common = [
            binding(SLOT_UNIFORMS, uniform::<ControlEvalUniforms>()),
            binding(SLOT_OUTPUT, storage(false, Some(4))),
            binding(SLOT_BOUNDS, storage(false, Some(BOUNDS_BYTES))),
        ];
        let make = |entry_point: &str, extra: &[wgpu::BindGroupLayoutEntry]| {
            let entries: Vec<_> = common.iter().chain(extra).copied().collect();
            let layout = compute::layout(device, entry_point, &entries);
            (compute::pipeline(device, entry_point, &module, Some(entry_point), &[&layout]), layout)
        };
        let tps = make(TPS_ENTRY_POINT, &[binding(SLOT_TPS_CENTRES, storage(true, Some(32)))]);
        let bspline = make(
            BSPLINE_ENTRY_POINT,
            &[binding(SLOT_LATTICES, uniform::<BSplineUniforms>()), binding(SLOT_COEFFICIENTS, storage(true, Some(4)))],
        );
        ctx.check_errors()?;
        Ok(Self { tps, bspline, staging: Mutex::new(None) })
    }

    /// Evaluates the TPS pull-back `tps` on `grid` and returns the control texture with its bounds read back
    /// (submits and waits). `target` is reused when its dims and format match (else it is dropped).
    pub fn evaluate_tps(
        &self,
        ctx: &GpuContext,
        tps: &TpsDesc<'_>,
        grid: &ControlGridDesc,
        target: Option<GpuControlTexture>,
    ) -> Result<GpuControlTexture> {
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("control eval (TPS)") });
        let pending = self.encode_tps(ctx, &mut encoder, tps, grid, target)?;
        ctx.queue.submit([encoder.finish()]);
        pending.resolve(ctx)
    }

    /// As [`Self::evaluate_tps`] for a hierarchical B-spline pull-back.
    pub fn evaluate_bspline(
        &self,
        ctx: &GpuContext,
        bspline: &BSplineDesc<'_>,
        grid: &ControlGridDesc,
        target: Option<GpuControlTexture>,
    ) -> Result<GpuControlTexture> {
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("control eval (B-spline)") });
        let pending = self.encode_bspline(ctx, &mut encoder, bspline, grid, target)?;
        ctx.queue.submit([encoder.finish()]);
        pending.resolve(ctx)
    }

    /// Records the TPS evaluation into `encoder` (the caller submits it, then calls [`PendingControl::resolve`]).
    /// Checks the input first: lengths, finiteness, at most [`MAX_TPS_CENTRES`] centres, a valid grid.
    pub fn encode_tps(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        tps: &TpsDesc<'_>,
        grid: &ControlGridDesc,
        target: Option<GpuControlTexture>,
    ) -> Result<PendingControl> {
        let n = tps.centres_ref.len();
        if n > MAX_TPS_CENTRES {
            return Err(GpuError::InvalidInput(format!(
                "a TPS of {n} centres; at most {MAX_TPS_CENTRES} are evaluated"
            )));
        }
        tps.validate()?;
        grid.validate(&ctx.limits)?;
        let centre_bytes = 32 * n.max(1) as u64;
        if centre_bytes > ctx.limits.max_storage_buffer_binding_size {
            return Err(GpuError::Unsupported(format!(
                "{n} TPS centres need a {centre_bytes}-byte storage buffer; the device binds at most {}",
                ctx.limits.max_storage_buffer_binding_size
            )));
        }
        let origin = 0.5 * (DVec3::from_array(grid.box_min_ref) + DVec3::from_array(grid.box_max_ref));
        let local = tps.local(origin.to_array());
        let first_local = (DVec3::from_array(grid.box_min_ref) + 0.5 * grid.pitch_mm() - origin).as_vec3();
        let l = local.linear_minus_identity;
        let mut uniforms = ControlEvalUniforms {
            count: n as u32,
            first_local: first_local.to_array(),
            offset_mm: local.offset_mm,
            linear_minus_identity: std::array::from_fn(|c| [l[0][c], l[1][c], l[2][c], 0.0]),
            ..Zeroable::zeroed()
        };
        let mut centres: Vec<[f32; 8]> = local
            .centres_local
            .iter()
            .zip(&local.weights)
            .map(|(p, w)| [p[0], p[1], p[2], 0.0, w[0], w[1], w[2], 0.0])
            .collect();
        let f32_finite = centres
            .iter()
            .flatten()
            .chain(uniforms.linear_minus_identity.iter().flatten())
            .chain(&uniforms.offset_mm)
            .all(|v| v.is_finite());
        if !f32_finite {
            return Err(GpuError::InvalidInput("the TPS's weights or affine part overflow f32".into()));
        }
        if centres.is_empty() {
            centres.push([0.0; 8]); // a binding cannot be empty; `count` is 0
        }
        let centres = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("control eval: TPS centres"),
            contents: bytemuck::cast_slice(&centres),
            usage: wgpu::BufferUsages::STORAGE,
        });
        self.encode(ctx, encoder, &mut uniforms, &Kind::Tps(&centres), grid, target)
    }

    /// Records the B-spline evaluation into `encoder` (see [`Self::encode_tps`]). Checks the input first: at most
    /// [`MAX_LATTICES`] lattices, each valid ([`crate::pullback::LatticeDesc::validate`]), a valid grid.
    pub fn encode_bspline(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        bspline: &BSplineDesc<'_>,
        grid: &ControlGridDesc,
        target: Option<GpuControlTexture>,
    ) -> Result<PendingControl> {
        if bspline.lattices.len() > MAX_LATTICES {
            return Err(GpuError::InvalidInput(format!(
                "a B-spline of {} lattices; at most {MAX_LATTICES} are evaluated (refine levels onto one lattice)",
                bspline.lattices.len()
            )));
        }
        bspline.validate()?;
        grid.validate(&ctx.limits)?;
        let total: usize = bspline.lattices.iter().map(|l| l.coefficients.len()).sum();
        if 4 * total.max(1) as u64 > ctx.limits.max_storage_buffer_binding_size {
            return Err(GpuError::Unsupported(format!(
                "{total} B-spline coefficients exceed the device's storage binding of {} bytes",
                ctx.limits.max_storage_buffer_binding_size
            )));
        }
        let mut coefficients: Vec<f32> = Vec::with_capacity(total.max(1));
        let mut lattices = BSplineUniforms::zeroed();
        let first_centre = DVec3::from_array(grid.box_min_ref) + 0.5 * grid.pitch_mm();
        for (desc, uniforms) in bspline.lattices.iter().zip(&mut lattices.lattices) {
            let min = DVec3::from_array(desc.min_mm);
            let cells = DVec3::new(desc.cells[0] as f64, desc.cells[1] as f64, desc.cells[2] as f64);
            let h = (DVec3::from_array(desc.max_mm) - min) / cells;
            *uniforms = LatticeUniforms {
                first_cell: ((first_centre - min) / h).as_vec3().to_array(),
                coef_offset: coefficients.len() as u32,
                cell_step: (grid.pitch_mm() / h).as_vec3().to_array(),
                cells: desc.cells.map(|c| c as u32),
                ..Zeroable::zeroed()
            };
            coefficients.extend(desc.coefficients.iter().map(|&c| c as f32));
        }
        if !coefficients.iter().all(|c| c.is_finite())
            || !lattices.lattices.iter().all(|l| l.first_cell.iter().chain(&l.cell_step).all(|v| v.is_finite()))
        {
            return Err(GpuError::InvalidInput("the B-spline's coefficients or geometry overflow f32".into()));
        }
        if coefficients.is_empty() {
            coefficients.push(0.0); // a binding cannot be empty; `count` is 0
        }
        let lattice_buffer = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("control eval: lattices"),
            contents: bytemuck::bytes_of(&lattices),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let coefficient_buffer = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("control eval: coefficients"),
            contents: bytemuck::cast_slice(&coefficients),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mut uniforms = ControlEvalUniforms { count: bspline.lattices.len() as u32, ..Zeroable::zeroed() };
        self.encode(ctx, encoder, &mut uniforms, &Kind::BSpline(&lattice_buffer, &coefficient_buffer), grid, target)
    }

    /// The staging buffer, at least `size` bytes.
    fn staging(&self, ctx: &GpuContext, size: u64) -> wgpu::Buffer {
        let mut pool = self.staging.lock().unwrap_or_else(PoisonError::into_inner);
        match pool.as_ref() {
            Some(buffer) if buffer.size() >= size => buffer.clone(),
            _ => {
                let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("control eval: staging"),
                    size,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                });
                *pool = Some(buffer.clone());
                buffer
            }
        }
    }

    /// The shared part: output layout, target texture, bounds buffers, the dispatch and the copies.
    fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        uniforms: &mut ControlEvalUniforms,
        kind: &Kind<'_>,
        grid: &ControlGridDesc,
        target: Option<GpuControlTexture>,
    ) -> Result<PendingControl> {
        let (format, texel_bytes) = if ctx.capabilities.float32_filterable {
            (wgpu::TextureFormat::Rgba32Float, 16u32)
        } else {
            (wgpu::TextureFormat::Rgba16Float, 8u32)
        };
        let [nx, ny, nz] = grid.dims.map(|d| d as u32);
        let row_bytes =
            (nx * texel_bytes).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let staging_bytes = u64::from(row_bytes) * u64::from(ny) * u64::from(nz);
        let most = ctx.limits.max_storage_buffer_binding_size.min(ctx.limits.max_buffer_size);
        if staging_bytes > most {
            return Err(GpuError::Unsupported(format!(
                "a {:?} control grid needs a {staging_bytes}-byte staging buffer; the device binds at most {most}",
                grid.dims
            )));
        }
        uniforms.dims = [nx, ny, nz];
        uniforms.row_stride_texels = row_bytes / texel_bytes;
        uniforms.store_f16 = u32::from(format == wgpu::TextureFormat::Rgba16Float);
        uniforms.pitch_mm = grid.pitch_mm().as_vec3().to_array();

        let size = wgpu::Extent3d { width: nx, height: ny, depth_or_array_layers: nz };
        let reusable = |t: &GpuControlTexture| {
            t.texture.size() == size
                && t.texture.format() == format
                && t.texture.dimension() == wgpu::TextureDimension::D3
                && t.texture.usage().contains(wgpu::TextureUsages::COPY_DST)
        };
        let (texture, view) = match target {
            Some(t) if reusable(&t) => (t.texture, t.view),
            _ => {
                let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("control texture (evaluated)"),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D3,
                    format,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING
                        | wgpu::TextureUsages::COPY_DST
                        | wgpu::TextureUsages::COPY_SRC,
                    view_formats: &[],
                });
                let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
                (texture, view)
            }
        };

        let staging = self.staging(ctx, staging_bytes);
        let uniform_buffer = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("control eval: uniforms"),
            contents: bytemuck::bytes_of(uniforms),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        // min = +∞ and max = −∞ in the ordered encoding: all ones and all zeros.
        let initial: [u32; BOUNDS_WORDS] = [u32::MAX, u32::MAX, u32::MAX, 0, 0, 0, 0, 0];
        let bounds = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("control eval: bounds"),
            contents: bytemuck::cast_slice(&initial),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        });
        let bounds_readback = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("control eval: bounds readback"),
            size: BOUNDS_BYTES,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let mut entries =
            vec![bind(SLOT_UNIFORMS, &uniform_buffer), bind(SLOT_OUTPUT, &staging), bind(SLOT_BOUNDS, &bounds)];
        let (pipeline, layout) = match kind {
            Kind::Tps(centres) => {
                entries.push(bind(SLOT_TPS_CENTRES, centres));
                &self.tps
            }
            Kind::BSpline(lattices, coefficients) => {
                entries.extend([bind(SLOT_LATTICES, lattices), bind(SLOT_COEFFICIENTS, coefficients)]);
                &self.bspline
            }
        };
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("control eval"),
            layout,
            entries: &entries,
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("control eval"),
                timestamp_writes: None,
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(nx.div_ceil(WORKGROUP[0]), ny.div_ceil(WORKGROUP[1]), nz.div_ceil(WORKGROUP[2]));
        }
        encoder.copy_buffer_to_texture(
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_bytes),
                    rows_per_image: Some(ny),
                },
            },
            texture.as_image_copy(),
            size,
        );
        encoder.copy_buffer_to_buffer(&bounds, 0, &bounds_readback, 0, BOUNDS_BYTES);
        Ok(PendingControl { grid: *grid, texture, view, bounds: bounds_readback })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shader's `ordered` map, for the round trip.
    fn ordered(x: f32) -> u32 {
        let bits = x.to_bits();
        if bits & 0x8000_0000 == 0 { bits | 0x8000_0000 } else { !bits }
    }

    #[test]
    fn ordered_encoding_preserves_order_and_round_trips() {
        let values = [f32::NEG_INFINITY, -3.0e38, -12.5, -1e-30, -0.0, 0.0, 1e-30, 0.25, 7.0, 3.0e38, f32::INFINITY];
        for pair in values.windows(2) {
            assert!(ordered(pair[0]) <= ordered(pair[1]), "{pair:?}");
        }
        for v in values {
            assert_eq!(from_ordered(ordered(v)).to_bits(), v.to_bits());
        }
        // The initial words of the bounds buffer are the extremes of the encoding.
        assert!(values.iter().all(|&v| ordered(v) < u32::MAX && ordered(v) > 0));
    }

    #[test]
    fn grid_centres_follow_the_texel_centre_convention() {
        let grid =
            ControlGridDesc { dims: [4, 2, 5], box_min_ref: [-10.0, 0.0, 100.0], box_max_ref: [10.0, 8.0, 150.0] };
        assert_eq!(grid.texel_centre([0, 0, 0]), DVec3::new(-7.5, 2.0, 105.0));
        let t = grid.ctrl_tex_from_ref().transform_point3(grid.texel_centre([3, 1, 4]).as_vec3());
        assert!((t - Vec3::new(7.0 / 8.0, 0.75, 0.9)).abs().max_element() < 1e-6, "{t}");
        let limits = wgpu::Limits::default();
        grid.validate(&limits).expect("valid grid");
        assert!(ControlGridDesc { dims: [0, 2, 5], ..grid }.validate(&limits).is_err());
        assert!(ControlGridDesc { dims: [4, 2, MAX_CONTROL_TEXELS + 1], ..grid }.validate(&limits).is_err());
        assert!(ControlGridDesc { box_max_ref: [10.0, f64::NAN, 150.0], ..grid }.validate(&limits).is_err());
        assert!(ControlGridDesc { box_max_ref: [-10.0, 8.0, 150.0], ..grid }.validate(&limits).is_err());
    }
}
