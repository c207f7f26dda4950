//! Ray picking in the *deformed* volumes (Brunet, Nowak & Gleicher 2006 §4.1 and §5.1): given a pixel of a rendered
//! view, or a ray in ref space, march it through one volume exactly as the frame samples it, and return the first hit
//! of a probe.
//!
//! The pass is the `cs_pick` compute entry point of `shaders/raycast.wgsl`, bound to the frame's own bind group
//! ([`RaycastDrawData`]): the same proxy box, step ([`RaycastUniforms::step_mm`]), pull-back through the control
//! texture, transfer function and gradients. It does not jitter. Probes ([`Probe`]), per sample s of the target
//! volume:
//! - [`Probe::Opacity`]: the first sample whose transfer-function opacity α(s) (before opacity correction, so the
//!   threshold does not depend on the sample rate) reaches the threshold;
//! - [`Probe::Gradient`]: the first sample whose deformed-space gradient magnitude |∇(v∘u)|(s) (value units per mm,
//!   of the prefiltered copy when the frame has one) reaches the threshold;
//! - [`Probe::Accumulated`]: the point where the volume's own front-to-back accumulated opacity reaches the level
//!   (default 0.95), A = A_prev + (1 − A_prev)(1 − (1 − α)^(Δt/ref_step)) with a partial last step.
//!
//! The first sample that satisfies the probe is refined by bisection between it and the previous sample
//! ([`PickRequest::bisection_steps`]; each halves the error, from one step), so hits are finer than the sample
//! spacing and the render resolution. Every lookup of a pick (volume, control texture) is filtered by hand with exact
//! f32 weights, where the frame uses the device's hardware filter: a filter may round its weights to 8 bits (NVIDIA)
//! or even 4 (Vulkan's least), which moves a threshold crossing by a fraction of a voxel, and a pick must land where
//! the CPU reference says on any device. A pick is one ray, so the 8 loads a lookup costs do not matter. A hit ([`PickHit`]) gives x_ref (ref = fixed LPS, mm), its distance along the
//! ray, the same point in the hit volume's own LPS space pulled back through its warp, p_lps = u(x_ref) (what a
//! landmark stores: a source point on the moving volume is p_lps, a target point on the fixed one is x_ref = p_lps),
//! and the value there.
//!
//! The CPU reference is [`crate::cpu_reference::pick`].

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3, Vec4};

use crate::compute::{self, binding, storage, uniform};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::raycast::{self, FRAME_GROUP, RaycastDrawData, RaycastRenderer, RaycastUniforms};
use crate::shader::{BindSlot, ShaderInterface, layout};

/// The pass's own bind group, after the frame's ([`FRAME_GROUP`]).
pub const PICK_GROUP: u32 = 1;
const _: () = assert!(FRAME_GROUP == 0 && PICK_GROUP == 1, "PickPass::new lists the layouts in group order");
pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(PICK_GROUP, 0, "pick");
pub const SLOT_RAYS: BindSlot = BindSlot::new(PICK_GROUP, 1, "pick_rays");
pub const SLOT_HITS: BindSlot = BindSlot::new(PICK_GROUP, 2, "pick_hits");

/// The picking pass's part of `shaders/raycast.wgsl` (the frame's slots are the ray caster's).
pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "pick",
    shader: raycast::SHADER,
    uniform_structs: &[
        layout!(PickUniforms { probe, target_volume, threshold, ray_count, bisection_steps }),
        layout!(PickRay { origin_ref, dir_ref }),
        layout!(PickHit { x_ref, t_mm, p_lps, value, hit, target_volume }),
    ],
    slots: &[SLOT_UNIFORMS, SLOT_RAYS, SLOT_HITS],
    constants: &[],
};

/// What counts as a hit (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Probe {
    /// The first sample with transfer-function opacity ≥ the threshold (0..1).
    Opacity { threshold: f32 },
    /// The first sample with deformed-space gradient magnitude ≥ the threshold (value units per mm).
    Gradient { threshold: f32 },
    /// The point where accumulated opacity reaches the level (0..1; 0.95 is the usual choice).
    Accumulated { level: f32 },
}

impl Probe {
    /// The accumulated-opacity probe at its usual level, 0.95.
    pub const DEFAULT: Self = Self::Accumulated { level: 0.95 };

    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::Opacity { .. } => 0,
            Self::Gradient { .. } => 1,
            Self::Accumulated { .. } => 2,
        }
    }

    #[must_use]
    pub fn threshold(self) -> f32 {
        match self {
            Self::Opacity { threshold } | Self::Gradient { threshold } => threshold,
            Self::Accumulated { level } => level,
        }
    }
}

impl Default for Probe {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Which volume a pick marches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PickTarget {
    /// The fixed volume: targets of landmark pairs.
    Fixed,
    /// The moving volume, deformed: sources of landmark pairs.
    Moving,
}

impl PickTarget {
    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::Fixed => 0,
            Self::Moving => 1,
        }
    }
}

/// One pick: the volume, the probe and the refinement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PickRequest {
    pub target: PickTarget,
    pub probe: Probe,
    /// Bisections between the last two samples (each halves the error; 8 leave step/256).
    pub bisection_steps: u32,
}

impl PickRequest {
    #[must_use]
    pub fn new(target: PickTarget, probe: Probe) -> Self {
        Self { target, probe, bisection_steps: 8 }
    }
}

/// The pass's uniforms: `PickUniforms` in shaders/raycast.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PickUniforms {
    pub probe: u32,
    pub target_volume: u32,
    pub threshold: f32,
    pub ray_count: u32,
    pub bisection_steps: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}
const _: () = assert!(std::mem::size_of::<PickUniforms>() == 32);

impl PickUniforms {
    #[must_use]
    pub fn new(request: &PickRequest, ray_count: u32) -> Self {
        Self {
            probe: request.probe.code(),
            target_volume: request.target.code(),
            threshold: request.probe.threshold(),
            ray_count,
            bisection_steps: request.bisection_steps.min(32),
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
        }
    }
}

/// A ray in ref space (mm): `PickRay` in shaders/raycast.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PickRay {
    pub origin_ref: [f32; 3],
    _pad0: f32,
    /// Unit direction.
    pub dir_ref: [f32; 3],
    _pad1: f32,
}
const _: () = assert!(std::mem::size_of::<PickRay>() == 32);

impl PickRay {
    /// A ray from `origin_ref` along `dir_ref` (normalised here). Errors on a zero or non-finite direction.
    pub fn new(origin_ref: Vec3, dir_ref: Vec3) -> Result<Self> {
        let dir = dir_ref.try_normalize().filter(|_| origin_ref.is_finite()).ok_or_else(|| {
            GpuError::InvalidInput(format!("pick ray from {origin_ref} along {dir_ref} is not a ray"))
        })?;
        Ok(Self { origin_ref: origin_ref.to_array(), _pad0: 0.0, dir_ref: dir.to_array(), _pad1: 0.0 })
    }

    /// The ray through framebuffer point `pixel` (x right, y down; pixel centres at i + ½) of the frame `u`: the same
    /// ray `cs_raycast` marches there, from the near plane.
    pub fn from_pixel(u: &RaycastUniforms, pixel: [f32; 2]) -> Result<Self> {
        let ref_from_clip = Mat4::from_cols_array_2d(&u.ref_from_clip);
        let ndc = [pixel[0] / u.viewport_px[0] * 2.0 - 1.0, 1.0 - pixel[1] / u.viewport_px[1] * 2.0];
        let near_h = ref_from_clip * Vec4::new(ndc[0], ndc[1], 0.0, 1.0);
        let far_h = ref_from_clip * Vec4::new(ndc[0], ndc[1], 1.0, 1.0);
        let origin = near_h.truncate() / near_h.w;
        Self::new(origin, far_h.truncate() / far_h.w - origin)
    }
}

/// The result of one ray: `PickHit` in shaders/raycast.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PickHit {
    /// The hit in ref space (fixed LPS, mm).
    pub x_ref: [f32; 3],
    /// Its distance along the ray from the ray's origin (mm).
    pub t_mm: f32,
    /// The same point in the hit volume's own LPS space: u(w(x_ref)) through its view deformation and its warp
    /// (x_ref without them): the point a landmark records. Under a procedural deformation p of the volume's data, the
    /// value is read at p(p_lps).
    pub p_lps: [f32; 3],
    /// The volume's value there (value units: HU for CT).
    pub value: f32,
    /// 1 for a hit, 0 for none (the other fields are then meaningless).
    pub hit: u32,
    /// [`PickTarget::code`] of the volume marched.
    pub target_volume: u32,
    _pad0: u32,
    _pad1: u32,
}
const _: () = assert!(std::mem::size_of::<PickHit>() == 48);

impl PickHit {
    /// The hit, if there was one.
    #[must_use]
    pub fn found(&self) -> Option<&Self> {
        (self.hit != 0).then_some(self)
    }

    /// A hit record (the CPU reference builds them).
    #[must_use]
    pub fn new(target: PickTarget, x_ref: Vec3, t_mm: f32, p_lps: Vec3, value: f32) -> Self {
        Self {
            x_ref: x_ref.to_array(),
            t_mm,
            p_lps: p_lps.to_array(),
            value,
            hit: 1,
            target_volume: target.code(),
            _pad0: 0,
            _pad1: 0,
        }
    }

    /// The volume marched.
    #[must_use]
    pub fn target(&self) -> PickTarget {
        if self.target_volume == PickTarget::Fixed.code() { PickTarget::Fixed } else { PickTarget::Moving }
    }

    /// No hit.
    #[must_use]
    pub fn miss(target: PickTarget) -> Self {
        Self { hit: 0, target_volume: target.code(), ..Self::zeroed() }
    }
}

/// The picking pass: a compute pipeline over the ray caster's module and frame bind group (group 0) plus its own
/// group 1 (uniforms, rays, hits).
#[derive(Debug)]
pub struct PickPass {
    /// One per set of deformations computed in the shader ([`RaycastUniforms::deformations`]), created on first use.
    pipelines: [std::sync::OnceLock<wgpu::ComputePipeline>; 4],
    layout: wgpu::BindGroupLayout,
    device: wgpu::Device,
    module: wgpu::ShaderModule,
    frame_layout: wgpu::BindGroupLayout,
}

impl PickPass {
    /// Rays per pick call (a click is one; a drag along a surface or a test may send more).
    pub const MAX_RAYS: usize = 65_536;
    const WORKGROUP: u32 = 64;

    pub fn new(ctx: &GpuContext, renderer: &RaycastRenderer) -> Result<Self> {
        if ctx.limits.max_storage_buffers_per_shader_stage < 2 {
            return Err(GpuError::Unsupported("picking needs 2 storage buffers in the compute stage".into()));
        }
        let device = &ctx.device;
        let layout = compute::layout(
            device,
            "pick",
            &[
                binding(SLOT_UNIFORMS, uniform::<PickUniforms>()),
                binding(SLOT_RAYS, storage(true, None)),
                binding(SLOT_HITS, storage(false, None)),
            ],
        );
        let pass = Self {
            pipelines: Default::default(),
            layout,
            device: device.clone(),
            module: renderer.module().clone(),
            frame_layout: renderer.bind_group_layout().clone(),
        };
        // The pipeline without deformations now, so that shader errors surface here; the others on first use.
        pass.pipeline(0);
        ctx.check_errors()?;
        Ok(pass)
    }

    /// The pipeline for `deformations` (the WGSL override `DEFORMATIONS`), created on first use.
    fn pipeline(&self, deformations: u32) -> &wgpu::ComputePipeline {
        let deformations = deformations & (raycast::DEFORM_PROCEDURAL | raycast::DEFORM_VIEW);
        self.pipelines[deformations as usize].get_or_init(|| {
            // The layouts in group order: the ray caster's frame, then the rays and hits.
            compute::pipeline_with(
                &self.device,
                "pick",
                &self.module,
                Some(raycast::PICK_ENTRY_POINT),
                &[&self.frame_layout, &self.layout],
                // Every lookup filtered by hand, exact on any device (shaders/raycast.wgsl, EXACT_FILTER).
                &[("DEFORMATIONS", f64::from(deformations)), ("EXACT_FILTER", 1.0)],
            )
        })
    }

    /// Marches `rays` through the frame `frame` (its uniforms set the box and the step) and returns one
    /// [`PickHit`] per ray. Waits for the result: this is the click-to-result latency.
    pub fn pick(
        &self,
        ctx: &GpuContext,
        frame: &RaycastDrawData,
        request: &PickRequest,
        rays: &[PickRay],
    ) -> Result<Vec<PickHit>> {
        if rays.is_empty() {
            return Ok(Vec::new());
        }
        if rays.len() > Self::MAX_RAYS {
            return Err(GpuError::InvalidInput(format!("{} pick rays; at most {}", rays.len(), Self::MAX_RAYS)));
        }
        if !request.probe.threshold().is_finite() {
            return Err(GpuError::InvalidInput(format!("pick threshold {} is not finite", request.probe.threshold())));
        }
        let count = rays.len() as u32;
        let uniforms = PickUniforms::new(request, count);
        let buffer = |label, size: u64, usage| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let uniform_buffer = buffer(
            "pick uniforms",
            std::mem::size_of::<PickUniforms>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        ctx.queue.write_buffer(&uniform_buffer, 0, bytemuck::bytes_of(&uniforms));
        let ray_buffer = buffer(
            "pick rays",
            std::mem::size_of_val(rays) as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        ctx.queue.write_buffer(&ray_buffer, 0, bytemuck::cast_slice(rays));
        let hits_size = (rays.len() * std::mem::size_of::<PickHit>()) as u64;
        let hit_buffer = buffer("pick hits", hits_size, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC);
        let readback = buffer("pick readback", hits_size, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("pick"),
            layout: &self.layout,
            entries: &[
                SLOT_UNIFORMS.entry(uniform_buffer.as_entire_binding()),
                SLOT_RAYS.entry(ray_buffer.as_entire_binding()),
                SLOT_HITS.entry(hit_buffer.as_entire_binding()),
            ],
        });
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("pick") });
        {
            let mut pass = encoder
                .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("pick"), timestamp_writes: None });
            pass.set_pipeline(self.pipeline(frame.uniforms.deformations()));
            pass.set_bind_group(FRAME_GROUP, frame.bind_group(), &[]);
            pass.set_bind_group(PICK_GROUP, &bind_group, &[]);
            pass.dispatch_workgroups(count.div_ceil(Self::WORKGROUP), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&hit_buffer, 0, &readback, 0, hits_size);
        ctx.queue.submit([encoder.finish()]);
        ctx.map_read(&readback, hits_size, bytemuck::pod_collect_to_vec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probes_carry_their_thresholds() {
        assert_eq!(Probe::default().code(), 2);
        assert!((Probe::default().threshold() - 0.95).abs() < f32::EPSILON);
        let u = PickUniforms::new(&PickRequest::new(PickTarget::Moving, Probe::Gradient { threshold: 40.0 }), 3);
        assert_eq!((u.probe, u.target_volume, u.ray_count, u.bisection_steps), (1, 1, 3, 8));
        assert!(PickRay::new(Vec3::ZERO, Vec3::ZERO).is_err());
        assert!(PickRay::new(Vec3::NAN, Vec3::X).is_err());
    }
}
