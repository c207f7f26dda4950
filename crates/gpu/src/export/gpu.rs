//! The GPU path of the export: [`ExportPass`] (the long-lived shader module, layout and specialised pipelines) runs
//! `shaders/export.wgsl` over the target one z-slab at a time.
//!
//! # Data in its own type, both ways
//!
//! The source is uploaded once, in its own type: u8 → `R8Uint`, i8 → `R8Sint`, u16 → `R16Uint`, i16 → `R16Sint`,
//! u32 → `R32Uint`, i32 → `R32Sint`, f32 → `R32Float` (f64 samples, which the GPU path takes only when every one is
//! exact in f32, as `R32Float`: the one type converted on the way). The shader reads it with `textureLoad` and
//! converts each tap to f32, which is exact for every accepted sample, so the interpolation is the f32 arithmetic
//! of the CPU path (hardware filtering, with its 8-bit weights on many GPUs, is never used; integer textures cannot
//! be filtered anyway). The volume is cut into pieces of about a MiB, each copied into a staging buffer of its own
//! on rayon's pool, and the pieces' copies to the texture are submitted a few tens of MiB at a time, so the GPU
//! copies one chunk while the next is filled.
//!
//! The shader also rounds and clamps into the output's type (WGSL's `round` is half to even, as the CPU's
//! conversion) and packs 8- and 16-bit outputs four and two to a 32-bit word (one voxel per invocation, packed
//! through workgroup memory), so a slab's readback holds exactly the output's bytes, which the host copies into
//! place on rayon's pool without converting them (f64 outputs, read as f32, are widened). The outside value is
//! rounded and clamped on the host, once, by the CPU path's conversion.
//!
//! # Slabs in flight
//!
//! Up to [`ExportPass::SLABS_IN_FLIGHT`] slabs are queued at once, each with its own storage buffer and readback
//! buffer: while slab k is mapped and copied out, slab k + 1 is computed and copied to its readback buffer. The host
//! waits for slab k's own submission ([`wgpu::PollType::Wait`] with its index and a timeout), never for all work on
//! the device, and never on a callback that no poll drives: every wait is a poll with a deadline
//! ([`ExportPass::SLAB_WAIT_LIMIT`]) after which the slab is reported as stalled. A cancelled export first lets the
//! slabs still in flight arrive and unmaps them, so nothing is left mapped; a pending map is never aborted with
//! `unmap`, which races with another thread's poll of a shared device (see `Ring`).
//!
//! Nothing needs an optional feature: this runs on lavapipe, on GL and on real GPUs.

use std::collections::VecDeque;
use std::mem::MaybeUninit;
use std::sync::mpsc::{Receiver, TryRecvError};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;

use super::plan::{Plan, PlanPullBack, report};
use super::request::{ExportRequest, ExportedSamples, ExportedVolume, Interpolation, Progress, SampleType};
use super::sample::{Sample, try_reserved, with_samples};
use crate::compute::{self, binding, storage, uniform};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, WgslConstant, layout};

/// `shaders/export.wgsl`: `cs_export`, one z-slab of the target per dispatch.
pub const SHADER: ShaderSource = ShaderSource {
    name: "export",
    path: "shaders/export.wgsl",
    source: include_str!("../../../../shaders/export.wgsl"),
    entry_points: &[("cs_export", Stage::Compute)],
};

pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "u");
/// The source volume when its texels are floats (f32, and f64 as f32); a placeholder otherwise.
pub const SLOT_SOURCE_FLOAT: BindSlot = BindSlot::new(0, 1, "source_float");
/// The control texture (a placeholder for the other pull-backs).
pub const SLOT_CONTROL: BindSlot = BindSlot::new(0, 2, "control");
/// The TPS's centres and weights (a placeholder for the other pull-backs).
pub const SLOT_TPS_TERMS: BindSlot = BindSlot::new(0, 3, "tps_terms");
/// One slab of the output, packed.
pub const SLOT_SLAB: BindSlot = BindSlot::new(0, 4, "slab");
/// The source volume when its samples are signed integers; a placeholder otherwise.
pub const SLOT_SOURCE_SINT: BindSlot = BindSlot::new(0, 5, "source_sint");
/// The source volume when its samples are unsigned integers; a placeholder otherwise.
pub const SLOT_SOURCE_UINT: BindSlot = BindSlot::new(0, 6, "source_uint");

pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "export",
    shader: SHADER,
    uniform_structs: &[layout!(ExportUniforms {
        source_index_from_target_index,
        pullback_from_target_index,
        source_index_from_lps,
        tps_row0,
        tps_row1,
        tps_row2,
        target_dims,
        slab_first_slice,
        source_dims,
        slab_voxels,
        control_dims,
        centre_count,
        outside_stored,
        invocations_per_row
    })],
    slots: &[
        SLOT_UNIFORMS,
        SLOT_SOURCE_FLOAT,
        SLOT_CONTROL,
        SLOT_TPS_TERMS,
        SLOT_SLAB,
        SLOT_SOURCE_SINT,
        SLOT_SOURCE_UINT,
    ],
    constants: &[
        WgslConstant::u32("PULLBACK_IDENTITY", PullBackKind::Identity.code()),
        WgslConstant::u32("PULLBACK_CONTROL", PullBackKind::Control.code()),
        WgslConstant::u32("PULLBACK_TPS", PullBackKind::Tps.code()),
        WgslConstant::u32("INTERPOLATION_NEAREST", interpolation_code(Interpolation::Nearest)),
        WgslConstant::u32("INTERPOLATION_TRILINEAR", interpolation_code(Interpolation::Trilinear)),
        WgslConstant::u32("INTERPOLATION_CATMULL_ROM", interpolation_code(Interpolation::CatmullRom)),
        WgslConstant::u32("SOURCE_FLOAT", SourceTexels::Float.code()),
        WgslConstant::u32("SOURCE_SINT", SourceTexels::Sint.code()),
        WgslConstant::u32("SOURCE_UINT", SourceTexels::Uint.code()),
        WgslConstant::u32("OUTPUT_F32", Stored::F32.code()),
        WgslConstant::u32("OUTPUT_U8", Stored::U8.code()),
        WgslConstant::u32("OUTPUT_I8", Stored::I8.code()),
        WgslConstant::u32("OUTPUT_U16", Stored::U16.code()),
        WgslConstant::u32("OUTPUT_I16", Stored::I16.code()),
        WgslConstant::u32("OUTPUT_U32", Stored::U32.code()),
        WgslConstant::u32("OUTPUT_I32", Stored::I32.code()),
    ],
};

/// `@workgroup_size` of `cs_export` (x; y and z are 1).
const WORKGROUP: u32 = 64;
/// Staging bytes filled per upload submission (whole source slices, at least one).
const UPLOAD_CHUNK_BYTES: u64 = 32 << 20;
/// Bytes one rayon task copies (uploads and readbacks).
const COPY_GRAIN_BYTES: usize = 1 << 20;
/// The longest single poll of a slab wait; the wait polls again until its deadline.
const POLL_STEP: Duration = Duration::from_millis(500);

/// The export's uniforms: `ExportUniforms` in shaders/export.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ExportUniforms {
    /// Columns of S (see [`crate::export`]).
    pub source_index_from_target_index: [[f32; 4]; 4],
    /// Columns: control-texel index (control texture) or local mm (TPS) from target index.
    pub pullback_from_target_index: [[f32; 4]; 4],
    /// Columns 0..2: mm → source voxels.
    pub source_index_from_lps: [[f32; 4]; 4],
    /// Rows of (A − I | A o + b − o).
    pub tps_row0: [f32; 4],
    pub tps_row1: [f32; 4],
    pub tps_row2: [f32; 4],
    pub target_dims: [u32; 3],
    pub slab_first_slice: u32,
    pub source_dims: [u32; 3],
    /// Target voxels in this slab.
    pub slab_voxels: u32,
    pub control_dims: [u32; 3],
    pub centre_count: u32,
    /// The outside value as the output stores it (rounded and clamped on the host), in the low bits.
    pub outside_stored: u32,
    /// Invocations along x of the dispatch (voxel = id.x + id.y · this), a multiple of the workgroup size.
    pub invocations_per_row: u32,
    _pad0: u32,
    _pad1: u32,
}
const _: () = assert!(std::mem::size_of::<ExportUniforms>() == 304);

/// The pull-back's kind, as the WGSL override `PULLBACK` specialises on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PullBackKind {
    Identity,
    Control,
    Tps,
}

impl PullBackKind {
    fn of(pullback: &PlanPullBack) -> Self {
        match pullback {
            PlanPullBack::Identity => Self::Identity,
            PlanPullBack::Control { .. } => Self::Control,
            PlanPullBack::Tps(_) => Self::Tps,
        }
    }

    /// `PULLBACK_*` in shaders/export.wgsl.
    const fn code(self) -> u32 {
        match self {
            Self::Identity => 0,
            Self::Control => 1,
            Self::Tps => 2,
        }
    }
}

/// `INTERPOLATION_*` in shaders/export.wgsl (the WGSL override `INTERPOLATION`).
const fn interpolation_code(interpolation: Interpolation) -> u32 {
    match interpolation {
        Interpolation::Nearest => 0,
        Interpolation::Trilinear => 1,
        Interpolation::CatmullRom => 2,
    }
}

/// How the source's texels are read: which binding holds the volume (the WGSL override `SOURCE`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SourceTexels {
    /// `texture_3d<f32>`: f32 samples, and f64 samples written as f32.
    Float,
    /// `texture_3d<i32>`: i8, i16, i32.
    Sint,
    /// `texture_3d<u32>`: u8, u16, u32.
    Uint,
}

impl SourceTexels {
    /// The texture format of `samples` and how the shader reads it.
    fn of(samples: SampleType) -> (wgpu::TextureFormat, Self) {
        use wgpu::TextureFormat as F;
        match samples {
            SampleType::U8 => (F::R8Uint, Self::Uint),
            SampleType::I8 => (F::R8Sint, Self::Sint),
            SampleType::U16 => (F::R16Uint, Self::Uint),
            SampleType::I16 => (F::R16Sint, Self::Sint),
            SampleType::U32 => (F::R32Uint, Self::Uint),
            SampleType::I32 => (F::R32Sint, Self::Sint),
            SampleType::F32 | SampleType::F64 => (F::R32Float, Self::Float),
        }
    }

    /// `SOURCE_*` in shaders/export.wgsl.
    const fn code(self) -> u32 {
        match self {
            Self::Float => 0,
            Self::Sint => 1,
            Self::Uint => 2,
        }
    }

    /// The binding type of a texture of this kind, read with `textureLoad`.
    fn binding_type(self) -> wgpu::BindingType {
        let sample_type = match self {
            Self::Float => wgpu::TextureSampleType::Float { filterable: false },
            Self::Sint => wgpu::TextureSampleType::Sint,
            Self::Uint => wgpu::TextureSampleType::Uint,
        };
        wgpu::BindingType::Texture { sample_type, view_dimension: wgpu::TextureViewDimension::D3, multisampled: false }
    }

    /// The format of this kind's 1×1×1 placeholder.
    fn placeholder_format(self) -> wgpu::TextureFormat {
        match self {
            Self::Float => wgpu::TextureFormat::R32Float,
            Self::Sint => wgpu::TextureFormat::R32Sint,
            Self::Uint => wgpu::TextureFormat::R32Uint,
        }
    }
}

/// How the output's samples are stored in a slab's 32-bit words (the WGSL override `OUTPUT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stored {
    /// One f32 per word: f32 outputs, and f64 outputs (widened on the host).
    F32,
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
}

impl Stored {
    fn of(output: SampleType) -> Self {
        match output {
            SampleType::U8 => Self::U8,
            SampleType::I8 => Self::I8,
            SampleType::U16 => Self::U16,
            SampleType::I16 => Self::I16,
            SampleType::U32 => Self::U32,
            SampleType::I32 => Self::I32,
            SampleType::F32 | SampleType::F64 => Self::F32,
        }
    }

    /// `OUTPUT_*` in shaders/export.wgsl.
    const fn code(self) -> u32 {
        match self {
            Self::F32 => 0,
            Self::U8 => 1,
            Self::I8 => 2,
            Self::U16 => 3,
            Self::I16 => 4,
            Self::U32 => 5,
            Self::I32 => 6,
        }
    }

    /// Bytes of one stored voxel (a word holds 4 / this voxels).
    fn bytes(self) -> u64 {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::F32 | Self::U32 | Self::I32 => 4,
        }
    }
}

/// What a pipeline is specialised on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PipelineKey {
    pullback: PullBackKind,
    interpolation: Interpolation,
    source: SourceTexels,
    stored: Stored,
}

/// The long-lived part of the export: the shader module, the bind group layout, and a pipeline per case (pull-back,
/// kernel, the source's texel type, the output's type), each compiled on first use.
#[derive(Debug)]
pub struct ExportPass {
    module: wgpu::ShaderModule,
    layout: wgpu::BindGroupLayout,
    pipelines: Mutex<Vec<(PipelineKey, wgpu::ComputePipeline)>>,
}

impl ExportPass {
    /// Storage buffers per compute stage and invocations per workgroup the pass needs.
    pub const STORAGE_BUFFERS: u32 = 2;
    pub const INVOCATIONS: u32 = WORKGROUP;
    /// Most bytes of one slab's output (and of its readback copy): 16 slabs for a 512³ i16 output, so that all but
    /// the first slab's compute and the last slab's copy overlap with other work.
    pub const SLAB_BUDGET_BYTES: u64 = 16 << 20;
    /// Most work in one dispatch, in voxel-terms: voxels × (1 + TPS centres). With a TPS of 1000 centres that is one
    /// 512 × 512 slice per slab; it keeps each dispatch short (an operating system may reset a GPU whose dispatch runs
    /// for about two seconds) and each slab's wait bounded.
    pub const WORK_BUDGET: u64 = 1 << 28;
    /// Slabs queued on the GPU at once, each with its own storage and readback buffers.
    pub const SLABS_IN_FLIGHT: usize = 3;
    /// How long the host waits for one slab before it reports the GPU as stalled (a slab is at most
    /// [`Self::WORK_BUDGET`] of work: well under a second on a GPU, seconds on lavapipe).
    pub const SLAB_WAIT_LIMIT: Duration = Duration::from_mins(2);
    /// Largest source accepted, in bytes of its texels.
    pub const MAX_SOURCE_BYTES: u64 = 4 << 30;

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        if l.max_storage_buffers_per_shader_stage < Self::STORAGE_BUFFERS
            || l.max_compute_invocations_per_workgroup < Self::INVOCATIONS
            || l.max_compute_workgroup_size_x < WORKGROUP
        {
            return Err(GpuError::Unsupported(format!(
                "the export needs compute with {} storage buffers and {} invocations per workgroup (limits: {}, {}); \
                 use export_cpu",
                Self::STORAGE_BUFFERS,
                Self::INVOCATIONS,
                l.max_storage_buffers_per_shader_stage,
                l.max_compute_invocations_per_workgroup
            )));
        }
        let device = &ctx.device;
        let module = SHADER.create_module(device);
        let layout = compute::layout(
            device,
            "export",
            &[
                binding(SLOT_UNIFORMS, uniform::<ExportUniforms>()),
                binding(SLOT_SOURCE_FLOAT, SourceTexels::Float.binding_type()),
                binding(SLOT_CONTROL, SourceTexels::Float.binding_type()),
                binding(SLOT_TPS_TERMS, storage(true, None)),
                binding(SLOT_SLAB, storage(false, None)),
                binding(SLOT_SOURCE_SINT, SourceTexels::Sint.binding_type()),
                binding(SLOT_SOURCE_UINT, SourceTexels::Uint.binding_type()),
            ],
        );
        ctx.check_errors()?;
        Ok(Self { module, layout, pipelines: Mutex::new(Vec::new()) })
    }

    /// The pipeline for `key`, compiled on first use.
    fn pipeline(&self, ctx: &GpuContext, key: PipelineKey) -> wgpu::ComputePipeline {
        let mut pipelines = self.pipelines.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((_, p)) = pipelines.iter().find(|(k, _)| *k == key) {
            return p.clone();
        }
        let constants = [
            ("PULLBACK", f64::from(key.pullback.code())),
            ("INTERPOLATION", f64::from(interpolation_code(key.interpolation))),
            ("SOURCE", f64::from(key.source.code())),
            ("OUTPUT", f64::from(key.stored.code())),
        ];
        let entry_point = SHADER.entry_point(Stage::Compute);
        let pipeline =
            compute::pipeline_with(&ctx.device, "export", &self.module, entry_point, &[&self.layout], &constants);
        pipelines.push((key, pipeline.clone()));
        pipeline
    }

    /// Slices per slab on this device for `request`, at most its [`ExportRequest::slab_slices`]: each slab's
    /// stored output fits one storage binding and [`Self::SLAB_BUDGET_BYTES`], and its work [`Self::WORK_BUDGET`]
    /// (one slice at least; see [`crate::export`]).
    pub fn slab_slices(ctx: &GpuContext, request: &ExportRequest<'_>) -> Result<usize> {
        let plan = Plan::new(request)?;
        Self::slab_slices_of(ctx, &plan)
    }

    fn slab_slices_of(ctx: &GpuContext, plan: &Plan) -> Result<usize> {
        let l = &ctx.limits;
        let [nx, ny, nz] = plan.target_dims;
        let slice_voxels = (nx * ny) as u64;
        let slice_bytes = slice_voxels * Stored::of(plan.output).bytes();
        // Whole words. At most 2²⁴ voxels (bytes, for 8-bit outputs) is 2¹⁸ workgroups, well within a 2-D
        // dispatch (65535² workgroups), and every voxel and word index of a slab fits the shader's u32.
        let cap = Self::SLAB_BUDGET_BYTES.min(l.max_storage_buffer_binding_size).min(l.max_buffer_size) / 4 * 4;
        if slice_bytes.next_multiple_of(4) > cap {
            return Err(GpuError::Unsupported(format!(
                "one target slice of {nx}×{ny} is {slice_bytes} bytes of output, above the {cap} bytes one storage \
                 binding holds here; use export_cpu"
            )));
        }
        let centres = match &plan.pullback {
            PlanPullBack::Tps(tps) => tps.centres_local.len() as u64,
            PlanPullBack::Identity | PlanPullBack::Control { .. } => 0,
        };
        let by_bytes = cap / slice_bytes.max(1);
        let by_work = Self::WORK_BUDGET / (slice_voxels * (1 + centres)).max(1);
        let fit = by_bytes.min(by_work).max(1) as usize;
        Ok(plan.slab_slices.unwrap_or(usize::MAX).min(fit).min(nz).max(1))
    }

    /// Resamples `request` on the GPU, calling `progress` after each slab; `false` cancels with
    /// [`GpuError::Cancelled`]. Sources that are not exact in f32 or too large for one texture are
    /// [`GpuError::Unsupported`] (the CPU path, [`crate::export::export_cpu`], takes them), and so are f64 outputs
    /// with an outside value that f32 does not hold.
    pub fn run(
        &self,
        ctx: &GpuContext,
        request: &ExportRequest<'_>,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<ExportedVolume> {
        let plan = Plan::new(request)?;
        let source = &request.source;
        let source_type = source.samples.sample_type();
        if !source.samples.exact_in_f32() {
            return Err(GpuError::Unsupported(format!(
                "{source_type:?} samples that f32 does not hold exactly (|v| > 2^24, or f64 fractions); use export_cpu"
            )));
        }
        let (format, texels) = SourceTexels::of(source_type);
        let texel_bytes = u64::from(format.block_copy_size(None).unwrap_or(4));
        let max_dim = ctx.limits.max_texture_dimension_3d as usize;
        let source_bytes = source.samples.len() as u64 * texel_bytes;
        if source.dims.iter().any(|&d| d > max_dim) || source_bytes > Self::MAX_SOURCE_BYTES {
            return Err(GpuError::Unsupported(format!(
                "source {:?} is larger than one 3-D texture here ({max_dim} per axis, {} bytes); use export_cpu",
                source.dims,
                Self::MAX_SOURCE_BYTES
            )));
        }
        let outside_stored = outside_stored(plan.output, plan.outside_value)?;
        let slab = Self::slab_slices_of(ctx, &plan)?;
        let key = PipelineKey {
            pullback: PullBackKind::of(&plan.pullback),
            interpolation: plan.interpolation,
            source: texels,
            stored: Stored::of(plan.output),
        };
        let pipeline = self.pipeline(ctx, key);
        let source_texture = with_samples!(source.samples, |s| upload_source(ctx, source.dims, s, format))?;
        let (control_view, control_dims) = upload_control(ctx, &plan.pullback, max_dim)?;
        let (tps_buffer, centre_count) = upload_tps(ctx, &plan.pullback);
        let uniforms = ExportUniforms { outside_stored, ..uniforms(&plan, control_dims, centre_count) };
        let source_view = source_texture.create_view(&wgpu::TextureViewDescriptor::default());
        // The binding of the source's kind holds it; the other two hold 1×1×1 placeholders.
        let views = [SourceTexels::Float, SourceTexels::Sint, SourceTexels::Uint]
            .map(|kind| (kind != texels).then(|| placeholder_view(ctx, kind.placeholder_format())));
        let view_of = |kind: SourceTexels| views[kind.code() as usize].as_ref().unwrap_or(&source_view);
        let shared = SlabShared {
            layout: &self.layout,
            pipeline: &pipeline,
            float_view: view_of(SourceTexels::Float),
            sint_view: view_of(SourceTexels::Sint),
            uint_view: view_of(SourceTexels::Uint),
            control_view: &control_view,
            tps_buffer: &tps_buffer,
        };
        ctx.check_errors()?;
        let samples = match plan.output {
            SampleType::U8 => ExportedSamples::U8(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::I8 => ExportedSamples::I8(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::U16 => ExportedSamples::U16(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::I16 => ExportedSamples::I16(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::U32 => ExportedSamples::U32(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::I32 => ExportedSamples::I32(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::F32 => ExportedSamples::F32(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
            SampleType::F64 => ExportedSamples::F64(read_slabs(ctx, &plan, &shared, uniforms, slab, progress)?),
        };
        Ok(ExportedVolume { dims: plan.target_dims, lps_from_index: request.target.lps_from_index, samples })
    }
}

/// The outside value as the output stores it: the CPU path's conversion, in the low bits of a word. An f64 output
/// goes through f32 on the GPU, so its outside value must be exact in f32.
fn outside_stored(output: SampleType, outside: f64) -> Result<u32> {
    Ok(match output {
        SampleType::U8 => u32::from(u8::from_f64(outside)),
        SampleType::I8 => u32::from(i8::from_f64(outside).cast_unsigned()),
        SampleType::U16 => u32::from(u16::from_f64(outside)),
        SampleType::I16 => u32::from(i16::from_f64(outside).cast_unsigned()),
        SampleType::U32 => u32::from_f64(outside),
        SampleType::I32 => i32::from_f64(outside).cast_unsigned(),
        SampleType::F32 => f32::from_f64(outside).to_bits(),
        SampleType::F64 => {
            let narrow = outside as f32;
            if !outside.is_nan() && f64::from(narrow).to_bits() != outside.to_bits() {
                return Err(GpuError::Unsupported(format!(
                    "an f64 output with the outside value {outside}, which f32 does not hold; use export_cpu"
                )));
            }
            narrow.to_bits()
        }
    })
}

fn uniforms(plan: &Plan, control_dims: [u32; 3], centre_count: u32) -> ExportUniforms {
    let tps_rows = match &plan.pullback {
        PlanPullBack::Identity | PlanPullBack::Control { .. } => [[0.0; 4]; 3],
        PlanPullBack::Tps(tps) => {
            let l = &tps.linear_minus_identity;
            let o = &tps.offset_mm;
            std::array::from_fn(|r| [l[r][0], l[r][1], l[r][2], o[r]])
        }
    };
    ExportUniforms {
        source_index_from_target_index: plan.source_index_from_target_index,
        pullback_from_target_index: plan.pullback_from_target_index,
        source_index_from_lps: plan.source_index_from_lps,
        tps_row0: tps_rows[0],
        tps_row1: tps_rows[1],
        tps_row2: tps_rows[2],
        target_dims: plan.target_dims.map(|d| d as u32),
        slab_first_slice: 0,
        source_dims: plan.source_dims.map(|d| d as u32),
        slab_voxels: 0,
        control_dims,
        centre_count,
        outside_stored: 0,
        invocations_per_row: 0,
        _pad0: 0,
        _pad1: 0,
    }
}

/// What every slab binds besides its own uniforms and output.
struct SlabShared<'a> {
    layout: &'a wgpu::BindGroupLayout,
    pipeline: &'a wgpu::ComputePipeline,
    float_view: &'a wgpu::TextureView,
    sint_view: &'a wgpu::TextureView,
    uint_view: &'a wgpu::TextureView,
    control_view: &'a wgpu::TextureView,
    tps_buffer: &'a wgpu::Buffer,
}

/// The buffers of one slab in flight: its uniforms, its output (storage) and the mappable copy of it.
struct SlabBuffers {
    uniforms: wgpu::Buffer,
    output: wgpu::Buffer,
    readback: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl SlabBuffers {
    fn new(ctx: &GpuContext, shared: &SlabShared<'_>, bytes: u64) -> Self {
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("export uniforms"),
            size: std::mem::size_of::<ExportUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let output = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("export slab"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("export readback"),
            size: bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("export"),
            layout: shared.layout,
            entries: &[
                SLOT_UNIFORMS.entry(uniforms.as_entire_binding()),
                SLOT_SOURCE_FLOAT.entry(wgpu::BindingResource::TextureView(shared.float_view)),
                SLOT_CONTROL.entry(wgpu::BindingResource::TextureView(shared.control_view)),
                SLOT_TPS_TERMS.entry(shared.tps_buffer.as_entire_binding()),
                SLOT_SLAB.entry(output.as_entire_binding()),
                SLOT_SOURCE_SINT.entry(wgpu::BindingResource::TextureView(shared.sint_view)),
                SLOT_SOURCE_UINT.entry(wgpu::BindingResource::TextureView(shared.uint_view)),
            ],
        });
        Self { uniforms, output, readback, bind_group }
    }
}

/// A slab submitted and not yet copied out: which buffers, which slices, its submission, and the channel its map
/// callback answers on.
struct InFlight {
    buffers: usize,
    first_slice: usize,
    slices: usize,
    /// Bytes of stored output (what is copied out).
    bytes: u64,
    submission: wgpu::SubmissionIndex,
    mapped: Receiver<std::result::Result<(), wgpu::BufferAsyncError>>,
}

/// The slabs in flight.
///
/// A queued slab's map is never cancelled with `unmap` while it may be pending: on a device that other threads poll
/// too, one of their polls may be mapping that very buffer, and wgpu-core (30) marks a buffer idle while it maps it,
/// so the unmap fails ("Buffer is not mapped", reported on the whole device) and the buffer ends up mapped anyway
/// (found by `tests/export.rs`'s shared-device test, 1 run in 20). A cancelled export drains the queue instead
/// ([`Ring::drain`]: each slab's map answered, then unmapped); after an error the buffers are only dropped, and wgpu
/// releases each when its work is done.
struct Ring {
    buffers: Vec<SlabBuffers>,
    queued: VecDeque<InFlight>,
}

impl Ring {
    /// Waits (bounded, as every slab wait) for each queued slab's map to be answered and unmaps the mapped ones, so
    /// that nothing is left mapped and no callback is left pending.
    fn drain(&mut self, ctx: &GpuContext, slices_total: usize) {
        for slab in self.queued.drain(..) {
            if wait_mapped(ctx, &slab, slices_total).is_ok() {
                self.buffers[slab.buffers].readback.unmap();
            }
        }
    }
}

/// Computes every slab of `plan`'s target, [`ExportPass::SLABS_IN_FLIGHT`] at a time, and copies each into the
/// output as it arrives (module docs).
fn read_slabs<O: Sample>(
    ctx: &GpuContext,
    plan: &Plan,
    shared: &SlabShared<'_>,
    mut uniforms: ExportUniforms,
    slab: usize,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<Vec<O>> {
    let [nx, ny, nz] = plan.target_dims;
    let stored = Stored::of(plan.output);
    let slab_words = (slab as u64 * (nx * ny) as u64 * stored.bytes()).div_ceil(4);
    let slab_bytes = slab_words.max(1) * 4;
    let mut out = try_reserved::<O>(plan.output_len)?;
    let slabs = nz.div_ceil(slab);
    let count = ExportPass::SLABS_IN_FLIGHT.min(slabs);
    let mut ring = Ring {
        buffers: (0..count).map(|_| SlabBuffers::new(ctx, shared, slab_bytes)).collect(),
        queued: VecDeque::new(),
    };
    let groups_limit = ctx.limits.max_compute_workgroups_per_dimension;
    let mut next_slice = 0;
    let mut next_buffers = 0;
    let mut written = 0;
    while written < plan.output_len {
        // Keep the GPU fed: queue slabs until every set of buffers is in use.
        while ring.queued.len() < count && next_slice < nz {
            let slices = slab.min(nz - next_slice);
            let voxels = slices * nx * ny;
            let words = (voxels as u64 * stored.bytes()).div_ceil(4);
            // One invocation per voxel (the shader packs them into words).
            let groups = (voxels as u64).div_ceil(u64::from(WORKGROUP)) as u32;
            let groups_x = groups.min(groups_limit);
            let groups_y = groups.div_ceil(groups_x);
            uniforms.slab_first_slice = next_slice as u32;
            uniforms.slab_voxels = voxels as u32;
            uniforms.invocations_per_row = groups_x * WORKGROUP;
            let buffers = &ring.buffers[next_buffers];
            ctx.queue.write_buffer(&buffers.uniforms, 0, bytemuck::bytes_of(&uniforms));
            let mut encoder =
                ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("export") });
            {
                let mut pass = encoder
                    .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("export"), timestamp_writes: None });
                pass.set_pipeline(shared.pipeline);
                pass.set_bind_group(0, &buffers.bind_group, &[]);
                pass.dispatch_workgroups(groups_x, groups_y, 1);
            }
            encoder.copy_buffer_to_buffer(&buffers.output, 0, &buffers.readback, 0, words * 4);
            let submission = ctx.queue.submit([encoder.finish()]);
            let (tx, mapped) = std::sync::mpsc::channel();
            buffers.readback.slice(..words * 4).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send(r);
            });
            ring.queued.push_back(InFlight {
                buffers: next_buffers,
                first_slice: next_slice,
                slices,
                bytes: voxels as u64 * stored.bytes(),
                submission,
                mapped,
            });
            next_buffers = (next_buffers + 1) % count;
            next_slice += slices;
        }
        let Some(front) = ring.queued.front() else {
            return Err(GpuError::Readback("the export's slabs ended before its output was complete".into()));
        };
        wait_mapped(ctx, front, nz)?;
        // The slab's map is done: take it off the queue first, so that an error below still unmaps it (once).
        let done = ring.queued.pop_front().ok_or_else(|| GpuError::Readback("a slab left the queue".into()))?;
        let readback = &ring.buffers[done.buffers].readback;
        let voxels = done.slices * nx * ny;
        {
            let view = readback.slice(..done.bytes.div_ceil(4) * 4).get_mapped_range();
            let copied = view.map_err(|e| GpuError::Readback(e.to_string())).and_then(|mapped| {
                store(&mut out.spare_capacity_mut()[written..written + voxels], &mapped[..done.bytes as usize])
            });
            if let Err(e) = copied {
                readback.unmap();
                return Err(e);
            }
        }
        readback.unmap();
        written += voxels;
        ctx.check_errors()?;
        if let Err(cancelled) = report(progress, done.first_slice + done.slices, nz) {
            ring.drain(ctx, nz);
            return Err(cancelled);
        }
    }
    #[allow(unsafe_code, reason = "the output is filled in place from the slabs, without zeroing it first")]
    // SAFETY: `try_reserved` reserved at least `output_len` elements, and the loop above wrote every one of them: the
    // slabs come back in order (first_slice 0, slab, 2·slab, …, each with slices·nx·ny voxels), each successful
    // `store` writes every element of [written, written + voxels) of the spare capacity (it checks the slab's length
    // first and returns an error, writing nothing, when it differs), and the loop ends when `written` reaches
    // `output_len`. A cancelled or failed export returns before this with `out` still empty.
    unsafe {
        out.set_len(plan.output_len);
    }
    Ok(out)
}

/// Waits until `slab`'s readback is mapped: polls for its own submission (in steps of at most [`POLL_STEP`]) until
/// its map callback has answered, for at most [`ExportPass::SLAB_WAIT_LIMIT`]. On a device that other threads poll
/// too, the callback may run in their poll after this thread's wait returned: the loop then looks again every
/// 100 µs, polling without waiting, until the answer is there.
fn wait_mapped(ctx: &GpuContext, slab: &InFlight, slices_total: usize) -> Result<()> {
    let started = Instant::now();
    let deadline = started + ExportPass::SLAB_WAIT_LIMIT;
    let what = || {
        format!(
            "slices {}..{} of {slices_total} (submission {:?})",
            slab.first_slice,
            slab.first_slice + slab.slices,
            slab.submission
        )
    };
    let mut finished = false;
    loop {
        match slab.mapped.try_recv() {
            Ok(Ok(())) => return Ok(()),
            Ok(Err(e)) => return Err(GpuError::Readback(format!("mapping {}: {e}", what()))),
            Err(TryRecvError::Disconnected) => {
                return Err(GpuError::Readback(format!("mapping {}: the map callback was dropped", what())));
            }
            Err(TryRecvError::Empty) => {}
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            let state = if finished { "finished, but its map was never answered" } else { "not finished" };
            return Err(GpuError::Readback(format!(
                "{} was {state} after {:.0} s; the device may be stalled",
                what(),
                started.elapsed().as_secs_f64()
            )));
        }
        let poll = if finished {
            std::thread::sleep(Duration::from_micros(100));
            wgpu::PollType::Poll
        } else {
            wgpu::PollType::Wait { submission_index: Some(slab.submission.clone()), timeout: Some(left.min(POLL_STEP)) }
        };
        match ctx.device.poll(poll) {
            Ok(_) => finished = true,
            Err(wgpu::PollError::Timeout) => {}
            Err(e) => return Err(GpuError::Readback(format!("waiting for {}: {e}", what()))),
        }
    }
}

/// Copies one slab's stored bytes into `dst` on rayon's pool: the output's own bytes (the GPU rounded, clamped and
/// packed them; GPU buffers and the hosts wgpu runs on are little-endian), or f32 widened for an f64 output. Writes
/// every element of `dst`, or none and says why.
fn store<O: Sample>(dst: &mut [MaybeUninit<O>], bytes: &[u8]) -> Result<()> {
    let size = std::mem::size_of::<O>();
    // f64 outputs travel as f32.
    let wire = size.min(4);
    if bytes.len() != dst.len() * wire {
        return Err(GpuError::Readback(format!(
            "a slab of {} bytes for {} voxels of {wire} bytes",
            bytes.len(),
            dst.len()
        )));
    }
    let grain = COPY_GRAIN_BYTES / wire;
    if size == 8 {
        dst.par_chunks_mut(grain).zip(bytes.par_chunks(grain * 4)).for_each(|(d, s)| {
            for (d, s) in d.iter_mut().zip(s.chunks_exact(4)) {
                d.write(O::from_f64(f64::from(f32::from_le_bytes([s[0], s[1], s[2], s[3]]))));
            }
        });
        return Ok(());
    }
    match bytemuck::try_cast_slice::<u8, O>(bytes) {
        Ok(values) => dst.par_chunks_mut(grain).zip(values.par_chunks(grain)).for_each(|(d, s)| {
            d.write_copy_of_slice(s);
        }),
        // A mapping aligned to less than the sample's size (no driver does this): element by element.
        Err(_) => dst.par_chunks_mut(grain).zip(bytes.par_chunks(grain * size)).for_each(|(d, s)| {
            for (d, s) in d.iter_mut().zip(s.chunks_exact(size)) {
                d.write(bytemuck::pod_read_unaligned(s));
            }
        }),
    }
    Ok(())
}

fn texture(ctx: &GpuContext, label: &str, dims: [usize; 3], format: wgpu::TextureFormat) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: dims[0] as u32, height: dims[1] as u32, depth_or_array_layers: dims[2] as u32 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D3,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
}

/// A 1×1×1 texture of `format` (its one texel is whatever a new texture holds: zero), for an unused binding.
fn placeholder_view(ctx: &GpuContext, format: wgpu::TextureFormat) -> wgpu::TextureView {
    texture(ctx, "export placeholder", [1, 1, 1], format).create_view(&wgpu::TextureViewDescriptor::default())
}

/// A box of the source that one staging buffer carries: `rows` rows from row `y` of `slices` slices from slice `z`
/// (several whole slices, or a band of one slice's rows).
#[derive(Clone, Copy, Debug)]
struct UploadPiece {
    z: usize,
    slices: usize,
    y: usize,
    rows: usize,
}

/// The source as a 3-D texture of `format`, its own type. The volume is cut into pieces of about
/// [`COPY_GRAIN_BYTES`] (whole slices, or bands of rows of a large slice); each piece is copied into a staging buffer
/// of its own, mapped at creation (rows padded to the copy alignment), on rayon's pool, and the pieces' copies to the
/// texture are submitted [`UPLOAD_CHUNK_BYTES`] at a time, so the GPU copies one chunk while the next is filled.
fn upload_source<S: Sample>(
    ctx: &GpuContext,
    dims: [usize; 3],
    samples: &[S],
    format: wgpu::TextureFormat,
) -> Result<wgpu::Texture> {
    let texture = texture(ctx, "export source", dims, format);
    let texel = format.block_copy_size(None).unwrap_or(4) as usize;
    let [nx, ny, nz] = dims;
    let row_bytes = nx * texel;
    let padded = row_bytes.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as usize);
    if padded as u64 > ctx.limits.max_buffer_size {
        return Err(GpuError::Unsupported(format!(
            "one source row of {nx} texels needs {padded} bytes of staging, above the {} bytes of one buffer here; \
             use export_cpu",
            ctx.limits.max_buffer_size
        )));
    }
    let rows_per_piece = (COPY_GRAIN_BYTES / padded).clamp(1, ny);
    let mut pieces = Vec::new();
    if rows_per_piece == ny {
        let slices_per_piece = (COPY_GRAIN_BYTES / (padded * ny)).max(1);
        for z in (0..nz).step_by(slices_per_piece) {
            pieces.push(UploadPiece { z, slices: slices_per_piece.min(nz - z), y: 0, rows: ny });
        }
    } else {
        for z in 0..nz {
            for y in (0..ny).step_by(rows_per_piece) {
                pieces.push(UploadPiece { z, slices: 1, y, rows: rows_per_piece.min(ny - y) });
            }
        }
    }
    let pieces_per_chunk = (UPLOAD_CHUNK_BYTES as usize / COPY_GRAIN_BYTES).max(1);
    for chunk in pieces.chunks(pieces_per_chunk) {
        let staged: Vec<wgpu::Buffer> = chunk
            .par_iter()
            .map(|piece| {
                let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("export source staging"),
                    size: (padded * piece.rows * piece.slices) as u64,
                    usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: true,
                });
                {
                    let mut mapped = staging
                        .slice(..)
                        .get_mapped_range_mut()
                        .map_err(|e| GpuError::Readback(format!("staging the source for upload: {e}")))?;
                    let mut dst = 0;
                    for z in piece.z..piece.z + piece.slices {
                        let slice = &samples[z * nx * ny..(z + 1) * nx * ny];
                        for row in slice[piece.y * nx..(piece.y + piece.rows) * nx].chunks(nx) {
                            S::write_texels(mapped.slice(dst..dst + row_bytes), row);
                            dst += padded;
                        }
                    }
                }
                staging.unmap();
                Ok(staging)
            })
            .collect::<Result<_>>()?;
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("export upload") });
        for (piece, staging) in chunk.iter().zip(&staged) {
            encoder.copy_buffer_to_texture(
                wgpu::TexelCopyBufferInfo {
                    buffer: staging,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(padded as u32),
                        rows_per_image: Some(piece.rows as u32),
                    },
                },
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: piece.y as u32, z: piece.z as u32 },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::Extent3d {
                    width: nx as u32,
                    height: piece.rows as u32,
                    depth_or_array_layers: piece.slices as u32,
                },
            );
        }
        ctx.queue.submit([encoder.finish()]);
    }
    Ok(texture)
}

/// The control texture as `Rgba32Float`, or a 1×1×1 zero placeholder; returns its view and dims.
fn upload_control(ctx: &GpuContext, pullback: &PlanPullBack, max_dim: usize) -> Result<(wgpu::TextureView, [u32; 3])> {
    let zero = [[0.0f32; 4]];
    let (dims, texels) = match pullback {
        PlanPullBack::Control { dims, texels } => (*dims, texels.as_slice()),
        _ => ([1, 1, 1], zero.as_slice()),
    };
    if dims.iter().any(|&d| d > max_dim) {
        return Err(GpuError::Unsupported(format!("control texture {dims:?} exceeds {max_dim} texels per axis")));
    }
    let texture = texture(ctx, "export control", dims, wgpu::TextureFormat::Rgba32Float);
    ctx.queue.write_texture(
        texture.as_image_copy(),
        bytemuck::cast_slice(texels),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some((dims[0] * 16) as u32),
            rows_per_image: Some(dims[1] as u32),
        },
        wgpu::Extent3d { width: dims[0] as u32, height: dims[1] as u32, depth_or_array_layers: dims[2] as u32 },
    );
    Ok((texture.create_view(&wgpu::TextureViewDescriptor::default()), dims.map(|d| d as u32)))
}

/// The TPS terms (centre, weight) as vec4 pairs; one zero pair when there are none.
fn upload_tps(ctx: &GpuContext, pullback: &PlanPullBack) -> (wgpu::Buffer, u32) {
    let mut terms: Vec<[f32; 4]> = Vec::new();
    let mut count = 0;
    if let PlanPullBack::Tps(tps) = pullback {
        for (p, w) in tps.centres_local.iter().zip(&tps.weights) {
            terms.push([p[0], p[1], p[2], 0.0]);
            terms.push([w[0], w[1], w[2], 0.0]);
        }
        count = tps.centres_local.len() as u32;
    }
    if terms.is_empty() {
        terms = vec![[0.0; 4]; 2];
    }
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("export TPS terms"),
        size: (terms.len() * 16) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    ctx.queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&terms));
    (buffer, count)
}
