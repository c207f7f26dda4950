//! The GPU path of the export: [`ExportPass`] (the long-lived compute pipeline) runs `shaders/export.wgsl` over the
//! target one z-slab at a time and reads each slab back as f32; the host rounds and clamps into the output type with
//! the CPU path's conversion, so both paths differ only by the f32 arithmetic of the device.
//!
//! Per call: the source is uploaded once as an `R32Float` 3-D texture (converted to f32 a few slices at a time), the
//! control texture as `Rgba32Float` (both read with `textureLoad` and filtered by hand, with full-precision weights:
//! hardware filtering uses 8-bit fractions on many GPUs, and neither format is filterable everywhere), the TPS terms
//! as a storage buffer. Nothing needs an optional feature: this runs on lavapipe, on GL and on real GPUs.

use bytemuck::{Pod, Zeroable};

use super::plan::{Plan, PlanPullBack, report};
use super::request::{ExportRequest, ExportedSamples, ExportedVolume, Interpolation, Progress, SampleType};
use super::sample::{Sample, try_zeroed, with_samples};
use crate::compute::{self, binding, storage, uniform};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, layout};

/// `shaders/export.wgsl`: `cs_export`, one z-slab of the target per dispatch.
pub const SHADER: ShaderSource = ShaderSource {
    name: "export",
    path: "shaders/export.wgsl",
    source: include_str!("../../../../shaders/export.wgsl"),
    entry_points: &[("cs_export", Stage::Compute)],
};

pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "u");
/// The source volume as f32.
pub const SLOT_SOURCE: BindSlot = BindSlot::new(0, 1, "source");
/// The control texture (a placeholder for the other pull-backs).
pub const SLOT_CONTROL: BindSlot = BindSlot::new(0, 2, "control");
/// The TPS's centres and weights (a placeholder for the other pull-backs).
pub const SLOT_TPS_TERMS: BindSlot = BindSlot::new(0, 3, "tps_terms");
/// One slab's f32 output.
pub const SLOT_SLAB: BindSlot = BindSlot::new(0, 4, "slab");

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
        slab_slices,
        control_dims,
        pullback,
        interpolation,
        centre_count,
        outside_value
    })],
    slots: &[SLOT_UNIFORMS, SLOT_SOURCE, SLOT_CONTROL, SLOT_TPS_TERMS, SLOT_SLAB],
    constants: &[],
};

/// `@workgroup_size` of `cs_export` (x, y; z is 1).
const WORKGROUP: u32 = 8;
/// Source slices converted to f32 and written per upload call are at most this many bytes.
const UPLOAD_CHUNK_BYTES: usize = 16 << 20;

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
    pub slab_slices: u32,
    pub control_dims: [u32; 3],
    /// 0 identity, 1 control texture, 2 TPS.
    pub pullback: u32,
    /// 0 nearest, 1 trilinear, 2 Catmull-Rom.
    pub interpolation: u32,
    pub centre_count: u32,
    pub outside_value: f32,
    _pad0: u32,
}
const _: () = assert!(std::mem::size_of::<ExportUniforms>() == 304);

/// The long-lived part of the export: the compute pipeline and its bind group layout.
#[derive(Debug)]
pub struct ExportPass {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl ExportPass {
    /// Storage buffers per compute stage and invocations per workgroup the pass needs.
    pub const STORAGE_BUFFERS: u32 = 2;
    pub const INVOCATIONS: u32 = WORKGROUP * WORKGROUP;
    /// Most bytes of one slab's f32 output (and of its readback copy).
    pub const SLAB_BUDGET_BYTES: u64 = 64 << 20;
    /// Largest source accepted, as f32 texels (4 bytes each).
    pub const MAX_SOURCE_BYTES: u64 = 4 << 30;

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        if l.max_storage_buffers_per_shader_stage < Self::STORAGE_BUFFERS
            || l.max_compute_invocations_per_workgroup < Self::INVOCATIONS
            || l.max_compute_workgroup_size_x < WORKGROUP
            || l.max_compute_workgroup_size_y < WORKGROUP
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
        let texture_3d = || compute::texture(wgpu::TextureViewDimension::D3);
        let layout = compute::layout(
            device,
            "export",
            &[
                binding(SLOT_UNIFORMS, uniform::<ExportUniforms>()),
                binding(SLOT_SOURCE, texture_3d()),
                binding(SLOT_CONTROL, texture_3d()),
                binding(SLOT_TPS_TERMS, storage(true, None)),
                binding(SLOT_SLAB, storage(false, None)),
            ],
        );
        let entry_point = SHADER.entry_point(Stage::Compute);
        let pipeline = compute::pipeline(device, "export", &module, entry_point, &[&layout]);
        ctx.check_errors()?;
        Ok(Self { pipeline, layout })
    }

    /// Slices per slab on this device for a target of `dims`, at most `requested` (see [`crate::export`]).
    pub fn slab_slices(ctx: &GpuContext, dims: [usize; 3], requested: Option<usize>) -> Result<usize> {
        let l = &ctx.limits;
        let slice_bytes = (dims[0] * dims[1]) as u64 * 4;
        let cap = Self::SLAB_BUDGET_BYTES.min(l.max_storage_buffer_binding_size).min(l.max_buffer_size);
        if slice_bytes > cap {
            return Err(GpuError::Unsupported(format!(
                "one target slice of {}×{} f32 is {slice_bytes} bytes, above the {cap} bytes one storage binding \
                 holds here; use export_cpu",
                dims[0], dims[1]
            )));
        }
        let groups = u64::from(l.max_compute_workgroups_per_dimension);
        if (dims[0] as u64).div_ceil(u64::from(WORKGROUP)) > groups
            || (dims[1] as u64).div_ceil(u64::from(WORKGROUP)) > groups
        {
            return Err(GpuError::Unsupported(format!(
                "target {dims:?} needs more than {groups} workgroups along x or y; use export_cpu"
            )));
        }
        let fit = (cap / slice_bytes).min(groups) as usize;
        Ok(requested.unwrap_or(usize::MAX).min(fit).min(dims[2]).max(1))
    }

    /// Resamples `request` on the GPU, calling `progress` after each slab; `false` cancels with
    /// [`GpuError::Cancelled`]. Sources that are not exact in f32 or too large for one texture are
    /// [`GpuError::Unsupported`] (the CPU path, [`crate::export::export_cpu`], takes them).
    pub fn run(
        &self,
        ctx: &GpuContext,
        request: &ExportRequest<'_>,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<ExportedVolume> {
        let plan = Plan::new(request)?;
        let source = &request.source;
        if !source.samples.exact_in_f32() {
            return Err(GpuError::Unsupported(format!(
                "{:?} samples that f32 does not hold exactly (|v| > 2^24, or f64 fractions); use export_cpu",
                source.samples.sample_type()
            )));
        }
        let max_dim = ctx.limits.max_texture_dimension_3d as usize;
        let source_bytes = source.samples.len() as u64 * 4;
        if source.dims.iter().any(|&d| d > max_dim) || source_bytes > Self::MAX_SOURCE_BYTES {
            return Err(GpuError::Unsupported(format!(
                "source {:?} is larger than one 3-D texture here ({max_dim} per axis, {} bytes as f32); use \
                 export_cpu",
                source.dims,
                Self::MAX_SOURCE_BYTES
            )));
        }
        let slab = Self::slab_slices(ctx, plan.target_dims, plan.slab_slices)?;
        let source_texture = with_samples!(source.samples, |s| upload_source(ctx, source.dims, s));
        let (control_view, control_dims) = upload_control(ctx, &plan.pullback, max_dim)?;
        let (tps_buffer, centre_count) = upload_tps(ctx, &plan.pullback);

        let [nx, ny, nz] = plan.target_dims;
        let slab_bytes = (slab * nx * ny * 4) as u64;
        let uniform_buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("export uniforms"),
            size: std::mem::size_of::<ExportUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let slab_buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("export slab"),
            size: slab_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("export readback"),
            size: slab_bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let source_view = source_texture.create_view(&wgpu::TextureViewDescriptor::default());
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("export"),
            layout: &self.layout,
            entries: &[
                SLOT_UNIFORMS.entry(uniform_buffer.as_entire_binding()),
                SLOT_SOURCE.entry(wgpu::BindingResource::TextureView(&source_view)),
                SLOT_CONTROL.entry(wgpu::BindingResource::TextureView(&control_view)),
                SLOT_TPS_TERMS.entry(tps_buffer.as_entire_binding()),
                SLOT_SLAB.entry(slab_buffer.as_entire_binding()),
            ],
        });
        ctx.check_errors()?;

        let mut uniforms = uniforms(&plan, control_dims, centre_count);
        let mut samples = allocate(plan.output, plan.output_len)?;
        let mut first = 0;
        while first < nz {
            let slices = slab.min(nz - first);
            uniforms.slab_first_slice = first as u32;
            uniforms.slab_slices = slices as u32;
            ctx.queue.write_buffer(&uniform_buffer, 0, bytemuck::bytes_of(&uniforms));
            let bytes = (slices * nx * ny * 4) as u64;
            let mut encoder =
                ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("export") });
            {
                let mut pass = encoder
                    .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("export"), timestamp_writes: None });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.dispatch_workgroups(
                    (nx as u32).div_ceil(WORKGROUP),
                    (ny as u32).div_ceil(WORKGROUP),
                    slices as u32,
                );
            }
            encoder.copy_buffer_to_buffer(&slab_buffer, 0, &readback, 0, bytes);
            ctx.queue.submit([encoder.finish()]);
            read_slab(ctx, &readback, bytes, |values| store(&mut samples, first * nx * ny, values))?;
            first += slices;
            report(progress, first, nz)?;
        }
        Ok(ExportedVolume { dims: plan.target_dims, lps_from_index: request.target.lps_from_index, samples })
    }
}

fn uniforms(plan: &Plan, control_dims: [u32; 3], centre_count: u32) -> ExportUniforms {
    let (tps_rows, pullback) = match &plan.pullback {
        PlanPullBack::Identity => ([[0.0; 4]; 3], 0),
        PlanPullBack::Control { .. } => ([[0.0; 4]; 3], 1),
        PlanPullBack::Tps(tps) => {
            let l = &tps.linear_minus_identity;
            let o = &tps.offset_mm;
            (std::array::from_fn(|r| [l[r][0], l[r][1], l[r][2], o[r]]), 2)
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
        slab_slices: 0,
        control_dims,
        pullback,
        interpolation: match plan.interpolation {
            Interpolation::Nearest => 0,
            Interpolation::Trilinear => 1,
            Interpolation::CatmullRom => 2,
        },
        centre_count,
        outside_value: plan.outside_value as f32,
        _pad0: 0,
    }
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

/// Writes `texels` (whole slices starting at slice `z`) into `texture`.
fn write_slices(ctx: &GpuContext, texture: &wgpu::Texture, dims: [usize; 3], z: usize, bytes: &[u8], texel: usize) {
    let slices = bytes.len() / (dims[0] * dims[1] * texel);
    ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d { x: 0, y: 0, z: z as u32 },
            aspect: wgpu::TextureAspect::All,
        },
        bytes,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some((dims[0] * texel) as u32),
            rows_per_image: Some(dims[1] as u32),
        },
        wgpu::Extent3d { width: dims[0] as u32, height: dims[1] as u32, depth_or_array_layers: slices as u32 },
    );
}

/// The source as an `R32Float` 3-D texture, converted and written a few slices at a time.
fn upload_source<S: Sample>(ctx: &GpuContext, dims: [usize; 3], samples: &[S]) -> wgpu::Texture {
    let texture = texture(ctx, "export source", dims, wgpu::TextureFormat::R32Float);
    let slice = dims[0] * dims[1];
    let per_chunk = (UPLOAD_CHUNK_BYTES / (4 * slice)).max(1);
    let mut converted = Vec::with_capacity(per_chunk * slice);
    for (c, chunk) in samples.chunks(per_chunk * slice).enumerate() {
        converted.clear();
        converted.extend(chunk.iter().map(|&v| v.to_f32()));
        write_slices(ctx, &texture, dims, c * per_chunk, bytemuck::cast_slice(&converted), 4);
    }
    texture
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
    write_slices(ctx, &texture, dims, 0, bytemuck::cast_slice(texels), 16);
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

/// Maps the first `bytes` of `readback`, hands the f32s to `sink`, unmaps.
fn read_slab(ctx: &GpuContext, readback: &wgpu::Buffer, bytes: u64, sink: impl FnOnce(&[f32])) -> Result<()> {
    ctx.map_read(readback, bytes, |mapped| sink(bytemuck::cast_slice(mapped)))
}

fn allocate(output: SampleType, len: usize) -> Result<ExportedSamples> {
    Ok(match output {
        SampleType::U8 => ExportedSamples::U8(try_zeroed(len)?),
        SampleType::I8 => ExportedSamples::I8(try_zeroed(len)?),
        SampleType::U16 => ExportedSamples::U16(try_zeroed(len)?),
        SampleType::I16 => ExportedSamples::I16(try_zeroed(len)?),
        SampleType::U32 => ExportedSamples::U32(try_zeroed(len)?),
        SampleType::I32 => ExportedSamples::I32(try_zeroed(len)?),
        SampleType::F32 => ExportedSamples::F32(try_zeroed(len)?),
        SampleType::F64 => ExportedSamples::F64(try_zeroed(len)?),
    })
}

fn convert<O: Sample>(dst: &mut [O], values: &[f32]) {
    for (d, &v) in dst.iter_mut().zip(values) {
        *d = O::from_f64(f64::from(v));
    }
}

/// Converts a slab's f32 values into the output at `offset` (the CPU path's conversion).
fn store(samples: &mut ExportedSamples, offset: usize, values: &[f32]) {
    let range = offset..offset + values.len();
    match samples {
        ExportedSamples::U8(v) => convert(&mut v[range], values),
        ExportedSamples::I8(v) => convert(&mut v[range], values),
        ExportedSamples::U16(v) => convert(&mut v[range], values),
        ExportedSamples::I16(v) => convert(&mut v[range], values),
        ExportedSamples::U32(v) => convert(&mut v[range], values),
        ExportedSamples::I32(v) => convert(&mut v[range], values),
        ExportedSamples::F32(v) => convert(&mut v[range], values),
        ExportedSamples::F64(v) => convert(&mut v[range], values),
    }
}
