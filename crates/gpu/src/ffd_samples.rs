//! The per-sample work of an intensity registration under a cubic B-spline free-form deformation, on the GPU
//! (`shaders/ffd_samples.wgsl`). The registration (the solver's `register` module) keeps the histogram, the mutual
//! information and the optimiser on the CPU; the GPU does what grows with the samples:
//!
//! - [`PreparedFfd::values`]: at every fixed sample x (continuous image index ξ, lattice footprint), the displacement
//!   D(x) = Σ B_a B_b B_c φ over its 4 × 4 × 4 control points, and the image's trilinear value and gradient (per mm)
//!   at ξ + A·D, A = ∂index/∂mm. The values come back (NaN outside the image); the gradients stay on the GPU.
//! - [`PreparedFfd::weighted_gradient`]: G_k = Σ_s w_s B_k(x_s) ∇v(x_s + D(x_s)) for every control point k, given the
//!   per-sample weights w_s the CPU derived from the values (for mutual information, the histogram's derivative).
//!
//! Both are gathers without atomics: one invocation per sample, then one per control point reading the samples of the
//! 4 × 4 × 4 "buckets" (first control points) around it, sorted once per level ([`PreparedFfd`] keeps the
//! permutation). The same inputs give the same bits on every run on a device.
//!
//! Arithmetic is f32. Continuous indices (at most a few hundred) and displacements of a few mm lose nothing that
//! matters to a registration; `tests/ffd_samples.rs` bounds the difference from an f64 reference by the rounding of
//! each step.

use wgpu::util::DeviceExt;

use crate::compute::{self, binding, storage, uniform};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, layout};
use bytemuck::{Pod, Zeroable};

/// `shaders/ffd_samples.wgsl`: `cs_values` (one invocation per sample) and `cs_gradient` (one per control point).
pub const SHADER: ShaderSource = ShaderSource {
    name: "ffd_samples",
    path: "shaders/ffd_samples.wgsl",
    source: include_str!("../../../shaders/ffd_samples.wgsl"),
    entry_points: &[(VALUES_ENTRY_POINT, Stage::Compute), (GRADIENT_ENTRY_POINT, Stage::Compute)],
};
const VALUES_ENTRY_POINT: &str = "cs_values";
const GRADIENT_ENTRY_POINT: &str = "cs_gradient";

pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "p");
/// The image, R32Float, read with `textureLoad`.
pub const SLOT_IMAGE: BindSlot = BindSlot::new(0, 1, "image");
/// [`FfdSample`]s, sorted by bucket.
pub const SLOT_SAMPLES: BindSlot = BindSlot::new(0, 2, "samples");
/// Bucket b's samples are `bucket_starts[b] .. bucket_starts[b + 1]`.
pub const SLOT_BUCKET_STARTS: BindSlot = BindSlot::new(0, 3, "bucket_starts");
/// The coefficients φ, 3 per control point.
pub const SLOT_PHI: BindSlot = BindSlot::new(0, 4, "phi");
/// Per sample (value, gradient), kept between the two entry points.
pub const SLOT_HITS: BindSlot = BindSlot::new(0, 5, "hits");
/// Per sample, the value (read back).
pub const SLOT_VALUES: BindSlot = BindSlot::new(0, 6, "values");
/// Per sample, w_s.
pub const SLOT_SAMPLE_WEIGHTS: BindSlot = BindSlot::new(0, 7, "sample_weights");
/// 3 per control point (read back).
pub const SLOT_GRADIENT: BindSlot = BindSlot::new(0, 8, "gradient");

pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "ffd_samples",
    shader: SHADER,
    uniform_structs: &[
        layout!(FfdUniforms {
            image_dims,
            sample_count,
            lattice_dims,
            row_invocations,
            buckets,
            control_points,
            index_from_mm
        }),
        layout!(FfdSample { index, bucket, weights }),
    ],
    slots: &[
        SLOT_UNIFORMS,
        SLOT_IMAGE,
        SLOT_SAMPLES,
        SLOT_BUCKET_STARTS,
        SLOT_PHI,
        SLOT_HITS,
        SLOT_VALUES,
        SLOT_SAMPLE_WEIGHTS,
        SLOT_GRADIENT,
    ],
    constants: &[],
};

/// `@workgroup_size` of both entry points (x).
const WORKGROUP: u32 = 64;
/// Storage buffers the pass binds per stage.
const STORAGE_BUFFERS: u32 = 7;

/// `FfdUniforms` in shaders/ffd_samples.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct FfdUniforms {
    pub image_dims: [u32; 3],
    pub sample_count: u32,
    pub lattice_dims: [u32; 3],
    /// Invocations per row of a dispatch: index = x + y · row_invocations.
    pub row_invocations: u32,
    /// First control points per axis: lattice_dims − 3.
    pub buckets: [u32; 3],
    pub control_points: u32,
    /// ∂index/∂mm, column-major as WGSL's `mat3x3<f32>` (each column padded to 4 floats).
    pub index_from_mm: [[f32; 4]; 3],
}
const _: () = assert!(std::mem::size_of::<FfdUniforms>() == 96);

/// One sample as the shader reads it: `FfdSample` in shaders/ffd_samples.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct FfdSample {
    /// Continuous image index of the undisplaced sample.
    pub index: [f32; 3],
    /// First control point, linearised over the buckets (x fastest).
    pub bucket: u32,
    /// Basis weights per axis.
    pub weights: [[f32; 4]; 3],
}
const _: () = assert!(std::mem::size_of::<FfdSample>() == 64);

/// The image the samples read: `dims` voxels, x fastest (NaN where it has no value), and ∂index/∂mm.
#[derive(Clone, Copy, Debug)]
pub struct FfdImage<'a> {
    pub dims: [usize; 3],
    pub values: &'a [f32],
    /// Row-major: `index_from_mm[r][c]` = ∂index_r/∂mm_c.
    pub index_from_mm: [[f64; 3]; 3],
}

/// One fixed sample: where it is in the image, and its lattice footprint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FfdSamplePoint {
    /// Continuous image index of x.
    pub index: [f64; 3],
    /// The first of its 4 × 4 × 4 control points.
    pub first: [usize; 3],
    /// The cubic B-spline weights per axis at x.
    pub weights: [[f64; 4]; 3],
}

/// One level of a registration: the image, the lattice's control points per axis and the samples.
#[derive(Clone, Copy, Debug)]
pub struct FfdLevel<'a> {
    pub image: FfdImage<'a>,
    /// Control points per axis (at least 4 each).
    pub lattice_dims: [usize; 3],
    pub samples: &'a [FfdSamplePoint],
}

impl FfdLevel<'_> {
    /// Checks sizes and footprints, naming what is wrong.
    fn validate(&self) -> Result<()> {
        let bad = |what: String| Err(GpuError::InvalidInput(what));
        let [nx, ny, nz] = self.image.dims;
        if self.image.dims.iter().any(|&n| n < 2) {
            return bad(format!("an image of {nx}×{ny}×{nz} voxels: each axis needs at least 2"));
        }
        if self.image.values.len() != nx * ny * nz {
            return bad(format!("{} image values for {nx}×{ny}×{nz} voxels", self.image.values.len()));
        }
        if self.lattice_dims.iter().any(|&n| n < 4) {
            return bad(format!("a lattice of {:?} control points: each axis needs at least 4", self.lattice_dims));
        }
        if self.samples.is_empty() {
            return bad("no samples".into());
        }
        if !self.image.index_from_mm.iter().flatten().all(|v| v.is_finite()) {
            return bad("the image's index map is not finite".into());
        }
        for (n, s) in self.samples.iter().enumerate() {
            let inside = (0..3).all(|a| s.first[a] + 4 <= self.lattice_dims[a]);
            if !inside || !s.index.iter().chain(s.weights.iter().flatten()).all(|v| v.is_finite()) {
                return bad(format!("sample {}: its footprint is outside the lattice or not finite", n + 1));
            }
        }
        Ok(())
    }
}

/// The two pipelines and their bind group layout; make once per device.
#[derive(Debug)]
pub struct FfdSamplesPass {
    values: wgpu::ComputePipeline,
    gradient: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl FfdSamplesPass {
    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let l = &ctx.limits;
        if l.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS
            || l.max_compute_invocations_per_workgroup < WORKGROUP
            || l.max_compute_workgroup_size_x < WORKGROUP
        {
            return Err(GpuError::Unsupported(format!(
                "the registration's samples need compute with {STORAGE_BUFFERS} storage buffers and {WORKGROUP} \
                 invocations per workgroup (limits: {} storage buffers, {} invocations)",
                l.max_storage_buffers_per_shader_stage, l.max_compute_invocations_per_workgroup
            )));
        }
        let device = &ctx.device;
        let module = SHADER.create_module(device);
        let entries = [
            binding(SLOT_UNIFORMS, uniform::<FfdUniforms>()),
            binding(SLOT_IMAGE, compute::texture(wgpu::TextureViewDimension::D3)),
            binding(SLOT_SAMPLES, storage(true, Some(64))),
            binding(SLOT_BUCKET_STARTS, storage(true, Some(4))),
            binding(SLOT_PHI, storage(true, Some(4))),
            binding(SLOT_HITS, storage(false, Some(16))),
            binding(SLOT_VALUES, storage(false, Some(4))),
            binding(SLOT_SAMPLE_WEIGHTS, storage(true, Some(4))),
            binding(SLOT_GRADIENT, storage(false, Some(4))),
        ];
        let layout = compute::layout(device, "ffd samples", &entries);
        let values = compute::pipeline(device, VALUES_ENTRY_POINT, &module, Some(VALUES_ENTRY_POINT), &[&layout]);
        let gradient = compute::pipeline(device, GRADIENT_ENTRY_POINT, &module, Some(GRADIENT_ENTRY_POINT), &[&layout]);
        ctx.check_errors()?;
        Ok(Self { values, gradient, layout })
    }

    /// Uploads one level: the image as an R32Float 3-D texture, the samples sorted by bucket, and the buffers the
    /// evaluations reuse.
    pub fn prepare(&self, ctx: &GpuContext, level: &FfdLevel<'_>) -> Result<PreparedFfd> {
        level.validate()?;
        let image = level.image;
        let dims = image.dims.map(|n| u32::try_from(n).unwrap_or(u32::MAX));
        let most = ctx.limits.max_texture_dimension_3d;
        if dims.iter().any(|&n| n > most) {
            return Err(GpuError::Unsupported(format!(
                "an image of {:?} voxels; the device's 3-D textures hold at most {most} per axis",
                image.dims
            )));
        }
        let n = level.samples.len();
        let sample_bytes = 64 * n as u64;
        let hit_bytes = 16 * n as u64;
        let largest = sample_bytes.max(hit_bytes);
        if largest > ctx.limits.max_storage_buffer_binding_size || n > u32::MAX as usize {
            return Err(GpuError::Unsupported(format!(
                "{n} samples need a {largest}-byte storage buffer; the device binds at most {}",
                ctx.limits.max_storage_buffer_binding_size
            )));
        }
        let lattice = level.lattice_dims;
        let buckets = lattice.map(|d| d - 3);
        let bucket_of = |first: [usize; 3]| (first[2] * buckets[1] + first[1]) * buckets[0] + first[0];
        let bucket_count = buckets.iter().product::<usize>();
        // A stable counting sort by bucket: `order[sorted] = original`.
        let mut starts = vec![0u32; bucket_count + 1];
        for s in level.samples {
            starts[bucket_of(s.first) + 1] += 1;
        }
        for b in 0..bucket_count {
            starts[b + 1] += starts[b];
        }
        let mut next = starts.clone();
        let mut order = vec![0u32; n];
        for (original, s) in level.samples.iter().enumerate() {
            let slot = &mut next[bucket_of(s.first)];
            order[*slot as usize] = original as u32;
            *slot += 1;
        }
        let gpu_samples: Vec<FfdSample> = order
            .iter()
            .map(|&o| {
                let s = &level.samples[o as usize];
                FfdSample {
                    index: s.index.map(|v| v as f32),
                    bucket: bucket_of(s.first) as u32,
                    weights: s.weights.map(|w| w.map(|v| v as f32)),
                }
            })
            .collect();
        let control_points = lattice.iter().product::<usize>();
        let a = image.index_from_mm;
        let uniforms = FfdUniforms {
            image_dims: dims,
            sample_count: n as u32,
            lattice_dims: lattice.map(|d| d as u32),
            row_invocations: 0,
            buckets: buckets.map(|d| d as u32),
            control_points: control_points as u32,
            index_from_mm: std::array::from_fn(|c| [a[0][c] as f32, a[1][c] as f32, a[2][c] as f32, 0.0]),
        };

        let device = &ctx.device;
        let texture = ctx.texture_3d(
            "ffd image",
            dims,
            wgpu::TextureFormat::R32Float,
            wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        );
        // In slabs of at most 16 MiB, so that no single staging copy is large.
        let plane = image.dims[0] * image.dims[1];
        let slab = (4 << 20) / plane.max(1);
        let slab = slab.max(1);
        for z0 in (0..image.dims[2]).step_by(slab) {
            let depth = slab.min(image.dims[2] - z0);
            ctx.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z: z0 as u32 },
                    aspect: wgpu::TextureAspect::All,
                },
                bytemuck::cast_slice(&image.values[z0 * plane..(z0 + depth) * plane]),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(4 * dims[0]),
                    rows_per_image: Some(dims[1]),
                },
                wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: depth as u32 },
            );
        }
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let copy_dst = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let copy_src = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let samples = init("ffd samples", bytemuck::cast_slice(&gpu_samples), wgpu::BufferUsages::STORAGE);
        let bucket_starts = init("ffd buckets", bytemuck::cast_slice(&starts), wgpu::BufferUsages::STORAGE);
        let coefficients = 3 * control_points;
        let phi = ctx.buffer("ffd phi", 4 * coefficients as u64, copy_dst);
        let hits = ctx.buffer("ffd hits", hit_bytes, wgpu::BufferUsages::STORAGE);
        let values = ctx.buffer("ffd values", 4 * n as u64, copy_src);
        let sample_weights = ctx.buffer("ffd sample weights", 4 * n as u64, copy_dst);
        let gradient = ctx.buffer("ffd gradient", 4 * coefficients as u64, copy_src);
        let read = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        let values_read = ctx.buffer("ffd values readback", 4 * n as u64, read);
        let gradient_read = ctx.buffer("ffd gradient readback", 4 * coefficients as u64, read);

        let sample_groups = Dispatch::of(n, ctx.limits.max_compute_workgroups_per_dimension);
        let point_groups = Dispatch::of(control_points, ctx.limits.max_compute_workgroups_per_dimension);
        let uniform_for = |d: Dispatch| {
            let value = FfdUniforms { row_invocations: d.row_invocations(), ..uniforms };
            ctx.uniform_buffer("ffd uniforms", &value)
        };
        let (values_uniforms, gradient_uniforms) = (uniform_for(sample_groups), uniform_for(point_groups));
        let group = |u: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("ffd samples"),
                layout: &self.layout,
                entries: &[
                    SLOT_UNIFORMS.entry(u.as_entire_binding()),
                    SLOT_IMAGE.entry(wgpu::BindingResource::TextureView(&view)),
                    SLOT_SAMPLES.entry(samples.as_entire_binding()),
                    SLOT_BUCKET_STARTS.entry(bucket_starts.as_entire_binding()),
                    SLOT_PHI.entry(phi.as_entire_binding()),
                    SLOT_HITS.entry(hits.as_entire_binding()),
                    SLOT_VALUES.entry(values.as_entire_binding()),
                    SLOT_SAMPLE_WEIGHTS.entry(sample_weights.as_entire_binding()),
                    SLOT_GRADIENT.entry(gradient.as_entire_binding()),
                ],
            })
        };
        let values_group = group(&values_uniforms);
        let gradient_group = group(&gradient_uniforms);
        ctx.check_errors()?;
        Ok(PreparedFfd {
            values_pipeline: self.values.clone(),
            gradient_pipeline: self.gradient.clone(),
            values_group,
            gradient_group,
            sample_groups,
            point_groups,
            order,
            coefficients,
            phi,
            values,
            sample_weights,
            gradient,
            values_read,
            gradient_read,
            _texture: texture,
        })
    }
}

/// A 1-D range of invocations laid out as rows of at most the device's workgroups per dimension.
#[derive(Clone, Copy, Debug)]
struct Dispatch {
    x: u32,
    y: u32,
}

impl Dispatch {
    fn of(invocations: usize, most_per_dimension: u32) -> Self {
        let groups = invocations.div_ceil(WORKGROUP as usize).max(1) as u32;
        let x = groups.min(most_per_dimension.max(1));
        Self { x, y: groups.div_ceil(x) }
    }

    fn row_invocations(self) -> u32 {
        self.x * WORKGROUP
    }
}

/// One level on the GPU ([`FfdSamplesPass::prepare`]). Evaluations reuse its buffers; each waits for the GPU.
#[derive(Debug)]
pub struct PreparedFfd {
    values_pipeline: wgpu::ComputePipeline,
    gradient_pipeline: wgpu::ComputePipeline,
    values_group: wgpu::BindGroup,
    gradient_group: wgpu::BindGroup,
    sample_groups: Dispatch,
    point_groups: Dispatch,
    /// `order[sorted] = original` sample index.
    order: Vec<u32>,
    coefficients: usize,
    phi: wgpu::Buffer,
    values: wgpu::Buffer,
    sample_weights: wgpu::Buffer,
    gradient: wgpu::Buffer,
    values_read: wgpu::Buffer,
    gradient_read: wgpu::Buffer,
    _texture: wgpu::Texture,
}

impl PreparedFfd {
    /// The samples.
    #[must_use]
    pub fn samples(&self) -> usize {
        self.order.len()
    }

    /// The image's value at every displaced sample, in the order the samples were given (NaN outside the image or
    /// where a corner has no value), for the coefficients `phi` (3 per control point, x fastest). Keeps the
    /// gradients for [`Self::weighted_gradient`].
    pub fn values(&self, ctx: &GpuContext, phi: &[f64], out: &mut [f64]) -> Result<()> {
        if phi.len() != self.coefficients || out.len() != self.order.len() {
            return Err(GpuError::InvalidInput(format!(
                "{} coefficients and {} outputs for a level of {} coefficients and {} samples",
                phi.len(),
                out.len(),
                self.coefficients,
                self.order.len()
            )));
        }
        let phi32: Vec<f32> = phi.iter().map(|&v| v as f32).collect();
        ctx.queue.write_buffer(&self.phi, 0, bytemuck::cast_slice(&phi32));
        self.run(ctx, Entry::Values, |sorted| {
            for (&original, &v) in self.order.iter().zip(sorted) {
                out[original as usize] = f64::from(v);
            }
        })
    }

    /// G_k = Σ_s w_s B_k(x_s) ∇v(x_s + D(x_s)) for every control point k (3 per point, x fastest) at the
    /// coefficients of the last [`Self::values`]; `weights` in the order the samples were given. A sample of weight
    /// 0 adds nothing, whatever its gradient.
    pub fn weighted_gradient(&self, ctx: &GpuContext, weights: &[f64], out: &mut [f64]) -> Result<()> {
        if weights.len() != self.order.len() || out.len() != self.coefficients {
            return Err(GpuError::InvalidInput(format!(
                "{} weights and {} outputs for a level of {} samples and {} coefficients",
                weights.len(),
                out.len(),
                self.order.len(),
                self.coefficients
            )));
        }
        let sorted: Vec<f32> = self.order.iter().map(|&o| weights[o as usize] as f32).collect();
        ctx.queue.write_buffer(&self.sample_weights, 0, bytemuck::cast_slice(&sorted));
        self.run(ctx, Entry::Gradient, |g| {
            for (o, &v) in out.iter_mut().zip(g) {
                *o = f64::from(v);
            }
        })
    }

    /// Runs `entry`'s pass, waits for the GPU and hands its output (f32, in the pass's order) to `read`.
    fn run(&self, ctx: &GpuContext, entry: Entry, read: impl FnOnce(&[f32])) -> Result<()> {
        let (label, pipeline, group, groups, output, readback) = match entry {
            Entry::Values => (
                VALUES_ENTRY_POINT,
                &self.values_pipeline,
                &self.values_group,
                self.sample_groups,
                &self.values,
                &self.values_read,
            ),
            Entry::Gradient => (
                GRADIENT_ENTRY_POINT,
                &self.gradient_pipeline,
                &self.gradient_group,
                self.point_groups,
                &self.gradient,
                &self.gradient_read,
            ),
        };
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        {
            let mut pass =
                encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(label), timestamp_writes: None });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(groups.x, groups.y, 1);
        }
        encoder.copy_buffer_to_buffer(output, 0, readback, 0, output.size());
        ctx.queue.submit([encoder.finish()]);
        ctx.map_read(readback, readback.size(), |bytes| read(bytemuck::cast_slice(bytes)))
    }
}

/// The two passes of a [`PreparedFfd`].
#[derive(Clone, Copy, Debug)]
enum Entry {
    /// `cs_values`: one invocation per sample.
    Values,
    /// `cs_gradient`: one invocation per control point.
    Gradient,
}
